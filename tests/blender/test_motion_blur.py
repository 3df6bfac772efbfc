"""Motion blur against Cycles in the same bpy (issue 23): Render Properties > Motion Blur with its
shutter, position, curve and rolling shutter; a spinning and moving object, a moving camera. Emission-only
scenes: each pixel is how long a surface covers it over the shutter, so the two engines agree
within sampling noise of the blur alone."""
import functools
import math

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, Warnings, core_available, load_addon, node_material, render_to_array
import material_scenes as ms

load_addon()
assert_agree = functools.partial(ms.assert_agree, floor=0.05)
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

SIZE = 48
SAMPLES = 1024  # emission only: about a second per engine at 48x48


def emissive(name, color):
    return node_material(name, "ShaderNodeEmission", Color=(*color, 1.0), Strength=1.0)


def linear_keys(obj, path, values):
    """Keyframes {frame: value} of obj.<path>, linearly interpolated (and extrapolated)."""
    prefs = bpy.context.preferences.edit
    old = prefs.keyframe_new_interpolation_type
    prefs.keyframe_new_interpolation_type = 'LINEAR'
    try:
        for frame, value in values.items():
            setattr(obj, path, value)
            obj.keyframe_insert(path, frame=frame)
    finally:
        prefs.keyframe_new_interpolation_type = old


def base_scene():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    ms.set_world((0.0, 0.0, 0.0))
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    return scene


def cube(name, color, **transform):
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.materials.append(emissive(name, color))
    for k, v in transform.items():
        setattr(obj, k, v)
    return obj


def spinning_scene(shutter=0.5, position='CENTER'):
    """A long emissive bar spinning about z (240 degrees a frame) and drifting along x, seen
    from above, over a still square."""
    scene = base_scene()
    scene.render.motion_blur_shutter = shutter
    scene.render.motion_blur_position = position
    bar = cube("Bar", (1.0, 0.8, 0.4), scale=(2.2, 0.35, 0.1))
    linear_keys(bar, "rotation_euler", {0: (0.0, 0.0, math.radians(-240.0)), 2: (0.0, 0.0, math.radians(240.0))})
    linear_keys(bar, "location", {0: (-0.4, 0.0, 0.3), 2: (0.4, 0.2, 0.3)})
    cube("Still", (0.2, 0.4, 1.0), scale=(1.0, 1.0, 0.1), location=(0.0, 0.0, -0.5))
    ms.add_camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), lens=40.0)
    scene.frame_set(1)
    return scene


def moving_camera_scene():
    """Still emissive cubes; the camera moves sideways and turns a little over the shutter."""
    scene = base_scene()
    colors = [(1.0, 0.3, 0.2), (0.3, 1.0, 0.3), (0.3, 0.4, 1.0), (1.0, 1.0, 0.3)]
    for i, (x, z) in enumerate([(-1.2, -0.6), (0.0, 0.7), (1.3, -0.2), (0.4, -1.2)]):
        cube(f"C{i}", colors[i], location=(x, 1.0 * i, z), scale=(1.0, 1.0, 1.0))
    cam = ms.add_camera((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), lens=30.0)
    rot = tuple(cam.rotation_euler)
    linear_keys(cam, "location", {0: (-3.2, -6.0, 0.0), 2: (3.2, -6.0, 0.8)})
    linear_keys(cam, "rotation_euler", {0: (rot[0] - 0.2, rot[1], rot[2] - 0.5), 2: (rot[0] + 0.2, rot[1], rot[2] + 0.5)})
    scene.frame_set(1)
    return scene


def render_both(scene, samples=SAMPLES):
    ours = render_to_array(scene, "PATHLIGHT", samples=samples, **BOX_FILTER)
    cycles = render_to_array(scene, "CYCLES", samples=samples, max_bounces=0, **BOX_FILTER)
    return ours, cycles


def test_spinning_object_matches_cycles():
    scene = spinning_scene()
    ours, cycles = render_both(scene)
    assert_agree(ours, cycles, "spinning bar")
    # Motion blur is really on: the still frame differs.
    scene.render.use_motion_blur = False
    still = render_to_array(scene, "PATHLIGHT", samples=16, **BOX_FILTER)
    assert ms.compare(still, cycles, floor=0.05)[1] > 0.2
    assert scene.frame_current == 1 and abs(scene.frame_subframe) < 1e-6  # the frame is restored


