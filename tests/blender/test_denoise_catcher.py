"""Denoising with shadow catchers, as Cycles 4.5 does it (integrator/denoiser_oidn.cpp): the
Shadow Catcher Matte denoised with the guides, the Shadow Catcher pass with the normal and a
constant 0.5 albedo, Combined composed again from them (the approximate composite, and the
world behind the catcher on an opaque film, as rendered); the Noisy Image and Noisy Shadow
Catcher passes the undenoised ones. docs/design/passes.md "Denoising"."""

import math

import bpy
import numpy as np
import pytest

from blender_util import canonical_order, core_available, empty_scene_with_camera, load_addon, node_material, \
    render_multilayer_file

load_addon()
from addon import denoise as oidn  # noqa: E402

pytestmark = [pytest.mark.skipif(not core_available(), reason="pathlight_core is not built"),
              pytest.mark.skipif(oidn.available() is not True, reason="no Open Image Denoise library here")]

NOISY_SPP, REFERENCE_SPP = 4, 1024
LAYER = "ViewLayer"


def catcher_scene():
    """A diffuse ball on a diffuse catcher plane under a sun and an area light, a grey world
    (test_shadow_catcher.py's scene, smaller and with a plain world), 48x48, box filter."""
    import bmesh
    sc = empty_scene_with_camera(48)
    sc.camera.location = (0.0, -5.0, 2.5)
    sc.camera.rotation_euler = (math.radians(65), 0.0, 0.0)
    bpy.ops.mesh.primitive_plane_add(size=8, location=(0, 0, -1))
    floor = bpy.context.active_object
    floor.data.materials.append(node_material("Floor", "ShaderNodeBsdfDiffuse", Color=(0.7, 0.7, 0.7, 1)))
    floor.is_shadow_catcher = True
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=0.8, location=(0.3, 0.4, -0.2))
    ball = bpy.context.active_object
    bm = bmesh.new()
    bm.from_mesh(ball.data)
    canonical_order(bm)  # (the same triangles in every process)
    bm.to_mesh(ball.data)
    bm.free()
    ball.data.materials.append(node_material("Ball", "ShaderNodeBsdfDiffuse", Color=(0.8, 0.3, 0.2, 1)))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.data.energy = 2.0
    sun.data.angle = math.radians(8)
    sun.rotation_euler = (math.radians(30), math.radians(-25), 0)
    sc.collection.objects.link(sun)
    area = bpy.data.objects.new("Area", bpy.data.lights.new("Area", 'AREA'))
    area.data.energy = 150.0
    area.data.size = 2.0
    area.location = (2.5, -1.5, 3.0)
    area.rotation_euler = (math.radians(40), 0, math.radians(60))
    sc.collection.objects.link(area)
    sc.world = bpy.data.worlds.new("Grey")
    sc.world.color = (0.3, 0.3, 0.3)
    sc.render.engine = "PATHLIGHT"
    p = sc.pathlight
    p.use_adaptive_sampling, p.filter_type, p.filter_width, p.max_bounces = False, 'BOX', 1.0, 8
    return sc


def configure(sc, transparent, pass_on, denoise, samples, seed):
    sc.render.film_transparent = transparent
    sc.view_layers[0].pathlight.use_pass_shadow_catcher = pass_on
    p = sc.pathlight
    p.use_denoising, p.samples, p.seed = denoise, samples, seed


def render_passes(sc, path):
    """{pass: (H, W, channels)} of the first view layer, image order (row 0 = top)."""
    ch = render_multilayer_file(sc, path)
    out = {}
    for key in sorted(ch):
        name, _, c = key.rpartition(".")
        out.setdefault(name, []).append((c, ch[key]))
    order = {c: i for i, c in enumerate("RGBAXYZ")}
    return {n: np.stack([a for _, a in sorted(v, key=lambda t: order.get(t[0], 9))], -1) for n, v in out.items()}


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))


