"""Anisotropic GGX through the core module (issue 24): the lobe's formulas (a quarter turn swaps
the two roughnesses; equal roughnesses are the isotropic lobe), the tangent frame and rotation
of the shader ops, and the white furnace of anisotropic Multiscatter GGX, which Cycles'
compensation (its tables read at sqrt(alpha_x alpha_y)) keeps at 1. Chi-square tests of the
anisotropic sampling against its pdf are test_bsdf's CASES."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, render, uv_sphere
from test_core_materials import closure, furnace

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def directions(n, seed):
    v = np.random.default_rng(seed).normal(size=(n, 3)).astype(np.float32)
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=1)[:, None]


def quarter_turn(v):
    return np.stack([-v[:, 1], v[:, 0], v[:, 2]], -1)


@pytest.mark.parametrize("kind,extra", [("conductor", {}), ("dielectric", {"eta": 1.5})])
def test_a_quarter_turn_swaps_the_roughnesses(kind, extra):
    wo, wi = directions(300, 1), directions(300, 2)
    wi[::2, 2] *= -1  # transmission too, for the dielectric
    a = {"alpha": 0.12, "alpha_y": 0.5, **extra}
    b = {"alpha": 0.5, "alpha_y": 0.12, **extra}
    wo_t, wi_t = quarter_turn(wo), quarter_turn(wi)
    fa = np.array([pc.bsdf_eval(kind, a, tuple(x), y[None])[0][0] for x, y in zip(wo, wi)])
    fb = np.array([pc.bsdf_eval(kind, b, tuple(x), y[None])[0][0] for x, y in zip(wo_t, wi_t)])
    assert np.abs(fa).max() > 0.1
    assert np.allclose(fa, fb, rtol=2e-4, atol=1e-6)
    # ...and the lobe is anisotropic: without the turn the values differ.
    fc = np.array([pc.bsdf_eval(kind, b, tuple(x), y[None])[0][0] for x, y in zip(wo, wi)])
    assert np.abs(fa - fc).max() > 0.1


@pytest.mark.parametrize("kind", ["conductor", "dielectric"])
def test_equal_roughnesses_are_the_isotropic_lobe(kind):
    wo = (0.4, -0.3, 0.866)
    wi = np.concatenate([directions(500, 3), -directions(100, 4)]).astype(np.float32)
    iso, pdf_iso = pc.bsdf_eval(kind, {"alpha": 0.3}, wo, wi)
    # alpha_y == alpha takes the isotropic code: bit for bit.
    same, pdf_same = pc.bsdf_eval(kind, {"alpha": 0.3, "alpha_y": 0.3}, wo, wi)
    assert np.array_equal(iso, same) and np.array_equal(pdf_iso, pdf_same)
    # The anisotropic formulas approach it as the roughnesses meet.
    near, pdf_near = pc.bsdf_eval(kind, {"alpha": 0.3, "alpha_y": 0.3 * (1 + 1e-4)}, wo, wi)
    assert np.allclose(iso, near, rtol=2e-3, atol=1e-6) and np.allclose(pdf_iso, pdf_near, rtol=2e-3, atol=1e-6)
    u = np.random.default_rng(5).random((1000, 3), dtype=np.float32)
    a = pc.bsdf_sample(kind, {"alpha": 0.3}, wo, u)
    b = pc.bsdf_sample(kind, {"alpha": 0.3, "alpha_y": 0.3}, wo, u)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


def lit_sphere(program, size=24, samples=16):
    s = pc.Scene()
    m = s.add_shader("m", program)
    pos, tris, _ = uv_sphere(1.0, nu=64, nv=32)
    add_object(s, pos, tris, m)
    s.set_world_color((0.0, 0.0, 0.0))
    s.add_sun_light((0.3, -0.5, 0.8), (2.0, 2.0, 2.0))
    s.set_camera(camera(pc, (0, -4, 0), (0, 0, 0), lens=60.0))
    return render(pc, s, size, size, samples=samples)[0][..., :3]


def principled_metal(anisotropic, rotation=0.0, tangent=True):
    prog = [("tangent", 0, "Z", 0)] if tangent else []
    prog += [("const", 1, (0.9, 0.7, 0.5)), ("const", 2, (1.0,)), ("const", 3, (0.4,)),
             ("const", 4, (anisotropic,)), ("const", 5, (rotation,))]
    regs = {"base_color": 1, "metallic": 2, "roughness": 3, "anisotropic": 4, "anisotropic_rotation": 5}
    if tangent:
        regs["tangent"] = 0
    return prog + [("closure", "principled", None, regs)]


def test_principled_anisotropy_follows_its_tangent_and_rotation():
    iso = lit_sphere(principled_metal(0.0))
    aniso = lit_sphere(principled_metal(0.9))
    turned = lit_sphere(principled_metal(0.9, rotation=0.25))
    assert np.abs(iso - aniso).mean() > 0.01 * iso.mean()
    assert np.abs(aniso - turned).mean() > 0.01 * iso.mean()
    # A half turn is the same lobe (D(m) = D(-m)): the image only differs by noise.
    half = lit_sphere(principled_metal(0.9, rotation=0.5))
    assert np.abs(aniso - half).mean() < 0.2 * np.abs(aniso - turned).mean()


def furnace_of(kind, samples=64, **params):
    prog = [("tangent", 20, "Z", 0)] + closure(kind, **params)
    prog[-1][3]["tangent"] = 20
    img = furnace(prog, samples=samples)
    return float(img[12:20, 12:20].mean()), float(img.mean())


WHITE_METAL = dict(base_color=(1.0, 1.0, 1.0), metallic=1.0)


@pytest.mark.parametrize("kind,params", [
    ("glossy", dict(roughness=0.3, anisotropy=0.3)),
    ("principled", dict(roughness=0.5, anisotropic=0.2, **WHITE_METAL)),
    ("principled", dict(roughness=0.3, anisotropic=0.5, anisotropic_rotation=0.2, **WHITE_METAL)),
])
def test_anisotropic_multiscatter_white_furnace(kind, params):
    # Blender's Multiscatter GGX keeps a white, moderately anisotropic lobe's energy: Cycles
    # reads its tables at the two alphas' geometric mean, a fine estimate here.
    centre, mean = furnace_of(kind, multiscatter=1.0, **params)
    assert abs(centre - 1.0) < 0.01 and abs(mean - 1.0) < 0.01, (centre, mean)


def test_strong_anisotropy_loses_energy_as_cycles_does():
    # Stretched far (alphas 0.26 and 1), the geometric mean's E overestimates the lobe's own
    # and Cycles' compensation falls short: 0.76 at normal view in Cycles 4.5, matched within
    # 1 % by test_anisotropy_cycles' furnace. It still restores much of single scatter's loss.
    params = dict(roughness=0.8, anisotropy=0.6)
    multi, _ = furnace_of("glossy", multiscatter=1.0, **params)
    single, _ = furnace_of("glossy", samples=32, **params)
    iso, _ = furnace_of("glossy", multiscatter=1.0, roughness=0.8)
    assert single + 0.05 < multi < iso - 0.1 and abs(iso - 1.0) < 0.01, (single, multi, iso)


@pytest.mark.parametrize("params", [
    dict(anisotropic=float("nan"), anisotropic_rotation=float("inf"), thin_film_thickness=float("nan")),
    dict(anisotropic=5.0, anisotropic_rotation=-3.0, thin_film_thickness=1e9, thin_film_ior=-2.0),
    dict(anisotropic=1.0, roughness=0.0, thin_film_thickness=500.0, thin_film_ior=0.0),
    dict(anisotropic=0.7, roughness=1.0, transmission=1.0, thin_film_thickness=250.0, thin_film_ior=3.0),
])
@pytest.mark.parametrize("tangent", [(0.0, 0.0, 0.0), (float("nan"), 1.0, 0.0), (0.0, 0.0, 1.0)])
def test_odd_anisotropy_and_film_inputs_render_finite(params, tangent):
    # Degenerate tangents (zero, NaN, along the normal at the poles) fall back to any frame;
    # out-of-range amounts clamp as Cycles' do. furnace() asserts every sample is finite.
    prog = closure("principled", base_color=(0.8, 0.8, 0.8), tangent=tangent, **params)
    img = furnace(prog, samples=4, size=16)
    assert np.isfinite(img).all() and img.max() < 2.0
    glossy = closure("glossy", roughness=0.5, anisotropy=params["anisotropic"],
                     rotation=params.get("anisotropic_rotation", 0.0), tangent=tangent)
    assert np.isfinite(furnace(glossy, samples=4, size=16)).all()
