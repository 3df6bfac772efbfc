#!/usr/bin/env python3
"""Pathlight's one entry point: set up, build, render, test, benchmark and package.

    python3 build.py render blender_scenes/cornell_box.blend -o out.png
    python3 build.py test [-- PYTEST ARGS]
    python3 build.py {setup,build,bench,package,clean} --help

Every command first does whatever setup and build is out of date, so a fresh
clone needs nothing else. This file runs under any python3 with the standard
library only; anything that needs bpy runs under .venv's Python 3.11. The code is the package
tools/buildsys/ (a module per command); this file puts tools/ on sys.path and calls its main.
"""

import sys
from pathlib import Path

# Second, not first: sys.path[0] stays this directory, which `build.py _run` replaces with its
# script's, as `python SCRIPT` would.
sys.path.insert(1, str(Path(__file__).resolve().parent / "tools"))

from buildsys.cli import main  # noqa: E402

# The names the tests reach through `import build`.
from buildsys.cli import parse_args  # noqa: E402
from buildsys.common import ROOT, UserError  # noqa: E402
from buildsys.merge import merge_exr  # noqa: E402
from buildsys.render import frame_range, numbered, render_options  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