def test_lit_spinning_object_and_its_shadow_match_cycles():
    """A diffuse bar spinning over a floor under an area light: its blurred shadow needs the
    shadow rays (and the bounces) to see the bar where the camera ray's time has it."""
    scene = ms.studio(size=SIZE, camera=((0.0, -4.0, 3.0), (0.0, 0.0, 0.3)))
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    bar = bpy.context.active_object
    bar.data.materials.append(ms.diffuse("Bar", (0.8, 0.8, 0.8)))
    bar.scale = (1.6, 0.3, 0.3)
    linear_keys(bar, "rotation_euler", {0: (0.0, 0.0, math.radians(-240.0)), 2: (0.0, 0.0, math.radians(240.0))})
    linear_keys(bar, "location", {0: (-0.4, 0.0, 0.6), 2: (0.4, 0.2, 0.6)})
    scene.frame_set(1)
    ours = render_to_array(scene, "PATHLIGHT", samples=512, max_bounces=3, **BOX_FILTER)
    cycles = render_to_array(scene, "CYCLES", samples=512, max_bounces=3, **BOX_FILTER)
    assert_agree(ours, cycles, "lit spinning bar")


def test_texture_stays_on_a_moving_object():
    """A checker (Object coordinates) on a sliding, slightly turning slab moves with it: texture
    coordinates come from the object's transform at the ray's time (with the frame's, the still
    checker would show through the moving slab)."""
    scene = base_scene()
    mat = emissive("Checker", (1.0, 1.0, 1.0))
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    checker = nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = 3.0
    checker.inputs["Color1"].default_value = (1.0, 0.9, 0.2, 1.0)
    checker.inputs["Color2"].default_value = (0.1, 0.2, 1.0, 1.0)
    coords = nodes.new("ShaderNodeTexCoord")
    links.new(coords.outputs["Object"], checker.inputs["Vector"])
    links.new(checker.outputs["Color"], nodes["Emission"].inputs["Color"])
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    slab = bpy.context.active_object
    slab.data.materials.append(mat)
    slab.scale = (1.3, 1.3, 0.1)
    linear_keys(slab, "rotation_euler", {0: (0.0, 0.0, math.radians(-30.0)), 2: (0.0, 0.0, math.radians(30.0))})
    linear_keys(slab, "location", {0: (-1.6, 0.0, 0.3), 2: (1.6, 0.2, 0.3)})
    ms.add_camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), lens=40.0)
    scene.frame_set(1)
    ours, cycles = render_both(scene, samples=512)
    assert_agree(ours, cycles, "textured sliding slab")


def test_shutter_position_and_curve_match_cycles():
    """Shutter at the frame's start, a longer shutter and a ramp-shaped shutter curve."""
    scene = spinning_scene(shutter=0.8, position='START')
    curve = scene.render.motion_blur_shutter_curve
    pts = curve.curves[0].points
    pts[0].location = (0.0, 0.0)
    pts[-1].location = (1.0, 1.0)
    curve.update()
    ours, cycles = render_both(scene, samples=SAMPLES)
    assert_agree(ours, cycles, "start, 0.8, ramp")


@pytest.mark.parametrize("duration", [0.0, 0.3])
def test_rolling_shutter_matches_cycles(duration):
    """Render ▸ Motion Blur ▸ Rolling Shutter 'TOP' (Cycles' camera_sample: rows read from the
    top down, each row's shutter shortened to the duration's share): the spinning bar leans."""
    rolling = dict(rolling_shutter_type='TOP', rolling_shutter_duration=duration)
    ours = render_to_array(spinning_scene(), "PATHLIGHT", samples=SAMPLES, **rolling, **BOX_FILTER)
    cycles = render_to_array(spinning_scene(), "CYCLES", samples=SAMPLES, max_bounces=0, **rolling, **BOX_FILTER)
    assert_agree(ours, cycles, f"rolling shutter, duration {duration}")
    # (it changed the picture: the plain shutter's is far from it)
    plain = render_to_array(spinning_scene(), "CYCLES", samples=SAMPLES, max_bounces=0, **BOX_FILTER)
    assert ms.compare(plain, cycles, floor=0.05)[1] > 0.2


def test_moving_camera_matches_cycles():
    scene = moving_camera_scene()
    ours, cycles = render_both(scene)
    assert_agree(ours, cycles, "moving camera")
    scene.render.use_motion_blur = False
    still = render_to_array(scene, "PATHLIGHT", samples=16, **BOX_FILTER)
    assert ms.compare(still, cycles, floor=0.05)[1] > 0.2


