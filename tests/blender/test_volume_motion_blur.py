"""Motion blur of volumes against Blender's own Cycles in the same bpy (docs/design/motion-blur.md
"Volumes"): a smoke volume object moving sideways over the shutter (transform blur: its grid is
looked up through the object's transform at the ray's time), and a volume whose .vdb has a
constant velocity grid (velocity blur: Cycles' semi-Lagrangian advection of the lookup); bad
velocity grids warn and render without velocity blur."""
import bpy
import numpy as np
import pytest

from blender_util import Warnings, load_addon, render_to_array
from test_motion_blur import linear_keys
from test_volume_objects import (check_agrees, export, file_volume, lit_scene, needs_grids, principled_volume,
                                 render_both, smoke_cube, vdb_file)

load_addon()

VOXEL = 1.0 / 16.0  # 32^3 voxels over [-1, 1]^3


@pytest.fixture(autouse=True, scope="module")
def factory_scene_afterwards():
    yield
    bpy.ops.wm.read_factory_settings(use_empty=True)


def blurred(scene, shutter=0.5, position='CENTER'):
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = shutter
    scene.render.motion_blur_position = position
    scene.frame_set(1)
    return scene


@needs_grids
def test_moving_smoke_volume_agrees_with_cycles():
    """The smoke cube (geometry-nodes Volume Cube, Principled Volume) sliding 1.6 units a frame
    along x and turning 40 degrees about z: the blur of its grid, not only of its box."""
    scene = lit_scene()
    ob = smoke_cube("Smoke", principled_volume("Smoke", density=1.5))
    linear_keys(ob, "location", {0: (-1.6, 0.0, 0.0), 2: (1.6, 0.0, 0.0)})
    linear_keys(ob, "rotation_euler", {0: (0.0, 0.0, -0.7), 2: (0.0, 0.0, 0.7)})
    blurred(scene)
    assert_blurred_agrees(scene, 512, "moving smoke")


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
    """A still volume object whose file has a velocity grid of (2, 0, 0) units per frame: with a
    0.5-frame shutter centred on the frame, the ball smears +-0.5 units along x."""
    scene = lit_scene()
    file_volume("Moving", velocity_file(tmp_path / "velocity.vdb"), principled_volume("Vel", density=1.0))
    blurred(scene)
    from addon.export.volume import apply_velocity
    warnings = Warnings()
    (mesh,) = export(warnings).meshes[-1:]
    apply_velocity(mesh, 0.5, 24.0, 'CENTER', warnings)
    assert mesh.velocity is not None and mesh.velocity[1:3] == (1.0, -0.5) and not warnings
    assert_blurred_agrees(scene, 512, "velocity grid")


def assert_blurred_agrees(scene, samples, what):
    ours, ref = render_both(scene, samples, what)
    check_agrees(ours, ref, what, 0.03)
    # The blur shows: the still frame differs from the blurred render by far more than noise.
    scene.render.use_motion_blur = False
    still = render_to_array(scene, samples=64, max_bounces=8)[..., :3]
    scene.render.use_motion_blur = True
    assert np.abs(still.mean(axis=2) - ours.mean(axis=2)).max() > 0.1 * ours.mean()


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
        bpy.ops.wm.read_factory_settings(use_empty=True)
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
