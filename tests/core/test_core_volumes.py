"""Homogeneous volumes through the core module: Henyey-Greenstein and free-flight sampling
against their densities (chi-square), the white furnace of a scattering sphere, closed forms
of absorption and emission behind pass-through boundaries, and light sampling (NEE with MIS)
against phase sampling alone."""
import math

import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, render, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def chi_square_ok(observed, expected, min_expected=5.0):
    """Pearson's statistic over the bins with enough expected counts (the rest pooled), against
    a bound of df + 6 sqrt(2 df) (about 4 standard deviations): a wrong density fails by far."""
    keep = expected >= min_expected
    obs = np.append(observed[keep], observed[~keep].sum())
    exp = np.append(expected[keep], expected[~keep].sum())
    if exp[-1] < min_expected:
        obs, exp = obs[:-1], exp[:-1]
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    df = len(obs) - 1
    return chi2, df + 6.0 * math.sqrt(2.0 * df)


@pytest.mark.parametrize("g", [0.0, 0.3, -0.6, 0.9])
def test_henyey_greenstein_samples_follow_its_pdf(g):
    n = 200_000
    u = np.random.default_rng(1).random((n, 2), dtype=np.float32)
    dirs, pdfs = pc.sample_henyey_greenstein(g, u)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-4)
    cos_t = dirs[:, 2]
    # The returned pdf is the phase function at the sampled direction, and it integrates to 1.
    assert np.allclose(pdfs, pc.henyey_greenstein_pdf(g, cos_t), rtol=1e-4)
    grid = np.linspace(-1.0, 1.0, 200_001, dtype=np.float32)
    integral = 2.0 * math.pi * np.trapz(pc.henyey_greenstein_pdf(g, grid), grid)
    assert abs(integral - 1.0) < 1e-3
    # Bins in (cos theta, phi): expected counts from the pdf integrated over each cos bin.
    nc, nphi = 40, 8
    edges = np.linspace(-1.0, 1.0, nc + 1)
    fine = np.linspace(-1.0, 1.0, nc * 2000 + 1, dtype=np.float32)
    f = pc.henyey_greenstein_pdf(g, fine).astype(np.float64) * 2.0 * math.pi
    cdf = np.concatenate([[0.0], np.cumsum((f[1:] + f[:-1]) * 0.5 * np.diff(fine))])
    p_cos = np.diff(cdf[::2000])
    p_cos /= p_cos.sum()
    phi = np.arctan2(dirs[:, 1], dirs[:, 0]) % (2.0 * math.pi)
    obs, _, _ = np.histogram2d(cos_t, phi, bins=[edges, np.linspace(0, 2 * math.pi, nphi + 1)])
    expected = np.repeat(p_cos[:, None] * n / nphi, nphi, axis=1)
    chi2, bound = chi_square_ok(obs.ravel(), expected.ravel())
    assert chi2 < bound, (g, chi2, bound)
    # A wrong anisotropy is caught by the same test (the test has power).
    if g != 0.0:
        wrong, _, _ = np.histogram2d(cos_t, phi, bins=[edges, np.linspace(0, 2 * math.pi, nphi + 1)])
        dirs2, _ = pc.sample_henyey_greenstein(g * 0.9, u)
        wrong, _, _ = np.histogram2d(dirs2[:, 2], phi, bins=[edges, np.linspace(0, 2 * math.pi, nphi + 1)])
        assert chi_square_ok(wrong.ravel(), expected.ravel())[0] > bound


def test_free_flight_distances_follow_the_channel_averaged_density():
    n = 200_000
    sigma_t = (0.5, 1.0, 3.0)
    u = np.random.default_rng(2).random((n, 2), dtype=np.float32)
    t = pc.sample_free_flight(sigma_t, u)
    assert np.all(t >= 0.0) and np.all(np.isfinite(t))
    edges = np.concatenate([np.linspace(0.0, 8.0, 81), [np.inf]])
    cdf = lambda x: 1.0 - np.mean([np.exp(-s * x) for s in sigma_t], axis=0)  # noqa: E731
    expected = np.diff(cdf(np.minimum(edges, 1e30))) * n
    obs, _ = np.histogram(t, bins=edges)
    chi2, bound = chi_square_ok(obs.astype(float), expected)
    assert chi2 < bound, (chi2, bound)
    # A zero-extinction channel never stops: its third of the samples flies to infinity.
    t0 = pc.sample_free_flight((0.0, 1.0, 1.0), u)
    assert abs(np.mean(np.isinf(t0)) - 1.0 / 3.0) < 0.01


