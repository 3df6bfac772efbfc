"""Equal-time error against Cycles (CPU), side by side in one process, on the Cornell box, the
Cornell box with a glass sphere and the HDR-lit scene: samples per second, relative MSE at equal
render time, and the time each engine needs to reach a target error. Writes
docs/bench/equal_time.md and a log-log plot of error against time.

The reference of each scene is the mean of a high-sample Pathlight render and a high-sample
Cycles render (both with a 1-pixel box filter, so they estimate the same image); their mutual
relative MSE / 4 estimates the reference's own error (the floor). An image's MSE against the
reference is its error against the truth plus that floor, for both engines alike (the renders are
independent of the references), so the floor is subtracted before the engines' errors are compared:
left in, it would pull every ratio towards 1. Each budget is rendered several times by each engine
(different seeds, the engines alternating; at least MIN_REPEATS times and at least REPEAT_SECONDS of
rendering per budget, so short budgets get as precise an error as long ones) and the errors
averaged: one render's error is itself noisy (the glass box's caustics are rare bright samples).
Cycles runs with its defaults (light tree, Sobol-Burley) but no denoising, no clamping and no
adaptive sampling, the same bounce limits as Pathlight, and all threads.

Alongside, the per-sample variance of each engine (variance_per_sample.py: VAR_SEEDS renders of
VAR_SPP samples with different seeds): unlike the timings, it does not depend on the machine's
load, and equal-time error is that variance over the samples per second."""
import sys
import time
from pathlib import Path

import bpy
import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
from blender_util import load_addon, open_fixture, render_to_array  # noqa: E402
from benchutil import parse_args, section_dir, write_section  # noqa: E402
from equal_time import ENGINES, measure, plot_errors, repeats_for, time_to  # noqa: E402

SCALE = 50                     # % of the fixtures' 256x256
TIMES = (1.0, 2.0, 4.0, 8.0)   # equal-time budgets, seconds of rendering (sync excluded)
REF_SPP = 4096
VAR_SEEDS, VAR_SPP = 16, 16


def glass_sphere(scene):
    """The Cornell box with its sphere made of clear glass (caustics on the floor)."""
    mat = bpy.data.materials.new("BenchGlass")
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    glass = nodes.new("ShaderNodeBsdfGlass")
    glass.distribution = "SHARP" if "SHARP" in glass.bl_rna.properties["distribution"].enum_items else "BECKMANN"
    glass.inputs["Roughness"].default_value = 0.0
    glass.inputs["IOR"].default_value = 1.5
    out = nodes.new("ShaderNodeOutputMaterial")
    mat.node_tree.links.new(glass.outputs[0], out.inputs["Surface"])
    sphere = scene.objects["Sphere"]
    sphere.data.materials.clear()
    sphere.data.materials.append(mat)


SCENES = {
    "Cornell box": ("cornell_box", None),
    "Cornell box, glass sphere": ("cornell_box", glass_sphere),
    "HDR-lit scene": ("hdr_scene", None),
}


def render(fixture, setup, engine, **settings):
    scene = open_fixture(fixture)
    if setup:
        setup(scene)
    if engine == "CYCLES":  # the same pixel filter as Pathlight: a 1-pixel box
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 1.0
    t = time.perf_counter()
    img = render_to_array(scene, engine, resolution_percentage=SCALE, max_bounces=12, **settings)
    return img[..., :3].astype(np.float64), time.perf_counter() - t


