"""Stereoscopy and multi-view renders (Output > Stereoscopy; addon/export/views.py,
docs/design/stereo.md). Every view of the result gets its own render through its own camera:
- Stereo 3D, each convergence mode (off-axis, parallel, toe-in) and pivot: each view equals a
  mono render through a camera built here by hand from the stereo settings (Blender's
  camera_stereo3d_model_matrix and camera_stereo3d_shift_x written out), with the view's seed;
- Multi-View: each view renders through the camera with its suffix;
- passes (Depth) per view;
- against Cycles (stored references): a perspective off-axis pair, and an equirectangular
  panorama with spherical stereo (per-ray offsets in the core), each view within noise.
"""
import math
import tempfile
from pathlib import Path

import bpy
import numpy as np
import OpenEXR
import pytest
from mathutils import Matrix

from blender_util import BOX_FILTER, core_available, load_addon, render_to_array
from light_scenes import add_light, box, camera, diffuse_material, empty_scene, plane, uv_sphere, world_color
from material_scenes import assert_agree

load_addon()
from addon.export.views import view_seed  # noqa: E402

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

W, H = 32, 24
IOD, CONV = 0.3, 4.0
SEED = 7


def scene_with_objects(width=W, height=H):
    scene = empty_scene(width, height)
    world_color((0.25, 0.3, 0.4))
    plane("floor", 10.0, diffuse_material("floor", (0.6, 0.6, 0.6)))
    uv_sphere("ball", 0.6, diffuse_material("ball", (0.8, 0.3, 0.2)), location=(-0.5, 0.3, 0.6))
    box("box", 0.8, diffuse_material("box", (0.2, 0.5, 0.8)), location=(0.9, 0.8, 0.4))
    box("post", 0.3, diffuse_material("post", (0.9, 0.9, 0.3)), location=(0.1, -1.2, 0.15))
    add_light('SUN', rotation=(0.6, 0.2, 0.8), energy=3.0)
    return scene


def stereo_scene(mode='OFFAXIS', pivot='CENTER', kind='PERSP'):
    scene = scene_with_objects()
    cam = camera((0.4, -4.5, 1.5), look_at=(0.0, 0.0, 0.5))
    cam.data.type = kind
    cam.data.ortho_scale = 5.0
    cam.data.shift_x = 0.02
    st = cam.data.stereo
    st.convergence_mode, st.pivot = mode, pivot
    st.interocular_distance, st.convergence_distance = IOD, CONV
    scene.render.use_multiview = True
    scene.render.views_format = 'STEREO_3D'
    return scene


def hand_view(cam, is_left):
    """(model matrix, shift_x) of the stereo view of camera object `cam`, written out from
    Blender's camera_stereo3d_model_matrix and camera_stereo3d_shift_x (blenkernel/camera.cc)."""
    data, st = cam.data, cam.data.stereo
    m = np.array(cam.matrix_world, np.float64)
    m[:3, :3] /= np.linalg.norm(m[:3, :3], axis=0)
    iod, conv = st.interocular_distance, st.convergence_distance
    if (st.pivot == 'LEFT' and is_left) or (st.pivot == 'RIGHT' and not is_left):
        return m, data.shift_x
    fac = 0.5 if st.pivot == 'CENTER' else 1.0
    fs = fac if is_left else -fac

    def translate(x):
        t = np.eye(4)
        t[0, 3] = x
        return t

    def rot_y(a):  # Blender's rotmat: [0][0] = cos, [2][0] = -sin, [0][2] = sin (column-major)
        r = np.eye(4)
        r[0, 0] = r[2, 2] = math.cos(a)
        r[0, 2], r[2, 0] = -math.sin(a), math.sin(a)
        return r
    shift = data.shift_x
    if st.convergence_mode == 'TOE':
        if st.pivot == 'CENTER':
            fac, fs = -fac, -fs
        angle = math.atan(iod * 0.5 / conv) / fac
        r = rot_y(angle * fs)
        if st.pivot == 'CENTER':
            t = r.copy()
            t[0, 3] = iod * fs
            m = m @ t
        else:
            m = m @ r @ translate(-iod * fs) @ r
    else:
        m = m @ translate(-iod * fs)
        if st.convergence_mode == 'OFFAXIS':
            shift += iod / data.sensor_width * (data.lens / conv) * fs
    return m, shift


