"""`build`: the C++ core with CMake (SIMD level, sanitizers), the module copied into addon/,
and the environment of the processes that load it."""

import filecmp
import os
import platform
import re
import shutil
import subprocess
from pathlib import Path

from .common import ADDON, BUILD, CORE, VENV_PY, Lock, UserError, jobs_default, log, read_json, rel, run, warn, write_json
from .setup import ensure_setup


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
    if args.sanitize:
        # -O1 instead of RelWithDebInfo's -O2: the same ASan and UBSan checks (inserted whatever
        # the level; -O2 only removes some of ASan's) for about half the compile time, which CI
        # pays from scratch every run (docs/building.md "CI time").
        config["defines"]["CMAKE_CXX_FLAGS_RELWITHDEBINFO"] = "-O1 -g -DNDEBUG"
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
