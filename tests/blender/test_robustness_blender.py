"""Hostile scenes through Blender (issue 7): the add-on, run headless by bpy.ops.render.render,
either renders a clean image or reports a clear error through engine.report (which the operator
raises as RuntimeError("Error: Pathlight: ...")); it never lets a Python traceback out, never
hangs and never takes Blender down. Cases that could hang or exhaust memory run in a fresh
interpreter with a timeout / an address-space limit."""

import logging
import math
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import bpy
import numpy as np
import pytest

from blender_util import REPO, empty_scene_with_camera, core_available, load_addon, read_exr, node_material

addon = load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


# ---------------------------------------------------------------- helpers

@pytest.fixture
def scene():
    """An empty scene, a camera at (0, -6, 0) looking at the origin, a grey world, 16x16 pixels."""
    sc = empty_scene_with_camera(16)
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    sc.world = world
    return sc


def mesh_object(name, verts, faces, material=None, location=(0.0, 0.0, 0.0)):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    if material is not None:
        mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    return obj


CUBE_V = [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]
CUBE_F = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]


def cube(name="Cube", material=None, location=(0.0, 0.0, 0.0)):
    return mesh_object(name, CUBE_V, CUBE_F, material, location)


def attempt(sc, samples=2, **render_overrides):
    """Render sc with Pathlight to an EXR. Returns (image or None, error message or None)."""
    sc.render.engine = "PATHLIGHT"
    sc.pathlight.samples = samples
    for k, v in render_overrides.items():
        setattr(sc.render, k, v)
    sc.view_settings.view_transform = 'Standard'
    sc.render.use_compositing = False
    sc.render.use_sequencer = False
    sc.render.image_settings.file_format = 'OPEN_EXR'
    sc.render.image_settings.color_mode = 'RGBA'
    sc.render.image_settings.color_depth = '32'
    with tempfile.TemporaryDirectory(prefix="pathlight_robust_") as tmp:
        path = Path(tmp) / "render.exr"
        sc.render.filepath = str(path)
        sc.render.use_file_extension = False
        try:
            bpy.ops.render.render(write_still=True, scene=sc.name)
        except RuntimeError as e:
            return None, str(e)
        return (read_exr(path) if path.exists() else None), None


def assert_clean(img, err, capfd, expect_image=True):
    """The render gave a finite, non-negative image, or a Pathlight/Blender error message; no
    Python traceback reached stderr."""
    out, errout = capfd.readouterr()
    assert "Traceback" not in errout and "Traceback" not in out, errout[-3000:]
    if expect_image:
        assert err is None, err
        assert img is not None, "no image was written"
    if img is not None:
        assert np.isfinite(img).all(), "NaN/Inf in the image"
        assert img.min() >= 0.0, img.min()
    if err is not None:
        assert "Pathlight:" in err or "Error:" in err, err


UNDER_ASAN = "asan" in os.environ.get("LD_PRELOAD", "")


def run_blender_isolated(code, timeout=120, mem_gb=None):
    """Run code in a fresh interpreter with bpy, the add-on registered and the scene fixture's
    setup available as make_scene(); returns CompletedProcess."""
    if mem_gb and UNDER_ASAN:
        pytest.skip("AddressSanitizer's shadow memory cannot live under an address-space limit")
    limit = (f"import resource; resource.setrlimit(resource.RLIMIT_AS, ({mem_gb} << 30, {mem_gb} << 30))\n"
             if mem_gb else "")
    prelude = textwrap.dedent(f"""
        import sys, math, time
        {limit}
        sys.path[:0] = [{str(REPO)!r}, {str(REPO / 'tests' / 'blender')!r}]
        import bpy
        from blender_util import empty_scene_with_camera, load_addon
        load_addon()
        def make_scene():
            sc = empty_scene_with_camera(16)
            sc.render.engine = "PATHLIGHT"
            sc.pathlight.samples = 1
            return sc
        def render():
            try:
                bpy.ops.render.render()
                print("RENDERED", flush=True)
            except RuntimeError as e:
                print("REPORTED", e, flush=True)
    """)
    try:
        return subprocess.run([sys.executable, "-c", prelude + textwrap.dedent(code)], capture_output=True,
                              text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"Blender did not finish within {timeout} s (hang?)")


