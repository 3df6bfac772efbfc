"""Denoising with Intel Open Image Denoise, the library Blender itself ships (Cycles' denoiser).

Nothing is vendored or built: the library is loaded with ctypes from where Blender keeps it, the
first found of
- the copy already loaded in this process (Blender links it for Cycles and the compositor),
- `lib/` beside the `bpy` module (the pip wheel: bpy/lib/libOpenImageDenoise.so.2; found
  without importing bpy where it is not imported, as in `build.py merge`),
- beside Blender's binary (`bpy.app.binary_path`): Linux `lib/`, Windows `blender.shared/`,
  macOS `../Resources/lib/`.
Only the OIDN 2.x C API is used (include/OpenImageDenoise/oidn.h): one CPU device, kept for
the process, and "RT" filters on float32 numpy images shared with the library (no copies of
the colour). ctypes releases the GIL during each call, so a denoise does not block other Python
threads. Any failure is a DenoiseError with the library's own message: the callers turn it into
a warning and keep the noisy image (never a crash). As Cycles (denoiser_oidn.cpp) it denoises
Combined and, with shadow catchers, the Shadow Catcher Matte and Shadow Catcher passes (the
latter with a constant 0.5 albedo), and Combined is composed again from them; nothing else.
docs/design/passes.md "Denoising".
"""

import ctypes
import logging
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

# Cycles' settings (scene.cycles.denoising_*), under the same identifiers.
INPUT_PASSES = ('RGB', 'RGB_ALBEDO', 'RGB_ALBEDO_NORMAL')
PREFILTERS = ('NONE', 'FAST', 'ACCURATE')
QUALITIES = ('HIGH', 'BALANCED', 'FAST')

# oidn.h (2.x) values
_DEVICE_TYPE_CPU = 1
_FORMAT_FLOAT3 = 3
_ERROR_NONE, _ERROR_CANCELLED = 0, 6
_QUALITY = {'FAST': 4, 'BALANCED': 5, 'HIGH': 6}

ALBEDO_PASS, NORMAL_PASS = "Denoising Albedo", "Denoising Normal"
# Shadow catchers (docs/design/passes.md "Shadow catcher and holdout objects"): the planes Cycles
# denoises besides Combined, and the world behind the catcher that the opaque composite adds.
SHADOW_CATCHER, MATTE, ENV = "Shadow Catcher", "Shadow Catcher Matte", "Env"
# How Combined is composed with catchers in the scene (the core's CatcherCombined): the matte
# alone (the Shadow Catcher pass is asked for), the approximate shadow catcher on a transparent
# film, or that over the world behind the catcher on an opaque one.
CATCHER_MODES = ('MATTE', 'APPROXIMATE', 'OVER_BACKGROUND')
# Cycles' stand-in albedo for passes denoised without one (set_fake_albedo_pass).
FAKE_ALBEDO = 0.5


class DenoiseError(RuntimeError):
    """Open Image Denoise could not be loaded or failed; the message says why."""


class DenoiseCancelled(DenoiseError):
    """The caller's cancel() said stop: the image is left as it was (OIDN's output is undefined)."""


# bool (*OIDNProgressMonitorFunction)(void* userPtr, double n): False cancels the filter.
_PROGRESS = ctypes.CFUNCTYPE(ctypes.c_bool, ctypes.c_void_p, ctypes.c_double)


def aux_passes(input_passes):
    """The core passes that denoising with `input_passes` reads (besides Combined)."""
    return {'RGB': [], 'RGB_ALBEDO': [ALBEDO_PASS]}.get(input_passes, [ALBEDO_PASS, NORMAL_PASS])


def _library_names():
    if sys.platform.startswith("win"):
        return ["OpenImageDenoise.dll"]
    if sys.platform == "darwin":
        return ["libOpenImageDenoise.2.dylib", "libOpenImageDenoise.dylib"]
    return ["libOpenImageDenoise.so.2", "libOpenImageDenoise.so"]


