"""`setup`: .venv with Python 3.11 and the pinned packages, redone only when requirements.txt
or the Python changes (a hash stamped in .venv)."""

import hashlib
import json
import os
import platform
import re
import shutil
import subprocess
import sys
from pathlib import Path

from .common import (PYTHON_NEEDED, REQUIREMENTS, SETUP_STAMP, VENV, VENV_PY, UserError, log, read_json, rel,
                     run, write_json)


def python_version_of(exe):
    try:
        proc = subprocess.run([exe, "-c", "import sys; print('%d.%d.%d' % sys.version_info[:3])"],
                              capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if proc.returncode != 0:  # e.g. a pyenv shim for a version that is not installed
        return None
    try:
        return tuple(int(x) for x in proc.stdout.strip().split("."))
    except ValueError:
        return None


def find_python311():
    if sys.version_info[:2] == PYTHON_NEEDED:
        return sys.executable
    exe = shutil.which("python3.11")
    if exe:
        version = python_version_of(exe)
        if version and version[:2] == PYTHON_NEEDED:
            return exe
    raise UserError(
        "Pathlight needs Python 3.11 for its .venv (Blender's bpy 4.5 wheels exist for CPython 3.11 only), "
        f"but this is Python {platform.python_version()} and no working python3.11 is on PATH.\n"
        "Install Python 3.11 (e.g. `pyenv install 3.11` or your distribution's python3.11 and python3.11-venv) "
        "and run again, or run this script with it: python3.11 build.py setup")


def venv_python_version():
    """The venv's Python version from pyvenv.cfg: reading a file is much faster than starting Python."""
    try:
        text = (VENV / "pyvenv.cfg").read_text()
    except OSError:
        return None
    m = re.search(r"^version(?:_info)?\s*=\s*(\d+)\.(\d+)\.(\d+)", text, re.M)
    return tuple(int(x) for x in m.groups()) if m else None


def setup_hash(py_version):
    h = hashlib.sha256()
    h.update(REQUIREMENTS.read_bytes())
    h.update(("python %d.%d.%d %s" % (*py_version, platform.machine())).encode())
    return h.hexdigest()


def ensure_setup():
    """Make .venv exist with Python 3.11 and the pinned packages; skip pip when the stamp matches.

    Returns the stamp (a dict with the pybind11 CMake dir and the bpy version)."""
    if not REQUIREMENTS.is_file():
        raise UserError(f"{rel(REQUIREMENTS)} is missing")
    version = venv_python_version()
    # os.path.exists follows the symlink, so a venv whose base Python was removed counts as broken.
    if not (VENV_PY.exists() and version and version[:2] == PYTHON_NEEDED):
        if VENV.exists():
            log(f"{rel(VENV)} is broken or not Python 3.11; recreating it")
            shutil.rmtree(VENV)
        base = find_python311()
        log(f"creating {rel(VENV)} with {base}")
        run([base, "-m", "venv", VENV], "creating the virtual environment")
        version = venv_python_version()
        if not version:
            raise UserError(f"created {rel(VENV)} but cannot read its pyvenv.cfg")

    digest = setup_hash(version)
    stamp = read_json(SETUP_STAMP) or {}
    if stamp.get("hash") == digest and Path(stamp.get("pybind11_cmakedir", "")).is_dir():
        return stamp

    log("installing the pinned Python packages (the first time downloads bpy, ~370 MB)")
    env = dict(os.environ, PIP_DISABLE_PIP_VERSION_CHECK="1")
    run([VENV_PY, "-m", "pip", "install", "--no-input", "-r", REQUIREMENTS],
        "pip install -r requirements.txt", env=env)
    probe = subprocess.run(
        [VENV_PY, "-c", "import json, bpy, numpy, pybind11, pytest; "
                        "print(json.dumps({'pybind11_cmakedir': pybind11.get_cmake_dir(), "
                        "'bpy': bpy.app.version_string, 'numpy': numpy.__version__}))"],
        capture_output=True, text=True)
    if probe.returncode != 0:
        raise UserError("the packages installed but do not import:\n" + probe.stderr.strip())
    info = json.loads(probe.stdout.strip().splitlines()[-1])
    stamp = dict(info, hash=digest, python="%d.%d.%d" % version)
    write_json(SETUP_STAMP, stamp)
    log(f"set up {rel(VENV)}: Python {stamp['python']}, bpy {stamp['bpy']}, numpy {stamp['numpy']}")
    return stamp