# ---------------------------------------------------------------- scenes

def test_empty_scene_renders_the_world(scene, capfd):
    img, err = attempt(scene)
    assert_clean(img, err, capfd)
    np.testing.assert_allclose(img[..., :3], 0.5, rtol=1e-4)


def test_empty_scene_without_world(scene, capfd):
    scene.world = None
    img, err = attempt(scene)
    assert_clean(img, err, capfd)
    assert img[..., :3].max() == 0.0


def test_no_camera_is_refused_cleanly(scene, capfd):
    cube()
    scene.camera = None
    img, err = attempt(scene)
    assert_clean(img, err, capfd, expect_image=False)
    assert err is not None and "camera" in err.lower(), err


def test_camera_that_is_not_a_camera(scene, capfd):
    # A mesh object as the scene camera: Blender renders through it as through a default camera.
    scene.camera = cube("NotACamera", location=(0.0, -8.0, 0.0))
    img, err = attempt(scene)
    assert_clean(img, err, capfd, expect_image=False)


def test_camera_inside_geometry(scene, capfd):
    cube(location=(0.0, -6.0, 0.0))  # around the camera: every camera ray hits its inside
    img, err = attempt(scene)
    assert_clean(img, err, capfd)
    assert img[..., :3].max() < 0.5  # the inside of a closed box is darker than the world


@pytest.mark.parametrize("clip_start,clip_end", [(1e-6, 1e6), (100.0, 200.0), (5.9, 6.1)])
def test_extreme_camera_clipping(scene, capfd, clip_start, clip_end):
    cube()
    scene.camera.data.clip_start, scene.camera.data.clip_end = clip_start, clip_end
    img, err = attempt(scene)
    assert_clean(img, err, capfd)


def test_zero_area_and_duplicate_triangles(scene, capfd, caplog):
    verts = [(0, 0, 0), (1, 0, 0), (0, 0, 1), (2, 0, 0), (2, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0), (5, 0, 0)]
    faces = [(0, 1, 2), (3, 4, 5), (6, 7, 8), (0, 1, 2), (0, 1, 2), (2, 1, 0)]  # degenerate, collinear, duplicates
    mesh_object("Bad", verts, faces)
    with caplog.at_level(logging.WARNING):
        img, err = attempt(scene)
    assert_clean(img, err, capfd)
    assert any("degenerate" in r.getMessage() for r in caplog.records), [r.getMessage() for r in caplog.records]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e38])