def volume_sphere(volume, world=1.0, surface=None, radius=1.0):
    """A sphere whose material is only a Volume (a pass-through boundary, as Cycles gives a
    material without a Surface) under a constant world, seen from 4 units away."""
    s = pc.Scene()
    prog = surface or [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})]
    m = s.add_shader("vol", prog, volume=volume)
    pos, tris, nrm = uv_sphere(radius, nu=64, nv=32)
    add_object(s, pos, tris, m, nrm)
    s.set_world_color((world, world, world))
    s.set_camera(camera(pc, (0, -4, 0), (0, 0, 0), lens=60.0))
    return s


def test_white_furnace_of_a_scattering_sphere():
    """Albedo 1 under a white world: every path returns 1, whatever the density and anisotropy;
    an absorbing part makes the sphere darker than the world around it."""
    for g in (0.0, 0.6):
        s = volume_sphere({"sigma_s": (3.0, 3.0, 3.0), "g": g})
        img, stats = render(pc, s, 24, 24, samples=32, max_bounces=1024)
        assert stats["nonfinite_samples"] == 0
        assert "volumes" in stats["features"]
        assert abs(float(img[..., :3].mean()) - 1.0) < 0.01, g
        assert abs(float(img[10:14, 10:14, :3].mean()) - 1.0) < 0.01, g
    s = volume_sphere({"sigma_s": (3.0, 3.0, 3.0), "sigma_a": (0.5, 1.0, 2.0)})
    img, _ = render(pc, s, 24, 24, samples=32, max_bounces=1024)
    centre = img[10:14, 10:14, :3].mean(axis=(0, 1))
    assert np.all(centre < 0.8) and centre[0] > centre[1] > centre[2]  # red absorbs least
    assert abs(float(img[0, 0, :3].mean()) - 1.0) < 1e-3  # the world beside it


def test_absorption_and_emission_behind_a_pass_through_boundary():
    """Closed forms along the central ray (chord 2): exp(-2 sigma_a) of the world through an
    absorbing volume; e (1 - exp(-2 sigma_a)) / sigma_a from an emitting one in a black world."""
    sa = np.array([0.2, 0.5, 1.0])
    img, _ = render(pc, volume_sphere({"sigma_a": tuple(sa)}), 17, 17, samples=4)
    assert np.allclose(img[8, 8, :3], np.exp(-2.0 * sa), rtol=0.01)
    e = 0.7
    img, _ = render(pc, volume_sphere({"sigma_a": tuple(sa), "emission": (e, e, e)}, world=0.0), 17, 17,
                    samples=4)
    assert np.allclose(img[8, 8, :3], e * (1.0 - np.exp(-2.0 * sa)) / sa, rtol=0.01)


def test_light_sampling_in_a_medium_agrees_with_phase_sampling():
    """A scattering sphere (with a diffuse floor below) lit by an emissive quad: NEE with MIS
    and pure phase/BSDF sampling estimate the same image (mean within 2 %)."""
    def scene():
        s = volume_sphere({"sigma_s": (1.5, 1.0, 0.6), "sigma_a": (0.1, 0.2, 0.3), "g": 0.4}, world=0.0,
                          radius=0.8)
        light = s.add_shader("light", [("const", 0, (6.0, 6.0, 6.0)), ("closure", "emission", None, {"color": 0})])
        pos, tris = quad((-1.0, -1.0, 2.0), (0.0, 2.0, 0.0), (2.0, 0.0, 0.0))  # facing down
        add_object(s, pos, tris, light)
        floor = s.add_shader("floor", [("const", 0, (0.8, 0.8, 0.8)), ("closure", "diffuse", None, {"color": 0})])
        pos, tris = quad((-3.0, -3.0, -0.8), (6.0, 0.0, 0.0), (0.0, 6.0, 0.0))
        add_object(s, pos, tris, floor)
        return s
    a, _ = render(pc, scene(), 24, 24, samples=256, max_bounces=16)
    b, _ = render(pc, scene(), 24, 24, samples=1024, max_bounces=16, use_nee=False)
    ma, mb = a[..., :3].mean(axis=(0, 1)), b[..., :3].mean(axis=(0, 1))
    assert np.all(ma > 0.02)
    assert np.allclose(ma, mb, rtol=0.02), (ma, mb)
    ca, cb = a[8:16, 8:16, :3].mean(), b[8:16, 8:16, :3].mean()  # the sphere itself
    assert abs(ca - cb) < 0.03 * cb, (ca, cb)


