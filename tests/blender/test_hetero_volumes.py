"""Heterogeneous volumes through the add-on against Blender's own Cycles in the same bpy: a
Principled Volume cube whose Density is a Noise Texture, one whose Density is a Gradient
Texture on Generated coordinates (a Volume Scatter plus Volume Absorption), under a point
light on a diffuse floor, and a Principled Volume glowing by its Blackbody emission with a
temperature that varies across the cube (docs/design/volumes.md).

Blender 4.5's Cycles ray-marches such volumes (steps of the object's bounds / 10 times the
scene's and the material's Volume Step Rate, one shader evaluation per jittered step, biased
for coarse steps); the references here use rates 0.1 x 0.1 (about 100 steps across the cube,
max steps raised to match), where its answer is within a fraction of a percent of the limit."""
import time

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, core_has, load_addon, render_to_array
from light_scenes import add_light, box, camera, diffuse_material, empty_scene, plane
from material_scenes import region_means

load_addon()

STEP_RATE = 0.3  # Cycles' scene and material Volume Step Rate for the references

needs_het = pytest.mark.skipif(not core_has("Scene", "medium_majorants"), reason="the core has no heterogeneous volumes")


def volume_material(name, build):
    """A material with only a Volume: build(nodes, link) returns the volume shader's output."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    out = build(nodes, links.new)
    links.new(out, nodes["Material Output"].inputs["Volume"])
    mat.cycles.volume_step_rate = STEP_RATE
    return mat


def noise_density(nodes, link):
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Color"].default_value = (0.8, 0.75, 0.6, 1.0)
    vol.inputs["Anisotropy"].default_value = 0.2
    noise = nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 2.5
    noise.inputs["Detail"].default_value = 2.0
    ramp = nodes.new("ShaderNodeMapRange")  # Fac 0.35..0.65 -> density 0..4
    ramp.inputs["From Min"].default_value = 0.35
    ramp.inputs["From Max"].default_value = 0.65
    ramp.inputs["To Max"].default_value = 4.0
    link(noise.outputs["Fac"], ramp.inputs["Value"])
    link(ramp.outputs["Result"], vol.inputs["Density"])
    return vol.outputs[0]


def gradient_density(nodes, link):
    coords = nodes.new("ShaderNodeTexCoord")
    grad = nodes.new("ShaderNodeTexGradient")
    link(coords.outputs["Generated"], grad.inputs["Vector"])
    scale = nodes.new("ShaderNodeMath")
    scale.operation = 'MULTIPLY'
    scale.inputs[1].default_value = 3.0
    link(grad.outputs["Fac"], scale.inputs[0])
    sc = nodes.new("ShaderNodeVolumeScatter")
    sc.inputs["Color"].default_value = (0.9, 0.8, 0.6, 1.0)
    link(scale.outputs[0], sc.inputs["Density"])
    ab = nodes.new("ShaderNodeVolumeAbsorption")
    ab.inputs["Color"].default_value = (0.6, 0.7, 0.9, 1.0)
    link(scale.outputs[0], ab.inputs["Density"])
    add = nodes.new("ShaderNodeAddShader")
    link(sc.outputs[0], add.inputs[0])
    link(ab.outputs[0], add.inputs[1])
    return add.outputs[0]


def blackbody_flame(nodes, link):
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Density"].default_value = 0.6
    vol.inputs["Color"].default_value = (0.3, 0.3, 0.3, 1.0)
    vol.inputs["Blackbody Intensity"].default_value = 1.0
    coords = nodes.new("ShaderNodeTexCoord")
    grad = nodes.new("ShaderNodeTexGradient")
    grad.gradient_type = 'SPHERICAL'
    link(coords.outputs["Object"], grad.inputs["Vector"])
    # 2200 K at the rim .. 3500 K at the centre (in cooler flames Cycles' blackbody colour has
    # negative green or blue, which its emission keeps and ours clamps to 0).
    temp = nodes.new("ShaderNodeMapRange")
    temp.inputs["To Min"].default_value = 2200.0
    temp.inputs["To Max"].default_value = 3500.0
    link(grad.outputs["Fac"], temp.inputs["Value"])
    link(temp.outputs["Result"], vol.inputs["Temperature"])
    return vol.outputs[0]


def absorption_texture(nodes, link):
    """Principled Volume whose Absorption Color is the Generated coordinates (a colour varying
    along each axis): absorption max(1 - colour, 0) max(1 - sqrt(that), 0) per point."""
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Color"].default_value = (0.6, 0.6, 0.6, 1.0)
    vol.inputs["Density"].default_value = 1.5
    coords = nodes.new("ShaderNodeTexCoord")
    link(coords.outputs["Generated"], vol.inputs["Absorption Color"])
    return vol.outputs[0]


def het_scene(build, lit=True, size=48):
    scene = empty_scene(size)
    scene.cycles.volume_step_rate = STEP_RATE
    scene.cycles.volume_max_steps = 4096
    plane("Floor", 8.0, diffuse_material("Floor", 0.6))
    box("Fog", 1.6, volume_material("Fog", build), location=(0.0, 0.0, 0.85), rotation_euler=(0.0, 0.0, 0.5))
    if lit:
        add_light('POINT', location=(1.6, -1.4, 2.6), energy=400.0, shadow_soft_size=0.3)
    camera((0.0, -4.5, 2.2), lens=40.0, look_at=(0.0, 0.0, 0.7))
    return scene


CASES = {"noise": (noise_density, True, 1024), "gradient": (gradient_density, True, 2048),
         "blackbody": (blackbody_flame, False, 2048), "absorption_texture": (absorption_texture, True, 1024)}
CYCLES_FACTOR = {"gradient": 2}


@needs_het
@pytest.mark.parametrize("case", CASES)
def test_heterogeneous_volume_agrees_with_cycles(case):
    build, lit, samples = CASES[case]
    scene = het_scene(build, lit)
    t0 = time.time()
    ours = render_to_array(scene, samples=samples, max_bounces=8)[..., :3]
    t1 = time.time()
    # (The gradient at 2048 spp, Cycles 4096, stored: at 1024 each its worst region was 1.4-4.9 %
    # over seeds 0-5 with the 4-D sets, 1.6-3.3 % with the pairs, tolerance 3 %; issue 25)
    ref = render_to_array(scene, "CYCLES", samples=samples * CYCLES_FACTOR.get(case, 1), max_bounces=8,
                          **BOX_FILTER)[..., :3]
    print(f"{case}: pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    a, b = region_means(ours), region_means(ref)
    floor = 0.25 * b.mean()
    rel = np.abs(a - b) / np.maximum(b, floor)
    worst = np.unravel_index(np.argmax(rel), rel.shape)
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    print(case, "mean ratio", ratio, "worst region", rel.max(), "median", np.median(rel))
    assert ours.mean() > 0.01
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    assert rel.max() < 0.03, (worst, a[worst], b[worst])


def test_compiler_makes_programs_only_for_varying_volumes():
    """A Noise-driven density compiles to a volume program; constant inputs keep the homogeneous
    dict (as before); a constant Blackbody folds to a homogeneous emission (red at 1000 K)."""
    from addon.export.material import convert_material
    from blender_util import Warnings

    def compiled(build):
        w = Warnings()
        data = convert_material(volume_material("M", build), w, None, None, False)
        assert len(w) == 0, w
        return data.volume

    prog = compiled(noise_density)
    assert isinstance(prog, list) and prog[-1][:3] == ("closure", "volume", None)
    assert set(prog[-1][3]) == {"sigma_a", "sigma_s", "g"} and any(op[0] == "tex_noise" for op in prog)

    def constant(nodes, link):
        return nodes.new("ShaderNodeVolumePrincipled").outputs[0]
    vol = compiled(constant)
    assert isinstance(vol, dict) and vol["sigma_s"] == pytest.approx((0.5, 0.5, 0.5))

    def hot(nodes, link):
        v = nodes.new("ShaderNodeVolumePrincipled")
        v.inputs["Blackbody Intensity"].default_value = 1.0
        v.inputs["Temperature"].default_value = 1000.0
        return v.outputs[0]
    vol = compiled(hot)
    assert isinstance(vol, dict)
    e = vol["emission"]
    # sigma T^4 (Cycles' 5.670373e-14 / pi) times a colour of luminance about 1.
    assert e[0] > e[1] > e[2] >= 0.0 and 0.3 * 5.670373e-14 / np.pi * 1e12 < e[0] < 10 * 5.670373e-14 / np.pi * 1e12


@needs_het
def test_mix_shader_with_a_linked_factor_compiles_and_the_core_accepts_it():
    """Mix Shader of Volume Scatter and Emission with its Fac from a Gradient: a program whose
    coefficients at points follow the mix (sigma_s = (1 - f) c d, emission = f e)."""
    from addon.export.material import convert_material
    from blender_util import Warnings

    def mixed(nodes, link):
        coords = nodes.new("ShaderNodeTexCoord")
        grad = nodes.new("ShaderNodeTexGradient")
        link(coords.outputs["Object"], grad.inputs["Vector"])
        sc = nodes.new("ShaderNodeVolumeScatter")
        sc.inputs["Density"].default_value = 2.0
        sc.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
        em = nodes.new("ShaderNodeEmission")
        em.inputs["Strength"].default_value = 3.0
        mix = nodes.new("ShaderNodeMixShader")
        link(grad.outputs["Fac"], mix.inputs["Fac"])
        link(sc.outputs[0], mix.inputs[1])
        link(em.outputs[0], mix.inputs[2])
        return mix.outputs[0]
    w = Warnings()
    data = convert_material(volume_material("Mixed", mixed), w, None, None, False)
    assert len(w) == 0 and isinstance(data.volume, list)
    pc = load_addon().core.get_core()
    s = pc.Scene()
    m = s.add_shader("Mixed", data.program, volume=data.volume)
    pos = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], np.float32)
    tris = np.array([(0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4), (2, 6, 7), (2, 7, 3),
                     (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5)], np.int32)
    s.add_instance(s.add_mesh(pos, tris, None, None, [m]), np.eye(4, dtype=np.float32))
    s.commit()
    for x in (-0.5, 0.0, 0.5):  # Blender's linear gradient: f = clamp(x, 0, 1) in object space
        f = min(max(x, 0.0), 1.0)
        d = s.medium_at(0, m, (x, 0.1, 0.2))
        assert d["sigma_s"] == pytest.approx(((1 - f) * 2.0, (1 - f) * 1.0, (1 - f) * 0.5), abs=1e-5)
        assert d["emission"] == pytest.approx((3.0 * f,) * 3, abs=1e-5)
