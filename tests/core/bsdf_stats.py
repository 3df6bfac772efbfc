"""Statistics shared by the BSDF sampling tests (Mitsuba's chi-square recipe): bins of equal
solid angle over the sphere, the pdf integrated per bin, and a pooled chi-square p-value."""
import math

import numpy as np


def chi2_pvalue(stat, dof):
    # Wilson-Hilferty approximation of the chi-square upper tail (no SciPy needed).
    z = ((stat / dof) ** (1 / 3) - (1 - 2 / (9 * dof))) / math.sqrt(2 / (9 * dof))
    return 0.5 * math.erfc(z / math.sqrt(2))


def sphere_bins(n_theta=16, n_phi=32):
    """Bin edges over the whole sphere in (cos theta, phi): equal solid angle per bin."""
    return np.linspace(-1, 1, n_theta + 1), np.linspace(-np.pi, np.pi, n_phi + 1)


def integrate_pdf(pc, kind, params, wo, ct_edges, ph_edges, res=24, **eval_kw):
    """The evaluated pdf integrated over each bin (res x res midpoint rule per bin); eval_kw go
    to bsdf_eval (sampled=True: the Hair BSDF's own sampling density)."""
    nt, nphi = len(ct_edges) - 1, len(ph_edges) - 1
    t = (np.arange(res) + 0.5) / res
    ct = (ct_edges[:-1, None] + np.diff(ct_edges)[:, None] * t[None, :]).ravel()
    ph = (ph_edges[:-1, None] + np.diff(ph_edges)[:, None] * t[None, :]).ravel()
    CT, PH = np.meshgrid(ct, ph, indexing="ij")
    st = np.sqrt(np.maximum(0, 1 - CT**2))
    wi = np.stack([st * np.cos(PH), st * np.sin(PH), CT], -1).reshape(-1, 3).astype(np.float32)
    _, pdf = pc.bsdf_eval(kind, params, wo, wi, **eval_kw)
    cell = (2.0 / nt / res) * (2 * np.pi / nphi / res)
    return (pdf.reshape(nt, res, nphi, res) * cell).sum(axis=(1, 3))


def pooled_chi2(obs, exp):
    """Chi-square of observed against expected counts, pooling bins with fewer than 5 expected
    samples into one (Mitsuba's rule); bins the pdf gives no mass are left out. Returns
    (statistic, degrees of freedom, p-value)."""
    o, e = np.ravel(obs), np.ravel(exp)
    order = np.argsort(e)
    o, e = o[order], e[order]
    small = e < 5
    o = np.append(o[~small], o[small].sum())
    e = np.append(e[~small], e[small].sum())
    keep = e > 0
    stat = float((((o - e) ** 2)[keep] / e[keep]).sum())
    dof = int(keep.sum()) - 1
    return stat, dof, chi2_pvalue(stat, dof)


def sampling_chi2(pc, kind, params, wo, wi, n, res=24, **eval_kw):
    """Histogram the sampled directions `wi` (successful samples of `n` drawn) over the sphere
    against the pdf's integral per bin. Returns (statistic, dof, p-value, expected counts)."""
    ct_edges, ph_edges = sphere_bins()
    obs, _, _ = np.histogram2d(wi[:, 2], np.arctan2(wi[:, 1], wi[:, 0]), bins=[ct_edges, ph_edges])
    exp = integrate_pdf(pc, kind, params, wo, ct_edges, ph_edges, res=res, **eval_kw) * n
    return (*pooled_chi2(obs, exp), exp)


def sample_then_eval(pc, kind, params, wo, n=2000, seed=3):
    """n samples of the lobe for wo and their eval: (ok, wi, weight, pdf, f, pdf_eval), the
    last five of the successful samples only (flags >= 0)."""
    u = np.random.default_rng(seed).random((n, 3), dtype=np.float32)
    wi, weight, pdf, flags = pc.bsdf_sample(kind, params, wo, u)
    ok = flags >= 0
    f, pdf_e = pc.bsdf_eval(kind, params, wo, wi[ok])
    return ok, wi[ok], weight[ok], pdf[ok], f, pdf_e


def eval_both_ways(pc, kind, params, a, b):
    """f(a -> b) and f(b -> a) (eval includes |cos| of the second direction) for direction pairs."""
    fab = np.array([pc.bsdf_eval(kind, params, tuple(x), y[None])[0][0] for x, y in zip(a, b)])
    fba = np.array([pc.bsdf_eval(kind, params, tuple(y), x[None])[0][0] for x, y in zip(a, b)])
    return fab, fba