def main():
    args = parse_args("smaller references and budgets (smoke run)")
    ref_spp, times = (REF_SPP, TIMES) if not args.quick else (256, (0.5, 1.0))
    repeats = repeats_for if not args.quick else (lambda budget: 1)
    load_addon()
    from variance_per_sample import per_sample_variance  # imports this module: not at the top
    var_seeds, var_spp = (VAR_SEEDS, VAR_SPP) if not args.quick else (4, 4)
    results = {}
    for name, (fixture, setup) in SCENES.items():
        sps = {}
        for e in ENGINES:  # wall time of a fixed-sample render minus a 1-sample one (sync)
            _, t1 = render(fixture, setup, e, samples=1)
            _, t65 = render(fixture, setup, e, samples=65)
            sps[e] = 64.0 / max(t65 - t1, 1e-6)
        m = measure(lambda e, **kw: render(fixture, setup, e, **kw), times, repeats, ref_spp, 12345)
        refs, errors = m["refs"], m["errors"]
        var = per_sample_variance(fixture, setup, var_seeds, var_spp, cache=False)
        target = errors["CYCLES"][-1]  # the error Cycles reaches with the longest budget
        tt = {e: time_to(errors[e], times, target) for e in ENGINES}
        results[name] = dict(sps=sps, errors=errors, raw=m["raw"], floor=m["floor"], target=target, time_to=tt,
                             var=var, pooled=m["pooled"],
                             mean_ratio=float(refs["PATHLIGHT"].mean() / refs["CYCLES"].mean()))
        print(name, results[name], flush=True)

    out = section_dir(args)
    plot = "equal_time.png" if plot_errors(results, times, out / "equal_time.png") else None

    lines = [
        "## Equal-time error against Cycles (CPU)",
        "",
        f"Fixtures at {SCALE} % (128x128), both engines in this process, all threads, no denoising, no",
        "clamping, no adaptive sampling, max bounces 12 (all types), 1-pixel box filter. Render time",
        "excludes scene export/sync. 'Lower error' is Cycles' relative MSE over Pathlight's at the same",
        "time (the mean of " + " / ".join(f"{repeats(t)}" for t in times) + " renders at those budgets, with "
        "different seeds, less the reference's own error, the floor",
        "below); 'all budgets pooled' is the same ratio estimated from every render at once (error x time,",
        "each budget's mean weighted alike; ± one standard error from the renders' spread), the most",
        "precise single figure; 'time to target' is the time each needs for the error Cycles reaches at the longest budget.",
        f"'Variance/sample' is Pathlight's relative variance of one sample over Cycles' ({var_seeds} seeds x "
        f"{var_spp} spp each; independent of the machine's load, unlike the timings).",
        "",
        "| Scene | samples/s Pathlight | samples/s Cycles | lower error at " + " / ".join(f"{t:g} s" for t in times)
        + " | all budgets pooled | time to target Pathlight / Cycles | variance/sample Pathlight / Cycles | mean ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        ratios = " / ".join(f"{c / p:.2f}x" for p, c in zip(r["errors"]["PATHLIGHT"], r["errors"]["CYCLES"]))
        lines.append(f"| {name} | {r['sps']['PATHLIGHT']:.0f} | {r['sps']['CYCLES']:.0f} | {ratios} | "
                     f"{r['pooled'][0]:.2f}x ± {r['pooled'][1]:.2f} | "
                     f"{r['time_to']['PATHLIGHT']:.2f} s / {r['time_to']['CYCLES']:.2f} s | "
                     f"{r['var'][0] / r['var'][1]:.2f}x | {r['mean_ratio']:.4f} |")
    lines += ["", "Relative MSE against the reference per budget (Pathlight / Cycles, before the floor is "
              "subtracted), the floor, and the ratio without the subtraction:", ""]
    for name, r in results.items():
        vals = ", ".join(f"{t:g} s: {p:.2e} / {c:.2e} ({c / p:.2f}x)" for t, p, c in
                         zip(times, r["raw"]["PATHLIGHT"], r["raw"]["CYCLES"]))
        lines.append(f"- {name}: {vals}; floor {r['floor']:.1e}; relative variance of one sample "
                     f"{r['var'][0]:.3g} / {r['var'][1]:.3g}")
    lines += ["", f"References: {ref_spp} spp of each engine. The mean ratio is Pathlight's reference image "
              "mean over Cycles' (bias between the engines shows there).", ""]
    if plot:
        lines += [f"![relative MSE against render time]({plot})", ""]
    (out / "cornell.md").unlink(missing_ok=True)  # replaced by this section
    (out / "cornell_rmse.png").unlink(missing_ok=True)
    write_section(out, "equal_time", lines)


if __name__ == "__main__":
    main()
