"""Path-guiding variants on the realistic bench's window room (issue 25) at equal samples and
equal CPU time against plain path tracing. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/guiding_window_variants.py [--seeds N] [--spp S] \
        [--size W] [--variants NAME=setting:value,setting:value ...]

A variant is the add-on's Path Guiding (use_guiding) with core RenderSettings overridden, e.g.
learnt=guiding_learn_probability:0 or camera=guiding_photons:0,guiding_caustics:0 ('default=':
the add-on's as it is; docs/design/sampling.md's runs were measured before it took the learnt
probability, cosine and filter on, so theirs was caustic photons, share 0.15, alone). 'plain'
(no guiding) is always rendered.
The method is guiding_photons_window.py --no-ref's: every variant renders seeds 1..N, the
variants interleaved so that a shared machine's load falls on all alike; the error is the
per-pixel variance over the seeds (relative as the bench's, over the plain renders' mean squared
+ 0.01), the estimators being unbiased; beside the mean, the pixels' median and the image
without its worst 1 %. Equal CPU time: plain's variance x CPU time (the process's, all threads)
over the variant's."""
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

MAX_BOUNCES = 12
OVERRIDES = {}


def parse(spec):
    out = {}
    for item in filter(None, spec.split(",")):
        k, v = item.split(":")
        out[k] = float(v)
    return out


def render(guided, spp, seed, build=rs.window_room):
    scene = build()
    t, cpu = time.perf_counter(), time.process_time()
    img = render_to_array(scene, "PATHLIGHT", max_bounces=MAX_BOUNCES, samples=spp, seed=seed, use_guiding=guided)
    return img[..., :3].astype(np.float64), time.perf_counter() - t, time.process_time() - cpu


def summary(imgs, base_mean):
    var = (np.var(imgs, axis=0, ddof=1) / (base_mean ** 2 + 1e-2)).mean(-1).ravel()
    cut = np.sort(var)[: int(len(var) * 0.99)]
    return np.array([var.mean(), np.median(var), cut.mean()])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--scene", default="window_room")
    ap.add_argument("--size", type=int, default=0, help="image width (height 3/4 of it; 0: the bench's)")
    ap.add_argument("--variants", nargs="*", default=["default=", "learnt=guiding_learn_probability:1"])
    ap.add_argument("--save", help="an .npz the images and times go to after every seed (partial runs)")
    ap.add_argument("--load", nargs="+", help="summarise runs saved with --save instead of rendering: the "
                    "seeds of every file, for the variants that all of them hold (their seeds must differ)")
    args = ap.parse_args()
    if args.load:
        imgs, times = {}, {}
        files = [np.load(f) for f in args.load]
        names = [k[4:] for k in files[0].files if k.startswith("img_") and all(k in d.files for d in files)]
        for d in files:
            n = min(len(d[f"img_{k}"]) for k in names)  # (a partial run: the seeds all variants rendered)
            for k in names:
                imgs.setdefault(k, []).extend(d[f"img_{k}"][:n])
                times.setdefault(k, []).extend(d[f"time_{k}"][:n])
        report(imgs, times, f"{' + '.join(args.load)}: {len(imgs['plain'])} seeds x {args.spp} spp")
        return
    build = getattr(rs, args.scene)
    if args.size:
        build = (lambda b, w: lambda: b(w, w * 3 // 4))(build, args.size)
    addon = load_addon()
    override_render_settings(addon, OVERRIDES, cast=True)

    variants = [("plain", None)] + [(v.split("=")[0], parse(v.split("=", 1)[1])) for v in args.variants]
    imgs = {n: [] for n, _ in variants}
    times = {n: [] for n, _ in variants}
    for k in range(args.seeds):
        for name, spec in variants:
            OVERRIDES.clear()
            OVERRIDES.update(spec or {})
            img, t, cpu = render(spec is not None, args.spp, args.first_seed + k, build)
            imgs[name].append(img)
            times[name].append((t, cpu))
            print(name, k, f"wall {t:.1f} s, CPU {cpu:.1f} s, mean {img.mean():.5f}", flush=True)
        if args.save:
            np.savez(args.save, **{f"img_{n}": np.array(v) for n, v in imgs.items()},
                     **{f"time_{n}": np.array(v) for n, v in times.items()})
    report(imgs, times, f"{args.scene}, {args.seeds} seeds (from {args.first_seed}) x {args.spp} spp")


def report(imgs, times, title):
    base = np.mean(imgs["plain"], axis=0)
    s0 = summary(np.array(imgs["plain"]), base)
    t0 = np.array(times["plain"]).mean(0)
    print(f"\n{title}: relative variance per pixel over the seeds; ratios plain / variant (mean / median / "
          "without top 1 %), CPU time variant / plain, equal CPU time (the same three)")
    for name in imgs:
        s = summary(np.array(imgs[name]), base)
        r = s0 / s
        t = np.array(times[name]).mean(0) / t0
        print(f"{name}: variance {s[0]:.4f}, {r[0]:.2f}x / {r[1]:.2f}x / {r[2]:.2f}x, wall {t[0]:.2f}x, "
              f"CPU {t[1]:.2f}x, equal CPU time {r[0] / t[1]:.2f}x / {r[1] / t[1]:.2f}x / {r[2] / t[1]:.2f}x; "
              f"image mean {np.mean(imgs[name]) / base.mean():.4f} of plain's", flush=True)


if __name__ == "__main__":
    main()
