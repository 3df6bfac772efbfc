#!/usr/bin/env python3
"""Generates core/scene/microfacet_tables.h: the GGX albedo tables that Blender's Multiscatter
GGX energy preservation and the Principled BSDF's layering read (the same quantities, axes and
parametrisation as Cycles' cycles_precompute, integrated here by our own quadrature).

    .venv/bin/python tools/gen_microfacet_tables.py            # writes the header
    .venv/bin/python tools/gen_microfacet_tables.py --check    # compares a coarse run with it

Every table is indexed like Cycles': x = roughness (Blender's, alpha = r^2) at x / (nx - 1),
y = cos(view, normal) at y / (ny - 1) (clamped to [1e-4, 1]), z = F0^(1/4) at z / (nz - 1)
(clamped to [1e-4, 0.99]; ior = ior_from_F0(z^4)). Values are means over the GGX visible-normal
distribution (Heitz 2018) seen from the view direction, on a midpoint grid (see grid()):
  ggx_E                  single-scatter albedo of GGX reflection (G2/G1 per sampled normal)
  ggx_Eavg               its cosine-weighted average over the view, 2 * int mu E(mu) dmu
  ggx_glass_E(_inv)      albedo of a GGX dielectric (reflection F + transmission 1 - F, each
                         G2/G1; no eta^2 radiance scaling) for ior > 1 (and for 1 / ior)
  ggx_glass_(inv_)Eavg   their averages over the view
  ggx_gen_schlick_ior_s  the mean Fresnel interpolation factor s = (F - F0) / (1 - F0) of the
                         real dielectric Fresnel over the reflected directions that stay above
                         the surface (0 for the rest), which the generalized-Schlick albedo
                         estimate mix(F0, F90, s) reads
  ggx_gen_schlick_s      the same for Schlick's curve (1 - cos)^e with the exponent
                         e = 5 (1 - z) / z on the z axis (z = 0.5: e = 5), which Cycles reads at
                         z = 0.5 for the F82-Tint metals' albedo estimate
"""

import argparse
import re
import sys
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent.parent / "core" / "scene" / "microfacet_tables.h"


def ior_from_f0(f0):
    s = np.sqrt(np.clip(f0, 0.0, 0.99))
    return (1.0 + s) / (1.0 - s)


