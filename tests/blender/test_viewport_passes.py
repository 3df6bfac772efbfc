"""The viewport's Render Pass selector (View3DShading.pathlight, addon/viewport.py): the pass the
viewport draws equals the final render's pass of the same scene, seed and samples (as Cycles'
viewport shows it: 1 and 3 channels with alpha 1, Sample Count over the samples); Combined alone
asks the core for no pass; a change of pass restarts; an unknown light group or AOV shows
Combined with one message; the shading popover's panel draws.

The viewport and the final render differ in their BVH (the viewport's is two-level, without
spatial splits) and in Automatic's noise pattern (Blue-Noise (First) in the viewport): the scene
sets Blue-Noise itself and has no spatial splits; the rest is the same render, bit for bit."""

import math
import types

import bpy
import numpy as np
import pytest

from blender_util import RecordingLayout, core_available, core_has, empty_scene_with_camera, load_addon, \
    render_multilayer_file
from test_light_passes import plane, sphere
from light_scenes import world_color

addon = load_addon()

from addon.core import get_core  # noqa: E402
from addon.viewport import VIEW_PASSES, ViewportSession, display_pass  # noqa: E402
from addon import viewport_draw  # noqa: E402

pytestmark = [pytest.mark.skipif(not core_available(), reason="pathlight_core is not built"),
              pytest.mark.skipif(not core_has("RenderSettings", "light_groups"), reason="core without light groups")]

SAMPLES = 4
W, H = 40, 30


def _material(name, color):
    """A Principled material (diffuse and glossy) whose shader AOV "tint" is its colour and
    "rough" its roughness."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.4
    for aov_name, socket, value in (("tint", "Color", (*color, 1.0)), ("rough", "Value", 0.4)):
        node = nt.nodes.new("ShaderNodeOutputAOV")
        node.aov_name = aov_name
        node.inputs[socket].default_value = value
    return mat


def build_scene():
    sc = empty_scene_with_camera(W)
    sc.render.resolution_y = H
    sc.render.engine = 'PATHLIGHT'
    sc.camera.location = (0.0, -6.0, 0.8)
    sc.camera.rotation_euler = (math.radians(84), 0.0, 0.0)
    plane("Floor", 10, (0, 0, -1), (0, 0, 0), _material("Floor", (0.6, 0.6, 0.6)))
    plane("Wall", 10, (0, 3, 2), (math.pi / 2, 0, 0), _material("Wall", (0.3, 0.5, 0.7)))
    sphere("Ball", (0.3, 0.0, -0.2), 0.8, _material("Ball", (0.8, 0.3, 0.1)))
    key = bpy.data.objects.new("Key", bpy.data.lights.new("Key", 'POINT'))
    key.data.energy, key.data.shadow_soft_size = 400.0, 0.3
    key.location = (-2.0, -3.0, 3.0)
    sc.collection.objects.link(key)
    world_color((0.1, 0.12, 0.2))
    vl = sc.view_layers[0]
    for name in ("key", "sky"):
        vl.lightgroups.add(name=name)
    key.lightgroup = "key"
    sc.world.lightgroup = "sky"
    for name, kind in (("tint", 'COLOR'), ("rough", 'VALUE')):
        aov = vl.aovs.add()
        aov.name, aov.type = name, kind
    vl.use_pass_diffuse_color = vl.use_pass_normal = vl.use_pass_mist = True
    vl.use_pass_ambient_occlusion = vl.use_pass_glossy_direct = vl.use_pass_uv = True
    vl.pathlight.use_pass_sample_count = True
    sc.world.mist_settings.start, sc.world.mist_settings.depth = 2.0, 8.0
    p = sc.pathlight
    p.samples = p.preview_samples = SAMPLES
    p.use_adaptive_sampling = False
    p.pixel_pattern = 'BLUE_NOISE'  # (Automatic is Blue-Noise (First) in the viewport)
    p.use_spatial_splits = False  # (the viewport's BVH never has them)
    p.seed = 3
    bpy.context.view_layer.update()
    return sc


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The final render's passes of build_scene(), {"<pass>.<channel>": (H, W)} row 0 = bottom
    (the viewport film's order). The tests that compare with it render the same scene, not a
    rebuilt one: Blender's smooth normals of the sphere (mesh.corner_normals) differ in their last
    bits from build to build (three builds, three hashes), so renders of two builds differ in
    about 1 value in 100 (0.8 % and 0.03 % of the Normal pass's); the tests that change the
    scene build it anew.
    Its core scene is dynamic, as the viewport's (each object over its own BVH, rays moved into
    the object's space): a final render's one-level BVH of world-space triangles puts hit points
    within float rounding of those, which the data passes show (1-ulp differences)."""
    from addon import session
    real = session.set_build_options
    session.set_build_options = lambda scene, **kw: real(scene, dynamic=True, **kw)
    try:
        channels = render_multilayer_file(build_scene(), tmp_path_factory.mktemp("vpass") / "final.exr")
    finally:
        session.set_build_options = real
    return {k: v[::-1] for k, v in channels.items()}