def test_non_finite_vertex_positions(scene, capfd, bad):
    obj = cube()
    co = np.zeros(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    co[::5] = bad
    obj.data.vertices.foreach_set("co", co)
    obj.data.update()
    cube("Good", location=(3.0, 0.0, 0.0))
    img, err = attempt(scene)
    assert_clean(img, err, capfd)


@pytest.mark.parametrize("shift", [0.0, 2e4, 5e4])
def test_scene_far_from_the_origin_is_warned_about(scene, capfd, caplog, shift):
    """Beyond ~3e4 units float32 hit points lose accuracy (test_robustness_numeric measures the
    limit): the artist is told, and the render still finishes."""
    cube(location=(shift, 0.0, 0.0))
    scene.camera.location.x += shift
    with caplog.at_level(logging.WARNING):
        img, err = attempt(scene)
    assert_clean(img, err, capfd)
    warned = [r.getMessage() for r in caplog.records if "from the world origin" in r.getMessage()]
    assert bool(warned) == (shift > 3e4), warned
    if warned:
        assert "5e+04 units" in warned[0], warned


def test_non_finite_object_transform(scene, capfd):
    obj = cube()
    obj.scale = (1e30, 1e30, 1e30)
    cube("Flat", location=(3.0, 0.0, 0.0)).scale = (0.0, 1.0, 1.0)
    img, err = attempt(scene)
    assert_clean(img, err, capfd, expect_image=False)


@pytest.mark.parametrize("node,inputs", [
    ("ShaderNodeBsdfDiffuse", {"Color": (math.nan, -1.0, math.inf, 1.0)}),
    ("ShaderNodeBsdfDiffuse", {"Color": (1e30, 1e30, 1e30, 1.0)}),
    ("ShaderNodeEmission", {"Color": (1.0, 1.0, 1.0, 1.0), "Strength": math.nan}),
    ("ShaderNodeEmission", {"Color": (1.0, 1.0, 1.0, 1.0), "Strength": -5.0}),
    ("ShaderNodeEmission", {"Color": (1.0, 1.0, 1.0, 1.0), "Strength": 1e30}),
    ("ShaderNodeEmission", {"Color": (-1.0, math.nan, 1.0, 1.0), "Strength": math.inf}),
    ("ShaderNodeBsdfPrincipled", {"Base Color": (math.nan, 0.5, 0.5, 1.0), "Roughness": math.nan,
                                  "Metallic": -3.0, "IOR": 0.0, "Emission Strength": -1.0}),
    ("ShaderNodeBsdfPrincipled", {"IOR": 1.0, "Roughness": 0.0, "Transmission Weight": 1.0}),
    ("ShaderNodeBsdfPrincipled", {"IOR": 1000.0, "Roughness": 1.0, "Coat Weight": 1.0}),
    ("ShaderNodeBsdfGlass", {"IOR": math.nan, "Roughness": -1.0}),
    ("ShaderNodeBsdfGlass", {"IOR": 1e-6, "Roughness": 1e30}),
    ("ShaderNodeBsdfGlossy", {"Roughness": math.inf}),
    ("ShaderNodeHoldout", {}),
    ("ShaderNodeBsdfTranslucent", {"Color": (math.nan, -1.0, 1e30, 1.0)}),
    ("ShaderNodeBsdfMetallic", {"Base Color": (math.nan, 2.0, -1.0, 1.0), "Roughness": math.nan}),
    ("ShaderNodeVolumeScatter", {"Density": math.nan}),
    ("ShaderNodeBsdfPrincipled", {"Subsurface Weight": math.nan, "Subsurface Scale": 1e30,
                                  "Subsurface Radius": (math.nan, -1.0, math.inf), "Subsurface Anisotropy": 5.0}),
    ("ShaderNodeSubsurfaceScattering", {"Color": (math.nan, 2.0, -1.0, 1.0), "Scale": math.inf,
                                        "Radius": (0.0, 1e-30, 1e30), "IOR": math.nan, "Anisotropy": -3.0}),
    # Sheen, rough diffuse and toon lobes (issue 24).
    ("ShaderNodeBsdfPrincipled", {"Sheen Weight": math.nan, "Sheen Roughness": math.nan,
                                  "Sheen Tint": (math.inf, -1.0, math.nan, 1.0), "Diffuse Roughness": math.nan}),
    ("ShaderNodeBsdfPrincipled", {"Sheen Weight": 1e30, "Sheen Roughness": -1.0, "Diffuse Roughness": 1e30,
                                  "Base Color": (1e30, 0.0, -1.0, 1.0)}),
    ("ShaderNodeBsdfDiffuse", {"Roughness": math.nan, "Color": (math.nan, 2.0, -1.0, 1.0)}),
    ("ShaderNodeBsdfSheen", {"Roughness": math.inf, "Color": (math.nan, 1e30, 0.5, 1.0)}),
    ("ShaderNodeBsdfToon", {"Size": math.nan, "Smooth": -1.0}),
])
def test_odd_node_values(scene, capfd, node, inputs):
    cube(material=node_material("Odd", node, **inputs))
    img, err = attempt(scene)
    assert_clean(img, err, capfd)


def test_material_with_an_unlinked_output_and_no_nodes(scene, capfd):
    a = bpy.data.materials.new("NoLinks")
    a.use_nodes = True
    a.node_tree.nodes.remove(a.node_tree.nodes["Principled BSDF"])
    b = bpy.data.materials.new("NoOutput")
    b.use_nodes = True
    b.node_tree.nodes.remove(b.node_tree.nodes["Material Output"])
    c = bpy.data.materials.new("Empty")
    c.use_nodes = True
    c.node_tree.nodes.clear()
    for i, mat in enumerate((a, b, c)):
        cube(f"C{i}", material=mat, location=(3.0 * i - 3.0, 0.0, 0.0))
    img, err = attempt(scene)
    assert_clean(img, err, capfd)


def test_unsupported_nodes_in_the_tree(scene, capfd):
    mat = bpy.data.materials.new("Unsupported")
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    # Odd links (Shader to RGB, whose links are dropped; a Ray Portal's shader into a value input) beside nodes
    # that were unsupported once (Float Curve, IES Texture without a profile, Particle Info off
    # particles).
    for i, kind in enumerate(("ShaderNodeShaderToRGB", "ShaderNodeBsdfRayPortal", "ShaderNodeFloatCurve",
                              "ShaderNodeTexIES", "ShaderNodeParticleInfo")):
        n = nt.nodes.new(kind)
        nt.links.new(n.outputs[0], bsdf.inputs[("Base Color", "Roughness", "Normal", "Metallic", "Alpha")[i]])
    script = nt.nodes.new("ShaderNodeScript")  # OSL: no outputs at all
    group = nt.nodes.new("ShaderNodeGroup")   # a group node without a tree
    assert script and group
    cube(material=mat)
    img, err = attempt(scene)
    assert_clean(img, err, capfd)


def test_reroute_cycle_does_not_hang():
    proc = run_blender_isolated("""
        sc = make_scene()
        bpy.ops.mesh.primitive_cube_add()
        mat = bpy.data.materials.new("Cyclic"); mat.use_nodes = True
        nt = mat.node_tree; nodes = nt.nodes
        nodes.remove(nodes["Principled BSDF"])
        a = nodes.new("NodeReroute"); b = nodes.new("NodeReroute")
        nt.links.new(a.outputs[0], nodes["Material Output"].inputs["Surface"])
        nt.links.new(b.outputs[0], a.inputs[0])
        nt.links.new(a.outputs[0], b.inputs[0])
        bpy.context.object.data.materials.append(mat)
        render()
    """, timeout=20)
    assert "RENDERED" in proc.stdout or "REPORTED" in proc.stdout


def test_cyclic_shader_nodes_do_not_hang():
    # A loop of Math nodes (and of Mix Shaders) feeding the BSDF: Blender flags it, the
    # add-on must give up on it (a warning) and render, in bounded time.
    proc = run_blender_isolated("""
        sc = make_scene()
        bpy.ops.mesh.primitive_cube_add()
        mat = bpy.data.materials.new("Cyclic"); mat.use_nodes = True
        nt = mat.node_tree; nodes = nt.nodes
        bsdf = nodes["Principled BSDF"]
        m1 = nodes.new("ShaderNodeMath"); m2 = nodes.new("ShaderNodeMath")
        nt.links.new(m1.outputs[0], m2.inputs[0]); nt.links.new(m2.outputs[0], m1.inputs[0])
        nt.links.new(m2.outputs[0], bsdf.inputs["Roughness"])
        mix1 = nodes.new("ShaderNodeMixShader"); mix2 = nodes.new("ShaderNodeMixShader")
        nt.links.new(mix1.outputs[0], mix2.inputs[1]); nt.links.new(mix2.outputs[0], mix1.inputs[1])
        nt.links.new(bsdf.outputs[0], mix1.inputs[2])
        nt.links.new(mix2.outputs[0], nodes["Material Output"].inputs["Surface"])
        bpy.context.object.data.materials.append(mat)
        render()
    """, timeout=60)
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert "RENDERED" in proc.stdout or "REPORTED" in proc.stdout, (proc.returncode, proc.stdout, proc.stderr[-3000:])


@pytest.mark.parametrize("energy", [0.0, 1e-30, 1e30, 3e38])
def test_point_light_strength_extremes(scene, capfd, energy):
    scene.world = None
    cube()
    light = bpy.data.objects.new("Light", bpy.data.lights.new("Light", 'POINT'))
    light.data.energy = energy
    light.location = (0.0, -3.0, 2.0)
    scene.collection.objects.link(light)
    img, err = attempt(scene)
    assert_clean(img, err, capfd)
    if energy == 0.0:
        assert img[..., :3].max() == 0.0
    if energy == 1e30:
        assert img[..., :3].max() > 1e20  # not silently dropped


@pytest.mark.parametrize("kind,params", [
    ('AREA', {"size": 0.0}), ('AREA', {"shape": 'RECTANGLE', "size": 0.0, "size_y": 1.0}),
    ('SPOT', {"spot_size": 0.0, "shadow_soft_size": 0.0}), ('SPOT', {"spot_size": math.pi, "spot_blend": 1.0}),
    ('SUN', {"angle": math.pi}), ('POINT', {"shadow_soft_size": 1e-30}), ('POINT', {"shadow_soft_size": 1e6}),
])
def test_degenerate_lights(scene, capfd, kind, params):
    scene.world = None
    cube()
    light = bpy.data.objects.new("Light", bpy.data.lights.new("Light", kind))
    for k, v in params.items():
        setattr(light.data, k, v)
    light.data.energy = 100.0
    light.location = (0.0, -3.0, 2.0)
    scene.collection.objects.link(light)
    img, err = attempt(scene)
    assert_clean(img, err, capfd)


def test_one_pixel_resolution(scene, capfd):
    cube()
    img, err = attempt(scene, resolution_x=100, resolution_y=100, resolution_percentage=1)
    assert_clean(img, err, capfd)
    assert img.shape == (1, 1, 4)
    img, err = attempt(scene, resolution_x=300, resolution_y=100, resolution_percentage=1)
    assert_clean(img, err, capfd)
    assert img.shape == (1, 3, 4)


def test_absurd_resolution_is_a_clear_error_before_allocating():
    # In a child limited to 8 GB of address space: a 65536 x 65536 film would need ~100 GB.
    proc = run_blender_isolated("""
        sc = make_scene()
        bpy.ops.mesh.primitive_cube_add()
        sc.render.resolution_x = sc.render.resolution_y = 65536
        sc.render.resolution_percentage = 100
        render()
    """, mem_gb=8)
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-3000:])
    assert "REPORTED" in proc.stdout and "too large" in proc.stdout, proc.stdout
    assert "Traceback" not in proc.stderr


