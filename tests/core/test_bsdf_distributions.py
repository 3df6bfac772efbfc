"""Blender's other microfacet distributions through the core module (issue 24): Beckmann on the
reflection and dielectric lobes, Ashikhmin-Shirley on the Glossy lobe, as Cycles 4.5 has them.
Sampled directions follow the evaluated pdf (chi-square), sample weights equal f*cos/pdf,
reflection is reciprocal, and eval matches an independent transcription of Cycles' formulas."""
import math

import numpy as np
import pytest

from bsdf_stats import eval_both_ways, sample_then_eval, sampling_chi2
from core_scenes import add_object, camera, core, render, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
N = 200_000
BECK = {"distribution": "beckmann"}
AS = {"distribution": "ashikhmin_shirley"}
CASES = [
    ("conductor", {"alpha": 0.05, **BECK}),
    ("conductor", {"alpha": 0.3, **BECK}),
    ("conductor", {"alpha": 0.9, "f0": (0.9, 0.6, 0.3), "f82_tint": (0.4, 0.8, 1.0), **BECK}),
    ("conductor", {"alpha": 0.08, "alpha_y": 0.5, **BECK}),
    ("conductor", {"alpha": 0.6, "alpha_y": 0.15, "f0": (2.757, 2.513, 2.231), "conductor_k": (3.867, 3.404, 3.009), **BECK}),
    ("dielectric", {"alpha": 0.1, "eta": 1.5, **BECK}),
    ("dielectric", {"alpha": 0.5, "eta": 1.33, **BECK}),
    ("dielectric", {"alpha": 0.3, "eta": 1.5, "reflection": False, "fresnel_on_transmission": False, **BECK}),
    ("dielectric", {"alpha": 0.4, "eta": 1.5, "transmission": False, **BECK}),
    ("conductor", {"alpha": 0.2, **AS}),
    ("conductor", {"alpha": 0.7, **AS}),
    ("conductor", {"alpha": 1.0, **AS}),  # exponent 0: a uniform half vector
    ("conductor", {"alpha": 0.1, "alpha_y": 0.45, **AS}),
    ("conductor", {"alpha": 0.6, "alpha_y": 0.2, **AS}),
]
WO = [(0.3, 0.2, 0.93), (0.8, 0.0, 0.2), (0.2, -0.3, -0.9)]  # incl. grazing and from inside


def ids(case):
    kind, p = case
    return kind + "-" + "-".join(f"{k}{v}" for k, v in p.items() if k != "distribution") + "-" + p["distribution"]


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def upper_directions(n, seed, z_min=0.05):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + z_min
    return unit(v).astype(np.float32)


