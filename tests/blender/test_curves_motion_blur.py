"""Motion blur of hair and point clouds against Cycles in the same bpy (issue 23): strands moving
with their object (transform blur), strands deformed by an animated Geometry Nodes offset and by
a 'velocity' attribute (deformation blur: Cycles' motion keys), and a point cloud with a
'velocity' attribute. Emission only, seen from above on black, box filter: each pixel is how
long a surface covers it over the shutter; the still frame differs from every blurred render."""

import functools
import math

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, Warnings, core_available, load_addon, render_to_array
import material_scenes as ms
from test_hair import add_hair

load_addon()
assert_agree = functools.partial(ms.assert_agree, floor=0.05)

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def _dark_scene(size=48):
    scene = ms.studio(size=size, world=(0.0, 0.0, 0.0), light_strength=0.0,
                      camera=((0.0, 0.0, 3.2), (0.0, 0.0, 0.0)), lens=40.0)
    for name in ("Floor", "Light"):
        bpy.data.objects[name].hide_render = True
    scene.cycles_curves.shape = 'THICK'
    scene.render.motion_blur_shutter = 1.0
    return scene


def _linear_keys():
    prefs = bpy.context.preferences.edit
    old = prefs.keyframe_new_interpolation_type
    prefs.keyframe_new_interpolation_type = 'LINEAR'
    return prefs, old


def _patch(scene, name="Hair"):
    """A patch of 7 emissive strands across the view (z = 0.5 and below)."""
    return add_hair(name, ms.emission("Glow", (1.0, 0.6, 0.3), 1.0), strands=7, keys=5, radius=0.04,
                    length=1.6, sag=0.1, spacing=0.2)


def _compare(build, what, samples=2048):
    ours = render_to_array(build(True), "PATHLIGHT", samples=samples, **BOX_FILTER)
    cycles = render_to_array(build(True), "CYCLES", samples=samples, max_bounces=0, **BOX_FILTER)
    still = render_to_array(build(False), "PATHLIGHT", samples=16, **BOX_FILTER)
    assert_agree(ours, cycles, what)
    assert np.abs(still[..., :3] - ours[..., :3]).max() > 0.2, f"{what}: not blurred"
    return ours, cycles


@pytest.mark.parametrize("shape", ['THICK', 'RIBBONS'])
def test_moving_strands_blur_as_cycles(shape):
    """Transform blur: the patch turning 60 degrees and drifting 0.5 over the shutter (keys
    2 frames apart, a shutter of 1 frame), as round curves and as ribbons."""
    def build(blur):
        scene = _dark_scene()
        scene.cycles_curves.shape = shape
        obj = _patch(scene)
        prefs, old = _linear_keys()
        try:
            for frame, angle, x in ((0, -60.0, -0.5), (2, 60.0, 0.5)):
                obj.rotation_euler = (0.0, 0.0, math.radians(angle))
                obj.location = (x, 0.0, 0.0)
                obj.keyframe_insert("rotation_euler", frame=frame)
                obj.keyframe_insert("location", frame=frame)
        finally:
            prefs.keyframe_new_interpolation_type = old
        scene.frame_set(1)
        scene.render.use_motion_blur = blur
        return scene
    _compare(build, f"moving strands ({shape.lower()})")


