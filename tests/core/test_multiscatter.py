"""Multiscatter GGX and the Principled BSDF's Cycles 4.5 layering, through the core module: the
generated albedo tables agree with a fresh integration, white furnaces keep (or, for
single-scatter GGX, lose) energy as Blender's models do, and the layering hands the diffuse what
the specular layer leaves."""
import sys
from pathlib import Path

import numpy as np
import pytest

from core_scenes import core
from test_core_materials import closure, furnace

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import gen_microfacet_tables as gen  # noqa: E402

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def test_tables_match_a_fresh_integration():
    stored = gen.read_header()
    # A coarse run of the generator (its own quadrature, 24x24 normals) on a few slices.
    e = gen.table_ggx_e(24)
    assert np.abs(e.ravel() - stored["ggx_E"]).max() < 0.01
    s = gen.table_gen_schlick_ior_s(24).ravel()
    assert np.abs(s - stored["ggx_gen_schlick_ior_s"]).max() < 0.01
    # Independent facts: a mirror reflects everything; rougher reflects less at normal
    # incidence; the dielectric factor s is 0 at normal incidence on a mirror.
    E = stored["ggx_E"].reshape(32, 32)
    assert E[:, 0].min() > 0.999 and np.all(np.diff(E[-1]) < 0)
    S = stored["ggx_gen_schlick_ior_s"].reshape(16, 16, 16)
    assert S[:, -1, 0].max() < 1e-3


def centre(img):
    return float(img[12:20, 12:20].mean())


def test_multiscatter_glossy_white_furnace():
    # Blender's default distribution keeps all the energy of a white rough glossy...
    for rough in (0.5, 1.0):
        img = furnace(closure("glossy", roughness=rough, multiscatter=1.0), samples=64)
        assert abs(centre(img) - 1.0) < 0.01 and abs(img.mean() - 1.0) < 0.01, rough
    # ...single-scatter GGX loses what its multiple bounces would have returned.
    lossy = centre(furnace(closure("glossy", roughness=1.0), samples=64))
    assert 0.2 < lossy < 0.6


def test_multiscatter_principled_metal_and_glass_white_furnace():
    img = furnace(closure("principled", base_color=(1.0, 1.0, 1.0), metallic=1.0, roughness=1.0,
                          multiscatter=1.0), samples=64)
    assert abs(centre(img) - 1.0) < 0.01
    single = furnace(closure("principled", base_color=(1.0, 1.0, 1.0), metallic=1.0, roughness=1.0),
                     samples=64)
    assert centre(single) < 0.6
    glass = furnace(closure("glass", roughness=0.6, ior=1.5, multiscatter=1.0), samples=128)
    assert abs(centre(glass) - 1.0) < 0.02


def test_coloured_multiscatter_saturates_like_kulla_conty():
    # A coloured lobe's extra bounces take the colour again: more than colour * 1, less than
    # colour / E (the colourless compensation), as Fms = F E_avg / (1 - F (1 - E_avg)) gives.
    c = 0.5
    img = furnace(closure("glossy", color=(c, c, c), roughness=1.0, multiscatter=1.0), samples=64)
    ss = furnace(closure("glossy", color=(c, c, c), roughness=1.0), samples=64)
    white = furnace(closure("glossy", roughness=1.0), samples=64)
    assert c * centre(white) < centre(ss) * 1.001 and centre(ss) < centre(img) < c * 0.99


def test_principled_layering_keeps_a_white_dielectric_near_one():
    # The specular layer's albedo estimate decides what the diffuse keeps: with multiscatter
    # the white dielectric is within a percent of 1 (Cycles' estimate is not exact either).
    img = furnace(closure("principled", base_color=(1.0, 1.0, 1.0), roughness=0.5, multiscatter=1.0),
                  samples=128)
    assert abs(centre(img) - 1.0) < 0.01
    # No specular (IOR Level 0): only the diffuse base.
    grey = furnace(closure("principled", base_color=(0.5, 0.5, 0.5), roughness=0.5,
                           specular_level=0.0, multiscatter=1.0), samples=32)
    assert abs(centre(grey) - 0.5) < 0.01


def test_specular_tint_colours_only_f0():
    # A tinted specular over black: at normal incidence the reflection takes the tint, at
    # grazing angles (f90 = 1) it turns white; the bsdf's own Fresnel shows both.
    wo = np.array([[0.0, 0.0, 1.0]], np.float32)
    p = {"alpha": 0.01, "f0": (0.08, 0.04, 0.0), "specular_eta": 1.5}
    f, _ = pc.bsdf_eval("conductor", p, (0.0, 0.0, 1.0), wo)
    _, w_n, _, _ = pc.bsdf_sample("conductor", p, (0.0, 0.0, 1.0), np.full((64, 3), 0.5, np.float32))
    assert w_n[0, 0] > w_n[0, 1] > w_n[0, 2] >= 0.0
    graze = (np.sin(np.radians(88)), 0.0, np.cos(np.radians(88)))
    _, w_g, _, flags = pc.bsdf_sample("conductor", p, graze, np.full((64, 3), 0.5, np.float32))
    assert w_g[0].min() > 0.5 and np.ptp(w_g[0]) < 0.1


def test_coat_layers_over_the_base():
    # A clear coat over a white (dielectric or metal) base: the coat reflects what the base
    # then misses, so the white furnace stays at 1 within a percent, as in Cycles.
    for base in ({}, {"metallic": 1.0}):
        img = furnace(closure("principled", base_color=(1.0, 1.0, 1.0), roughness=0.5, multiscatter=1.0,
                              coat_weight=1.0, coat_roughness=0.1, **base), samples=128)
        assert abs(centre(img) - 1.0) < 0.01, base
    # An index-matched coat (IOR 1) reflects nothing and only tints: Beer's law over the view's
    # path through it, 1 / cos (about 1 face-on), per channel.
    img = furnace(closure("principled", base_color=(1.0, 1.0, 1.0), roughness=0.5, specular_level=0.0,
                          coat_weight=1.0, coat_ior=1.0, coat_tint=(0.5, 0.25, 1.0)), samples=64)
    mid = img[15:17, 15:17].reshape(-1, 3).mean(0)
    assert np.allclose(mid, (0.5, 0.25, 1.0), atol=0.01), mid
    # Away from face-on the path is longer: darker than there.
    assert img[12:20, 12:20, 0].mean() < mid[0] - 0.005


def test_specular_tint_on_glass_colours_the_reflection_only():
    # Smooth Principled glass seen face-on: reflections carry F0 * tint (F0 = 0.04 here), the
    # transmitted rest 1 - F0 * tint per channel (no eta^2 on refraction, as Cycles').
    tint = np.array([1.0, 0.5, 0.2])
    u = np.random.default_rng(4).random((200_000, 3), dtype=np.float32)
    p = {"alpha": 0.0, "eta": 1.5, "f0_tint": tuple(tint)}
    wi, w, pdf, flags = pc.bsdf_sample("dielectric", p, (0.0, 0.0, 1.0), u)
    refl, trans = (flags & 1) != 0, (flags & 2) != 0
    f0 = 0.04 * tint
    energy_r = (w * refl[:, None]).mean(0)
    energy_t = (w * trans[:, None]).mean(0)
    assert np.allclose(energy_r, f0, rtol=0.03), energy_r
    assert np.allclose(energy_t, 1.0 - f0, rtol=0.01), energy_t
