"""The built-in denoiser (Sampling > Denoise, Viewport Denoise): Open Image Denoise as Blender
ships it, loaded by addon/denoise.py, driven by the render (addon/session.py) and the viewport
(addon/viewport.py). docs/design/passes.md "Denoising"."""

import logging
from pathlib import Path
import time

import bpy

import numpy as np
import pytest

from blender_util import core_available, load_addon, open_fixture, read_exr, render_multilayer_file, \
    render_to_array

load_addon()
from addon import denoise as oidn  # noqa: E402

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
needs_oidn = pytest.mark.skipif(oidn.available() is not True, reason="no Open Image Denoise library here")

# The Cornell box at 64x64 (25 %): 4 samples noisy, 1024 the reference.
NOISY_SPP, REFERENCE_SPP = 4, 1024


def cornell(**props):
    sc = open_fixture("cornell_box")
    sc.render.resolution_percentage = 25
    sc.render.engine = "PATHLIGHT"
    for name, value in props.items():
        setattr(sc.pathlight, name, value)
    return sc


def layers(sc, tmp, name="r.exr", **props):
    """The first view layer's passes, {pass: (H, W, channels)}, of a multilayer render of `sc`
    with Pathlight's render_to_array setup (no adaptive sampling, box filter) and `props`."""
    from blender_util import _setup_pathlight
    _setup_pathlight(sc.pathlight)
    for key, value in props.items():
        setattr(sc.pathlight, key, value)
    ch = render_multilayer_file(sc, tmp / name)
    out = {}
    for key in sorted(ch):
        pass_name, _, chan = key.rpartition(".")
        out.setdefault(pass_name, []).append((chan, ch[key]))
    order = {c: i for i, c in enumerate("RGBAXYZW")}
    return {p: np.stack([a for _, a in sorted(v, key=lambda t: order.get(t[0], 9))], -1) for p, v in out.items()}


def rmse(a, b):
    return float(np.sqrt(np.mean((a[..., :3].astype(np.float64) - b[..., :3]) ** 2)))


@pytest.fixture(scope="module")
def reference():
    if not core_available():
        pytest.skip("pathlight_core is not built")
    return render_to_array(cornell(), samples=REFERENCE_SPP, seed=1)


@needs_core
@needs_oidn
def test_denoised_combined_is_closer_to_the_converged_render(reference, tmp_path):
    sc = cornell(use_denoising=True)
    sc.view_layers[0].pathlight.use_pass_denoising_data = True
    out = layers(sc, tmp_path, samples=NOISY_SPP, seed=2)
    denoised, noisy = out["Combined"], out["Noisy Image"]
    sc.pathlight.use_denoising = False
    plain = render_to_array(sc, samples=NOISY_SPP, seed=2)
    # The Noisy Image pass is the undenoised render of the same seed, bit for bit.
    np.testing.assert_array_equal(noisy, plain)
    # Alpha is not denoised.
    np.testing.assert_array_equal(denoised[..., 3], noisy[..., 3])
    # The lamp (12 in every channel) and the pixels next to it are left out: their error is the
    # anti-aliasing of its edge, which the features share and no denoiser removes (with them the
    # RMSE falls only from 0.111 to 0.103).
    lamp = reference[..., :3].max(-1) > 1.5
    near = lamp.copy()
    for axis in (0, 1):
        for step in (-1, 1):
            near |= np.roll(lamp, step, axis)
    keep = ~near
    e_noisy, e_denoised = rmse(noisy[keep], reference[keep]), rmse(denoised[keep], reference[keep])
    # Measured 2026-12-07: noisy 0.0687, denoised 0.0163 (0.24x; Accurate, High, all guides).
    assert e_denoised < 0.4 * e_noisy, (e_denoised, e_noisy)


@needs_core
@needs_oidn
def test_denoised_image_is_deterministic_and_the_guides_need_no_pass(tmp_path):
    sc = cornell(use_denoising=True)
    assert not sc.view_layers[0].pathlight.use_pass_denoising_data
    sc.render.threads_mode = 'FIXED'
    a = render_to_array(sc, samples=NOISY_SPP, seed=3, threads=2)
    b = render_to_array(sc, samples=NOISY_SPP, seed=3, threads=1)  # (the film does not depend on them)
    np.testing.assert_array_equal(a, b)
    # No Denoising Data: no guide passes in the result (the Noisy Image is there, as in Cycles,
    # whenever Denoise is on), but the guides were used (an image denoised from its colour
    # alone differs).
    out = layers(sc, tmp_path, samples=NOISY_SPP, seed=3)
    assert set(out) == {"Combined", "Noisy Image"}, set(out)
    np.testing.assert_array_equal(out["Combined"], a)
    rgb_only = render_to_array(sc, samples=NOISY_SPP, seed=3, denoising_input_passes='RGB')
    assert np.abs(rgb_only - a).max() > 1e-3


