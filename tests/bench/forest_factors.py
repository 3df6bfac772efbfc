"""The two factors of the equal-time error on the instanced forest (issue 25): samples per second
and the relative variance of one sample, Pathlight against Cycles, in one run.

    .venv/bin/python tests/bench/forest_factors.py [--scale 50] [--threads 2] [--seeds 8] [--spp 4]

Time per sample: each engine renders at `--lo` and `--hi` samples per pixel (alternating, twice),
and the difference of the wall times over the difference of the sample counts is one sample's
time: the export, Cycles' sync and both BVH builds cancel out. Variance: `--seeds` renders of
`--spp` samples each, scored as variance_per_sample.py does (mean over pixels of var x spp /
(ref^2 + 1e-2), ref the mean of both engines' renders). Efficiency (what the equal-time ratio
estimates) is 1 / (variance x time per sample). PL_CORE_DIR=<dir> renders with the module in
<dir> (an older build, for before/after runs in one session)."""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
from kernel_scenes import core  # noqa: E402
import realistic_scenes  # noqa: E402
from equal_time import rel_mse  # noqa: E402
from variance_per_sample import rel_var  # noqa: E402

MAX_BOUNCES = 12


def render(engine, scale, threads, **settings):
    scene = realistic_scenes.instanced_forest()
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    if engine == "CYCLES":
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 1.0
    t, c = time.perf_counter(), time.process_time()
    img = render_to_array(scene, engine, max_bounces=MAX_BOUNCES, resolution_percentage=scale, **settings)
    render.cpu = time.process_time() - c
    return img[..., :3].astype(np.float64), time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scale", type=int, default=50, help="percent of the bench's 96x72")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--lo", type=int, default=4)
    ap.add_argument("--hi", type=int, default=68)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--engines", nargs="+", default=["PATHLIGHT", "CYCLES"])
    ap.add_argument("--budget", type=float, default=0.0,
                    help="also the equal-time error at this time limit (seconds), against both "
                         "engines' --ref-spp renders")
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--ref-spp", type=int, default=256)
    a = ap.parse_args()
    sys.modules.setdefault("addon.pathlight_core", core())  # PL_CORE_DIR's module for the add-on too
    load_addon()
    if a.budget > 0:
        equal_time(a)
    per_sample = {e: [] for e in a.engines}
    cpu = {e: [] for e in a.engines}
    for _ in range(2):
        for e in a.engines:
            t_lo = render(e, a.scale, a.threads, samples=a.lo, seed=1)[1]
            c_lo = render.cpu
            t_hi = render(e, a.scale, a.threads, samples=a.hi, seed=1)[1]
            per_sample[e].append((t_hi - t_lo) / (a.hi - a.lo))
            cpu[e].append((render.cpu - c_lo) / (a.hi - a.lo))
    imgs = {e: np.stack([render(e, a.scale, a.threads, samples=a.spp, seed=100 + s)[0] for s in range(a.seeds)])
            for e in a.engines}
    ref = np.mean([imgs[e].mean(0) for e in a.engines], axis=0)
    out = {}
    for e in a.engines:
        t = float(np.median(per_sample[e]))
        v = rel_var(imgs[e], ref, a.spp)
        out[e] = (t, v)
        print(f"{e}: {1e3 * t:.2f} ms/sample (runs {', '.join(f'{1e3 * x:.2f}' for x in per_sample[e])}), "
              f"CPU {1e3 * np.median(cpu[e]):.2f} ms/sample, "
              f"rel. variance/sample {v:.4g}, mean {imgs[e].mean():.5f}", flush=True)
    if len(out) == 2:
        (tp, vp), (tc, vc) = out["PATHLIGHT"], out["CYCLES"]
        print(f"CPU time per sample Cycles/Pathlight {np.median(cpu['CYCLES']) / np.median(cpu['PATHLIGHT']):.3f}")
        print(f"samples/s Pathlight/Cycles {tc / tp:.3f}, variance/sample Cycles/Pathlight {vc / vp:.3f}, "
              f"efficiency (equal-time error ratio) {tc * vc / (tp * vp):.3f}")


def equal_time(a):
    """Cycles' relative MSE over Pathlight's at a time limit of a.budget seconds (the bench's
    measure without the floor), and the floor."""
    refs = [render(e, a.scale, a.threads, samples=a.ref_spp, seed=4242)[0] for e in ("PATHLIGHT", "CYCLES")]
    ref = 0.5 * (refs[0] + refs[1])
    floor = rel_mse(refs[0], refs[1]) / 4.0
    errs = {"PATHLIGHT": [], "CYCLES": []}
    for k in range(a.repeats):
        for e in errs:
            img = render(e, a.scale, a.threads, samples=1_000_000, time_limit=a.budget, seed=1 + k)[0]
            errs[e].append(rel_mse(img, ref))
    p, c = (np.mean(errs[e]) - floor for e in ("PATHLIGHT", "CYCLES"))
    print(f"equal time {a.budget:g} s: rel. MSE Pathlight {p:.3e}, Cycles {c:.3e} (floor {floor:.1e} "
          f"subtracted), lower error {c / p:.3f}x")


if __name__ == "__main__":
    main()
