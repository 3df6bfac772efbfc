"""Cycles' Hair BSDF node (Reflection and Transmission components) in the core: its sampling
follows its own density (chi-square over the sphere), a sample's weight is 1 (Cycles: eval =
pdf), and the evaluation that light samples use is Cycles' bsdf_hair_*_eval, checked against an
independent numpy transcription. Cycles' sampling and evaluation differ (a sample is never
tested against N's side; a reflection sample may land past 90 degrees of azimuth, where the
evaluation is 0): both are kept, as hair_bsdf.h explains."""
import math

import numpy as np
import pytest

from bsdf_stats import sampling_chi2
from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize
N = 200_000

CASES = [
    {"roughness_u": 0.1, "roughness_v": 1.0},                       # the node's defaults
    {"roughness_u": 0.3, "roughness_v": 0.3, "offset": 0.15},
    {"roughness_u": 0.05, "roughness_v": 0.7, "offset": -0.1, "tangent": (0.6, 0.0, 0.8)},
]
# Views in the closure frame (+Z the normal; the fibre along +X unless a case says otherwise).
WO = [(0.0, 0.3, 0.954), (0.5, -0.2, 0.843), (-0.7, 0.1, 0.707)]
KINDS = ["hair_reflection", "hair_transmission"]


def ids(p):
    return "-".join(f"{k}{v}" for k, v in p.items())


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("params", CASES, ids=ids)
@pytest.mark.parametrize("wo", WO)
def test_sampling_matches_its_density_chi2(kind, params, wo):
    u = np.random.default_rng(5).random((N, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample(kind, params, wo, u)
    ok = flags >= 0
    stat, dof, p, exp = sampling_chi2(pc, kind, params, wo, wi[ok], N, res=32, sampled=True)
    assert p > 1e-4, f"chi2={stat:.1f} dof={dof} p={p:.2e}"
    # Only samples that land within 0.001 rad of the fibre axis are refused (Cycles: pdf 0).
    assert ok.mean() > 0.99
    assert abs(exp.sum() / N - ok.mean()) < 0.01
    # Weight 1 and the reported pdf is the density along the sampled direction.
    assert np.allclose(weight[ok], 1.0)
    _, pdf_s = pc.bsdf_eval(kind, params, wo, wi[ok][:2000], sampled=True)
    assert np.allclose(pdf[ok][:2000], pdf_s, rtol=2e-3, atol=1e-6)


def cycles_eval(kind, params, wo, wi):
    """Cycles' bsdf_hair_reflection_eval / bsdf_hair_transmission_eval transcribed in numpy
    (I = wo, omega_in = wi; N = +Z; T the tangent)."""
    r1 = min(max(params.get("roughness_u", 0.1), 0.001), 1.0)
    r2 = min(max(params.get("roughness_v", 1.0), 0.001), 1.0)
    off = params.get("offset", 0.0)
    T = np.asarray(params.get("tangent", (1.0, 0.0, 0.0)), np.float64)
    T = T / np.linalg.norm(T)
    I = np.asarray(wo, np.float64)
    I = I / np.linalg.norm(I)
    iz = I @ T
    locy = I - T * iz
    locy /= np.linalg.norm(locy)
    theta_r = math.pi / 2 - math.acos(iz)
    wz = wi @ T
    wy = wi - np.outer(wz, T)
    wy /= np.linalg.norm(wy, axis=1, keepdims=True)
    theta_i = np.pi / 2 - np.arccos(np.clip(wz, -1, 1))
    cosphi = np.clip(wy @ locy, -1, 1)
    a = math.atan(((math.pi / 2 + theta_r) / 2 - off) / r1)
    b = math.atan(((-math.pi / 2 + theta_r) / 2 - off) / r1)
    t = (theta_i + theta_r) / 2 - off
    theta_pdf = r1 / (2 * (t * t + r1 * r1) * (a - b) * np.cos(theta_i))
    if kind == "hair_reflection":
        phi = np.minimum(np.arccos(cosphi) / r2, np.pi)
        phi_pdf = np.cos(phi / 2) * 0.25 / r2
        bad = (wi[:, 2] < 0) | (cosphi < 0)
    else:
        p = np.pi - np.arccos(cosphi)
        c = 2 * math.atan(math.pi / 2 / r2)
        phi_pdf = r2 / (c * (p * p + r2 * r2))
        bad = wi[:, 2] >= 0
    bad |= np.pi / 2 - np.abs(theta_i) < 0.001
    return np.where(bad, 0.0, phi_pdf * theta_pdf)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("params", CASES, ids=ids)
def test_eval_is_cycles(kind, params):
    rng = np.random.default_rng(6)
    wi = rng.normal(size=(4000, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    # Within 3 degrees of the fibre the azimuth and 1 / cos(theta) are ill-conditioned in float.
    T = np.asarray(params.get("tangent", (1.0, 0.0, 0.0)))
    wi = wi[np.abs(wi @ (T / np.linalg.norm(T))) < 0.9986]
    for wo in WO:
        f, pdf = pc.bsdf_eval(kind, params, wo, wi.astype(np.float32))
        ref = cycles_eval(kind, params, wo, wi)
        assert np.allclose(pdf, ref, rtol=2e-3, atol=1e-5), np.abs(pdf - ref).max()
        assert np.allclose(f, pdf[:, None])  # f * |cos| is the pdf, per channel
        assert (ref > 0).mean() > 0.2        # the comparison covers the lobe, not only zeros


def test_eval_and_sampling_differ_only_where_cycles_does():
    """Reflection with roughness_v 1: where the evaluation is nonzero it equals the sampling
    density; the sampling also covers the other side of N and azimuths beyond 90 degrees."""
    params = CASES[0]
    rng = np.random.default_rng(7)
    wi = rng.normal(size=(20000, 3)).astype(np.float32)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    _, pe = pc.bsdf_eval("hair_reflection", params, WO[0], wi)
    _, ps = pc.bsdf_eval("hair_reflection", params, WO[0], wi, sampled=True)
    on = pe > 0
    assert np.allclose(pe[on], ps[on], rtol=1e-4)
    assert ((ps > 0) & ~on).mean() > 0.05


def test_bad_inputs_are_clamped_not_nan():
    for params in ({"roughness_u": float("nan"), "roughness_v": -3.0}, {"roughness_u": 0.0, "roughness_v": 0.0}):
        u = np.random.default_rng(8).random((2000, 3), dtype=np.float32)
        wi, weight, pdf, flags = pc.bsdf_sample("hair_reflection", params, WO[1], u)
        assert np.isfinite(wi).all() and np.isfinite(weight).all() and np.isfinite(pdf).all()
        f, p = pc.bsdf_eval("hair_transmission", params, WO[1], wi)
        assert np.isfinite(f).all() and np.isfinite(p).all()
