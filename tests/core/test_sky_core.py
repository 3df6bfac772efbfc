"""The core's Sky Texture (tests/blender/test_sky.py compares it with Cycles): the sampling of the sky
map and the sun disc (pdf consistent with the sampled directions), bad settings."""
import math

import numpy as np
import pytest

from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
DEG = math.pi / 180


def sky_scene(**settings):
    s = pc.Scene()  # nothing but the world
    s.set_world_sky(**settings)
    s.commit()
    return s


@pytest.mark.parametrize("settings", [dict(sun_elevation=25 * DEG, sun_rotation=1.0),
                                      dict(sun_elevation=0.2 * DEG, dust=3.0)])
def test_sampling_pdf_matches_the_directions(settings):
    # E[g(w) / pdf(w)] = integral of g: for g = 1 over the upper hemisphere (radiance > 0
    # everywhere there) it is 2 pi, and for g = 1 in the sun's cone its solid angle; the cone
    # must also get a fair share of the samples (NEE finds the disc).
    s = sky_scene(**settings)
    n = 200000
    rng = np.random.default_rng(3)
    e, r = settings["sun_elevation"], math.tau - settings.get("sun_rotation", 0.0)
    sun = np.array([-math.cos(e) * math.sin(r), math.cos(e) * math.cos(r), math.sin(e)])
    half = 0.009512 / 2
    cone = 2 * np.pi * (1 - math.cos(half))
    for bsdf_follows in (False, True):
        ok, wi, dist, pdf, _, _ = s.light_samples(np.zeros((n, 3), np.float32),
                                                 rng.random((n, 3), dtype=np.float32),
                                                 bsdf_follows=bsdf_follows)
        assert ok.mean() > 0.99 and np.all(pdf[ok] > 0) and np.all(np.isinf(dist[ok]))
        w, p = wi[ok], pdf[ok]
        if not bsdf_follows:  # this one covers every direction with radiance
            est = np.sum(1.0 / p[w[:, 2] > 0]) / n
            assert est == pytest.approx(2 * np.pi, rel=0.02)
        in_cone = w @ sun > math.cos(half)
        assert in_cone.mean() > 0.04  # the disc keeps at least a 5 % share
        assert np.sum(1.0 / p[in_cone]) / n == pytest.approx(cone, rel=0.02)
    # The disc is where the sky evaluator says it is (brighter than any sky texel by far).
    rad = pc.sky_radiance(np.vstack([sun, [0, 0, 1]]).astype(np.float32), **settings)
    assert rad[0].sum() > 100 * rad[1].sum()


@pytest.mark.parametrize("args", [
    dict(sun_elevation=float("nan"), sun_rotation=float("inf"), sun_size=float("nan")),
    dict(sun_elevation=1e30, altitude=-5.0, air=float("inf"), dust=-1.0, ozone=float("nan")),
    dict(sun_elevation=-1.4, sun_size=10.0, sun_intensity=float("nan"), altitude=1e9),
    dict(sun_elevation=7.0, sun_rotation=-20.0, sun_disc=False, strength=float("nan")),
])
def test_bad_settings_give_finite_light(args):
    # Never a crash nor a NaN: out-of-range settings are clamped as Cycles clamps them.
    s = pc.Scene()
    s.set_world_sky(**args)
    s.commit()
    n = 2000
    ok, _, _, pdf, _, _ = s.light_samples(np.zeros((n, 3), np.float32),
                                         np.random.default_rng(1).random((n, 3), dtype=np.float32))
    assert np.isfinite(pdf).all()
    d = np.random.default_rng(2).normal(size=(500, 3)).astype(np.float32)
    sky = {k: v for k, v in args.items() if k != "strength"}
    assert np.isfinite(pc.sky_radiance(d, **sky)).all()
    p = pc.Scene()
    p.set_world_preetham(sun_direction=(0.0, 0.0, 0.0), turbidity=float(args.get("air", 1e6)))
    p.commit()


# ---------------------------------------------------------------- Hosek / Wilkie

HOSEK = [dict(sun_direction=(0.4, 0.7, 0.35), turbidity=3.0, ground_albedo=0.3),
         dict(sun_direction=(-0.8, 0.2, 0.05), turbidity=8.7, ground_albedo=1.0)]


@pytest.mark.parametrize("settings", HOSEK)
def test_hosek_sampling_pdf_matches_the_directions(settings):
    # The sky has radiance in every direction (below the horizon: the horizon's colour), so
    # E[1 / pdf] over all samples is the sphere's 4 pi; the samples crowd around the sun.
    s = pc.Scene()
    s.set_world_hosek(**settings)
    s.commit()
    n = 200000
    ok, wi, dist, pdf, _, _ = s.light_samples(np.zeros((n, 3), np.float32),
                                             np.random.default_rng(4).random((n, 3), dtype=np.float32),
                                             bsdf_follows=False)
    assert ok.mean() > 0.99 and np.all(pdf[ok] > 0) and np.all(np.isinf(dist[ok]))
    assert np.sum(1.0 / pdf[ok]) / n == pytest.approx(4 * np.pi, rel=0.02)
    sun = np.array(settings["sun_direction"]) / np.linalg.norm(settings["sun_direction"])
    near = wi[ok] @ sun > math.cos(10 * DEG)  # the bright circumsolar region
    assert near.mean() > 2 * (1 - math.cos(10 * DEG)) / 2  # twice its share of the sphere
    assert pdf[ok][near].mean() > 3 * pdf[ok][wi[ok][:, 2] > 0.95].mean()  # against the zenith


@pytest.mark.parametrize("settings", HOSEK)
def test_hosek_sky_is_finite_positive_and_symmetric_about_the_sun(settings):
    # The model depends on the view's zenith angle and its angle to the sun only: a camera
    # looking along the sun's azimuth (up = +z) sees a mirror-symmetric image.
    from core_scenes import camera, render
    s = pc.Scene()
    s.set_world_hosek(**settings)
    x, y, _ = settings["sun_direction"]
    s.set_camera(camera(pc, (0.0, 0.0, 0.0), (x, y, 0.2 * math.hypot(x, y)), lens=12.0))
    s.commit()
    img = render(pc, s, 32, 32, samples=64)[0][..., :3]
    assert np.isfinite(img).all() and img.min() > 0
    mirrored = img[:, ::-1]
    rel = np.abs(img - mirrored) / np.maximum(img, mirrored)
    assert rel.mean() < 0.01 and rel.max() < 0.05
    # brighter towards the sun (the image's upper rows, for a sun above the camera's aim)
    assert img[:8].mean() > img[-8:].mean() or settings["sun_direction"][2] < 0.1


def test_hosek_bad_settings_give_finite_light():
    for args in (dict(sun_direction=(0.0, 0.0, 0.0), turbidity=float("nan"), ground_albedo=float("inf")),
                 dict(sun_direction=(1e30, -1e30, 1e30), turbidity=-3.0, ground_albedo=-1.0),
                 dict(sun_direction=(0.0, 0.3, -1.0), turbidity=1e6, ground_albedo=7.0, strength=float("nan"))):
        s = pc.Scene()
        s.set_world_hosek(**args)
        s.commit()
        n = 2000
        ok, _, _, pdf, _, _ = s.light_samples(np.zeros((n, 3), np.float32),
                                             np.random.default_rng(1).random((n, 3), dtype=np.float32))
        assert np.isfinite(pdf).all()
