"""How fast each sampler's error falls with the sample count (issue 25; docs/design/sampling.md,
"Random numbers"): N x mean relative MSE against a high-spp reference, a few seeds per count
(flat for plain Monte Carlo, falling where QMC beats 1/N). Box filter, max bounces 12.

  .venv/bin/python tests/bench/sampler_slope.py instanced_forest [--ref-spp 4096] [--seeds 4]
      [--spp 16,256,1024] [--samplers SOBOL,SOBOL_DEEP,SOBOL4D,SOBOL4D_DEEP] [--cycles-ref]

The reference is the mean of two Pathlight renders (Sobol, seeds 9000-9001), plus two Cycles
renders with --cycles-ref (as the issue's first measurement); the reference's own noise (from the
spread of its renders) is subtracted. Scenes: realistic_scenes' builders, or cornell (the
tests' Cornell box fixture)."""
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
    a = ap.parse_args()

    def run(engine, spp, seed, sampler=None):
        sc = build(a.scene)
        if engine == "CYCLES":
            sc.cycles.pixel_filter_type = "BOX"
            sc.cycles.filter_width = 1.0
        elif sampler:
            sc.pathlight.sampler = sampler
        img = render_to_array(sc, engine, max_bounces=12, samples=spp, seed=seed)
        return img[..., :3].astype(np.float64)

    t0 = time.time()
    engines = ("PATHLIGHT", "CYCLES") if a.cycles_ref else ("PATHLIGHT",)
    refs = [[run(e, a.ref_spp, 9000 + k) for k in range(2)] for e in engines]
    ref = np.mean([r for pair in refs for r in pair], axis=0)
    # a render pair's rel. MSE is twice one render's; the mean of 2n renders has 1/(2n) of it
    floor = np.mean([rel_mse(p[0], p[1]) for p in refs]) / 2 / (2 * len(refs))
    print(f"{a.scene}: reference {len(refs) * 2} x {a.ref_spp} spp, floor {floor:.3e} "
          f"({time.time() - t0:.0f} s)", flush=True)
    for spp in map(int, a.spp.split(",")):
        cols = []
        for s in a.samplers.split(","):
            errs = [rel_mse(run("PATHLIGHT", spp, 1 + k, s), ref) - floor for k in range(a.seeds)]
            cols.append(f"{s} {np.mean(errs) * spp:.3e}")
        print(a.scene, spp, "N*err:", "; ".join(cols), f"({time.time() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
