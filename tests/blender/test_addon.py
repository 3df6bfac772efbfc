"""Tests of the Blender add-on through headless bpy: registration, export (no core needed),
and renders through bpy.ops.render.render (need the compiled core)."""

import subprocess
import sys
import time

import bpy
import numpy as np
import pytest

from blender_util import REPO, empty_scene_with_camera, core_available, load_addon, open_fixture, render_to_array, Warnings, node_material

addon = load_addon()
from addon import session, ui  # noqa: E402  (registered above)
from addon.export import ExportError, export_scene  # noqa: E402
from addon.export.material import convert_material  # noqa: E402
from addon.export.mesh import collect_meshes  # noqa: E402
from addon.export.world import world_color  # noqa: E402

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


@pytest.fixture
def scene():
    """An empty scene with a camera looking at the origin from -y."""
    return empty_scene_with_camera(32)


def add_mesh_object(name, build, collection=None, materials=(), **transform):
    import bmesh
    bm = bmesh.new()
    build(bm)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    for mat in materials:
        mesh.materials.append(mat)
    obj = bpy.data.objects.new(name, mesh)
    for key, value in transform.items():
        setattr(obj, key, value)
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def cube(name="Cube", **kw):
    import bmesh
    return add_mesh_object(name, lambda bm: bmesh.ops.create_cube(bm, size=2.0), **kw)


def sphere(name="Sphere", smooth=True, **kw):
    import bmesh
    obj = add_mesh_object(name, lambda bm: bmesh.ops.create_uvsphere(
        bm, u_segments=32, v_segments=16, radius=1.0), **kw)
    if smooth:
        obj.data.shade_smooth()
    return obj


def depsgraph():
    return bpy.context.evaluated_depsgraph_get()


# ---------------------------------------------------------------- registration

def engine_in_enum(name="PATHLIGHT"):
    """Whether the render engine enum accepts `name` (RNA does not list dynamic enum items)."""
    render = bpy.context.scene.render
    previous = render.engine
    try:
        render.engine = name
    except TypeError:
        return False
    render.engine = previous
    return True


def test_engine_registered():
    assert engine_in_enum()
    engine = bpy.types.RenderEngine.bl_rna_get_subclass_py("PATHLIGHT")
    assert engine.bl_label == "Pathlight"
    assert engine.bl_use_shading_nodes_custom is False
    # The defaults on a new scene (the current one may carry an earlier test's settings).
    scene = bpy.data.scenes.new("Defaults")
    try:
        settings = scene.pathlight
        assert (settings.samples, settings.time_limit, settings.max_bounces, settings.seed,
                settings.use_nee) == (128, 0.0, 12, 0, True)
    finally:
        bpy.data.scenes.remove(scene)


def test_register_unregister_register():
    addon.register()  # twice: a no-op
    addon.unregister()
    try:
        assert not engine_in_enum()
        assert not hasattr(bpy.types.Scene, "pathlight")
        assert not any("PATHLIGHT" in p.COMPAT_ENGINES for p in ui.compat_panels())
        addon.unregister()  # twice: a no-op
    finally:
        addon.register()
    assert engine_in_enum()
    scene = bpy.data.scenes.new("Registered")  # (the current scene may carry earlier settings)
    try:
        assert scene.pathlight.samples == 128
    finally:
        bpy.data.scenes.remove(scene)


def test_panels_compatible():
    expected = {
        "EEVEE_MATERIAL_PT_context_material", "EEVEE_MATERIAL_PT_surface", "MATERIAL_PT_preview",
        "WORLD_PT_context_world", "EEVEE_WORLD_PT_surface", "DATA_PT_context_light",
        "DATA_PT_light", "DATA_PT_context_camera", "DATA_PT_lens", "DATA_PT_camera",
        "RENDER_PT_format", "RENDER_PT_output", "RENDER_PT_color_management",
    }
    for name in expected:
        assert "PATHLIGHT" in getattr(bpy.types, name).COMPAT_ENGINES, name
    for cls in ui.classes:
        assert cls.is_registered


