"""Equal-time error against Cycles (CPU) on realistic scenes (issue 25), side by side in one
process: a room lit through a window, a room lit by 50 lamps and 3 spots, a textured model
under an HDRI and 1.3 M instanced triangles (tests/bench/realistic_scenes.py builds them).
Writes docs/bench/realistic.md and a plot of error against time.

The method is bench_equal_time.py's: a reference from both engines' high-sample renders (their
mutual error / 4, the floor, subtracted), renders at each budget with different seeds, the
engines alternating, Cycles with its defaults (light tree, no denoising, no clamping, no adaptive
sampling), equal bounce limits, 1-pixel box filters. Beside it, the converged agreement (the
references' mean ratio and worst 8x8 region, each engine's own seed noise next to it: own_noise), on the lamp room Pathlight's per-sample variance
with its light tree against its power-proportional light choice, and on the window-lit room
Pathlight's equal-time error with path guiding against without (issue 25's guiding figure)."""
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
from benchutil import parse_args, section_dir, write_section  # noqa: E402
from equal_time import ENGINES, measure, plot_errors, pooled_ratio, rel_mse, repeats_for  # noqa: E402
import material_scenes as ms  # noqa: E402
import realistic_scenes  # noqa: E402

TIMES = (1.0, 2.0, 4.0, 8.0)
REF_SPP = 1024
MAX_BOUNCES = 12
TREE_SEEDS, TREE_SPP = 8, 8
CAUSTICS_OFF = dict(use_caustic_light_paths=False, caustic_light_paths_auto=False)  # explicit off


def render(build, engine, **settings):
    scene = build()
    if engine == "CYCLES":
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 1.0
    t = time.perf_counter()
    img = render_to_array(scene, engine, max_bounces=MAX_BOUNCES, **settings)
    return img[..., :3].astype(np.float64), time.perf_counter() - t


def own_noise(halves, refs, floor=0.02):
    """Each engine's own seed-to-seed noise in the converged comparison's terms, from the two
    half-sample renders its reference averages: per engine the worst 8x8 region between two
    references of its own at the full sample count (the halves' difference / sqrt 2: a half's
    variance is twice the reference's), relative as ms.compare; and 'z', the rms of the two
    engines' region differences over the rms those halves predict for them (about 1 where the
    references differ by their noise alone, well above where they disagree)."""
    denom = np.maximum(ms.region_means(refs["CYCLES"], 8).mean(-1), floor)
    half_diff = {e: (ms.region_means(a, 8) - ms.region_means(b, 8)).mean(-1) / denom for e, (a, b) in halves.items()}
    worst = {e: float(np.abs(d).max() / np.sqrt(2.0)) for e, d in half_diff.items()}
    diff = (ms.region_means(refs["PATHLIGHT"], 8) - ms.region_means(refs["CYCLES"], 8)).mean(-1) / denom
    # Var(P - C) = var_P + var_C at the full count; a half's difference has 4x a reference's variance.
    predicted = sum(np.mean(d ** 2) for d in half_diff.values()) / 4.0
    return worst, float(np.sqrt(np.mean(diff ** 2) / max(predicted, 1e-30)))


def measure_scene(build, times, repeats, ref_spp):
    """The equal-time measure of one scene and the converged agreement of its two references
    (mean_ratio, worst 8x8 region, each engine's own noise beside it: own_noise); returns
    (results, the references)."""
    r = measure(lambda e, **kw: render(build, e, **kw), times, repeats, ref_spp, 4242, halves=True)
    refs = r.pop("refs")
    ratio, worst, _ = ms.compare(refs["PATHLIGHT"], refs["CYCLES"])
    own, z = own_noise(r.pop("ref_halves"), refs)
    r.update(mean_ratio=float(ratio), worst=float(worst), own_worst=own, noise_z=z)
    return r, refs


def table_header(times):
    return ["| Scene | lower error at " + " / ".join(f"{t:g} s" for t in times) +
            " | pooled | converged mean / worst region | own seed noise: worst region Pathlight / Cycles; "
            "difference over noise |", "|---|---|---|---|---|"]


