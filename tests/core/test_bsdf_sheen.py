"""Sheen, rough diffuse and toon lobes through the core module (issue 24): Zeltner et al.'s
microfibre sheen (an LTC fitted per roughness and view, Cycles 4.5's table), Ashikhmin's velvet,
Cycles' energy-preserving Oren-Nayar and the Toon BSDF's cones. Sampling follows each pdf (chi-square), sample weights are
f cos / pdf, the sheen's LTC is a normalised density for every entry of the fit, and white
furnaces state the energy: rough diffuse of albedo 1 keeps all of it (EON's promise), sheen over
white diffuse keeps all of it too (Cycles' layering gives the layer below 1 - the sheen albedo)."""
import math

import numpy as np
import pytest

from bsdf_stats import sampling_chi2
from core_scenes import core
from test_core_materials import closure, furnace

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
N = 200_000
WO = [(0.3, 0.2, 0.93), (0.8, 0.0, 0.2), (0.2, -0.3, -0.9)]  # incl. grazing and from behind


def lobe(kind, params, wo):
    """The lobe's parameters for this view: sheen and Oren-Nayar are set up per view cosine."""
    p = dict(params)
    if kind in ("sheen", "oren_nayar"):
        p["cos_view"] = abs(wo[2])
    if kind in ("sheen", "oren_nayar"):  # a view from behind is a backfacing hit: lit from behind
        p["back"] = wo[2] < 0.0
    return p


CASES = [
    ("sheen", {"roughness": 0.5}),
    ("sheen", {"roughness": 0.15}),
    ("sheen", {"roughness": 1.0}),
    ("velvet", {"sigma": 0.5}),
    ("oren_nayar", {"roughness": 0.5, "color": (0.8, 0.5, 0.2)}),
    ("oren_nayar", {"roughness": 1.0}),
    ("toon", {"size": 0.8, "smooth": 0.3}),
    ("toon", {"size": 0.5, "smooth": 0.5, "glossy": True}),
]


def ids(case):
    kind, p = case
    return kind + "-" + "-".join(f"{k}{v}" for k, v in p.items())


@pytest.mark.parametrize("case", CASES, ids=ids)
@pytest.mark.parametrize("wo", WO)
def test_sampling_matches_pdf_chi2(case, wo):
    kind, params = case
    params = lobe(kind, params, wo)
    u = np.random.default_rng(7).random((N, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample(kind, params, wo, u)
    ok = flags >= 0
    stat, dof, p, exp = sampling_chi2(pc, kind, params, wo, wi[ok], N)
    assert p > 1e-4, f"chi2={stat:.1f} dof={dof} p={p:.2e}"
    assert abs(ok.mean() - exp.sum() / N) < 0.01 + 3 / math.sqrt(N)
    # Samples stay on the view's side; weights are f cos / pdf.
    assert (np.sign(wi[ok, 2]) == np.sign(wo[2])).all()
    f, pdf_e = pc.bsdf_eval(kind, params, wo, wi[ok][:2000])
    assert np.allclose(pdf[ok][:2000], pdf_e, rtol=2e-3, atol=1e-6)
    assert np.allclose(weight[ok][:2000] * pdf_e[:, None], f, rtol=2e-3, atol=1e-6)


def hemisphere(n=400):
    ct, ph = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi - np.pi,
                         indexing="ij")
    st = np.sqrt(1 - ct**2)
    wi = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3).astype(np.float32)
    return wi, (1 / n) * (np.pi / n)


def test_sheen_ltc_is_a_normalised_density_across_the_fit():
    # eval is the LTC's density (the albedo lives in the closure weight): it must integrate to 1
    # over the hemisphere for every roughness and view the fit covers, or the layer would gain
    # or lose energy that its albedo does not say.
    # (Where the fit's albedo is ~0, very smooth fibres seen steeply, its a is 0: a lobe squeezed
    # onto the horizon that carries no energy; those entries are left out.)
    wi, dw = hemisphere()
    for rough in (0.15, 0.3, 0.5, 0.8, 1.0):
        for mu in (0.05, 0.3, 0.7, 1.0):
            if pc.sheen_albedo(rough, mu) < 0.01:
                continue
            wo = (math.sqrt(1 - mu * mu), 0.0, mu)
            f, pdf = pc.bsdf_eval("sheen", {"roughness": rough, "cos_view": mu}, wo, wi)
            total = f[:, 0].sum() * dw
            assert abs(total - 1.0) < 0.01, (rough, mu, total)
            assert np.allclose(f[:, 0], pdf)


