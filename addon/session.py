"""Final-render driver: export the scene, run a core Session, stream its film into the result."""

import logging
import time

import bpy

from . import render_cache
from .core import get_core
from .export import ExportError, export_scene, to_core

log = logging.getLogger(__name__)

_progress_listener = None
PREVIEW_SAMPLES = 32  # material preview thumbnails


def set_progress_listener(fn):
    """Call fn(info) at each progress update of a render, with info = {samples_done,
    samples_total, elapsed_s, eta_s (None if unknown)}; a truthy return cancels the render
    (like Esc in Blender). None removes the listener. Used by build.py's render command."""
    global _progress_listener
    _progress_listener = fn


def render_size(scene):
    r = scene.render
    return (r.resolution_x * r.resolution_percentage // 100,
            r.resolution_y * r.resolution_percentage // 100)


def render_settings(pc, scene):
    props = scene.pathlight
    st = pc.RenderSettings()
    st.width, st.height = render_size(scene)
    st.samples = props.samples
    st.time_limit = props.time_limit
    st.max_bounces = props.max_bounces
    st.seed = render_seed(scene)
    st.use_nee = props.use_nee
    st.threads = scene.render.threads  # the detected count in AUTO mode
    if hasattr(st, "sample_offset"):
        st.sample_offset = getattr(props, "sample_offset", 0)
    # Issue 4 settings; hasattr keeps older core builds working (they render without them).
    optional = {
        "sampler": props.sampler.lower(),
        "adaptive_threshold": props.adaptive_threshold if props.use_adaptive_sampling else 0.0,
        "adaptive_min_samples": props.adaptive_min_samples,
        "diffuse_bounces": props.diffuse_bounces,
        "glossy_bounces": props.glossy_bounces,
        "transmission_bounces": props.transmission_bounces,
    }
    for name, value in optional.items():
        if hasattr(st, name):
            setattr(st, name, value)
    return st


def render_seed(scene):
    """The seed of this frame: with use_animated_seed the frame number is added, so that each
    frame of an animation gets different noise (kept within the core's 32-bit range)."""
    props = scene.pathlight
    if not props.use_animated_seed:
        return props.seed
    return (props.seed + scene.frame_current) % (1 << 31)


def render(engine, depsgraph):
    """RenderEngine.render: never raises; errors go to engine.report."""
    warn = _warner(engine)
    try:
        pc = get_core()
        scene = depsgraph.scene
        cache = None if engine.is_preview else render_cache.MESH_CACHE
        core_scene = to_core(pc, export_scene(depsgraph, warn, cache), warn)
        if cache is not None and cache.previous is not None:
            engine.update_stats("", "Pathlight | meshes: {hits} cached, {misses} exported"
                                .format(**cache.previous))
        settings = render_settings(pc, scene)
        if engine.is_preview:  # material thumbnails: small and quick
            settings.samples = min(settings.samples, PREVIEW_SAMPLES)
            if hasattr(settings, "sample_offset"):
                settings.sample_offset = 0
        sess = pc.Session(core_scene, settings)
        dropped = core_scene.stats().get("dropped_triangles", 0)
        if dropped:
            warn(f"{dropped} degenerate triangle(s) skipped")
        done = _run(engine, sess, *render_size(scene), time_limit=scene.pathlight.time_limit)
        _stamp(engine, getattr(settings, "sample_offset", 0), done)
    except (ExportError, RuntimeError, ValueError) as e:  # also the core's C++ exceptions
        engine.report({'ERROR'}, f"Pathlight: {e}")
    except Exception as e:  # a bug: keep the traceback in the log, not in Blender's face
        log.exception("render failed")
        engine.report({'ERROR'}, f"Pathlight: {type(e).__name__}: {e}")


def _warner(engine):
    seen = set()

    def warn(msg):
        if msg not in seen:
            seen.add(msg)
            log.warning(msg)
            engine.report({'WARNING'}, msg)
    return warn


def _run(engine, sess, width, height, time_limit):
    """Streams the session's film into the render result; returns the samples done."""
    result = engine.begin_result(0, 0, width, height)
    info = {"samples_done": 0}
    try:
        combined = result.layers[0].passes["Combined"]
        sess.start()
        shown = -1
        stats_at = -1.0
        while True:
            finished = sess.wait(0.25)
            info = _progress_info(sess.progress(), time_limit)
            if info["samples_done"] != shown or finished:
                # film(): float32 (H, W, 4), row 0 = bottom, which is also Blender's order.
                combined.rect.foreach_set(sess.film().ravel())  # ~400x faster than `rect = `
                engine.update_result(result)
                shown = info["samples_done"]
            engine.update_progress(info["samples_done"] / max(info["samples_total"], 1))
            listener = _progress_listener
            # In background mode Blender prints each stats line to stdout: that is the
            # terminal progress, about once a second, unless a listener shows its own.
            now = time.monotonic()
            if not bpy.app.background or (listener is None and (
                    finished or now - stats_at >= 1.0)):
                engine.update_stats("", _status_line(info, sess))
                stats_at = now
            cancel = listener is not None and listener(info)  # also sees the final state
            if finished:
                break
            if cancel or engine.test_break():
                sess.cancel()
    finally:
        if not sess.is_finished():  # an exception above: stop the worker threads
            sess.cancel()
            sess.wait(5.0)
        engine.end_result(result)
    return info["samples_done"]


def _stamp(engine, sample_offset, samples):
    """Sample range of the render as image metadata (EXR header attributes, PNG text):
    `python3 build.py merge` weighs partial renders of one frame by it (docs/farm.md)."""
    try:
        result = engine.get_result()  # the whole frame's result (a tile's stamp is not saved)
        result.stamp_data_add_field("Pathlight Sample Offset", str(sample_offset))
        result.stamp_data_add_field("Pathlight Samples", str(samples))
    except (AttributeError, RuntimeError, TypeError, ReferenceError) as e:  # no metadata then
        log.warning("could not stamp the sample range: %s", e)


def _progress_info(progress, time_limit):
    done, total = progress["samples_done"], progress["samples_total"]
    elapsed = progress["elapsed_s"]
    eta = elapsed / done * (total - done) if done else None
    if time_limit > 0:
        left = max(time_limit - elapsed, 0.0)
        eta = left if eta is None else min(eta, left)
    return {"samples_done": done, "samples_total": total, "elapsed_s": elapsed, "eta_s": eta}


def _status_line(info, sess):
    parts = [f"Pathlight | Sample {info['samples_done']}/{info['samples_total']}",
             f"{info['elapsed_s']:.1f} s"]
    if info["eta_s"] is not None and info["samples_done"] < info["samples_total"]:
        parts.append(f"ETA {info['eta_s']:.1f} s")
    rays = sess.stats().get("rays_per_s")
    if rays:
        parts.append(f"{rays / 1e6:.1f} Mrays/s")
    return " | ".join(parts)