def _loaded_copy():
    """The path of a libOpenImageDenoise already mapped into this process (Linux), or None."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            for line in f:
                path = line.rstrip("\n").split(maxsplit=5)[-1]
                if os.path.basename(path) in _library_names():
                    return path
    except OSError:
        pass
    return None


def library_candidates():
    """Paths to try, in order (see the module's docstring); only those that exist."""
    out = []
    loaded = _loaded_copy()
    if loaded:
        out.append(Path(loaded))
    dirs = []
    bpy = sys.modules.get("bpy")
    if bpy is not None and getattr(bpy, "__file__", None):
        dirs.append(Path(bpy.__file__).resolve().parent / "lib")
    elif bpy is None:  # (build.py merge: the bpy wheel is installed, not imported)
        import importlib.util
        try:
            spec = importlib.util.find_spec("bpy")
        except (ImportError, ValueError):
            spec = None
        if spec is not None and spec.origin:
            dirs.append(Path(spec.origin).resolve().parent / "lib")
    binary = getattr(getattr(bpy, "app", None), "binary_path", "") if bpy is not None else ""
    if binary:
        root = Path(binary).resolve().parent
        dirs += [root / "lib", root / "blender.shared", root.parent / "Resources" / "lib"]
    for d in dirs:
        for name in _library_names():
            if (d / name).is_file():
                out.append(d / name)
    seen, unique = set(), []
    for p in out:
        if str(p) not in seen:
            seen.add(str(p))
            unique.append(p)
    return unique


def _declare(lib):
    """argtypes / restype of the few C functions used (oidn.h 2.x)."""
    p, s, c, i, b = ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_int, ctypes.c_bool
    sigs = {
        "oidnNewDevice": ([i], p),
        "oidnSetDeviceBool": ([p, c, b], None),
        "oidnCommitDevice": ([p], None),
        "oidnGetDeviceError": ([p, ctypes.POINTER(ctypes.c_char_p)], i),
        "oidnReleaseDevice": ([p], None),
        "oidnNewFilter": ([p, c], p),
        "oidnSetSharedFilterImage": ([p, c, p, i, s, s, s, s, s], None),
        "oidnSetFilterBool": ([p, c, b], None),
        "oidnSetFilterInt": ([p, c, i], None),
        "oidnCommitFilter": ([p], None),
        "oidnExecuteFilter": ([p], None),
        "oidnSetFilterProgressMonitorFunction": ([p, _PROGRESS, p], None),
        "oidnReleaseFilter": ([p], None),
    }
    for name, (args, res) in sigs.items():
        fn = getattr(lib, name)  # AttributeError: not an OIDN 2.x library
        fn.argtypes, fn.restype = args, res


def load_library():
    """ctypes.CDLL of Open Image Denoise 2.x; DenoiseError when there is none that works."""
    tried = []
    for path in library_candidates():
        try:
            lib = ctypes.CDLL(str(path))
            _declare(lib)
            return lib
        except (OSError, AttributeError) as e:
            tried.append(f"{path}: {e}")
    where = "; ".join(tried) if tried else "none found in this process, beside bpy or beside Blender"
    raise DenoiseError(f"Open Image Denoise (Blender's libOpenImageDenoise 2.x) could not be loaded ({where})")


_lock = threading.Lock()
_state = {}  # "lib", "device" once loaded; "error" when loading failed


def reset():
    """Forget the loaded library and device (tests, or after the library's files changed)."""
    with _lock:
        dev, lib = _state.get("device"), _state.get("lib")
        if dev and lib is not None:
            lib.oidnReleaseDevice(dev)
        _state.clear()


def _error(lib, device):
    msg = ctypes.c_char_p()
    code = lib.oidnGetDeviceError(device, ctypes.byref(msg))
    text = msg.value.decode("utf-8", "replace") if msg.value else f"error code {code}"
    return code, text


def _device():
    """(lib, device), created once (under _lock); DenoiseError when that fails."""
    if "error" in _state:
        raise DenoiseError(_state["error"])
    if "device" not in _state:
        try:
            lib = load_library()
            dev = lib.oidnNewDevice(_DEVICE_TYPE_CPU)
            if not dev:
                raise DenoiseError("Open Image Denoise: no CPU device ({})".format(_error(lib, None)[1]))
            lib.oidnSetDeviceBool(dev, b"setAffinity", False)  # as Cycles: leave thread pinning alone
            lib.oidnCommitDevice(dev)
            code, text = _error(lib, dev)
            if code != _ERROR_NONE:
                lib.oidnReleaseDevice(dev)
                raise DenoiseError(f"Open Image Denoise: the CPU device failed: {text}")
        except DenoiseError as e:
            _state["error"] = str(e)  # (once: a missing library is not looked for at every frame)
            raise
        _state.update(lib=lib, device=dev)
    return _state["lib"], _state["device"]


def available():
    """True when the library loads and its CPU device works; else the reason (a str)."""
    try:
        with _lock:
            _device()
        return True
    except DenoiseError as e:
        return str(e)


def _image(arr, name):
    """A float32 (H, W, C >= 3) C-contiguous array, checked (OIDN reads through raw pointers)."""
    if (not isinstance(arr, np.ndarray) or arr.dtype != np.float32 or arr.ndim != 3
            or arr.shape[2] < 3 or not arr.flags.c_contiguous or not arr.flags.writeable):
        raise ValueError(f"{name} must be a writable C-contiguous float32 (H, W, >=3) array, not "
                         f"{getattr(arr, 'dtype', type(arr))} {getattr(arr, 'shape', '')}")
    return arr


def _set_image(lib, filt, name, arr):
    h, w, c = arr.shape
    lib.oidnSetSharedFilterImage(filt, name, arr.ctypes.data, _FORMAT_FLOAT3, w, h, 0, 4 * c, 4 * c * w)


def denoise(color, albedo=None, normal=None, prefilter='ACCURATE', quality='HIGH', cancel=None):
    """Denoises the RGB of `color` (float32 (H, W, 3 or 4), C-contiguous, scene-linear HDR) in
    place; a fourth channel (alpha) is left as it is. albedo / normal: (H, W, 3) guides (the
    Denoising Albedo / Normal passes) or None; a normal needs an albedo (OIDN's rule). They are
    copied, so the caller's passes are never changed. prefilter as Cycles': 'ACCURATE' first
    denoises the guides with their own filters and then trusts them (cleanAux), 'FAST' uses them
    as they are, noise and all, 'NONE' trusts them as they are (noise-free guides). Returns the
    seconds it took; DenoiseError (the library's message) when the library is missing or fails.
    cancel: a function polled by the library while it filters (from the calling thread); True
    stops it: DenoiseCancelled, and `color` is then restored (a partial result is undefined).
    Non-finite values (NaN, +-inf) become 0 first, as Cycles' film keeps none (ensure_finite):
    the library reads NaN as 0 but smears one +inf over the whole image."""
    return denoise_many([(color, True)], albedo, normal, prefilter=prefilter, quality=quality, cancel=cancel)


def _finite(arr, name):
    """Sets the non-finite values of arr's first three channels to 0 (in place); logs how many."""
    rgb = arr[..., :3]
    bad = ~np.isfinite(rgb)
    count = int(np.count_nonzero(bad))
    if count:
        rgb[bad] = 0.0
        log.warning("Pathlight: %d non-finite value(s) in the %s set to 0 before denoising", count, name)
    return count


def denoise_many(colors, albedo=None, normal=None, prefilter='ACCURATE', quality='HIGH', cancel=None):
    """denoise() of several images of one frame with the same guides, each prefiltered once
    (as Cycles' OIDNDenoiseContext). colors: [(color, use_albedo)]; use_albedo False denoises
    that image with a constant 0.5 albedo where there is an albedo guide (Cycles' fake albedo,
    for the Shadow Catcher pass: its values are not lit by the surfaces' colour) and the normal
    as for the others. On cancel every image is restored. Returns the seconds it took."""
    colors = [(_image(c, "color"), bool(a)) for c, a in colors]
    if prefilter not in PREFILTERS or quality not in QUALITIES:
        raise ValueError(f"prefilter {prefilter!r} / quality {quality!r}")
    if normal is not None and albedo is None:
        raise ValueError("a normal guide needs an albedo guide (Open Image Denoise's rule)")
    if not colors:
        return 0.0
    h, w = colors[0][0].shape[:2]
    if any(c.shape[:2] != (h, w) for c, _ in colors):
        raise ValueError(f"images of different sizes: {[c.shape for c, _ in colors]}")
    guides = []
    for name, aux in ((b"albedo", albedo), (b"normal", normal)):
        if aux is not None:
            aux = np.ascontiguousarray(np.asarray(aux, np.float32)[..., :3]).copy()
            if aux.shape != (h, w, 3):
                raise ValueError(f"{name.decode()} is {aux.shape}, the colour {colors[0][0].shape}")
            guides.append((name, aux))
    if h == 0 or w == 0:
        return 0.0
    t0 = time.perf_counter()
    saved = [c.copy() for c, _ in colors] if cancel is not None else None
    for k, (color, _) in enumerate(colors):
        _finite(color, "image" if len(colors) == 1 else f"image {k + 1} of {len(colors)}")
    for name, aux in guides:
        _finite(aux, f"{name.decode()} guide")
    with _lock:  # one filter at a time on the one device
        lib, dev = _device()
        filters = []

        monitor = _PROGRESS(lambda user, n: not cancel()) if cancel is not None else None

        def run(filt, what):
            lib.oidnSetFilterInt(filt, b"quality", _QUALITY[quality])
            if monitor is not None:
                lib.oidnSetFilterProgressMonitorFunction(filt, monitor, None)
            lib.oidnCommitFilter(filt)
            code, text = _error(lib, dev)
            if code == _ERROR_NONE:
                if cancel is not None and cancel():
                    raise DenoiseCancelled("denoising cancelled")
                lib.oidnExecuteFilter(filt)
                code, text = _error(lib, dev)
            if code == _ERROR_CANCELLED:
                raise DenoiseCancelled("denoising cancelled")
            if code != _ERROR_NONE:
                raise DenoiseError(f"Open Image Denoise failed {what} ({w}x{h}): {text}")

        def new_filter():
            filt = lib.oidnNewFilter(dev, b"RT")
            if not filt:
                raise DenoiseError("Open Image Denoise: no RT filter ({})".format(_error(lib, dev)[1]))
            filters.append(filt)
            return filt

        fake = None
        try:
            _error(lib, dev)  # (clear anything left from an earlier call on this thread)
            if prefilter == 'ACCURATE':
                for name, aux in guides:  # each guide denoised on its own, in place (a copy)
                    filt = new_filter()
                    _set_image(lib, filt, name, aux)
                    _set_image(lib, filt, b"output", aux)
                    run(filt, f"prefiltering the {name.decode()}")
            for color, use_albedo in colors:
                filt = new_filter()
                _set_image(lib, filt, b"color", color)
                _set_image(lib, filt, b"output", color)  # in place, as Cycles
                for name, aux in guides:
                    if name == b"albedo" and not use_albedo:
                        if fake is None:  # (not prefiltered: it is clean)
                            fake = np.full((h, w, 3), FAKE_ALBEDO, np.float32)
                        aux = fake
                    _set_image(lib, filt, name, aux)
                lib.oidnSetFilterBool(filt, b"hdr", True)
                lib.oidnSetFilterBool(filt, b"cleanAux", prefilter in ('NONE', 'ACCURATE'))
                run(filt, "denoising")
        except DenoiseCancelled:
            for (color, _), before in zip(colors, saved):
                color[...] = before
            raise
        finally:
            for filt in filters:
                lib.oidnReleaseFilter(filt)
    return time.perf_counter() - t0


def settings(props, viewport=False):
    """{input_passes, prefilter, quality} of Pathlight's scene settings (render or viewport),
    or None when denoising is off."""
    prefix = "preview_denoising_" if viewport else "denoising_"
    if not getattr(props, "use_preview_denoising" if viewport else "use_denoising", False):
        return None
    return {"input_passes": getattr(props, prefix + "input_passes"),
            "prefilter": getattr(props, prefix + "prefilter"),
            "quality": getattr(props, prefix + "quality")}


def denoise_film(film, film_pass, input_passes='RGB_ALBEDO_NORMAL', prefilter='ACCURATE', quality='HIGH',
                 cancel=None, catcher=None, use_albedo=True):
    """A denoised copy of `film` ((H, W, 4) float32, RGBA; alpha kept) with the guides that
    `input_passes` names read through film_pass(name) (a core Session's film_pass). catcher:
    how the film composes Combined with shadow catchers (CATCHER_MODES; None: as rendered). With
    a catcher in the scene (film_pass has the Shadow Catcher Matte), as Cycles: the matte is
    denoised with the guides, the Shadow Catcher pass with the normal and a 0.5 albedo, and
    Combined composed again from both (and the noisy Env: Cycles does not denoise the
    background); without one, `film` itself (use_albedo False: with a constant 0.5 albedo, as
    Cycles denoises a Shadow Catcher pass: a Shadow bake). Returns (image, seconds, passes):
    passes {"Shadow Catcher": denoised (H, W, 3)} where a catcher was, else {}."""
    guides = [film_pass(name) for name in aux_passes(input_passes)]
    planes = _catcher_planes(film_pass, catcher) if catcher is not None else None
    if planes is None:
        image = np.array(film, np.float32, order="C", copy=True)
        if use_albedo:
            seconds = denoise(image, *guides, prefilter=prefilter, quality=quality, cancel=cancel)
        else:
            seconds = denoise_many([(image, False)], *guides, prefilter=prefilter, quality=quality, cancel=cancel)
        return image, seconds, {}
    matte, shadow, env = planes
    seconds = denoise_many([(matte, True), (shadow, False)], *guides, prefilter=prefilter, quality=quality,
                           cancel=cancel)
    return compose_catcher(matte, shadow, env, catcher), seconds, {SHADOW_CATCHER: shadow}


def catcher_mode(passes, film_transparent):
    """How the core composes Combined with catchers (session.cpp): CATCHER_MODES' entry for a
    render of `passes` (names) on a transparent film or not."""
    if SHADOW_CATCHER in passes:
        return 'MATTE'
    return 'APPROXIMATE' if film_transparent else 'OVER_BACKGROUND'


def catcher_pass_names(catcher):
    """The film passes denoise_film reads for shadow catchers in `catcher` mode."""
    return [MATTE, SHADOW_CATCHER] + ([ENV] if catcher == 'OVER_BACKGROUND' else [])


def _catcher_planes(film_pass, catcher):
    """(matte (H, W, 4), shadow catcher (H, W, 3), env (H, W, 3) or None) as writable copies,
    or None when the film has no catcher planes (no catcher in the scene)."""
    if catcher not in CATCHER_MODES:
        raise ValueError(f"catcher {catcher!r}: one of {CATCHER_MODES} or None")
    try:
        matte = film_pass(MATTE)
    except (ValueError, KeyError):  # (the core: not kept; a dict of passes read earlier)
        return None
    matte = np.array(matte, np.float32, order="C", copy=True)
    shadow = np.array(film_pass(SHADOW_CATCHER), np.float32, order="C", copy=True)
    env = np.asarray(film_pass(ENV), np.float32) if catcher == 'OVER_BACKGROUND' else None
    return matte, shadow, env


def compose_catcher(matte, shadow, env, catcher):
    """Combined as the core's Film::catcher_combined reads it (Cycles' PassAccessor with
    film_calculate_shadow_catcher_matte_with_shadow): the matte's colour under its alpha
    ('MATTE'); under the approximate alpha (1 - a)(1 - average(shadow)) + a ('APPROXIMATE');
    or that alpha-overed onto env with alpha 1 ('OVER_BACKGROUND'). float32 (H, W, 4)."""
    out = np.empty(matte.shape[:2] + (4,), np.float32)
    out[..., :3] = matte[..., :3]
    alpha = np.clip(matte[..., 3], np.float32(0), np.float32(1))
    out[..., 3] = alpha
    if catcher == 'MATTE':
        return out
    s = shadow[..., :3]
    avg = np.clip((s[..., 0] + s[..., 1] + s[..., 2]) * np.float32(1.0 / 3.0), np.float32(0), np.float32(1))
    alpha_matte = (np.float32(1) - alpha) * (np.float32(1) - avg) + alpha
    out[..., 3] = alpha_matte
    if catcher == 'OVER_BACKGROUND' and env is not None:
        out[..., :3] += env[..., :3] * (np.float32(1) - alpha_matte)[..., None]
        out[..., 3] = 1.0
    return out


def describe(opts):
    """A short human description of denoise settings (for log lines)."""
    inputs = {'RGB': "colour only", 'RGB_ALBEDO': "colour + albedo"}.get(opts["input_passes"],
                                                                         "colour + albedo + normal")
    return f"{inputs}, prefilter {opts['prefilter'].title()}, quality {opts['quality'].title()}"
