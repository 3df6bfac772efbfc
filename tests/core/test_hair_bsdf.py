"""The Principled Hair BSDF (Chiang) in the core: its sampling follows its pdf (chi-square over
the whole sphere), sample weights are f/pdf, and with no absorption it conserves energy (a
white furnace: the lobes' attenuations sum to 1, so the loss is only what the longitudinal and
azimuthal terms lose to their approximations and trimming)."""
import math

import numpy as np
import pytest

from bsdf_stats import sampling_chi2
from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize
N = 200_000

CASES = [
    {"roughness": 0.3, "radial_roughness": 0.3, "h": 0.3},
    {"roughness": 0.15, "radial_roughness": 0.5, "h": -0.7, "sigma": (0.4, 0.9, 1.8)},
    {"roughness": 0.6, "radial_roughness": 0.2, "h": 0.0, "offset": 0.1, "ior": 1.4},
]
# View directions in the fibre frame (x along the fibre): across it, tilted, nearly along it.
WO = [(0.0, 0.0, -1.0), (0.5, 0.0, -0.866), (0.9, 0.3, -0.316)]


def ids(p):
    return "-".join(f"{k}{v}" for k, v in p.items())


@pytest.mark.parametrize("params", CASES, ids=ids)
@pytest.mark.parametrize("wo", WO)
def test_hair_sampling_matches_pdf_chi2(params, wo):
    rng = np.random.default_rng(3)
    u = rng.random((N, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample("hair_chiang", params, wo, u)
    ok = flags >= 0
    stat, dof, p, exp = sampling_chi2(pc, "hair_chiang", params, wo, wi[ok], N, res=32)
    assert p > 1e-4, f"chi2={stat:.1f} dof={dof} p={p:.2e}"
    # Every sample succeeds, and the pdf integrates to 1 over the sphere.
    assert ok.mean() > 0.999
    assert abs(exp.sum() / N - 1.0) < 0.01


@pytest.mark.parametrize("params", CASES, ids=ids)
def test_hair_sample_weight_is_f_over_pdf(params):
    u = np.random.default_rng(4).random((3000, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample("hair_chiang", params, WO[1], u)
    ok = flags >= 0
    f, pdf_e = pc.bsdf_eval("hair_chiang", params, WO[1], wi[ok])
    assert np.allclose(pdf[ok], pdf_e, rtol=2e-3, atol=1e-6)
    assert np.allclose(weight[ok] * pdf_e[:, None], f, rtol=2e-3, atol=1e-6)


def sphere_integral(params, wo, res=384):
    """The integral of f*cos over the sphere (midpoint rule in cos theta and phi)."""
    ct = (np.arange(res) + 0.5) / res * 2 - 1
    ph = (np.arange(2 * res) + 0.5) / (2 * res) * 2 * np.pi - np.pi
    CT, PH = np.meshgrid(ct, ph, indexing="ij")
    st = np.sqrt(1 - CT**2)
    wi = np.stack([st * np.cos(PH), st * np.sin(PH), CT], -1).reshape(-1, 3).astype(np.float32)
    f, _ = pc.bsdf_eval("hair_chiang", params, wo, wi)
    return f.sum(axis=0) * (2.0 / res) * (2 * np.pi / (2 * res))


@pytest.mark.parametrize("roughness", [0.2, 0.5, 0.9])
@pytest.mark.parametrize("h", [0.0, 0.6, -0.9])
def test_hair_white_furnace(roughness, h):
    """No absorption: R + TT + TRT + TRRT+ attenuations sum to exactly 1, so the albedo is 1 up
    to the longitudinal term's normalisation under the cuticle tilt (Cycles' model, < 2 %)."""
    for wo in WO:
        a = sphere_integral({"roughness": roughness, "radial_roughness": 0.3, "h": h}, wo)
        assert np.all(np.abs(a - 1.0) < 0.02), (wo, a)
    # With absorption the fibre darkens: less than 1, more than the R lobe alone.
    a = sphere_integral({"roughness": roughness, "radial_roughness": 0.3, "h": h, "sigma": (0.5, 1.0, 4.0)}, WO[0])
    assert 0.03 < a[2] < a[1] < a[0] < 0.95


def test_hair_extreme_parameters_stay_finite():
    """Roughness and radial roughness at their clamps, IOR 1 and below 1, h at +-1, huge
    absorption, views along the fibre: evaluation and sampling stay finite."""
    rng = np.random.default_rng(9)
    u = rng.random((4000, 3), dtype=np.float32)
    wi_eval = rng.normal(size=(4000, 3)).astype(np.float32)
    wi_eval /= np.linalg.norm(wi_eval, axis=1, keepdims=True)
    for params in ({"roughness": 0.0, "radial_roughness": 0.0, "h": 1.0},
                   {"roughness": 1.0, "radial_roughness": 1.0, "h": -1.0, "ior": 1.0},
                   {"roughness": 0.01, "radial_roughness": 2.0, "h": 0.99, "ior": 0.7, "coat": 1.0},
                   {"roughness": 0.3, "sigma": (1e6, 1e3, 0.0), "offset": 1.5}):
        for wo in [(1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.7071, 0.7071, 0.0)]:
            wi, w, pdf, flags = pc.bsdf_sample("hair_chiang", params, wo, u)
            ok = flags >= 0
            assert np.isfinite(wi[ok]).all() and np.isfinite(w[ok]).all() and (pdf[ok] > 0).all()
            f, p = pc.bsdf_eval("hair_chiang", params, wo, wi_eval)
            assert np.isfinite(f).all() and np.isfinite(p).all() and (f >= 0).all()
