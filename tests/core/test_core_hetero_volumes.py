"""Heterogeneous volumes through the core module (docs/design/volumes.md): a Volume program
evaluated at points, its majorant grid, ratio tracking's transmittance and delta tracking's
collision distances against the closed forms of a density linear in x (also with majorants
deliberately too small: the null-scattering estimators stay unbiased), and the white furnace."""
import math

import numpy as np
import pytest

from core_scenes import add_object, camera, core, render
from test_core_volumes import chi_square_ok

pc = core()
pytestmark = pytest.mark.sanitize

A, B = 0.2, 1.0  # sigma(x) = A + B (x + 1) inside the cube [-1, 1]^3


def cube(half=1.0):
    """A closed box [-half, half]^3 with outward-facing triangles."""
    h = half
    pos = np.array([[x, y, z] for z in (-h, h) for y in (-h, h) for x in (-h, h)], np.float32)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = []
    for a, b, c, d in quads:
        tris += [(a, b, c), (a, c, d)]
    return pos, np.array(tris, np.int32)


def linear_program(a=A, b=B, albedo=1.0, absorb=0.0, emission=None):
    """sigma_t = a + b (x + 1): scattering albedo * sigma_t, absorption absorb * sigma_t."""
    prog = [("position", 0), ("separate", 1, 0, 0), ("const", 2, (1.0,)), ("math", 3, 1, 2, "ADD", False),
            ("const", 4, (b,)), ("math", 5, 3, 4, "MULTIPLY", False), ("const", 6, (a,)),
            ("math", 7, 5, 6, "ADD", False), ("const", 8, (albedo,)), ("math", 9, 7, 8, "MULTIPLY", False),
            ("const", 10, (absorb,)), ("math", 11, 7, 10, "MULTIPLY", False)]
    out = {"sigma_s": 9, "sigma_a": 11}
    if emission is not None:
        prog.append(("const", 12, tuple(emission)))
        out["emission"] = 12
    prog.append(("closure", "volume", None, out))
    return prog


def medium_scene(volume, world=1.0, majorant_scale=None):
    s = pc.Scene()
    m = s.add_shader("vol", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                     volume=volume)
    pos, tris = cube()
    add_object(s, pos, tris, m)
    s.set_world_color((world, world, world))
    s.set_camera(camera(pc, (0, -5, 0), (0, 0, 0), lens=50.0))
    if majorant_scale is not None:
        s.set_majorant_scale(majorant_scale)
    s.commit()
    return s, m


def tau(t):
    """Optical depth from x = -1 over a distance t along +x."""
    return A * t + 0.5 * B * t * t


ORG, DIR = (-1.0, 0.1, -0.3), (1.0, 0.0, 0.0)


def test_volume_program_and_majorants():
    s, m = medium_scene(linear_program(absorb=0.5))
    for x in (-0.9, 0.0, 0.7):
        d = s.medium_at(0, m, (x, 0.2, 0.1))
        assert d["sigma_s"] == pytest.approx((A + B * (x + 1),) * 3, rel=1e-5)
        assert d["sigma_a"] == pytest.approx((0.5 * (A + B * (x + 1)),) * 3, rel=1e-5)
    grid, lo, hi = s.medium_majorants(0, m)
    assert grid.shape == (16, 16, 16) and np.all(np.isfinite(grid))
    # Every cell bounds the extinction at its far x face (the density's maximum in it).
    xs = np.linspace(lo[0], hi[0], 17)[1:]
    true_max = 1.5 * (A + B * (np.minimum(xs, 1.0) + 1.0))
    assert np.all(grid >= true_max[None, None, :] * (1.0 - 1e-5))
    assert "heterogeneous volumes" in s.stats()["features"]
    with pytest.raises(ValueError):
        pc.Scene().add_shader("bad", [], volume=[("const", 0, (1.0,))])  # no 'volume' closure last
    pc.Scene().set_world_volume(linear_program())  # the world's too (test_core_world_volume.py)


@pytest.mark.parametrize("scale", [1.0, 0.25])
def test_ratio_tracking_transmittance_matches_exp_minus_tau(scale):
    """Mean of n estimates within 4 standard errors (and 1.5 %) of exp(-tau); with majorants
    a quarter of what they should be (null coefficients negative) it is still unbiased."""
    s, m = medium_scene(linear_program(), majorant_scale=scale)
    for tmax in (0.7, 2.0):
        _, w = s.medium_track(0, m, ORG, DIR, tmax, 40000 if scale == 1.0 else 400000, "ratio", seed=3)
        est = w[:, 0].astype(np.float64)
        want = math.exp(-tau(tmax))
        err = est.std() / math.sqrt(len(est))
        assert abs(est.mean() - want) < max(4.0 * err, 1e-4), (scale, tmax, est.mean(), want, err)
        assert abs(est.mean() / want - 1.0) < (0.015 if scale == 1.0 else 0.03), (est.mean(), want)
        if scale < 1.0:
            assert np.any(est < 0.0)  # the test does reach negative null coefficients
        else:
            assert np.all(est >= 0.0)


