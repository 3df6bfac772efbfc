"""Thin-film interference through the core module (issue 24): the Principled BSDF's Thin Film
as Cycles 4.5 applies it (Belcour & Barla's Airy sum with the XYZ fit, to linear Rec.709).
Facts that do not depend on the fit: a film of the base's own IOR is no film (the plain
Fresnel, grey: the colour conversion keeps white white); a film thinner than the cutoff is
none; a film reflects colour that changes with its thickness and the view; glass with a film
still reflects and transmits everything between them. Sampling (chi-square) with a film:
test_bsdf's CASES; against Cycles: test_thin_film_cycles."""
import math

import numpy as np
import pytest

from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def fresnel_dielectric(c, eta):
    s2 = (1 - c * c) / eta**2
    t = math.sqrt(1 - s2)
    rs = (c - eta * t) / (c + eta * t)
    rp = (eta * c - t) / (eta * c + t)
    return 0.5 * (rs * rs + rp * rp)


def mirror_reflectance(wo, **film):
    """The specular lobe's Fresnel at cos = wo.z: a smooth Principled specular's sample weight."""
    params = {"alpha": 0.0, "f0": (f0(1.5),) * 3, "specular_eta": 1.5, **film}
    _, w, _, _ = pc.bsdf_sample("conductor", params, wo, np.full((1, 3), 0.5, np.float32))
    return w[0]


def f0(eta):
    return ((eta - 1) / (eta + 1)) ** 2


def view(c):
    return (math.sqrt(1 - c * c), 0.0, c)


def test_a_film_of_the_base_ior_is_no_film():
    for c in (1.0, 0.7, 0.3):
        r = mirror_reflectance(view(c), film_thickness=500.0, film_ior=1.5)
        plain = mirror_reflectance(view(c))
        assert np.allclose(r, fresnel_dielectric(c, 1.5), atol=2e-3), (c, r)
        assert np.allclose(plain, fresnel_dielectric(c, 1.5), atol=1e-5)


def test_thinner_than_the_cutoff_is_no_film():
    assert np.array_equal(mirror_reflectance(view(0.8), film_thickness=0.05),
                          mirror_reflectance(view(0.8)))


def test_a_soap_film_reflects_colour_that_shifts_with_thickness_and_view():
    colours = [mirror_reflectance(view(c), film_thickness=t, film_ior=1.33)
               for t in (300.0, 500.0, 700.0) for c in (1.0, 0.5)]
    for rgb in colours:
        assert np.all(rgb >= 0) and np.all(rgb <= 1)
        assert rgb.max() - rgb.min() > 0.01  # coloured, not grey
    hues = np.array([rgb / rgb.sum() for rgb in colours])
    assert np.abs(hues[:, None] - hues[None]).max() > 0.1  # and the colour changes
    # A low-IOR film on a higher-IOR base reflects less than the bare base somewhere (destructive
    # interference) and more elsewhere: it redistributes, it does not only add.
    bare = fresnel_dielectric(1.0, 1.5)
    stack = np.array(colours)
    assert stack.min() < bare < stack.max()


def test_glass_with_a_film_reflects_and_transmits_all():
    # Smooth glass with a film: reflection + transmission is 1 per channel, from outside and from
    # inside (refraction carries no 1/eta^2, as Cycles').
    u = np.random.default_rng(2).random((40_000, 3), dtype=np.float32)
    for wo in ((0.3, 0.2, 0.93), (0.6, 0.0, -0.8)):
        wi, w, _, flags = pc.bsdf_sample("dielectric", {"alpha": 0.0, "eta": 1.5, "film_thickness": 450.0}, wo, u)
        ok = flags >= 0
        trans = (flags & 2) != 0
        energy = w[ok].sum(axis=0) / len(u)
        assert np.allclose(energy, 1.0, atol=0.01), (wo, energy)
        # ...and the reflected part is coloured by the film.
        refl = (w * ~trans[:, None]).sum(axis=0) / len(u)
        assert refl.max() - refl.min() > 0.005, refl


def film_reference(cos_1, eta2, eta3, thickness):
    """Belcour & Barla's reflectance as Cycles 4.5 writes it (fresnel_iridescence), in float64:
    every term's exp and cos called directly, where thin_film.h shares them between the
    polarisations and derives the 2nd and 3rd path differences' from the 1st."""
    def polarized(ci, eta):
        e2 = eta * eta - (1 - ci * ci)
        if e2 <= 0:
            return None
        ci = abs(ci)
        ct = -math.sqrt(e2) / eta
        a_s = (ci + eta * ct) / (ci - eta * ct)
        a_p = (ct + eta * ci) / (eta * ci - ct)
        return a_s * a_s, a_p * a_p, math.pi * (a_s < 0), math.pi * (a_p < 0), ct

    def sensitivity(opd, shift):
        phase = 2 * math.pi * opd * 1e-9
        val, pos, var = (5.4856e-13, 4.4201e-13, 5.2481e-13), (1.6810e6, 1.7953e6, 2.2084e6), (4.3278e9, 9.3046e9, 6.6121e9)
        xyz = [val[i] * math.sqrt(2 * math.pi * var[i]) * math.cos(pos[i] * phase + shift) * math.exp(-phase**2 * var[i])
               for i in range(3)]
        xyz[0] += 1.64408e-8 * math.cos(2.2399e6 * phase + shift) * math.exp(-4.5282e9 * phase**2)
        return np.array(xyz) / 1.0685e-7

    def airy(t121, r12, r23, opd, phi):
        if r23 == 1:
            return np.ones(3)
        r123 = r12 * r23
        rs = t121 * t121 * r23 / (1 - r123)
        r, cm = np.full(3, r12 + rs), rs - t121
        for m in (1, 2, 3):
            cm *= math.sqrt(r123)
            r = r + sensitivity(m * opd, m * phi) * 2 * cm
        return r

    if thickness < 30:
        t = thickness / 30
        eta2 = 1 + (eta2 - 1) * t * t * (3 - 2 * t)
    f12 = polarized(cos_1, eta2)
    f23 = f12 and polarized(-f12[4], eta3 / eta2)
    if f23 is None:
        return np.ones(3)
    opd = -2 * eta2 * thickness * f12[4]
    xyz = 0.5 * (airy(1 - f12[0], f12[0], f23[0], opd, math.pi - f12[2] + f23[2]) +
                 airy(1 - f12[1], f12[1], f23[1], opd, math.pi - f12[3] + f23[3]))
    w = xyz * (0.95047, 1.0, 1.08883)
    m = np.array([[3.2404542, -1.5371385, -0.4985314], [-0.9692660, 1.8760108, 0.0415560],
                  [0.0556434, -0.2040259, 1.0572252]])
    return np.clip(m @ w, 0, 1)


def test_the_film_matches_the_direct_airy_sum():
    # thin_film.h computes 4 exp and 6 sincos where the direct form calls 24 of each (issue 25's
    # Principled spheres); the values must be the same within float rounding, over thicknesses
    # (thin, fading, ordinary, thick), film IORs below and above the base's, and views.
    for t in (20.0, 120.0, 380.0, 500.0, 900.0, 2500.0):
        for fi in (1.2, 1.33, 2.0):
            for c in (1.0, 0.8, 0.5, 0.2, 0.05):
                got = mirror_reflectance(view(c), film_thickness=t, film_ior=fi)
                ref = film_reference(c, fi, 1.5, t)
                assert np.allclose(got, ref, atol=2e-5), (t, fi, c, got, ref)
