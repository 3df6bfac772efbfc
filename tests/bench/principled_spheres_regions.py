"""Where the converged comparison's 'own seed noise' on the Principled spheres comes from (issue
25): per 8x8-grid region of the realistic bench's image (96x72: regions of 12x9 pixels), the
variance of one sample of the region's mean for Pathlight and Cycles at equal samples, split by
light pass, beside the mean per-pixel variance. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/principled_spheres_regions.py --region 4,5 [--seeds N] [--spp S]
        [--cycles-pattern TABULATED_SOBOL]

Only the region is rendered (a render border; pixels keep their full-image sample streams), N
times at S spp with seeds seed0.. (the bench's settings: 1-pixel box filter, max bounces 12, no
clamping or denoising). Per pass (light passes times their colour passes): the ratio of the
engines' region-mean variances with a 90 % bootstrap interval over the seeds, and 'pixel': the
ratio of their mean per-pixel variances. 'factor' per engine is the region-mean variance over
(pixel variance / pixels): 1 where pixels' errors are independent, well below 1 where they
cancel across the region (Cycles' default blue-noise pattern), above 1 where they correlate.
'halves' is the bench's own-noise figure (|one S-spp render - the next| / sqrt 2 over the
region's mean) over consecutive seed pairs: its median and 10 / 90 % quantiles."""
import argparse
import sys
import tempfile
from pathlib import Path

import bpy
import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_multilayer_file  # noqa: E402
import realistic_scenes as rs  # noqa: E402

GRID = 8
LIGHT = ("DiffDir", "DiffInd", "GlossDir", "GlossInd", "TransDir", "TransInd")


def setup(engine, spp, pattern):
    scene = rs.principled_spheres()
    vl = scene.view_layers[0]
    for kind in ("diffuse", "glossy", "transmission"):
        for part in ("direct", "indirect", "color"):
            setattr(vl, f"use_pass_{kind}_{part}", True)
    scene.render.engine = engine
    if engine == "CYCLES":
        c = scene.cycles
        c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = 'CPU', spp, False, False
        c.sample_clamp_direct = c.sample_clamp_indirect = c.blur_glossy = 0.0
        c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = 12
        c.volume_bounces = c.transparent_max_bounces = 12
        c.pixel_filter_type, c.filter_width = 'BOX', 1.0
        if pattern != "AUTOMATIC":  # the other patterns are listed with Cycles' debug UI only
            bpy.context.preferences.experimental.use_cycles_debug = True
            bpy.context.preferences.view.show_developer_ui = True
            c.sampling_pattern = pattern
    else:
        p = scene.pathlight
        p.samples, p.use_adaptive_sampling, p.max_bounces = spp, False, 12
        p.diffuse_bounces = p.glossy_bounces = p.transmission_bounces = p.volume_bounces = 12
        p.transparent_bounces = 12
        p.filter_type, p.filter_width = 'BOX', 1.0
    return scene


def renders(engine, region, seeds, spp, seed0, pattern, tmp):
    """{pass: (seeds, h, w) grey} of the region's pixels; light passes times their colours."""
    scene = setup(engine, spp, pattern)
    r = scene.render
    w, h = r.resolution_x, r.resolution_y
    y0, y1 = region[0] * h // GRID, (region[0] + 1) * h // GRID
    x0, x1 = region[1] * w // GRID, (region[1] + 1) * w // GRID
    r.use_border, r.use_crop_to_border = True, False
    r.border_min_x, r.border_max_x = (x0 - 0.5) / w, (x1 + 0.5) / w
    r.border_min_y, r.border_max_y = (h - y1 - 0.5) / h, (h - y0 + 0.5) / h
    out = {}
    for s in range(seeds):
        (scene.cycles if engine == "CYCLES" else scene.pathlight).seed = seed0 + s
        ch = render_multilayer_file(scene, Path(tmp) / f"{engine}.exr")
        grey = lambda name: np.mean([ch[f"{name}.{c}"] for c in "RGB"], axis=0)[y0:y1, x0:x1]
        out.setdefault("Combined", []).append(grey("Combined"))
        for name in LIGHT:
            out.setdefault(name, []).append(grey(name) * grey(name[:-3] + "Col"))
    return {k: np.stack(v).astype(np.float64) for k, v in out.items()}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--region", default="4,5", help="row,column in the 8x8 grid (row 0 = top)")
    ap.add_argument("--seeds", type=int, default=48)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--cycles-pattern", default="AUTOMATIC",
                    help="Cycles' sampling pattern: AUTOMATIC (blue noise), TABULATED_SOBOL, SOBOL_BURLEY")
    args = ap.parse_args()
    region = tuple(int(v) for v in args.region.split(","))
    load_addon()
    with tempfile.TemporaryDirectory(prefix="pathlight_regions_") as tmp:
        imgs = {e: renders(e, region, args.seeds, args.spp, args.seed0, args.cycles_pattern, tmp)
                for e in ("PATHLIGHT", "CYCLES")}
    ref = 0.5 * sum(v["Combined"].mean() for v in imgs.values())
    rng = np.random.default_rng(0)
    print(f"region {region}, {args.seeds} seeds x {args.spp} spp, Cycles pattern {args.cycles_pattern}; "
          f"mean {ref:.4f} (Pathlight / Cycles {imgs['PATHLIGHT']['Combined'].mean() / imgs['CYCLES']['Combined'].mean():.4f})")
    print(f"{'pass':9s} {'Pathlight':>10s} {'Cycles':>10s} {'ratio':>6s} {'90 %':>12s} {'pixel':>6s} factor P / C")
    for name in ("Combined",) + LIGHT:
        a, b = imgs["PATHLIGHT"][name], imgs["CYCLES"][name]
        ra, rb = a.mean((1, 2)), b.mean((1, 2))
        va, vb = ra.var(ddof=1), rb.var(ddof=1)
        if not (va > 0.0 and vb > 0.0):
            continue
        n = a.shape[1] * a.shape[2]
        pa, pb = a.var(0, ddof=1).mean(), b.var(0, ddof=1).mean()
        lo = hi = float("nan")
        if args.seeds >= 8:  # (fewer: no interval worth printing)
            ia, ib = (rng.integers(0, args.seeds, (4000, args.seeds)) for _ in range(2))
            with np.errstate(divide="ignore", invalid="ignore"):
                lo, hi = np.nanpercentile(ra[ia].var(1, ddof=1) / rb[ib].var(1, ddof=1), [5, 95])
        print(f"{name:9s} {va * args.spp / ref**2:10.4g} {vb * args.spp / ref**2:10.4g} {va / vb:6.2f} "
              f"[{lo:4.2f}, {hi:4.2f}] {pa / pb:6.2f} {va * n / pa:.2f} / {vb * n / pb:.2f}")
    for e, v in imgs.items():
        r = v["Combined"].mean((1, 2))
        d = np.abs(r[0:-1:2] - r[1::2]) / np.sqrt(2.0) / ref * 100.0
        print(f"{e} halves: median {np.median(d):.2f} %, 10 / 90 %: {np.percentile(d, 10):.2f} / {np.percentile(d, 90):.2f} %")


if __name__ == "__main__":
    main()
