"""BSDF tests in the Mitsuba style, through the core module: sampled directions follow the
evaluated pdf (chi-square), sample weights equal f*cos/pdf, reflection is reciprocal, and a white
furnace (the directional albedo) conserves energy where the model does."""
import math

import numpy as np
import pytest

from bsdf_stats import eval_both_ways, sample_then_eval, sampling_chi2
from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
N = 200_000
CASES = [
    ("diffuse", {}),
    ("translucent", {}),  # diffuse transmission (Translucent BSDF)
    ("conductor", {"alpha": 0.05}),
    ("conductor", {"alpha": 0.3}),
    ("conductor", {"alpha": 0.8, "f0": (0.9, 0.6, 0.3), "schlick": True}),
    # Principled's metal (F82-Tint) and dielectric specular (generalized Schlick, real Fresnel).
    ("conductor", {"alpha": 0.25, "f0": (0.9, 0.6, 0.3), "f82_tint": (0.4, 0.8, 1.0)}),
    ("conductor", {"alpha": 0.36, "f0": (0.06, 0.04, 0.02), "specular_eta": 1.5}),
    # Metallic BSDF's physical conductor (f0: n, with extinction k; Blender's default gold-ish).
    ("conductor", {"alpha": 0.3, "f0": (2.757, 2.513, 2.231), "conductor_k": (3.867, 3.404, 3.009)}),
    ("dielectric", {"alpha": 0.1, "eta": 1.5}),
    ("dielectric", {"alpha": 0.4, "eta": 1.33}),
    # Principled glass with a Specular Tint: coloured reflection, the rest transmitted.
    ("dielectric", {"alpha": 0.3, "eta": 1.5, "f0_tint": (1.0, 0.5, 0.2)}),
    ("dielectric", {"alpha": 0.4, "eta": 1.5, "transmission": False}),
    ("dielectric", {"alpha": 0.3, "eta": 1.5, "reflection": False, "fresnel_on_transmission": False}),
    # Anisotropic GGX (alpha along the tangent, alpha_y across): reflection and glass.
    ("conductor", {"alpha": 0.08, "alpha_y": 0.5}),
    ("conductor", {"alpha": 0.6, "alpha_y": 0.15, "f0": (0.9, 0.6, 0.3), "f82_tint": (0.4, 0.8, 1.0)}),
    ("dielectric", {"alpha": 0.1, "alpha_y": 0.45, "eta": 1.5}),
    # Principled's Thin Film on its specular and on its glass (coloured Fresnel, from inside too).
    ("conductor", {"alpha": 0.3, "f0": (0.04, 0.04, 0.04), "specular_eta": 1.5, "film_thickness": 500.0}),
    ("dielectric", {"alpha": 0.25, "eta": 1.5, "film_thickness": 400.0, "film_ior": 1.33}),
]
WO = [(0.3, 0.2, 0.93), (0.8, 0.0, 0.2), (0.2, -0.3, -0.9)]  # incl. grazing and from inside


def ids(case):
    kind, p = case
    return kind + "-" + "-".join(f"{k}{v}" for k, v in p.items())


