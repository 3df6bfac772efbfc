"""Light-vertex connections (RenderSettings.caustic_connections) on a realistic scene (issue 25):
the add-on's default (Automatic caustic light paths) against the same with connections at the
first K rough vertices, seeds x spp interleaved. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/caustic_connections_window.py [--scene window_room] [--seeds N]
        [--spp S] [--variants NAME=setting:value,... ...] [--save F.npz] [--load F.npz ...]

The error of each render is its relative squared error (the bench's weighting, 1 / (ref^2 +
0.01)) against the mean of all renders of all variants (each unbiased: the least noisy
reference at hand), averaged over the seeds, with the 5-95 % range of a paired bootstrap over
the seeds; beside it the mean without each image's top 1 % of pixels and the per-pixel variance
over the seeds (guiding_window_variants.py's estimate). Equal time: take instruction counts
from callgrind_forest.py --scene S --set caustic_light_paths=0.1 [caustic_connections=K]."""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
from core_bench import override_render_settings  # noqa: E402
import realistic_scenes as rs  # noqa: E402
from guiding_window_variants import parse  # noqa: E402  (a variant's "setting:value,..." spec)

OVERRIDES = {}


def report(imgs, times, title):
    names = list(imgs)
    ref = np.mean([np.mean(imgs[n], axis=0) for n in names], axis=0)
    w = 1.0 / (ref ** 2 + 1e-2)
    print(f"\n{title}")
    rng = np.random.default_rng(7)
    n = min(len(imgs[k]) for k in names)
    boot = rng.integers(0, n, (2000, n))
    err = {}
    for k in names:
        a = np.array(imgs[k])[:n]
        e = (w * (a - ref) ** 2).mean(-1).reshape(n, -1)  # per render and pixel
        cut = np.sort(e, axis=1)[:, : int(e.shape[1] * 0.99)].mean(1)
        err[k] = (e.mean(1), cut)
        var = (np.var(a, axis=0, ddof=1) * w).mean()
        t = np.array(times[k])[:n].mean(0)
        print(f"{k}: error {e.mean():.5f} (without top 1 %: {cut.mean():.5f}), per-pixel variance {var:.5f}, "
              f"image mean {a.mean() / ref.mean():.4f}, wall {t[0]:.1f} s, CPU {t[1]:.1f} s")
    base = names[0]
    for k in names[1:]:
        r = err[base][0][boot].mean(1) / err[k][0][boot].mean(1)
        rc = err[base][1][boot].mean(1) / err[k][1][boot].mean(1)
        print(f"{base} / {k}: error ratio {err[base][0].mean() / err[k][0].mean():.3f} [{np.percentile(r, 5):.3f}, "
              f"{np.percentile(r, 95):.3f}], without top 1 % {err[base][1].mean() / err[k][1].mean():.3f} "
              f"[{np.percentile(rc, 5):.3f}, {np.percentile(rc, 95):.3f}]")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--scene", default="window_room")
    ap.add_argument("--variants", nargs="*", default=["conn1=caustic_connections:1", "conn2=caustic_connections:2"])
    ap.add_argument("--save")
    ap.add_argument("--load", nargs="+")
    args = ap.parse_args()
    if args.load:
        imgs, times = {}, {}
        files = [np.load(f) for f in args.load]
        names = [k[4:] for k in files[0].files if k.startswith("img_") and all(k in d.files for d in files)]
        for d in files:  # (the variants that every file holds)
            for k in names:
                imgs.setdefault(k, []).extend(d["img_" + k])
                times.setdefault(k, []).extend(d["time_" + k])
        report(imgs, times, " + ".join(args.load))
        return
    build = getattr(rs, args.scene)
    override_render_settings(load_addon(), OVERRIDES, cast=True)
    variants = [("auto", {})] + [(v.split("=")[0], parse(v.split("=", 1)[1])) for v in args.variants]
    imgs = {n: [] for n, _ in variants}
    times = {n: [] for n, _ in variants}
    for k in range(args.seeds):
        for name, spec in variants:
            OVERRIDES.clear()
            OVERRIDES.update(spec)
            scene = build()
            t, cpu = time.perf_counter(), time.process_time()
            img = render_to_array(scene, "PATHLIGHT", max_bounces=12, samples=args.spp, seed=args.first_seed + k)
            imgs[name].append(img[..., :3].astype(np.float64))
            times[name].append((time.perf_counter() - t, time.process_time() - cpu))
            print(name, k, f"mean {imgs[name][-1].mean():.5f}", flush=True)
        if args.save:
            np.savez(args.save, **{f"img_{n}": np.array(v) for n, v in imgs.items()},
                     **{f"time_{n}": np.array(v) for n, v in times.items()})
    report(imgs, times, f"{args.scene}, {args.seeds} seeds (from {args.first_seed}) x {args.spp} spp")


if __name__ == "__main__":
    main()
