"""`package`: addon/ zipped into dist/pathlight-VERSION.zip, checked by Blender's extension
validator and by installing it into a throwaway Blender user dir (`build.py _check_zip`)."""

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

from .bench import core_build_info
from .common import ADDON, DIST, MANIFEST, ROOT, VENV, VENV_PY, UserError, hard_exit, log, rel, warn
from .compile import setup_and_build, simd_level


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