@pytest.mark.parametrize("case", CASES, ids=ids)
@pytest.mark.parametrize("wo", WO)
def test_sampling_matches_pdf_chi2(case, wo):
    kind, params = case
    u = np.random.default_rng(7).random((N, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample(kind, params, wo, u)
    ok = flags >= 0
    assert np.isfinite(weight[ok]).all() and (pdf[ok] > 0).all()
    stat, dof, p, exp = sampling_chi2(pc, kind, params, wo, wi[ok], N)
    assert p > 1e-4, f"chi2={stat:.1f} dof={dof} p={p:.2e}"
    # Mass: the fraction of successful samples equals the pdf's integral over the sphere.
    assert abs(ok.mean() - exp.sum() / N) < 0.01 + 3 / math.sqrt(N)


@pytest.mark.parametrize("case", CASES, ids=ids)
@pytest.mark.parametrize("wo", WO[:2])
def test_sample_weight_is_f_cos_over_pdf(case, wo):
    kind, params = case
    ok, wi, weight, pdf, f, pdf_e = sample_then_eval(pc, kind, params, wo)
    assert ok.mean() > 0.25  # a uniform half vector (alpha 1) often reflects below the surface
    assert np.allclose(pdf, pdf_e, rtol=2e-3, atol=1e-6)
    assert np.allclose(weight * pdf_e[:, None], f, rtol=2e-3, atol=1e-6)


@pytest.mark.parametrize("case", [c for c in CASES if c[1].get("reflection", True)], ids=ids)
def test_reflection_is_reciprocal(case):
    kind, params = case
    a, b = upper_directions(400, 5), upper_directions(400, 6)
    fab, fba = eval_both_ways(pc, kind, params, a, b)
    assert np.abs(fab).max() > 0.05
    # eval includes |cos(wi)|: divide it out on both sides.
    assert np.allclose(fab / b[:, 2:3], fba / a[:, 2:3], rtol=1e-3, atol=1e-6)


# Cycles 4.5's formulas, transcribed independently in float64 (bsdf_microfacet.h,
# bsdf_ashikhmin_shirley.h), for a white reflection lobe: f * cos(wi) and the pdf.
def beckmann_lambda(ax, ay, v):
    s = ((ax * v[..., 0]) ** 2 + (ay * v[..., 1]) ** 2) / v[..., 2] ** 2
    a = 1 / np.sqrt(np.maximum(s, 1e-30))
    lam = ((0.396 * a - 1.259) * a + 1) / ((2.181 * a + 3.535) * a)
    return np.where(s < 0.39, 0.0, lam)


def beckmann_reference(ax, ay, wo, wi):
    h = unit(wo + wi)
    c2 = h[..., 2] ** 2
    d = np.exp(-((h[..., 0] / ax) ** 2 + (h[..., 1] / ay) ** 2) / c2) / (np.pi * ax * ay * c2**2)
    lo, li = beckmann_lambda(ax, ay, wo), beckmann_lambda(ax, ay, wi)
    common = d / wo[..., 2] * 0.25
    return common / (1 + lo + li), common / (1 + lo)


def ashikhmin_shirley_reference(ax, ay, wo, wi):
    nx, ny = 2 / ax**2 - 2, 2 / ay**2 - 2
    h = unit(wo + wi)
    h_o = np.abs((h * wo).sum(-1))
    e = (nx * h[..., 0] ** 2 + ny * h[..., 1] ** 2) / (1 - h[..., 2] ** 2)
    lobe = h[..., 2] ** e
    norm = np.sqrt((nx + 1) * (ny + 1)) / (8 * np.pi)
    pump = 1 / (h_o * np.maximum(wo[..., 2], wi[..., 2]))
    return wi[..., 2] * norm * lobe * pump, norm * lobe / h_o


@pytest.mark.parametrize("alphas", [(0.3, 0.3), (0.1, 0.5), (0.7, 0.25)])
@pytest.mark.parametrize("dist", ["beckmann", "ashikhmin_shirley"])
def test_eval_matches_cycles_formulas(dist, alphas):
    ax, ay = alphas
    params = {"alpha": ax, "distribution": dist}
    if ay != ax:
        params["alpha_y"] = ay
    ref = beckmann_reference if dist == "beckmann" else ashikhmin_shirley_reference
    wi = upper_directions(300, 9)
    for wo in [(0.3, 0.2, 0.93), (0.8, 0.0, 0.2), (-0.5, 0.6, 0.62)]:
        wo = tuple(unit(wo))
        f, pdf = pc.bsdf_eval("conductor", params, wo, wi)
        f_ref, pdf_ref = ref(ax, ay, np.asarray(wo)[None], wi.astype(np.float64))
        assert np.allclose(f[:, 0], f_ref, rtol=2e-3, atol=1e-5)
        assert np.allclose(pdf, pdf_ref, rtol=2e-3, atol=1e-5)
        # ...and it is not GGX's lobe.
        f_ggx, _ = pc.bsdf_eval("conductor", {k: v for k, v in params.items() if k != "distribution"}, wo, wi)
        assert np.abs(f_ggx[:, 0] - f_ref).max() > 0.01


def test_beckmann_glass_is_not_ggx_and_its_lobes_share_the_light():
    # Rough Beckmann glass differs from GGX (GGX's longer tails), yet both put the same Fresnel
    # share of the samples into reflection, and a smooth one is the same perfect interface.
    wo = (0.3, 0.2, 0.93)
    u = np.random.default_rng(2).random((100_000, 3), dtype=np.float32)
    beck = pc.bsdf_sample("dielectric", {"alpha": 0.4, "eta": 1.5, **BECK}, wo, u)
    ggx = pc.bsdf_sample("dielectric", {"alpha": 0.4, "eta": 1.5}, wo, u)
    refl_b, refl_g = (beck[3] & 1) != 0, (ggx[3] & 1) != 0
    assert abs(refl_b.mean() - refl_g.mean()) < 0.01
    assert np.abs(beck[0] - ggx[0]).max() > 0.05
    smooth = [pc.bsdf_sample("dielectric", {"alpha": 0.0, "eta": 1.5, **d}, wo, u) for d in ({}, BECK)]
    assert all(np.array_equal(x, y) for x, y in zip(*smooth))


def albedo(kind, params, wo, n=200_000):
    u = np.random.default_rng(11).random((n, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample(kind, params, wo, u)
    return weight.mean(axis=0)


def test_white_furnace_energy():
    wo = (0.3, 0.2, 0.93)
    # Single-scattering Beckmann loses a little to the bounces it ignores (no compensation, as
    # Cycles), more when rough; the sampled albedo is the integral of eval.
    assert 0.97 < albedo("conductor", {"alpha": 0.1, **BECK}, wo)[0] <= 1.001
    rough = albedo("conductor", {"alpha": 1.0, **BECK}, wo)[0]
    assert 0.4 < rough < 0.95
    ct, ph = np.meshgrid((np.arange(400) + 0.5) / 400, (np.arange(800) + 0.5) / 800 * 2 * np.pi - np.pi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    wi = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3).astype(np.float32)
    for dist in (BECK, AS):
        a = albedo("conductor", {"alpha": 0.6, **dist}, wo)[0]
        f, _ = pc.bsdf_eval("conductor", {"alpha": 0.6, **dist}, wo, wi)
        integral = f[:, 0].sum() * (1 / 400) * (2 * np.pi / 800)
        assert abs(a - integral) < 0.005, (dist, a, integral)
    # Never (much) more than 1 (glass too: no eta^2 on its transmission, as Cycles').
    for kind, params in CASES:
        for w in WO:
            a = albedo(kind, params, w, 50_000)
            assert a.max() <= 1.0 + 0.01, (kind, params, w, a)


def test_unknown_distribution_is_refused():
    wo, wi = (0.0, 0.0, 1.0), np.array([[0.0, 0.0, 1.0]], np.float32)
    with pytest.raises(ValueError, match="distribution"):
        pc.bsdf_eval("dielectric", {"alpha": 0.3, **AS}, wo, wi)  # Glossy only
    with pytest.raises(ValueError, match="distribution"):
        pc.bsdf_eval("conductor", {"alpha": 0.3, "distribution": "phong"}, wo, wi)


# ---------------------------------------------------------------- through shader programs


def furnace_centre(kind, flags, roughness=1.0, samples=64):
    """A white sphere of one closure in a white world, seen head on: a convex surface, so the
    centre pixels are the lobe's directional albedo at normal incidence."""
    s = pc.Scene()
    prog = [("const", 0, (roughness,)), ("const", 1, (1.0,)), ("const", 2, (1.45,)),
            ("closure", kind, None, {"roughness": 0, **({"ior": 2} if kind != "glossy" else {}),
                                     **{f: 1 for f in flags}})]
    pos, tris, nrm = uv_sphere(1.0, nu=64, nv=32)
    add_object(s, pos, tris, s.add_shader("m", prog))
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0, -4, 0), (0, 0, 0), lens=60.0))
    img, stats = render(pc, s, 16, 16, samples=samples, max_bounces=1)
    assert stats["nonfinite_samples"] == 0
    return img[7:9, 7:9, 0].mean()


def test_programs_pick_the_distribution():
    # Glossy at roughness 1: the three lobes lose different amounts of energy, each as its
    # BSDF says at normal incidence (the program's flag keys reach the lobe).
    for flags, dist in (((), "ggx"), (("beckmann",), "beckmann"), (("ashikhmin_shirley",), "ashikhmin_shirley")):
        expected = albedo("conductor", {"alpha": 1.0, "distribution": dist}, (0.0, 0.0, 1.0))[0]
        got = furnace_centre("glossy", flags)
        assert abs(got - expected) < 0.02, (dist, got, expected)
    assert abs(furnace_centre("glossy", ()) - furnace_centre("glossy", ("beckmann",))) > 0.03
    # Ashikhmin-Shirley is the Glossy BSDF's only.
    for kind in ("glass", "refraction", "metallic"):
        with pytest.raises(ValueError, match="Ashikhmin-Shirley"):
            pc.Scene().add_shader("bad", [("const", 0, (1.0,)), ("closure", kind, None, {"ashikhmin_shirley": 0})])