@needs_core
@needs_oidn
def test_each_setting_reaches_the_denoiser(monkeypatch):
    sc = cornell(use_denoising=True)
    seen = []
    real = oidn.denoise

    def spy(color, albedo=None, normal=None, prefilter='ACCURATE', quality='HIGH', **kw):
        seen.append((albedo is not None, normal is not None, prefilter, quality))
        return real(color, albedo, normal, prefilter=prefilter, quality=quality, **kw)

    monkeypatch.setattr(oidn, "denoise", spy)
    images = {}
    for key, value in (("denoising_input_passes", 'RGB_ALBEDO_NORMAL'), ("denoising_input_passes", 'RGB_ALBEDO'),
                       ("denoising_input_passes", 'RGB'), ("denoising_prefilter", 'FAST'),
                       ("denoising_prefilter", 'NONE'), ("denoising_quality", 'BALANCED'),
                       ("denoising_quality", 'FAST')):
        sc = cornell(use_denoising=True)
        images[value] = render_to_array(sc, samples=NOISY_SPP, seed=2, **{key: value})
    assert seen == [(True, True, 'ACCURATE', 'HIGH'), (True, False, 'ACCURATE', 'HIGH'),
                    (False, False, 'ACCURATE', 'HIGH'), (True, True, 'FAST', 'HIGH'),
                    (True, True, 'NONE', 'HIGH'), (True, True, 'ACCURATE', 'BALANCED'),
                    (True, True, 'ACCURATE', 'FAST')]
    base = images['RGB_ALBEDO_NORMAL']
    # What OIDN makes of them differs (BALANCED is High's network on this CPU: not compared).
    for other in ('RGB_ALBEDO', 'RGB', 'FAST', 'NONE'):
        assert np.abs(images[other] - base).max() > 1e-4, other
    assert np.abs(images['RGB_ALBEDO'] - images['RGB']).max() > 1e-4


@needs_core
def test_missing_library_warns_and_keeps_the_noisy_image(monkeypatch, caplog):
    sc = cornell()
    plain = render_to_array(sc, samples=NOISY_SPP, seed=2)

    def missing():
        raise oidn.DenoiseError("Open Image Denoise (test) could not be loaded")

    monkeypatch.setattr(oidn, "load_library", missing)
    oidn.reset()
    try:
        with caplog.at_level(logging.WARNING, logger="addon.session"):
            got = render_to_array(sc, samples=NOISY_SPP, seed=2, use_denoising=True)
    finally:
        monkeypatch.undo()
        oidn.reset()
    np.testing.assert_array_equal(got, plain)
    assert any("not denoised" in r.getMessage() and "could not be loaded" in r.getMessage()
               for r in caplog.records), [r.getMessage() for r in caplog.records]


@needs_core
def test_a_failing_denoise_warns_and_keeps_the_noisy_image(monkeypatch, caplog):
    sc = cornell()
    plain = render_to_array(sc, samples=NOISY_SPP, seed=2)

    def failing(*a, **kw):
        raise oidn.DenoiseError("Open Image Denoise failed denoising (64x64): out of memory")

    monkeypatch.setattr(oidn, "denoise", failing)
    with caplog.at_level(logging.WARNING, logger="addon.session"):
        got = render_to_array(sc, samples=NOISY_SPP, seed=2, use_denoising=True)
    np.testing.assert_array_equal(got, plain)
    assert any("out of memory" in r.getMessage() for r in caplog.records)


@needs_core
def test_a_piece_of_a_split_frame_is_not_denoised(caplog):
    sc = cornell()
    plain = render_to_array(sc, samples=NOISY_SPP, seed=2, sample_offset=4)
    with caplog.at_level(logging.INFO, logger="addon.session"):
        got = render_to_array(sc, samples=NOISY_SPP, seed=2, sample_offset=4, use_denoising=True)
        np.testing.assert_array_equal(got, plain)
        # Offset 0 but Frame Samples beyond this piece: a piece too.
        first = render_to_array(sc, samples=NOISY_SPP, seed=2, sample_offset=0, frame_samples=8)
    sc.pathlight.use_denoising = False
    np.testing.assert_array_equal(first, render_to_array(sc, samples=NOISY_SPP, seed=2))
    assert any("split frame" in r.getMessage() for r in caplog.records)