def core_film(sc, passes):
    """(session, film) of the scene through the add-on's export and settings, rendered to the
    end by a core Session with `passes`: as the render does, for a look at the planes."""
    from addon import session
    from addon.core import get_core
    from addon.export import export_scene
    from addon.scene_writer import to_core
    pc = get_core()
    warnings = []
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings.append)
    settings = session.render_settings(pc, sc)
    settings.passes = list(passes)
    sess = pc.Session(to_core(pc, data, warnings.append), settings)
    sess.start()
    while not sess.wait(1.0):
        pass
    return sess, sess.film()


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The converged passes (REFERENCE_SPP, no denoise): transparent film with the Shadow
    Catcher pass (Combined = the matte), and the opaque film's composite."""
    sc = catcher_scene()
    tmp = tmp_path_factory.mktemp("catcher_ref")
    configure(sc, True, True, False, REFERENCE_SPP, 1)
    out = render_passes(sc, tmp / "matte.exr")
    configure(sc, False, False, False, REFERENCE_SPP, 1)
    out["Opaque"] = render_passes(sc, tmp / "opaque.exr")["Combined"]
    configure(sc, True, False, False, REFERENCE_SPP, 1)
    out["Approximate"] = render_passes(sc, tmp / "approx.exr")["Combined"]
    return out


def test_shadow_catcher_pass_and_matte_are_denoised(reference, tmp_path):
    sc = catcher_scene()
    configure(sc, True, True, True, NOISY_SPP, 2)
    den = render_passes(sc, tmp_path / "den.exr")
    assert set(den) == {"Combined", "Shadow Catcher", "Noisy Image", "Noisy Shadow Catcher"}, set(den)
    configure(sc, True, True, False, NOISY_SPP, 2)
    plain = render_passes(sc, tmp_path / "plain.exr")
    # The noisy passes are the render without Denoise, bit for bit (as Cycles').
    np.testing.assert_array_equal(den["Noisy Image"], plain["Combined"])
    np.testing.assert_array_equal(den["Noisy Shadow Catcher"], plain["Shadow Catcher"])
    # The Shadow Catcher pass's noise falls. Measured 2026-12-07 (seeds 2, 3, 4): RMSE against
    # the converged pass 0.050 -> 0.029 (0.58x), 0.61x, 0.63x; Cycles 4.5 on this scene at the
    # same samples against its own converged pass: 0.52x, 0.53x (what is left is mostly the
    # ball's anti-aliased edge, which no denoiser removes).
    e_noisy = rmse(plain["Shadow Catcher"], reference["Shadow Catcher"])
    e_den = rmse(den["Shadow Catcher"], reference["Shadow Catcher"])
    assert e_den < 0.75 * e_noisy, (e_den, e_noisy)
    # Combined is the matte (the pass is on): its colour denoised (measured 0.57x-0.59x;
    # Cycles 0.61x, 0.73x), its alpha as rendered.
    e_noisy = rmse(plain["Combined"][..., :3], reference["Combined"][..., :3])
    e_den = rmse(den["Combined"][..., :3], reference["Combined"][..., :3])
    assert e_den < 0.75 * e_noisy, (e_den, e_noisy)
    np.testing.assert_array_equal(den["Combined"][..., 3], plain["Combined"][..., 3])


