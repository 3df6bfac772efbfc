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