@needs_oidn
def test_denoise_in_place_keeps_alpha_and_survives_odd_sizes():
    rng = np.random.default_rng(1)
    clean = np.zeros((24, 40, 4), np.float32)
    clean[..., :3] = np.linspace(0.1, 1.0, 40)[None, :, None]
    clean[..., 3] = np.linspace(0.0, 1.0, 24)[:, None]
    noisy = clean + np.concatenate([rng.normal(0, 0.2, (24, 40, 3)), np.zeros((24, 40, 1))], -1).astype(np.float32)
    img = noisy.copy()
    oidn.denoise(img, prefilter='NONE')
    np.testing.assert_array_equal(img[..., 3], clean[..., 3])
    assert rmse(img, clean) < 0.3 * rmse(noisy, clean)
    # RGB (3 channels) and RGBA strides give the same denoise.
    rgb = np.ascontiguousarray(noisy[..., :3])
    oidn.denoise(rgb, prefilter='NONE')
    np.testing.assert_array_equal(rgb, img[..., :3])
    albedo = np.full((24, 40, 3), 0.5, np.float32)
    guided = noisy.copy()
    oidn.denoise(guided, albedo, prefilter='NONE')
    assert not np.array_equal(guided, img)
    np.testing.assert_array_equal(albedo, 0.5)  # the caller's guide is never changed
    for shape in ((1, 1, 4), (1, 7, 3), (5, 1, 4), (0, 3, 4)):  # no crash, no error
        oidn.denoise(np.ones(shape, np.float32))
    with pytest.raises(ValueError):
        oidn.denoise(np.ones((4, 4, 4), np.float64))
    with pytest.raises(ValueError):
        oidn.denoise(np.ones((4, 4, 4), np.float32), np.ones((4, 5, 3), np.float32))
    with pytest.raises(ValueError):
        oidn.denoise(np.ones((4, 4, 4), np.float32)[:, ::2])


def test_library_is_found_beside_bpy():
    found = oidn.library_candidates()
    assert found, "no libOpenImageDenoise in this process or beside bpy / Blender"
    assert all(p.is_file() for p in found)
    assert any(p.parent.name == "lib" and p.parent.parent.name == "bpy" for p in found), found
    if oidn.available() is True:  # once loaded, the copy in the process comes first
        loaded = oidn._loaded_copy()
        assert loaded is not None and oidn.library_candidates()[0] == Path(loaded)


class _FakeSession:
    """What ViewportSession.display reads of a core Session, with a sample count the test sets."""

    def __init__(self, film):
        self.done, self.finished, self._film = 0, False, film

    def progress(self):
        return {"samples_done": self.done}

    def film(self):
        return self._film.copy()

    def film_pass(self, name):
        return np.full(self._film.shape[:2] + (3,), 0.5 if "Albedo" in name else 0.0, np.float32)

    def is_finished(self):
        return self.finished


@needs_oidn
def test_viewport_denoises_from_its_start_sample_when_the_samples_double():
    from addon.viewport import ViewportSession
    rng = np.random.default_rng(2)
    film = np.concatenate([rng.random((16, 16, 3)), np.ones((16, 16, 1))], -1).astype(np.float32)
    vs = ViewportSession(pc=None)
    vs.denoise_async = False  # (the rule, in the draw call; the worker thread: below)
    vs.denoiser = {"input_passes": 'RGB_ALBEDO', "prefilter": 'FAST', "quality": 'BALANCED'}
    vs.denoise_start = 3
    vs.full = fake = _FakeSession(film)
    shown = []
    for done, finished in ((1, False), (2, False), (3, False), (4, False), (5, False), (6, False),
                           (7, False), (7, True), (7, True)):
        fake.done, fake.finished = done, finished
        image, n = vs.display()
        shown.append((n, vs.counters["denoises"], bool(np.array_equal(image, film))))
    # Noisy before sample 3; denoised at 3, 6 (doubled) and the last (7, finished); in between
    # the last denoised image.
    assert shown == [(1, 0, True), (2, 0, True), (3, 1, False), (4, 1, False), (5, 1, False),
                     (6, 2, False), (7, 2, False), (7, 3, False), (7, 3, False)]
    expected = film.copy()
    oidn.denoise(expected, np.full((16, 16, 3), 0.5, np.float32), prefilter='FAST', quality='BALANCED')
    np.testing.assert_array_equal(vs.display()[0], expected)