def render_pass(channels, name, ids):
    return np.stack([channels[f"{name}.{c}"] for c in ids], -1)


def viewport(render_pass_id="COMBINED", name="", messages=None):
    """A finished ViewportSession of the current scene, through the scene camera at the render's
    size, showing `render_pass_id` (a light group's or AOV's `name`)."""
    vs = ViewportSession(get_core(), (messages if messages is not None else []).append)
    vs.set_pass(render_pass_id, name)
    vs.set_view(None, W, H)  # (too small for the low-resolution pass)
    vs.sync(bpy.context.evaluated_depsgraph_get())
    finish(vs)
    return vs


def finish(vs):
    for _ in range(4000):  # bounded, not a timing assertion
        if not vs.poll():
            return
        (vs.full or vs.low).wait(0.05)
    raise AssertionError("the viewport never finished")


def shown(vs):
    film, samples = vs.display()
    assert samples == SAMPLES and film.shape == (H, W, 4)
    return film


# (Render Pass id, name, the final render's pass, its channels, the viewport's scale of it)
CASES = [
    ('DIFFUSE_COLOR', "", "DiffCol", "RGB", 1.0),
    ('NORMAL', "", "Normal", "XYZ", 1.0),
    ('MIST', "", "Mist", "Z", 1.0),
    ('UV', "", "UV", "UVA", 1.0),
    ('AO', "", "AO", "RGB", 1.0),
    ('GLOSSY_DIRECT', "", "GlossDir", "RGB", 1.0),
    ('SAMPLE_COUNT', "", "Sample Count", "X", 1.0 / SAMPLES),
    ('LIGHT_GROUP', "key", "Combined_key", "RGB", 1.0),
    ('LIGHT_GROUP', "sky", "Combined_sky", "RGB", 1.0),
    ('AOV', "tint", "tint", "RGBA", 1.0),
    ('AOV', "rough", "rough", "X", 1.0),
]


@pytest.mark.parametrize("pass_id, name, final, ids, scale", CASES, ids=[c[2] for c in CASES])
def test_viewport_pass_is_the_final_renders_pass(rendered, pass_id, name, final, ids, scale):
    channels = rendered
    messages = []
    vs = viewport(pass_id, name, messages)
    assert not messages
    assert vs.shown is not None
    film = shown(vs)
    ref = render_pass(channels, final, ids)
    if pass_id != 'SAMPLE_COUNT':
        assert np.abs(ref).max() > 0  # the pass shows something
    expect = display_pass(ref, scale)
    np.testing.assert_array_equal(film, expect)
    if len(ids) != 4:  # 1 and 3 channels: opaque, 1 channel as grey
        assert (film[..., 3] == 1).all()
        if len(ids) == 1:
            assert (film[..., 0] == film[..., 1]).all() and (film[..., 1] == film[..., 2]).all()
    vs.free()


def test_sample_count_is_the_share_of_samples(rendered):
    """As Cycles' viewport: every pixel took all samples (no adaptive sampling) -> 1."""
    vs = viewport('SAMPLE_COUNT')
    np.testing.assert_array_equal(shown(vs)[..., :3], 1.0)
    vs.free()


