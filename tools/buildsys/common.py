"""What every command shares: the repository's paths, messages, running a step, JSON files,
the setup/build lock and the hard exit of the processes that load bpy."""

import json
import os
import subprocess
import sys
from pathlib import Path

try:
    import fcntl
except ImportError:  # not on Linux/macOS; locking is only a courtesy
    fcntl = None

# The repository root: this file is tools/buildsys/common.py.
ROOT = Path(__file__).resolve().parents[2]
VENV = ROOT / ".venv"
VENV_PY = VENV / "bin" / "python"
SETUP_STAMP = VENV / ".pathlight-setup.json"
REQUIREMENTS = ROOT / "requirements.txt"
ADDON = ROOT / "addon"
MANIFEST = ADDON / "blender_manifest.toml"
CORE = ROOT / "core"
BUILD = ROOT / "build"
DIST = ROOT / "dist"
DOCS = ROOT / "docs"
BENCH_SCRIPTS = ROOT / "tests" / "bench"
BENCH_SECTIONS = DOCS / "bench"

PYTHON_NEEDED = (3, 11)  # the bpy 4.5 wheels are CPython 3.11 only
SIMD_LEVELS = ("avx512", "avx2", "sse4.2", "generic")  # avx512: opt-in only, never detected
COMMANDS = ("setup", "build", "render", "merge", "test", "bench", "package", "clean")


class UserError(Exception):
    """Something the user can fix: reported as one message, no traceback."""


def log(msg):
    print(f"[build.py] {msg}", flush=True)


def warn(msg):
    print(f"[build.py] warning: {msg}", file=sys.stderr, flush=True)


def rel(path):
    try:
        return str(Path(path).relative_to(ROOT))
    except ValueError:
        return str(path)


def run(cmd, what, **kwargs):
    """Run a command, echoing it; a failure becomes a UserError naming the step."""
    cmd = [str(c) for c in cmd]
    print("+ " + " ".join(cmd), flush=True)
    try:
        proc = subprocess.run(cmd, **kwargs)
    except FileNotFoundError:
        raise UserError(f"{what} failed: {cmd[0]} not found")
    if proc.returncode != 0:
        raise UserError(f"{what} failed (exit code {proc.returncode}); see the output above")
    return proc


def jobs_default():
    # The affinity mask, not os.cpu_count(): containers and CI often get fewer cores than the host has.
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return os.cpu_count() or 1


def read_json(path):
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def write_json(path, data):
    tmp = Path(str(path) + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)


class Lock:
    """Serialises setup+build between concurrent build.py runs (two pip installs into one venv corrupt it)."""

    def __enter__(self):
        self.fd = None
        if fcntl is not None:
            BUILD.mkdir(exist_ok=True)
            self.fd = open(BUILD / ".lock", "w")
            try:
                fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                log("another build.py is setting up or building; waiting for it")
                fcntl.flock(self.fd, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        if self.fd is not None:
            self.fd.close()


def flush_all():
    """Flush Python's and C's stdio buffers: Blender prints through C's, which os._exit would drop."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass
    try:
        import ctypes
        ctypes.CDLL(None).fflush(None)
    except Exception:
        pass


def hard_exit(code):
    """End a process that loaded bpy without interpreter teardown: bpy 4.5 hangs for ever in exit()
    while a RenderEngine subclass is still registered, and a crashed or failed run may not have
    unregistered it."""
    flush_all()
    os._exit(code)


def run_internal(body):
    """Runs body() for an internal command under .venv's Python: a UserError is one line on
    stderr, anything else a traceback; then a hard exit (see hard_exit)."""
    code = 0
    try:
        body()
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = 1
    except BaseException:
        import traceback
        traceback.print_exc()
        code = 1
    hard_exit(code)