@needs_core
@needs_oidn
def test_viewport_session_renders_the_guides_and_denoises():
    from addon.core import get_core
    from addon.viewport import ViewportSession
    sc = cornell(preview_samples=4, use_preview_denoising=True, preview_denoising_start_sample=2)
    vs = ViewportSession(get_core())
    vs.set_view(None, 24, 24)  # tiny: no low-resolution pass
    vs.sync(bpy.context.evaluated_depsgraph_get())
    try:
        deadline = time.monotonic() + 120.0  # (by time, not by count: a loaded machine is slow)
        while time.monotonic() < deadline:  # as view_draw: poll, then display; denoises on a worker thread
            if not vs.poll():
                break
            vs.display()
            vs.full.wait(0.05)
            time.sleep(0.005)
        assert not vs.denoising()
        image, n = vs.display()
        # The last sample's image denoised (and maybe an earlier one on the way).
        assert n == 4 and vs.counters["denoises"] >= 1 and vs._denoised[1] == 4
        assert not np.array_equal(image, vs.full.film())
        assert vs.full.film_pass("Denoising Albedo").shape == (24, 24, 3)
    finally:
        vs.free()


def test_panels_draw_the_denoise_settings():
    from blender_util import RecordingLayout
    from addon import ui
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    context = type("Ctx", (), {"scene": bpy.context.scene, "engine": "PATHLIGHT"})
    shown = []
    for cls in (ui.PATHLIGHT_RENDER_PT_sampling_denoise, ui.PATHLIGHT_RENDER_PT_sampling_viewport_denoise):
        for method in ("draw_header", "draw"):
            layout = RecordingLayout()
            getattr(cls, method)(type("Panel", (), {"layout": layout})(), context)
            shown += layout.props
    assert shown == ["use_denoising", "denoising_input_passes", "denoising_prefilter", "denoising_quality",
                     "use_preview_denoising", "preview_denoising_input_passes", "preview_denoising_prefilter",
                     "preview_denoising_quality", "preview_denoising_start_sample"]
    props = bpy.context.scene.pathlight
    assert not props.use_denoising and not props.use_preview_denoising  # off by default (for now)
    assert (props.denoising_input_passes, props.denoising_prefilter, props.denoising_quality) == \
        ('RGB_ALBEDO_NORMAL', 'ACCURATE', 'HIGH')


@needs_oidn
def test_in_blender_merge_denoises_the_merged_frame(tmp_path):
    from addon.farm_merge import merge_pieces
    rng = np.random.default_rng(3)
    paths = []
    for k in range(2):
        img = bpy.data.images.new(f"p{k}", 32, 16, alpha=True, float_buffer=True)
        img.colorspace_settings.name = 'Non-Color'
        px = np.concatenate([0.5 + rng.normal(0, 0.2, (16, 32, 3)), np.ones((16, 32, 1))], -1)
        img.pixels.foreach_set(px.astype(np.float32).ravel())
        img.filepath_raw, img.file_format = str(tmp_path / f"p{k}.exr"), 'OPEN_EXR'
        img.save()
        bpy.data.images.remove(img)
        paths.append(str(tmp_path / f"p{k}.exr"))
    merge_pieces([(paths[0], 0, 2), (paths[1], 2, 2)], str(tmp_path / "plain.exr"))
    merge_pieces([(paths[0], 0, 2), (paths[1], 2, 2)], str(tmp_path / "den.exr"),
                 denoise={"input_passes": 'RGB_ALBEDO_NORMAL', "prefilter": 'ACCURATE', "quality": 'HIGH'})
    plain, den = read_exr(tmp_path / "plain.exr"), read_exr(tmp_path / "den.exr")
    assert np.std(den[..., :3]) < 0.5 * np.std(plain[..., :3])
    np.testing.assert_array_equal(den[..., 3], plain[..., 3])


