"""The blue-noise pixel pattern against independent pixels (and Cycles' default, blue noise) on
the realistic bench's scenes and the tests' Cornell box (docs/design/sampling.md, "Blue-noise
pattern"): over seeds at equal samples, the mean per-pixel variance (the per-pixel MSE of an
unbiased render), relative to the mean image, and the region factor, the variance of 8x8-pixel
region means over (pixel variance / 64): 1 where pixels' errors are independent, well below 1
where they cancel across a region; pooled (all regions' variance over all pixels', so the
noisiest regions decide) and the median region's. Box filter 1 px, max bounces 12. Not named bench_*.

    .venv/bin/python tests/bench/blue_noise_variance.py [--scenes instanced_forest,...]
        [--seeds 16] [--seed0 1] [--spp 16] [--patterns INDEPENDENT,BLUE_NOISE] [--cycles] [--sampler SOBOL4D]
"""
import argparse
import os
import sys
import time
from pathlib import Path

here = Path(__file__).resolve().parent
sys.path[:0] = [str(here), str(here.parent / "core"), str(here.parent / "blender")]
os.environ.setdefault("PATHLIGHT_CYCLES_REFS", "render")  # measurements: store nothing
import numpy as np  # noqa: E402
from blender_util import load_addon, render_to_array  # noqa: E402

load_addon()
from sampler_slope import build  # noqa: E402  (the realistic scenes, or 'cornell')

REGION = 8


def stats(imgs):
    """(relative pixel variance, region factor, image mean) of renders (seeds, H, W)."""
    imgs = np.asarray(imgs)
    n, h, w = imgs.shape
    mean = imgs.mean(axis=0)
    pix = imgs.var(axis=0, ddof=1)
    gh, gw = h // REGION, w // REGION
    reg = imgs[:, :gh * REGION, :gw * REGION].reshape(n, gh, REGION, gw, REGION).mean(axis=(2, 4))
    reg_var = reg.var(axis=0, ddof=1)
    pix_reg = pix[:gh * REGION, :gw * REGION].reshape(gh, REGION, gw, REGION).mean(axis=(1, 3))
    factor = reg_var.sum() / (pix_reg.sum() / REGION ** 2)
    median = np.median(reg_var / np.maximum(pix_reg / REGION ** 2, 1e-30))
    relpix = pix / (mean ** 2 + 1e-4)
    rel = relpix.mean()
    trimmed = np.sort(relpix.ravel())[: int(relpix.size * 0.99)].mean()  # without the top 1 %
    return rel, factor, median, mean.mean(), trimmed


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="instanced_forest,hdri_model,principled_spheres,cornell")
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--seed0", type=int, default=1)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--patterns", default="INDEPENDENT,BLUE_NOISE")
    ap.add_argument("--cycles", action="store_true", help="also Cycles' Automatic (blue noise)")
    ap.add_argument("--sampler", default="SOBOL", help="scene.pathlight.sampler of the Pathlight renders")
    a = ap.parse_args()
    t0 = time.time()
    for name in a.scenes.split(","):
        runs = [("PATHLIGHT", p) for p in a.patterns.split(",")] + ([("CYCLES", None)] if a.cycles else [])
        rows = []
        for engine, pattern in runs:
            imgs = []
            for seed in range(a.seed0, a.seed0 + a.seeds):
                sc = build(name)
                kw = dict(max_bounces=12, samples=a.spp, seed=seed)
                if engine == "CYCLES":
                    sc.cycles.pixel_filter_type, sc.cycles.filter_width = "BOX", 1.0
                    sc.cycles.use_denoising = False
                else:
                    sc.pathlight.pixel_pattern = pattern
                    sc.pathlight.sampler = a.sampler
                img = render_to_array(sc, engine, **kw)
                imgs.append(img[..., :3].mean(axis=2).astype(np.float64))
            rows.append((engine if engine == "CYCLES" else pattern, *stats(imgs)))
        base = rows[0][1]
        base_t = rows[0][5]
        for label, rel, factor, median, mean, trimmed in rows:
            print(f"{name} {a.sampler} {a.spp} spp x {a.seeds} seeds | {label:12s} | pixel rel. variance {rel:.4e} "
                  f"({rel / base:.3f}x; without the top 1 %: {trimmed / base_t:.3f}x) | region factor pooled {factor:.3f}, median {median:.3f} | mean {mean:.5f} "
                  f"({time.time() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