def mono_of_view(scene, index, name):
    """Turns multiview off and renders through a copy of the camera placed as view `name` by
    hand (hand_view), with the seed the view gets."""
    cam = scene.camera
    m, shift = hand_view(cam, name == "left")
    twin = bpy.data.objects.new(f"Hand {name}", cam.data.copy())
    scene.collection.objects.link(twin)
    twin.data.shift_x = shift
    twin.matrix_world = Matrix(m.tolist())
    scene.camera = twin
    scene.render.use_multiview = False
    try:
        return render_to_array(scene, samples=4, seed=view_seed(SEED, index))
    finally:
        scene.camera = cam
        scene.render.use_multiview = True


def assert_same_render(a, b, what):
    """The same image up to the last bits of a camera rebuilt from loc/rot/scale (measured: at
    most 4e-6 apart)."""
    diff = np.abs(a - b)
    print(f"\n{what}: max |diff| {diff.max():.3g}")  # pytest -s
    assert diff.max() < 5e-5, f"{what}: max |diff| {diff.max():.3g}"


@needs_core
def test_a_stereo_render_has_both_views_and_they_differ():
    views = render_to_array(stereo_scene(), samples=4, seed=SEED)
    assert sorted(views) == ["left", "right"]
    left, right = views["left"], views["right"]
    assert left.shape == right.shape == (H, W, 4)
    assert left[..., :3].mean() > 0.05 and right[..., :3].mean() > 0.05
    assert np.abs(left - right).max() > 0.1


CASES = [('OFFAXIS', 'CENTER', 'PERSP'), ('OFFAXIS', 'LEFT', 'PERSP'), ('PARALLEL', 'CENTER', 'PERSP'),
         ('TOE', 'CENTER', 'PERSP'), ('TOE', 'LEFT', 'PERSP'), ('TOE', 'RIGHT', 'PERSP'),
         ('OFFAXIS', 'CENTER', 'ORTHO'), ('PARALLEL', 'CENTER', 'PANO')]


@needs_core
@pytest.mark.parametrize("mode,pivot,kind", CASES)
def test_each_view_equals_a_mono_render_through_its_camera(mode, pivot, kind):
    scene = stereo_scene(mode, pivot, kind)
    if kind == 'PANO':  # without spherical stereo a panorama is a moved camera too
        scene.camera.data.panorama_type = 'EQUIRECTANGULAR'
    views = render_to_array(scene, samples=4, seed=SEED)
    for index, name in enumerate(("left", "right")):
        assert_same_render(views[name], mono_of_view(scene, index, name), f"{mode} {pivot} {kind} {name}")


@needs_core
def test_multiview_renders_each_view_through_its_suffixed_camera():
    scene = scene_with_objects()
    cams = {}
    for suffix, loc in (("_L", (-1.0, -4.5, 1.2)), ("_R", (1.5, -4.0, 2.0)), ("_top", (0.0, -1.0, 6.0))):
        cams[suffix] = camera(loc, look_at=(0.0, 0.0, 0.5))
        cams[suffix].name = "Cam" + suffix
    scene.camera = cams["_L"]
    scene.render.use_multiview = True
    scene.render.views_format = 'MULTIVIEW'
    top = scene.render.views.new("top")  # a custom view, its camera found by its suffix
    top.file_suffix = "_top"
    views = render_to_array(scene, samples=4, seed=SEED)
    assert list(views) == ["left", "right", "top"]
    scene.render.use_multiview = False
    for index, (name, suffix) in enumerate((("left", "_L"), ("right", "_R"), ("top", "_top"))):
        scene.camera = cams[suffix]
        mono = render_to_array(scene, samples=4, seed=view_seed(SEED, index))
        assert np.array_equal(views[name], mono), f"multiview {name}"  # the camera object itself
    assert np.abs(views["left"] - views["right"]).max() > 0.1
    assert np.abs(views["top"] - views["right"]).max() > 0.1