def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance for cos_i > 0 on the side of the incident ray; eta is the
    relative IOR (transmitted side / incident side). Also returns cos of the transmitted ray."""
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    tir = sin2_t >= 1.0
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    f = 0.5 * (r_par * r_par + r_perp * r_perp)
    return np.where(tir, 1.0, f), cos_t


def lam(alpha, cz):
    """Smith Lambda of GGX for a direction with cos theta = cz (> 0)."""
    c2 = np.maximum(cz * cz, 1e-30)
    t2 = np.maximum(0.0, 1.0 - c2) / c2
    return 0.5 * (-1.0 + np.sqrt(1.0 + alpha * alpha * t2))


def grid(n):
    """Midpoint grid over the unit square, denser towards u1 = 1 (u1 = 1 - (1 - t)^3, with its
    Jacobian as weights): there the visible normals of a smooth surface reach the distribution's
    tail, where reflections start to leave the hemisphere."""
    t = (np.arange(n) + 0.5) / n
    t1, u2 = np.meshgrid(t, t, indexing="ij")
    t1, u2 = t1.ravel(), u2.ravel()
    return 1.0 - (1.0 - t1) ** 3, u2, 3.0 * (1.0 - t1) ** 2


def sample_vndf(alpha, mu, u1, u2):
    """Visible normals of GGX (alpha: (E,1), mu: (E,1); u: (S,)) for the view (sin, 0, mu).
    Returns h (E,S,3) and the view (E,1,3)."""
    wo = np.stack([np.sqrt(np.maximum(0.0, 1.0 - mu * mu)), np.zeros_like(mu), mu], -1)  # (E,1,3)
    vh = np.stack([alpha * wo[..., 0], alpha * wo[..., 1], wo[..., 2]], -1)
    vh /= np.linalg.norm(vh, axis=-1, keepdims=True)
    len2 = vh[..., 0] ** 2 + vh[..., 1] ** 2
    inv = np.where(len2 > 0, 1.0 / np.sqrt(np.maximum(len2, 1e-300)), 0.0)
    t1 = np.where((len2 > 0)[..., None], np.stack([-vh[..., 1] * inv, vh[..., 0] * inv, 0 * inv], -1),
                  np.array([1.0, 0.0, 0.0]))
    t2 = np.cross(vh, t1)
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vh[..., 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
    pz = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
    nh = t1 * p1[..., None] + t2 * p2[..., None] + vh * pz[..., None]
    h = np.stack([alpha * nh[..., 0], alpha * nh[..., 1], np.maximum(1e-12, nh[..., 2])], -1)
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    return h, wo


def conductor_terms(alpha, mu, u1, u2):
    """(G2/G1 where the reflection stays above the surface else 0, cos(view, h))."""
    h, wo = sample_vndf(alpha, mu, u1, u2)
    woh = (h * wo).sum(-1)
    wi_z = 2.0 * woh * h[..., 2] - wo[..., 2]
    lo = lam(alpha, mu)
    w = np.where(wi_z > 0, (1.0 + lo) / (1.0 + lo + lam(alpha, np.abs(wi_z))), 0.0)
    return w, woh


def glass_albedo(alpha, mu, eta, u1, u2):
    h, wo = sample_vndf(alpha, mu, u1, u2)
    woh = (h * wo).sum(-1)
    F, cos_t = fresnel_dielectric(woh, eta)
    lo = lam(alpha, mu)
    wr_z = 2.0 * woh * h[..., 2] - wo[..., 2]
    wr = np.where(wr_z > 0, (1.0 + lo) / (1.0 + lo + lam(alpha, np.abs(wr_z))), 0.0)
    # Refracted: -wo / eta + h (cos_i / eta - cos_t).
    wt_z = -wo[..., 2] / eta + h[..., 2] * (woh / eta - cos_t)
    wt = np.where((wt_z < 0) & (F < 1.0), (1.0 + lo) / (1.0 + lo + lam(alpha, np.abs(wt_z))), 0.0)
    return F * wr + (1.0 - F) * wt


def axis(n, lo, hi):
    return np.clip(np.arange(n) / (n - 1), lo, hi)


def table_ggx_e(n, nx=32, ny=32):
    u1, u2, wt = grid(n)
    rough = axis(nx, 1e-4, 1.0)
    mu = axis(ny, 1e-4, 1.0)
    R, M = np.meshgrid(rough, mu, indexing="xy")  # (ny, nx)
    w, _ = conductor_terms((R * R).reshape(-1, 1), M.reshape(-1, 1), u1, u2)
    return (w * wt).mean(-1).reshape(ny, nx)


def mu_strata(n_mu):
    return (np.arange(n_mu) + 0.5) / n_mu


def table_ggx_eavg(n, n_mu, nx=32):
    u1, u2, wt = grid(n)
    rough = axis(nx, 1e-4, 1.0)
    mu = mu_strata(n_mu)
    R, M = np.meshgrid(rough, mu, indexing="ij")  # (nx, n_mu)
    w, _ = conductor_terms((R * R).reshape(-1, 1), M.reshape(-1, 1), u1, u2)
    e = (w * wt).mean(-1).reshape(nx, n_mu)
    return (2.0 * mu[None, :] * e).mean(-1)


def ior_axis(nz):
    z = axis(nz, 1e-4, 0.99)
    return ior_from_f0(z ** 4)


def table_glass_e(n, invert, nx=16, ny=16, nz=16):
    u1, u2, wt = grid(n)
    rough = axis(nx, 1e-4, 1.0)
    mu = axis(ny, 1e-4, 1.0)
    out = np.zeros((nz, ny, nx))
    for k, ior in enumerate(ior_axis(nz)):
        eta = 1.0 / ior if invert else ior
        R, M = np.meshgrid(rough, mu, indexing="xy")
        e = glass_albedo((R * R).reshape(-1, 1), M.reshape(-1, 1), eta, u1, u2)
        out[k] = (e * wt).mean(-1).reshape(ny, nx)
    return out


def table_glass_eavg(n, n_mu, invert, nx=16, nz=16):
    u1, u2, wt = grid(n)
    rough = axis(nx, 1e-4, 1.0)
    mu = mu_strata(n_mu)
    out = np.zeros((nz, nx))
    for k, ior in enumerate(ior_axis(nz)):
        eta = 1.0 / ior if invert else ior
        R, M = np.meshgrid(rough, mu, indexing="ij")
        e = (glass_albedo((R * R).reshape(-1, 1), M.reshape(-1, 1), eta, u1, u2) * wt).mean(-1)
        out[k] = (2.0 * mu[None, :] * e.reshape(nx, n_mu)).mean(-1)
    return out


def table_gen_schlick_ior_s(n, nx=16, ny=16, nz=16):
    u1, u2, wt = grid(n)
    rough = axis(nx, 1e-4, 1.0)
    mu = axis(ny, 1e-4, 1.0)
    out = np.zeros((nz, ny, nx))
    for k, ior in enumerate(ior_axis(nz)):
        R, M = np.meshgrid(rough, mu, indexing="xy")
        w, woh = conductor_terms((R * R).reshape(-1, 1), M.reshape(-1, 1), u1, u2)
        F, _ = fresnel_dielectric(np.clip(woh, 0.0, 1.0), ior)
        f0 = ((ior - 1.0) / (ior + 1.0)) ** 2
        s = np.clip((F - f0) / (1.0 - f0), 0.0, 1.0)
        out[k] = (np.where(w > 0, s, 0.0) * wt).mean(-1).reshape(ny, nx)
    return out


def table_gen_schlick_s(n, nx=16, ny=16, nz=16):
    u1, u2, wt = grid(n)
    rough = axis(nx, 1e-4, 1.0)
    mu = axis(ny, 1e-4, 1.0)
    out = np.zeros((nz, ny, nx))
    for k, z in enumerate(axis(nz, 1e-4, 0.99)):
        exponent = 5.0 * (1.0 - z) / z
        R, M = np.meshgrid(rough, mu, indexing="xy")
        w, woh = conductor_terms((R * R).reshape(-1, 1), M.reshape(-1, 1), u1, u2)
        s = (1.0 - np.clip(woh, 0.0, 1.0)) ** exponent
        out[k] = (np.where(w > 0, s, 0.0) * wt).mean(-1).reshape(ny, nx)
    return out


def compute(n, n_avg, n_mu):
    return {
        "ggx_E": table_ggx_e(n),
        "ggx_Eavg": table_ggx_eavg(n_avg, n_mu),
        "ggx_glass_E": table_glass_e(n, False),
        "ggx_glass_Eavg": table_glass_eavg(n_avg, n_mu, False),
        "ggx_glass_inv_E": table_glass_e(n, True),
        "ggx_glass_inv_Eavg": table_glass_eavg(n_avg, n_mu, True),
        "ggx_gen_schlick_ior_s": table_gen_schlick_ior_s(n),
        "ggx_gen_schlick_s": table_gen_schlick_s(n),
    }


def write(tables, n, n_avg, n_mu):
    lines = [
        "// Generated by tools/gen_microfacet_tables.py (do not edit): GGX albedo tables for",
        "// Multiscatter GGX energy preservation and Principled layering; see the script for the",
        f"// quantities and axes. Quadrature: {n}x{n} visible normals per entry, {n_avg}x{n_avg} x "
        f"{n_mu} views for averages.",
        "#pragma once",
        "",
        "namespace pl::tables {",
        "",
    ]
    for name, t in tables.items():
        t = np.clip(np.asarray(t, np.float64), 0.0, 1.0)
        flat = t.ravel()
        dims = "x".join(str(d) for d in t.shape)
        lines.append(f"// {name}: {dims} (outermost first)")
        lines.append(f"inline constexpr float {name}[{flat.size}] = {{")
        row = t.shape[-1]
        for i in range(0, flat.size, row):
            lines.append("    " + ", ".join(f"{v:.6f}f" for v in flat[i:i + row]) + ",")
        lines.append("};")
        lines.append("")
    lines.append("}  // namespace pl::tables")
    OUT.write_text("\n".join(lines) + "\n")


def read_header():
    text = OUT.read_text()
    out = {}
    for m in re.finditer(r"inline constexpr float (\w+)\[(\d+)\] = \{([^}]*)\};", text):
        out[m.group(1)] = np.array([float(v.rstrip("f")) for v in m.group(3).replace("\n", " ").split(",")
                                    if v.strip()])
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare a coarse run with the header")
    ap.add_argument("-n", type=int, default=96, help="visible normals per axis per entry (the header: 96)")
    args = ap.parse_args()
    if args.check:
        coarse = compute(48, 24, 32)
        stored = read_header()
        worst = max(float(np.abs(coarse[k].ravel() - stored[k]).max()) for k in coarse)
        print(f"largest difference to a coarse run: {worst:.4f}")
        return 0 if worst < 0.02 else 1
    write(compute(args.n, args.n // 2, 64), args.n, args.n // 2, 64)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