def test_object_without_motion_blur_and_singular_motion():
    """object.cycles.use_motion_blur off renders that object still (as Cycles); a motion step
    with zero scale (singular) warns once and leaves the object still, never fails the render."""
    scene = spinning_scene()
    bar = scene.objects["Bar"]
    bar.cycles.use_motion_blur = False
    ours, cycles = render_both(scene, samples=64)
    ratio, worst, _ = ms.compare(ours, cycles, floor=0.05)
    assert abs(ratio - 1.0) < 0.02 and worst < 0.06, (ratio, worst)

    from addon.export import export_scene, motion
    bar.cycles.use_motion_blur = True
    linear_keys(bar, "scale", {1: (2.2, 0.35, 0.1), 1.25: (0.0, 0.0, 0.0)})  # flat at the shutter's end
    scene.frame_set(1)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    warn = Warnings()
    data = export_scene(depsgraph, warn)

    class Engine:  # what add_motion asks of the RenderEngine
        def frame_set(self, frame, subframe):
            scene.frame_set(frame, subframe=subframe)

    assert motion.add_motion(Engine(), depsgraph, data, warn) == 0
    assert all(m is None for d in data.meshes for m in d.motions)
    assert sum("Bar" in w and "motion" in w for w in warn) == 1, warn
    assert scene.frame_current == 1 and abs(scene.frame_subframe) < 1e-6


def deforming_scene():
    """An emissive slab whose shape key stretches and shears it over the shutter (deformation
    blur: the object itself does not move), seen from above."""
    scene = base_scene()
    slab = cube("Slab", (0.9, 0.6, 1.0), scale=(1.0, 1.0, 0.1))
    slab.shape_key_add(name="Basis")
    key = slab.shape_key_add(name="Stretch")
    co = np.array([v.co[:] for v in slab.data.vertices])
    moved = co.copy()
    right = co[:, 0] > 0
    moved[right, 0] += 1.6
    moved[right, 1] += 0.9
    for point, p in zip(key.data, moved):
        point.co = p
    linear_keys(key, "value", {0.75: 0.0, 1.25: 1.0})
    ms.add_camera((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), lens=35.0)
    scene.frame_set(1)
    return scene


def test_deforming_mesh_matches_cycles():
    scene = deforming_scene()
    ours, cycles = render_both(scene)
    assert_agree(ours, cycles, "deforming slab")
    scene.objects["Slab"].cycles.use_deform_motion = False
    still = render_to_array(scene, "PATHLIGHT", samples=16, **BOX_FILTER)
    assert ms.compare(still, cycles, floor=0.05)[1] > 0.2


def test_topology_change_warns_and_renders_still(monkeypatch):
    """A mesh whose vertex count differs at a sub-frame gets no deformation blur and one warning."""
    scene = deforming_scene()
    from addon.export import export_scene, motion
    depsgraph = bpy.context.evaluated_depsgraph_get()
    warn = Warnings()
    data = export_scene(depsgraph, warn)
    real = motion._positions
    calls = []

    def fewer(obj_eval):  # a sub-frame that loses a vertex
        p = real(obj_eval)
        calls.append(1)
        return p[:-1] if len(calls) == 2 else p

    monkeypatch.setattr(motion, "_positions", fewer)

    class Engine:
        def frame_set(self, frame, subframe):
            scene.frame_set(frame, subframe=subframe)

    motion.add_motion(Engine(), depsgraph, data, warn)
    assert len(calls) == 3
    assert all(m.motion_positions is None for m in data.meshes)
    assert sum("topology" in w for w in warn) == 1, warn


def test_failing_motion_export_still_renders(monkeypatch):
    """A bug in the motion export costs the blur, not the render."""
    import addon.session as session

    def broken(*args):
        raise RuntimeError("boom")

    monkeypatch.setattr(session, "add_motion", broken)
    scene = spinning_scene()
    still = render_to_array(scene, "PATHLIGHT", samples=4, **BOX_FILTER)
    assert still[..., :3].mean() > 0.01  # the bar and the square (black without a render)