@needs_core
def test_camera_motion_blur_moves_with_each_view():
    # A camera sliding and turning over the shutter: each view's steps are the camera's moved
    # by the view's offset, as a twin parented to the camera at that offset renders them.
    scene = stereo_scene('TOE', 'CENTER')
    cam = scene.camera
    for frame, x, turn in ((1, 0.4, 0.0), (2, 1.4, 0.15)):
        scene.frame_set(frame)
        cam.location.x = x
        cam.rotation_euler.z = turn
        cam.keyframe_insert("location", frame=frame)
        cam.keyframe_insert("rotation_euler", frame=frame)
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 0.8
    views = render_to_array(scene, samples=4, seed=SEED)
    scene.render.use_multiview = False
    for index, name in enumerate(("left", "right")):
        m, shift = hand_view(cam, name == "left")
        base = np.array(cam.matrix_world, np.float64)
        twin = bpy.data.objects.new(f"Twin {name}", cam.data.copy())
        scene.collection.objects.link(twin)
        twin.data.shift_x = shift
        twin.parent = cam
        twin.matrix_parent_inverse = Matrix.Identity(4)
        twin.matrix_basis = Matrix((np.linalg.inv(base) @ m).tolist())
        scene.camera = twin
        mono = render_to_array(scene, samples=4, seed=view_seed(SEED, index))
        assert_same_render(views[name], mono, f"motion blur {name}")
        scene.camera = cam
    still = stereo_scene('TOE', 'CENTER')
    assert np.abs(render_to_array(still, samples=4, seed=SEED)["left"] - views["left"]).max() > 0.05


@needs_core
def test_views_share_one_export_and_progress_counts_over_them(monkeypatch):
    import addon.session as session
    calls = []
    real = session.export_scene
    monkeypatch.setattr(session, "export_scene", lambda *a, **k: calls.append(1) or real(*a, **k))
    seen = []
    session.set_progress_listener(lambda info: seen.append(dict(info)) and False)
    try:
        render_to_array(stereo_scene(), samples=3, seed=SEED)
    finally:
        session.set_progress_listener(None)
    assert len(calls) == 1  # the second view re-exports nothing
    sampled = [i for i in seen if i.get("stage") is None]
    assert sampled[-1]["samples_total"] == 6 and sampled[-1]["samples_done"] == 6
    done = [i["samples_done"] for i in sampled]
    assert done == sorted(done) and any(0 < d <= 3 for d in done)


@needs_core
def test_multiview_cameras_blur_with_their_own_motion():
    # The right view's camera (not the scene camera) slides over the shutter: its view blurs as
    # a mono render through it does.
    scene = scene_with_objects()
    cams = {}
    for suffix, loc in (("_L", (-1.0, -4.5, 1.2)), ("_R", (1.5, -4.0, 2.0))):
        cams[suffix] = camera(loc, look_at=(0.0, 0.0, 0.5))
        cams[suffix].name = "Cam" + suffix
    moving = cams["_R"]
    for frame, x in ((1, 1.5), (2, 2.5)):
        moving.location.x = x
        moving.keyframe_insert("location", frame=frame)
    scene.frame_set(1)
    scene.camera = cams["_L"]
    scene.render.use_motion_blur = True
    scene.render.use_multiview = True
    scene.render.views_format = 'MULTIVIEW'
    views = render_to_array(scene, samples=4, seed=SEED)
    scene.render.use_multiview = False
    scene.camera = moving
    mono = render_to_array(scene, samples=4, seed=view_seed(SEED, 1))
    assert_same_render(views["right"], mono, "multiview motion blur")
    scene.render.use_motion_blur = False
    still = render_to_array(scene, samples=4, seed=view_seed(SEED, 1))
    assert np.abs(still - mono).max() > 0.05  # (it does blur)


