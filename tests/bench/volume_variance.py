"""Equal-time error on the volume bench scenes split into its two parts (issue 23): per-sample
variance at equal samples, and cost per sample, Pathlight against Cycles.

    .venv/bin/python tests/bench/volume_variance.py [--scene smoke|fog] [--size 40] [--seeds 8]
        [--spp 16] [--timing-reps 3] [--no-timing] [--threads 1]

Variance: each engine renders the scene `seeds` times at `spp` with different seeds; the score
is variance_per_sample.py's (mean over pixels of var * spp / (ref^2 + 1e-2), ref the mean of
both engines). Cycles' images are cached in /tmp (they do not change with our code).
Cost: each engine renders at spp and at 3 spp, back to back, `timing-reps` times, with one
thread; the time per sample is the difference over 2 spp (export and setup cancel), and the
ratio Pathlight / Cycles is taken per repetition (the machine's load drifts slowly); --cpu-time
counts the process's CPU time instead of wall time (both engines render in this process).
Equal-time error ratio (Pathlight / Cycles) = variance ratio x cost ratio."""
import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
import volume_scenes  # noqa: E402

BUILDS = {"smoke": volume_scenes.smoke_grid, "fog": volume_scenes.fog_box}
MAX_BOUNCES = 12


def render(name, size, engine, threads=0, **settings):
    settings.setdefault("max_bounces", MAX_BOUNCES)
    scene = BUILDS[name](size, size)
    if engine == "CYCLES":
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 1.0
    if threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
    t, cpu = time.perf_counter(), time.process_time()
    img = render_to_array(scene, engine, **settings)
    if render.cpu_time:  # the process's CPU time: what a loaded machine's waits do not inflate
        return img[..., :3].astype(np.float64), time.process_time() - cpu
    return img[..., :3].astype(np.float64), time.perf_counter() - t


render.cpu_time = False


def images(name, size, engine, seeds, spp, threads, max_bounces=MAX_BOUNCES):
    key = hashlib.sha1(f"{name}{size}{seeds}{spp}{max_bounces}v1".encode()).hexdigest()[:12]
    cache = Path("/tmp") / f"pathlight_cycles_volvar_{key}.npy"
    if engine == "CYCLES" and cache.exists():
        return np.load(cache)
    out = np.stack([render(name, size, engine, threads, samples=spp, seed=1000 + s, max_bounces=max_bounces)[0]
                    for s in range(seeds)])
    if engine == "CYCLES":
        np.save(cache, out)
    return out


def rel_var(imgs, ref, spp):
    return float(np.mean(imgs.var(axis=0, ddof=1) * spp / (ref**2 + 1e-2)))