@needs_oidn
def test_build_py_merge_denoises_with_the_merged_guides(tmp_path):
    import subprocess
    import sys
    import OpenEXR
    from blender_util import REPO
    rng = np.random.default_rng(4)
    h, w = 24, 32
    wall = np.zeros((h, w, 3), np.float32)
    wall[:, w // 2:] = 1.0  # two walls of different albedo: the guide keeps the edge
    files = []
    for k in range(2):
        rgba = np.concatenate([0.1 + 0.5 * wall + rng.normal(0, 0.15, (h, w, 3)), np.ones((h, w, 1))], -1)
        ch = {f"ViewLayer.Combined.{c}": rgba[..., i] for i, c in enumerate("RGBA")}
        ch.update({f"ViewLayer.Denoising Albedo.{c}": 0.1 + 0.8 * wall[..., i] for i, c in enumerate("RGB")})
        ch.update({f"ViewLayer.Denoising Normal.{c}": np.full((h, w), float(c == "Z")) for c in "XYZ"})
        path = tmp_path / f"p{k}.exr"
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "Pathlight Samples": "2",
                      "Pathlight Sample Offset": str(2 * k)},
                     {n: np.ascontiguousarray(v, np.float32) for n, v in ch.items()}).write(str(path))
        files.append(str(path))

    def merge(out, *extra):
        proc = subprocess.run([sys.executable, str(REPO / "build.py"), "merge", *files, "-o", str(out), *extra],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        with OpenEXR.File(str(out)) as f:
            return proc.stdout, np.array(f.channels()["ViewLayer.Combined"].pixels)

    _, plain = merge(tmp_path / "plain.exr")
    log_text, den = merge(tmp_path / "den.exr", "--denoise")
    assert "colour + albedo + normal" in log_text, log_text
    truth = 0.1 + 0.5 * wall
    assert rmse(den, truth) < 0.5 * rmse(plain, truth), (rmse(den, truth), rmse(plain, truth))
    np.testing.assert_array_equal(den[..., 3], plain[..., 3])


@needs_core
@needs_oidn
def test_each_stereo_view_is_denoised(monkeypatch):
    sc = cornell()
    sc.render.use_multiview = True
    sc.render.views_format = 'STEREO_3D'
    sc.camera.data.stereo.interocular_distance = 0.2
    noisy = render_to_array(sc, samples=NOISY_SPP, seed=2)
    shapes = []
    real = oidn.denoise

    def spy(color, *a, **kw):
        shapes.append(color.shape)
        return real(color, *a, **kw)

    monkeypatch.setattr(oidn, "denoise", spy)
    denoised = render_to_array(sc, samples=NOISY_SPP, seed=2, use_denoising=True)
    assert set(denoised) == {"left", "right"} and len(shapes) == 2
    for view in ("left", "right"):
        assert np.abs(denoised[view] - noisy[view]).max() > 1e-3, view
        np.testing.assert_array_equal(denoised[view][..., 3], noisy[view][..., 3])
    assert not np.array_equal(denoised["left"], denoised["right"])


@needs_core
@needs_oidn
def test_a_cancelled_render_is_denoised_too(tmp_path):
    from addon import session
    sc = cornell(use_denoising=True)
    sc.view_layers[0].pathlight.use_pass_denoising_data = True
    session.set_progress_listener(lambda info: info.get("samples_done", 0) >= 1)  # Esc after a sample
    try:
        out = layers(sc, tmp_path, samples=100000, seed=2)
    finally:
        session.set_progress_listener(None)
    denoised, noisy = out["Combined"], out["Noisy Image"]
    assert noisy[..., :3].max() > 0
    assert np.abs(denoised[..., :3] - noisy[..., :3]).max() > 1e-3
    np.testing.assert_array_equal(denoised[..., 3], noisy[..., 3])


def test_compositor_shows_the_noisy_sockets():
    sc = cornell()
    sc.use_nodes = True
    rl = sc.node_tree.nodes.new("CompositorNodeRLayers")
    names = lambda: {s.name for s in rl.outputs if s.enabled}  # noqa: E731
    vl = sc.view_layers[0].pathlight
    vl.use_pass_denoising_data = True
    rl.update()
    assert "Denoising Albedo" in names() and "Noisy Image" not in names()
    sc.pathlight.use_denoising = True  # (its update requeries the passes, as Cycles')
    rl.update()
    assert "Noisy Image" in names() and "Noisy Shadow Catcher" not in names()
    # As Cycles' engine.py: Noisy Image whenever Denoise is on, Denoising Data or not; Noisy
    # Shadow Catcher with the Shadow Catcher pass.
    vl.use_pass_denoising_data = False
    vl.use_pass_shadow_catcher = True
    rl.update()
    assert {"Noisy Image", "Noisy Shadow Catcher", "Shadow Catcher"} <= names()
    assert "Denoising Albedo" not in names()
    sc.pathlight.use_denoising = False
    rl.update()
    assert "Noisy Image" not in names() and "Noisy Shadow Catcher" not in names()


@needs_oidn
def test_cancel_stops_the_filter_and_keeps_the_image():
    rng = np.random.default_rng(5)
    noisy = rng.random((256, 256, 4)).astype(np.float32)
    polls = []

    def cancel_soon():  # polled by the library while it filters
        polls.append(1)
        return len(polls) > 2

    img = noisy.copy()
    with pytest.raises(oidn.DenoiseCancelled):
        oidn.denoise(img, cancel=cancel_soon)
    assert len(polls) > 2  # the library polled it (not only the check before executing)
    np.testing.assert_array_equal(img, noisy)
    with pytest.raises(oidn.DenoiseCancelled):
        oidn.denoise(img, cancel=lambda: True)
    np.testing.assert_array_equal(img, noisy)
    done = noisy.copy()
    oidn.denoise(done, cancel=lambda: False)
    plain = noisy.copy()
    oidn.denoise(plain)
    np.testing.assert_array_equal(done, plain)


@needs_oidn
def test_non_finite_values_are_zeroed_before_denoising(caplog):
    rng = np.random.default_rng(9)
    img = (0.5 + rng.normal(0, 0.1, (32, 32, 4))).astype(np.float32)
    zeroed = img.copy()
    zeroed[10, 10, 0] = zeroed[20, 5, 1] = zeroed[3, 30, 2] = 0.0
    oidn.denoise(zeroed, prefilter='NONE')
    for bad in (np.inf, np.nan, -np.inf):
        got = img.copy()
        got[10, 10, 0] = got[20, 5, 1] = got[3, 30, 2] = bad
        with caplog.at_level(logging.WARNING, logger="addon.denoise"):
            oidn.denoise(got, prefilter='NONE')
        # As Cycles' film, which keeps no non-finite value: 0 there. (Unchanged, the library
        # reads NaN as 0 but spreads one +inf over the whole image: 2750 of 4096 pixels off by
        # more than 1 in a 64x64 test.)
        np.testing.assert_array_equal(got, zeroed)
        assert any("3 non-finite" in r.getMessage() for r in caplog.records)
        caplog.clear()
    # Non-finite guides too (the caller's guide is not changed).
    albedo = np.full((32, 32, 3), 0.5, np.float32)
    bad_albedo = albedo.copy()
    bad_albedo[7, 7] = np.inf
    a, b = img.copy(), img.copy()
    oidn.denoise(a, bad_albedo, prefilter='NONE')
    albedo[7, 7] = 0.0
    oidn.denoise(b, albedo, prefilter='NONE')
    np.testing.assert_array_equal(a, b)
    assert np.isinf(bad_albedo[7, 7]).all()


def test_material_previews_are_not_denoised_as_cycles():
    # Cycles reads a material preview's Denoise from Blender's built-in preview scene, whose
    # cycles.use_denoising is stored off (docs/design/passes.md); Pathlight's previews likewise
    # skip the denoiser and its passes whatever the user's scene says.
    from addon import session
    sc = cornell(use_denoising=True)

    class Engine:
        is_preview = True

    class Final:
        is_preview = False

    assert session.render_denoiser(sc, Engine(), print) is None
    assert session.render_denoiser(sc, Final(), print) is not None
    sc.pathlight.use_denoising = False
    assert session.render_denoiser(sc, Final(), print) is None


@needs_core
@needs_oidn
def test_light_groups_and_shader_aovs_are_not_denoised(tmp_path):
    sc = cornell()
    vl = sc.view_layers[0]
    vl.lightgroups.add(name="lamp")
    sc.objects["Light"].lightgroup = "lamp"  # (the emissive ceiling lamp)
    aov = vl.aovs.add()
    aov.name, aov.type = "shade", 'COLOR'
    mat = bpy.data.materials["White"]
    node = mat.node_tree.nodes.new("ShaderNodeOutputAOV")
    node.aov_name = "shade"
    node.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    plain = layers(sc, tmp_path, "plain.exr", samples=NOISY_SPP, seed=2)
    den = layers(sc, tmp_path, "den.exr", samples=NOISY_SPP, seed=2, use_denoising=True)
    assert {"Combined_lamp", "shade"} <= set(den)
    assert plain["Combined_lamp"].max() > 0 and plain["shade"].max() > 0
    # As Cycles (Pass::get_info: support_denoise only for Combined, not a light group's, and
    # the shadow catcher passes): these stay as rendered; Combined is denoised.
    for name in ("Combined_lamp", "shade"):
        np.testing.assert_array_equal(den[name], plain[name])
    assert np.abs(den["Combined"] - plain["Combined"]).max() > 1e-3


@needs_core
def test_an_unexpected_error_while_denoising_keeps_the_noisy_image(monkeypatch, caplog):
    # numpy's own copies of a huge frame can fail where the library would not: MemoryError is
    # no DenoiseError, and still only a warning.
    sc = cornell()
    plain = render_to_array(sc, samples=NOISY_SPP, seed=2)

    def no_memory(*a, **kw):
        raise MemoryError("Unable to allocate 7.9 GiB for an array")

    monkeypatch.setattr(oidn, "denoise_film", no_memory)
    with caplog.at_level(logging.WARNING, logger="addon.session"):
        got = render_to_array(sc, samples=NOISY_SPP, seed=2, use_denoising=True)
    np.testing.assert_array_equal(got, plain)
    assert any("not denoised" in r.getMessage() and "MemoryError" in r.getMessage() for r in caplog.records)


@needs_oidn
def test_esc_while_denoising_keeps_the_noisy_image(caplog):
    from addon import session
    rng = np.random.default_rng(10)
    film = rng.random((320, 320, 4)).astype(np.float32)  # (seconds of filtering: Esc comes first)

    class Engine:  # Esc is down from the start: the worker's filter stops at its next poll
        def __init__(self):
            self.breaks = 0

        def test_break(self):
            self.breaks += 1
            return True

        def update_stats(self, *a):
            pass

    warnings = []
    engine = Engine()
    with caplog.at_level(logging.INFO, logger="addon.session"):
        out = session._denoised(engine, _FakeSession(film), film, {"input_passes": 'RGB_ALBEDO_NORMAL',
                                "prefilter": 'ACCURATE', "quality": 'HIGH'}, warnings.append)
    assert out is None and not warnings
    assert engine.breaks >= 1
    assert any("denoising cancelled" in r.getMessage() for r in caplog.records)


@needs_oidn
def test_build_py_merge_denoises_the_shadow_catcher_pass_as_cycles(tmp_path):
    import subprocess
    import sys
    import OpenEXR
    from blender_util import REPO
    rng = np.random.default_rng(11)
    h, w = 24, 32
    wall = np.zeros((h, w, 3), np.float32)
    wall[:, w // 2:] = 1.0
    shadow = np.ones((h, w, 3), np.float32)
    shadow[6:18, 8:20] = 0.4  # a shadow on the catcher
    files, pieces = [], []
    for k in range(2):
        rgba = np.concatenate([0.1 + 0.5 * wall + rng.normal(0, 0.15, (h, w, 3)), np.ones((h, w, 1))], -1)
        sc = shadow + rng.normal(0, 0.15, (h, w, 3))
        ch = {f"ViewLayer.Combined.{c}": rgba[..., i] for i, c in enumerate("RGBA")}
        ch.update({f"ViewLayer.Shadow Catcher.{c}": sc[..., i] for i, c in enumerate("RGB")})
        ch.update({f"ViewLayer.Noisy Shadow Catcher.{c}": sc[..., i] for i, c in enumerate("RGB")})
        ch.update({f"ViewLayer.Combined_key.{c}": rgba[..., i] for i, c in enumerate("RGB")})  # (a light group)
        ch.update({f"ViewLayer.Denoising Albedo.{c}": 0.1 + 0.8 * wall[..., i] for i, c in enumerate("RGB")})
        ch.update({f"ViewLayer.Denoising Normal.{c}": np.full((h, w), float(c == "Z")) for c in "XYZ"})
        path = tmp_path / f"p{k}.exr"
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "Pathlight Samples": "2",
                      "Pathlight Sample Offset": str(2 * k)},
                     {n: np.ascontiguousarray(v, np.float32) for n, v in ch.items()}).write(str(path))
        files.append(str(path))
        pieces.append((rgba.astype(np.float32), sc.astype(np.float32)))

    def merge(out, *extra):
        proc = subprocess.run([sys.executable, str(REPO / "build.py"), "merge", *files, "-o", str(out), *extra],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        with OpenEXR.File(str(out)) as f:
            chans = f.channels()
            return proc.stdout, {n: np.array(chans[f"ViewLayer.{n}"].pixels)
                                 for n in ("Combined", "Shadow Catcher", "Noisy Shadow Catcher", "Combined_key")}

    _, plain = merge(tmp_path / "plain.exr")
    log_text, den = merge(tmp_path / "den.exr", "--denoise")
    assert "with its Shadow Catcher pass" in log_text, log_text
    assert rmse(den["Shadow Catcher"], shadow) < 0.5 * rmse(plain["Shadow Catcher"], shadow)
    np.testing.assert_array_equal(den["Noisy Shadow Catcher"], plain["Noisy Shadow Catcher"])
    np.testing.assert_array_equal(den["Combined_key"], plain["Combined_key"])  # (light groups: as Cycles, not)
    # Exactly Cycles' recipe on the merged planes: the guides prefiltered once, the catcher
    # with the normal and a 0.5 albedo, Combined as before.
    comb, sc = plain["Combined"].astype(np.float32).copy(), plain["Shadow Catcher"].astype(np.float32).copy()
    albedo = 0.1 + 0.8 * wall
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 2] = 1.0
    oidn.denoise_many([(comb, True), (sc, False)], albedo, normal)
    np.testing.assert_array_equal(den["Shadow Catcher"], sc)
    np.testing.assert_array_equal(den["Combined"], comb)


