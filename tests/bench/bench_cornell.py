"""Cornell box, Pathlight against Cycles (CPU) in one run: samples per second and relative MSE
at equal render time against a converged reference. Writes docs/bench/cornell.md (+ a plot).

The reference is the mean of a high-sample Pathlight render and a high-sample Cycles render
(both with a 1-pixel box filter, so they estimate the same image); their mutual relative MSE
is reported too, as the floor below which neither engine's error can be read."""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from blender_util import load_addon, open_fixture, render_to_array  # noqa: E402

SCALE = 50                     # % of the fixture's 256x256
TIMES = (1.0, 2.0, 4.0, 8.0)   # equal-time budgets, seconds of rendering (sync excluded)
REF_SPP = 4096


def render(engine, **settings):
    scene = open_fixture("cornell_box")
    if engine == "CYCLES":  # same pixel filter as Pathlight: a 1-pixel box
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 1.0
    t = time.perf_counter()
    img = render_to_array(scene, engine, resolution_percentage=SCALE, **settings)
    return img[..., :3].astype(np.float64), time.perf_counter() - t


def rel_mse(img, ref):
    return float(np.mean((img - ref) ** 2 / (ref**2 + 1e-2)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="docs/")
    ap.add_argument("--quick", action="store_true", help="smaller reference and budgets, for a smoke run")
    args = ap.parse_args()
    ref_spp, times = (REF_SPP, TIMES) if not args.quick else (256, (0.5, 1.0))
    load_addon()
    engines = ("PATHLIGHT", "CYCLES")

    # Throughput: wall time of a fixed-sample render minus that of a 1-sample one (export/sync).
    sps = {}
    for e in engines:
        _, t1 = render(e, samples=1)
        _, t64 = render(e, samples=65)
        sps[e] = 64.0 / max(t64 - t1, 1e-6)
        print(f"{e}: {sps[e]:.1f} samples/s per image ({sps[e] * 128 * 128 / 1e6:.2f} M samples/s)")

    refs = {}
    for e in engines:
        refs[e], t = render(e, samples=ref_spp, seed=12345)
        print(f"{e}: reference {ref_spp} spp in {t:.1f} s")
    ref = 0.5 * (refs["PATHLIGHT"] + refs["CYCLES"])
    floor = rel_mse(refs["PATHLIGHT"], refs["CYCLES"]) / 4.0  # each is half the distance from the mean

    errors = {e: [] for e in engines}
    for budget in times:
        for e in engines:
            img, wall = render(e, samples=1_000_000, time_limit=budget, seed=1)
            errors[e].append(rel_mse(img, ref))
            print(f"{e}: {budget:.1f} s budget ({wall:.1f} s wall) relMSE {errors[e][-1]:.3e}")

    out = Path(args.out) / "bench"
    out.mkdir(parents=True, exist_ok=True)
    plot = None
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(5, 3.5))
        for e in engines:
            ax.loglog(times, errors[e], "o-", label=e.title())
        ax.axhline(floor, color="grey", ls=":", label="reference noise floor")
        ax.set_xlabel("render time (s)")
        ax.set_ylabel("relative MSE")
        ax.set_title("Cornell box, 128x128")
        ax.legend()
        fig.tight_layout()
        plot = "cornell_rmse.png"
        fig.savefig(out / plot, dpi=110)
    except ImportError:
        pass

    lines = [
        "## Cornell box: Pathlight vs Cycles (CPU)",
        "",
        f"`blender_scenes/cornell_box.blend` at {SCALE} % (128x128), both engines in this process, all",
        "threads, no denoising, no clamping, equal bounce limits, 1-pixel box filter. Render time",
        "excludes scene export/sync (Cycles' own time limit excludes it too).",
        "",
        "| | Pathlight | Cycles | ratio |",
        "|---|---|---|---|",
        f"| samples per second (whole image) | {sps['PATHLIGHT']:.1f} | {sps['CYCLES']:.1f} | "
        f"{sps['PATHLIGHT'] / sps['CYCLES']:.2f}x |",
    ]
    for i, budget in enumerate(times):
        p, c = errors["PATHLIGHT"][i], errors["CYCLES"][i]
        lines.append(f"| relative MSE at {budget:g} s | {p:.3e} | {c:.3e} | {c / p:.2f}x lower |")
    lines += [
        "",
        f"Reference: mean of {ref_spp}-spp renders of both engines; their mutual relative MSE / 4 = "
        f"{floor:.2e} is the floor of these errors (it includes any bias between the engines).",
        "",
    ]
    if plot:
        lines += [f"![relative MSE against render time]({plot})", ""]
    (out / "cornell.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
