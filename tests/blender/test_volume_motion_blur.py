"""Motion blur of volumes against Blender's own Cycles in the same bpy (docs/design/motion-blur.md
"Volumes"): a smoke volume object moving sideways over the shutter (transform blur: its grid is
looked up through the object's transform at the ray's time), and a volume whose .vdb has a
constant velocity grid (velocity blur: Cycles' semi-Lagrangian advection of the lookup); bad
velocity grids warn and render without velocity blur."""
import time

import bpy
import numpy as np

from blender_util import BOX_FILTER, Warnings, load_addon, render_to_array
from light_scenes import camera, empty_scene
from test_motion_blur import linear_keys
from test_volume_objects import (check_agrees, export, file_volume, lit_scene, needs_grids, principled_volume,
                                 smoke_cube, vdb_file)

load_addon()

VOXEL = 1.0 / 16.0  # 32^3 voxels over [-1, 1]^3
SMOKE_SAMPLES = (1024, 512)  # (ours, Cycles': worst region 1.0 % over two seeds, 1.1 % at 2048, 1.4-1.9 % at 512)
VELOCITY_SAMPLES = (4096, 512)  # (the smear's ends are noisy in ours: 3.7 % at 2048)


def glowing_volume(name, emission=2.0):
    """Principled Volume that absorbs (Color black: no scattering) and glows in proportion to
    its "density" grid: each pixel is the grid's emission seen through its absorption over the
    shutter, with little noise in either engine (no lights, no scattering)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    vol.inputs["Emission Color"].default_value = (1.0, 0.6, 0.3, 1.0)
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "density"
    mul = nodes.new("ShaderNodeMath")
    mul.operation = 'MULTIPLY'
    mul.inputs[1].default_value = emission
    links.new(attr.outputs["Fac"], mul.inputs[0])
    links.new(mul.outputs[0], vol.inputs["Emission Strength"])
    links.new(vol.outputs[0], nodes["Material Output"].inputs["Volume"])
    return mat


def dark_scene(size=40):
    """No lights, a black world: only the volume's own glow."""
    scene = empty_scene(size)
    scene.cycles.volume_step_rate = 0.25
    scene.cycles.volume_max_steps = 4096
    camera((0.0, -4.2, 1.4), lens=40.0, look_at=(0.0, 0.0, 0.0))
    return scene


def blurred(scene, shutter=0.5, position='CENTER'):
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = shutter
    scene.render.motion_blur_position = position
    scene.frame_set(1)
    return scene


@needs_grids
def test_moving_smoke_volume_agrees_with_cycles():
    """The smoke cube (geometry-nodes Volume Cube) glowing by its density, sliding 1.6 units a
    frame along x and turning 40 degrees about z: the blur of its grid, not only of its box."""
    scene = dark_scene()
    ob = smoke_cube("Smoke", glowing_volume("Smoke"))
    linear_keys(ob, "location", {0: (-1.6, 0.0, 0.0), 2: (1.6, 0.0, 0.0)})
    linear_keys(ob, "rotation_euler", {0: (0.0, 0.0, -0.7), 2: (0.0, 0.0, 0.7)})
    blurred(scene)
    assert_blurred_agrees(scene, SMOKE_SAMPLES, "moving smoke")


def velocity_file(path, vx=2.0, name="velocity", nan=False, vector=True):
    """A ball of density 3 (1 - |p| / 0.8) and a constant velocity (vx, 0, 0) per frame."""
    import vdb_writer as vw
    dens = vw.Grid(name="density", codec="blosc", transform=("UniformScaleMap", VOXEL))
    vel = vw.Grid(name=name, value_type="vec3s" if vector else "float",
                  background=(vx, 0.0, 0.0) if vector else vx, codec="blosc", transform=("UniformScaleMap", VOXEL))
    for o in [(x, y, z) for x in range(-16, 16, 8) for y in range(-16, 16, 8) for z in range(-16, 16, 8)]:
        idx = (np.indices((8, 8, 8)).transpose(1, 2, 3, 0) + np.array(o)) * VOXEL
        d = np.clip(3.0 * (1.0 - np.linalg.norm(idx, axis=-1) / 0.8), 0.0, None).astype(np.float32)
        dens.leaves[o] = (d, d > 0.0)
        v = np.tile(np.float32([vx, 0.0, 0.0]), (8, 8, 8, 1)) if vector else np.full((8, 8, 8), vx, np.float32)
        if nan:
            v[3, 3, 3] = np.nan
        vel.leaves[o] = (v, np.ones((8, 8, 8), bool))
    dens.leaves = {k: v for k, v in dens.leaves.items() if v[1].any()}
    return vdb_file(path, [dens, vel])


