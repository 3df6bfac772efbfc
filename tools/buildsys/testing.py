"""`test`: pytest under .venv's Python (`build.py _pytest`), and `build.py _run`, which runs a
benchmark script the same way."""

import os
import sys

from .common import ROOT, VENV_PY, UserError, hard_exit
from .compile import runtime_env, setup_and_build


def cmd_test(args, extra):
    setup_and_build(args)
    if not (ROOT / "tests").is_dir():
        raise UserError("tests/ does not exist")
    # Test paths among the arguments (`build.py test -- tests/core/test_bsdf.py`) replace the whole
    # suite; options alone (`-k furnace`) select from all of tests/.
    paths = [a for a in extra if not a.startswith("-") and (ROOT / a.split("::")[0]).exists()]
    pytest_args = [] if paths else ["tests"]
    if args.sanitize:
        # A sanitizer report goes to fd 2 and then the process dies: with pytest's default fd capture
        # the report would vanish with it. Capture only Python-level output (later options override).
        pytest_args.append("--capture=sys")
    if not paths and not any(a in ("-n", "--numprocesses", "--dist") or a.startswith(("-n", "--numprocesses=", "--dist="))
                             or a == "no:xdist" for a in extra):
        pytest_args += xdist_args()
    if args.record_durations:
        pytest_args.append("--record-durations")
    pytest_args += extra
    argv = [str(VENV_PY), str(ROOT / "build.py"), "_pytest", *pytest_args]
    print("+ pytest " + " ".join(pytest_args), flush=True)
    sys.stderr.flush()
    os.chdir(ROOT)
    # tests/conftest.py reads the flavour to pick its file times (tests/durations.json).
    env = runtime_env(args, {"PATHLIGHT_BUILD": "sanitize" if args.sanitize else "release"})
    os.execve(str(VENV_PY), argv, env)  # pytest's exit code becomes ours


def xdist_args():
    """pytest-xdist for the whole suite: a worker per core (at most 4, each loads bpy). The core's
    tests are mostly one thread of Python and numpy, the Blender ones render on every core, so two
    workers on two cores take about half the core tests' time and cost the renders little. Whole
    files go to one worker (`loadfile`): module fixtures render their references once."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    workers = min(cores, 4)
    return ["-n", str(workers), "--dist", "loadfile"] if workers > 1 else []


def internal_pytest(argv):
    """`build.py _pytest ARGS`: pytest under .venv's Python, ended with a hard exit (see hard_exit)."""
    import pytest
    sys.path.insert(0, str(ROOT))  # what `python -m pytest` run from the root would do
    code = pytest.main(argv)
    hard_exit(int(code))


def internal_run_script(argv):
    """`build.py _run SCRIPT ARGS`: run a script as `python SCRIPT ARGS` would, ended with a hard exit."""
    import runpy
    script = argv[0]
    sys.argv = list(argv)
    sys.path[0] = os.path.dirname(os.path.abspath(script))
    code = 0
    try:
        runpy.run_path(script, run_name="__main__")
    except SystemExit as exc:
        if isinstance(exc.code, int) or exc.code is None:
            code = exc.code or 0
        else:
            print(exc.code, file=sys.stderr)
            code = 1
    except BaseException:
        import traceback
        traceback.print_exc()
        code = 1
    hard_exit(code)