def test_oren_nayar_white_furnace_keeps_all_energy():
    # EON: with albedo 1 the multiple-scattering term returns what single scattering loses,
    # from every view; with albedo 0.5 it returns its share (rho^2 Eavg / (1 - rho (1 - Eavg)))
    # on top of single scattering, so the lobe reflects more than rho * E_ss but less than 1.
    wi, dw = hemisphere()
    for rough in (0.3, 0.7, 1.0):
        for mu in (0.1, 0.5, 0.95):
            wo = (math.sqrt(1 - mu * mu), 0.0, mu)
            f, _ = pc.bsdf_eval("oren_nayar", {"roughness": rough, "cos_view": mu}, wo, wi)
            total = f[:, 0].sum() * dw
            assert abs(total - 1.0) < 0.01, (rough, mu, total)
            grey, _ = pc.bsdf_eval("oren_nayar", {"roughness": rough, "cos_view": mu, "color": (0.5,) * 3}, wo, wi)
            single = pc.bsdf_eval("oren_nayar", {"roughness": rough, "cos_view": mu, "color": (0.0,) * 3}, wo, wi)[0]
            g, s = grey[:, 0].sum() * dw, single[:, 0].sum() * dw
            assert s < 1.0 and s < g < 1.0, (rough, mu, s, g)
    # Sampled, the weight's mean is the same albedo.
    u = np.random.default_rng(2).random((100_000, 3), dtype=np.float32)
    _, w, _, flags = pc.bsdf_sample("oren_nayar", {"roughness": 1.0, "cos_view": 0.4}, (0.9165, 0.0, 0.4), u)
    assert abs(w[flags >= 0, 0].sum() / len(u) - 1.0) < 0.01


def test_sheen_fit_albedo_is_physical():
    # The fitted albedo: within [0, 1], rising with roughness (more fibres scatter) and strongest
    # at grazing views, where light crosses the most fibres.
    mus = np.linspace(0.05, 1.0, 12)
    for rough in (0.3, 0.6, 1.0):
        alb = [sheen_albedo(rough, mu) for mu in mus]
        assert all(0.0 <= a <= 1.0 for a in alb)
        assert all(b <= a + 1e-3 for a, b in zip(alb, alb[1:])), alb
    assert sheen_albedo(0.3, 0.5) < sheen_albedo(0.6, 0.5) < sheen_albedo(1.0, 0.5)


def sheen_albedo(rough, mu):
    """The fitted albedo the core gives the Sheen BSDF's closure: a white Sheen BSDF in a white
    furnace shows exactly it (one bounce: the camera ray's)."""
    return pc.sheen_albedo(rough, mu)


def blocks(img, n=8):
    """Means of n x n pixel blocks (per-pixel noise of the rough lobes' weights averages out)."""
    h, w = img.shape[:2]
    return img[..., 0].reshape(h // n, n, w // n, n).mean(axis=(1, 3))


def test_furnace_rough_diffuse_and_sheen_over_white_diffuse():
    # Rough Diffuse BSDF and Principled Diffuse Roughness, albedo 1: invisible in a white furnace.
    for prog in (closure("diffuse", roughness=1.0),
                 closure("principled", base_color=(1.0, 1.0, 1.0), specular_level=0.0, diffuse_roughness=0.8)):
        img = furnace(prog, samples=64)
        assert np.abs(blocks(img) - 1.0).max() < 0.01, (prog[-1], blocks(img))
    # Sheen 1 over a white diffuse base (no specular): the base keeps 1 - sheen albedo, so the
    # sum is 1 at every view (Cycles' layering is exact here); with a black base only the
    # sheen's albedo remains, largest towards the rim.
    img = furnace(closure("principled", base_color=(1.0, 1.0, 1.0), specular_level=0.0,
                          sheen_weight=1.0, sheen_roughness=0.5), samples=64)
    assert np.abs(blocks(img) - 1.0).max() < 0.01, blocks(img)
    dark = furnace(closure("principled", base_color=(0.0, 0.0, 0.0), specular_level=0.0,
                           sheen_weight=1.0, sheen_roughness=0.5), samples=64)
    centre = dark[15:17, 15:17, 0].mean()
    assert abs(centre - sheen_albedo(0.5, 1.0)) < 0.02, centre
    assert dark[16, 3:6, 0].mean() > centre  # towards the rim: grazing views


def test_sheen_lobe_stays_on_the_geometry_side_at_a_smooth_silhouette():
    """Where a smooth normal turns away from the view (a silhouette of a coarse mesh: the view
    just below the shading normal, the hit still front-facing), Cycles' sheen stays on its
    normal's side: light from above the normal reflects, light from below does not. A
    backfacing hit (back) is the mirror image. (Before: the lobe mirrored to the view's side.)"""
    wo = (0.6, 0.0, -0.05)
    up = np.array([[0.3, 0.2, 0.9], [-0.5, 0.1, 0.6]], np.float32)
    down = up * np.float32([1, 1, -1])
    for back, lit, dark in ((False, up, down), (True, down, up)):
        p = {"roughness": 0.5, "cos_view": 0.0, "back": back}
        f_lit, pdf_lit = pc.bsdf_eval("sheen", p, wo, lit)
        f_dark, pdf_dark = pc.bsdf_eval("sheen", p, wo, dark)
        assert (f_lit > 0).all() and (pdf_lit > 0).all()
        assert (f_dark == 0).all() and (pdf_dark == 0).all()
        u = np.random.default_rng(3).random((1000, 3), dtype=np.float32)
        wi, _, _, flags = pc.bsdf_sample("sheen", p, wo, u)
        assert (np.sign(wi[flags >= 0, 2]) == (-1 if back else 1)).all()
