"""Procedural world volumes through the add-on against Blender's own Cycles in the same bpy
(docs/design/volumes.md "World volumes"): a closed room filled with world fog whose density is
a Gradient Texture of Position, and a Principled Volume world whose emission comes from a Noise
Texture, each lit by an area light (the spot light's variant is in room_scene, measured in the
docs: too noisy in both engines for 3 % regions at a test's budget); bad values; the compiler's choice between a
program and the homogeneous medium; the warning for an open scene.

Cycles 4.5 ray-marches a heterogeneous world volume in steps of the World's Volume Step Size
times the scene's Volume Step Rate (one jittered shader evaluation per step); the references
use small steps (ROOM / 40), where its answer is near the limit that Pathlight's unbiased
tracking converges to. The room is closed: no ray leaves the scene."""
import logging
import time

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, core_has, load_addon, render_to_array, Warnings
from light_scenes import add_light, box, camera, diffuse_material, empty_scene
from material_scenes import region_means

load_addon()

ROOM = 3.0  # the room's edge (metres)
STEP = 0.075  # Cycles' world Volume Step Size for the references

needs_het = pytest.mark.skipif(not core_has("Scene", "medium_majorants"), reason="the core has no heterogeneous volumes")


def volume_world(name, build):
    """A world with only a Volume (black background): build(nodes, link) returns its shader."""
    world = bpy.data.worlds.new(name)
    world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes["Background"].inputs["Strength"].default_value = 0.0
    out = build(nodes, links.new)
    links.new(out, nodes["World Output"].inputs["Volume"])
    world.cycles.volume_step_size = STEP
    if hasattr(world.cycles, "homogeneous_volume"):
        world.cycles.homogeneous_volume = False
    return world


def position(nodes):
    return nodes.new("ShaderNodeNewGeometry").outputs["Position"]


def gradient_fog(nodes, link):
    """Volume Scatter, density 0.04 + 0.5 clamp(x / ROOM + 0.5) (a Linear Gradient Texture of
    Position, scaled to the room): thin on the left, dense on the right."""
    scale = nodes.new("ShaderNodeVectorMath")
    scale.operation = 'MULTIPLY_ADD'
    scale.inputs[1].default_value = (1.0 / ROOM,) * 3
    scale.inputs[2].default_value = (0.5, 0.5, 0.5)
    link(position(nodes), scale.inputs[0])
    grad = nodes.new("ShaderNodeTexGradient")
    link(scale.outputs[0], grad.inputs["Vector"])
    dens = nodes.new("ShaderNodeMath")
    dens.operation = 'MULTIPLY_ADD'
    dens.inputs[1].default_value = 0.5
    dens.inputs[2].default_value = 0.04
    link(grad.outputs["Fac"], dens.inputs[0])
    sc = nodes.new("ShaderNodeVolumeScatter")
    sc.inputs["Color"].default_value = (0.9, 0.85, 0.75, 1.0)
    sc.inputs["Anisotropy"].default_value = 0.3
    link(dens.outputs[0], sc.inputs["Density"])
    return sc.outputs[0]


def noise_emission(nodes, link):
    """Principled Volume (density 0.3) whose Emission Strength is a Noise Texture of Position
    through Map Range (Fac 0.35..0.65 -> 0..0.6)."""
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Density"].default_value = 0.3
    vol.inputs["Color"].default_value = (0.7, 0.7, 0.7, 1.0)
    vol.inputs["Emission Color"].default_value = (1.0, 0.6, 0.3, 1.0)
    noise = nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 0.8
    noise.inputs["Detail"].default_value = 0.0
    link(position(nodes), noise.inputs["Vector"])
    ramp = nodes.new("ShaderNodeMapRange")
    ramp.inputs["From Min"].default_value = 0.35
    ramp.inputs["From Max"].default_value = 0.65
    ramp.inputs["To Max"].default_value = 0.6
    link(noise.outputs["Fac"], ramp.inputs["Value"])
    link(ramp.outputs["Result"], vol.inputs["Emission Strength"])
    return vol.outputs[0]


def room_scene(build, light, size=48):
    """A closed box room (diffuse walls), the camera inside it, the world's Volume filling it."""
    scene = empty_scene(size)
    scene.cycles.volume_step_rate = 1.0
    scene.cycles.volume_max_steps = 1024
    box("Room", ROOM, diffuse_material("Walls", 0.5), location=(0.0, 0.0, 0.5 * ROOM))
    box("Block", 0.6, diffuse_material("Block", 0.7), location=(0.3, 0.4, 0.3))
    if light == 'SPOT':
        # Above and behind the camera, its cone going away from it: the fog close to the lamp
        # (where both engines' light samples are noisiest) is out of view.
        from mathutils import Vector
        at, aim = Vector((-0.4, -0.5 * ROOM + 0.3, ROOM - 0.3)), Vector((0.3, 0.6, 0.0))
        add_light('SPOT', location=at, rotation=(aim - at).to_track_quat('-Z', 'Y').to_euler(), energy=800.0,
                  spot_size=1.0, spot_blend=0.3, shadow_soft_size=0.2)
    else:
        # Above the camera: the fog right under the lamp (where our light samples, without
        # equiangular sampling, are noisiest) is out of view.
        add_light('AREA', location=(0.0, -0.9, ROOM - 0.05), energy=300.0, size=0.8)
    camera((0.0, -0.5 * ROOM + 0.2, 1.2), lens=18.0, look_at=(0.0, 0.5 * ROOM, 0.9))
    return scene


