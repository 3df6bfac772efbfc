"""Baking (Render ▸ Bake, bpy.ops.object.bake) with Pathlight, as Cycles bakes
(docs/design/bake.md).

What Blender does around the engine (source/blender/render/intern/engine.cc and
editors/object/object_bake_api.cc, Blender 4.5): it finds the texels of the object's active
UV map (or of the selected objects, for Selected to Active, after its own cage rays), calls the
engine's `bake(depsgraph, obj, pass_type, pass_filter, width, height)` once per target image,
and hands it a render result whose layer has "BakePrimitive" (per texel: u, v and the loop
triangle of the evaluated mesh as the bits of an int, -1 where the texel is not this object's)
and "BakeDifferential" (du/dx, du/dy, dv/dx, dv/dy). The engine writes "Combined" (RGBA) and
ends the result; Blender copies this object's texels into the image, converts Normal from world
space to tangent or object space itself, adds the margins and saves. Blender's u weights the
triangle's first corner and v its second (Cycles converts them the same way,
init_from_bake.h): Pathlight's b1 = v, b2 = 1 - u - v.

Without a `bake` callback Blender refuses with "Current render engine does not support
baking" (RE_bake_has_engine).
"""

import dataclasses
import logging
import threading
import time

import numpy as np

from .core import get_core
from .export import ExportCancelled, ExportError, export_scene
from .export.view_layer import layer_settings
from .export.world import warn_open_world_volume

log = logging.getLogger(__name__)

# Blender's eBakePassFilter bits (DNA_scene_types.h).
FILTER_EMIT = 1 << 1
FILTER_DIFFUSE = 1 << 2
FILTER_GLOSSY = 1 << 3
FILTER_TRANSMISSION = 1 << 4
FILTER_SUBSURFACE = 1 << 5
FILTER_DIRECT = 1 << 6
FILTER_INDIRECT = 1 << 7
FILTER_COLOR = 1 << 8

# Light components of Combined by filter bit: (direct pass, indirect pass).
COMPONENTS = ((FILTER_DIFFUSE, "DiffDir", "DiffInd", "DiffCol"),
              (FILTER_GLOSSY, "GlossDir", "GlossInd", "GlossCol"),
              (FILTER_TRANSMISSION, "TransDir", "TransInd", "TransCol"))
KIND_PASSES = {"DIFFUSE": COMPONENTS[0], "GLOSSY": COMPONENTS[1], "TRANSMISSION": COMPONENTS[2]}
ALL_COMBINED = FILTER_EMIT | FILTER_DIFFUSE | FILTER_GLOSSY | FILTER_TRANSMISSION | FILTER_DIRECT | FILTER_INDIRECT

# Bake types whose value is a render pass of the texel's path (the pass Cycles' bake_setup_pass
# names), and the data bakes read off the point itself.
DATA_PASSES = {"POSITION": "Position", "NORMAL": "Normal", "UV": "UV", "EMIT": "Emit", "AO": "AO"}


def blank_texel(pass_type):
    """What Cycles 4.5 writes into a texel of no triangle (Blender copies those too), as
    measured: transparent black for Combined and the light components and colours (their alpha
    is Combined's), opaque black for the data passes and AO, opaque white for Shadow."""
    if pass_type == "SHADOW":
        return (1.0, 1.0, 1.0, 1.0)
    if pass_type == "COMBINED" or pass_type in KIND_PASSES:
        return (0.0, 0.0, 0.0, 0.0)
    return (0.0, 0.0, 0.0, 1.0)


# The bakes Cycles denoises (Pass::get_info's support_denoise: PASS_COMBINED, and
# PASS_SHADOW_CATCHER for a Shadow bake), to image textures only (sync_integrator: "No denoising
# support for vertex color baking"). Checked in this bpy's Cycles: Combined and Shadow bakes
# change with Denoise on, Diffuse, Glossy and AO do not.
DENOISED_BAKES = ("COMBINED", "SHADOW")