def test_bad_volume_values_are_cleaned():
    nan = float("nan")
    s = volume_sphere({"sigma_s": (nan, -1.0, 2.0), "sigma_a": (float("inf"), 0.0, 0.0), "g": nan,
                       "emission": (-1.0, nan, 0.0)})
    img, stats = render(pc, s, 8, 8, samples=4, max_bounces=64)
    assert stats["nonfinite_samples"] == 0 and np.all(np.isfinite(img))
    with pytest.raises(ValueError):
        pc.Scene().add_shader("x", [], volume={"density": 1.0})


def test_world_volume_closed_forms():
    """The world's Volume fills the scene: an infinite emitting, absorbing and scattering medium
    is in equilibrium at emission / sigma_a in every direction; an emitter seen through
    absorbing fog at distance 3 is dimmed by exp(-3 sigma_a)."""
    s = pc.Scene()
    s.set_world_color((5.0, 5.0, 5.0))  # hidden by the fog, which never ends
    s.set_world_volume({"sigma_a": (0.5, 1.0, 2.0), "sigma_s": (1.0, 0.5, 0.2), "g": 0.5,
                        "emission": (0.5, 0.5, 0.5)})
    s.set_camera(camera(pc, (0, -4, 0), (0, 0, 0), lens=60.0))
    img, stats = render(pc, s, 8, 8, samples=64, max_bounces=256)
    assert "volumes" in stats["features"]
    assert np.allclose(img[..., :3].mean(axis=(0, 1)), [1.0, 0.5, 0.25], rtol=0.01)
    s = pc.Scene()
    light = s.add_shader("light", [("const", 0, (2.0, 2.0, 2.0)), ("closure", "emission", None, {"color": 0})])
    pos, tris = quad((-5.0, 3.0, -5.0), (10.0, 0.0, 0.0), (0.0, 0.0, 10.0))
    add_object(s, pos, tris, light)
    sa = np.array([0.1, 0.3, 0.6])
    s.set_world_volume({"sigma_a": tuple(sa)})
    cam = camera(pc, (0, 0, 0), (0, 1, 0), lens=200.0)
    cam.clip_start = 1e-4  # rays (and so the fog they cross) start at the clip distance
    s.set_camera(cam)
    img, _ = render(pc, s, 5, 5, samples=4)
    assert np.allclose(img[2, 2, :3], 2.0 * np.exp(-3.0 * sa), rtol=0.01)
    s.set_world_volume(None)  # removed again: no medium, no feature
    img, stats = render(pc, s, 5, 5, samples=4)
    assert "volumes" not in stats["features"] and np.allclose(img[2, 2, :3], 2.0, rtol=1e-4)