# (samples: the fewest where both engines' 8x8 regions agree within 3 %; a spot light's cone
# with the same fog: docs/design/volumes.md "World volumes")
# (max bounces 8 for the emitting fog: at 4 ours is 0.8 % darker in red, the emission's channel,
# a bounce-limit difference on the last segment's volume emission; 0.4 % at 8)
CASES = {"gradient_area": (gradient_fog, 'AREA', 1024, 4), "noise_emission_area": (noise_emission, 'AREA', 512, 8)}
# Cycles' image is stored (no test time): the emitting fog's at 4x, where at equal samples it
# failed at one seed of three with the 4-D sets (3.30 %, tolerance 3 %), issue 25.
CYCLES_FACTOR = {"noise_emission_area": 4}


@needs_het
@pytest.mark.parametrize("case", CASES)
def test_world_volume_program_agrees_with_cycles(case):
    build, light, samples, bounces = CASES[case]
    scene = room_scene(build, light)
    scene.world = volume_world(case, build)
    t0 = time.time()
    ours = render_to_array(scene, samples=samples, max_bounces=bounces)[..., :3]
    t1 = time.time()
    ref = render_to_array(scene, "CYCLES", samples=samples * CYCLES_FACTOR.get(case, 1), max_bounces=bounces,
                          **BOX_FILTER)[..., :3]
    print(f"{case}: pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    a, b = region_means(ours), region_means(ref)
    rel = np.abs(a - b) / np.maximum(b, 0.25 * b.mean())
    worst = np.unravel_index(np.argmax(rel), rel.shape)
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    print(case, "mean ratio", ratio, "worst region", rel.max(), "median", np.median(rel))
    assert ours.mean() > 0.01
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    assert rel.max() < 0.03, (worst, a[worst], b[worst])


def test_world_volume_compiles_to_a_program_only_where_it_varies():
    """A Gradient of Position gives a program (no warning); constant inputs keep the dict."""
    from addon.export.world import world_volume
    w = Warnings()
    prog = world_volume(volume_world("Varying", gradient_fog), w)
    assert len(w) == 0, w
    assert isinstance(prog, list) and prog[-1][:3] == ("closure", "volume", None)
    assert any(op[0] == "gradient" for op in prog), [op[0] for op in prog]

    def constant(nodes, link):
        return nodes.new("ShaderNodeVolumeScatter").outputs[0]
    vol = world_volume(volume_world("Constant", constant), w)
    assert len(w) == 0 and isinstance(vol, dict) and vol["sigma_s"] == pytest.approx((0.8, 0.8, 0.8))  # colour 0.8 x density 1


@needs_het
def test_bad_world_volume_values_render_finite_and_open_scenes_warn(caplog):
    """A world density that goes negative (Map Range below 0) and NaN (0 / 0 in a Math node
    that Cycles makes safe, ours too) renders finite; an open scene (no room) warns that the
    fog ends at the scene's bounds, a closed one does not."""
    def bad(nodes, link):
        sep = nodes.new("ShaderNodeSeparateXYZ")
        link(position(nodes), sep.inputs[0])
        neg = nodes.new("ShaderNodeMapRange")  # x in [-1, 1] -> density [-3, 1]
        neg.inputs["From Min"].default_value = -1.0
        neg.inputs["To Min"].default_value = -3.0
        neg.clamp = False
        link(sep.outputs["X"], neg.inputs["Value"])
        div = nodes.new("ShaderNodeMath")
        div.operation = 'DIVIDE'
        link(sep.outputs["Y"], div.inputs[0])
        div.inputs[1].default_value = 0.0
        add = nodes.new("ShaderNodeMath")
        link(neg.outputs["Result"], add.inputs[0])
        link(div.outputs[0], add.inputs[1])
        vol = nodes.new("ShaderNodeVolumePrincipled")
        link(add.outputs[0], vol.inputs["Density"])
        link(add.outputs[0], vol.inputs["Emission Strength"])
        return vol.outputs[0]
    scene = room_scene(bad, 'AREA', size=16)
    scene.world = volume_world("Bad", bad)
    with caplog.at_level(logging.WARNING, logger="addon.session"):
        img = render_to_array(scene, samples=8, max_bounces=8)
    assert np.all(np.isfinite(img)) and img[..., :3].max() > 0.0
    assert not any("leave the scene" in r.getMessage() for r in caplog.records)
    # Open: the room removed.
    bpy.data.objects.remove(bpy.data.objects["Room"])
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="addon.session"):
        img = render_to_array(scene, samples=4, max_bounces=4)
    assert np.all(np.isfinite(img))
    assert any("leave the scene" in r.getMessage() for r in caplog.records), caplog.records

