"""Where the window room's error is (issue 25): per-pixel variance split by path class, plain
and guided. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/guiding_path_classes.py [--seeds N] [--spp S] [--variants ...]

Each render keeps the light of one path class only (RenderSettings.guiding_class_mask, a
measurement setting of the guided kernels; PathClass in core/render/trace_path.inl): the kinds
of a path's scattering vertices from the camera, rough (what guiding samples) or smooth (the
metal bowl, the lacquer, glass). Plain is the guided kernel with guide probability 0 (the plain
estimator, with the guided kernel's cost). A class's variance per pixel is its renders' spread
over the seeds (the estimators are unbiased, so that is its expected squared error), relative as
the bench's error (over ref^2 + 0.01, ref: the cached plain reference of
guiding_photons_window.py, or the mean of the seeds' renders)."""
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
CLASSES = ("direct (L D E, L S E)", "caustic L S+ D E", "caustic L S+ D D+ E", "caustic seen: L .. S .. D E",
           "smooth first: L .. S E", "rough only: L D D+ E")
SETTINGS = {}


def render(spp, seed, mask, spec):
    SETTINGS.clear()
    SETTINGS.update(spec, guiding_class_mask=mask)
    t = time.process_time()
    img = render_to_array(rs.window_room(), "PATHLIGHT", max_bounces=MAX_BOUNCES, samples=spp, seed=seed,
                          use_guiding=True)
    return img[..., :3].astype(np.float64), time.process_time() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--ref", default="/tmp/lguide_window_ref.npy")
    ap.add_argument("--variants", nargs="*", default=["plain", "guided"])
    args = ap.parse_args()
    addon = load_addon()
    override_render_settings(addon, SETTINGS)
    specs = {"plain": dict(guiding_probability=0.0, guiding_photons=0.0),
             "camera": dict(guiding_photons=0.0),
             "guided": {},  # the add-on's Path Guiding as it is
             "lobes": dict(guiding_caustic_lobes=0.3),  # with caustic lobes
             "nolobes": dict(guiding_caustic_lobes=0.0)}  # without them
    imgs = {v: np.zeros((len(CLASSES), args.seeds, rs.HEIGHT, rs.WIDTH, 3)) for v in args.variants}
    cpu = {v: 0.0 for v in args.variants}
    for s in range(args.seeds):
        for v in args.variants:
            for k in range(len(CLASSES)):
                imgs[v][k, s], t = render(args.spp, 1 + s, 1 << k, specs[v])
                cpu[v] += t
            print(v, s, flush=True)
    ref_path = Path(args.ref)
    ref = np.load(ref_path) if ref_path.exists() else imgs[args.variants[0]].sum(0).mean(0)
    denom = (ref ** 2 + 1e-2)
    print(f"\n{args.seeds} seeds x {args.spp} spp, 96x72; relative variance per pixel (image mean) by class;"
          " share of the sum; share of it in the 1 % of pixels with the most total variance; class mean light")
    for v in args.variants:
        var = imgs[v].var(axis=1, ddof=1) / denom  # (class, h, w, 3)
        per_class = var.mean(-1)  # (class, h, w)
        total = imgs[v].sum(0).var(axis=0, ddof=1) / denom
        tot_px = total.mean(-1)
        top = tot_px >= np.quantile(tot_px, 0.99)
        s = per_class.reshape(len(CLASSES), -1).mean(1)
        print(f"{v}: total (with covariances) {tot_px.mean():.4g}, sum of classes {s.sum():.4g}, "
              f"top 1 % hold {tot_px[top].sum() / tot_px.sum():.0%}; CPU {cpu[v]:.0f} s")
        for k, name in enumerate(CLASSES):
            print(f"  {name:32s} {s[k]:.4g}  {s[k] / s.sum():6.1%}  top1% {per_class[k][top].sum() / max(per_class[k].sum(), 1e-30):6.1%}"
                  f"  light {imgs[v][k].mean() / max(imgs[v].sum(0).mean(), 1e-30):6.2%}")
    np.savez_compressed("/tmp/wguide_classes.npz", **{v: imgs[v] for v in args.variants})


if __name__ == "__main__":
    main()