def bake_denoiser(scene, pass_type, view_layer=None):
    """The denoise settings (denoise.settings) for a bake of `pass_type`, or None where Cycles
    would not denoise it (also where the view layer's Denoising is off)."""
    from . import denoise as oidn
    from .session import layer_denoising
    opts = oidn.settings(scene.pathlight)
    if opts is None or pass_type not in DENOISED_BAKES:
        return None
    if view_layer is not None and not layer_denoising(view_layer):
        return None
    if getattr(scene.render.bake, "target", 'IMAGE_TEXTURES') != 'IMAGE_TEXTURES':
        return None
    # The Shadow bake is the Shadow Catcher pass: a 0.5 albedo, as Cycles denoises that pass.
    return dict(opts, use_albedo=pass_type != "SHADOW")


class BakeError(Exception):
    """A bake Pathlight cannot do: reported as an error, the image is left alone."""


def plan(pass_type, pass_filter):
    """What a bake of `pass_type` (Blender's name) with `pass_filter` (eBakePassFilter bits)
    takes from a Pathlight render: (mode, passes to render, combine) where mode is the core's
    bake mode and combine(film, read) makes the RGBA result from the film's Combined (H, W, 4)
    and read(name) (a pass, (H, W, channels)). Raises BakeError for what is not supported."""
    f = int(pass_filter)
    direct, indirect, color = bool(f & FILTER_DIRECT), bool(f & FILTER_INDIRECT), bool(f & FILTER_COLOR)

    def rgb(v):
        out = np.ones(v.shape[:2] + (4,), np.float32)
        out[..., :3] = v[..., :3] if v.shape[-1] >= 3 else v[..., :1]
        return out

    if pass_type in DATA_PASSES:
        name = DATA_PASSES[pass_type]
        return "surface", [name], lambda film, read: rgb(read(name))
    if pass_type == "ROUGHNESS":
        return "roughness", [], lambda film, read: rgb(film)
    if pass_type == "ENVIRONMENT":
        return "environment", [], lambda film, read: rgb(film)
    if pass_type == "SHADOW":
        return "surface", ["Shadow Catcher"], lambda film, read: rgb(read("Shadow Catcher"))
    if pass_type in KIND_PASSES:
        _, d, i, c = KIND_PASSES[pass_type]
        if not direct and not indirect:  # Cycles' PASS_*_COLOR
            return "surface", [c], lambda film, read: rgb(read(c))
        wanted = [d] * direct + [i] * indirect

        def light(film, read):
            col = read(c)
            raw = sum(read(p) * col for p in wanted)  # (the film reads components divided by col)
            if not color:  # Cycles divides by the colour unless the Color filter is on
                raw = np.divide(raw, col, out=np.zeros_like(raw), where=col != 0)
            return rgb(raw)
        return "surface", wanted + [c], light
    if pass_type == "COMBINED":
        if not (f & FILTER_EMIT) and not ((direct or indirect) and f & (FILTER_DIFFUSE | FILTER_GLOSSY | FILTER_TRANSMISSION)):
            raise BakeError("Combined bake needs Emit, or Diffuse, Glossy or Transmission with Direct or Indirect")
        if f & ALL_COMBINED == ALL_COMBINED:
            return "surface", [], lambda film, read: film.copy()
        # A part of the light: the sum of the components asked for (read undivided), the
        # volumes' by direct / indirect, and the emission seen on the surface.
        names = []
        for bit, d, i, c in COMPONENTS:
            if f & bit:
                names += [(d, c)] * direct + [(i, c)] * indirect
        volume = ["VolumeDir"] * direct + ["VolumeInd"] * indirect
        emit = ["Emit"] if f & FILTER_EMIT else []

        def combined(film, read):
            out = np.zeros(film.shape[:2] + (3,), np.float32)
            for p, c in names:
                out += read(p) * read(c)
            for p in volume + emit:
                out += read(p)
            res = film.copy()
            res[..., :3] = out
            return res
        return "surface", sorted({n for pc in names for n in pc} | set(volume) | set(emit)), combined
    raise BakeError(f"bake type {pass_type} is not supported by Pathlight")


