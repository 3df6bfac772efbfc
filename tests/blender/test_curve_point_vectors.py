"""The Vector pass of moving and deforming Curves objects and point clouds against Cycles 4.5
in the same bpy (multilayer EXR, as test_uv_vector_passes.py): the camera stands still, so every
vector is the objects' own motion between frames. One render per engine (48x48, 16 samples, 1-pixel
box filter, emission only on a transparent film: alpha tells where they are)."""
import math

import bpy
import numpy as np
import pytest

from blender_util import core_available, empty_scene_with_camera, load_addon, render_multilayer_pair
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


def render_both(sc, tmp):
    """The scene's multilayer passes from Cycles and from Pathlight, rendered alike (emission
    only: no bounces)."""
    return render_multilayer_pair(sc, tmp, SAMPLES, 0)


def vectors_and_masks(cycles, pathlight, cloud_pixels=20):
    """Both engines' Vector passes (H, W, 4) and where both cover a pixel fully: everywhere,
    the strands' left half, the cloud's right half."""
    vc = np.stack([cycles[f"Vector.{c}"] for c in "XYZW"], -1)
    vp = np.stack([pathlight[f"Vector.{c}"] for c in "XYZW"], -1)
    full = (cycles["Combined.A"] > 0.999) & (pathlight["Combined.A"] > 0.999)
    w = full.shape[1]
    hair, cloud = full.copy(), full.copy()
    hair[:, w // 2:] = False
    cloud[:, : w // 2] = False
    assert hair.sum() > 40 and cloud.sum() >= cloud_pixels, (hair.sum(), cloud.sum())
    return vc, vp, full, hair, cloud


def assert_vectors_agree(vc, vp, full, what):
    d = np.abs(vc - vp)[full]
    print(f"\n{what}: median |d| {np.median(d):.4f} px, 99 % {np.quantile(d, 0.99):.4f} px "
          f"over {full.sum()} pixels")
    assert np.median(d) < 0.05, np.median(d)
    assert np.quantile(d, 0.99) < 0.3, np.quantile(d, 0.99)


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    return render_both(moving_scene(), tmp_path_factory.mktemp("curve_point_vectors"))


def test_curve_and_point_vectors_match_cycles(renders):
    cycles, pathlight = renders
    vc, vp, full, hair, cloud = vectors_and_masks(cycles, pathlight)
    # Both move by pixels a frame (the camera does not): the strands mostly across, the cloud up.
    assert np.median(np.abs(vc[hair][:, 0])) > 2.0 and np.median(np.abs(vc[hair][:, 2])) > 2.0
    assert np.median(np.abs(vc[cloud][:, 1])) > 1.5 and np.median(np.abs(vc[cloud][:, 3])) > 1.5
    assert_vectors_agree(vc, vp, full, "curve/point vectors")
    # The world: no motion in either.
    miss = (cycles["Combined.A"] == 0.0) & (pathlight["Combined.A"] == 0.0)
    assert miss.sum() > 300 and not vc[miss].any() and not vp[miss].any()


def offset_by_frame(obj, name, axis_in, axis_out, rate, bias=0.0):
    """A Geometry Nodes modifier that moves each point along `axis_out` by
    rate * (its `axis_in` coordinate + bias) * the scene frame: a deformation, not a transform."""
    tree = bpy.data.node_groups.new(name, 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    nodes, links = tree.nodes, tree.links
    gi, go = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    set_pos, pos = nodes.new("GeometryNodeSetPosition"), nodes.new("GeometryNodeInputPosition")
    sep, comb = nodes.new("ShaderNodeSeparateXYZ"), nodes.new("ShaderNodeCombineXYZ")
    time = nodes.new("GeometryNodeInputSceneTime")
    shift, scale = nodes.new("ShaderNodeMath"), nodes.new("ShaderNodeMath")
    shift.operation, scale.operation = 'ADD', 'MULTIPLY'
    shift.inputs[1].default_value = bias
    by_frame = nodes.new("ShaderNodeMath")
    by_frame.operation = 'MULTIPLY'
    by_frame.inputs[1].default_value = rate
    links.new(pos.outputs[0], sep.inputs[0])
    links.new(sep.outputs[axis_in], shift.inputs[0])
    links.new(shift.outputs[0], scale.inputs[0])
    links.new(time.outputs["Frame"], scale.inputs[1])
    links.new(scale.outputs[0], by_frame.inputs[0])
    links.new(by_frame.outputs[0], comb.inputs[axis_out])
    links.new(gi.outputs[0], set_pos.inputs["Geometry"])
    links.new(comb.outputs[0], set_pos.inputs["Offset"])
    links.new(set_pos.outputs[0], go.inputs[0])
    obj.modifiers.new(name, 'NODES').node_group = tree


def deforming_scene():
    """Frame 1 of: the strands standing still but bending, their tips rising 0.4 a frame and
    their roots not at all (Geometry Nodes, by the frame); the cloud's points rising by
    0.1-0.5 a frame, more the further right. The objects' transforms do not change."""
    sc = empty_scene_with_camera(48)
    sc.cycles_curves.shape = 'THICK'
    hair = add_hair("Hair", ms.emission("HairGlow", (1.0, 0.6, 0.3), 1.0), strands=5, keys=5, radius=0.1,
                    length=1.6, sag=0.1, spacing=0.3)
    hair.rotation_euler = (math.pi / 2, 0.0, 0.0)  # strands along x, side by side in z
    hair.location = (-0.8, 0.0, -0.3)
    offset_by_frame(hair, "Bend", 0, 1, 0.25, bias=0.8)  # object y (world z) by x + 0.8
    cloud = add_cloud("Cloud", ms.emission("CloudGlow", (0.3, 0.8, 1.0), 1.0), n=30, spread=1.0,
                      radii=np.full(30, 0.12))
    cloud.location = (0.9, 0.0, -0.9)
    offset_by_frame(cloud, "Rise", 0, 2, 0.4, bias=0.75)
    sc.frame_set(1)
    sc.view_layers[0].use_pass_vector = True
    sc.render.use_motion_blur = False
    sc.render.film_transparent = True
    return sc


def test_deforming_curve_and_point_vectors_match_cycles(tmp_path):
    """Cycles reads the strands' own motion between frames (its motion keys); so does Pathlight
    (pass_points). The deforming cloud is checked against its closed form instead: Cycles 4.5
    gives each of its points the same position at both frames (X = -Z, Y = -W: not a motion),
    where Pathlight moves each point's centre as the points move."""
    cycles, pathlight = render_both(deforming_scene(), tmp_path)
    vc, vp, full, hair, cloud = vectors_and_masks(cycles, pathlight)
    # The strands: vertical motion only, unlike along them (a deformation), as Cycles'.
    assert np.median(np.abs(vc[hair][:, 1])) > 0.5 and np.ptp(vc[hair][:, 1]) > 2.0
    assert np.median(np.abs(vc[hair][:, 0])) < 0.05
    assert_vectors_agree(vc, vp, hair, "deforming curve vectors")
    # The cloud: each point rises steadily (previous - now = now - next, both vertical), by
    # 0.1-0.5 a frame (the camera sees about 10 px per unit there), unlike from point to point.
    v = vp[cloud]
    assert np.abs(v[:, [0, 2]]).max() < 0.05
    np.testing.assert_allclose(v[:, 1], v[:, 3], atol=0.02)
    assert -6.0 < v[:, 1].min() and v[:, 1].max() < -0.5 and np.ptp(v[:, 1]) > 2.0


def test_curve_vectors_from_a_velocity_attribute_match_cycles(tmp_path):
    """A Curves object with a 'velocity' attribute (units per second) and nothing animated:
    Cycles takes its motion keys from it (the points -+ velocity x one frame in seconds), and
    so does Pathlight's Vector pass."""
    sc = empty_scene_with_camera(48)
    sc.cycles_curves.shape = 'THICK'
    hair = add_hair("Hair", ms.emission("HairGlow", (1.0, 0.6, 0.3), 1.0), strands=5, keys=5, radius=0.1,
                    length=1.6, sag=0.1, spacing=0.3)
    hair.rotation_euler = (math.pi / 2, 0.0, 0.0)
    hair.location = (-0.8, 0.0, -0.3)
    n = len(hair.data.points)
    velocity = np.zeros((n, 3), np.float32)
    velocity[:, 1] = np.linspace(0.0, 24.0, n)  # object y (world z), up to a unit a frame at 24 fps
    hair.data.attributes.new("velocity", 'FLOAT_VECTOR', 'POINT').data.foreach_set("vector", velocity.ravel())
    sc.frame_set(1)
    sc.view_layers[0].use_pass_vector = True
    sc.render.use_motion_blur = False
    sc.render.film_transparent = True
    cycles, pathlight = render_both(sc, tmp_path)
    vc, vp, full, hair_px, _cloud = vectors_and_masks(cycles, pathlight, cloud_pixels=0)
    assert np.median(np.abs(vc[hair_px][:, 1])) > 2.0
    assert_vectors_agree(vc, vp, full, "curve vectors from velocity")
