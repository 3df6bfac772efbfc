"""RenderEngine.view_update / view_draw: the Blender side of viewport rendering.

Everything that decides and renders is in viewport.py (tested headless); this module only
reads the region's view, feeds the ViewportSession and draws its film with the gpu module,
through the viewport's colour management (engine.bind_display_space_shader). It cannot be
tested headless (bpy has no 3D viewport and no GPU context there). Errors never escape into
Blender: they go to engine.report once and the viewport stays empty.
"""

import logging

import numpy as np

from .core import get_core
from .viewport import ViewportSession
from .viewport_camera import ViewCameraError, view_camera_params
from .viewport_update import describe_updates

log = logging.getLogger(__name__)

HALF_MAX = 65504.0  # largest finite half float: the texture is RGBA16F


def _session(engine):
    return getattr(engine, "_pathlight_viewport", None)


def _report_once(engine, msg):
    seen = getattr(engine, "_pathlight_reported", None)
    if seen is None:
        seen = engine._pathlight_reported = set()
    if msg not in seen:
        seen.add(msg)
        log.warning(msg)
        engine.report({'WARNING'}, f"Pathlight: {msg}")


def view_camera(engine, context):
    """(pc.Camera fields, width, height) of the region's view."""
    region, rv3d = context.region, context.region_data
    try:
        camera = view_camera_params(np.array(rv3d.view_matrix), np.array(rv3d.window_matrix),
                                    region.width, region.height, rv3d.is_perspective)
    except ViewCameraError as e:
        _report_once(engine, f"{e}; showing a perspective view instead")
        camera = None  # the scene camera
    return camera, region.width, region.height


def view_update(engine, context, depsgraph):
    try:
        vs = _session(engine)
        if vs is None:
            vs = ViewportSession(get_core(), lambda msg: _report_once(engine, msg))
            engine._pathlight_viewport = vs
            vs.set_view(*view_camera(engine, context))
            vs.sync(depsgraph)
        else:
            vs.sync(depsgraph, describe_updates(depsgraph.updates))
    except Exception as e:  # never into Blender's face; the viewport shows nothing
        log.exception("viewport update failed")
        engine.report({'ERROR'}, f"Pathlight viewport: {type(e).__name__}: {e}")


def view_draw(engine, context, depsgraph):
    vs = _session(engine)
    if vs is None:
        return
    try:
        vs.check_settings(depsgraph)
        vs.set_view(*view_camera(engine, context))
        more = vs.poll()
        shown = vs.display()
        if shown is not None:
            _draw(engine, depsgraph.scene, shown[0], context.region.width, context.region.height)
        if more:
            engine.tag_redraw()  # keep polling while the render refines
    except Exception as e:
        log.exception("viewport draw failed")
        engine.report({'ERROR'}, f"Pathlight viewport: {type(e).__name__}: {e}")


def _draw(engine, scene, film, width, height):
    import gpu
    from gpu_extras.presets import draw_texture_2d
    h, w = film.shape[:2]
    pixels = np.ascontiguousarray(np.clip(film, -HALF_MAX, HALF_MAX), np.float32).ravel()
    buf = gpu.types.Buffer('FLOAT', pixels.size, pixels)
    texture = gpu.types.GPUTexture((w, h), format='RGBA16F', data=buf)
    gpu.state.blend_set('ALPHA_PREMULT')
    engine.bind_display_space_shader(scene)
    draw_texture_2d(texture, (0, 0), width, height)  # a low-resolution film is stretched
    engine.unbind_display_space_shader()
    gpu.state.blend_set('NONE')


def free(engine):
    vs = _session(engine)
    if vs is not None:
        vs.free()
        engine._pathlight_viewport = None
