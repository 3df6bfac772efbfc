"""Viewport rendering below the gpu drawing: the update planner fed with real depsgraph
updates (depsgraph_update_post, as view_update receives them), the region-view camera, and
the ViewportSession's restarts (what is re-exported, rebuilt or only restarted)."""

import math

import bpy
import numpy as np
import pytest

from blender_util import core_available, core_has, empty_scene_with_camera, load_addon

from addon.viewport_camera import ViewCameraError, view_camera_params
from addon.viewport_update import Update, ViewState, describe_updates, plan_updates, \
    settings_signature


@pytest.fixture
def scene():
    load_addon()
    sc = empty_scene_with_camera(32)
    sc.render.engine = "PATHLIGHT"
    mesh = bpy.data.meshes.new("Cube")
    import bmesh
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=2.0)
    bm.to_mesh(mesh)
    bm.free()
    cube = bpy.data.objects.new("Cube", mesh)
    sc.collection.objects.link(cube)
    mat = bpy.data.materials.new("M")
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.8, 0.8, 0.8, 1)
    mesh.materials.append(mat)
    light = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    light.location = (0, -4, 3)
    light.data.energy = 500
    sc.collection.objects.link(light)
    sc.world = bpy.data.worlds.new("W")
    sc.world.use_nodes = True
    bpy.context.view_layer.update()
    return sc


class Recorder:
    """Collects describe_updates() of each depsgraph_update_post, like view_update sees them."""

    def __init__(self):
        self.updates = []

    def __call__(self, scene, depsgraph):
        self.updates.extend(describe_updates(depsgraph.updates))

    def __enter__(self):
        bpy.app.handlers.depsgraph_update_post.append(self)
        return self

    def __exit__(self, *exc):
        bpy.app.handlers.depsgraph_update_post.remove(self)

    def take(self):
        bpy.context.view_layer.update()
        out, self.updates = self.updates, []
        return out


def _plan(rec, sc, state):
    return plan_updates(rec.take(), state, settings_signature(sc))


def test_plan_from_real_depsgraph_updates(scene):
    sc = scene
    state = ViewState(camera_name="Camera", settings=settings_signature(sc),
                      materials=frozenset({"M"}))
    cube, light, cam = (bpy.data.objects[n] for n in ("Cube", "Lamp", "Camera"))
    with Recorder() as rec:
        rec.take()
        assert _plan(rec, sc, state).nothing  # no change, no work

        cube.select_set(True)  # a Scene update without flags
        assert _plan(rec, sc, state).nothing

        cam.location.z += 0.5
        p = _plan(rec, sc, state)
        assert p.camera and p.restart_only and not p.rebuild_geometry

        mat = bpy.data.materials["M"]
        mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (1, 0, 0, 1)
        p = _plan(rec, sc, state)
        assert p.materials == ["M"] and not p.rebuild_geometry and not p.restart_only

        light.data.energy = 100
        p = _plan(rec, sc, state)
        assert p.lights and not p.rebuild_geometry and not p.materials

        light.location.x += 1
        p = _plan(rec, sc, state)
        assert p.lights and not p.rebuild_geometry

        sc.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 2.0
        p = _plan(rec, sc, state)
        assert p.lights and not p.rebuild_geometry and not p.materials

        sc.pathlight.max_bounces = 3
        sc.update_tag()  # what a change in the UI does (a script's change tags nothing)
        p = _plan(rec, sc, state)
        assert p.settings and not p.rebuild_geometry and not p.materials

        # Cycles' curve shape: the curves' geometry changes (ribbons or round curves).
        sc.cycles_curves.shape = 'THICK' if sc.cycles_curves.shape == 'RIBBONS' else 'RIBBONS'
        sc.update_tag()
        p = _plan(rec, sc, state)
        assert p.settings and p.rebuild_geometry
        state.settings = settings_signature(sc)
        sc.cycles_curves.subdivisions += 1
        sc.update_tag()
        assert _plan(rec, sc, state).rebuild_geometry
        state.settings = settings_signature(sc)

        cube.location.x += 0.25  # a move: new matrices, the top level only
        p = _plan(rec, sc, state)
        assert p.transforms == ["Cube"] and not p.rebuild_geometry and not p.lights
        assert p.restart and not p.restart_only and p.materials == []

        cube.rotation_euler.z += 0.3
        cube.scale.y = 1.5
        assert _plan(rec, sc, state).transforms == ["Cube"]

        cube.data.vertices[0].co.x += 0.1
        cube.data.update()
        assert _plan(rec, sc, state).rebuild_geometry