@pytest.mark.parametrize("t_max", [3.0, float("inf")])
def test_equiangular_distances_follow_their_pdf(t_max):
    """Equiangular distances towards a point on a light (direct light in media, Cycles' default
    volume sampling): a chi-square of their histogram against the closed-form cdf, and the pdf
    they report is that density (it integrates to 1 over [0, t_max])."""
    n = 200_000
    origin, direction, light = (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (1.2, 0.4, 0.0)
    u = np.random.default_rng(5).random(n, dtype=np.float32)
    t, pdf = pc.sample_equiangular(origin, direction, t_max, light, u)
    assert np.all(np.isfinite(t)) and np.all(t >= -1e-5) and np.all(t <= t_max * (1 + 1e-5))
    delta, dist = 1.2, 0.4
    th_a = math.atan2(-delta, dist)
    th_b = math.atan2(t_max - delta, dist) if math.isfinite(t_max) else math.pi / 2
    cdf = lambda x: (np.arctan2(x - delta, dist) - th_a) / (th_b - th_a)  # noqa: E731
    top = t_max if math.isfinite(t_max) else 60.0
    edges = np.concatenate([np.linspace(0.0, top, 121), [np.inf]])
    expected = np.diff(np.where(np.isinf(edges), 1.0, cdf(np.minimum(edges, 1e30)))) * n
    obs, _ = np.histogram(t, bins=edges)
    chi2, bound = chi_square_ok(obs.astype(float), expected)
    assert chi2 < bound, (chi2, bound)
    exact = dist / ((th_b - th_a) * (dist ** 2 + (t - delta) ** 2))
    np.testing.assert_allclose(pdf, exact, rtol=1e-3)
    # The light on the ray's line has no equiangular density: the integrator skips it.
    t_on, _ = pc.sample_equiangular(origin, direction, t_max, (2.0, 0.0, 0.0), u[:4])
    assert np.all(np.isnan(t_on))


def lamp_in_fog(spot=False):
    """A small lamp inside a scattering sphere (black world), with an opaque quad shadowing part
    of the fog, so that the fog's light samples see the lamp differently; spot: a spot light
    pointing down, whose cone lights a part of the fog."""
    s = volume_sphere({"sigma_s": (1.2, 1.0, 0.8), "sigma_a": (0.1, 0.1, 0.1), "g": 0.3}, world=0.0)
    grey = s.add_shader("grey", [("const", 0, (0.7, 0.7, 0.7)), ("closure", "diffuse", None, {"color": 0})])
    pos, tris = quad((-0.5, -0.3, -0.2), (0.5, 0.0, 0.0), (0.0, 0.6, 0.0))
    add_object(s, pos, tris, grey)
    if spot:
        m = np.eye(4, dtype=np.float32)
        m[:3, 3] = (0.1, 0.0, 0.5)
        s.add_spot_light(m, (4.0, 4.0, 4.0), radius=0.05, spot_size=math.radians(70.0), spot_blend=0.2)
    else:
        s.add_point_light((0.1, 0.0, 0.3), (2.0, 2.0, 2.0), radius=0.05)
    return s


def render_both(setting, spot, samples=384):
    """The lamp in fog with a RenderSettings switch on and off: images, rays per path."""
    imgs, rays = {}, {}
    for on in (True, False):
        img, st = render(pc, lamp_in_fog(spot), 24, 24, samples=samples, max_bounces=8, **{setting: on})
        assert st["nonfinite_samples"] == 0
        imgs[on], rays[on] = img[..., :3].astype(np.float64), st["rays"] / st["paths"]
    a, b = imgs[True], imgs[False]
    assert b.mean() > 0.01
    assert abs(a.mean() / b.mean() - 1.0) < 0.02, (a.mean(), b.mean())
    ra, rb = (x.reshape(4, 6, 4, 6, 3).mean(axis=(1, 3, 4)) for x in (a, b))
    lit = rb > 0.1 * rb.max()
    assert np.all(np.abs(ra[lit] / rb[lit] - 1.0) < 0.08), np.abs(ra / rb - 1.0).max()
    return rays


def test_shared_shadow_ray_is_unbiased_and_traces_fewer_rays():
    """Homogeneous fog's equiangular and distance-sampled light samples share one shadow ray
    (RenderSettings.volume_shared_shadow): the image agrees with a shadow ray for each (means
    within 2 %, 6x6-pixel regions within 8 %) for fewer rays per path."""
    rays = render_both("volume_shared_shadow", spot=False)
    assert rays[True] < 0.9 * rays[False], rays


def test_equiangular_distances_within_the_spot_cone():
    """Equiangular distances only where a spot's cone reaches (RenderSettings.volume_light_reach):
    the image agrees with distances along the whole segment, and more of the light samples land
    in the cone (so more shadow rays are traced)."""
    rays = render_both("volume_light_reach", spot=True)
    assert rays[True] > 1.01 * rays[False], rays


def test_phase_samples_beside_a_lamp_share_the_segment_mis():
    """A homogeneous segment's three direct-light strategies weighed together (RenderSettings.
    volume_phase_mis): the free-flight point's phase sample against the equiangular light
    sample too. A lamp (radius 0.3) in thin fog: the same image as the two-step weights before
    (mean within 1 %, 6x6-pixel regions within 5 %), and the pixels beside the lamp, where a
    scattering point next to it found it by its phase ray at weight about 1, less noisy (the
    largest pixel variance over 12 seeds below 0.65x; 0.33-0.45x measured)."""
    def scene():
        s = volume_sphere({"sigma_s": (0.5, 0.5, 0.5), "sigma_a": (0.02, 0.02, 0.02), "g": 0.2}, world=0.0)
        s.add_point_light((0.1, 0.0, 0.3), (2.0, 2.0, 2.0), radius=0.3)
        return s
    imgs = {}
    for on in (True, False):
        runs = [render(pc, scene(), 24, 24, samples=32, max_bounces=8, volume_phase_mis=on, seed=k,
                           sampler="sobol_pairs") for k in range(12)]  # (the ratio was measured with the pairs)
        assert all(st["nonfinite_samples"] == 0 for _, st in runs)
        imgs[on] = np.stack([img[..., :3].astype(np.float64) for img, _ in runs])
    a, b = imgs[True], imgs[False]
    assert b.mean() > 0.01
    assert abs(a.mean() / b.mean() - 1.0) < 0.01, (a.mean(), b.mean())
    ra, rb = (x.mean(axis=0).reshape(4, 6, 4, 6, 3).mean(axis=(1, 3, 4)) for x in (a, b))
    lit = rb > 0.1 * rb.max()
    assert np.all(np.abs(ra[lit] / rb[lit] - 1.0) < 0.05), np.abs(ra / rb - 1.0).max()
    va, vb = (x.var(axis=0, ddof=1).mean(axis=-1).max() for x in (a, b))
    assert va < 0.65 * vb, (va, vb)


def test_volume_only_boundaries_cross_unshaded_to_the_same_image():
    """Volume-only boundaries (a white Transparent closure alone: Material::pass_through) are
    crossed without shading them (RenderSettings.volume_pass_through), drawing the same sample
    dimensions: bit for bit the image of shading them, also where the path ends at the boundary
    (the bounce limit, Volume bounces 0) and where the boundary is not pure (a tinted
    Transparent closure, which must be shaded)."""
    tinted = [("const", 0, (0.6, 0.8, 1.0)), ("closure", "transparent", None, {"color": 0})]
    for scene, kw in ((lambda: lamp_in_fog(spot=True), dict(max_bounces=8)),
                      (lambda: lamp_in_fog(spot=False), dict(max_bounces=1)),
                      (lambda: lamp_in_fog(spot=False), dict(max_bounces=8, volume_bounces=0)),
                      (lambda: volume_sphere({"sigma_s": (1.0, 1.0, 1.0)}, surface=tinted), dict(max_bounces=4))):
        imgs = [render(pc, scene(), 16, 16, samples=16, volume_pass_through=on, **kw)[0] for on in (True, False)]
        assert imgs[1][..., :3].mean() > 1e-3
        assert np.array_equal(imgs[0], imgs[1]), kw


def test_light_max_bounces_in_fog():
    """A light's Max Bounces in a medium (the medium light samples check it too): a point light
    limited to 1 bounce inside the fog lights the camera path's first two vertices, surface or
    scattering, which is what a render limited to 1 bounce gives (means within 2 %, regions
    within 8 %); unlimited, the fog's multiple scattering is brighter."""
    def film(light_limit, max_bounces):
        s = volume_sphere({"sigma_s": (1.2, 1.0, 0.8), "sigma_a": (0.1, 0.1, 0.1), "g": 0.3}, world=0.0)
        s.add_point_light((0.1, 0.0, 0.3), (2.0, 2.0, 2.0))
        if light_limit is not None:
            s.set_light_max_bounces(0, light_limit)
        img, st = render(pc, s, 24, 24, samples=384, max_bounces=max_bounces)
        assert st["nonfinite_samples"] == 0
        return img[..., :3].astype(np.float64)
    limited, direct, full = film(1, 8), film(None, 1), film(None, 8)
    assert abs(limited.mean() / direct.mean() - 1.0) < 0.02, (limited.mean(), direct.mean())
    ra, rb = (x.reshape(4, 6, 4, 6, 3).mean(axis=(1, 3, 4)) for x in (limited, direct))
    lit = rb > 0.1 * rb.max()
    assert np.all(np.abs(ra[lit] / rb[lit] - 1.0) < 0.08), np.abs(ra / rb - 1.0).max()
    assert full.mean() > 1.1 * limited.mean()