def barycentrics(primitive, differential):
    """Blender's BakePrimitive (N, 3: u, v, triangle bits) and BakeDifferential (N, 4) ->
    (triangle int32 (N,), bary float32 (N, 2) in Pathlight's b1, b2, differentials float32
    (N, 4): db1/dx, db1/dy, db2/dx, db2/dy). Blender's u weights the first corner, v the
    second: b1 = v, b2 = 1 - u - v."""
    tri = np.ascontiguousarray(primitive[:, 2]).view(np.int32).copy()
    u = primitive[:, 0].astype(np.float32)
    v = primitive[:, 1].astype(np.float32)
    empty = tri < 0
    u[empty] = v[empty] = 0.0
    bary = np.stack([v, np.float32(1.0) - u - v], axis=1).astype(np.float32)
    d = differential.astype(np.float32).copy()
    d[empty] = 0.0
    dudx, dudy, dvdx, dvdy = d[:, 0], d[:, 1], d[:, 2], d[:, 3]
    diff = np.stack([dvdx, dvdy, -dudx - dvdx, -dudy - dvdy], axis=1).astype(np.float32)
    bad = ~np.isfinite(bary).all(axis=1) | ~np.isfinite(diff).all(axis=1)
    tri[bad & ~empty] = -1  # (Blender never writes these; refuse nothing, bake nothing there)
    bary[bad] = 0.0
    diff[bad] = 0.0
    tri[empty] = -1
    return np.ascontiguousarray(tri), np.ascontiguousarray(bary), np.ascontiguousarray(diff)


def find_instance(data, name):
    """The core instance index (to_core's add_instance order) of the object called `name`
    (not an instance made by an instancer), and its MeshData and matrix index; None if the
    export has no such object."""
    index = 0
    for mesh in data.meshes:
        owners = getattr(mesh, "owners", None) or []
        for k in range(len(mesh.matrices)):
            if k < len(owners) and owners[k][0] == name and not owners[k][1]:
                return index, mesh, k
            index += 1
    return None


def _read_pass(result_layer, name, channels, n):
    rp = result_layer.passes.get(name)
    if rp is None:
        return None
    out = np.empty(n * channels, np.float32)
    rp.rect.foreach_get(out)
    return out.reshape(n, channels)


_bake_id = 0


