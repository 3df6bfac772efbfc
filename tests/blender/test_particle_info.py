"""Particle Info on particle instances against Cycles in the same bpy: small emissive spheres
instanced by an emitter particle system at frame 4, each coloured by one of the node's outputs
(Random, Index, Age over Lifetime, Size, Location, Velocity, Angular Velocity), and the same
material on an object that is no particle (Cycles' dummy particle: zeros, the random number of
index 0)."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms
from shader_compiler_util import compile_

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

FRAME = 4
# (Particle Info output, how its value becomes an emission colour: a vector as it is, scaled; a
# scalar through a Combine Color with fixed G, B so that a channel mix-up shows).
OUTPUTS = (("Random", 1.0), ("Index", 0.05), ("Age", 0.2), ("Lifetime", 0.02), ("Size", 4.0),
           ("Location", 0.4), ("Velocity", 0.5), ("Angular Velocity", 0.5))


def particle_material(output, scale):
    mat, nodes, links, out = ms.new_material(f"PI {output}")
    info = nodes.new("ShaderNodeParticleInfo")
    emit = nodes.new("ShaderNodeEmission")
    mul = nodes.new("ShaderNodeVectorMath")
    mul.operation = 'MULTIPLY'
    mul.inputs[1].default_value = (scale, scale, scale)
    if info.outputs[output].type == 'VECTOR':
        links.new(info.outputs[output], mul.inputs[0])
        absolute = nodes.new("ShaderNodeVectorMath")  # negative components glow too
        absolute.operation = 'ABSOLUTE'
        links.new(mul.outputs[0], absolute.inputs[0])
        links.new(absolute.outputs[0], emit.inputs["Color"])
    else:
        combine = nodes.new("ShaderNodeCombineColor")
        links.new(info.outputs[output], combine.inputs["Red"])
        combine.inputs["Green"].default_value = 0.3
        combine.inputs["Blue"].default_value = 0.1
        links.new(combine.outputs[0], mul.inputs[0])
        links.new(mul.outputs[0], emit.inputs["Color"])
    links.new(emit.outputs[0], out.inputs["Surface"])
    return mat


def build(output, scale):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    sc = bpy.context.scene
    sc.render.resolution_x, sc.render.resolution_y = 64, 48
    sc.render.resolution_percentage = 100
    ms.set_world((0.0, 0.0, 0.0))
    ms.add_camera((0.0, -3.2, 3.0), (0.2, 0.0, 0.2))
    mat = particle_material(output, scale)
    dot = ms.add_sphere("Dot", 1.0, mat, segments=12, rings=6, location=(0.0, 0.0, -20.0))
    emitter = ms.add_plane("Emitter", 2.4, ms.emission("Hidden", (0, 0, 0), 0.0), location=(0.0, 0.0, 0.0))
    mod = emitter.modifiers.new("Scatter", 'PARTICLE_SYSTEM')
    s = mod.particle_system.settings
    s.count = 24
    s.frame_start, s.frame_end = 1.0, 3.0  # births over three frames: ages differ
    s.lifetime = 40.0
    s.lifetime_random = 0.5
    s.emit_from = 'FACE'
    s.normal_factor = 0.3
    s.object_align_factor[2] = 0.0
    s.use_rotations = True
    s.angular_velocity_mode = 'RAND'
    s.angular_velocity_factor = 2.0
    s.effector_weights.gravity = 0.0
    s.render_type = 'OBJECT'
    s.instance_object = dot
    s.particle_size = 0.09
    s.size_random = 0.6
    emitter.show_instancer_for_render = False
    # The same material off particles: a cube beside the patch.
    ms.add_mesh_object("Plain", lambda bm: __import__("bmesh").ops.create_cube(bm, size=0.4), (mat,),
                       location=(1.7, 0.0, 0.3))
    for f in range(1, FRAME + 1):  # the particle cache steps frame by frame
        sc.frame_set(f)
    return sc


@pytest.fixture(scope="module")
def renders():
    out = {}
    for output, scale in OUTPUTS:
        ours = render_to_array(build(output, scale), "PATHLIGHT", samples=16, max_bounces=2)
        cycles = render_to_array(build(output, scale), "CYCLES", samples=16, max_bounces=2,
                                 **ms.BOX_FILTER)
        out[output] = ours, cycles
    return out


def test_particle_info_compiles_without_warnings():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    for output, scale in OUTPUTS:
        _, warnings = compile_(particle_material(output, scale))
        assert not warnings, (output, warnings)


@pytest.mark.parametrize("output", [o for o, _ in OUTPUTS])
def test_particle_info_output_agrees_with_cycles(renders, output):
    ours, cycles = renders[output]
    a, b = ours[..., :3].astype(np.float64), cycles[..., :3].astype(np.float64)
    assert b.max() > 0.05, "the scene shows nothing"
    lit = b.max(-1) > 1e-3
    assert lit.sum() > 40, "too few particle pixels to compare"
    # Emission only, 16 samples of a box filter: pixels inside a particle agree exactly; only
    # silhouettes differ, by coverage noise (so regions of these few-pixel particles are not
    # compared); the image means agree closely.
    ratio = a.mean() / b.mean()
    print(f"\n{output}: mean ratio {ratio:.4f}")
    assert abs(ratio - 1.0) < 0.03, ratio
    # Per channel inside the particles (pixels whose 3x3 neighbourhood is lit in both images,
    # away from silhouettes): the colours, not only the grey levels, agree to float precision.
    both = (a.max(-1) > 1e-3) & lit
    inside = both.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            inside &= np.roll(np.roll(both, dy, 0), dx, 1)
    inside[[0, -1], :] = inside[:, [0, -1]] = False
    assert inside.sum() > 10, "no particle interiors to compare"
    err = np.abs(a[inside] - b[inside]).max() / b[inside].max()
    print(f"{output}: {inside.sum()} interior pixels, worst colour difference {err:.2e}")
    assert err < 1e-3, err
