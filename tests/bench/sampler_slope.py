"""How fast each sampler's error falls with the sample count (issue 25; docs/design/sampling.md,
"Random numbers"): N x mean relative MSE against a high-spp reference, a few seeds per count
(flat for plain Monte Carlo, falling where QMC beats 1/N). Box filter, max bounces 12.

  .venv/bin/python tests/bench/sampler_slope.py instanced_forest [--ref-spp 4096] [--seeds 4]
      [--spp 16,256,1024] [--samplers SOBOL,SOBOL_DEEP,SOBOL4D,SOBOL4D_DEEP] [--cycles-ref]
      [--robust] [--seeds-at 16:24,64:24,256:8] [--ref-cache ref.npz]
      [--pattern INDEPENDENT]

The reference is the mean of two Pathlight renders (Sobol, seeds 9000-9001), plus two Cycles
renders with --cycles-ref (as the issue's first measurement); the reference's own noise (from the
spread of its renders) is subtracted. Scenes: realistic_scenes' builders, or cornell (the
tests' Cornell box fixture).

--robust adds, per sampler, the per-pixel relative squared error's median and its mean without
the top 1 % of pixels (rare bright samples, which a few seeds do not pin down, dominate the plain
mean on caustic scenes), each N x, with the standard error over seeds, and the ratio to the
first sampler. These two are not floor-corrected (the same small bias for every sampler)."""
import argparse
import os
import sys
import time
from pathlib import Path

here = Path(__file__).resolve().parent
sys.path[:0] = [str(here), str(here.parent / "core"), str(here.parent / "blender")]
os.environ.setdefault("PATHLIGHT_CYCLES_REFS", "render")
import numpy as np  # noqa: E402
from blender_util import load_addon, open_fixture, render_to_array  # noqa: E402

load_addon()
import realistic_scenes as rs  # noqa: E402
from equal_time import rel_mse  # noqa: E402


def pixel_errors(img, ref):
    """equal_time.rel_mse per pixel (mean over the channels): its mean is rel_mse."""
    return np.mean((img - ref) ** 2 / (ref**2 + 1e-2), axis=-1).ravel()


def robust_stats(errs):
    """(mean, median, mean without the top 1 %) of one render's per-pixel errors."""
    e = np.sort(errs)
    return e.mean(), float(np.median(e)), e[:int(len(e) * 0.99)].mean()


def build(name):
    if name == "cornell":  # the tests' Cornell box fixture, 96 x 96
        sc = open_fixture("cornell_box")
        sc.render.resolution_x = sc.render.resolution_y = 96
        sc.render.resolution_percentage = 100
        return sc
    return getattr(rs, name)()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--spp", default="16,256,1024")
    ap.add_argument("--samplers", default="SOBOL,SOBOL_DEEP,SOBOL4D,SOBOL4D_DEEP")
    ap.add_argument("--cycles-ref", action="store_true")
    ap.add_argument("--robust", action="store_true")
    ap.add_argument("--seeds-at", default="", help="seeds per spp, e.g. 16:24,64:24,256:8")
    ap.add_argument("--ref-cache", help="an .npz that keeps the reference renders between runs")
    ap.add_argument("--pattern", default="INDEPENDENT", help="Pathlight's Noise Pattern (per-pixel error: "
                    "independent pixels by default, as before blue noise became the add-on's default)")
    a = ap.parse_args()

    sc = build(a.scene)  # once: the renders differ only in settings (the export cache helps)

    def run(engine, spp, seed, sampler="SOBOL"):
        if engine == "CYCLES":
            sc.cycles.pixel_filter_type = "BOX"
            sc.cycles.filter_width = 1.0
        else:
            sc.pathlight.sampler = sampler
            sc.pathlight.pixel_pattern = a.pattern
        img = render_to_array(sc, engine, max_bounces=12, samples=spp, seed=seed)
        return img[..., :3].astype(np.float64)

    t0 = time.time()
    engines = ("PATHLIGHT", "CYCLES") if a.cycles_ref else ("PATHLIGHT",)
    if a.ref_cache and os.path.exists(a.ref_cache):
        refs = list(np.load(a.ref_cache)["refs"])
    else:
        refs = [[run(e, a.ref_spp, 9000 + k) for k in range(2)] for e in engines]
        if a.ref_cache:
            np.savez(a.ref_cache, refs=np.asarray(refs))
    ref = np.mean([r for pair in refs for r in pair], axis=0)
    # a render pair's rel. MSE is twice one render's; the mean of 2n renders has 1/(2n) of it
    floor = np.mean([rel_mse(p[0], p[1]) for p in refs]) / 2 / (2 * len(refs))
    print(f"{a.scene}: reference {len(refs) * 2} x {a.ref_spp} spp, floor {floor:.3e} "
          f"({time.time() - t0:.0f} s)", flush=True)
    seeds_at = {int(k): int(v) for k, v in (kv.split(":") for kv in a.seeds_at.split(",") if kv)}
    for spp in map(int, a.spp.split(",")):
        cols, rob, base = [], [], None
        n = seeds_at.get(spp, a.seeds)
        for s in a.samplers.split(","):
            st = np.array([robust_stats(pixel_errors(run("PATHLIGHT", spp, 1 + k, s), ref)) for k in range(n)])
            st[:, 0] -= floor
            m, se = st.mean(axis=0) * spp, st.std(axis=0, ddof=1) * spp / np.sqrt(n)
            base = m if base is None else base
            cols.append(f"{s} {m[0]:.3e}")
            rob.append(f"{s} " + " / ".join(f"{x:.3e}±{e:.1e} ({x / b:.2f}x)" for x, e, b in zip(m, se, base)))
        print(a.scene, spp, "N*err:", "; ".join(cols), f"({time.time() - t0:.0f} s)", flush=True)
        if a.robust:
            print(f"  {n} seeds, mean / median / without top 1 %:", *rob, sep="\n    ", flush=True)


if __name__ == "__main__":
    main()
