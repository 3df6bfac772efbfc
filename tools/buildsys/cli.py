"""The command line: parse_args, the dispatch of the public commands and of the internal ones
that run under .venv's Python, and `clean`."""

import argparse
import shutil
import sys

from .bench import cmd_bench
from .common import ADDON, BUILD, COMMANDS, DIST, SIMD_LEVELS, VENV, Lock, UserError, log, rel
from .compile import setup_and_build
from .merge import cmd_merge, internal_merge
from .package import cmd_package, internal_check_zip
from .render import cmd_render, internal_render
from .setup import ensure_setup
from .testing import cmd_test, internal_pytest, internal_run_script


def cmd_clean(args):
    targets = [BUILD, DIST] + ([VENV] if args.all else [])
    for path in targets:
        if path.exists():
            shutil.rmtree(path)
            log(f"removed {rel(path)}/")
    if args.all:
        for so in ADDON.glob("pathlight_core*.so"):
            so.unlink()
            log(f"removed {rel(so)}")
    return 0



def parse_args(argv):
    build_opts = argparse.ArgumentParser(add_help=False)
    g = build_opts.add_argument_group("build options (every command builds what is out of date first)")
    g.add_argument("--simd", choices=SIMD_LEVELS, help="SIMD level to compile the core for "
                   "(default: the best this CPU has, from /proc/cpuinfo, avx2 at most: avx512 only "
                   "when asked)")
    g.add_argument("--portable", action="store_true", help="build for any x86-64 CPU (same as --simd generic)")
    g.add_argument("--sanitize", "--debug", dest="sanitize", action="store_true",
                   help="use a RelWithDebInfo build with AddressSanitizer and UBSan, in build/sanitize")
    g.add_argument("-j", "--jobs", type=int, metavar="N", help="parallel compile jobs (default: all cores)")
    g.add_argument("--core-dir", help=argparse.SUPPRESS)  # build another CMake project (testing build.py)

    parser = argparse.ArgumentParser(
        prog="build.py", description="Set up, build, render, test, benchmark and package Pathlight.",
        epilog="Run `python3 build.py COMMAND --help` for a command's options.")
    sub = parser.add_subparsers(dest="command", metavar="{" + ",".join(COMMANDS) + "}")

    sub.add_parser("setup", help="create .venv (Python 3.11) and install requirements.txt",
                   description="Create .venv with Python 3.11 and install the pinned packages; "
                               "does nothing when requirements.txt has not changed.")
    sub.add_parser("build", parents=[build_opts], help="build the C++ core and copy it into addon/",
                   description="Configure and build the core with CMake into build/release "
                               "(build/sanitize with --sanitize) and copy the module into addon/.")

    p = sub.add_parser("render", parents=[build_opts], help="render a .blend with Pathlight, like blender -b",
                       description="Render a .blend's camera at its resolution with the Pathlight engine, "
                                   "like `blender -b SCENE -E PATHLIGHT -o OUT -f 1`.")
    p.add_argument("scene", help="the .blend file to render, or an .obj (+.mtl) to import with "
                                 "Blender's importer, framed by a camera and lit by a grey world")
    p.add_argument("-o", "--output", required=True, help="image to write (.png or .exr)")
    p.add_argument("--samples", type=int, help="samples per pixel (default: the scene's)")
    p.add_argument("--time-limit", type=float, metavar="S", help="stop after S seconds (0: no limit)")
    p.add_argument("--threads", type=int, metavar="N", help="render threads (default: the scene's setting)")
    p.add_argument("--seed", type=int, help="random seed (default: the scene's)")
    p.add_argument("--format", type=str.upper, choices=("PNG", "EXR"),
                   help="PNG (8-bit, view transform applied) or EXR (32-bit float linear, ZIP); "
                        "default: from the file name")
    p.add_argument("--frame", type=int, default=1, help="frame to render (default: 1)")
    p.add_argument("--frames", metavar="FIRST-LAST",
                   help="render a range of frames (e.g. 1-3) into numbered files: '#'s in the "
                        "output name become the frame number (out_####.png), else _#### is "
                        "added before the extension")
    p.add_argument("--frame-start", type=int, metavar="F", help="first frame of a range")
    p.add_argument("--frame-end", type=int, metavar="F", help="last frame of a range")
    p.add_argument("--sample-offset", type=int, metavar="N",
                   help="render sample indices N .. N+samples-1 (farm splitting: partial renders "
                        "with consecutive offsets merge with `build.py merge`; docs/farm.md)")
    p.add_argument("--frame-samples", type=int, metavar="N",
                   help="the frame's total samples when it is rendered in pieces with "
                        "--sample-offset, so that blue-noise pieces merge into one render (docs/farm.md)")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="keep Blender's own status line for every update")

    p = sub.add_parser("merge", help="merge partial EXR renders of one frame (farm splitting)",
                       description="Merge EXR renders of the same frame with different sample "
                                   "ranges (render --sample-offset) into one, weighting each by "
                                   "its sample count (per pixel when the files have a Sample "
                                   "Count pass, else from the Pathlight Samples metadata).")
    p.add_argument("inputs", nargs="+", help="partial renders (.exr)")
    p.add_argument("-o", "--output", required=True, help="merged image to write (.exr)")
    p.add_argument("--denoise", action="store_true",
                   help="denoise the merged Combined with Open Image Denoise (Blender's, beside the "
                        "installed bpy), guided by Denoising Albedo / Normal where the files have them")

    p = sub.add_parser("test", parents=[build_opts], help="run the test suite (pytest arguments after --)",
                       description="Run `pytest tests` in .venv; arguments after -- go to pytest, "
                                   "e.g. python3 build.py test -- -k furnace -x")
    p.add_argument("--refs", choices=("use", "render", "check", "refresh", "prune"),
                   help="the stored Cycles references (tests/cycles_refs/): use them (the default), "
                        "render without them, check them against fresh renders, refresh (re-render and "
                        "overwrite) them, or prune: run the whole suite, then delete the ones it did not use")
    p.add_argument("--record-durations", action="store_true",
                   help="write each test file's time into tests/durations.json (under release or "
                        "sanitize), which orders the files longest first under xdist")

    p = sub.add_parser("bench", parents=[build_opts], help="run the benchmarks into docs/benchmarks.md",
                       description="Run every tests/bench/bench_*.py and assemble docs/benchmarks.md; "
                                   "arguments after -- go to every script, e.g. python3 build.py bench -- --quick")
    p.add_argument("--only", action="append", metavar="TEXT",
                   help="run only the scripts whose name contains TEXT (repeatable)")

    sub.add_parser("package", parents=[build_opts], help="make dist/pathlight-VERSION.zip (a Blender extension)",
                   description="Build and zip addon/ into an extension installable in Blender 4.2+.")

    p = sub.add_parser("clean", help="remove build/ and dist/",
                       description="Remove build/ and dist/; with --all also .venv and the module in addon/.")
    p.add_argument("--all", action="store_true", help="also remove .venv and addon/pathlight_core*.so")

    # Everything after `--` belongs to pytest.
    extra = []
    if "--" in argv:
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1:]
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        parser.exit(2)
    if extra and args.command not in ("test", "bench"):
        parser.error(f"only `test` and `bench` take arguments after --, not `{args.command}`")
    if getattr(args, "jobs", None) is not None and args.jobs < 1:
        parser.error("--jobs must be at least 1")
    return args, extra


# Internal commands: what runs under .venv's Python on behalf of the public ones.
INTERNAL = {"_render": internal_render, "_merge": internal_merge, "_pytest": internal_pytest, "_run": internal_run_script,
            "_check_zip": internal_check_zip}


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] in INTERNAL:
        return INTERNAL[argv[0]](argv[1:])
    args, extra = parse_args(argv)
    try:
        if args.command == "setup":
            with Lock():
                ensure_setup()
            log(f"{rel(VENV)} is ready")
            return 0
        if args.command == "build":
            setup_and_build(args)
            return 0
        if args.command == "render":
            return cmd_render(args)
        if args.command == "merge":
            return cmd_merge(args)
        if args.command == "test":
            return cmd_test(args, extra)
        if args.command == "bench":
            return cmd_bench(args, extra)
        if args.command == "package":
            return cmd_package(args)
        if args.command == "clean":
            return cmd_clean(args)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return 130
    raise AssertionError(args.command)
