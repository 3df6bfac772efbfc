"""Equal-time error against Cycles (CPU) on volume scenes (issue 23), side by side in one
process, by bench_realistic.py's method: a fog-filled Cornell box under a spot light and a smoke
grid read from a .vdb (tests/bench/volume_scenes.py builds them). Writes docs/bench/volumes.md
and a plot of error against time."""
import sys
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_realistic import MAX_BOUNCES, REF_SPP, TIMES, measure_scene, raw_lines, table_header, table_rows  # noqa: E402
from blender_util import load_addon  # noqa: E402
from benchutil import parse_args, section_dir, write_section  # noqa: E402
from equal_time import plot_errors, repeats_for  # noqa: E402
import volume_scenes  # noqa: E402


def main():
    args = parse_args("smaller references and budgets (smoke run)")
    ref_spp, times = (REF_SPP, TIMES) if not args.quick else (32, (0.25, 0.5))
    repeats = repeats_for if not args.quick else (lambda budget: 1)
    load_addon()
    results = {}
    for name, build in volume_scenes.scenes().items():
        r, _ = measure_scene(build, times, repeats, ref_spp)
        results[name] = r
        print(name, r, flush=True)

    out = section_dir(args)
    plot = "volumes.png" if plot_errors(results, times, out / "volumes.png", width=4.0, title_size=9,
                                        legend_size=7) else None
    w, h = volume_scenes.WIDTH, volume_scenes.HEIGHT
    lines = [
        "## Equal-time error against Cycles on volumes (CPU)",
        "",
        f"Scenes of `tests/bench/volume_scenes.py` at {w}x{h}, measured as the realistic scenes are (both",
        f"engines in this process, all threads, max bounces {MAX_BOUNCES} of every type, 1-pixel box filter,",
        "no denoising, clamping or adaptive sampling; Cycles' homogeneous-volume option on for the fog).",
        "'Lower error' is Cycles' relative MSE over Pathlight's at the same time (the mean of "
        + " / ".join(f"{repeats(t)}" for t in times) + " renders per budget, the",
        f"references' own error subtracted); 'converged' compares the two {ref_spp}-spp references (issue 23",
        "asks for means within 1 % and 8x8 regions within 3 %), each engine's own seed noise beside it as on",
        "the realistic scenes.",
        "",
        *table_header(times),
        *table_rows(results),
    ]
    lines += raw_lines(results, times)
    if plot:
        lines += [f"![relative MSE against render time on the volume scenes]({plot})", ""]
    write_section(out, "volumes", lines)


if __name__ == "__main__":
    main()
