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
    # Smooth glass with a film: reflection + transmission (importance terms: eta^2 for the
    # transmitted radiance's compression) is 1 per channel, from outside and from inside.
    u = np.random.default_rng(2).random((40_000, 3), dtype=np.float32)
    for wo in ((0.3, 0.2, 0.93), (0.6, 0.0, -0.8)):
        wi, w, _, flags = pc.bsdf_sample("dielectric", {"alpha": 0.0, "eta": 1.5, "film_thickness": 450.0}, wo, u)
        ok = flags >= 0
        trans = (flags & 2) != 0
        scale = np.where(trans, (1.5 if wo[2] > 0 else 1 / 1.5) ** 2, 1.0)[:, None]
        energy = (w * scale)[ok].sum(axis=0) / len(u)
        assert np.allclose(energy, 1.0, atol=0.01), (wo, energy)
        # ...and the reflected part is coloured by the film.
        refl = (w * ~trans[:, None]).sum(axis=0) / len(u)
        assert refl.max() - refl.min() > 0.005, refl