def test_plan_rules_on_plain_updates():
    state = ViewState(materials=frozenset({"A"}), settings=(1,))
    # A material not in the core scene yet (just created) needs nothing by itself.
    assert plan_updates([Update("Material", "B", shading=True)], state, (1,)).nothing
    # Shading-only updates of objects and meshes come with every material edit.
    p = plan_updates([Update("Object", "Cube", shading=True, object_type="MESH"),
                      Update("Mesh", "Cube", shading=True),
                      Update("Material", "A", shading=True)], state, (1,))
    assert p.materials == ["A"] and not p.rebuild_geometry
    # A moved empty that instances a collection moves geometry; a plain empty does not.
    assert plan_updates([Update("Object", "E", transform=True, object_type="EMPTY",
                                is_instancer=True)], state, (1,)).rebuild_geometry
    assert plan_updates([Update("Object", "E", transform=True, object_type="EMPTY")],
                        state, (1,)).nothing
    # A moved mesh: a transform update; one that instances (verts, faces) re-exports, and so
    # does a move together with new geometry (which also drops the transform list).
    p = plan_updates([Update("Object", "Cube", transform=True, object_type="MESH")], state, (1,))
    assert p.transforms == ["Cube"] and not p.rebuild_geometry and p.restart
    p = plan_updates([Update("Object", "V", transform=True, object_type="MESH", is_instancer=True)],
                     state, (1,))
    assert p.rebuild_geometry and p.transforms == []
    p = plan_updates([Update("Object", "Cube", transform=True, object_type="MESH"),
                      Update("Object", "Cube", transform=True, object_type="MESH"),
                      Update("Object", "B", transform=True, geometry=True, object_type="MESH")],
                     state, (1,))
    assert p.rebuild_geometry and p.transforms == [] and p.lights
    p = plan_updates([Update("Object", "Cube", transform=True, object_type="MESH"),
                      Update("Object", "Cube", transform=True, object_type="MESH"),
                      Update("Object", "Ball", transform=True, object_type="CURVE")], state, (1,))
    assert p.transforms == ["Cube", "Ball"] and not p.lights


def _proj(cam_obj, width, height):
    dg = bpy.context.evaluated_depsgraph_get()
    return np.array(cam_obj.calc_matrix_camera(dg, x=width, y=height))


def test_view_camera_reproduces_blender_projection(scene):
    """A camera view's window matrix (what Blender computes for the camera) gives back the
    camera's lens, shift and clipping in our camera model."""
    cam = bpy.data.objects["Camera"]
    cam.data.lens = 35.0
    cam.data.shift_x, cam.data.shift_y = 0.1, -0.05
    cam.data.clip_start, cam.data.clip_end = 0.5, 80.0
    bpy.context.view_layer.update()
    width, height = 96, 64  # wider than tall: horizontal fit, as the AUTO sensor fit does
    proj = _proj(cam, width, height)
    view = np.array(cam.matrix_world.inverted())
    p = view_camera_params(view, proj, width, height, True)
    assert p["lens"] == pytest.approx(35.0, rel=1e-5)
    assert p["shift_x"] == pytest.approx(0.1, abs=1e-6)
    assert p["shift_y"] == pytest.approx(-0.05, abs=1e-6)
    assert p["clip_start"] == pytest.approx(0.5, rel=1e-4)
    assert p["clip_end"] == pytest.approx(80.0, rel=1e-3)
    assert p["pixel_aspect_y"] == pytest.approx(1.0, rel=1e-5)
    np.testing.assert_allclose(p["matrix_world"], np.array(cam.matrix_world), atol=1e-5)
    _assert_rays_hit_projected_points(p, view, proj, width, height)
    # A matrix that is neither projection, or one that contradicts the perspective flag.
    bad = proj.copy()
    bad[3] = (0, 0, 0.5, 0.5)
    with pytest.raises(ViewCameraError):
        view_camera_params(view, bad, width, height, True)
    with pytest.raises(ViewCameraError):
        view_camera_params(view, proj, width, height, False)