@needs_grids
def test_velocity_grid_agrees_with_cycles(tmp_path):
    """A still volume object whose file has a velocity grid of (2, 0, 0) units per frame (unit
    FRAME, scale 1): Cycles moves the lookup by velocity x (time - 0.5) whatever the shutter,
    so the ball smears +-1 unit along x."""
    scene = dark_scene()
    file_volume("Moving", velocity_file(tmp_path / "velocity.vdb"), glowing_volume("Vel"))
    blurred(scene)
    from addon.export.volume import apply_velocity
    warnings = Warnings()
    (mesh,) = export(warnings).meshes[-1:]
    apply_velocity(mesh, 0.5, 24.0, 'CENTER', warnings)
    assert mesh.velocity is not None and mesh.velocity[1:3] == (1.0, -0.5) and not warnings
    assert_blurred_agrees(scene, VELOCITY_SAMPLES, "velocity grid")


def assert_blurred_agrees(scene, samples, what):
    """Both engines' blurred renders agree (check_agrees: means within 1 %, 8x8 regions within
    3 %), and differ from the still frame by far more than their noise. samples: (ours,
    Cycles'); ours are cheaper per sample but noisier where the blur's ends cross a pixel."""
    t0 = time.time()
    ours = render_to_array(scene, samples=samples[0], max_bounces=2)[..., :3]
    t1 = time.time()
    ref = render_to_array(scene, "CYCLES", samples=samples[1], max_bounces=2, **BOX_FILTER)[..., :3]
    print(f"{what}: pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    check_agrees(ours, ref, what, 0.03)
    scene.render.use_motion_blur = False
    still = render_to_array(scene, samples=64, max_bounces=2)[..., :3]
    scene.render.use_motion_blur = True
    assert np.abs(still.mean(axis=2) - ours.mean(axis=2)).max() > ours.mean()


@needs_grids
def test_bad_velocity_grids_warn_and_render(tmp_path):
    """A velocity grid with NaN values, a float grid named as the velocity: each warns and
    renders without velocity blur. (Blender refuses to name a grid the volume lacks as its
    Velocity Grid.) A vector grid under another name, named by the volume, is used."""
    from addon.export.volume import apply_velocity
    cases = {"NaNs": velocity_file(tmp_path / "nan.vdb", nan=True),
             "NotVector": velocity_file(tmp_path / "float.vdb", vector=False),
             "Named": velocity_file(tmp_path / "vel.vdb", name="vel")}
    for name, path in cases.items():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = lit_scene(16)
        ob = file_volume(name, path, principled_volume(name))
        if name == "Named":
            ob.data.grids.load()
            ob.data.velocity_grid = "vel"
        blurred(scene)
        warnings = Warnings()
        data = export(warnings)
        for mesh in data.meshes:  # (what export.motion.add_motion does for volumes)
            apply_velocity(mesh, 0.5, 24.0, 'CENTER', warnings)
        text = "\n".join(warnings)
        print(name, text)
        if name == "Named":
            assert not warnings and data.meshes[-1].velocity is not None
        else:
            assert f"Volume '{name}'" in text and "without velocity blur" in text
            assert all(getattr(m, "velocity", None) is None for m in data.meshes)
        img = render_to_array(scene, samples=4)
        assert np.isfinite(img).all() and img[..., :3].max() > 0.0