def test_register_does_not_need_core():
    # A fresh interpreter: registering must not import the core, and exiting with the add-on
    # registered must not hang (the bpy module does without the atexit unregister).
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import bpy, addon; addon.register(); "
            "bpy.context.scene.render.engine = 'PATHLIGHT'; "
            "print(any(m.endswith('pathlight_core') for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code, str(REPO)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_missing_core_error(monkeypatch):
    from addon import core
    monkeypatch.setattr(core, "_core", None)
    monkeypatch.delattr(addon, "pathlight_core", raising=False)
    monkeypatch.setitem(sys.modules, "addon.pathlight_core", None)  # makes the import fail
    with pytest.raises(RuntimeError, match="not built: run `python3 build.py build`"):
        core.get_core()


# ---------------------------------------------------------------- export (no core)

def test_mesh_arrays(scene):
    cube()
    (mesh,) = collect_meshes(depsgraph())
    assert mesh.positions.shape == (8, 3) and mesh.positions.dtype == np.float32
    assert mesh.triangles.shape == (12, 3) and mesh.triangles.dtype == np.int32
    assert mesh.corner_normals.shape == (12, 3, 3) and mesh.corner_normals.dtype == np.float32
    assert mesh.material_indices.shape == (12,) and mesh.material_indices.dtype == np.int32
    assert mesh.triangles.min() == 0 and mesh.triangles.max() == 7
    assert len(mesh.matrices) == 1 and mesh.matrices[0].shape == (4, 4)


def test_flat_cube_has_face_normals(scene):
    cube()
    (mesh,) = collect_meshes(depsgraph())
    p = mesh.positions[mesh.triangles]
    face = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    # All three corners carry the outward face normal.
    np.testing.assert_allclose(mesh.corner_normals, np.repeat(face[:, None], 3, 1), atol=1e-5)
    assert (np.einsum("ij,ij->i", face, p.mean(axis=1)) > 0).all()


def test_smooth_sphere_has_vertex_normals(scene):
    sphere()
    (mesh,) = collect_meshes(depsgraph())
    n = mesh.corner_normals
    radial = mesh.positions[mesh.triangles]
    radial /= np.linalg.norm(radial, axis=2, keepdims=True)
    assert np.abs(n - radial).max() < 0.05  # smooth normals point away from the centre
    spread = np.linalg.norm(n - n.mean(axis=1, keepdims=True), axis=2).max(axis=1)
    assert (spread > 1e-3).all()  # and vary across every triangle


def test_linked_duplicates_and_instances_share_a_mesh(scene):
    source = bpy.data.collections.new("Source")
    scene.collection.children.link(source)
    original = cube(collection=source)
    duplicate = bpy.data.objects.new("Duplicate", original.data)  # linked duplicate
    duplicate.location = (0.0, 5.0, 0.0)
    scene.collection.objects.link(duplicate)
    for x in (3.0, 6.0):
        empty = bpy.data.objects.new(f"Instance{x}", None)
        empty.instance_type = 'COLLECTION'
        empty.instance_collection = source
        empty.location = (x, 0.0, 0.0)
        scene.collection.objects.link(empty)
    (mesh,) = collect_meshes(depsgraph())
    offsets = sorted(tuple(m[:3, 3]) for m in mesh.matrices)
    assert offsets == [(0, 0, 0), (0, 5, 0), (3, 0, 0), (6, 0, 0)]


def test_modified_objects_do_not_share(scene):
    a = cube("A")
    b = bpy.data.objects.new("B", a.data)
    scene.collection.objects.link(b)
    b.modifiers.new("Subdivision", 'SUBSURF').levels = 1
    meshes = sorted(collect_meshes(depsgraph()), key=lambda m: len(m.triangles))
    assert [len(m.triangles) for m in meshes] == [12, 48]


def test_hidden_and_non_geometry_objects_are_skipped(scene):
    cube("Hidden").hide_render = True
    scene.collection.objects.link(bpy.data.objects.new("Empty", None))
    curve = bpy.data.curves.new("Path", 'CURVE')  # no bevel: no surface
    curve.splines.new('POLY').points.add(2)
    scene.collection.objects.link(bpy.data.objects.new("Path", curve))
    assert collect_meshes(depsgraph()) == []


