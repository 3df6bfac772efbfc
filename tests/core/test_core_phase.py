"""The Volume Scatter node's phase functions in the core (Cycles 4.5's Henyey-Greenstein,
Draine, Rayleigh, Fournier-Forand and Mie, the last a mixture of an HG and a Draine lobe):
each density integrates to 1 and the integrator's samples follow it (chi-square over
scattering-angle bins, with a check that the test notices a wrong parameter)."""
import math

import numpy as np
import pytest

from core_scenes import core
from test_core_volumes import chi_square_ok

pc = core()
pytestmark = pytest.mark.sanitize

CASES = [
    ("hg", [0.6]),
    ("draine", [0.3, 0.5]),
    ("draine", [-0.6, 2.0]),
    ("draine", [0.02, 250.0]),
    ("rayleigh", []),
    ("ff", [0.1, 1.33]),   # Blender's defaults
    ("ff", [0.3, 1.4]),
    ("mie", [20.0]),       # Blender's default diameter
    ("mie", [0.05]),
    ("mie", [2.5]),
]
# A slightly different phase for each case (the chi-square test must reject its samples).
WRONG = {
    "hg": ("hg", [0.55]), "draine": ("draine", None), "rayleigh": ("draine", [0.0, 0.8]),
    "ff": ("ff", None), "mie": ("mie", None),
}

# Scattering-angle bins: fine near the forward peaks (Fournier-Forand's is infinite at 0).
EDGES = np.concatenate([[0.0], np.geomspace(1e-3, 0.5, 20), np.linspace(0.5, math.pi, 31)[1:]])


def bin_probabilities(kind, params):
    """Each angle bin's probability, the density integrated numerically (the first bin takes
    what the others leave: the forward peak); and the integral over all directions."""
    probs, total = [], 0.0
    for a, b in zip(EDGES[1:-1], EDGES[2:]):
        th = np.linspace(a, b, 4001)
        f = pc.phase_pdf(kind, params, np.cos(th).astype(np.float32)).astype(np.float64)
        p = np.trapz(f * 2.0 * math.pi * np.sin(th), th)
        probs.append(p)
        total += p
    return np.array([1.0 - total] + probs), total


def forward_mass(kind, params):
    """The density's integral over the first bin (theta < 1e-3), in the small-angle limit."""
    th = np.geomspace(1e-9, 1e-3, 4001)
    f = pc.phase_pdf(kind, params, np.cos(th).astype(np.float64).astype(np.float32)).astype(np.float64)
    return np.trapz(f * 2.0 * math.pi * th, th)


@pytest.mark.parametrize("kind,params", CASES)
def test_phase_integrates_to_one(kind, params):
    probs, total = bin_probabilities(kind, params)
    # Outside the forward bin the density is smooth; inside it, float cosines cannot resolve
    # the angle, so Fournier-Forand's peak is bounded there: below 1e-3 of the total it holds.
    assert -1e-5 <= probs[0] < 0.02, probs[0]
    if kind != "ff":
        assert abs(total + forward_mass(kind, params) - 1.0) < 2e-3, total
    else:
        assert total < 1.0 and total > 0.97


@pytest.mark.parametrize("kind,params", CASES)
def test_phase_samples_follow_its_pdf(kind, params):
    n = 200_000
    u = np.random.default_rng(7).random((n, 2), dtype=np.float32)
    dirs, pdfs = pc.sample_phase(kind, params, u)
    assert np.all(np.isfinite(dirs)) and np.all(pdfs > 0.0)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-4)
    th = np.arccos(np.clip(dirs[:, 2].astype(np.float64), -1.0, 1.0))
    # The returned pdf is the density at the sampled direction (away from the unresolved peak).
    away = th > 1e-2
    assert np.allclose(pdfs[away], pc.phase_pdf(kind, params, dirs[away, 2]), rtol=2e-3)
    probs, _ = bin_probabilities(kind, params)
    probs[0] = max(probs[0], 0.0)
    nphi = 4
    phi = np.arctan2(dirs[:, 1], dirs[:, 0]) % (2.0 * math.pi)
    phi_edges = np.linspace(0.0, 2.0 * math.pi, nphi + 1)
    obs, _, _ = np.histogram2d(th, phi, bins=[EDGES, phi_edges])
    expected = np.repeat(probs[:, None] * n / nphi, nphi, axis=1)
    chi2, bound = chi_square_ok(obs.ravel(), expected.ravel())
    assert chi2 < bound, (kind, params, chi2, bound)
    # The test has power: samples of a slightly different phase fail it.
    other_kind, other = WRONG[kind]
    if other is None:  # Draine: g or (near 0) alpha; Fournier-Forand: B; Mie: the diameter
        if kind == "mie":
            other = [params[0] * 2.0]
        elif abs(params[0]) > 0.05:
            other = [params[0] * 1.3] + params[1:]
        else:
            other = [params[0], params[1] * 0.1]
    dirs2, _ = pc.sample_phase(other_kind, other, u)
    th2 = np.arccos(np.clip(dirs2[:, 2].astype(np.float64), -1.0, 1.0))
    wrong, _, _ = np.histogram2d(th2, np.arctan2(dirs2[:, 1], dirs2[:, 0]) % (2.0 * math.pi), bins=[EDGES, phi_edges])
    assert chi_square_ok(wrong.ravel(), expected.ravel())[0] > bound


def test_special_cases_match_their_closed_forms():
    c = np.linspace(-1.0, 1.0, 101, dtype=np.float32)
    rayleigh = 3.0 / (16.0 * math.pi) * (1.0 + c.astype(np.float64) ** 2)
    assert np.allclose(pc.phase_pdf("rayleigh", [], c), rayleigh, rtol=1e-5)
    assert np.allclose(pc.phase_pdf("draine", [0.0, 1.0], c), rayleigh, rtol=1e-5)
    # Draine with alpha 0 is HG.
    assert np.allclose(pc.phase_pdf("draine", [0.4, 0.0], c), pc.henyey_greenstein_pdf(0.4, c), rtol=1e-5)
    # Mie: Cycles' fit, a mixture (1 - w) HG + w Draine.
    g_hg, g_d, alpha, w = pc.mie_fit(20.0)
    assert 0.0 < w < 1.0 and 0.9 < g_hg < 1.0 and alpha > 1.0
    mix = (1 - w) * pc.phase_pdf("hg", [g_hg], c) + w * pc.phase_pdf("draine", [g_d, alpha], c)
    assert np.allclose(pc.phase_pdf("mie", [20.0], c), mix, rtol=1e-5)
    # Fournier-Forand's backscatter fraction is its parameter B.
    th = np.linspace(math.pi / 2, math.pi, 20001)
    b = np.trapz(pc.phase_pdf("ff", [0.1, 1.33], np.cos(th).astype(np.float32)) * 2 * math.pi * np.sin(th), th)
    assert abs(b - 0.1) < 1e-3, b


def test_bad_phase_parameters_are_clamped():
    u = np.random.default_rng(3).random((1000, 2), dtype=np.float32)
    for kind, params in [("draine", [float("nan"), float("inf")]), ("ff", [-3.0, 0.5]), ("ff", [float("nan"), 1.0]),
                         ("mie", [-5.0]), ("mie", [float("nan")]), ("draine", [2.0, -1.0])]:
        dirs, pdfs = pc.sample_phase(kind, params, u)
        assert np.all(np.isfinite(dirs)) and np.all(np.isfinite(pdfs)) and np.all(pdfs >= 0.0), (kind, params)
    with pytest.raises(ValueError):
        pc.sample_phase("cardioid", [], u)