@pytest.mark.parametrize("case", CASES, ids=ids)
@pytest.mark.parametrize("wo", WO)
def test_sampling_matches_pdf_chi2(case, wo):
    kind, params = case
    rng = np.random.default_rng(7)
    u = rng.random((N, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample(kind, params, wo, u)
    ok = flags >= 0
    wi = wi[ok]
    # Samples that fail (e.g. below the surface) are the pdf's missing mass: compare only where
    # the pdf says samples go, pooling bins with few expected samples (Mitsuba's rule).
    stat, dof, p, exp = sampling_chi2(pc, kind, params, wo, wi, N)
    assert p > 1e-4, f"chi2={stat:.1f} dof={dof} p={p:.2e}"
    # Mass: the fraction of successful samples equals the pdf's integral over the sphere.
    assert abs(ok.mean() - exp.sum() / N) < 0.01 + 3 / math.sqrt(N)


@pytest.mark.parametrize("case", CASES, ids=ids)
def test_sample_weight_is_f_cos_over_pdf(case):
    kind, params = case
    ok, wi, weight, pdf, f, pdf_e = sample_then_eval(pc, kind, params, WO[0])
    assert np.allclose(pdf, pdf_e, rtol=2e-3, atol=1e-6)
    assert np.allclose(weight * pdf_e[:, None], f, rtol=2e-3, atol=1e-6)


@pytest.mark.parametrize("case", [c for c in CASES if c[1].get("reflection", True)], ids=ids)
def test_reflection_is_reciprocal(case):
    kind, params = case
    rng = np.random.default_rng(5)
    a = rng.normal(size=(500, 3)).astype(np.float32)
    b = rng.normal(size=(500, 3)).astype(np.float32)
    a[:, 2], b[:, 2] = np.abs(a[:, 2]) + 0.05, np.abs(b[:, 2]) + 0.05
    a /= np.linalg.norm(a, axis=1)[:, None]
    b /= np.linalg.norm(b, axis=1)[:, None]
    fab, fba = eval_both_ways(pc, kind, params, a, b)
    # eval includes |cos(wi)|: divide it out on both sides.
    assert np.allclose(fab / b[:, 2:3], fba / a[:, 2:3], rtol=1e-3, atol=1e-6)


def albedo(kind, params, wo, n=200_000):
    u = np.random.default_rng(11).random((n, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample(kind, params, wo, u)
    return weight.mean(axis=0)


def test_white_furnace_energy():
    wo = (0.3, 0.2, 0.93)
    assert abs(albedo("diffuse", {}, wo)[0] - 1.0) < 1e-3
    # Smooth mirror and smooth glass: exactly 1 (refraction carries no 1/eta^2, as Cycles').
    assert abs(albedo("conductor", {"alpha": 0.0}, wo)[0] - 1.0) < 1e-6
    wi, w, _, flags = pc.bsdf_sample("dielectric", {"alpha": 0.0, "eta": 1.5}, wo, np.random.default_rng(1).random((100_000, 3), dtype=np.float32))
    assert ((flags & 2) != 0).any()
    assert abs(w[:, 0].mean() - 1.0) < 1e-3
    # Single-scattering GGX loses energy to the multiple bounces it ignores: small when smooth,
    # larger when rough (the known loss; Blender's default Multiscatter GGX restores it).
    assert 0.97 < albedo("conductor", {"alpha": 0.1}, wo)[0] <= 1.001
    rough = albedo("conductor", {"alpha": 1.0}, wo)[0]
    assert 0.3 < rough < 0.9
    # ...and the sampled albedo is the integral of eval (sampling and evaluation agree).
    ct, ph = np.meshgrid((np.arange(400) + 0.5) / 400, (np.arange(800) + 0.5) / 800 * 2 * np.pi - np.pi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    wi = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3).astype(np.float32)
    f, _ = pc.bsdf_eval("conductor", {"alpha": 1.0}, wo, wi)
    integral = f[:, 0].sum() * (1 / 400) * (2 * np.pi / 800)
    assert abs(rough - integral) < 0.005, (rough, integral)
    # Never more than 1 (glass too, from either side: no eta^2 on its transmission).
    for kind, params in CASES:
        for w in WO:
            a = albedo(kind, params, w, 50_000)
            assert a.max() <= 1.0 + 0.01, (kind, params, w, a)


def test_refraction_carries_no_eta_squared():
    """Refraction scales nothing, as Cycles' bsdf_microfacet_eval (docs/materials.md "Refraction:
    no 1/eta^2, as Cycles"): smooth glass conserves energy from outside and from inside (pbrt's
    radiance convention gave 1/eta^2 and eta^2 on the refracted share), and rough glass's
    transmission obeys f(a, b) / n_b^2 = f(b, a) / n_a^2 (n the IOR on each direction's side;
    pbrt's radiance BSDF has n_a^2 and n_b^2 swapped: the ratio below was 1 / 1.45^4 of this)."""
    u = np.random.default_rng(5).random((100_000, 3), dtype=np.float32)
    for wo in ((0.3, 0.2, 0.93), (0.2, 0.1, -0.97)):
        for params in ({"alpha": 0.0, "eta": 1.5}, {"alpha": 0.0, "eta": 1.5, "reflection": False, "fresnel_on_transmission": False}):
            _, w, _, flags = pc.bsdf_sample("dielectric", params, wo, u)
            assert ((flags & 2) != 0).any() and abs(w[:, 0].mean() - 1.0) < 1e-3, (wo, params, w[:, 0].mean())
    rng = np.random.default_rng(6)
    a = rng.normal(size=(2000, 3)).astype(np.float32)
    b = rng.normal(size=(2000, 3)).astype(np.float32)
    a[:, 2], b[:, 2] = np.abs(a[:, 2]) + 0.05, -np.abs(b[:, 2]) - 0.05  # a outside, b inside
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    for params in ({"alpha": 0.3, "eta": 1.45}, {"alpha": 0.3, "eta": 1.45, "distribution": "beckmann"}):
        fab, fba = eval_both_ways(pc, "dielectric", params, a, b)
        ok = (fab[:, 0] > 1e-6) & (fba[:, 0] > 1e-6)
        assert ok.sum() > 100  # (most random pairs have no refracting microfacet)
        # (eval includes |cos(wi)|: divided out)
        np.testing.assert_allclose(fab[ok] / np.abs(b[ok, 2:3]) / 1.45**2, fba[ok] / a[ok, 2:3], rtol=2e-3, atol=3e-5)


def test_translucent_transmits_all_to_the_other_side():
    # A white Translucent BSDF conserves energy (Cycles' bsdf_translucent: cos / pi on the far
    # side), from either side, and never reflects.
    u = np.random.default_rng(4).random((100_000, 3), dtype=np.float32)
    for wo in WO:
        wi, w, pdf, flags = pc.bsdf_sample("translucent", {}, wo, u)
        assert abs(w[:, 0].mean() - 1.0) < 1e-3
        assert ((flags & 2) != 0).all() and (wi[:, 2] * wo[2] < 0).all()
        f, _ = pc.bsdf_eval("translucent", {}, wo, np.array([(0.0, 0.0, math.copysign(1.0, wo[2]))], np.float32))
        assert f[0, 0] == 0.0


def test_conductor_fresnel_is_exact():
    # A smooth physical conductor reflects the exact Fresnel of its complex IOR: against the
    # s and p amplitudes computed here with complex numbers (Snell's law with n + ik).
    n, k = np.array([0.2, 1.1, 2.757]), np.array([3.9, 2.4, 3.867])
    for c in (1.0, 0.7, 0.3, 1 / 7, 0.02):
        wo = (math.sqrt(1 - c * c), 0.0, c)
        _, w, _, _ = pc.bsdf_sample("conductor", {"alpha": 0.0, "f0": tuple(n), "conductor_k": tuple(k)}, wo,
                                    np.full((1, 3), 0.5, np.float32))
        eta = n + 1j * k
        ct = np.sqrt(1 - (1 - c * c) / eta**2)
        rs = (c - eta * ct) / (c + eta * ct)
        rp = (eta * c - ct) / (eta * c + ct)
        expected = 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)
        assert np.allclose(w[0], expected, rtol=2e-4, atol=1e-6), (c, w[0], expected)


def test_fresnel_and_total_internal_reflection():
    u = np.random.default_rng(2).random((50_000, 3), dtype=np.float32)
    # From inside glass beyond the critical angle (41.8 deg): everything reflects.
    wo = (np.sin(np.radians(60)), 0.0, -np.cos(np.radians(60)))
    wi, w, _, flags = pc.bsdf_sample("dielectric", {"alpha": 0.0, "eta": 1.5}, wo, u)
    assert ((flags & 1) != 0).all()
    # Normal incidence from outside: R = ((1.5 - 1) / 2.5)^2 = 0.04.
    wi, w, _, flags = pc.bsdf_sample("dielectric", {"alpha": 0.0, "eta": 1.5}, (0, 0, 1), u)
    assert abs(((flags & 1) != 0).mean() - 0.04) < 0.005
    # IOR 1: no reflection, straight through.
    wi, w, _, flags = pc.bsdf_sample("dielectric", {"alpha": 0.0, "eta": 1.0}, WO[0], u)
    assert ((flags & 2) != 0).all() and np.allclose(wi, -np.array(WO[0]) / np.linalg.norm(WO[0]), atol=1e-5)
    # Schlick: the seed's approximation, close to exact at normal incidence.
    wi, w, _, flags = pc.bsdf_sample("dielectric", {"alpha": 0.0, "eta": 1.5, "schlick": True}, (0, 0, 1), u)
    assert abs(((flags & 1) != 0).mean() - 0.04) < 0.005
