"""Colour spaces of byte images converted to scene linear by OpenColorIO, the library Blender
ships and Cycles converts images with: its Python bindings (Blender's Python imports them; the
`bpy` wheel keeps them in its own site-packages, off sys.path) and the config Blender reads
($OCIO, else its bundled config.ocio). One CPU processor per colour space, cached. What the
library is missing for, or cannot build a processor of, raises Unsupported (the caller warns)."""

import os
import sys
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache

import numpy as np


class Unsupported(Exception):
    """A colour space this module cannot convert (the reason in the message)."""


_CHUNK = 1 << 18  # pixels per apply call (the bindings release the GIL: chunks run in parallel)


def _bindings_dirs():
    """Site-packages folders of Blender's own Python that may hold PyOpenColorIO: under the
    version folder (bpy.utils.resource_path('LOCAL'), four folders above bpy's __init__.py in
    the wheel), in the layouts of Linux / macOS and Windows."""
    try:
        import bpy
        local = bpy.utils.resource_path('LOCAL')
    except (ImportError, AttributeError):
        return []
    py = f"python{sys.version_info.major}.{sys.version_info.minor}"
    return [os.path.join(local, "python", "lib", py, "site-packages"),
            os.path.join(local, "python", "lib", "site-packages"),
            os.path.join(local, "python", "Lib", "site-packages")]


@lru_cache(maxsize=1)
def bindings():
    """The PyOpenColorIO module, or Unsupported why not."""
    try:
        import PyOpenColorIO
        return PyOpenColorIO
    except ImportError as e:
        first = e
    for folder in _bindings_dirs():
        if not os.path.isdir(os.path.join(folder, "PyOpenColorIO")):
            continue
        sys.path.append(folder)
        try:
            import PyOpenColorIO
            return PyOpenColorIO
        except ImportError as e:
            first = e
        finally:
            sys.path.remove(folder)  # (the module stays loaded; the folder's others stay hidden)
    raise Unsupported(f"OpenColorIO's Python bindings (PyOpenColorIO) cannot be imported: {first}")


def config_path():
    """Blender's bundled config (what it reads when $OCIO is unset or fails)."""
    import bpy
    return os.path.join(bpy.utils.system_resource('DATAFILES'), "colormanagement", "config.ocio")


@lru_cache(maxsize=4)
def _config(env):
    """The OCIO config Blender picks (colormanagement.cc): $OCIO's if set and loadable, else
    the bundled one. `env`: $OCIO's value (the cache key)."""
    ocio = bindings()
    if env:
        try:
            return ocio.Config.CreateFromEnv()
        except Exception:  # (the library's exceptions have no common base but this)
            pass
    try:
        return ocio.Config.CreateFromFile(config_path())
    except Exception as e:
        raise Unsupported(f"OCIO config cannot be read: {e}") from None


def load_config():
    return _config(os.environ.get("OCIO", ""))


@lru_cache(maxsize=64)
def _processor(env, space_name):
    ocio = bindings()
    config = _config(env)
    try:
        return config.getProcessor(space_name, ocio.ROLE_SCENE_LINEAR).getDefaultCPUProcessor()
    except Exception as e:  # (ocio.Exception, ExceptionMissingFile: no processor for it)
        raise Unsupported(str(e).strip().rstrip(".")) from None


def processor(space_name):
    """The cached CPU processor from `space_name` to the scene_linear role, or Unsupported."""
    return _processor(os.environ.get("OCIO", ""), space_name)


def to_scene_linear(rgb, space_name):
    """float32 `rgb` (..., 3) in colour space `space_name` of the config, in scene linear
    (a new array). Raises Unsupported where the bindings or the space's processor are not to
    be had."""
    proc = processor(space_name)
    out = np.array(rgb, np.float32, order="C", copy=True)
    flat = out.reshape(-1, 3)
    chunks = [flat[i:i + _CHUNK] for i in range(0, len(flat), _CHUNK)]
    workers = min(len(chunks), os.cpu_count() or 1)
    try:
        if workers <= 1:
            for chunk in chunks:
                proc.applyRGB(chunk)
        else:
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(proc.applyRGB, chunks))
    except Exception as e:
        raise Unsupported(str(e)) from None
    return out