def _core_camera(fields):
    from addon.core import get_core
    cam = get_core().Camera()
    for name, value in fields.items():
        setattr(cam, name, value)
    return cam


def _assert_rays_hit_projected_points(fields, view, proj, width, height, depths=None):
    """World points that Blender's matrices put at raster (x, y) lie on the core camera's ray
    through (x, y), within its clipping range; points outside the clipping range do not."""
    if not core_available():
        return
    cam = _core_camera(fields)
    rng = np.random.default_rng(3)
    inv = np.linalg.inv(proj @ view)
    for _ in range(40):
        ndc = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-0.999, 0.999), 1.0])
        world = inv @ ndc
        world = world[:3] / world[3]
        x, y = (ndc[0] + 1) * 0.5 * width, (ndc[1] + 1) * 0.5 * height
        org, d, tmax = (np.array(v, np.float64) for v in cam.generate_ray(width, height, x, y))
        t = float(np.dot(world - org, d))
        scale = max(1.0, float(np.abs(world).max()))
        # Pixel-exact: the miss distance is a tiny fraction of a pixel's footprint.
        assert np.linalg.norm(org + t * d - world) < 1e-4 * scale
        assert -1e-3 * scale <= t <= tmax + 1e-3 * scale
    for z in (-1.02, 1.02):  # beyond the near and far planes: outside the ray's range
        world = inv @ np.array([0.1, -0.2, z, 1.0])
        world = world[:3] / world[3]
        x, y = 1.1 * 0.5 * width, 0.8 * 0.5 * height
        org, d, tmax = (np.array(v, np.float64) for v in cam.generate_ray(width, height, x, y))
        t = float(np.dot(world - org, d))
        assert t < 0 or t > tmax


def _ortho_matrix(left, right, bottom, top, near, far):
    """OpenGL's glOrtho, which is what Blender's orthographic_m4 builds for the region."""
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1], m[2, 2] = 2 / (right - left), 2 / (top - bottom), -2 / (far - near)
    m[0, 3] = -(right + left) / (right - left)
    m[1, 3] = -(top + bottom) / (top - bottom)
    m[2, 3] = -(far + near) / (far - near)
    m[3, 3] = 1.0
    return m


def test_view_camera_reproduces_blender_orthographic_projection(scene):
    """Camera view through an orthographic scene camera: Blender's own window matrix gives
    back its ortho scale, shift and clipping, and the core's rays go through the points the
    matrices project to each pixel."""
    cam = bpy.data.objects["Camera"]
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = 5.0
    cam.data.shift_x, cam.data.shift_y = 0.15, -0.1
    cam.data.clip_start, cam.data.clip_end = 0.5, 40.0
    cam.rotation_euler = (1.3, 0.2, 0.4)
    bpy.context.view_layer.update()
    width, height = 96, 64
    proj = _proj(cam, width, height)
    view = np.array(cam.matrix_world.inverted())
    p = view_camera_params(view, proj, width, height, False)
    assert p["type"] == "ORTHO"
    assert p["ortho_scale"] == pytest.approx(5.0, rel=1e-5)
    assert p["shift_x"] == pytest.approx(0.15, abs=1e-6)
    assert p["shift_y"] == pytest.approx(-0.1, abs=1e-6)
    assert p["clip_start"] == pytest.approx(0.5, rel=1e-4)
    assert p["clip_end"] == pytest.approx(40.0, rel=1e-4)
    assert p["pixel_aspect_y"] == pytest.approx(1.0, rel=1e-5)
    np.testing.assert_allclose(p["matrix_world"], np.array(cam.matrix_world), atol=1e-5)
    _assert_rays_hit_projected_points(p, view, proj, width, height)
    # Taller than wide (Blender fits the ortho scale to the height then).
    proj = _proj(cam, 40, 90)
    p = view_camera_params(view, proj, 40, 90, False)
    _assert_rays_hit_projected_points(p, view, proj, 40, 90)