def test_curves_text_and_metaballs_convert_to_meshes(scene):
    text = bpy.data.curves.new("Text", 'FONT')
    text.body = "Hi"
    curve = bpy.data.curves.new("Tube", 'CURVE')
    curve.bevel_depth = 0.1
    points = curve.splines.new('POLY').points
    points.add(2)
    points.foreach_set("co", [0, 0, 0, 1, 1, 0, 0, 1, 1, 1, 0, 1])
    metaball = bpy.data.metaballs.new("Blob")
    metaball.elements.new()
    for name, data in (("Text", text), ("Tube", curve), ("Blob", metaball)):
        scene.collection.objects.link(bpy.data.objects.new(name, data))
    meshes = {m.name: m for m in collect_meshes(depsgraph())}
    assert sorted(meshes) == ["Blob", "Text", "Tube"]  # once each
    assert all(len(m.triangles) > 10 for m in meshes.values())


def test_material_slots_and_indices(scene):
    red = node_material("Red", "ShaderNodeBsdfDiffuse", Color=(1, 0, 0, 1))
    blue = node_material("Blue", "ShaderNodeBsdfDiffuse", Color=(0, 0, 1, 1))
    obj = cube(materials=(red, blue))
    obj.data.polygons[0].material_index = 1
    obj.data.polygons[1].material_index = 5  # out of range: Blender uses the last slot
    cube("Plain", location=(4, 0, 0))  # no slots: default material
    warnings = Warnings()
    data = export_scene(depsgraph(), warnings)
    assert warnings == []
    by_name = {m.name: (m, slots) for m, slots in zip(data.meshes, data.material_slots)}
    mesh, slots = by_name["Cube"]
    assert [data.materials[i].base_color for i in slots] == [(1, 0, 0), (0, 0, 1)]
    assert sorted(np.bincount(mesh.material_indices).tolist()) == [4, 8]
    assert mesh.material_indices.max() == 1
    mesh, slots = by_name["Plain"]
    assert slots == [] and (mesh.material_indices == 0).all()


def test_materials_map_to_colours():
    warnings = Warnings()
    diffuse = node_material("Diffuse", "ShaderNodeBsdfDiffuse", Color=(0.2, 0.4, 0.6, 1))
    emission = node_material("Emission", "ShaderNodeEmission", Color=(1, 0.5, 0.25, 1),
                             Strength=4.0)
    principled = bpy.data.materials.new("Principled")
    principled.use_nodes = True
    bsdf = principled.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.1, 0.2, 0.3, 1)
    bsdf.inputs["Emission Color"].default_value = (1, 1, 0.5, 1)
    bsdf.inputs["Emission Strength"].default_value = 2.0
    flat = bpy.data.materials.new("NoNodes")
    flat.use_nodes = False
    flat.diffuse_color = (0.5, 0.25, 0.125, 1)

    def colors(mat):
        m = convert_material(mat, warnings)
        return np.array([m.base_color, m.emission])

    np.testing.assert_allclose(colors(diffuse), [(0.2, 0.4, 0.6), (0, 0, 0)], atol=1e-6)
    np.testing.assert_allclose(colors(emission), [(0, 0, 0), (4, 2, 1)], atol=1e-6)
    np.testing.assert_allclose(colors(principled), [(0.1, 0.2, 0.3), (2, 2, 1)], atol=1e-6)
    np.testing.assert_allclose(colors(flat), [(0.5, 0.25, 0.125), (0, 0, 0)], atol=1e-6)
    np.testing.assert_allclose(colors(None), [(0.8, 0.8, 0.8), (0, 0, 0)])
    assert warnings == []


def test_unsupported_node_warns_once_and_falls_back_to_diffuse(scene):
    toon = node_material("Toony", "ShaderNodeBackground", Color=(0.2, 0.4, 0.6, 1))
    cube("A", materials=(toon,))
    cube("B", materials=(toon, toon), location=(4, 0, 0))
    warnings = Warnings()
    data = export_scene(depsgraph(), warnings)
    assert len(warnings) == 1
    assert "Toony" in warnings[0] and "ShaderNodeBackground" in warnings[0]
    (toony,) = [m for m in data.materials if m.name == "Toony"]
    # A diffuse closure of the node's own Color input.
    consts = {op[1]: op[2] for op in toony.program if op[0] == "const"}
    (closure,) = [op for op in toony.program if op[0] == "closure"]
    assert closure[1] == "diffuse" and closure[2] is None
    assert consts[closure[3]["color"]][:3] == pytest.approx((0.2, 0.4, 0.6))


