"""RenderEngine.view_update / view_draw: the Blender side of viewport rendering.

Everything that decides and renders is in viewport.py; this module reads the region's view,
feeds the ViewportSession and draws its film with the gpu module. Errors never escape into
Blender: they go to engine.report once and the viewport stays empty.

Drawing, as Blender expects it from a render engine (and as Cycles' display driver does):
- The texture holds SCENE-LINEAR values, exactly the session's film. Blender's draw manager
  applies the scene's view transform, look and display device to the whole viewport after
  view_draw; `engine.bind_display_space_shader(scene)` only binds the builtin IMAGE shader
  (sampler "image" in slot 0, see rna_render.cc engine_bind_display_space_shader in Blender
  4.x), which is the shader draw_texture_2d draws with. Converting to sRGB here would apply
  the display transform twice.
- Row 0 of the film is the bottom row, as in a GPU texture and in draw_texture_2d's
  coordinates (origin at the region's bottom-left): no flip.
- RGBA16F (half float, what Cycles uses for display): values are clamped to +-65504 so that
  bright pixels stay bright instead of turning into inf. Alpha is premultiplied (the film's
  alpha is coverage), hence blend 'ALPHA_PREMULT'.
- The pixels reach gpu.types.Buffer as one contiguous float32 numpy array, reused from draw
  to draw. Buffer wraps an object with the buffer protocol without copying it and checks only
  its total length, not its element type (gpu_py_buffer.cc, pygpu_buffer__tp_new), so the
  array must be float32; a Python list would be converted item by item instead. The texture
  copies the data when it is created, so the array can be overwritten by the next draw.
texture_pixels() and draw_film() are tested headless (tests/blender/test_viewport_draw.py, with a
recording stand-in for the gpu module: bpy has no GPU context in background mode).
"""

import logging

import numpy as np

from .core import get_core
from .viewport import ViewportSession
from .viewport_camera import ViewCameraError, pano_view_params, view_camera_params
from .viewport_update import describe_updates

log = logging.getLogger(__name__)

HALF_MAX = 65504.0  # largest finite half float
TEXTURE_FORMAT = 'RGBA16F'


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
    """(pc.Camera fields, width, height) of the region's view (perspective or orthographic,
    free navigation or camera view)."""
    region, rv3d = context.region, context.region_data
    pano = _pano_camera_view(engine, context)
    if pano is not None:
        return pano, region.width, region.height
    try:
        camera = view_camera_params(np.array(rv3d.view_matrix), np.array(rv3d.window_matrix),
                                    region.width, region.height, rv3d.is_perspective)
    except ViewCameraError as e:
        _report_once(engine, f"{e}; showing the scene camera's view instead")
        camera = None  # the scene camera
    return camera, region.width, region.height


def _pano_camera_view(engine, context):
    """The scene camera's panorama mapped to the camera border when the region looks through a
    panoramic camera (as Cycles' viewport renders it), else None."""
    rv3d, scene = context.region_data, getattr(context, "scene", None)
    cam_obj = scene.camera if scene is not None else None
    if getattr(rv3d, "view_perspective", None) != 'CAMERA' or cam_obj is None or cam_obj.type != 'CAMERA':
        return None
    if cam_obj.data.type != 'PANO':
        return None
    from .export.camera import camera_params
    try:
        depsgraph = context.evaluated_depsgraph_get()
        fields = camera_params(scene, depsgraph, lambda msg: _report_once(engine, msg))
        cam_eval = cam_obj.evaluated_get(depsgraph)
        m = np.array(cam_eval.matrix_world, np.float64)
        m[:3, :3] /= np.linalg.norm(m[:3, :3], axis=0)
        frame = [(m @ np.array([*c, 1.0]))[:3] for c in cam_eval.data.view_frame(scene=scene)]
        r = scene.render
        aspect = (r.resolution_x * r.pixel_aspect_x) / (r.resolution_y * r.pixel_aspect_y)
        return pano_view_params(fields, frame, np.array(rv3d.view_matrix), np.array(rv3d.window_matrix),
                                context.region.width, context.region.height, aspect)
    except Exception as e:  # a perspective view of it is the fallback
        _report_once(engine, f"panoramic camera view: {e}; showing a perspective view instead")
        return None


def view_pass(context):
    """(render_pass, light group or AOV name) of the region's Render Pass selector
    (View3DShading.pathlight); Combined where the context has no 3D view shading."""
    shading = getattr(getattr(context, "space_data", None), "shading", None)
    settings = getattr(shading, "pathlight", None)
    if settings is None:
        return 'COMBINED', ""
    name = {'LIGHT_GROUP': settings.light_group, 'AOV': settings.aov_name}.get(settings.render_pass, "")
    return settings.render_pass, name


def view_update(engine, context, depsgraph):
    try:
        vs = _session(engine)
        if vs is None:
            vs = ViewportSession(get_core(), lambda msg: _report_once(engine, msg))
            engine._pathlight_viewport = vs
            vs.set_pass(*view_pass(context))
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
        vs.set_pass(*view_pass(context), depsgraph=depsgraph)
        vs.set_view(*view_camera(engine, context))
        more = vs.poll()
        shown = vs.display()
        if shown is not None:
            engine._pathlight_pixels = draw_film(engine, depsgraph.scene, shown[0],
                                                 context.region.width, context.region.height,
                                                 getattr(engine, "_pathlight_pixels", None))
        if more:
            engine.tag_redraw()  # keep polling while the render refines
    except Exception as e:
        log.exception("viewport draw failed")
        engine.report({'ERROR'}, f"Pathlight viewport: {type(e).__name__}: {e}")


def texture_pixels(film, out=None):
    """The flat float32 array to upload for `film` ((H, W, 4) float32 scene-linear RGBA, row 0
    at the bottom): the same values in the same order, clamped into the half-float range.
    Written into `out` (reused between draws) when it has the right size."""
    film = np.asarray(film)
    if film.ndim != 3 or film.shape[2] != 4:
        raise ValueError(f"film must be (H, W, 4), not {film.shape}")
    if out is None or out.size != film.size or out.dtype != np.float32:
        out = np.empty(film.size, np.float32)
    np.clip(film.reshape(-1), -HALF_MAX, HALF_MAX, out=out)
    return out


def draw_film(engine, scene, film, width, height, pixels=None):
    """Draws `film` over the region (width x height; a low-resolution film is stretched) as
    Blender's RenderEngine example and Cycles do. Returns the pixel array, for reuse."""
    import gpu
    from gpu_extras.presets import draw_texture_2d
    h, w = film.shape[:2]
    pixels = texture_pixels(film, pixels)
    buf = gpu.types.Buffer('FLOAT', pixels.size, pixels)
    texture = gpu.types.GPUTexture((w, h), format=TEXTURE_FORMAT, data=buf)
    gpu.state.blend_set('ALPHA_PREMULT')
    engine.bind_display_space_shader(scene)
    try:
        draw_texture_2d(texture, (0, 0), width, height)
    finally:
        engine.unbind_display_space_shader()
        gpu.state.blend_set('NONE')
    return pixels


def free(engine):
    vs = _session(engine)
    if vs is not None:
        vs.free()
        engine._pathlight_viewport = None
    engine._pathlight_pixels = None
