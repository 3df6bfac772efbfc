"""Calibration for issue 25's guiding bar: what Cycles' own path guiding (Intel Open PGL, CPU)
gains on the realistic bench's window room against Cycles without it, at equal samples and at
equal CPU time. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/cycles_guiding_window.py [--seeds N] [--spp S] [--variants ...]

The method is guiding_photons_window.py --no-ref's: each variant renders the same seeds (1..N,
variants interleaved so that a shared machine's load falls on all alike); its error is the
per-pixel variance over the seeds, relative as the bench's (over the plain renders' mean
squared + 0.01), the estimators being unbiased; beside the mean, the pixels' median and the
image without its worst 1 %. Equal CPU time: plain's variance x CPU time over the variant's
(the process's CPU time, all threads; wall time is printed too). Renders never come from
tests/cycles_refs/ (refs="render").

Variants: name=training:probability[:sampling[:distribution[:mis]]]: guiding_training_samples,
surface_guiding_probability, guiding_directional_sampling_type (RIS, MIS, ROUGHNESS),
guiding_distribution_type (PARALLAX_AWARE_VMM, DIRECTIONAL_QUAD_TREE, VMM), use_guiding_mis_weights."""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import render_to_array  # noqa: E402
import realistic_scenes as rs  # noqa: E402

MAX_BOUNCES = 12


def render(spp, seed, guided=None):
    scene = rs.window_room()
    c = scene.cycles
    scene.cycles.pixel_filter_type, scene.cycles.filter_width = "BOX", 1.0
    c.use_guiding = guided is not None
    if guided is not None:
        training, prob, *rest = guided
        c.use_surface_guiding, c.use_volume_guiding = True, False
        c.guiding_training_samples = int(training)
        c.surface_guiding_probability = float(prob)
        if len(rest) > 0:
            c.guiding_directional_sampling_type = rest[0]
        if len(rest) > 1:
            c.guiding_distribution_type = rest[1]
        if len(rest) > 2:
            c.use_guiding_mis_weights = rest[2] not in ("0", "off", "False")
    t, cpu = time.perf_counter(), time.process_time()
    img = render_to_array(scene, "CYCLES", max_bounces=MAX_BOUNCES, samples=spp, seed=seed, refs="render")
    return img[..., :3].astype(np.float64), time.perf_counter() - t, time.process_time() - cpu


def summary(imgs, base_mean):
    denom = base_mean ** 2 + 1e-2
    var = (np.var(imgs, axis=0, ddof=1) / denom).mean(-1).ravel()
    cut = np.sort(var)[: int(len(var) * 0.99)]
    return np.array([var.mean(), np.median(var), cut.mean()])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--variants", nargs="*", default=["guided=128:0.5"])
    args = ap.parse_args()
    variants = [("plain", None)] + [(v.split("=")[0], v.split("=")[1].split(":")) for v in args.variants]
    imgs = {n: [] for n, _ in variants}
    times = {n: [] for n, _ in variants}
    for k in range(args.seeds):
        for name, spec in variants:
            img, t, cpu = render(args.spp, args.first_seed + k, spec)
            imgs[name].append(img)
            times[name].append((t, cpu))
            print(name, k, f"wall {t:.1f} s, CPU {cpu:.1f} s, mean {img.mean():.5f}", flush=True)
    base = np.mean(imgs["plain"], axis=0)
    s0 = summary(np.array(imgs["plain"]), base)
    t0 = np.array(times["plain"]).mean(0)
    print(f"\nCycles, {args.seeds} seeds x {args.spp} spp, 96x72: relative variance per pixel over the seeds; "
          "ratios plain / variant (mean / median / without top 1 %), CPU time variant / plain, equal CPU time")
    for name, _ in variants:
        s = summary(np.array(imgs[name]), base)
        r = s0 / s
        t = np.array(times[name]).mean(0) / t0
        per_seed = [float(((im - base) ** 2 / (base ** 2 + 1e-2)).mean()) for im in imgs[name]]
        print(f"{name}: variance {s[0]:.4f}, {r[0]:.2f}x / {r[1]:.2f}x / {r[2]:.2f}x, wall {t[0]:.2f}x, "
              f"CPU {t[1]:.2f}x, equal CPU time {r[0] / t[1]:.2f}x / {r[1] / t[1]:.2f}x / {r[2] / t[1]:.2f}x; "
              f"image mean {np.mean(imgs[name]) / base.mean():.4f} of plain's; per-seed error against plain's "
              "mean " + " ".join(f"{x:.3f}" for x in per_seed), flush=True)


if __name__ == "__main__":
    main()