def table_rows(results):
    rows = []
    for name, r in results.items():
        ratios = " / ".join(f"{c / p:.2f}x" for p, c in zip(r["errors"]["PATHLIGHT"], r["errors"]["CYCLES"]))
        rows.append(f"| {name} | {ratios} | {r['pooled'][0]:.2f}x ± {r['pooled'][1]:.2f} | "
                    f"{r['mean_ratio']:.4f} / {100 * r['worst']:.1f} % | "
                    f"{100 * r['own_worst']['PATHLIGHT']:.1f} % / {100 * r['own_worst']['CYCLES']:.1f} %; "
                    f"{r['noise_z']:.2f} |")
    return rows


def raw_lines(results, times):
    lines = ["", "Relative MSE per budget (Pathlight / Cycles, before the floor is subtracted) and the floor:", ""]
    for name, r in results.items():
        vals = ", ".join(f"{t:g} s: {p:.2e} / {c:.2e}" for t, p, c in
                         zip(times, r["raw"]["PATHLIGHT"], r["raw"]["CYCLES"]))
        lines.append(f"- {name}: {vals}; floor {r['floor']:.1e}")
    return lines + [""]


def tree_variance(build, seeds, spp):
    """Pathlight's relative variance of one sample with the light tree (Auto) and without (Off)."""
    out = {}
    for mode in ("AUTO", "OFF"):
        imgs = np.stack([render(build, "PATHLIGHT", samples=spp, seed=100 + s, light_tree=mode)[0]
                         for s in range(seeds)])
        mean = imgs.mean(0)
        out[mode] = float(np.mean(imgs.var(0, ddof=1) * spp / (mean ** 2 + 1e-2)))
    return out


def option_gain(build, times, repeats, ref, floor, cycles_renders=None, off=None, **option):
    """Pathlight's equal-time error without a render option over with it, per budget and pooled
    (the equal-time method, the plain renders in Cycles' place), against the scene's reference;
    with cycles_renders (measure's per-budget errors of Cycles) also Cycles' error over
    Pathlight's with the option ('cycles'). off: the plain renders' settings (default: none)."""
    renders = {"PATHLIGHT": [], "CYCLES": []}  # with the option, plain
    for budget in times:
        per = {"PATHLIGHT": [], "CYCLES": []}
        for k in range(repeats(budget)):
            for key, on in (("PATHLIGHT", True), ("CYCLES", False)):
                img, _ = render(build, "PATHLIGHT", samples=1_000_000, time_limit=budget, seed=1 + k,
                                **(option if on else (off or {})))
                per[key].append(rel_mse(img, ref))
        for key in per:
            renders[key].append(per[key])
    out = dict(ratios=_ratios(renders, floor), pooled=pooled_ratio(renders, times, floor))
    if cycles_renders is not None:
        vs = {"PATHLIGHT": renders["PATHLIGHT"], "CYCLES": cycles_renders}
        out["cycles"] = dict(ratios=_ratios(vs, floor), pooled=pooled_ratio(vs, times, floor))
    return out


def _ratios(renders, floor):
    return [float(max(np.mean(c) - floor, 1e-3 * np.mean(c)) / max(np.mean(p) - floor, 1e-3 * np.mean(p)))
            for p, c in zip(renders["PATHLIGHT"], renders["CYCLES"])]


def _gain_line(what, name, gain, times, target):
    line = (f"{what} on '{name}': Pathlight's error at equal time without it over with it, "
            + " / ".join(f"{x:.2f}x" for x in gain["ratios"]) + " at " + " / ".join(f"{t:g} s" for t in times)
            + f", pooled {gain['pooled'][0]:.2f}x ± {gain['pooled'][1]:.2f}{target}.")
    if "cycles" in gain:
        c = gain["cycles"]
        line += (" With it, Cycles' error over Pathlight's: " + " / ".join(f"{x:.2f}x" for x in c["ratios"])
                 + f", pooled {c['pooled'][0]:.2f}x ± {c['pooled'][1]:.2f}.")
    return line