def test_unsupported_value_node_uses_the_input_value_and_warns():
    mat = bpy.data.materials.new("Textured")
    mat.use_nodes = True
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.3, 0.3, 0.3, 1)
    info = tree.nodes.new("ShaderNodeShaderToRGB")  # EEVEE only: its link is dropped, as in Cycles
    tree.links.new(info.outputs["Color"], bsdf.inputs["Base Color"])
    warnings = Warnings()
    m = convert_material(mat, warnings)
    assert m.base_color == pytest.approx((0.3, 0.3, 0.3))
    assert len(warnings) == 1 and "Shader to RGB" in warnings[0] and "Base Color" in warnings[0]
    consts = {op[1]: op[2] for op in m.program if op[0] == "const"}
    (closure,) = [op for op in m.program if op[0] == "closure"]
    assert consts[closure[3]["base_color"]][:3] == pytest.approx((0.3, 0.3, 0.3))


def test_world_color():
    warnings = Warnings()
    assert world_color(None, warnings) == (0, 0, 0)
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.5, 0.25, 1.0, 1)
    background.inputs["Strength"].default_value = 2.0
    assert world_color(world, warnings) == pytest.approx((1.0, 0.5, 2.0))
    assert warnings == []

    sky = world.node_tree.nodes.new("ShaderNodeMixShader")
    world.node_tree.links.new(sky.outputs[0],
                              world.node_tree.nodes["World Output"].inputs["Surface"])
    world.color = (0.1, 0.2, 0.3)
    assert world_color(world, warnings) == pytest.approx((0.1, 0.2, 0.3))
    assert len(warnings) == 1 and "Mix Shader" in warnings[0]


def test_camera_export(scene):
    cam = scene.camera
    cam.data.lens = 35.0
    cam.data.sensor_fit = 'VERTICAL'
    cam.data.shift_x = 0.1
    cam.scale = (2.0, 2.0, 2.0)  # ignored, like Cycles
    scene.render.pixel_aspect_x = 2.0
    warnings = Warnings()
    params = export_scene(depsgraph(), warnings).camera
    assert params["lens"] == pytest.approx(35.0)
    assert params["sensor_fit"] == 'VERTICAL' and params["shift_x"] == pytest.approx(0.1)
    assert params["pixel_aspect_x"] == 2.0 and params["pixel_aspect_y"] == 1.0
    m = params["matrix_world"]
    assert m.shape == (4, 4) and m.dtype == np.float32
    np.testing.assert_allclose(m[:3, 3], (0, -6, 0), atol=1e-6)
    np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(-m[:3, 2], (0, 1, 0), atol=1e-6)  # looks down its local -Z
    assert warnings == []

    cam.data.type = 'ORTHO'  # supported since issue 5: no warning
    params = export_scene(depsgraph(), warnings).camera
    assert warnings == [] and params["type"] == 'ORTHO'
    cam.data.type = 'PANO'  # supported since the panoramic cameras: no warning
    params = export_scene(depsgraph(), warnings).camera
    assert warnings == [] and params["type"] == 'PANO'
    cam.data.type = 'CUSTOM'  # (an OSL camera) still unsupported: a warning, and a perspective render
    params = export_scene(depsgraph(), warnings).camera
    assert len(warnings) == 1 and "custom" in warnings[0] and params["type"] == 'PERSP'


def test_no_camera_is_an_export_error(scene):
    scene.camera = None
    with pytest.raises(ExportError, match="no active camera"):
        export_scene(depsgraph(), Warnings())


def test_cornell_box_export():
    open_fixture("cornell_box")
    warnings = Warnings()
    data = export_scene(depsgraph(), warnings)
    assert warnings == []
    assert sorted(m.name for m in data.meshes) == [
        "Back", "Box", "Ceiling", "Floor", "Left", "Light", "Right", "Sphere"]
    emissive = [m for m in data.materials if any(m.emission)]
    assert len(emissive) == 1
    assert emissive[0].emission == pytest.approx((12.0, 10.2, 7.8))
    assert data.world_color == (0, 0, 0)


# ---------------------------------------------------------------- renders (need the core)