@pytest.mark.parametrize("transparent", [True, False], ids=["approximate", "over_background"])
def test_composite_is_made_of_the_denoised_planes(reference, tmp_path, transparent):
    sc = catcher_scene()
    configure(sc, transparent, False, False, NOISY_SPP, 2)
    mode = 'APPROXIMATE' if transparent else 'OVER_BACKGROUND'
    guides = oidn.aux_passes('RGB_ALBEDO_NORMAL')
    assert oidn.catcher_mode(guides, transparent) == mode
    sess, film = core_film(sc, guides)
    # Composing the film's noisy planes here gives the core's Combined (to float rounding).
    planes = {name: sess.film_pass(name) for name in oidn.catcher_pass_names(mode)}
    composed = oidn.compose_catcher(planes[oidn.MATTE], planes[oidn.SHADOW_CATCHER], planes.get(oidn.ENV), mode)
    np.testing.assert_allclose(composed, film, rtol=1e-6, atol=1e-7)
    image, _, passes = oidn.denoise_film(film, sess.film_pass, catcher=mode)
    assert set(passes) == {oidn.SHADOW_CATCHER}
    plain, _, none = oidn.denoise_film(film, sess.film_pass)  # (the composite denoised as an image)
    assert none == {}
    ref = np.flipud(reference["Approximate" if transparent else "Opaque"])  # (film: row 0 = bottom)
    if transparent:
        # The colour is the matte's: denoised alike; the alpha now comes from the denoised
        # shadow (denoising the composite as an image left it as it was). Measured (seeds 2,
        # 3, 4): alpha RMSE 0.0375 -> 0.0219 (0.58x), 0.62x, 0.62x; Cycles 0.56x, 0.60x.
        np.testing.assert_array_equal(image[..., :3], plain[..., :3])
        np.testing.assert_array_equal(plain[..., 3], film[..., 3])
        e_noisy, e_den = rmse(film[..., 3], ref[..., 3]), rmse(image[..., 3], ref[..., 3])
        assert e_den < 0.75 * e_noisy, (e_den, e_noisy)
    else:
        # The world behind the catcher over the denoised matte and shadow. Measured (seeds 2,
        # 3, 4): RMSE 0.0298 -> 0.0127 (0.43x), 0.47x, 0.54x; Cycles 0.50x, 0.59x.
        np.testing.assert_array_equal(image[..., 3], 1.0)
        assert np.abs(image - plain).max() > 1e-3  # (not the composite denoised as an image)
        e_noisy, e_den = rmse(film[..., :3], ref[..., :3]), rmse(image[..., :3], ref[..., :3])
        assert e_den < 0.7 * e_noisy, (e_den, e_noisy)
        # The render's own Combined is this image: the session composes it the same way.
        configure(sc, transparent, False, True, NOISY_SPP, 2)
        rendered = render_passes(sc, tmp_path / "den.exr")
        np.testing.assert_array_equal(np.flipud(rendered["Combined"]), image)
        np.testing.assert_array_equal(np.flipud(rendered["Noisy Image"]), film)


def test_guides_are_prefiltered_once_and_the_catcher_gets_a_constant_albedo(monkeypatch):
    rng = np.random.default_rng(7)
    h, w = 16, 24
    matte = rng.random((h, w, 4)).astype(np.float32)
    shadow = (0.5 + 0.2 * rng.random((h, w, 3))).astype(np.float32)
    albedo = rng.random((h, w, 3)).astype(np.float32)
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 2] = 1.0
    a, b = matte.copy(), shadow.copy()
    oidn.denoise_many([(a, True), (b, False)], albedo, normal)
    # The matte: as denoised alone with the guides.
    alone = matte.copy()
    oidn.denoise(alone, albedo, normal)
    np.testing.assert_array_equal(a, alone)
    # The shadow catcher: with the prefiltered normal and 0.5 for the albedo, not the albedo.
    c = shadow.copy()
    oidn.denoise_many([(c, False)], albedo, normal)
    np.testing.assert_array_equal(b, c)
    with_albedo = shadow.copy()
    oidn.denoise(with_albedo, albedo, normal)
    assert np.abs(with_albedo - b).max() > 1e-4
    # Albedo only ('RGB_ALBEDO'): the constant albedo; colour only: no guide at all.
    d, e = shadow.copy(), shadow.copy()
    oidn.denoise_many([(d, False)], albedo)
    oidn.denoise_many([(e, False)], np.full((h, w, 3), oidn.FAKE_ALBEDO, np.float32), prefilter='NONE')
    np.testing.assert_array_equal(d, e)


def test_cancel_restores_every_plane():
    rng = np.random.default_rng(8)
    matte = rng.random((128, 128, 4)).astype(np.float32)
    shadow = rng.random((128, 128, 3)).astype(np.float32)
    a, b = matte.copy(), shadow.copy()
    polls = []

    def cancel_in_the_second_filter():
        polls.append(1)
        return len(polls) > 40

    with pytest.raises(oidn.DenoiseCancelled):
        oidn.denoise_many([(a, True), (b, False)], cancel=cancel_in_the_second_filter)
    assert len(polls) > 40
    np.testing.assert_array_equal(a, matte)
    np.testing.assert_array_equal(b, shadow)


def test_a_failing_denoise_keeps_every_catcher_pass_noisy(monkeypatch, tmp_path):
    sc = catcher_scene()
    configure(sc, True, True, False, NOISY_SPP, 2)
    plain = render_passes(sc, tmp_path / "plain.exr")

    def missing():
        raise oidn.DenoiseError("Open Image Denoise (test) could not be loaded")

    monkeypatch.setattr(oidn, "load_library", missing)
    oidn.reset()
    try:
        configure(sc, True, True, True, NOISY_SPP, 2)
        got = render_passes(sc, tmp_path / "missing.exr")
    finally:
        monkeypatch.undo()
        oidn.reset()
    for name in ("Combined", "Shadow Catcher"):
        np.testing.assert_array_equal(got[name], plain[name])
    np.testing.assert_array_equal(got["Noisy Shadow Catcher"], plain["Shadow Catcher"])


