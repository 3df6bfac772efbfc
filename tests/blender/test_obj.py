"""OBJ+MTL scenes (issue 3): the fixture of blender_scenes/make_obj_fixture.py imported with
Blender's own importer by addon/obj_scene.py (what `build.py render model.obj` does), framed
by a camera, compiled without fallback warnings and rendered with its texture."""

import runpy
import subprocess
import sys

import bpy
import numpy as np
import pytest
from mathutils import Vector

from blender_util import REPO, SCENES, core_available, load_addon, render_to_array, Warnings

load_addon()
from addon.export import export_scene  # noqa: E402
from addon.obj_scene import ObjSceneError, load_obj_scene  # noqa: E402

MODEL = SCENES / "obj_materials" / "model.obj"


def test_fixture_is_up_to_date(tmp_path):
    """The committed fixture is what the generator writes."""
    write = runpy.run_path(str(SCENES / "make_obj_fixture.py"))["write"]
    write.__globals__["OUT"] = tmp_path
    write()
    for name in ("model.obj", "model.mtl", "checker.png"):
        assert (tmp_path / name).read_bytes() == (MODEL.parent / name).read_bytes(), name


def test_import_builds_a_framed_scene():
    scene = load_obj_scene(MODEL, resolution=(96, 72))
    meshes = sorted(o.name for o in scene.objects if o.type == 'MESH')
    assert meshes == ["Floor", "Glass", "Shiny"]
    assert (scene.render.resolution_x, scene.render.resolution_y) == (96, 72)
    # What Blender's importer made of the MTL.
    mats = {m.name: m for m in bpy.data.materials}
    assert sorted(mats) == ["checker", "glass", "shiny"]
    bsdf = {name: m.node_tree.nodes["Principled BSDF"] for name, m in mats.items()}
    tex = [n for n in mats["checker"].node_tree.nodes if n.type == 'TEX_IMAGE']
    assert len(tex) == 1 and tex[0].image is not None and tuple(tex[0].image.size) == (4, 4)
    assert bsdf["glass"].inputs["Transmission Weight"].default_value == pytest.approx(1.0)
    assert bsdf["glass"].inputs["IOR"].default_value == pytest.approx(1.5)
    assert bsdf["glass"].inputs["Metallic"].default_value == 0.0
    assert bsdf["shiny"].inputs["Specular IOR Level"].default_value == pytest.approx(0.5)
    assert bsdf["shiny"].inputs["Roughness"].default_value < 0.6
    # Every bounding-box corner projects into the frame, and the box nearly fills it.
    cam = scene.camera
    from bpy_extras.object_utils import world_to_camera_view
    points = [o.matrix_world @ Vector(c) for o in scene.objects if o.type == 'MESH'
              for c in o.bound_box]
    ndc = np.array([world_to_camera_view(scene, cam, p)[:] for p in points])
    assert (ndc[:, :2] > 0).all() and (ndc[:, :2] < 1).all() and (ndc[:, 2] > 0).all()
    span = ndc[:, :2].max(0) - ndc[:, :2].min(0)
    assert span.max() > 0.85
    assert abs(ndc[:, 0].min() - (1 - ndc[:, 0].max())) < 0.02  # centred
    assert scene.world is not None and scene.world.node_tree.nodes["Background"].inputs[
        "Color"].default_value[0] > 0


def test_compiles_without_warnings():
    load_obj_scene(MODEL)
    warnings = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert warnings == []
    (checker,) = [m for m in data.materials if m.name == "checker"]
    assert any(op[0] == "image" for op in checker.program)
    assert len(data.images) == 1 and data.images[0].pixels.shape == (4, 4, 4)
    floor = next(m for m in data.meshes if m.name == "Floor")
    assert floor.uvs[0].shape == (2, 3, 2) and floor.uvs[0].max() == pytest.approx(2.0)


def test_missing_or_empty_files_are_errors(tmp_path):
    with pytest.raises(ObjSceneError, match="not found"):
        load_obj_scene(tmp_path / "nothing.obj")
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(ObjSceneError, match="no geometry"):
        load_obj_scene(empty)


@pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
def test_renders_with_its_texture():
    ours = render_to_array(load_obj_scene(MODEL, resolution=(96, 72)), "PATHLIGHT", samples=32,
                           max_bounces=32)
    assert np.isfinite(ours).all()
    # The floor shows the texture's four colours: pixels where each of red, yellow (red and
    # green), green and blue clearly dominates.
    rgb = ours[..., :3]
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    kinds = {"red": (r > 1.6 * g) & (r > 1.6 * b), "yellow": (r > 1.6 * b) & (g > 1.6 * b),
             "green": (g > 1.3 * r) & (g > 1.3 * b), "blue": (b > 1.3 * r) & (b > 1.1 * g)}
    counts = {k: int(v.sum()) for k, v in kinds.items()}
    assert all(c > 20 for c in counts.values()), counts
    # Cycles renders the same import alike (a loose bound: the core interpolates 8-bit sRGB
    # texels in linear space, Cycles in sRGB; see test_materials).
    cycles = render_to_array(load_obj_scene(MODEL, resolution=(96, 72)), "CYCLES", samples=32,
                             max_bounces=32, pixel_filter_type='BOX', filter_width=1.0)
    ratio = rgb.mean() / cycles[..., :3].mean()
    assert abs(ratio - 1) < 0.05, ratio


def test_build_py_accepts_obj():
    """`build.py render` takes an .obj (checked without rendering: the argument check only)."""
    code = ("import sys, types; sys.argv = ['build.py']; import build; "
            "ns = types.SimpleNamespace(scene=sys.argv_obj, output='/tmp/x.png', format=None, "
            "samples=None, threads=None, time_limit=None, seed=None, frame=1, verbose=False); "
            "print(build.render_options(ns)['scene'])")
    code = code.replace("sys.argv_obj", repr(str(MODEL)))
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("model.obj")