def test_combined_is_the_final_render_and_asks_for_no_pass(rendered):
    channels = rendered
    vs = viewport()
    assert vs.shown is None
    film = shown(vs)
    np.testing.assert_array_equal(film, render_pass(channels, "Combined", "RGBA"))
    # Combined alone: the core session asks for no pass, AOV or light group buffer.
    started = []
    real = vs.pc

    class Spy:  # the settings each new core Session gets
        def __getattr__(self, name):
            return getattr(real, name)

        def Session(self, scene, settings, **kw):
            started.append(settings)
            return real.Session(scene, settings, **kw)
    vs.pc = Spy()
    vs.restart()
    finish(vs)
    assert len(started) == 1
    assert list(started[0].passes) == [] and list(started[0].shader_aovs) == [] and started[0].light_groups == 0
    np.testing.assert_array_equal(shown(vs), film)
    # Showing a pass leaves Combined (the session's film) bit for bit as it was.
    vs.set_pass('DIFFUSE_COLOR')
    finish(vs)
    assert list(started[-1].passes) == ["DiffCol"] and started[-1].light_groups == 0
    np.testing.assert_array_equal(vs.full.film(), film)
    vs.set_pass('LIGHT_GROUP', "key")  # group 0: its buffer only, no pass
    assert list(started[-1].passes) == [] and started[-1].light_groups == 1
    vs.set_pass('LIGHT_GROUP', "sky")  # group 1: groups 0 and 1
    assert list(started[-1].passes) == [] and started[-1].light_groups == 2
    vs.set_pass('AOV', "tint")  # AOV slot 0 only
    assert list(started[-1].shader_aovs) == [4] and started[-1].light_groups == 0
    vs.free()


def test_switching_the_pass_restarts_and_unknown_names_fall_back():
    build_scene()
    messages = []
    vs = viewport(messages=messages)
    restarts = vs.counters["restarts"]
    assert not vs.set_pass('COMBINED')  # no change
    assert vs.set_pass('NORMAL') and vs.counters["restarts"] == restarts + 1
    assert vs.shown == ("pass", "Normal")
    assert not vs.set_pass('NORMAL')
    assert vs.set_pass('LIGHT_GROUP', "key") and vs.shown == ("group", 0)
    assert vs.set_pass('AOV', "rough") and vs.shown == ("aov", 1, 1)
    assert vs.set_pass('COMBINED') and vs.shown is None
    restarts = vs.counters["restarts"]
    # An unknown light group or AOV shows Combined: nothing to restart, one message each.
    assert not vs.set_pass('LIGHT_GROUP', "nope")
    assert vs.shown is None and vs.counters["restarts"] == restarts
    vs.set_pass('COMBINED')
    vs.set_pass('LIGHT_GROUP', "nope")
    assert not vs.set_pass('AOV', "missing")
    assert len(messages) == 2
    assert "light group 'nope'" in messages[0] and "Combined" in messages[0]
    assert "shader AOV 'missing'" in messages[1]
    # UV needs the meshes' UV maps: to it and back re-exports (from the depsgraph at hand).
    exports = vs.counters["exports"]
    dg = bpy.context.evaluated_depsgraph_get()
    assert vs.set_pass('UV', depsgraph=dg) and vs.counters["exports"] == exports + 1
    assert vs.shown == ("pass", "UV") and vs.uv_pass_set is not None
    assert vs.set_pass('NORMAL', depsgraph=dg) and vs.counters["exports"] == exports + 2
    assert vs.uv_pass_set is None
    assert vs.set_pass('MIST', depsgraph=dg) and vs.counters["exports"] == exports + 2
    # From a pass to an unknown group: back to Combined, a restart.
    vs.set_pass('MIST')
    assert vs.set_pass('LIGHT_GROUP', "nope") and vs.shown is None
    finish(vs)
    film, _ = vs.display()
    np.testing.assert_array_equal(film, vs.full.film())
    vs.free()


def test_light_groups_survive_a_light_edit():
    """A light's edit re-reads the lights without a re-export: they keep their light groups, and
    the group's pass is a fresh export's."""
    build_scene()
    vs = viewport('LIGHT_GROUP', "key")
    assert shown(vs)[..., :3].max() > 0
    exports = vs.counters["exports"]
    from test_viewport import Recorder
    with Recorder() as rec:
        rec.take()
        bpy.data.lights["Key"].energy = 800.0
        plan = vs.sync(bpy.context.evaluated_depsgraph_get(), rec.take())
    assert plan.lights and vs.counters["exports"] == exports and vs.counters["light_updates"] == 1
    finish(vs)
    fresh = viewport('LIGHT_GROUP', "key")
    assert shown(fresh)[..., :3].max() > 0
    np.testing.assert_array_equal(shown(vs), shown(fresh))
    vs.free()
    fresh.free()