def test_large_resolution_without_the_memory_is_a_clear_error():
    proc = run_blender_isolated("""
        sc = make_scene()
        sc.render.resolution_x = sc.render.resolution_y = 20000
        sc.render.resolution_percentage = 100
        render()
    """, mem_gb=6)
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-3000:])
    assert "REPORTED" in proc.stdout
    assert "bad_alloc" not in proc.stdout and "Traceback" not in proc.stderr, proc.stdout + proc.stderr[-2000:]


def cancel_with(scene, capfd, caplog, stop, logged):
    """Render with a progress listener that cancels when stop(info, seen so far) is true; the
    render must end cleanly and log `logged`. Returns the progress reports seen."""
    seen = []

    def listener(info):
        seen.append(info)
        return stop(info, seen)

    addon.session.set_progress_listener(listener)
    try:
        with caplog.at_level(logging.INFO):
            img, err = attempt(scene, samples=64)
    finally:
        addon.session.set_progress_listener(None)
    out, errout = capfd.readouterr()
    assert "Traceback" not in errout and err is None, (err, errout[-2000:])
    assert any(logged in r.getMessage() for r in caplog.records), [r.getMessage() for r in caplog.records]
    return seen


def test_cancel_during_the_bvh_build(scene, capfd, caplog):
    """Esc while a big mesh's BVH is being built stops the build itself (the core's commit is
    cancelled from the engine's thread), not only the sampling after it."""
    q = 1000  # a 2M-triangle heightfield, built with foreach_set
    xs = np.linspace(-2.0, 2.0, q + 1, dtype=np.float32)
    x, y = np.meshgrid(xs, xs)
    co = np.stack([x, y, 0.1 * np.sin(5 * x) * np.cos(3 * y)], -1).reshape(-1)
    i = (np.arange(q)[None, :] + (q + 1) * np.arange(q)[:, None]).reshape(-1)
    quads = np.stack([i, i + 1, i + q + 2, i + q + 1], -1).reshape(-1).astype(np.int32)
    me = bpy.data.meshes.new("Big")
    me.vertices.add(len(co) // 3)
    me.vertices.foreach_set("co", co)
    me.loops.add(len(quads))
    me.loops.foreach_set("vertex_index", quads)
    me.polygons.add(q * q)
    me.polygons.foreach_set("loop_start", np.arange(0, len(quads), 4, dtype=np.int32))
    me.update()
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("Big", me))
    # Esc as soon as the build is under way.
    seen = cancel_with(scene, capfd, caplog, lambda info, seen: info.get("stage") == "build",
                       "cancelled during the BVH build")
    assert seen and all(i.get("stage") in ("export", "build") for i in seen), seen  # no sample rendered


