"""Russian roulette on the realistic bench's window room (issue 25): Pathlight's relative variance
of one sample and its CPU time per sample for several RenderSettings.rr_start_bounce values, one
thread, in one run. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/window_room_rr.py [--starts 1 2 3 5] [--seeds 24] [--spp 16]

Variance as variance_per_sample.py scores it (relative, against the mean of every variant's
renders: the estimators are unbiased), beside it the pixels' median and the image without its
worst 1 % (the bowl's caustic fireflies hold most of the mean); CPU time per sample as
sky_samples_variance.py (the difference of --hi and --lo spp renders over the difference of the
sample counts, the variants alternating, median of --repeats); rays per path from the core's
counters. Equal-time error: variance x time, each variant over the default's (3)."""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from core_bench import export_for_core, render_cpu  # noqa: E402
import realistic_scenes  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--starts", type=int, nargs="+", default=[1, 2, 3, 5])
    ap.add_argument("--seeds", type=int, default=24)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--lo", type=int, default=4)
    ap.add_argument("--hi", type=int, default=36)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--width", type=int, default=96)
    a = ap.parse_args()
    scene = realistic_scenes.window_room(a.width, a.width * 3 // 4)
    pc, cs, st = export_for_core(scene)

    def run(start, spp, seed):
        st.rr_start_bounce = start
        st.samples, st.seed = spp, seed
        img, rays_per_path, run.cpu = render_cpu(pc, cs, st)
        return img, rays_per_path

    run(3, 1, 0)  # (the first render builds what the others share)
    cpu = {s: [] for s in a.starts}
    for _ in range(a.repeats):
        for s in a.starts:
            run(s, a.lo, 1)
            lo = run.cpu
            run(s, a.hi, 1)
            cpu[s].append((run.cpu - lo) / (a.hi - a.lo))
    imgs, rpp = {}, {}
    for s in a.starts:
        out = [run(s, a.spp, 100 + k) for k in range(a.seeds)]
        imgs[s] = np.stack([o[0] for o in out])
        rpp[s] = float(np.mean([o[1] for o in out]))
        print(f"rendered start {s}", flush=True)
    ref = np.mean([imgs[s].mean(0) for s in a.starts], axis=0)
    base = 3 if 3 in a.starts else a.starts[0]
    res = {}
    for s in a.starts:
        var = (imgs[s].var(0, ddof=1) * a.spp / (ref ** 2 + 1e-2)).mean(-1).ravel()
        cut = np.sort(var)[: int(len(var) * 0.99)]
        res[s] = (var.mean(), float(np.median(var)), cut.mean(), float(np.median(cpu[s])))
    b = res[base]
    print(f"\n{a.seeds} seeds x {a.spp} spp, {a.width}x{a.width * 3 // 4}, one thread; relative variance of one "
          "sample (mean / median / without top 1 %), CPU ms per sample, rays per path; equal-time error "
          f"of start {base} over this one's (mean / median / without top 1 %)")
    for s in a.starts:
        v = res[s]
        eff = [b[i] * b[3] / (v[i] * v[3]) for i in range(3)]
        print(f"start {s}: {v[0]:.4g} / {v[1]:.4g} / {v[2]:.4g}, {1e3 * v[3]:.2f} ms "
              f"(runs {', '.join(f'{1e3 * x:.2f}' for x in cpu[s])}), {rpp[s]:.3f} rays/path, "
              f"mean {imgs[s].mean():.5f}; equal time {eff[0]:.3f}x / {eff[1]:.3f}x / {eff[2]:.3f}x", flush=True)


if __name__ == "__main__":
    main()
