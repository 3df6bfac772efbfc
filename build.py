#!/usr/bin/env python3
"""Pathlight's one entry point: set up, build, render, test, benchmark and package.

    python3 build.py render blender_scenes/cornell_box.blend -o out.png
    python3 build.py test [-- PYTEST ARGS]
    python3 build.py {setup,build,bench,package,clean} --help

Every command first does whatever setup and build is out of date, so a fresh
clone needs nothing else. This file runs under any python3 with the standard
library only; anything that needs bpy runs under .venv's Python 3.11.
"""

import argparse
import filecmp
import hashlib
import json
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

try:
    import fcntl
except ImportError:  # not on Linux/macOS; locking is only a courtesy
    fcntl = None

ROOT = Path(__file__).resolve().parent
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
SIMD_LEVELS = ("avx2", "sse4.2", "generic")
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


# ---------------------------------------------------------------- setup

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


# ---------------------------------------------------------------- build

def detect_simd():
    """The best SIMD level this CPU runs, from the kernel's CPU flags."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "generic"
    for line in text.splitlines():
        if line.startswith("flags"):
            flags = set(line.partition(":")[2].split())
            break
    else:
        return "generic"  # no x86 flags line (e.g. ARM)
    if {"avx2", "fma", "bmi2"} <= flags:
        return "avx2"
    if "sse4_2" in flags:
        return "sse4.2"
    return "generic"


def simd_level(args):
    if args.portable:
        if args.simd and args.simd != "generic":
            raise UserError(f"--portable and --simd {args.simd} contradict each other")
        return "generic"
    return args.simd or detect_simd()


def build_dir(args):
    return BUILD / ("sanitize" if args.sanitize else "release")


def find_built_module(bdir):
    found = sorted(bdir.glob("pathlight_core*.so"))
    if not found:  # the core may set an output directory of its own
        found = [p for p in bdir.rglob("pathlight_core*.so") if "CMakeFiles" not in p.parts]
    if not found:
        raise UserError(f"the build finished but left no pathlight_core*.so under {rel(bdir)}")
    return max(found, key=lambda p: p.stat().st_mtime)


def install_module(so):
    """Copy the built module into addon/ when it differs from the one there."""
    ADDON.mkdir(exist_ok=True)
    dest = ADDON / so.name
    for stale in ADDON.glob("pathlight_core*.so"):
        if stale.name != so.name:
            stale.unlink()
    # copy2 keeps the mtime, so a shallow compare (size + mtime) is exact enough and reads nothing.
    if dest.exists() and filecmp.cmp(so, dest, shallow=True):
        return False
    tmp = ADDON / (so.name + ".tmp")
    shutil.copy2(so, tmp)
    # Replace rather than overwrite: a Blender that has the old module loaded keeps its inode intact.
    os.replace(tmp, dest)
    log(f"installed {rel(dest)}")
    return True


def ensure_build(args, stamp):
    core_dir = Path(args.core_dir).resolve() if args.core_dir else CORE
    if not (core_dir / "CMakeLists.txt").is_file():
        raise UserError(f"{rel(core_dir / 'CMakeLists.txt')} not found: the C++ core is not in this "
                        "checkout yet, so there is nothing to build")
    if not shutil.which("cmake"):
        raise UserError("cmake not found on PATH; install CMake (3.25 or newer) and a C++17 compiler")
    bdir = build_dir(args)
    generator = "Ninja" if shutil.which("ninja") else "Unix Makefiles"
    config = {
        "source": str(core_dir),
        "generator": generator,
        "defines": {
            "CMAKE_BUILD_TYPE": "RelWithDebInfo" if args.sanitize else "Release",
            "Python_EXECUTABLE": str(VENV_PY),
            # pybind11's classic FindPythonInterp mode (its default before CMake 3.27) ignores
            # Python_EXECUTABLE and may pick whatever python is on PATH; FindPython mode honours it.
            "PYBIND11_FINDPYTHON": "ON",
            "pybind11_DIR": stamp["pybind11_cmakedir"],
            "PATHLIGHT_SIMD": simd_level(args),
            "PATHLIGHT_SANITIZE": "ON" if args.sanitize else "OFF",
        },
    }
    config_file = bdir / "pathlight-configure.json"
    saved = read_json(config_file)
    if saved and (saved.get("source"), saved.get("generator")) != (config["source"], generator):
        # CMake refuses to reuse a build tree for another source dir or generator.
        log(f"{rel(bdir)} was configured for another source dir or generator; starting it afresh")
        shutil.rmtree(bdir)
        saved = None
    if saved != config or not (bdir / "CMakeCache.txt").is_file():
        bdir.mkdir(parents=True, exist_ok=True)
        if config_file.exists():
            config_file.unlink()  # so a failed configure is retried next time
        log(f"configuring {rel(core_dir)} into {rel(bdir)} (SIMD {config['defines']['PATHLIGHT_SIMD']}"
            + (", sanitizers" if args.sanitize else "") + ")")
        run(["cmake", "-S", core_dir, "-B", bdir, "-G", generator]
            + [f"-D{k}={v}" for k, v in config["defines"].items()], "configuring the core with CMake")
        write_json(config_file, config)
    jobs = args.jobs or jobs_default()
    run(["cmake", "--build", bdir, "--target", "pathlight_core", "-j", str(jobs)], "building the core")
    install_module(find_built_module(bdir))


def setup_and_build(args):
    with Lock():
        stamp = ensure_setup()
        ensure_build(args, stamp)
    return stamp


def runtime_env(args, extra=None):
    """Environment for processes that load the core; a sanitizer build needs its runtime preloaded."""
    env = dict(os.environ)
    env.update(extra or {})
    # numpy's OpenBLAS threads spin (sched_yield) after every product, taking cores from the
    # core's own threads; the tests' and benchmarks' arrays are too small to gain from them.
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    if args.sanitize:
        preload = sanitizer_runtime(build_dir(args))
        if preload:
            env["LD_PRELOAD"] = ":".join(preload + ([env["LD_PRELOAD"]] if env.get("LD_PRELOAD") else []))
        else:
            warn("could not find the AddressSanitizer runtime; loading the core will probably fail")
        # Python and bpy keep memory alive until exit by design: leak reports would be noise.
        env.setdefault("ASAN_OPTIONS", "detect_leaks=0")
        env.setdefault("UBSAN_OPTIONS", "print_stacktrace=1:halt_on_error=1")
    return env


def sanitizer_runtime(bdir):
    """Libraries to preload for the sanitizer build: the ASan runtime of the compiler that built the
    core (it must come before everything else in a Python that is not instrumented), then libstdc++:
    ASan wraps __cxa_throw only if libstdc++ is already loaded when it starts, and the first C++
    exception thrown otherwise aborts with "CHECK failed: real___cxa_throw"."""
    try:
        cache = (bdir / "CMakeCache.txt").read_text()
    except OSError:
        return None
    m = re.search(r"^CMAKE_CXX_COMPILER:\w+=(.+)$", cache, re.M)
    cxx = m.group(1).strip() if m else "c++"

    def find(name):
        try:
            out = subprocess.run([cxx, f"-print-file-name={name}"], capture_output=True, text=True).stdout.strip()
        except OSError:
            return None
        return os.path.realpath(out) if os.path.isabs(out) and os.path.exists(out) else None

    asan = find("libasan.so") or find("libclang_rt.asan-%s.so" % platform.machine())
    if not asan:
        return None
    return [asan] + [lib for lib in [find("libstdc++.so")] if lib]


# ---------------------------------------------------------------- render

OUTPUT_FORMATS = {".png": "PNG", ".exr": "EXR"}


def render_options(args):
    """Check the render arguments before any slow setup, and turn them into plain data for the venv side."""
    scene = Path(args.scene)
    if not scene.is_file():
        raise UserError(f"scene not found: {args.scene}")
    if scene.suffix.lower() not in (".blend", ".obj"):
        raise UserError(f"expected a .blend or .obj file, got {args.scene}")
    out = Path(args.output)
    ext_format = OUTPUT_FORMATS.get(out.suffix.lower())
    fmt = args.format or ext_format
    if fmt is None:
        raise UserError(f"cannot tell the image format from '{out.name}': name it .png or .exr, or pass --format")
    if args.format and ext_format and args.format != ext_format:
        raise UserError(f"--format {args.format} does not match the file name {out.name}")
    if out.parent != Path("") and not out.parent.resolve().is_dir():
        raise UserError(f"output directory does not exist: {out.parent}")
    for name, low in (("samples", 1), ("threads", 1), ("time_limit", 0)):
        value = getattr(args, name)
        if value is not None and value < low:
            raise UserError(f"--{name.replace('_', '-')} must be at least {low}")
    if args.threads is not None and args.threads > 1024:
        raise UserError("--threads must be at most 1024 (Blender's limit)")
    sample_offset = getattr(args, "sample_offset", None)  # the options added later are optional
    if sample_offset is not None and sample_offset < 0:
        raise UserError("--sample-offset must be at least 0")
    frames = frame_range(args)
    if frames[0] != frames[1] and "#" not in out.name:
        # Blender's convention: '#'s become the zero-padded frame number.
        out = out.with_name(f"{out.stem}_####{out.suffix}")
    return {
        "scene": str(scene.resolve()), "output": str(out.resolve()), "format": fmt,
        "samples": args.samples, "time_limit": args.time_limit, "threads": args.threads,
        "seed": args.seed, "frame": frames[0], "frame_end": frames[1], "verbose": args.verbose,
        "sample_offset": sample_offset,
    }


def frame_range(args):
    """(first, last) frame from --frame, --frames A-B or --frame-start/--frame-end."""
    first = last = args.frame
    frames = getattr(args, "frames", None)
    start, end = getattr(args, "frame_start", None), getattr(args, "frame_end", None)
    if frames is not None:
        if start is not None or end is not None:
            raise UserError("give either --frames or --frame-start/--frame-end")
        m = re.fullmatch(r"\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*)?", frames)
        if not m:
            raise UserError(f"--frames takes FIRST-LAST (e.g. 1-3) or one frame, not '{frames}'")
        first = int(m.group(1))
        last = int(m.group(2)) if m.group(2) is not None else first
    elif start is not None or end is not None:
        first = start if start is not None else args.frame
        last = end if end is not None else first
    if last < first:
        raise UserError(f"the frame range {first}-{last} is empty")
    return first, last


def numbered(path, frame):
    """path with its last run of '#' replaced by the zero-padded frame number (Blender's rule)."""
    runs = list(re.finditer(r"#+", path))
    if not runs:
        return path
    m = runs[-1]
    return path[:m.start()] + f"{frame:0{len(m.group())}d}" + path[m.end():]


def cmd_render(args):
    opts = render_options(args)
    setup_and_build(args)
    # Hand over to the venv's Python (bpy lives there); exec so signals and the exit code pass straight through.
    argv = [str(VENV_PY), str(ROOT / "build.py"), "_render", json.dumps(opts)]
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(str(VENV_PY), argv, runtime_env(args))


def format_duration(seconds):
    if seconds is None:
        return "?"
    seconds = int(round(max(0.0, seconds)))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class ProgressPrinter:
    """Draws the add-on's progress reports: a redrawn bar on a terminal, occasional plain lines otherwise."""

    def __init__(self, stream):
        self.stream = stream
        self.tty = stream.isatty()
        self.lock = threading.Lock()
        self.last = None
        self.last_draw = 0.0
        self.last_line = (-1, 0.0)  # (tenths done, time) of the last plain line
        self.bar = None  # the bar as drawn, while it is on screen

    def __call__(self, info):
        # Called from the render; a broken progress display must never break a render.
        try:
            with self.lock:
                self.update(dict(info))
        except Exception:
            pass

    def update(self, info):
        self.last = info
        done = int(info.get("samples_done") or 0)
        total = int(info.get("samples_total") or 0)
        elapsed = info.get("elapsed_s")
        eta = info.get("eta_s")
        now = time.monotonic()
        fraction = min(1.0, done / total) if total > 0 else 0.0
        finished = total > 0 and done >= total
        if self.tty:
            if now - self.last_draw < 0.1 and not finished:
                return
            width = shutil.get_terminal_size((80, 24)).columns
            text = f" {done}/{total} samples  {format_duration(elapsed)} elapsed  {format_duration(eta)} left"
            bar_width = max(10, min(40, width - len(text) - 4))
            filled = int(round(fraction * bar_width))
            self.bar = ("[" + "#" * filled + "-" * (bar_width - filled) + "]" + text)[: width - 1]
            self.stream.write("\r" + self.bar + "\x1b[K")
            self.stream.flush()
            self.last_draw = now
        else:
            tenths = int(fraction * 10)
            last_tenths, last_time = self.last_line
            if tenths == last_tenths and now - last_time < 15 and not finished:
                return
            if finished and last_tenths == 10:
                return
            self.stream.write(f"progress: {done}/{total} samples, {format_duration(elapsed)} elapsed, "
                              f"{format_duration(eta)} left\n")
            self.stream.flush()
            self.last_line = (10 if finished else tenths, now)

    def print_above(self, write):
        """Let other output through without tearing the bar: clear it, write, draw it again."""
        with self.lock:
            if self.bar is not None:
                self.stream.write("\r\x1b[K")
                self.stream.flush()
            write()
            if self.bar is not None:
                self.stream.write("\r" + self.bar)
                self.stream.flush()

    def finish(self):
        with self.lock:
            if self.bar is not None:
                self.stream.write("\n")
                self.stream.flush()
                self.bar = None


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


def write_all(fd, data):
    while data:
        data = data[os.write(fd, data):]


def hard_exit(code):
    """End a process that loaded bpy without interpreter teardown: bpy 4.5 hangs for ever in exit()
    while a RenderEngine subclass is still registered, and a crashed or failed run may not have
    unregistered it."""
    flush_all()
    os._exit(code)


class StatusLineFilter:
    """In background mode Blender prints 'Fra:1 Mem:... | Time:...' on stdout for every status update
    (once per pass): while our progress display is up, drop those and pass everything else through."""

    def __init__(self, progress):
        self.progress = progress
        self.saved = None

    def start(self):
        flush_all()
        self.saved = os.dup(1)
        read_end, write_end = os.pipe()
        os.dup2(write_end, 1)
        os.close(write_end)
        self.thread = threading.Thread(target=self.pump, args=(read_end,), name="pathlight-stdout", daemon=True)
        self.thread.start()

    def pump(self, read_end):
        with os.fdopen(read_end, "rb") as pipe:
            for line in pipe:
                if not line.startswith(b"Fra:"):
                    self.progress.print_above(lambda: write_all(self.saved, line))

    def stop(self):
        if self.saved is None:
            return
        flush_all()
        os.dup2(self.saved, 1)  # closes the pipe's last write end: the pump sees EOF and ends
        self.thread.join(timeout=5)
        os.close(self.saved)
        self.saved = None


def exit_on_signals():
    """Ctrl-C must stop a headless render: bpy installs no signal handlers and cannot be interrupted
    from Python while it is inside C code. Block the signals in every thread and let one thread wait
    for them and end the process at once."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, sigs)  # before bpy starts threads, so they inherit it

    def wait():
        sig = signal.sigwait(sigs)
        sys.stderr.write("\ninterrupted; the render was not saved\n")
        hard_exit(128 + sig)

    threading.Thread(target=wait, name="pathlight-signals", daemon=True).start()


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


def internal_render(argv):
    """`build.py _render OPTIONS_JSON`: the `render` command's second half, under .venv's Python."""
    run_internal(lambda: render_in_venv(json.loads(argv[0])))


def render_in_venv(opts):
    exit_on_signals()
    try:
        import bpy
    except ImportError as exc:
        raise UserError(f"bpy does not import in {rel(VENV)} ({exc}); run `python3 build.py setup`")

    # Blender prints a Python error raised inside a RenderEngine callback through sys.excepthook and
    # carries on; record such errors so a failed render exits non-zero.
    engine_errors = []
    default_hook = sys.excepthook

    def hook(*exc_info):
        engine_errors.append(exc_info[1])
        default_hook(*exc_info)
    sys.excepthook = hook

    sys.path.insert(0, str(ROOT))
    if opts["scene"].lower().endswith(".obj"):
        # Blender's OBJ importer into an empty scene, a camera framing it and a world light.
        from addon.obj_scene import ObjSceneError, load_obj_scene
        try:
            load_obj_scene(opts["scene"])
        except ObjSceneError as exc:
            raise UserError(str(exc))
    else:
        try:
            bpy.ops.wm.open_mainfile(filepath=opts["scene"])
        except RuntimeError as exc:
            raise UserError(f"could not open {opts['scene']}: {exc}")

    try:
        import addon
        addon.register()
    except Exception as exc:
        raise UserError(f"the Pathlight add-on failed to load: {type(exc).__name__}: {exc}")

    scene = bpy.context.scene
    try:
        scene.render.engine = "PATHLIGHT"
    except TypeError:
        raise UserError("the add-on did not register a render engine called PATHLIGHT")
    if scene.camera is None:
        raise UserError(f"scene '{scene.name}' has no active camera")

    settings = getattr(scene, "pathlight", None)
    for name in ("samples", "time_limit", "seed", "sample_offset"):
        if opts[name] is not None:
            if settings is None or not hasattr(settings, name):
                raise UserError(f"the add-on has no scene.pathlight.{name} setting")
            setattr(settings, name, opts[name])
    if opts["threads"] is not None:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = opts["threads"]
    first, last = opts["frame"], opts.get("frame_end", opts["frame"])
    scene.frame_set(first)

    image = scene.render.image_settings
    if opts["format"] == "EXR":
        image.file_format = "OPEN_EXR"
        image.color_depth = "32"
        image.exr_codec = "ZIP"
    else:
        keep_depth = image.file_format == "PNG"  # the scene may ask for 16-bit PNG
        image.file_format = "PNG"
        if not keep_depth:
            image.color_depth = "8"
    # Write exactly the path given: no extension appended.
    scene.render.use_file_extension = False
    scene.render.filepath = opts["output"]

    r = scene.render
    width = r.resolution_x * r.resolution_percentage // 100
    height = r.resolution_y * r.resolution_percentage // 100
    samples = getattr(settings, "samples", None)
    time_limit = getattr(settings, "time_limit", 0)
    frames = f"frame {first}" if first == last else f"frames {first}-{last}"
    print(f"Rendering {Path(opts['scene']).name}, {frames}, {width}x{height}"
          + (f", {samples} samples" if samples is not None else "")
          + (f", time limit {time_limit:g} s" if time_limit else "")
          + f" -> {opts['output']}", flush=True)

    progress = ProgressPrinter(sys.stderr)
    session = getattr(addon, "session", None)
    listening = session is not None and hasattr(session, "set_progress_listener")
    status_filter = StatusLineFilter(progress)
    if listening:
        session.set_progress_listener(progress)
        if not opts.get("verbose"):
            status_filter.start()

    outs = [Path(numbered(opts["output"], f)) for f in range(first, last + 1)]

    def failed(msg):
        # Blender saves whatever the film held even when the engine failed; don't leave that
        # looking like a finished render.
        for out in outs:
            if out.is_file() and out.stat().st_mtime >= start - 1:
                out.unlink()
                msg += f"; removed the incomplete {out.name}"
        return UserError(msg)

    start = time.time()
    try:
        if first == last:
            scene.render.filepath = str(outs[0])
            result = bpy.ops.render.render(write_still=True)
        else:
            # One animation job, as `blender -a`: meshes that do not change between frames are
            # exported once (the add-on's export cache lives for the job).
            scene.frame_start, scene.frame_end, scene.frame_step = first, last, 1
            result = bpy.ops.render.render(animation=True)
    except RuntimeError as exc:  # the engine's ERROR reports surface here
        raise failed(f"render failed: {str(exc).strip()}")
    finally:
        status_filter.stop()
        progress.finish()
        if listening:
            session.set_progress_listener(None)
    elapsed = time.time() - start

    if engine_errors:
        raise failed("render failed: the add-on raised an error during the render (see above)")
    if "FINISHED" not in result:
        raise failed(f"render failed: the render operator returned {sorted(result)}")
    for out in outs:
        if not out.is_file() or out.stat().st_mtime < start - 1:
            raise UserError(f"the render finished but {out} was not written")

    info = progress.last or {}
    if info.get("samples_total"):
        done = f"{info.get('samples_done', 0)}/{info['samples_total']} samples"
    else:
        done = f"{samples} samples" if samples is not None else "done"
    where = outs[0] if len(outs) == 1 else f"{outs[0]} ... {outs[-1].name}"
    print(f"Rendered {done}{'' if len(outs) == 1 else ' per frame'} in {elapsed:.1f} s -> {where}",
          flush=True)


# ---------------------------------------------------------------- merge

MERGE_SAMPLES = "Pathlight Samples"  # header attributes the add-on stamps into its renders
MERGE_OFFSET = "Pathlight Sample Offset"
COUNT_CHANNEL = re.compile(r"(^|\.)(Sample ?Count|Samples)(\.[A-Z])?$", re.IGNORECASE)


def cmd_merge(args):
    inputs = [Path(p) for p in args.inputs]
    for p in inputs:
        if not p.is_file():
            raise UserError(f"not found: {p}")
    out = Path(args.output)
    if out.suffix.lower() != ".exr":
        raise UserError("the merged output must be an .exr")
    if out.parent != Path("") and not out.parent.resolve().is_dir():
        raise UserError(f"output directory does not exist: {out.parent}")
    with Lock():
        ensure_setup()
    argv = [str(VENV_PY), str(ROOT / "build.py"), "_merge",
            json.dumps({"inputs": [str(p.resolve()) for p in inputs], "output": str(out.resolve())})]
    sys.stdout.flush()
    os.execve(str(VENV_PY), argv, dict(os.environ))  # numpy and OpenEXR only: no core, no bpy


def internal_merge(argv):
    """`build.py _merge OPTIONS_JSON`: the `merge` command, under .venv's Python."""
    def merge():
        opts = json.loads(argv[0])
        info = merge_exr(opts["inputs"], opts["output"])
        ranges = ", ".join(f"[{a}, {a + n})" if a is not None else f"{n}" for a, n in info["ranges"])
        print(f"Merged {len(opts['inputs'])} renders ({info['samples']} samples: {ranges}; "
              f"weights: {info['weights']}) -> {opts['output']}", flush=True)
    run_internal(merge)


def merge_exr(inputs, output):
    """Merges EXR renders of one frame with disjoint sample ranges: every channel is the
    sample-weighted mean of the inputs' channels, a per-pixel sample-count channel (the
    "Sample Count" pass, when the files have one) is summed and weighs its pixels; without it
    each file weighs by its "Pathlight Samples" header attribute. Returns a summary dict."""
    import numpy as np
    import OpenEXR
    parts = []
    for path in inputs:
        with OpenEXR.File(str(path)) as exr:
            header = dict(exr.header())
            channels = {name: np.array(ch.pixels, dtype=np.float32) for name, ch in exr.channels().items()}
        parts.append((path, header, channels))
    names = list(parts[0][2])
    shapes = {n: parts[0][2][n].shape for n in names}
    for path, _, channels in parts[1:]:
        if list(channels) != names or any(channels[n].shape != shapes[n] for n in names):
            raise UserError(f"{Path(path).name} has other channels or another resolution than "
                            f"{Path(parts[0][0]).name}")
    count_names = [n for n in names if COUNT_CHANNEL.search(n)]
    ranges, file_samples = [], []
    for path, header, _ in parts:
        samples = header.get(MERGE_SAMPLES)
        offset = header.get(MERGE_OFFSET)
        if samples is None and not count_names:
            raise UserError(f"{Path(path).name} has neither a Sample Count pass nor a "
                            f"'{MERGE_SAMPLES}' attribute: render it with Pathlight")
        n = int(float(samples)) if samples is not None else None
        ranges.append((int(float(offset)) if offset is not None else None, n))
        file_samples.append(n)
    known = sorted((a, n) for a, n in ranges if a is not None and n is not None)
    for (a0, n0), (a1, _) in zip(known, known[1:]):
        if a1 < a0 + n0:
            raise UserError(f"sample ranges [{a0}, {a0 + n0}) and [{a1}, ...) overlap: the "
                            "merged render would count those samples twice (use --sample-offset)")

    def weight(i, shape):
        channels = parts[i][2]
        if count_names:
            w = channels[count_names[0]].astype(np.float64)
        else:
            w = np.full(shape[:2], float(file_samples[i]))
        return w.reshape(w.shape + (1,) * (len(shape) - w.ndim))

    merged = {}
    for name in names:
        if name in count_names:
            merged[name] = sum(p[2][name].astype(np.float64) for p in parts).astype(np.float32)
            continue
        shape = shapes[name]
        num = np.zeros(shape, np.float64)
        den = np.zeros(shape[:2] + (1,) * (len(shape) - 2), np.float64)
        for i, part in enumerate(parts):
            w = weight(i, shape)
            num += w * part[2][name]
            den += w
        merged[name] = np.where(den > 0, num / np.maximum(den, 1e-300), 0.0).astype(np.float32)
    header = {k: v for k, v in parts[0][1].items()
              if k in ("compression", "pixelAspectRatio") or not k[:1].islower()}
    total = sum(n for n in file_samples if n is not None) if all(file_samples) else None
    if total is not None:
        header[MERGE_SAMPLES] = str(total)
        header[MERGE_OFFSET] = str(min(a for a, _ in ranges if a is not None)) \
            if all(a is not None for a, _ in ranges) else "0"
    OpenEXR.File(header, merged).write(str(output))
    return {"samples": total, "ranges": ranges,
            "weights": "per-pixel sample counts" if count_names else "samples per file"}


# ---------------------------------------------------------------- test

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
    pytest_args += extra
    argv = [str(VENV_PY), str(ROOT / "build.py"), "_pytest", *pytest_args]
    print("+ pytest " + " ".join(pytest_args), flush=True)
    sys.stderr.flush()
    os.chdir(ROOT)
    os.execve(str(VENV_PY), argv, runtime_env(args))  # pytest's exit code becomes ours


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


# ---------------------------------------------------------------- bench

def machine_description():
    model, mem = platform.processor() or platform.machine(), None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.partition(":")[2].strip()
                break
        m = re.search(r"^MemTotal:\s+(\d+) kB", Path("/proc/meminfo").read_text(), re.M)
        mem = int(m.group(1)) / 2**20 if m else None
    except OSError:
        pass
    cores = f"{jobs_default()} cores"
    if (os.cpu_count() or 0) != jobs_default():
        cores += f" usable of {os.cpu_count()}"
    text = f"{model}, {cores}"
    if mem:
        text += f", {mem:.0f} GiB RAM"
    return text + f"; {platform.system()} {platform.release()} {platform.machine()}"


def git_commit():
    try:
        sha = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=ROOT,
                             capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True).stdout.strip()
    except OSError:
        return "unknown (git not found)"
    if not sha:
        return "unknown (not a git checkout)"
    return sha + (" with uncommitted changes" if dirty else "")