def test_a_new_light_group_reexports():
    sc = build_scene()
    messages = []
    vs = viewport('LIGHT_GROUP', "fill", messages)
    assert vs.shown is None and len(messages) == 1
    sc.view_layers[0].lightgroups.add(name="fill")
    bpy.data.objects["Key"].lightgroup = "fill"
    exports = vs.counters["exports"]
    # Through a depsgraph update (whatever it lists) or, when none comes, the draw's check.
    plan = vs.sync(bpy.context.evaluated_depsgraph_get(), [])
    assert plan.rebuild_geometry and vs.counters["exports"] == exports + 1 and vs.shown == ("group", 2)
    finish(vs)
    assert shown(vs)[..., :3].max() > 0
    assert not vs.check_settings(bpy.context.evaluated_depsgraph_get())
    vs.set_pass('LIGHT_GROUP', "rim")
    sc.view_layers[0].lightgroups.add(name="rim")
    bpy.data.objects["Key"].lightgroup = "rim"
    assert vs.check_settings(bpy.context.evaluated_depsgraph_get())
    assert vs.counters["exports"] == exports + 2 and vs.shown == ("group", 3)
    finish(vs)
    assert shown(vs)[..., :3].max() > 0
    assert len(messages) == 2  # 'fill' and 'rim' before they existed
    vs.free()


def test_view_draw_reads_the_selector(monkeypatch):
    """view_update / view_draw take the region's View3DShading.pathlight."""
    from test_viewport_draw import FakeEngine, FakeGpu
    calls = []
    FakeGpu(calls).install(monkeypatch)
    sc = build_scene()
    dg = bpy.context.evaluated_depsgraph_get()
    shading = types.SimpleNamespace(pathlight=types.SimpleNamespace(
        render_pass='LIGHT_GROUP', light_group="sky", aov_name=""))
    cam = sc.camera
    context = types.SimpleNamespace(
        region=types.SimpleNamespace(width=W, height=H), space_data=types.SimpleNamespace(shading=shading),
        region_data=types.SimpleNamespace(view_matrix=np.array(cam.matrix_world.inverted()),
                                          window_matrix=np.array(cam.calc_matrix_camera(dg, x=W, y=H)),
                                          is_perspective=True))
    engine = FakeEngine(calls)
    viewport_draw.view_update(engine, context, dg)
    vs = engine._pathlight_viewport
    assert vs.shown == ("group", 1)
    shading.pathlight.render_pass = 'NORMAL'
    restarts = vs.counters["restarts"]
    viewport_draw.view_draw(engine, context, dg)
    assert vs.shown == ("pass", "Normal") and vs.counters["restarts"] == restarts + 1
    assert not engine.reports
    viewport_draw.free(engine)


def _view3d_shading():
    for screen in bpy.data.screens:
        for area in screen.areas:
            if area.type == 'VIEW_3D':
                return area.spaces[0].shading
    return None


def test_panel_draws_the_selector():
    from addon.ui import PATHLIGHT_VIEW3D_PT_shading_render_pass as Panel
    from addon.properties import VIEWPORT_PASS_ITEMS
    sc = build_scene()
    shading = _view3d_shading()
    if shading is None:
        pytest.skip("no 3D view in this file")
    settings = shading.pathlight  # registered on View3DShading, as Cycles' .cycles
    assert settings.render_pass == 'COMBINED'
    # Every selectable entry maps to a core pass (or is Combined, a light group, an AOV).
    ids = {i[0] for i in VIEWPORT_PASS_ITEMS if i[0]}
    assert ids - {'COMBINED', 'LIGHT_GROUP', 'AOV'} == set(VIEW_PASSES)
    assert set(VIEW_PASSES.values()) <= set(get_core().render_passes())
    shading.type = 'RENDERED'
    context = types.SimpleNamespace(engine='PATHLIGHT', space_data=types.SimpleNamespace(shading=shading),
                                    view_layer=sc.view_layers[0])
    assert Panel.poll(context)
    assert not Panel.poll(types.SimpleNamespace(engine='CYCLES', space_data=context.space_data))
    shading.type = 'SOLID'
    assert not Panel.poll(context)
    for choice, drawn in (('COMBINED', ["render_pass"]), ('LIGHT_GROUP', ["render_pass", "light_group"]),
                          ('AOV', ["render_pass", "aov_name"])):
        settings.render_pass = choice
        panel = types.SimpleNamespace(layout=RecordingLayout())
        Panel.draw(panel, context)
        assert panel.layout.props == drawn
    settings.render_pass = 'COMBINED'