def test_delta_tracking_distances_follow_the_collision_density():
    """Scattering only (albedo 1): the first collision's density is sigma(t) exp(-tau(t)),
    chi-square against it; the probability of passing is exp(-tau(2))."""
    s, m = medium_scene(linear_program())
    n = 100_000
    t, w = s.medium_track(0, m, ORG, DIR, 2.0, n, "delta", seed=5)
    assert np.allclose(w, 1.0, atol=1e-5)  # gray medium, true majorants: classical delta tracking
    edges = np.concatenate([np.linspace(0.0, 2.0, 41), [np.inf]])
    cdf = 1.0 - np.exp(-tau(np.minimum(edges, 2.0)))
    cdf[-1] = 1.0
    expected = np.diff(cdf) * n
    obs, _ = np.histogram(np.where(np.isinf(t), 1e9, t), bins=edges)
    chi2, bound = chi_square_ok(obs.astype(float), expected)
    assert chi2 < bound, (chi2, bound)
    # A wrong density (the slope 10 % off) fails the same test.
    wrong = np.diff(np.concatenate([1.0 - np.exp(-(A * edges[:-1] + 0.55 * B * edges[:-1] ** 2)), [1.0]])) * n
    assert chi_square_ok(obs.astype(float), wrong)[0] > bound


def test_delta_tracking_stays_unbiased_with_too_small_majorants():
    """Majorants a quarter of the density: signed weights, whose weighted histogram still
    follows the collision density (each bin within 5 standard errors)."""
    s, m = medium_scene(linear_program(), majorant_scale=0.25)
    n = 200_000
    t, w = s.medium_track(0, m, ORG, DIR, 2.0, n, "delta", seed=7)
    w = w[:, 0].astype(np.float64)
    assert np.any(w < 0.0)
    edges = np.linspace(0.0, 2.0, 11)
    cdf = 1.0 - np.exp(-tau(edges))
    for k in range(10):
        inside = (t >= edges[k]) & (t < edges[k + 1])
        x = np.where(inside, w, 0.0)
        want = cdf[k + 1] - cdf[k]
        err = x.std() / math.sqrt(n)
        assert abs(x.mean() - want) < 5.0 * err + 1e-3, (k, x.mean(), want, err)
    passed = np.where(np.isinf(t), w, 0.0)
    assert abs(passed.mean() - math.exp(-tau(2.0))) < 5.0 * passed.std() / math.sqrt(n) + 1e-3


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_white_furnace_of_a_heterogeneous_medium():
    """Albedo 1 under a white world: radiance 1 within 1 % (mean and centre). With majorants
    too small (0.6 of the sampled maxima times the 1.5 safety factor: 0.9, below the density
    at the top of each cell) the signed weights make it far noisier but it stays 1 (2 % at
    4096 samples)."""
    s, _ = medium_scene(linear_program(a=0.5, b=2.0))
    img, stats = render(pc, s, 24, 24, samples=32, max_bounces=1024)
    assert stats["nonfinite_samples"] == 0
    assert "heterogeneous volumes" in stats["features"]
    assert abs(float(img[..., :3].mean()) - 1.0) < 0.01
    assert abs(float(img[8:16, 8:16, :3].mean()) - 1.0) < 0.01
    s, _ = medium_scene(linear_program(a=0.5, b=2.0), majorant_scale=0.6)
    img, stats = render(pc, s, 16, 16, samples=4096, max_bounces=1024)
    assert stats["nonfinite_samples"] == 0
    assert abs(float(img[..., :3].mean()) - 1.0) < 0.02


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_absorbing_and_emitting_program_closed_forms():
    """Along the central ray through x (chord 2, sigma_a = sigma(x)): the world seen through
    it, exp(-tau(2)); an emission e in a black world: e * integral of exp(-tau) over the chord."""
    prog = linear_program(albedo=0.0, absorb=1.0)
    s, _ = medium_scene(prog)
    s.set_camera(camera(pc, (-5, 0, 0), (0, 0, 0), lens=50.0))
    img, _ = render(pc, s, 17, 17, samples=1024)
    centre = img[7:10, 7:10, :3].mean(axis=(0, 1))  # chords through the whole cube along x
    assert centre == pytest.approx([math.exp(-tau(2.0))] * 3, rel=0.03)
    e = 0.7
    s, _ = medium_scene(linear_program(albedo=0.0, absorb=1.0, emission=(e, e, e)), world=0.0)
    s.set_camera(camera(pc, (-5, 0, 0), (0, 0, 0), lens=50.0))
    img, _ = render(pc, s, 17, 17, samples=1024)
    ts = np.linspace(0.0, 2.0, 20001)
    want = e * np.trapz(np.exp(-tau(ts)), ts)
    assert img[7:10, 7:10, :3].mean(axis=(0, 1)) == pytest.approx([want] * 3, rel=0.03)