def read_view_passes(path):
    """{pass.channel: (H, W)} of a multilayer EXR's first layer."""
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        return {k.split(".", 1)[1]: np.array(v.pixels, np.float32) for k, v in exr.channels().items() if "." in k}


@needs_core
def test_passes_are_written_per_view():
    scene = stereo_scene()
    scene.view_layers[0].use_pass_z = True
    render_to_array(scene, samples=2, seed=SEED)  # (the settings)
    image = scene.render.image_settings
    image.file_format, image.views_format = 'OPEN_EXR_MULTILAYER', 'INDIVIDUAL'
    with tempfile.TemporaryDirectory(prefix="pathlight_test_") as tmp:
        scene.render.filepath = str(Path(tmp) / "passes.exr")
        bpy.ops.render.render(write_still=True, scene=scene.name)
        files = {p.name: read_view_passes(p) for p in Path(tmp).glob("*.exr")}
    assert sorted(files) == ["passes_L.exr", "passes_R.exr"]
    left, right = files["passes_L.exr"], files["passes_R.exr"]
    depth_l, depth_r = left["Depth.Z"], right["Depth.Z"]
    assert np.isfinite(depth_l).all() and np.isfinite(depth_r).all()
    assert 1.0 < np.median(depth_l) < 20.0 and 1.0 < np.median(depth_r) < 20.0
    assert np.abs(depth_l - depth_r).max() > 0.1  # each view's own depths
    # and each equals its view's mono Depth (the hand-built camera)
    for index, (name, data) in enumerate((("left", left), ("right", right))):
        cam = scene.camera
        m, shift = hand_view(cam, name == "left")
        twin = bpy.data.objects.new(f"Hand {name}", cam.data.copy())
        scene.collection.objects.link(twin)
        twin.data.shift_x, twin.matrix_world = shift, Matrix(m.tolist())
        scene.camera, scene.render.use_multiview = twin, False
        scene.pathlight.seed = view_seed(SEED, index)
        with tempfile.TemporaryDirectory(prefix="pathlight_test_") as tmp:
            scene.render.filepath = str(Path(tmp) / "mono.exr")
            bpy.ops.render.render(write_still=True, scene=scene.name)
            mono = read_view_passes(Path(tmp) / "mono.exr")
        scene.camera, scene.render.use_multiview = cam, True
        scene.pathlight.seed = SEED
        diff = np.abs(mono["Depth.Z"] - data["Depth.Z"])
        assert (diff > 1e-3).mean() < 0.01, name


def checker_material(name, scale=6.0):
    mat = diffuse_material(name, (1.0, 1.0, 1.0))
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    checker = nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = scale
    checker.inputs["Color1"].default_value = (0.8, 0.8, 0.8, 1.0)
    checker.inputs["Color2"].default_value = (0.1, 0.1, 0.1, 1.0)
    links.new(checker.outputs["Color"], nodes["Diffuse BSDF"].inputs["Color"])
    return mat


def render_passes(scene, stem):
    """{view file name: {pass.channel: (H, W)}} of a render of `scene` through multilayer EXRs
    (one per view with multiview on)."""
    image = scene.render.image_settings
    image.file_format, image.views_format, image.color_depth = 'OPEN_EXR_MULTILAYER', 'INDIVIDUAL', '32'
    with tempfile.TemporaryDirectory(prefix="pathlight_test_") as tmp:
        scene.render.filepath = str(Path(tmp) / f"{stem}.exr")
        scene.render.use_file_extension = False
        bpy.ops.render.render(write_still=True, scene=scene.name)
        return {p.name: read_view_passes(p) for p in Path(tmp).glob("*.exr")}