def _offset_modifier(obj, name="Bend"):
    """Geometry Nodes: each point moved along y by Shift x its x (a shear that bends the patch),
    Shift keyframed from -1 to 1 over frames 0..2 (an animated deformation)."""
    tree = bpy.data.node_groups.new(name, 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    shift = tree.interface.new_socket("Shift", in_out='INPUT', socket_type='NodeSocketFloat')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    n, links = tree.nodes, tree.links
    gi, go = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    pos = n.new("GeometryNodeInputPosition")
    sep = n.new("ShaderNodeSeparateXYZ")
    mul = n.new("ShaderNodeMath")
    mul.operation = 'MULTIPLY'
    comb = n.new("ShaderNodeCombineXYZ")
    setp = n.new("GeometryNodeSetPosition")
    links.new(pos.outputs[0], sep.inputs[0])
    links.new(sep.outputs["X"], mul.inputs[0])
    links.new(gi.outputs["Shift"], mul.inputs[1])
    links.new(mul.outputs[0], comb.inputs["Y"])
    links.new(gi.outputs["Geometry"], setp.inputs["Geometry"])
    links.new(comb.outputs[0], setp.inputs["Offset"])
    links.new(setp.outputs[0], go.inputs["Geometry"])
    mod = obj.modifiers.new(name, 'NODES')
    mod.node_group = tree
    prefs, old = _linear_keys()
    try:
        for frame, value in ((0, -1.0), (2, 1.0)):
            mod[shift.identifier] = value
            obj.keyframe_insert(f'modifiers["{name}"]["{shift.identifier}"]', frame=frame)
    finally:
        prefs.keyframe_new_interpolation_type = old
    return mod


def test_deforming_strands_blur_as_cycles():
    """Deformation blur: the patch sheared by an animated Geometry Nodes offset (the strands'
    keys read at every motion step)."""
    def build(blur):
        scene = _dark_scene()
        obj = _patch(scene)
        _offset_modifier(obj)
        scene.frame_set(1)
        scene.render.use_motion_blur = blur
        return scene
    _compare(build, "deforming strands")


def test_strand_velocity_blurs_as_cycles():
    """Deformation blur from a 'velocity' attribute on a still Curves object: each point moves
    with its own velocity (units per second) over the shutter (1 frame at 24 fps)."""
    def build(blur):
        scene = _dark_scene()
        scene.render.fps, scene.render.fps_base = 24, 1.0
        obj = _patch(scene)
        pts = np.empty(len(obj.data.points) * 3, np.float32)
        obj.data.attributes["position"].data.foreach_get("vector", pts)
        pts = pts.reshape(-1, 3)
        vel = np.zeros_like(pts)
        vel[:, 1] = 12.0 * pts[:, 0]  # +-0.4 units over the shutter at the ends
        vel[:, 0] = 6.0
        obj.data.attributes.new("velocity", 'FLOAT_VECTOR', 'POINT').data.foreach_set("vector", vel.ravel())
        scene.render.use_motion_blur = blur
        return scene
    _compare(build, "strand velocity")


def test_point_velocity_blurs_as_cycles():
    """A point cloud (Mesh to Points) whose points carry a 'velocity' attribute."""
    from test_point_clouds import add_cloud

    def build(blur):
        scene = _dark_scene()
        scene.render.fps, scene.render.fps_base = 24, 1.0
        obj = add_cloud("Cloud", ms.emission("Glow", (0.3, 0.8, 1.0), 1.0), n=60, spread=1.4)
        rng = np.random.default_rng(7)
        vel = rng.normal(0.0, 8.0, size=(60, 3)).astype(np.float32)
        obj.data.attributes.new("velocity", 'FLOAT_VECTOR', 'POINT').data.foreach_set("vector", vel.ravel())
        scene.render.use_motion_blur = blur
        return scene
    _compare(build, "point velocity")


def test_curves_motion_export_and_bad_motion():
    """The export: a moving patch gets its matrices at the steps, a deforming one its keys at
    the steps (3, the middle one the frame's); a velocity attribute with NaN warns once and the
    strands render still; strands whose point count changes over the shutter warn too."""
    from addon.export import export_scene
    from addon.export.motion import add_motion

    class Engine:
        def frame_set(self, frame, subframe):
            bpy.context.scene.frame_set(frame, subframe=subframe)

    scene = _dark_scene(16)
    obj = _patch(scene)
    _offset_modifier(obj)
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    warn = Warnings()
    dg = bpy.context.evaluated_depsgraph_get()
    data = export_scene(dg, warn)
    assert add_motion(Engine(), dg, data, warn) >= 1 and not warn
    (c,) = data.curves
    assert c.motion_points.shape == (3, len(c.points), 3)
    np.testing.assert_allclose(c.motion_points[1], c.points, atol=1e-6)
    assert np.abs(c.motion_points[0] - c.motion_points[2]).max() > 0.5

    scene = _dark_scene(16)
    obj = _patch(scene)
    vel = np.zeros(len(obj.data.points) * 3, np.float32)
    vel[4] = np.nan
    obj.data.attributes.new("velocity", 'FLOAT_VECTOR', 'POINT').data.foreach_set("vector", vel)
    scene.render.use_motion_blur = True
    warn = Warnings()
    dg = bpy.context.evaluated_depsgraph_get()
    data = export_scene(dg, warn)
    add_motion(Engine(), dg, data, warn)
    assert len(warn) == 1 and "velocity" in warn[0] and data.curves[0].motion_points is None
    img = render_to_array(scene, "PATHLIGHT", samples=2)
    assert np.isfinite(img).all()

    # A Geometry Nodes modifier that resamples the strands to more points after frame 1.
    scene = _dark_scene(16)
    obj = _patch(scene)
    tree = bpy.data.node_groups.new("Grow", 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    n = tree.nodes
    gi, go = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    resample = n.new("GeometryNodeResampleCurve")
    frame = n.new("GeometryNodeInputSceneTime")
    add = n.new("ShaderNodeMath")  # 4, 6, 8 points at the steps
    add.operation = 'MULTIPLY_ADD'
    add.inputs[1].default_value = 4.0
    add.inputs[2].default_value = 2.0
    tree.links.new(frame.outputs["Frame"], add.inputs[0])
    tree.links.new(add.outputs[0], resample.inputs["Count"])
    tree.links.new(gi.outputs[0], resample.inputs["Curve"])
    tree.links.new(resample.outputs[0], go.inputs[0])
    obj.modifiers.new("Grow", 'NODES').node_group = tree
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    warn = Warnings()
    dg = bpy.context.evaluated_depsgraph_get()
    data = export_scene(dg, warn)
    add_motion(Engine(), dg, data, warn)
    assert len(warn) == 1 and "number of points" in warn[0] and data.curves[0].motion_points is None
    img = render_to_array(scene, "PATHLIGHT", samples=2)
    assert np.isfinite(img).all()


def test_particle_hair_moves_with_its_emitter_as_cycles():
    """Transform blur of particle hair: a hidden emitter standing upright (its hair horizontal,
    seen from above) turning 25 degrees and drifting 0.15 over the shutter; its keys, the same
    in the emitter's space at every step, give no deformation."""
    from test_particle_hair import add_hair_patch

    def build(blur):
        scene = _dark_scene()
        emitter = add_hair_patch(ms.emission("Glow", (1.0, 0.6, 0.3), 1.0), patch_size=0.8, count=60,
                                 length=0.5, step=2, root=2.0, tip=1.0, scale=0.02)
        emitter.show_instancer_for_render = False
        prefs, old = _linear_keys()
        try:
            for frame, angle, x in ((0, -25.0, -0.15), (2, 25.0, 0.15)):
                emitter.rotation_euler = (math.radians(90.0), 0.0, math.radians(angle))
                emitter.location = (x, 0.3, 0.0)
                emitter.keyframe_insert("rotation_euler", frame=frame)
                emitter.keyframe_insert("location", frame=frame)
        finally:
            prefs.keyframe_new_interpolation_type = old
        scene.frame_set(1)
        scene.render.use_motion_blur = blur
        return scene
    from addon.export import export_scene
    from addon.export.motion import add_motion

    class Engine:
        def frame_set(self, frame, subframe):
            bpy.context.scene.frame_set(frame, subframe=subframe)

    build(True)
    warn = Warnings()
    dg = bpy.context.evaluated_depsgraph_get()
    data = export_scene(dg, warn)
    add_motion(Engine(), dg, data, warn)
    (c,) = data.curves
    assert c.motions[0] is not None and c.motions[0].shape == (3, 4, 4) and c.motion_points is None and not warn
    _compare(build, "moving particle hair")


def test_hair_systems_of_one_emitter_each_get_their_motion():
    """Two hair systems with their own materials on one moving emitter (two curve sets with
    the emitter's key): both get its steps, and reading their keys at the steps warns of
    nothing."""
    from addon.export import export_scene
    from addon.export.motion import add_motion
    from test_particle_hair import add_hair_patch

    class Engine:
        def frame_set(self, frame, subframe):
            bpy.context.scene.frame_set(frame, subframe=subframe)

    scene = _dark_scene(16)
    emitter = add_hair_patch(ms.emission("A", (1.0, 0.6, 0.3), 1.0), count=20)
    emitter.data.materials.append(ms.emission("B", (0.3, 0.6, 1.0), 1.0))  # slot 3
    mod = emitter.modifiers.new("Hair2", 'PARTICLE_SYSTEM')
    second = mod.particle_system.settings
    second.type, second.count, second.hair_length, second.material = 'HAIR', 20, 0.3, 3
    prefs, old = _linear_keys()
    try:
        for frame, x in ((0, -0.2), (2, 0.2)):
            emitter.location = (x, 0.0, 0.0)
            emitter.keyframe_insert("location", frame=frame)
    finally:
        prefs.keyframe_new_interpolation_type = old
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    warn = Warnings()
    dg = bpy.context.evaluated_depsgraph_get()
    data = export_scene(dg, warn)
    add_motion(Engine(), dg, data, warn)
    assert len(data.curves) == 2 and not warn, warn
    for c in data.curves:
        assert c.motions[0] is not None and c.motion_points is None