def core_build_info():
    code = ("import json, sys; sys.path.insert(0, 'addon'); import pathlight_core as c; "
            "print(json.dumps(dict(c.build_info(), version=c.__version__)))")
    try:
        proc = subprocess.run([str(VENV_PY), "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
        info = json.loads(proc.stdout.strip().splitlines()[-1])
    except Exception:
        return "unknown"
    return ", ".join(f"{k} {v}" for k, v in sorted(info.items()))


def relink_section(text):
    """Sections live in docs/bench/ but are pasted into docs/: point their relative links at bench/."""
    def fix(m):
        target = m.group(2)
        if re.match(r"^([a-z]+:|/|#)", target) or not (BENCH_SECTIONS / target).exists() \
                or (DOCS / target).exists():
            return m.group(0)
        return f"{m.group(1)}(bench/{target})"
    return re.sub(r"(\]\s*)\(([^)\s]+)\)", fix, text)


def assemble_benchmarks(stamp, started, ran, failed, extra):
    sections = sorted(BENCH_SECTIONS.glob("*.md")) if BENCH_SECTIONS.is_dir() else []
    lines = [
        "# Benchmarks",
        "",
        "Generated by `python3 build.py bench`; do not edit by hand. Each section below is written by a",
        "script `tests/bench/bench_*.py` into `docs/bench/<name>.md` and pasted here in name order.",
        "",
        "| | |",
        "|---|---|",
        f"| Date | {time.strftime('%Y-%m-%d %H:%M %Z', time.localtime(started))} |",
        f"| Machine | {machine_description()} |",
        f"| Commit | {git_commit()} |",
        f"| Core | {core_build_info()} |",
        f"| Python / bpy | {stamp.get('python', '?')} / {stamp.get('bpy', '?')} |",
        f"| Scripts run | {', '.join(ran) or 'none'}" + (f" with `{' '.join(extra)}`" if extra else "") + " |",
    ]
    if failed:
        lines.append(f"| Failed | {', '.join(failed)} |")
    lines.append("")
    if not sections:
        lines += ["No benchmark sections were written.", ""]
    for path in sections:
        lines.append("")
        if path.stat().st_mtime < started:
            lines += [f"> `{rel(path)}` was not rewritten by this run (its script failed, was skipped or "
                      "is gone), so it may describe another commit or machine.", ""]
        lines.append(relink_section(path.read_text()).rstrip())
        lines.append("")
    out = DOCS / "benchmarks.md"
    out.write_text("\n".join(lines).rstrip() + "\n")
    log(f"wrote {rel(out)} from {len(sections)} section(s)")
    update_readme_benchmarks(sections, started, extra)


README_BENCH_BEGIN, README_BENCH_END = "<!-- bench-table:begin -->", "<!-- bench-table:end -->"

# The README's headline of each section (docs/bench/<stem>.md): what its figure means, and the
# text of one row of the section's first table (a dict of column header -> cell), or None to
# leave the row out. A section not listed here, or whose columns were renamed, gets its first
# column and its last one, so a new benchmark still shows up.
README_BENCH_HEADLINES = {
    "equal_time": ("Cycles' error over Pathlight's at equal time, pooled (above 1: Pathlight ahead)",
                   lambda r: f"{r['Scene']} {r['all budgets pooled']}"),
    "export": ("Cold render (export, BVH, 1 sample): Cycles' time over Pathlight's",
               lambda r: f"{r['Triangles']} triangles {r['Cycles time / Pathlight time']}"),
    "export_rerender": ("Re-renders: Cycles' time over Pathlight's",
                        lambda r: f"{r['Triangles']} triangles, {r['Render']} {r['Cycles time / Pathlight time']}"
                        if "animation" in r["Render"] or "first" in r["Render"] else None),
    "realistic": ("As equal time (converged mean ratio)",
                  lambda r: f"{r['Scene'].split(' (')[0]} {r['pooled'].split(' ')[0]} "
                            f"({r['converged mean / worst region'].split(' /')[0]})"),
    "kernels": ("Specialised kernel's samples/s over the general one's",
                lambda r: f"{r['Scene']} {r['Speed-up']}"),
    "rays": ("Embree's rays/s over Pathlight's, one thread each",
             lambda r: f"{r['Rays']} {r['Embree / Pathlight']}"),
    "sbvh": ("Ray speed-up from spatial splits, primary / diffuse",
             lambda r: f"{r['Scene']} {r['Speed-up, primary / diffuse']}"
             if r["Spatial splits"].startswith("on") else None),
    "scaling": ("Milliseconds per sample at 128x128 (peak memory)",
                lambda r: f"{r['Triangles']} triangles {r['ms per sample at 128x128']} ms "
                          f"({r['peak RSS (MiB)']} MiB)"),
}


def first_table(lines):
    """The first Markdown table in `lines`: its header cells and its rows as dicts."""
    rows, header = [], None
    for line in lines:
        if not line.startswith("|"):
            if header is not None:
                break
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if header is None:
            header = cells
        elif not all(set(c) <= set("-: ") for c in cells):
            rows.append(dict(zip(header, cells)))
    return header or [], rows


def bench_headline(stem, lines):
    """(what the figure means, the section's headline figures) for the README's table."""
    header, rows = first_table(lines)
    if not rows:
        return None
    if stem in README_BENCH_HEADLINES:
        what, fmt = README_BENCH_HEADLINES[stem]
        try:
            return what, "; ".join(s for s in map(fmt, rows) if s)
        except (KeyError, AttributeError):
            pass  # its columns changed: the generic headline below
    return header[-1], "; ".join(f"{r.get(header[0], '')} {r.get(header[-1], '')}" for r in rows)


def update_readme_benchmarks(sections, started, extra, readme=None):
    """The README's benchmark table: one line per section with its headline figures, stamped with
    date, machine and commit of this run (the full tables stay in docs/benchmarks.md)."""
    readme = readme or ROOT / "README.md"
    text = readme.read_text()
    if README_BENCH_BEGIN not in text or README_BENCH_END not in text:
        warn(f"{readme.name} has no benchmark-table markers; its table was not updated")
        return
    body = [f"Measured by `python3 build.py bench`{' ' + ' '.join(extra) if extra else ''} on "
            f"{time.strftime('%Y-%m-%d', time.localtime(started))}, {machine_description()}, "
            f"commit {git_commit()}. Full tables: [docs/benchmarks.md](docs/benchmarks.md).", "",
            "| Benchmark | Figure | Result |", "|---|---|---|"]
    for path in sections:
        sec = path.read_text().splitlines()
        heading = next((l.lstrip("#").strip() for l in sec if l.startswith("#")), path.stem)
        # A section this run did not rewrite (`bench --only`, or its script failed) keeps its
        # line, marked as older, rather than vanishing from the README.
        if path.stat().st_mtime < started:
            heading += " (earlier run)"
        line = bench_headline(path.stem, sec)
        if line:
            body.append(f"| {heading} | {line[0]} | {line[1]} |")
    head, _, rest = text.partition(README_BENCH_BEGIN)
    _, _, tail = rest.partition(README_BENCH_END)
    readme.write_text(head + README_BENCH_BEGIN + "\n" + "\n".join(body).rstrip() + "\n" + README_BENCH_END + tail)
    log(f"updated the benchmark table in {readme.name}")


def cmd_bench(args, extra):
    stamp = setup_and_build(args)
    scripts = sorted(BENCH_SCRIPTS.glob("bench_*.py")) if BENCH_SCRIPTS.is_dir() else []
    if args.only:
        scripts = [s for s in scripts if any(k in s.stem for k in args.only)]
    if not scripts:
        log(f"no benchmark scripts to run ({rel(BENCH_SCRIPTS)}/bench_*.py"
            + (f" matching {args.only}" if args.only else "") + ")")
        return 0
    started = time.time()
    env = runtime_env(args, {"PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))})
    ran, failed = [], []
    for script in scripts:
        log(f"running {rel(script)}")
        t0 = time.time()
        rc = subprocess.call([str(VENV_PY), str(ROOT / "build.py"), "_run", str(script), "--out", "docs/", *extra],
                             cwd=ROOT, env=env)
        ran.append(script.stem)
        if rc != 0:
            failed.append(f"{script.stem} (exit code {rc})")
            warn(f"{rel(script)} failed with exit code {rc}")
        else:
            log(f"{rel(script)} took {time.time() - t0:.1f} s")
    assemble_benchmarks(stamp, started, ran, failed, extra)
    if failed:
        raise UserError(f"{len(failed)} benchmark script(s) failed: {', '.join(failed)}")
    return 0


# ---------------------------------------------------------------- package

def manifest_version():
    """The add-on's version: blender_manifest.toml is the one place it is written."""
    try:
        text = MANIFEST.read_text()
    except OSError:
        raise UserError(f"{rel(MANIFEST)} is missing")
    m = re.search(r'^version\s*=\s*"([^"]+)"', text, re.M)
    if not m:
        raise UserError(f"no version = \"...\" line in {rel(MANIFEST)}")
    return m.group(1)


def package_files():
    """The add-on's files for the zip: everything in addon/ but caches, temporaries and hidden files."""
    files = []
    for dirpath, dirnames, filenames in os.walk(ADDON):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__" and not d.startswith("."))
        for name in sorted(filenames):
            if name.startswith(".") or name.endswith((".pyc", ".pyo", ".tmp")):
                continue
            files.append(Path(dirpath) / name)
    return files


def validate_with_blender(zip_path):
    """Blender's own extension validator ships inside the bpy wheel; use it when it is there."""
    found = sorted(VENV.glob("lib/python3*/site-packages/bpy/*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        warn("Blender's extension validator was not found in the bpy package; the zip was not validated")
        return
    proc = subprocess.run([str(VENV_PY), str(found[-1]), "validate", str(zip_path)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise UserError("Blender's extension validator rejected the zip:\n" + (proc.stdout + proc.stderr).strip())
    log("Blender's extension validator accepts the zip")


def internal_check_zip(argv):
    """`build.py _check_zip ZIP`: install the zip into a Blender whose user dir is a temp dir (the
    caller sets BLENDER_USER_RESOURCES), then check the engine registers and the core loads."""
    code = 1
    try:
        import bpy
        result = bpy.ops.extensions.package_install_files(
            filepath=argv[0], repo="user_default", enable_on_install=True)
        if "FINISHED" not in result:
            raise UserError(f"Blender did not install it: {sorted(result)}")
        try:
            bpy.context.scene.render.engine = "PATHLIGHT"
        except TypeError:
            raise UserError("installed and enabled, but no PATHLIGHT render engine was registered")
        import importlib
        try:
            core = importlib.import_module("bl_ext.user_default.pathlight.core")
        except ImportError as exc:
            raise UserError(f"the installed add-on has no loadable core.py: {exc}")
        version = core.get_core().__version__
        print(f"installed in Blender {bpy.app.version_string}: engine registered, core {version} loads")
        code = 0
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
    except BaseException:
        import traceback
        traceback.print_exc()
    hard_exit(code)


def check_zip_installs(zip_path):
    import tempfile
    with tempfile.TemporaryDirectory(prefix="pathlight-user-") as user_dir:
        env = dict(os.environ, BLENDER_USER_RESOURCES=user_dir)
        proc = subprocess.run([str(VENV_PY), str(ROOT / "build.py"), "_check_zip", str(zip_path)],
                              capture_output=True, text=True, env=env, timeout=300)
    if proc.returncode != 0:
        raise UserError("the zip does not install and load in Blender:\n" + (proc.stdout + proc.stderr).strip())
    log(proc.stdout.strip().splitlines()[-1])


def cmd_package(args):
    if args.sanitize:
        raise UserError("package ships a release build; run it without --sanitize")
    setup_and_build(args)
    version = manifest_version()
    if not (ADDON / "__init__.py").is_file():
        raise UserError(f"{rel(ADDON)}/__init__.py is missing: the add-on is not in this checkout yet")
    modules = list(ADDON.glob("pathlight_core*.so"))
    if not modules:
        raise UserError(f"no pathlight_core*.so in {rel(ADDON)} after the build")
    # Blender reads the version from the manifest; a legacy bl_info copy must not drift from it.
    m = re.search(r'"version"\s*:\s*\(([\d,\s]+)\)', (ADDON / "__init__.py").read_text())
    if m:
        bl_version = ".".join(x.strip() for x in m.group(1).split(",") if x.strip())
        if bl_version != version:
            warn(f"bl_info in {rel(ADDON)}/__init__.py says version {bl_version} but {rel(MANIFEST)} says {version}")
    core_info = core_build_info()
    core_version = re.search(r"version (\S+)", core_info)
    if core_version and core_version.group(1).rstrip(",") != version:
        warn(f"the core says version {core_version.group(1).rstrip(',')} but {rel(MANIFEST)} says {version}")

    DIST.mkdir(exist_ok=True)
    zip_path = DIST / f"pathlight-{version}.zip"
    tmp = DIST / f".pathlight-{version}.partial.zip"  # becomes zip_path only once it passed the checks
    files = package_files()
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        for path in files:
            # Fixed timestamps: the same inputs give the same zip.
            info = zipfile.ZipInfo(path.relative_to(ADDON).as_posix(), date_time=(2024, 1, 1, 0, 0, 0))
            info.external_attr = ((0o755 if os.access(path, os.X_OK) else 0o644) | 0o100000) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, path.read_bytes())
    try:
        validate_with_blender(tmp)
        check_zip_installs(tmp)
    except BaseException:
        tmp.unlink()
        raise
    os.replace(tmp, zip_path)
    simd = re.search(r"simd (\S+)", core_info)
    simd = simd.group(1).rstrip(",") if simd else simd_level(args)
    log(f"wrote {rel(zip_path)} ({zip_path.stat().st_size / 2**20:.1f} MiB, {len(files)} files); "
        f"install it in Blender with Edit > Preferences > Get Extensions > Install from Disk")
    if simd != "generic":
        log(f"its core uses {simd} instructions and will not load on CPUs without them; "
            "`python3 build.py package --portable` makes one that runs on any x86-64 CPU")
    return 0


# ---------------------------------------------------------------- clean

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


# ---------------------------------------------------------------- command line

def parse_args(argv):
    build_opts = argparse.ArgumentParser(add_help=False)
    g = build_opts.add_argument_group("build options (every command builds what is out of date first)")
    g.add_argument("--simd", choices=SIMD_LEVELS, help="SIMD level to compile the core for "
                   "(default: the best this CPU has, from /proc/cpuinfo)")
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
    p.add_argument("-v", "--verbose", action="store_true",
                   help="keep Blender's own status line for every update")

    p = sub.add_parser("merge", help="merge partial EXR renders of one frame (farm splitting)",
                       description="Merge EXR renders of the same frame with different sample "
                                   "ranges (render --sample-offset) into one, weighting each by "
                                   "its sample count (per pixel when the files have a Sample "
                                   "Count pass, else from the Pathlight Samples metadata).")
    p.add_argument("inputs", nargs="+", help="partial renders (.exr)")
    p.add_argument("-o", "--output", required=True, help="merged image to write (.exr)")

    sub.add_parser("test", parents=[build_opts], help="run the test suite (pytest arguments after --)",
                   description="Run `pytest tests` in .venv; arguments after -- go to pytest, "
                               "e.g. python3 build.py test -- -k furnace -x")

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


if __name__ == "__main__":
    sys.exit(main())