@needs_core
def test_the_vector_pass_moves_with_each_view():
    # The camera sliding and turning from frame to frame: each view's motion vectors are those
    # of its own eye (the camera's steps at the frames around moved by the view's offset), as a
    # twin parented to the camera at that offset sees them.
    scene = stereo_scene('TOE', 'CENTER')
    cam = scene.camera
    for frame, x, turn in ((1, 0.0, -0.1), (2, 0.4, 0.0), (3, 0.9, 0.12)):
        cam.location.x, cam.rotation_euler.z = x, turn
        cam.keyframe_insert("location", frame=frame)
        cam.keyframe_insert("rotation_euler", frame=frame)
    scene.frame_set(2)
    scene.view_layers[0].use_pass_vector = True
    render_to_array(scene, samples=2, seed=SEED)  # (the settings)
    views = render_passes(scene, "vec")
    assert sorted(views) == ["vec_L.exr", "vec_R.exr"]
    scene.render.use_multiview = False
    for index, (name, file) in enumerate((("left", "vec_L.exr"), ("right", "vec_R.exr"))):
        m, shift = hand_view(cam, name == "left")
        twin = bpy.data.objects.new(f"Twin {name}", cam.data.copy())
        scene.collection.objects.link(twin)
        twin.data.shift_x = shift
        twin.parent = cam
        twin.matrix_parent_inverse = Matrix.Identity(4)
        twin.matrix_basis = Matrix((np.linalg.inv(np.array(cam.matrix_world, np.float64)) @ m).tolist())
        scene.camera = twin
        scene.pathlight.seed = view_seed(SEED, index)
        mono = render_passes(scene, "mono")["mono.exr"]
        scene.camera, scene.pathlight.seed = cam, SEED
        for ch in "XYZW":
            ours, want = views[file][f"Vector.{ch}"], mono[f"Vector.{ch}"]
            assert np.abs(want).max() > 0.5  # the camera moves a few pixels a frame
            assert np.abs(ours - want).max() < 1e-3, (name, ch, np.abs(ours - want).max())
    left, right = views["vec_L.exr"]["Vector.X"], views["vec_R.exr"]["Vector.X"]
    assert np.abs(left - right).max() > 0.05


def spherical_scene(width=64, height=32):
    """An equirectangular camera with spherical stereo among objects all around it, over a
    checkered floor (what the pole merge's lower rows see)."""
    scene = scene_with_objects(width, height)
    bpy.data.objects["floor"].data.materials[0] = checker_material("checker floor")
    box("back", 0.8, diffuse_material("back", (0.3, 0.8, 0.3)), location=(0.2, -5.5, 0.4))
    box("side", 0.8, diffuse_material("side", (0.8, 0.8, 0.8)), location=(-2.5, -4.0, 0.9))
    cam = camera((0.4, -3.5, 1.0), rotation=(math.pi / 2, 0.0, 0.0))
    cam.data.type, cam.data.panorama_type = 'PANO', 'EQUIRECTANGULAR'
    st = cam.data.stereo
    st.use_spherical_stereo = True
    st.interocular_distance, st.convergence_distance = 0.4, 2.0
    scene.render.use_multiview = True
    scene.render.views_format = 'STEREO_3D'
    return scene


@needs_core
def test_spherical_stereo_offsets_every_ray_not_the_camera():
    scene = spherical_scene()
    views = render_to_array(scene, samples=4, seed=SEED)
    assert np.abs(views["left"] - views["right"]).max() > 0.1
    # Not the moved camera of plain stereo (parallel here: the same view matrix per eye as
    # spherical stereo would need, the directions unturned): different images.
    scene.camera.data.stereo.use_spherical_stereo = False
    scene.camera.data.stereo.convergence_mode = 'PARALLEL'
    moved = render_to_array(scene, samples=4, seed=SEED)
    assert np.abs(views["left"] - moved["left"]).max() > 0.05