def main():
    args = parse_args("smaller references and budgets (smoke run)")
    ref_spp, times = (REF_SPP, TIMES) if not args.quick else (32, (0.25, 0.5))
    repeats = repeats_for if not args.quick else (lambda budget: 1)
    tree_seeds, tree_spp = (TREE_SEEDS, TREE_SPP) if not args.quick else (3, 2)
    load_addon()
    results = {}
    for name, build in realistic_scenes.SCENES.items():
        r, refs = measure_scene(build, times, repeats, ref_spp)
        if build is realistic_scenes.lamp_room:
            r["tree"] = tree_variance(build, tree_seeds, tree_spp)
        if build is realistic_scenes.window_room:
            ref = 0.5 * (refs["PATHLIGHT"] + refs["CYCLES"])
            r["guiding"] = option_gain(build, times, repeats, ref, r["floor"], use_guiding=True)
        if build is realistic_scenes.hdri_model:
            # Caustic light tracing, automatic by default (docs/design/sampling.md "Automatic caustic
            # light paths"): the default (on here) against explicit off
            ref = 0.5 * (refs["PATHLIGHT"] + refs["CYCLES"])
            r["caustics"] = option_gain(build, times, repeats, ref, r["floor"], off=CAUSTICS_OFF)
        results[name] = r
        print(name, r, flush=True)

    out = section_dir(args)
    plot = "realistic.png" if plot_errors(results, times, out / "realistic.png", width=4.0, title_size=9,
                                          legend_size=7) else None

    w, h = realistic_scenes.WIDTH, realistic_scenes.HEIGHT
    lines = [
        "## Equal-time error against Cycles on realistic scenes (CPU)",
        "",
        f"Scenes of `tests/bench/realistic_scenes.py` at {w}x{h}, both engines in this process, all threads, no",
        f"denoising, no clamping, no adaptive sampling, max bounces {MAX_BOUNCES} (all types), 1-pixel box filter,",
        "Cycles' light tree on. 'Lower error' is Cycles' relative MSE over Pathlight's at the same time (the",
        "mean of " + " / ".join(f"{repeats(t)}" for t in times) + " renders per budget, the references' own "
        "error subtracted, as in the equal-time section); 'pooled' estimates it from every render at once.",
        f"'Converged' compares the two {ref_spp}-spp references (each the mean of two {ref_spp // 2}-spp renders",
        "with different seeds): Pathlight's mean over Cycles', and the worst 8x8 region's relative difference",
        "(issue 25 asks for 1 % and 3 %). Beside it each engine's own seed noise: the worst region between two",
        f"{ref_spp}-spp references of that engine alone (from its two halves), and the rms of the region",
        "differences over the rms the halves predict for them (about 1: the references differ by their noise",
        "alone; well above 1: they disagree). Where the own noise is as large as the region figure, the 3 % bar",
        f"cannot be judged at {ref_spp} spp (tests/bench/window_room_converged.py renders more).",
        "",
        *table_header(times),
        *table_rows(results),
    ]
    for name, r in results.items():
        if "tree" in r:
            t = r["tree"]
            lines += ["", f"Light tree on '{name}': Pathlight's relative variance of one sample "
                      f"({tree_seeds} seeds x {tree_spp} spp) {t['AUTO']:.3g} with the tree, {t['OFF']:.3g} with "
                      f"lights chosen by power alone: {t['OFF'] / t['AUTO']:.2f}x lower with the tree."]
        if "guiding" in r:
            lines += ["", _gain_line("Path guiding", name, r["guiding"], times, " (issue 25 asks for 1.5x)")]
        if "caustics" in r:
            lines += ["", _gain_line("Caustic Light Paths (the default, automatic: on here at 0.1 per sample; "
                                     "without = explicit off)", name, r["caustics"], times, "")]
    lines += raw_lines(results, times)
    if plot:
        lines += [f"![relative MSE against render time on the realistic scenes]({plot})", ""]
    write_section(out, "realistic", lines)


if __name__ == "__main__":
    main()
