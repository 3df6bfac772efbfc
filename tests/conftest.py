"""Shared pytest setup: the repository root on sys.path, so tests import the add-on as `addon`
(as build.py does). Blender-specific helpers live in blender_util.py, imported only by the
tests that use bpy. Under pytest-xdist the test files are handed out longest first, from the
per-file times in tests/durations.json (`build.py test --record-durations` refreshes them)."""

import json
import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
# Each folder's shared helpers (core_scenes, bsdf_stats; blender_util, material_scenes,
# light_scenes) import by name from either folder and from tests/bench.
HELPERS = [str(REPO / "tests" / d) for d in ("core", "blender")]
sys.path[1:1] = [h for h in HELPERS if h not in sys.path]

DURATIONS = REPO / "tests" / "durations.json"
_recorded = None  # file -> seconds, while --record-durations records (controller process only)


def build_flavour():
    """Which core build the tests run against: build.py sets PATHLIGHT_BUILD (release or sanitize)."""
    return os.environ.get("PATHLIGHT_BUILD", "release")


def pytest_addoption(parser):
    parser.addoption("--record-durations", action="store_true",
                     help="write each file's time (setup + call + teardown of its tests, one worker) "
                          "into tests/durations.json under this build's flavour")


def pytest_configure(config):
    global _recorded
    config.addinivalue_line(
        "markers",
        "converged: a long convergence render (millions of samples: two estimators at low noise, or an "
        "estimator against a closed form); the "
        "sanitizer step of .ci/run deselects it (5x slower there), and cheaper tests run the same "
        "code paths under the sanitizer")
    config.addinivalue_line(
        "markers",
        "sanitize: a test of the core module that .ci/run also runs against the AddressSanitizer "
        "and UBSan build (`build.py test --sanitize -- -m \"sanitize and not converged\"`); set "
        "per file with `pytestmark`: the core's own tests, not the Blender-side ones")
    config.addinivalue_line(
        "markers",
        "release_only: a long statistical test in a `sanitize` file whose lines of core/ the rest of "
        "the sanitizer step already runs (measured with gcov, docs/building.md \"CI time\"); the "
        "sanitizer step deselects it, the release step runs it")
    # pytest-xdist's default (--loadscope-reorder) hands out files by their number of tests, which
    # would undo the longest-first order of pytest_collection_modifyitems below.
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False
    if config.getoption("record_durations") and not hasattr(config, "workerinput"):
        _recorded = {}


def read_durations():
    try:
        return json.loads(DURATIONS.read_text()).get(build_flavour(), {})
    except (OSError, ValueError):
        return {}


RELEASE_ONLY = REPO / "tests" / "sanitizer_release_only.json"


def mark_release_only(items):
    """Marks `release_only` the tests of tests/sanitizer_release_only.json: the slow ones whose
    lines of core/ the rest of the sanitizer step already covers (chosen with gcov,
    docs/building.md "CI time")."""
    try:
        names = set(json.loads(RELEASE_ONLY.read_text()))
    except (OSError, ValueError):
        return
    import pytest
    for item in items:
        if item.nodeid in names:
            item.add_marker(pytest.mark.release_only)


def pytest_collection_modifyitems(session, config, items):
    """Under xdist (`--dist loadfile`), order whole files longest first, so that no long file starts
    last and leaves the other worker idle. Files without a recorded time go first (assume long),
    most tests first. Tests keep their order inside a file; a run without xdist is not reordered."""
    mark_release_only(items)
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return
    times = read_durations()
    files = {}
    for item in items:
        files.setdefault(item.nodeid.split("::")[0], []).append(item)

    def key(name):
        if name in times:
            return (1, -float(times[name]))
        return (0, -len(files[name]))

    items[:] = [item for name in sorted(files, key=key) for item in files[name]]


def pytest_runtest_logreport(report):
    # Under xdist the controller receives every worker's reports, with their durations.
    if _recorded is not None:
        name = report.nodeid.split("::")[0]
        _recorded[name] = _recorded.get(name, 0.0) + report.duration


def pytest_sessionfinish(session, exitstatus):
    times = _recorded
    if not times:
        return
    try:
        data = json.loads(DURATIONS.read_text())
    except (OSError, ValueError):
        data = {}
    table = data.setdefault(build_flavour(), {})
    table.update({name: round(t, 1) for name, t in times.items()})
    data[build_flavour()] = dict(sorted(table.items()))
    DURATIONS.write_text(json.dumps(data, indent=1) + "\n")
    print(f"\nrecorded the times of {len(times)} test files in {DURATIONS.relative_to(REPO)} "
          f"({build_flavour()})")


# The stored Cycles references (tests/blender/cycles_refs.py): each process that renders with
# Cycles appends "KEY hit|stored|checked CPU_S WALL_S TEST" lines to
# build/cycles_refs_used/<session>-<worker>-<pid>.txt; the summary counts this run's lines (the
# session id is set here and inherited by xdist's workers), so that references missing from the
# repository show.
_REFS_USED = REPO / "build" / "cycles_refs_used"
# Tests use the store unless told otherwise; outside pytest (bench scripts) it is off.
os.environ.setdefault("PATHLIGHT_CYCLES_REFS", "use")


def pytest_sessionstart(session):
    import os
    import time
    if not hasattr(session.config, "workerinput"):
        os.environ["PATHLIGHT_REFS_SESSION"] = f"{int(time.time())}-{os.getpid()}"


def pytest_terminal_summary(terminalreporter):
    import os
    sid = os.environ.get("PATHLIGHT_REFS_SESSION")
    if not sid or not _REFS_USED.is_dir() or hasattr(terminalreporter.config, "workerinput"):
        return
    counts, stored = {}, []
    for f in _REFS_USED.glob(f"{sid}-*.txt"):
        for line in f.read_text().splitlines():
            parts = line.split(" ", 4)  # KEY hit|stored|checked CPU_S WALL_S TEST
            if len(parts) >= 4:
                n, cpu = counts.get(parts[1], (0, 0.0))
                counts[parts[1]] = (n + 1, cpu + float(parts[2]))
                if parts[1] == "stored":
                    stored.append(parts[4] if len(parts) > 4 else "?")
    if counts:
        terminalreporter.write_line(
            "Cycles references: " + ", ".join(f"{n} {k} ({cpu:.1f} CPU s)" for k, (n, cpu) in sorted(counts.items()))
            + (" (new files in tests/cycles_refs/: commit them)" if stored else ""))
        for test in sorted(set(stored))[:20]:
            terminalreporter.write_line(f"  stored for {test}")