def tail(imgs, ref, spp):
    """How heavy the error's tail is: each image's squared deviation per pixel from the engine's
    own mean (relative, as rel_var), its largest value and the share of the sum held by the 10
    largest and by the largest 0.1 % (fireflies, which a few seeds' variance undercounts)."""
    dev = np.sort(((imgs - imgs.mean(axis=0)) ** 2 * spp / (ref**2 + 1e-2)).mean(axis=-1).ravel())[::-1]
    return dev[0], dev[:10].sum() / dev.sum(), dev[:max(1, dev.size // 1000)].sum() / dev.sum()


def print_blocks(pl, cy, ref, spp, b):
    """Where the variance is: per block of b x b pixels (image rows top first), the block's mean
    radiance, its share of Pathlight's summed relative variance, and Pathlight / Cycles."""
    def per_block(imgs):
        v = (imgs.var(axis=0, ddof=1) * spp / (ref**2 + 1e-2)).mean(axis=-1)
        h, w = v.shape[0] // b, v.shape[1] // b
        return v[:h * b, :w * b].reshape(h, b, w, b).mean(axis=(1, 3))
    vp, vc = per_block(pl), per_block(cy)
    h, w = vp.shape
    lum = ref.mean(axis=-1)[:h * b, :w * b].reshape(h, b, w, b).mean(axis=(1, 3))
    for title, grid, fmt in (("mean radiance", lum, "{:6.3f}"), ("share of Pathlight's variance (%)",
                             100 * vp / vp.sum(), "{:6.1f}"), ("Pathlight / Cycles", vp / vc, "{:6.2f}")):
        print(f"  {title} per {b}x{b} block:")
        for row in grid:  # (top row first)
            print("   " + "".join(fmt.format(x) for x in row))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", choices=list(BUILDS), default="smoke")
    ap.add_argument("--size", type=int, default=40)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--timing-reps", type=int, default=3)
    ap.add_argument("--timing-spp", type=int, default=16)
    ap.add_argument("--threads", type=int, default=2, help="threads of the variance renders")
    ap.add_argument("--max-bounces", type=int, default=MAX_BOUNCES)
    ap.add_argument("--no-timing", action="store_true")
    ap.add_argument("--cpu-time", action="store_true",
                    help="time per sample as the process's CPU time, not wall time (a loaded machine)")
    ap.add_argument("--no-variance", action="store_true")
    ap.add_argument("--blocks", type=int, default=0,
                    help="also print the variance per block of this many pixels a side, Pathlight / Cycles")
    ap.add_argument("--save", help="save both engines' images (npz: pathlight, cycles) here")
    a = ap.parse_args()
    render.cpu_time = a.cpu_time
    load_addon()
    var_ratio = cost_ratio = None
    if not a.no_variance:
        pl = images(a.scene, a.size, "PATHLIGHT", a.seeds, a.spp, a.threads, a.max_bounces)
        cy = images(a.scene, a.size, "CYCLES", a.seeds, a.spp, a.threads, a.max_bounces)
        ref = 0.5 * (pl.mean(0) + cy.mean(0))
        vp, vc = rel_var(pl, ref, a.spp), rel_var(cy, ref, a.spp)
        var_ratio = vp / vc
        print(f"{a.scene} {a.size}x{a.size} @ {a.spp} spp x {a.seeds} seeds: rel. variance/sample "
              f"Pathlight {vp:.4g}, Cycles {vc:.4g}, ratio {var_ratio:.3f}; mean ratio {pl.mean() / cy.mean():.4f}",
              flush=True)
        for engine, imgs in (("Pathlight", pl), ("Cycles", cy)):
            big, top10, top_milli = tail(imgs, ref, a.spp)
            print(f"  {engine} tail: largest pixel {big:.4g}, 10 largest {100 * top10:.1f} %, "
                  f"largest 0.1 % {100 * top_milli:.1f} % of the summed squared deviation", flush=True)
        if a.blocks:
            print_blocks(pl, cy, ref, a.spp, a.blocks)
        if a.save:
            np.savez_compressed(a.save, pathlight=pl, cycles=cy)
    if not a.no_timing:
        ratios = []
        for rep in range(a.timing_reps):
            per = {}
            for engine in ("PATHLIGHT", "CYCLES"):
                t1 = render(a.scene, a.size, engine, 1, samples=a.timing_spp, seed=7,
                            max_bounces=a.max_bounces)[1]
                t3 = render(a.scene, a.size, engine, 1, samples=3 * a.timing_spp, seed=7,
                            max_bounces=a.max_bounces)[1]
                per[engine] = (t3 - t1) / (2 * a.timing_spp)
            ratios.append(per["PATHLIGHT"] / per["CYCLES"])
            print(f"  timing {rep}: s/sample Pathlight {per['PATHLIGHT']:.4g}, Cycles {per['CYCLES']:.4g}, "
                  f"ratio {ratios[-1]:.3f}", flush=True)
        cost_ratio = float(np.median(ratios))
        print(f"{a.scene}: cost per sample ratio (median) {cost_ratio:.3f}, spread {min(ratios):.3f}-{max(ratios):.3f}")
    if var_ratio and cost_ratio:
        print(f"{a.scene}: equal-time error ratio Pathlight / Cycles ~ {var_ratio * cost_ratio:.3f} "
              f"(Cycles ahead when > 1)")


if __name__ == "__main__":
    main()