@pytest.mark.parametrize("transparent", [True, False], ids=["approximate", "over_background"])
def test_viewport_denoise_composes_the_denoised_planes(transparent):
    import time
    from addon.core import get_core
    from addon.viewport import ViewportSession
    sc = catcher_scene()
    configure(sc, transparent, False, False, NOISY_SPP, 2)
    p = sc.pathlight
    p.preview_samples, p.use_preview_denoising, p.preview_denoising_start_sample = NOISY_SPP, True, 1
    vs = ViewportSession(get_core())
    vs.denoise_async = False
    vs.set_view(None, 24, 24)  # tiny: no low-resolution pass
    vs.sync(bpy.context.evaluated_depsgraph_get())
    try:
        mode = 'APPROXIMATE' if transparent else 'OVER_BACKGROUND'
        assert vs.denoiser["catcher"] == mode
        deadline = time.monotonic() + 120.0
        while vs.poll() and time.monotonic() < deadline:
            vs.display()
            if vs.full is not None:
                vs.full.wait(0.05)
            else:
                time.sleep(0.01)
        image, n = vs.display()
        assert n == NOISY_SPP and vs._denoised[1] == NOISY_SPP
        sess = vs.full
        opts = {k: v for k, v in vs.denoiser.items() if k != "catcher"}
        expected, _, passes = oidn.denoise_film(sess.film(), sess.film_pass, catcher=mode, **opts)
        assert set(passes) == {oidn.SHADOW_CATCHER}
        np.testing.assert_array_equal(image, expected)
        # (denoising the composite as an image gives another picture)
        assert np.abs(image - oidn.denoise_film(sess.film(), sess.film_pass, **opts)[0]).max() > 1e-4
    finally:
        vs.free()


def test_viewport_denoises_the_shadow_catcher_pass_shown():
    # Cycles' viewport shows a pass's denoised variant where it has one: of the passes the
    # viewport can show, the Shadow Catcher pass (with a 0.5 albedo, as in the render).
    import time
    from addon.core import get_core
    from addon.viewport import ViewportSession, display_pass
    sc = catcher_scene()
    configure(sc, True, False, False, NOISY_SPP, 2)
    p = sc.pathlight
    p.preview_samples, p.use_preview_denoising, p.preview_denoising_start_sample = NOISY_SPP, True, 1
    vs = ViewportSession(get_core())
    vs.denoise_async = False
    vs.set_view(None, 24, 24)
    vs.sync(bpy.context.evaluated_depsgraph_get())
    try:
        vs.set_pass('SHADOW_CATCHER')
        assert vs.shown == ("pass", oidn.SHADOW_CATCHER)
        deadline = time.monotonic() + 120.0
        while vs.poll() and time.monotonic() < deadline:
            vs.display()
            if vs.full is not None:
                vs.full.wait(0.05)
            else:
                time.sleep(0.01)
        image, n = vs.display()
        sess = vs.full
        assert n == NOISY_SPP and vs._denoised[0] is sess
        noisy = display_pass(sess.film_pass(oidn.SHADOW_CATCHER))
        opts = {k: v for k, v in vs.denoiser.items() if k != "catcher"}
        expected = oidn.denoise_film(noisy, sess.film_pass, use_albedo=False, **opts)[0]
        np.testing.assert_array_equal(image, expected)
        assert np.abs(image - noisy).max() > 1e-3
        # Another pass is shown as it is, and the redraws stop with its last sample (they
        # waited for a denoise that never came, until 2026-12-07).
        vs.set_pass('AO')
        deadline = time.monotonic() + 120.0
        while vs.poll() and time.monotonic() < deadline:
            vs.display()
            if vs.full is not None:
                vs.full.wait(0.05)
            else:
                time.sleep(0.01)
        assert vs.full is not None and vs.full.is_finished() and not vs.poll()
        image, _ = vs.display()
        np.testing.assert_array_equal(image, display_pass(vs.full.film_pass("AO")))
    finally:
        vs.free()