def test_view_camera_free_orthographic_view():
    """Free orthographic navigation: an off-centre box (the view's offset and zoom), a
    non-square pixel footprint, and Blender's near plane behind the view point
    (-clip_end / 2): the camera moves back so every visible point stays reachable."""
    rot = np.array([[0.8, -0.6, 0.0], [0.36, 0.48, -0.8], [0.48, 0.64, 0.6]])
    view = np.eye(4)
    view[:3, :3] = rot
    view[:3, 3] = (0.3, -0.2, -7.0)
    width, height = 120, 70
    proj = _ortho_matrix(-2.1, 1.7, -1.3, 1.0, -50.0, 50.0)
    p = view_camera_params(view, proj, width, height, False)
    assert p["type"] == "ORTHO" and p["clip_start"] == 0.0
    assert p["clip_end"] == pytest.approx(100.0, rel=1e-6)
    assert p["ortho_scale"] == pytest.approx(3.8, rel=1e-6)
    _assert_rays_hit_projected_points(p, view, proj, width, height)
    with pytest.raises(ViewCameraError):
        view_camera_params(view, proj, width, height, True)  # says perspective: contradiction


@pytest.mark.skipif(not core_has("Scene", "set_shader"), reason="core without live edits")
def test_viewport_session_renders_an_orthographic_view(scene):
    """The session renders through an orthographic view: the cube (2 units wide) fills the
    middle of a view 4 units wide and leaves its border empty."""
    from addon.core import get_core
    from addon.viewport import ViewportSession
    scene.pathlight.preview_samples = 1
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    view = np.array(bpy.data.objects["Camera"].matrix_world.inverted())
    vs = ViewportSession(get_core())
    vs.set_view(view_camera_params(view, _ortho_matrix(-2, 2, -2, 2, -20, 20), 16, 16, False),
                16, 16)
    vs.sync(bpy.context.evaluated_depsgraph_get())
    film, n = _finish(vs)
    lum = film[..., :3].sum(axis=2)
    assert n == 1 and film.shape == (16, 16, 4)
    assert lum[5:11, 5:11].min() > 0 and lum[:3].max() == 0 and lum[:, :3].max() == 0
    vs.free()


def _finish(vs):
    for _ in range(2000):  # bounded: never hangs, not a timing assertion
        if not vs.poll():
            return vs.display()
        vs.full.wait(0.05) if vs.full is not None else vs.low.wait(0.05)
    raise AssertionError("viewport render did not finish")