def test_shared_meshes_and_collection_instances_blur_each_on_their_own():
    """Two objects sharing one mesh, moving apart, and a moving empty that instances a
    collection: each instance is matched across sub-frames and blurred by its own motion."""
    scene = base_scene()
    a = cube("A", (1.0, 0.5, 0.2), scale=(0.8, 0.25, 0.1))
    b = bpy.data.objects.new("B", a.data)  # a linked duplicate: the same mesh
    scene.collection.objects.link(b)
    b.scale = (0.8, 0.25, 0.1)
    linear_keys(a, "location", {0: (-1.5, 0.9, 0.0), 2: (0.5, 0.9, 0.0)})
    linear_keys(b, "rotation_euler", {0: (0.0, 0.0, -2.0), 2: (0.0, 0.0, 2.0)})
    b.location = (0.0, -0.2, 0.0)
    source = bpy.data.collections.new("Source")
    bpy.ops.mesh.primitive_cube_add(size=0.5)
    inner = bpy.context.active_object
    inner.data.materials.append(emissive("Inner", (0.2, 0.5, 1.0)))
    for coll in list(inner.users_collection):
        coll.objects.unlink(inner)
    source.objects.link(inner)
    empty = bpy.data.objects.new("Instancer", None)
    empty.instance_type = 'COLLECTION'
    empty.instance_collection = source
    scene.collection.objects.link(empty)
    linear_keys(empty, "location", {0: (0.8, -2.0, 0.0), 2: (0.8, 0.0, 0.0)})
    ms.add_camera((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), lens=35.0)
    scene.frame_set(1)
    ours, cycles = render_both(scene, samples=512)
    assert_agree(ours, cycles, "shared mesh and collection instance")
    scene.render.use_motion_blur = False
    still = render_to_array(scene, "PATHLIGHT", samples=16, **BOX_FILTER)
    assert ms.compare(still, cycles, floor=0.05)[1] > 0.2


def test_lit_deforming_smooth_mesh_matches_cycles():
    """A smooth ball whose shape key shears and stretches it over the shutter, lit by an area
    light: its shading normals must turn with the deformation (the frame's normals: 8 % off)."""
    scene = ms.studio(size=SIZE, camera=((0.0, -4.0, 3.0), (0.0, 0.0, 0.5)))
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    ball = ms.add_sphere("Ball", 0.7, ms.diffuse("Ball", (0.8, 0.8, 0.8)), segments=24, rings=12,
                         location=(0.0, 0.0, 0.8))
    ball.shape_key_add(name="Basis")
    key = ball.shape_key_add(name="Bend")
    co = np.array([v.co[:] for v in ball.data.vertices])
    moved = co.copy()
    moved[:, 0] += 0.9 * co[:, 2]  # the top leans over
    moved[:, 2] *= 1.4
    for point, p in zip(key.data, moved):
        point.co = p
    linear_keys(key, "value", {0.75: 0.0, 1.25: 1.0})
    scene.frame_set(1)
    ours = render_to_array(scene, "PATHLIGHT", samples=512, max_bounces=3, **BOX_FILTER)
    cycles = render_to_array(scene, "CYCLES", samples=512, max_bounces=3, **BOX_FILTER)
    assert_agree(ours, cycles, "lit deforming ball")


def test_rolling_shutter_settings_have_cycles_names_and_panel():
    """scene.pathlight's rolling shutter under Cycles' names, defaults and choices; the Motion
    Blur panel draws Cycles' layout; the camera gets the fields only where it is on."""
    from addon import ui
    from addon.export.motion import rolling_shutter
    from blender_util import RecordingLayout
    scene = base_scene()
    ours, cycles = scene.pathlight, scene.cycles
    for name in ("rolling_shutter_type", "rolling_shutter_duration"):
        assert getattr(ours, name) == pytest.approx(getattr(cycles, name)), name
    assert ours.bl_rna.properties["rolling_shutter_type"].enum_items.keys() == \
        cycles.bl_rna.properties["rolling_shutter_type"].enum_items.keys()
    assert rolling_shutter(scene) == {}
    ours.rolling_shutter_type, ours.rolling_shutter_duration = 'TOP', 0.25
    assert rolling_shutter(scene) == {"rolling_shutter": True, "rolling_shutter_duration": pytest.approx(0.25)}
    panel = ui.PATHLIGHT_RENDER_PT_motion_blur
    layout = RecordingLayout()
    panel.draw_header(type("Panel", (), {"layout": layout})(), type("Ctx", (), {"scene": scene}))
    panel.draw(type("Panel", (), {"layout": layout})(), type("Ctx", (), {"scene": scene}))
    assert layout.props == ["use_motion_blur", "motion_blur_position", "motion_blur_shutter",
                            "rolling_shutter_type", "rolling_shutter_duration"]
