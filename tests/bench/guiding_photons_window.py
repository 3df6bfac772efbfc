"""Photon-trained path guiding on the realistic bench's window room (issue 25): plain, camera-
trained guiding and photon-trained guiding at equal samples, each render's time beside it, for
the equal-time ratio (error x time). Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/guiding_photons_window.py [--seeds N] [--spp S] [--ref PATH]

The reference (plain renders, --ref-renders x --ref-spp, seeds 1000...) is rendered once and
cached at --ref. Variants: name=photons:share[:split[:caustics[:probability[:lobes[:cube[:cone]]]]]]
(photons per pixel and training sample, their share of a cell's distribution, a photon record's
weight in the split count, 1: caustic photons only, kept over the iterations; the guide's
probability; the caustic lobes' probability, cube and cone, RenderSettings.guiding_caustic_*).
Relative MSE as the bench's (equal_time.rel_mse); beside the mean, the pixels' median and the
image without its worst 1 %.

--no-ref: no reference; the error is each variant's per-pixel variance over the seeds (relative
as the bench's, over the plain renders' mean squared + 0.01), the estimators being unbiased:
equal time is then plain's variance x CPU time over the variant's."""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
import realistic_scenes as rs  # noqa: E402

MAX_BOUNCES = 12
PHOTONS = {"photons": 0.0, "share": 0.5, "split": 1.0, "caustics": 0.0, "probability": 0.5, "lobes": 0.0,
           "cube": 0.01, "cone": 0.1}


def render(guiding, spp, seed, photons=0.0, share=0.5, split=1.0, caustics=0.0, probability=0.5, lobes=0.0,
           cube=0.01, cone=0.1):
    PHOTONS.update(photons=photons, share=share, split=split, caustics=caustics, probability=probability,
                   lobes=lobes, cube=cube, cone=cone)
    scene = rs.window_room()
    t, cpu = time.perf_counter(), time.process_time()
    img = render_to_array(scene, "PATHLIGHT", max_bounces=MAX_BOUNCES, samples=spp, seed=seed, use_guiding=guiding)
    return img[..., :3].astype(np.float64), time.perf_counter() - t, time.process_time() - cpu


def errors(img, ref):
    e = (img - ref) ** 2 / (ref ** 2 + 1e-2)
    per_pixel = e.mean(-1).ravel()
    cut = np.sort(per_pixel)[: int(len(per_pixel) * 0.99)]
    return float(per_pixel.mean()), float(np.median(per_pixel)), float(cut.mean())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--ref", default="/tmp/lguide_window_ref.npy")
    ap.add_argument("--ref-renders", type=int, default=12)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--variants", nargs="*", default=["camera=0:0.5", "photons=1:0.5"])
    ap.add_argument("--no-ref", action="store_true")
    args = ap.parse_args()
    addon = load_addon()
    inner = addon.session.render_settings

    def patched(pc, scene, warn=None):
        st = inner(pc, scene, warn)
        st.guiding_photons = PHOTONS["photons"]
        st.guiding_photon_share = PHOTONS["share"]
        st.guiding_photon_split = PHOTONS["split"]
        st.guiding_caustics = bool(PHOTONS["caustics"])
        st.guiding_probability = PHOTONS["probability"]
        st.guiding_caustic_lobes = PHOTONS["lobes"]
        st.guiding_caustic_cube = PHOTONS["cube"]
        st.guiding_caustic_cone = PHOTONS["cone"]
        return st
    addon.session.render_settings = patched

    ref_path = Path(args.ref)
    if args.no_ref:
        ref = None
    elif ref_path.exists():
        ref = np.load(ref_path)
    else:
        ref = np.mean([render(False, args.ref_spp, 1000 + k)[0] for k in range(args.ref_renders)], axis=0)
        np.save(ref_path, ref)
    variants = [("plain", None)]
    for v in args.variants:
        name, spec = v.split("=")
        variants.append((name, tuple(float(x) for x in spec.split(":"))))
    res = {name: [] for name, _ in variants}
    imgs = {name: [] for name, _ in variants}
    for k in range(args.seeds):  # interleaved, so that the machine's load falls on all alike
        for name, spec in variants:
            if spec is None:
                img, t, cpu = render(False, args.spp, 1 + k)
            else:
                img, t, cpu = render(True, args.spp, 1 + k, *spec)
            imgs[name].append(img)
            res[name].append(list((errors(img, ref) if ref is not None else (0.0, 0.0, 0.0)) + (t, cpu)))
            print(name, k, res[name][-1], flush=True)
    if ref is None:  # the seeds' spread in place of the error against a reference
        denom = np.mean(imgs["plain"], axis=0) ** 2 + 1e-2
        for name, _ in variants:
            var = (np.var(imgs[name], axis=0, ddof=1) / denom).mean(-1).ravel()
            cut = np.sort(var)[: int(len(var) * 0.99)]
            for r in res[name]:
                r[:3] = float(var.mean()), float(np.median(var)), float(cut.mean())
    base = np.array(res["plain"])
    print(f"\n{args.seeds} seeds x {args.spp} spp, 96x72; error ratios plain / variant "
          "(mean / median / without top 1 %), time variant / plain, equal time")
    for name, _ in variants:
        a = np.array(res[name])
        r = base[:, :3].mean(0) / a[:, :3].mean(0)
        tr = a[:, 3].mean() / base[:, 3].mean()
        # CPU time too (the process's, all threads): less at the mercy of a shared machine's load
        cr = a[:, 4].mean() / base[:, 4].mean()
        print(f"{name}: MSE {a[:, 0].mean():.4f}, {r[0]:.2f}x / {r[1]:.2f}x / {r[2]:.2f}x, "
              f"time {tr:.2f}x, equal time {r[0] / tr:.2f}x; CPU time {cr:.2f}x, equal CPU time "
              f"{r[0] / cr:.2f}x; per seed MSE "
              + " ".join(f"{x:.3f}" for x in a[:, 0]))


if __name__ == "__main__":
    main()