@needs_core
@pytest.mark.converged
@pytest.mark.parametrize("mode", ['OFFAXIS', 'TOE'])
def test_a_perspective_stereo_pair_agrees_with_cycles(mode):
    """Cycles at 1024 spp (stored), Pathlight at 512; pivot Center."""
    def build():
        scene = stereo_scene(mode)
        scene.render.resolution_x, scene.render.resolution_y = 48, 32
        return scene
    ours = render_to_array(build(), "PATHLIGHT", samples=512, max_bounces=8)
    cycles = render_to_array(build(), "CYCLES", samples=1024, max_bounces=8, **BOX_FILTER)
    for name in ("left", "right"):
        assert_agree(ours[name], cycles[name], f"{mode} stereo, {name}")


@needs_core
@pytest.mark.converged
def test_an_equirectangular_spherical_stereo_pair_agrees_with_cycles():
    """Cycles at 1024 spp (stored), Pathlight at 512; pole merge on from 15 to 35 degrees (low,
    so that most of the image is faded or merged: without the pole merge the worst region is
    off by 34 %, with it 0.5 %)."""
    def build():
        scene = spherical_scene()
        st = scene.camera.data.stereo
        st.use_pole_merge = True
        st.pole_merge_angle_from, st.pole_merge_angle_to = math.radians(15.0), math.radians(35.0)
        return scene
    ours = render_to_array(build(), "PATHLIGHT", samples=512, max_bounces=8)
    cycles = render_to_array(build(), "CYCLES", samples=1024, max_bounces=8, **BOX_FILTER)
    for name in ("left", "right"):
        assert_agree(ours[name], cycles[name], f"equirectangular spherical stereo, {name}")


@needs_core
def test_a_farm_merge_keeps_both_views():
    # Pieces of a stereo frame as multilayer, multiview EXRs (one file, a channel set per view):
    # `build.py merge` weighs each view's channels and keeps the view names (multiView), by
    # which Blender reads the merged file as stereo again.
    import build
    scene = stereo_scene()
    render_to_array(scene, samples=2, seed=SEED)  # (the settings)
    image = scene.render.image_settings
    image.file_format, image.views_format = 'OPEN_EXR_MULTILAYER', 'MULTIVIEW'
    with tempfile.TemporaryDirectory(prefix="pathlight_test_") as tmp:
        pieces = []
        for offset in (0, 2):
            scene.pathlight.sample_offset = offset
            scene.render.filepath = str(Path(tmp) / f"piece{offset}.exr")
            bpy.ops.render.render(write_still=True, scene=scene.name)
            pieces.append(scene.render.filepath)
        out = str(Path(tmp) / "merged.exr")
        build.merge_exr(pieces, out)
        files = []
        for path in pieces + [out]:
            with OpenEXR.File(path, separate_channels=True) as exr:
                files.append((exr.header().get("multiView"),
                              {k: np.array(v.pixels, np.float64) for k, v in exr.channels().items()}))
    (views_a, a), (_, b), (views_m, m) = files
    assert list(views_a) == list(views_m) == ["left", "right"]
    assert sorted(m) == sorted(a) and any(".right." in k for k in m)
    for k in m:
        np.testing.assert_allclose(m[k], 0.5 * (a[k] + b[k]), rtol=1e-6, atol=1e-7)
    assert np.abs(m["ViewLayer.Combined.left.R"] - m["ViewLayer.Combined.right.R"]).max() > 0.05


def test_the_in_blender_farm_merge_refuses_several_views():
    # It reads pieces through Blender's image API, which gives one view: refused, not halved.
    from addon import farm_merge
    stereo_scene()
    with pytest.raises(ValueError, match="build.py merge"):
        farm_merge.merge_frame(1, [("//a_####", 0, 2), ("//b_####", 2, 2)], "//out_####")