@pytest.mark.skipif(not core_has("Scene", "set_shader"), reason="core without live edits")
def test_viewport_session_restarts_without_rebuilding(scene):
    from addon.core import get_core
    from addon.viewport import LOW_RES_DIVIDER, ViewportSession
    sc = scene
    sc.pathlight.preview_samples = 4
    pc = get_core()
    with Recorder() as rec:
        rec.take()
        vs = ViewportSession(pc)
        dg = bpy.context.evaluated_depsgraph_get()
        vs.set_view(None, 64, 64)
        vs.sync(dg)
        # The first pass after a change is a low-resolution one.
        assert vs.low is not None and vs.low.film().shape == (64 // LOW_RES_DIVIDER,) * 2 + (4,)
        film, n = _finish(vs)
        assert film.shape == (64, 64, 4) and n == 4
        core_scene = vs.scene
        assert core_scene.stats()["geometry_builds"] == 1

        # Navigating: the view's camera overrides the scene's; nothing rebuilt or exported.
        cam = bpy.data.objects["Camera"]
        view = np.array(cam.matrix_world.inverted())
        view[0, 3] += 0.3
        fields = view_camera_params(view, _proj(cam, 64, 64), 64, 64, True)
        assert vs.set_view(fields, 64, 64)
        moved, _ = _finish(vs)
        assert not np.allclose(moved, film)
        assert vs.scene is core_scene and core_scene.stats()["geometry_builds"] == 1
        assert vs.counters["exports"] == 1
        assert not vs.set_view(fields, 64, 64)  # the same view: no restart

        # Editing the material replaces its program: no export, no BVH build; the image
        # turns red.
        builds = core_scene.stats()["light_builds"]
        mat = bpy.data.materials["M"]
        mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (1, 0, 0, 1)
        plan = vs.sync(dg, rec.take())
        assert plan.materials == ["M"]
        red, _ = _finish(vs)
        assert vs.counters == dict(vs.counters, exports=1, material_updates=1)
        assert core_scene.stats()["geometry_builds"] == 1
        assert core_scene.stats()["light_builds"] == builds + 1
        lit = moved[..., 0] > 0.02
        assert red[lit][:, 1].mean() < 0.5 * moved[lit][:, 1].mean()

        # A light edit: lights re-read, geometry kept.
        bpy.data.objects["Lamp"].data.energy = 50
        vs.sync(dg, rec.take())
        dim, _ = _finish(vs)
        assert vs.counters["light_updates"] == 1 and vs.counters["exports"] == 1
        assert core_scene.stats()["geometry_builds"] == 1
        assert dim[lit][:, 0].mean() < 0.5 * red[lit][:, 0].mean()

        # Moving the object: its instance gets the new matrix, only the top level is rebuilt,
        # and the image is the one a fresh export of the moved scene renders.
        stats = core_scene.stats()
        assert stats["dynamic"] and stats["real_instances"] == 1
        bpy.data.objects["Cube"].location.x += 0.5
        bpy.data.objects["Cube"].rotation_euler.z += 0.4
        plan = vs.sync(dg, rec.take())
        assert plan.transforms == ["Cube"] and not plan.rebuild_geometry
        moved_cube, _ = _finish(vs)
        assert vs.counters == dict(vs.counters, exports=1, transform_updates=1)
        assert vs.scene is core_scene
        assert core_scene.stats()["geometry_builds"] == stats["geometry_builds"]
        assert core_scene.stats()["top_level_builds"] == stats["top_level_builds"] + 1
        assert not np.array_equal(moved_cube, dim)
        fresh = ViewportSession(pc)
        fresh.set_view(fields, 64, 64)
        fresh.sync(bpy.context.evaluated_depsgraph_get())
        expect, _ = _finish(fresh)
        assert fresh.scene.stats()["top_level_builds"] == 0
        assert np.array_equal(moved_cube, expect)
        fresh.free()

        # Editing the mesh still re-exports.
        cube = bpy.data.objects["Cube"]
        cube.data.vertices[0].co.x += 0.1
        cube.data.update()
        vs.sync(dg, rec.take())
        _finish(vs)
        assert vs.counters["exports"] == 2 and vs.scene is not core_scene
        vs.free()


@pytest.mark.skipif(not core_has("Scene", "set_shader"), reason="core without live edits")
def test_viewport_needs_no_scene_camera(scene):
    """The viewport renders through its own view: a scene without a camera still renders."""
    from addon.core import get_core
    from addon.viewport import ViewportSession
    cam = bpy.data.objects["Camera"]
    view, proj = np.array(cam.matrix_world.inverted()), _proj(cam, 16, 16)
    bpy.data.objects.remove(cam)
    scene.pathlight.preview_samples = 1
    vs = ViewportSession(get_core())
    vs.set_view(view_camera_params(view, proj, 16, 16, True), 16, 16)
    vs.sync(bpy.context.evaluated_depsgraph_get())
    film, n = _finish(vs)
    assert n == 1 and film.shape == (16, 16, 4) and film[..., :3].max() > 0
    vs.free()


@pytest.mark.skipif(not core_has("Scene", "set_instance_transform"), reason="core without instances")
def test_viewport_re_exports_when_a_moved_object_is_also_instanced(scene):
    """An object that a collection instance also shows moves in two places: the session cannot
    move just its own instance, so it re-exports; a plain object next to it still moves alone."""
    from addon.core import get_core
    from addon.viewport import ViewportSession
    sc = scene
    sc.pathlight.preview_samples = 2
    cube = bpy.data.objects["Cube"]
    coll = bpy.data.collections.new("Shown")
    coll.objects.link(cube)
    empty = bpy.data.objects.new("Instancer", None)
    empty.instance_type = "COLLECTION"
    empty.instance_collection = coll
    empty.location = (2.5, 2.0, 0.0)
    sc.collection.objects.link(empty)
    ball_mesh = bpy.data.meshes.new("Ball")
    import bmesh
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=12, v_segments=6, radius=0.5)
    bm.to_mesh(ball_mesh)
    bm.free()
    ball = bpy.data.objects.new("Ball", ball_mesh)
    ball.location = (-1.5, -1.0, 0.0)
    sc.collection.objects.link(ball)
    bpy.context.view_layer.update()
    with Recorder() as rec:
        rec.take()
        vs = ViewportSession(get_core())
        vs.set_view(None, 32, 32)
        dg = bpy.context.evaluated_depsgraph_get()
        vs.sync(dg)
        _finish(vs)
        assert "Cube" in vs.instanced_names and "Ball" in vs.instance_index
        assert vs.scene.stats()["instances"] == 3
        ball.location.z += 0.7
        plan = vs.sync(dg, rec.take())
        assert plan.transforms == ["Ball"]
        _finish(vs)
        assert vs.counters["exports"] == 1 and vs.counters["transform_updates"] == 1
        cube.location.z += 0.5
        plan = vs.sync(dg, rec.take())
        assert "Cube" in plan.transforms or plan.rebuild_geometry
        img, _ = _finish(vs)
        assert vs.counters["exports"] == 2 and vs.counters["transform_updates"] == 1
        fresh = ViewportSession(get_core())
        fresh.set_view(None, 32, 32)
        fresh.sync(bpy.context.evaluated_depsgraph_get())
        assert np.array_equal(img, _finish(fresh)[0])
        fresh.free()
        vs.free()


