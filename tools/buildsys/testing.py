"""`test`: pytest under .venv's Python (`build.py _pytest`), and `build.py _run`, which runs a
benchmark script the same way."""

import os
import shutil
import subprocess
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
    refs = getattr(args, "refs", None)
    # tests/conftest.py reads the flavour to pick its file times (tests/durations.json).
    extra_env = {"PATHLIGHT_BUILD": "sanitize" if args.sanitize else "release"}
    if refs:
        extra_env["PATHLIGHT_CYCLES_REFS"] = "use" if refs == "prune" else refs
    env = runtime_env(args, extra_env)
    if refs == "prune":
        return prune_refs(argv, paths, extra, env)
    print("+ pytest " + " ".join(pytest_args), flush=True)
    sys.stderr.flush()
    os.chdir(ROOT)
    os.execve(str(VENV_PY), argv, env)  # pytest's exit code becomes ours


REFS = ROOT / "tests" / "cycles_refs"
REFS_USED = ROOT / "build" / "cycles_refs_used"  # tests/blender/cycles_refs.py records keys there


def prune_refs(argv, paths, extra, env):
    """`test --refs prune`: the whole suite, then delete the stored Cycles references no test used.
    Only after a full, passing run: a partial one would delete references that others need."""
    selecting = [a for a in extra if a.startswith(("-k", "-m", "--deselect", "-x", "--exitfirst", "--lf",
                                                   "--last-failed", "--ff", "--sw", "--stepwise", "--maxfail"))]
    if paths or selecting:
        raise UserError("--refs prune needs the whole suite: no test paths, -k, -m, -x or the like")
    shutil.rmtree(REFS_USED, ignore_errors=True)
    print("+ pytest " + " ".join(argv[3:]), flush=True)
    code = subprocess.call(argv, cwd=ROOT, env=env)
    if code != 0:
        print(f"pytest failed (exit code {code}): no reference pruned", file=sys.stderr, flush=True)
        return code
    used, stale = prune_unused(REFS, REFS_USED)
    print(f"Cycles references: {len(used)} used, {len(stale)} unused removed from {REFS.relative_to(ROOT)}/",
          flush=True)
    return 0


def prune_unused(refs, used_dir):
    """Delete the files of `refs` (KEY.plref, KEY.exr, leftover temporaries) whose key no record
    in `used_dir` names; returns (the keys used, the files removed)."""
    used = set()
    for f in used_dir.glob("*.txt"):
        used.update(line.split()[0] for line in f.read_text().splitlines() if line.strip())
    stale = [f for f in sorted(refs.iterdir()) if f.is_file() and f.name.split(".")[0] not in used] \
        if refs.is_dir() else []
    for f in stale:
        f.unlink()
    return used, stale


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