def test_cancel_during_the_export(scene, capfd, caplog):
    """Esc while the meshes are being exported stops the export between meshes: nothing is
    built or rendered, the render ends cleanly."""
    for k in range(8):
        cube(f"Cube{k}", location=(3.0 * k, 0.0, 0.0))
    # Esc after two meshes.
    seen = cancel_with(scene, capfd, caplog, lambda info, seen: info.get("stage") == "export" and len(seen) >= 3,
                       "cancelled during the export")
    assert [i.get("stage") for i in seen] == ["export"] * 3, seen  # no build, no samples


def test_render_twice_in_a_row(scene, capfd):
    cube()
    scene.pathlight.seed = 5
    a, err = attempt(scene)
    assert_clean(a, err, capfd)
    b, err = attempt(scene)
    assert_clean(b, err, capfd)
    np.testing.assert_array_equal(a, b)


def test_unregister_and_register_between_renders(scene, capfd):
    cube()
    scene.pathlight.seed = 5
    a, err = attempt(scene)
    assert_clean(a, err, capfd)
    addon.unregister()
    addon.register()
    scene.render.engine = "PATHLIGHT"
    scene.pathlight.seed = 5  # the properties were re-registered: set again
    b, err = attempt(scene)
    assert_clean(b, err, capfd)
    np.testing.assert_array_equal(a, b)


def test_render_after_a_failed_render(scene, capfd):
    cube()
    scene.camera = None
    _, err = attempt(scene)
    assert err is not None
    cam = bpy.data.objects["Camera"]
    scene.camera = cam
    img, err = attempt(scene)
    assert_clean(img, err, capfd)


def test_many_objects_and_instances(scene, capfd):
    src = cube("Src")
    for i in range(200):
        dup = bpy.data.objects.new(f"D{i}", src.data)  # linked duplicates share the mesh
        dup.location = (i % 20 - 10.0, 10.0 + i // 20, 0.0)
        dup.scale = (0.3, 0.3, 0.3)
        scene.collection.objects.link(dup)
    img, err = attempt(scene)
    assert_clean(img, err, capfd)
