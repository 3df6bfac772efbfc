"""Converged agreement of Pathlight and Cycles on the realistic bench's window room (issue 25),
with each engine's own seed-to-seed noise beside it. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/window_room_converged.py [--seeds N] [--spp S] [--out DIR]
    .venv/bin/python tests/bench/window_room_converged.py --report [--out DIR]

Renders the bench's scene with the bench's settings (96x72, max bounces 12 of every type,
1-pixel box filter, no denoising, clamping or adaptive sampling, Cycles' light tree on) as N
seeds x S spp per engine, the engines alternating, each render saved to DIR (so that an
interrupted run keeps what it rendered and --report reads whatever is there). Cycles renders
with PATHLIGHT_CYCLES_REFS=render: nothing goes to tests/cycles_refs.

The report: the mean ratio and the 8x8 grid of regions (ms.compare), each region's difference
over its standard error from both engines' seed spread (z), the regions' chi^2 per region, and
each engine's own noise as the bench sees it: the worst region between two renders of one
engine (its seeds split in halves), i.e. what two references of that many samples show when
nothing differs."""
import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("PATHLIGHT_CYCLES_REFS", "render")

import numpy as np  # noqa: E402

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))

ENGINES = ("PATHLIGHT", "CYCLES")
GRID = 8


def region_values(img):
    from core_scenes import region_means
    return region_means(img, GRID).mean(-1)


def load(out):
    imgs = {e: [] for e in ENGINES}
    spp = {}
    for e in ENGINES:
        for f in sorted(out.glob(f"{e}_*.npy")):
            imgs[e].append(np.load(f))
            spp[e] = int(f.stem.split("_")[2])
    return imgs, spp


def region_stats(imgs, floor=0.02):
    """Per engine: the mean image, its regions and their standard errors (seed spread)."""
    out = {}
    for e, lst in imgs.items():
        stack = np.stack(lst)
        regions = np.stack([region_values(i) for i in stack])
        out[e] = dict(mean=stack.mean(0), regions=regions.mean(0),
                      se=regions.std(0, ddof=1) / np.sqrt(len(stack)), n=len(stack), per_seed=regions)
    return out


def report(out, floor=0.02):
    import bpy  # noqa: F401  (material_scenes needs bmesh, which comes with bpy)
    import material_scenes as ms
    imgs, spp = load(out)
    if min(len(v) for v in imgs.values()) < 2:
        print("need at least 2 renders per engine")
        return None
    st = region_stats(imgs)
    p, c = st["PATHLIGHT"], st["CYCLES"]
    ratio, worst, rel = ms.compare(p["mean"], c["mean"], floor=floor)
    denom = np.maximum(c["regions"], floor)
    diff = p["regions"] - c["regions"]
    se = np.hypot(p["se"], c["se"])
    z = diff / se
    # the image means' standard errors from the seeds
    pm = np.array([i[..., :3].mean() for i in imgs["PATHLIGHT"]])
    cm = np.array([i[..., :3].mean() for i in imgs["CYCLES"]])
    ratio_se = ratio * np.hypot(pm.std(ddof=1) / np.sqrt(len(pm)) / pm.mean(),
                                cm.std(ddof=1) / np.sqrt(len(cm)) / cm.mean())
    k = np.unravel_index(np.argmax(rel), rel.shape)
    lines = [f"Pathlight {p['n']} x {spp['PATHLIGHT']} spp, Cycles {c['n']} x {spp['CYCLES']} spp",
             f"mean ratio {ratio:.4f} +- {ratio_se:.4f}",
             f"worst region {100 * worst:.2f} % at {tuple(int(x) for x in k)}, z = {z[k]:.2f}; "
             f"max |z| {np.abs(z).max():.2f}; regions chi^2 per region {np.mean(z ** 2):.2f} "
             f"(noise alone: about {(st['PATHLIGHT']['n'] - 1) / (st['PATHLIGHT']['n'] - 3):.2f} with "
             f"{st['PATHLIGHT']['n']} seeds, Student's t)"]
    for e in ENGINES:
        s = st[e]
        rel_se = s["se"] / np.maximum(c["regions"], floor)
        # each engine's own noise as two references of half its renders each would show it
        h = s["n"] // 2
        a, b = s["per_seed"][:h].mean(0), s["per_seed"][h:2 * h].mean(0)
        halves = np.abs(a - b) / np.maximum(b, floor)
        lines.append(f"{e}: region relative standard error of the mean: median {100 * np.median(rel_se):.2f} %, "
                     f"max {100 * rel_se.max():.2f} %; worst region between its two halves "
                     f"({h} x {spp[e]} spp each) {100 * halves.max():.2f} %")
        lines.append(f"  per seed image mean: " + " ".join(f"{i[..., :3].mean():.5f}" for i in imgs[e]))
    order = np.argsort(rel.ravel())[::-1][:6]
    lines.append("worst regions (row, col): relative difference, z, Pathlight / Cycles relative s.e.")
    for o in order:
        r = np.unravel_index(o, rel.shape)
        lines.append(f"  {tuple(int(x) for x in r)}: {100 * rel[r]:.2f} %, z {z[r]:+.2f}, "
                     f"{100 * p['se'][r] / denom[r]:.2f} % / {100 * c['se'][r] / denom[r]:.2f} %")
    print("\n".join(lines))
    return dict(ratio=ratio, worst=worst, z=z, rel=rel)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--first-seed", type=int, default=101)
    ap.add_argument("--engines", nargs="*", default=list(ENGINES))
    ap.add_argument("--out", default="/tmp/wroom_converged")
    ap.add_argument("--report", action="store_true")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not args.report:
        from blender_util import load_addon, render_to_array
        import realistic_scenes as rs
        load_addon()
        for k in range(args.seeds):
            seed = args.first_seed + k
            for e in args.engines:
                path = out / f"{e}_{seed}_{args.spp}.npy"
                if path.exists():
                    continue
                scene = rs.window_room()
                extra = dict(pixel_filter_type="BOX", filter_width=1.0)
                t = time.perf_counter()
                img = render_to_array(scene, e, max_bounces=12, samples=args.spp, seed=seed, **extra)
                np.save(path, img[..., :3].astype(np.float64))
                print(e, seed, f"{time.perf_counter() - t:.1f} s", flush=True)
    report(out)


if __name__ == "__main__":
    main()
