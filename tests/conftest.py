"""Shared pytest setup: the repository root on sys.path, so tests import the add-on as `addon`
(as build.py does). Blender-specific helpers live in blender_util.py, imported only by the
tests that use bpy."""

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
