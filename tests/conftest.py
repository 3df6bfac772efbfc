"""Shared pytest setup: the repository root on sys.path, so tests import the add-on as `addon`
(as build.py does). Blender-specific helpers live in blender_util.py, imported only by the
tests that use bpy."""

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
# Each folder's shared helpers (core_scenes, bsdf_stats; blender_util, material_scenes,
# light_scenes) import by name from either folder and from tests/bench.
HELPERS = [str(REPO / "tests" / d) for d in ("core", "blender")]
sys.path[1:1] = [h for h in HELPERS if h not in sys.path]


def pytest_configure(config):
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


# The stored Cycles references (tests/blender/cycles_refs.py): each process that renders with
# Cycles appends "KEY hit|stored|checked CPU_S WALL_S TEST" lines to
# build/cycles_refs_used/<session>-<worker>-<pid>.txt; the summary counts this run's lines (the
# session id is set here and inherited by xdist's workers), so that references missing from the
# repository show.
_REFS_USED = REPO / "build" / "cycles_refs_used"


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
