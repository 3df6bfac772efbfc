"""The Vector pass of a moving Curves object and a moving point cloud against Cycles 4.5 in the
same bpy (multilayer EXR, as test_uv_vector_passes.py): the camera stands still, so every vector
is the objects' own motion between frames. One render per engine (48x48, 16 samples, 1-pixel
box filter, emission only on a transparent film: alpha tells where they are)."""
import math

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, _setup_cycles, core_available, empty_scene_with_camera, load_addon, \
    render_multilayer_file
import material_scenes as ms
from test_hair import add_hair
from test_point_clouds import add_cloud

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

SAMPLES = 16


def _keys(obj, path, values):
    for f, v in values:
        setattr(obj, path, v)
        obj.keyframe_insert(path, frame=f)
    for fc in obj.animation_data.action.fcurves:
        for k in fc.keyframe_points:
            k.interpolation = 'LINEAR'


def moving_scene():
    """Frame 1 of: five thick strands on the left, standing in a vertical plane, sliding +x by
    0.3 a frame and turning about the view axis; a point cloud on the right rising by 0.25 a
    frame."""
    sc = empty_scene_with_camera(48)
    sc.cycles_curves.shape = 'THICK'
    hair = add_hair("Hair", ms.emission("HairGlow", (1.0, 0.6, 0.3), 1.0), strands=5, keys=5, radius=0.1,
                    length=1.6, sag=0.1, spacing=0.3)
    hair.rotation_euler = (math.pi / 2, 0.0, 0.0)  # strands along x, side by side in z
    _keys(hair, "location", ((0, (-1.1, 0.0, -0.5)), (2, (-0.5, 0.0, -0.5))))
    _keys(hair, "rotation_euler", ((0, (math.pi / 2, -0.1, 0.0)), (2, (math.pi / 2, 0.1, 0.0))))
    cloud = add_cloud("Cloud", ms.emission("CloudGlow", (0.3, 0.8, 1.0), 1.0), n=30, spread=1.0,
                      radii=np.full(30, 0.12))
    _keys(cloud, "location", ((0, (0.9, 0.0, -0.9)), (2, (0.9, 0.0, -0.4))))
    sc.frame_set(1)
    sc.view_layers[0].use_pass_vector = True
    sc.render.use_motion_blur = False
    sc.render.film_transparent = True
    return sc


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("curve_point_vectors")
    sc = moving_scene()
    sc.render.engine = 'CYCLES'
    _setup_cycles(sc.cycles, 0)
    sc.cycles.samples = SAMPLES
    sc.cycles.pixel_filter_type, sc.cycles.filter_width = BOX_FILTER["pixel_filter_type"], 1.0
    cycles = render_multilayer_file(sc, tmp / "cycles.exr")
    sc.render.engine = 'PATHLIGHT'
    sc.pathlight.samples = SAMPLES
    sc.pathlight.use_adaptive_sampling = False
    sc.pathlight.max_bounces = 0
    sc.pathlight.filter_type, sc.pathlight.filter_width = 'BOX', 1.0
    pathlight = render_multilayer_file(sc, tmp / "pathlight.exr")
    return cycles, pathlight


def test_curve_and_point_vectors_match_cycles(renders):
    cycles, pathlight = renders
    vc = np.stack([cycles[f"Vector.{c}"] for c in "XYZW"], -1)
    vp = np.stack([pathlight[f"Vector.{c}"] for c in "XYZW"], -1)
    full = (cycles["Combined.A"] > 0.999) & (pathlight["Combined.A"] > 0.999)
    w = full.shape[1]
    hair, cloud = full.copy(), full.copy()
    hair[:, w // 2:] = False
    cloud[:, : w // 2] = False
    assert hair.sum() > 40 and cloud.sum() > 20, (hair.sum(), cloud.sum())
    # Both move by pixels a frame (the camera does not): the strands mostly across, the cloud up.
    assert np.median(np.abs(vc[hair][:, 0])) > 2.0 and np.median(np.abs(vc[hair][:, 2])) > 2.0
    assert np.median(np.abs(vc[cloud][:, 1])) > 1.5 and np.median(np.abs(vc[cloud][:, 3])) > 1.5
    d = np.abs(vc - vp)[full]
    print(f"\ncurve/point vectors: median |d| {np.median(d):.4f} px, 99 % {np.quantile(d, 0.99):.4f} px "
          f"over {full.sum()} pixels")
    assert np.median(d) < 0.05, np.median(d)
    assert np.quantile(d, 0.99) < 0.3, np.quantile(d, 0.99)
    # The world: no motion in either.
    miss = (cycles["Combined.A"] == 0.0) & (pathlight["Combined.A"] == 0.0)
    assert miss.sum() > 300 and not vc[miss].any() and not vp[miss].any()