@pytest.mark.skipif(not core_has("Scene", "set_shader"), reason="core without live edits")
def test_viewport_renders_the_view_layers_material_override(scene):
    """Rendered mode shows the view layer as Cycles' viewport does: a Material Override set or
    cleared while the viewport runs re-exports, and the image is the override's (red here)."""
    from addon.core import get_core
    from addon.viewport import ViewportSession
    scene.pathlight.preview_samples = 2
    red = bpy.data.materials.new("Red")
    red.use_nodes = True
    red.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (1, 0, 0, 1)
    cam = bpy.data.objects["Camera"]
    with Recorder() as rec:
        rec.take()
        vs = ViewportSession(get_core())
        vs.set_view(view_camera_params(np.array(cam.matrix_world.inverted()), _proj(cam, 32, 32), 32, 32, True),
                    32, 32)
        dg = bpy.context.evaluated_depsgraph_get()
        vs.sync(dg)
        grey, _ = _finish(vs)
        bpy.context.view_layer.material_override = red
        bpy.context.view_layer.update()
        vs.sync(dg, rec.take())
        overridden, _ = _finish(vs)
        assert vs.counters["exports"] == 2 and set(vs.material_ids) == {"Red"}
        lit = grey[..., 0] > 0.02
        assert overridden[lit][:, 1].mean() < 0.3 * grey[lit][:, 1].mean()
        bpy.context.view_layer.material_override = None
        bpy.context.view_layer.update()
        vs.sync(dg, rec.take())
        again, _ = _finish(vs)
        assert vs.counters["exports"] == 3 and np.array_equal(again, grey)
        vs.free()