@pytest.fixture
def listener():
    """Install a progress listener; calls(info) returns the listener's answer (default None)."""
    class Listener:
        def __init__(self):
            self.infos, self.answer = [], lambda info: None

        def __call__(self, info):
            self.infos.append(dict(info))
            return self.answer(info)
    fn = Listener()
    session.set_progress_listener(fn)
    yield fn
    session.set_progress_listener(None)


@needs_core
def test_cornell_box_renders(listener):
    scene = open_fixture("cornell_box")
    img = render_to_array(scene, samples=8, resolution_percentage=25)
    assert img.shape == (64, 64, 4) and img.dtype == np.float32
    assert np.isfinite(img).all()
    assert (img[..., 3] == 1.0).all()  # film not transparent
    rgb = img[..., :3]
    assert rgb.mean() > 0.05
    left, right = rgb[16:48, 4:10].mean(axis=(0, 1)), rgb[16:48, -10:-4].mean(axis=(0, 1))
    assert left[0] > 2 * left[1] and right[1] > 2 * right[0]  # red left wall, green right
    assert rgb[:32].max() > 5.0 > rgb[32:].max()  # the light is in the top half (row 0 = top)
    assert listener.infos[-1]["samples_done"] == listener.infos[-1]["samples_total"] == 8


@needs_core
def test_cornell_box_mean_matches_cycles():
    scene = open_fixture("cornell_box")
    ours = render_to_array(scene, samples=64, resolution_percentage=25, max_bounces=16)
    ref = render_to_array(scene, "CYCLES", samples=64, resolution_percentage=25, max_bounces=16)
    # A smoke test of units and conventions, not of accuracy: image means within 3 %.
    np.testing.assert_allclose(ours[..., :3].mean(axis=(0, 1)), ref[..., :3].mean(axis=(0, 1)),
                               rtol=0.03)


@needs_core
def test_cancel_through_listener(listener):
    scene = open_fixture("cornell_box")
    start = time.monotonic()
    listener.answer = lambda info: time.monotonic() - start > 0.5
    img = render_to_array(scene, samples=100000, resolution_percentage=50)
    assert time.monotonic() - start < 3.0
    info = listener.infos[-1]
    assert info["samples_total"] == 100000 and 0 < info["samples_done"] < 100000
    assert set(info) == {"samples_done", "samples_total", "elapsed_s", "eta_s"}
    # The result was ended: the partial image was written.
    assert img.shape == (128, 128, 4) and np.isfinite(img).all() and img[..., :3].mean() > 0.05


@needs_core
def test_time_limit_stops_render(listener):
    scene = open_fixture("cornell_box")
    start = time.monotonic()
    render_to_array(scene, samples=100000, time_limit=0.5, resolution_percentage=25)
    assert time.monotonic() - start < 2.5
    assert listener.infos[-1]["samples_done"] < 100000
    assert all(0 <= info["eta_s"] <= 0.5 for info in listener.infos)


@needs_core
def test_seed_and_threads_reach_the_core():
    scene = open_fixture("cornell_box")
    scene.render.threads_mode = 'FIXED'
    scene.render.threads = 1
    a, b, c = (render_to_array(scene, samples=2, seed=seed, resolution_percentage=12)
               for seed in (1, 1, 2))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@needs_core
def test_empty_scene_renders_world(scene):
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.2, 0.3, 0.4, 1)
    scene.world = world
    img = render_to_array(scene, samples=2)
    assert img.shape == (32, 32, 4)
    np.testing.assert_allclose(img[..., :3], np.broadcast_to((0.2, 0.3, 0.4), (32, 32, 3)),
                               rtol=1e-4)


@needs_core
def test_errors_are_reported_not_raised(scene, listener):
    cube()
    scene.render.engine = "PATHLIGHT"
    listener.answer = lambda info: 1 / 0  # an exception inside the progress loop
    with pytest.raises(RuntimeError, match="Pathlight: ZeroDivisionError: division by zero"):
        bpy.ops.render.render()  # the operator turns the engine's ERROR report into this
    session.set_progress_listener(None)
    # Rendering works again afterwards: the session was cancelled and the result ended.
    img = render_to_array(scene, samples=1)
    assert np.isfinite(img).all()
