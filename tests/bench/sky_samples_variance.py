"""Sky samples (docs/design/sampling.md "Sky samples") on the instanced forest: relative variance of
one sample and CPU time per sample with Scene.world_light_samples on and off, Pathlight alone,
one thread, in one run.

    .venv/bin/python tests/bench/sky_samples_variance.py [--no-sun] [--width 96] [--seeds 16]

Variance as variance_per_sample.py scores it (against the mean of both settings' renders); CPU
time per sample as forest_factors.py (the difference of --hi and --lo spp renders over the
difference of the sample counts, alternating the settings)."""
import argparse
import sys
from pathlib import Path

import bpy
import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from core_bench import export_for_core, render_cpu  # noqa: E402
import realistic_scenes  # noqa: E402
from variance_per_sample import rel_var  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--no-sun", action="store_true", help="the sun's strength 0: the sky the only light")
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--lo", type=int, default=4)
    ap.add_argument("--hi", type=int, default=68)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    scene = realistic_scenes.instanced_forest(a.width, a.width * 3 // 4)
    if a.no_sun:
        bpy.data.objects["Sun"].data.energy = 0.0
    pc, cs, st = export_for_core(scene)

    def run(on, spp, seed):
        cs.world_light_samples = on
        st.samples, st.seed = spp, seed
        img, rays_per_path, run.cpu = render_cpu(pc, cs, st)
        return img, rays_per_path

    run(True, 1, 0)  # (the first render builds what the others share)
    cpu = {True: [], False: []}
    for _ in range(a.repeats):
        for on in (False, True):
            run(on, a.lo, 1)
            lo = run.cpu
            run(on, a.hi, 1)
            cpu[on].append((run.cpu - lo) / (a.hi - a.lo))
    imgs, rpp = {}, {}
    for on in (False, True):
        out = [run(on, a.spp, 100 + s) for s in range(a.seeds)]
        imgs[on] = np.stack([o[0] for o in out])
        rpp[on] = out[0][1]
    ref = np.mean([imgs[on].mean(0) for on in imgs], axis=0)
    res = {}
    for on in (False, True):
        v, t = rel_var(imgs[on], ref, a.spp), float(np.median(cpu[on]))
        res[on] = (v, t)
        print(f"world_light_samples={on}: rel. variance/sample {v:.4g}, CPU {1e3 * t:.2f} ms/sample "
              f"(runs {', '.join(f'{1e3 * x:.2f}' for x in cpu[on])}), rays/path {rpp[on]:.3f}, "
              f"mean {imgs[on].mean():.5f}", flush=True)
    (v0, t0), (v1, t1) = res[False], res[True]
    print(f"variance {v0 / v1:.3f}x lower, CPU {t1 / t0:.3f}x, equal-time error {v0 * t0 / (v1 * t1):.3f}x lower")


if __name__ == "__main__":
    main()