def test_viewport_and_farm_merge_without_the_library_keep_the_noisy_image(monkeypatch, tmp_path, capsys):
    from addon.farm_merge import merge_pieces
    from addon.viewport import ViewportSession
    rng = np.random.default_rng(12)
    film = np.concatenate([rng.random((16, 16, 3)), np.ones((16, 16, 1))], -1).astype(np.float32)

    def missing():
        raise oidn.DenoiseError("Open Image Denoise (test) could not be loaded")

    monkeypatch.setattr(oidn, "load_library", missing)
    oidn.reset()
    try:
        vs = ViewportSession(pc=None)
        vs.denoise_async = False
        warnings = []
        vs.warn = warnings.append
        vs.denoiser = {"input_passes": 'RGB_ALBEDO', "prefilter": 'FAST', "quality": 'BALANCED', "catcher": None}
        vs.denoise_start = 1
        vs.full = fake = _FakeSession(film)
        fake.done = 2
        for _ in range(3):  # the noisy film, one warning, no more tries
            image, n = vs.display()
            np.testing.assert_array_equal(image, film)
        assert vs.denoiser is None and len(warnings) == 1 and "could not be loaded" in warnings[0], warnings
        # The in-Blender farm merge: the merged frame as merged, and a line saying why.
        img = bpy.data.images.new("piece", 16, 16, alpha=True, float_buffer=True)
        img.colorspace_settings.name = 'Non-Color'
        img.pixels.foreach_set(film.ravel())
        img.filepath_raw, img.file_format = str(tmp_path / "p.exr"), 'OPEN_EXR'
        img.save()
        bpy.data.images.remove(img)
        merge_pieces([(str(tmp_path / "p.exr"), 0, 2)], str(tmp_path / "plain.exr"))
        merge_pieces([(str(tmp_path / "p.exr"), 0, 2)], str(tmp_path / "den.exr"),
                     denoise={"input_passes": 'RGB', "prefilter": 'NONE', "quality": 'HIGH'})
    finally:
        monkeypatch.undo()
        oidn.reset()
    np.testing.assert_array_equal(read_exr(tmp_path / "den.exr"), read_exr(tmp_path / "plain.exr"))
    assert "not denoised" in capsys.readouterr().out


@needs_core
def test_a_view_layer_with_denoising_off_is_not_denoised(tmp_path):
    from blender_util import RecordingLayout
    from addon import ui
    sc = cornell(use_denoising=True)
    plain = layers(sc, tmp_path, "plain.exr", samples=NOISY_SPP, seed=2, use_denoising=False)
    vl = sc.view_layers[0]
    assert vl.pathlight.use_denoising and vl.cycles.use_denoising  # (on by default, as Cycles')
    for owner in (vl.pathlight, vl.cycles):  # Pathlight's switch, or Cycles' own (View Layer ▸ Denoising)
        owner.use_denoising = False
        out = layers(sc, tmp_path, "off.exr", samples=NOISY_SPP, seed=2, use_denoising=True)
        owner.use_denoising = True
        assert set(out) == {"Combined"}, set(out)  # (no Noisy Image either, as Cycles)
        np.testing.assert_array_equal(out["Combined"], plain["Combined"])
    layout = RecordingLayout()
    context = type("Ctx", (), {"view_layer": vl})
    ui.PATHLIGHT_VIEWLAYER_PT_denoising.draw_header(type("Panel", (), {"layout": layout})(), context)
    assert layout.props == ["use_denoising"]