def bake(engine, depsgraph, obj, pass_type, pass_filter, width, height):
    """RenderEngine.bake: never raises; errors go to engine.report (Blender then fails the
    bake operator with them)."""
    from .session import _commit, _warner, render_settings
    from .scene_writer import set_build_options, to_core
    global _bake_id
    warn = _warner(engine)
    # A layer name of its own per image: Blender finds the image a result belongs to by it
    # (render_result_to_bake; Cycles names them "bake_%d" alike), so with several target images
    # each gets its own texels (with the default layer name, bpy 4.5 crashed in the
    # two-material test).
    _bake_id += 1
    result = engine.begin_result(0, 0, width, height, layer=f"pathlight_bake_{_bake_id}")
    filled = False
    try:
        layer = result.layers[0]
        n = width * height
        primitive = _read_pass(layer, "BakePrimitive", 3, n)
        differential = _read_pass(layer, "BakeDifferential", 4, n)
        if primitive is None or differential is None:
            raise BakeError("Blender gave no BakePrimitive / BakeDifferential pass (a Blender older than 4.2?)")
        mode, passes, combine = plan(pass_type, pass_filter)
        from_camera = getattr(depsgraph.scene.render.bake, "view_from", "ABOVE_SURFACE") == 'ACTIVE_CAMERA'
        if from_camera and depsgraph.scene.camera is None:
            raise BakeError("View From 'Active Camera' needs a scene camera")
        tri, bary, diff = barycentrics(primitive, differential)
        pc = get_core()
        scene = depsgraph.scene
        try:
            # Surfaces always on in a bake, as Cycles (nothing to bake to otherwise).
            layer_filter = dataclasses.replace(layer_settings(depsgraph), use_solid=True)
            data = export_scene(depsgraph, warn, None, need_camera=False, uv_pass=pass_type == "UV",
                                should_stop=engine.test_break, layer=layer_filter)
        except ExportCancelled:
            return
        found = find_instance(data, obj.name)
        if found is None:
            raise BakeError(f"object '{obj.name}' was not exported (hidden from renders, or no faces)")
        instance, mesh, k = found
        if getattr(mesh, "subdivision", None):
            raise BakeError(f"object '{obj.name}' uses adaptive subdivision: its diced triangles are not the "
                            "mesh Blender bakes; apply or disable the subdivision to bake it")
        if pass_type == "SHADOW":  # Cycles: the object as a shadow catcher for this bake
            info = list(mesh.infos[k])
            info[5] = True
            mesh.infos[k] = tuple(info)
        # (No motion blur in a bake: the frame's geometry, as Cycles' bake rays at the shutter's
        # middle see it for still objects.)
        core_scene = to_core(pc, data, warn)
        settings = render_settings(pc, scene, warn)
        settings.width, settings.height = width, height
        for name in ("border_x", "border_y", "border_width", "border_height"):
            setattr(settings, name, 0)
        settings.film_transparent = True  # Cycles: "Always use transparent background for baking"
        settings.debug_view = "none"
        settings.passes = list(passes)
        denoiser = bake_denoiser(scene, pass_type, depsgraph.view_layer)
        if denoiser is not None:  # its guides, at the baked points as Cycles writes them
            from .denoise import aux_passes
            settings.passes += [n for n in aux_passes(denoiser["input_passes"]) if n not in settings.passes]
        if pass_type == "UV":
            if "" in data.uv_sets.names:
                settings.uv_pass_set = data.uv_sets.names.index("")
        set_build_options(core_scene, spatial_splits=scene.pathlight.use_spatial_splits,
                          light_tree=scene.pathlight.light_tree.lower())
        if not _commit(engine, core_scene, settings.threads, scene.pathlight.time_limit):
            return
        warn_open_world_volume(core_scene.stats(), scene.world, warn)
        if pass_type == "COMBINED" and not int(pass_filter) & FILTER_EMIT and core_scene.stats().get("emissive_triangles", 0):
            # Measured (docs/design/bake.md): Cycles then drops the light of emitting meshes too.
            warn("Combined bake without Emit: Pathlight keeps the light emitting meshes cast on the object "
                 "(Cycles leaves it out)")
        sess = pc.Session(core_scene, settings,
                          bake={"instance": instance, "triangle": tri, "bary": bary, "differentials": diff,
                                "mode": mode, "view_from_camera": from_camera})
        _run(engine, sess)
        film = sess.film().reshape(n, 4)
        image = combine(film[:, None, :], lambda name: sess.film_pass(name).reshape(n, 1, -1))
        image = image.reshape(n, 4).astype(np.float32)
        # Texels of no triangle: Blender copies them too (its blank texels have object id 0,
        # primitive -1), so they get what Cycles gives them.
        image[tri < 0] = blank_texel(pass_type)
        if denoiser is not None:  # texel space, blank texels and all, as Cycles' bake buffer
            image = _denoise(engine, sess, image.reshape(height, width, 4), denoiser, warn).reshape(n, 4)
        channels = int(layer.passes["Combined"].channels)
        if channels < 4:  # (Blender's bake targets are RGBA; keep what the pass holds)
            image = image[:, :channels]
        layer.passes["Combined"].rect.foreach_set(np.ascontiguousarray(image).ravel())
        filled = True
    except BakeError as e:
        engine.report({'ERROR'}, f"Pathlight: {e}")
    except (ExportError, RuntimeError, ValueError) as e:  # also the core's C++ exceptions
        engine.report({'ERROR'}, f"Pathlight: {e}")
    except Exception as e:  # a bug: keep the traceback in the log
        log.exception("bake failed")
        engine.report({'ERROR'}, f"Pathlight: {type(e).__name__}: {e}")
    finally:
        # Only a filled result reaches the image: a failed bake leaves it as it was.
        engine.end_result(result, cancel=not filled)


def _denoise(engine, sess, image, opts, warn):
    """The bake's RGBA (H, W, 4) denoised with the render's denoiser (session._denoised: Esc,
    a missing library or a failure keep it as it is, with a warning)."""
    from .session import _denoised
    out = _denoised(engine, sess, np.ascontiguousarray(image), opts, warn, what="bake")
    return image if out is None else out[0]


def _run(engine, sess):
    """Runs the bake's session to its end, cancelled by Esc."""
    sess.start()
    while not sess.wait(0.25):
        info = sess.progress()
        engine.update_progress(info["samples_done"] / max(info["samples_total"], 1))
        if engine.test_break():
            sess.cancel()
    engine.update_progress(1.0)
