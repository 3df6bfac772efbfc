"""Final-render driver: export the scene, run a core Session, stream its film into the result."""

import json
import logging
import math
import threading
import time

import bpy
import numpy as np

from . import denoise as oidn
from . import render_cache
from .core import get_core
from .export import MAX_LIGHT_GROUPS, ExportCancelled, ExportError, export_scene
from .export.motion import add_motion, add_pass_motion
from .export.view_layer import layer_settings, lit_world
from .export.world import warn_open_world_volume
from .export.camera import camera_params
from .export.views import view_camera, view_motion, view_names, view_seed
from .scene_writer import core_camera, set_build_options, to_core

log = logging.getLogger(__name__)

_progress_listener = None
PREVIEW_SAMPLES = 32  # material preview thumbnails


def set_progress_listener(fn):
    """Call fn(info) at each progress update of a render, with info = {samples_done,
    samples_total, elapsed_s, eta_s (None if unknown)}; a truthy return cancels the render
    (like Esc in Blender). While the scene is exported and its BVH built the info has
    stage="export" or "build" and no samples. None removes the listener. Used by build.py's render command."""
    global _progress_listener
    _progress_listener = fn


def render_size(scene):
    r = scene.render
    return (r.resolution_x * r.resolution_percentage // 100,
            r.resolution_y * r.resolution_percentage // 100)


# Render passes besides Combined: (name, channels, channel ids, compositor socket type, whether
# the view layer asks for it). Names and layouts are Cycles' (Depth, Normal, ... are also
# Blender's built-in pass names), so compositor sockets and EXR layers line up; the core uses
# the same names. "Sample Count" is the raw number of samples of each pixel (Cycles' "Debug
# Sample Count" is normalised instead, hence the different name).
PASSES = (
    ("Depth", 1, "Z", 'VALUE', lambda sc, vl: vl.use_pass_z),
    ("Normal", 3, "XYZ", 'VECTOR', lambda sc, vl: vl.use_pass_normal),
    ("Position", 3, "XYZ", 'VECTOR', lambda sc, vl: vl.use_pass_position),
    ("Emit", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_emit),
    ("Env", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_environment),
    ("Denoising Normal", 3, "XYZ", 'VECTOR', lambda sc, vl: vl.pathlight.use_pass_denoising_data),
    ("Denoising Albedo", 3, "RGB", 'COLOR', lambda sc, vl: vl.pathlight.use_pass_denoising_data),
    ("Sample Count", 1, "X", 'VALUE', lambda sc, vl: vl.pathlight.use_pass_sample_count),
    # Cycles' light components (divided by their colour, as Cycles does), Mist and AO.
    ("DiffDir", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_diffuse_direct),
    ("DiffInd", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_diffuse_indirect),
    ("DiffCol", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_diffuse_color),
    ("GlossDir", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_glossy_direct),
    ("GlossInd", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_glossy_indirect),
    ("GlossCol", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_glossy_color),
    ("TransDir", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_transmission_direct),
    ("TransInd", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_transmission_indirect),
    ("TransCol", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_transmission_color),
    ("VolumeDir", 3, "RGB", 'COLOR', lambda sc, vl: _volume_pass(vl, "use_pass_volume_direct")),
    ("VolumeInd", 3, "RGB", 'COLOR', lambda sc, vl: _volume_pass(vl, "use_pass_volume_indirect")),
    ("Mist", 1, "Z", 'VALUE', lambda sc, vl: vl.use_pass_mist),
    ("AO", 3, "RGB", 'COLOR', lambda sc, vl: vl.use_pass_ambient_occlusion),
    ("IndexOB", 1, "X", 'VALUE', lambda sc, vl: vl.use_pass_object_index),
    ("IndexMA", 1, "X", 'VALUE', lambda sc, vl: vl.use_pass_material_index),
    # The first surface's active render UV map (U, V, and 1 where there is one), and Cycles'
    # motion vectors to the previous and next frames in pixels (only without motion blur).
    ("UV", 3, "UVA", 'VECTOR', lambda sc, vl: vl.use_pass_uv),
    ("Vector", 4, "XYZW", 'VECTOR', lambda sc, vl: vl.use_pass_vector),
    ("Shadow Catcher", 3, "RGB", 'COLOR', lambda sc, vl: _volume_pass(vl, "use_pass_shadow_catcher")),
    ("BVH Nodes", 1, "X", 'VALUE', lambda sc, vl: sc.pathlight.debug_view == 'BVH'),
    ("BVH Triangles", 1, "X", 'VALUE', lambda sc, vl: sc.pathlight.debug_view == 'BVH'),
)


def _volume_pass(view_layer, prop):
    """Volume Direct / Indirect and Shadow Catcher: Blender's view layer has no switch for them,
    Cycles' settings (view_layer.cycles) and Pathlight's own do."""
    cycles = getattr(view_layer, "cycles", None)
    return bool(getattr(view_layer.pathlight, prop) or (cycles is not None and getattr(cycles, prop, False)))


# world.mist_settings.falloff as Cycles' exponent
MIST_FALLOFF = {'LINEAR': 1.0, 'QUADRATIC': 2.0, 'INVERSE_QUADRATIC': 0.5}


def enabled_passes(scene, view_layer):
    """The PASSES entries this view layer asks for."""
    return [p for p in PASSES if p[4](scene, view_layer)]


def shader_aovs(view_layer):
    """The view layer's shader AOVs as (name, channels, channel ids, socket type), in their
    order (the core's slots): COLOR as RGBA, VALUE as X, as Cycles. Blender marks AOVs whose
    name another pass or AOV has as not valid; those are left out, as Cycles does. At most
    MAX_SHADER_AOVS."""
    out = []
    for aov in getattr(view_layer, "aovs", ()):
        if not aov.is_valid or not aov.name:
            continue
        out.append((aov.name, 4, "RGBA", 'COLOR') if aov.type == 'COLOR' else (aov.name, 1, "X", 'VALUE'))
    return out[:MAX_SHADER_AOVS]


MAX_SHADER_AOVS = 16  # the core's kMaxShaderAovs


def light_group_passes(view_layer):
    """The view layer's light group passes as (name, channels, channel ids, socket type), in its
    order (the core's group indices), named and laid out as Cycles': "Combined_<group>", RGB."""
    from .export import view_layer_lightgroups
    return [("Combined_" + name, 3, "RGB", 'COLOR') for name in view_layer_lightgroups(view_layer)]


# Cryptomatte layers: (view-layer switch, Cycles' pass-name stem, the core's layer name).
CRYPTO_LAYERS = (
    ("use_pass_cryptomatte_object", "CryptoObject", "object"),
    ("use_pass_cryptomatte_material", "CryptoMaterial", "material"),
    ("use_pass_cryptomatte_asset", "CryptoAsset", "asset"),
)


def crypto_layers(view_layer):
    """The CRYPTO_LAYERS entries this view layer asks for."""
    return [c for c in CRYPTO_LAYERS if getattr(view_layer, c[0], False)]


def crypto_passes(view_layer):
    """PASSES-like entries of the Cryptomatte passes this view layer asks for, named and laid
    out as Cycles': CryptoObject00, 01, ... RGBA, two (id, coverage) pairs each, as many as
    its levels (pass_cryptomatte_depth, at most 16) need."""
    count = (min(16, int(view_layer.pass_cryptomatte_depth)) + 1) // 2
    return [(f"{stem}{i:02d}", 4, "rgba", 'COLOR', None)
            for _, stem, _ in crypto_layers(view_layer) for i in range(count)]


def update_render_passes(engine, scene, view_layer):
    """RenderEngine.update_render_passes: declares the passes, so the compositor shows sockets."""
    if scene is None or view_layer is None:
        return
    engine.register_pass(scene, view_layer, "Combined", 4, "RGBA", 'COLOR')
    for name, channels, chan_id, socket, _ in enabled_passes(scene, view_layer) + crypto_passes(view_layer):
        engine.register_pass(scene, view_layer, name, channels, chan_id, socket)
    for name, channels, chan_id, socket in shader_aovs(view_layer) + light_group_passes(view_layer):
        engine.register_pass(scene, view_layer, name, channels, chan_id, socket)
    for name, channels, chan_id in noisy_passes(scene, view_layer):
        engine.register_pass(scene, view_layer, name, channels, chan_id, 'COLOR')


NOISY_IMAGE = "Noisy Image"  # Cycles' pass: Combined before denoising
NOISY_SHADOW_CATCHER = "Noisy Shadow Catcher"  # and the Shadow Catcher pass before denoising


def layer_denoising(view_layer):
    """Cycles' View Layer ▸ Denoising: on unless Pathlight's switch or Cycles' own is off."""
    cycles = getattr(view_layer, "cycles", None)
    return bool(view_layer.pathlight.use_denoising and getattr(cycles, "use_denoising", True))


def noisy_image_pass(scene, view_layer):
    """Whether the view layer gets Cycles' Noisy Image pass: whenever Denoise is on for it
    (Cycles' engine.py list_render_passes, with or without the Denoising Data passes)."""
    return bool(scene.pathlight.use_denoising and layer_denoising(view_layer))


def noisy_passes(scene, view_layer):
    """[(name, channels, channel ids)] of Cycles' noisy passes for this view layer: Noisy Image
    with Denoise on, and Noisy Shadow Catcher when the Shadow Catcher pass is on too."""
    if not noisy_image_pass(scene, view_layer):
        return []
    out = [(NOISY_IMAGE, 4, "RGBA")]
    if _volume_pass(view_layer, "use_pass_shadow_catcher"):
        out.append((NOISY_SHADOW_CATCHER, 3, "RGB"))
    return out


def partial_sample_range(props):
    """Whether this render is one piece of a frame split into sample ranges (docs/farm.md):
    a Sample Offset, or Frame Samples beyond this piece's end. Such pieces are not denoised."""
    return props.sample_offset > 0 or props.frame_samples > props.sample_offset + props.samples


def render_denoiser(scene, engine, warn, view_layer=None):
    """The final render's denoise settings ({input_passes, prefilter, quality}; None: none),
    with a log line where Denoise is on but this render is not denoised."""
    opts = oidn.settings(scene.pathlight)
    if opts is None or engine.is_preview:  # (material thumbnails: not denoised)
        return None
    if view_layer is not None and not layer_denoising(view_layer):  # (as Cycles' get_denoise_params)
        return None
    if scene.pathlight.debug_view == 'BVH':
        return None
    if partial_sample_range(scene.pathlight):
        log.info("Pathlight: Denoise is on, but this render is one piece of a split frame (Sample Offset / "
                 "Frame Samples): not denoised; denoise the merged frame")
        return None
    return opts


def _denoised(engine, sess, image, opts, warn, view="", what=""):
    """(Combined denoised (a new array; alpha kept), {pass: denoised}: the Shadow Catcher
    pass where the scene has catchers), or None with a warning when the library is missing or
    fails: the noisy image and passes stay. The filter runs on a worker thread while this one
    (Blender's) watches for Esc, which stops it (noisy image, log line)."""
    engine.update_stats("", "Pathlight | Denoising" + (f" view {view}" if view else "")
                        + (f" the {what}" if what else ""))
    stop = threading.Event()
    box = {}

    def work():
        try:
            box["out"] = oidn.denoise_film(image, sess.film_pass, cancel=stop.is_set, **opts)
        except BaseException as e:  # handed to the engine's thread below
            box["error"] = e

    worker = threading.Thread(target=work, name="pathlight-denoise", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(0.1)
        if not stop.is_set() and engine.test_break():
            stop.set()
    error = box.get("error")
    if isinstance(error, oidn.DenoiseCancelled):
        log.info("Pathlight: denoising cancelled; the image is not denoised")
        return None
    if isinstance(error, (oidn.DenoiseError, ValueError)):
        warn(f"Denoising failed, the image is not denoised: {error}")
        return None
    if error is not None:  # a bug: the render is still worth keeping, noisy
        log.error("denoising failed", exc_info=error)
        warn(f"Denoising failed, the image is not denoised: {type(error).__name__}: {error}")
        return None
    out, seconds, passes = box["out"]
    h, w = image.shape[:2]
    log.info("Pathlight: denoised %s%dx%d%s in %.2f s (Open Image Denoise: %s%s)", f"the {what} " if what else "",
             w, h, f" (view {view})" if view else "", seconds, oidn.describe(opts),
             "; the shadow catcher's matte and pass, Combined composed from them" if passes else "")
    return out, passes


def cryptomatte_metadata(pc, data, view_layer):
    """{field: value} of the render result's Cryptomatte metadata, as Cycles writes it: per layer
    "cryptomatte/<first 7 hex digits of the hash of '<view layer>.CryptoObject'>/" name, hash,
    conversion and manifest (JSON {name: "%08x" hash}) of the names in SceneData `data`."""
    from .export.material import cryptomatte_name
    objects, assets = set(), set()
    for entry in list(data.meshes) + list(getattr(data, "curves", [])) + list(getattr(data, "points", [])):
        for info in getattr(entry, "infos", []):
            if info is not None and len(info) > 4 and info[4] is not None:
                objects.add(info[4][0])
                assets.add(info[4][1])
    names = {"object": objects, "asset": assets,
             "material": {cryptomatte_name(m) for m in data.materials}}
    out = {}
    for _, stem, layer in crypto_layers(view_layer):
        layer_name = f"{view_layer.name}.{stem}"
        prefix = f"cryptomatte/{pc.cryptomatte_hash(layer_name):08x}"[:len("cryptomatte/") + 7] + "/"
        manifest = {n: f"{pc.cryptomatte_hash(n):08x}" for n in sorted(names[layer])}
        out[prefix + "name"] = layer_name
        out[prefix + "hash"] = "MurmurHash3_32"
        out[prefix + "conversion"] = "uint32_to_float32"
        out[prefix + "manifest"] = json.dumps(manifest, separators=(",", ":"), ensure_ascii=False)
    return out


def render_border(scene, warn=None):
    """The rendered rectangle (x, y, w, h) in pixels from the bottom-left of the full frame:
    the render border when it is on (Blender's own rounding: truncated fractions of the
    frame), else the whole frame."""
    width, height = render_size(scene)
    r = scene.render
    if not r.use_border:
        return 0, 0, width, height
    x0, x1 = int(r.border_min_x * width), int(r.border_max_x * width)
    y0, y1 = int(r.border_min_y * height), int(r.border_max_y * height)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, width), min(y1, height)
    if x1 - x0 < 1 or y1 - y0 < 1:
        if warn:
            warn("The render border is empty; rendering the whole frame")
        return 0, 0, width, height
    return x0, y0, x1 - x0, y1 - y0


_SCENE_WORLD = object()  # (render_settings' default: the scene's world)


def layer_samples(props, view_layer, warn=None):
    """(samples, pattern_samples) of a render of `view_layer` whose RenderSettings say
    (props.samples, the pattern's total), or None where the layer's Samples do not apply: Cycles'
    rule (blender_session.cpp), the layer's count (0: the scene's) replaces the frame's total
    under Layer Samples 'USE', only a smaller one under 'BOUNDED', never under 'IGNORE'. A farm
    piece (Sample Offset, Frame Samples) keeps its range cut at the layer's total, and its blue
    noise is laid out for that total; adaptive sampling and the time limit stay as they are."""
    mode = getattr(props, "use_layer_samples", 'USE')
    n = int(getattr(view_layer, "samples", 0) or 0)
    if mode == 'IGNORE' or n <= 0:
        return None
    offset = props.sample_offset
    total = props.frame_samples or (offset + props.samples)
    if mode == 'BOUNDED' and n >= total:
        return None
    if not partial_sample_range(props):
        return n, 0 if not props.frame_samples else n
    return max(0, min(offset + props.samples, n) - offset), n if props.frame_samples else 0


def fast_gi_settings(scene, viewport=False, world=_SCENE_WORLD):
    """Cycles' Fast GI as its BlenderSync gives it to its Integrator: ao_bounces (the viewport's
    or the final render's; only Replace uses them), the world's AO factor on Replace or Add
    (ao_factor / ao_additive_factor), nothing without Fast GI or a world. world: the view
    layer's (its World Override, as Cycles' sync_world reads the AO settings), default the scene's."""
    props = scene.pathlight
    world = scene.world if world is _SCENE_WORLD else world
    if not props.use_fast_gi or world is None:
        return {"ao_bounces": 0, "ao_factor": 0.0, "ao_additive_factor": 0.0}
    factor = world.light_settings.ao_factor
    replace = props.fast_gi_method == 'REPLACE'
    return {"ao_bounces": props.ao_bounces if viewport else props.ao_bounces_render,
            "ao_factor": factor if replace else 0.0,
            "ao_additive_factor": 0.0 if replace else factor}


def render_settings(pc, scene, warn=None, viewport=False, world=_SCENE_WORLD):
    """The core's RenderSettings of the scene. world: the view layer's world (World Override),
    which Fast GI and the AO distance read; the mist stays the scene world's (Cycles' sync_film)."""
    props = scene.pathlight
    st = pc.RenderSettings()
    st.width, st.height = render_size(scene)
    st.samples = props.samples
    st.time_limit = props.time_limit
    st.max_bounces = props.max_bounces
    st.seed = render_seed(scene)
    st.use_nee = props.use_nee
    st.threads = scene.render.threads  # the detected count in AUTO mode
    st.sample_offset = props.sample_offset
    optional = {
        "sampler": props.sampler.lower(),
        "adaptive_threshold": props.adaptive_threshold if props.use_adaptive_sampling else 0.0,
        "adaptive_min_samples": props.adaptive_min_samples,
        "diffuse_bounces": props.diffuse_bounces,
        "glossy_bounces": props.glossy_bounces,
        "transmission_bounces": props.transmission_bounces,
        "volume_bounces": props.volume_bounces,
        "transparent_bounces": props.transparent_bounces,
        "clamp_direct": clamp_limit(props.sample_clamp_direct, "Clamp Direct", warn),
        "clamp_indirect": clamp_limit(props.sample_clamp_indirect, "Clamp Indirect", warn),
        "filter_glossy": clamp_limit(props.blur_glossy, "Filter Glossy", warn),
        "caustics_reflective": props.caustics_reflective,
        "caustics_refractive": props.caustics_refractive,
        "filter_type": props.filter_type.lower(),
        "filter_width": props.filter_width,
    }
    optional.update(fast_gi_settings(scene, viewport, world))
    optional.update({
        "film_transparent": scene.render.film_transparent,
        "film_transparent_glass": props.film_transparent_glass,
        "film_transparent_roughness": props.film_transparent_roughness,
        "exposure": props.film_exposure,
        "debug_view": props.debug_view.lower(),
    })
    ao_world = scene.world if world is _SCENE_WORLD else world
    world = scene.world
    if world is not None:  # (no world: Cycles' defaults, which the core's are)
        mist = world.mist_settings
        optional.update(mist_start=mist.start, mist_depth=mist.depth,
                        mist_falloff=MIST_FALLOFF.get(mist.falloff, 2.0))
    if ao_world is not None:
        optional.update(ao_distance=ao_world.light_settings.distance)
    optional["force_general_kernel"] = props.use_general_kernel
    optional["guiding"] = props.use_guiding
    # Caustic light tracing (docs/design/sampling.md "Caustics by light tracing"); the core turns
    # it off where it cannot be combined exactly and says why (_report_caustics).
    # Automatic (the default) where not asked for explicitly: the core decides, silently.
    optional["caustic_light_paths"] = props.caustic_light_paths if props.use_caustic_light_paths else 0.0
    optional["caustic_light_paths_auto"] = props.caustic_light_paths_auto and not props.use_caustic_light_paths
    if props.use_guiding:
        # Caustic photons train the guide (docs/design/sampling.md, "Caustic photons"): on the
        # window room they cut the error at equal samples 1.2-1.5x, camera training alone did not.
        # A learnt probability per cell (at most 0.5), the cosine product and the directional
        # filter then lowered it further over 9 seeds (mean, median and all but the top 1 %;
        # "Learnt guide probability"). The Automatic caustic light paths stay on with guiding,
        # and where they run the core traces no caustic photons ("Guiding with caustic light
        # paths": ahead of guiding alone at equal time, about even with plain).
        optional.update(guiding_photons=1.0, guiding_caustics=True, guiding_photon_share=0.15,
                        guiding_learn_probability=True, guiding_cosine=True, guiding_filter=True)
    x, y, w, h = render_border(scene, warn)
    if (w, h) != (st.width, st.height):
        optional.update(border_x=x, border_y=y, border_width=w, border_height=h)
    optional.update(pixel_pattern_settings(props, warn))
    for name, value in optional.items():  # (the add-on and its core ship together)
        setattr(st, name, value)
    return st


def clamp_limit(value, label, warn=None):
    """A Clamping limit or Filter Glossy for the core: 0 (off) where it is negative or not finite
    (a property set from Python past its range), with a warning."""
    value = float(value)
    if math.isfinite(value) and value >= 0.0:
        return value
    if warn:
        warn(f"{label} is {value}; it must be a finite number >= 0: rendering without it (0)")
    return 0.0


def pixel_pattern_settings(props, warn, viewport=False):
    """RenderSettings.pixel_pattern and pattern_samples of the scene's Noise Pattern and Frame
    Samples. Automatic is Cycles' choice: blue noise, its First variant in the viewport."""
    pattern = props.pixel_pattern
    if pattern == 'AUTOMATIC':
        pattern = 'BLUE_NOISE_FIRST' if viewport else 'BLUE_NOISE'
    total = 0 if viewport else props.frame_samples
    if not viewport and not total and props.sample_offset > 0 and pattern != 'INDEPENDENT' and warn:
        # (a blue-noise pattern lays a pixel's samples out by the frame's total: farm pieces need it)
        warn(f"Sample Offset without Frame Samples: this piece's blue noise is laid out for "
             f"{props.sample_offset + props.samples} samples, so it merges with other pieces exactly only "
             f"if that is the frame's total; set Frame Samples to it")
    if total and total < props.sample_offset + props.samples:
        if warn and pattern != 'INDEPENDENT':
            warn(f"Frame Samples ({total}) is below Sample Offset + Samples "
                 f"({props.sample_offset + props.samples}); using the latter, so this piece's blue "
                 f"noise will not merge with the others' exactly")
        total = 0
    return {"pixel_pattern": pattern.lower(), "pattern_samples": total}


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
        cache = render_cache.cache_for(engine, depsgraph)  # first: it reads the depsgraph's updates
        pc = get_core()
        scene = depsgraph.scene
        view_layer = depsgraph.view_layer
        layer = layer_settings(depsgraph, engine.is_preview)  # overrides and filters
        # Filter ▸ Motion Blur: the layer's and the scene's (Cycles' view_layer.use_motion_blur).
        motion_blur = scene.render.use_motion_blur and layer.use_motion_blur
        t0 = time.monotonic()
        passes = enabled_passes(scene, view_layer)
        names = {p[0] for p in passes}
        aovs = [] if engine.is_preview else shader_aovs(view_layer)
        if len(getattr(view_layer, "aovs", ())) > len(aovs) and not engine.is_preview:
            dropped = [a.name for a in view_layer.aovs if a.name not in {x[0] for x in aovs}]
            warn(f"Shader AOV(s) {', '.join(map(repr, dropped))} left out (a name another pass has, "
                 f"or more than {MAX_SHADER_AOVS}); they stay empty")
        try:
            data = export_scene(depsgraph, warn, cache, should_stop=lambda: _stop_requested(
                engine, "export", time.monotonic() - t0, scene.pathlight.time_limit),
                uv_pass="UV" in names and not engine.is_preview,
                aovs=[(a[0], 'COLOR' if a[1] == 4 else 'VALUE') for a in aovs], layer=layer,
                cull_udim_tiles=True)  # (as Cycles' final renders: its viewport loads every tile)
        except ExportCancelled:
            log.info("render cancelled during the export")
            _empty_result(engine, scene, view_layer)
            return
        # Multiview (Output > Stereoscopy): each view's camera, read at this frame, before the
        # motion export moves through the frame (whose steps each view's camera takes too).
        views = view_names(engine, scene, view_layer.name)
        view_cams = {v: view_camera(engine, scene, depsgraph, v) for v in views if v}
        others = [c.camera.original for c in view_cams.values()]
        if motion_blur and not engine.is_preview:
            _add_motion_blur(engine, depsgraph, data, warn, others)
        elif "Vector" in names and not engine.is_preview:
            _add_pass_motion(engine, depsgraph, data, warn, others)
        view_fields = {v: _view_fields(scene, depsgraph, data, c, warn) for v, c in view_cams.items()}
        kept = render_cache.SCENE_CACHE
        core_scene = kept.scene_for(pc, data, warn) if cache is not None else to_core(pc, data, warn)
        if cache is not None and cache.previous is not None:
            engine.update_stats("", "Pathlight | meshes: {hits} cached, {misses} exported{kept}".format(
                **cache.previous, kept=", scene kept" if kept.reused else ""))
        settings = render_settings(pc, scene, warn, world=layer.world)
        if engine.is_preview:  # material thumbnails: small and quick
            settings.samples = min(settings.samples, PREVIEW_SAMPLES)
            settings.sample_offset = 0
            settings.pattern_samples = 0
        else:
            counts = layer_samples(scene.pathlight, view_layer)
            if counts is not None:
                if counts[0] <= 0:
                    warn(f"View layer '{view_layer.name}' has {view_layer.samples} samples: this piece's "
                         f"Sample Offset ({scene.pathlight.sample_offset}) is past them; nothing rendered")
                    _empty_result(engine, scene, view_layer)
                    return
                settings.samples = counts[0]
                if getattr(settings, "pattern_samples", 0):
                    settings.pattern_samples = counts[1]
        known = pc.render_passes()
        for p in [p for p in passes if p[0] not in known]:
            warn(f"the {p[0]} pass is not rendered by Pathlight; it stays empty")
            passes.remove(p)
        # Cycles writes no motion vectors with motion blur on: the pass stays 0.
        empty = {"Vector"} if motion_blur or engine.is_preview else set()
        if "Vector" in names and "Vector" in empty and not engine.is_preview:
            warn("The Vector pass is written only without motion blur (as Cycles); it stays 0")
        settings.passes = [p[0] for p in passes if p[0] != "Sample Count" and p[0] not in empty]
        denoiser = render_denoiser(scene, engine, warn, view_layer)
        if denoiser is not None:  # its guides, rendered whether or not their passes are shown
            settings.passes = settings.passes + [n for n in oidn.aux_passes(denoiser["input_passes"])
                                                 if n not in settings.passes and n in known]
            # With shadow catchers: Combined is composed from the denoised matte and pass.
            denoiser["catcher"] = oidn.catcher_mode(settings.passes, scene.render.film_transparent)
        if aovs:
            settings.shader_aovs = [a[1] for a in aovs]
        groups = [] if engine.is_preview or scene.pathlight.debug_view == 'BVH' else light_group_passes(view_layer)
        if len(groups) == MAX_LIGHT_GROUPS and len([g for g in view_layer.lightgroups if g.name]) > MAX_LIGHT_GROUPS:
            warn(f"Pathlight renders the first {MAX_LIGHT_GROUPS} light groups; the others' passes are not added")
        if groups:
            settings.light_groups = len(groups)
        if "UV" in names and "" in data.uv_sets.names:
            settings.uv_pass_set = data.uv_sets.names.index("")
        crypto = crypto_passes(view_layer) if hasattr(pc, "cryptomatte_hash") else []
        if crypto:
            settings.cryptomatte = [c[2] for c in crypto_layers(view_layer)]
            settings.cryptomatte_depth = max(1, min(16, int(view_layer.pass_cryptomatte_depth)))
        # Spatial splits in final renders only: not thumbnails, never the viewport.
        set_build_options(core_scene,
                          spatial_splits=scene.pathlight.use_spatial_splits and not engine.is_preview,
                          light_tree=scene.pathlight.light_tree.lower())
        if not _commit(engine, core_scene, settings.threads, scene.pathlight.time_limit):
            _empty_result(engine, scene, view_layer)
            return
        stats = core_scene.stats()
        warn_open_world_volume(stats, lit_world(layer), warn)
        if cache is not None:
            kept.keep(core_scene)
            if kept.reused:
                log.info("scene kept from the last render: %d BVH build(s), %d top-level build(s) so far",
                         stats.get("geometry_builds", 0), stats.get("top_level_builds", 0))
        log.info(bvh_line(stats))
        dropped = stats.get("dropped_triangles", 0)
        if dropped:
            warn(f"{dropped} degenerate triangle(s) skipped")
        for name, channels, chan_id, _, _ in passes + crypto:
            engine.add_pass(name, channels, chan_id, layer=view_layer.name)
        for name, channels, chan_id, _ in aovs + groups:
            engine.add_pass(name, channels, chan_id, layer=view_layer.name)
        noisy = [] if engine.is_preview else noisy_passes(scene, view_layer)
        for name, channels, chan_id in noisy:
            engine.add_pass(name, channels, chan_id, layer=view_layer.name)
        _, _, width, height = render_border(scene)
        # Multiview (Output > Stereoscopy): one render per view of the one committed scene,
        # each through its view's camera (as the viewport's camera override: nothing is
        # exported or rebuilt), with the full sample count, into its view of the result.
        seed = settings.seed
        done = None
        for index, view in enumerate(views):
            camera = None
            if view:
                settings.seed = view_seed(seed, index)
                camera = core_camera(pc, view_fields[view])
            sess = pc.Session(core_scene, settings, camera=camera)
            _report_focus(sess, warn)
            _report_caustics(sess, warn)
            if index == 0:
                _report_kernel(sess)
            view_done, cancelled = _run(
                engine, sess, width, height, time_limit=scene.pathlight.time_limit,
                passes=[p[0] for p in passes if p[0] not in empty], aovs=[a[0] for a in aovs],
                bvh_view=scene.pathlight.debug_view == 'BVH', layer=view_layer.name,
                final_passes=[c[0] for c in crypto], groups=[g[0] for g in groups], view=view,
                view_index=index, view_count=len(views), denoiser=denoiser,
                noisy_passes=[n[0] for n in noisy], warn=warn)
            done = view_done if done is None else min(done, view_done)
            del sess
            if cancelled:
                break
        _stamp(engine, settings.sample_offset, done or 0,
               cryptomatte_metadata(pc, data, view_layer) if crypto else {})
    except (ExportError, RuntimeError, ValueError) as e:  # also the core's C++ exceptions
        engine.report({'ERROR'}, f"Pathlight: {e}")
    except Exception as e:  # a bug: keep the traceback in the log, not in Blender's face
        log.exception("render failed")
        engine.report({'ERROR'}, f"Pathlight: {type(e).__name__}: {e}")


def _view_fields(scene, depsgraph, data, v, warn):
    """pc.Camera fields of render view ViewCamera `v`: its camera, model matrix and shift
    (Blender's multiview functions), spherical stereo, and its camera's motion-blur and
    Vector-pass steps moved by the view's offset from that camera."""
    fields = camera_params(scene, depsgraph, warn, view=v)
    own = scene.camera is not None and v.camera.name == scene.camera.name
    for key, others in (("motion", "camera_motions"), ("pass_motion", "camera_pass_motions")):
        steps = data.camera.get(key) if own else getattr(data, others, {}).get(v.camera.name)
        if steps is not None:
            fields[key] = view_motion(steps, v)
    for key in ("shutter_curve", "rolling_shutter", "rolling_shutter_duration"):
        if key in data.camera:
            fields[key] = data.camera[key]
    if fields.get("stereo_eye"):
        log.info("Pathlight: view '%s' renders with spherical stereo (each ray offset by %.4g)",
                 v.name, 0.5 * fields["interocular_distance"])
    return fields


def _add_motion_blur(engine, depsgraph, data, warn, cameras=()):
    """export.motion.add_motion, never failing the render: on an error the frame renders
    without motion blur, with one warning."""
    try:
        add_motion(engine, depsgraph, data, warn, cameras)
    except Exception as e:  # a bug or an unexpected scene: the still frame is still a render
        log.exception("motion blur export failed")
        warn(f"Motion blur could not be exported ({type(e).__name__}: {e}); rendering without it")
        for mesh in data.meshes:
            mesh.motions = [None] * len(mesh.matrices)
            mesh.motion_positions = None
            mesh.velocity = None
        data.camera.pop("motion", None)
        data.camera_motions = {}


def _add_pass_motion(engine, depsgraph, data, warn, cameras=()):
    """export.motion.add_pass_motion, never failing the render: on an error the Vector pass
    shows the camera's motion at most, with one warning."""
    try:
        add_pass_motion(engine, depsgraph, data, warn, cameras)
    except Exception as e:  # a bug or an unexpected scene
        log.exception("Vector pass motion export failed")
        warn(f"The Vector pass's motion could not be exported ({type(e).__name__}: {e}); it stays 0")
        for mesh in data.meshes:
            mesh.pass_motions = [None] * len(mesh.matrices)
            mesh.pass_positions = None
        for entry in list(getattr(data, "curves", [])) + list(getattr(data, "points", [])):
            entry.pass_motions = [None] * len(entry.matrices)
        data.camera.pop("pass_motion", None)
        data.camera_pass_motions = {}


def _stop_requested(engine, stage, elapsed, time_limit):
    """Esc in Blender, or a truthy answer of the progress listener, before sampling starts.
    The listener hears the stage ("export" or "build") with no samples; its ETA is the time
    limit, when there is one (sampling starts after)."""
    listener = _progress_listener
    info = {"samples_done": 0, "samples_total": 0, "elapsed_s": elapsed,
            "eta_s": time_limit if time_limit > 0 else None, "stage": stage}
    return bool(listener is not None and listener(info)) or engine.test_break()


def _empty_result(engine, scene, view_layer):
    """An empty (transparent black) result for a render cancelled before sampling: Blender may
    still save the frame, and bpy crashes saving a frame whose engine gave it no result."""
    engine.end_result(engine.begin_result(0, 0, *render_border(scene)[2:], layer=view_layer.name))


def _commit(engine, core_scene, threads, time_limit=0.0):
    """Builds the BVH and the lights on a worker thread (the core releases the GIL) while this
    thread, the one Blender called, watches for Esc: a cancel stops even a long build within
    milliseconds. Returns False when the render was cancelled."""
    failure = []

    def build():
        try:
            core_scene.commit(threads)
        except BaseException as e:  # handed to the engine's thread below
            failure.append(e)

    worker = threading.Thread(target=build, name="pathlight-commit", daemon=True)
    t0 = time.monotonic()
    worker.start()
    cancelled = False
    while worker.is_alive():
        worker.join(0.05)
        if not cancelled and _stop_requested(engine, "build", time.monotonic() - t0, time_limit):
            core_scene.cancel_commit()
            cancelled = True
    stopped = cancelled and failure and "cancelled" in str(failure[0])
    if failure and not stopped:
        raise failure[0]
    if cancelled:
        log.info("render cancelled " + ("during the BVH build" if stopped else "before it started"))
    return not cancelled


def _report_caustics(sess, warn):
    # Only where asked for explicitly: the automatic mode's "off (automatic): ..." is silent,
    # but for spherical stereo, Filter Glossy and the caustics toggles, which turn them off: a
    # log line.
    stats = sess.stats()
    state = stats.get("caustics", "")
    if state.startswith("off:"):
        warn(f"Caustic Light Paths {state}; rendering without them")
    elif ("spherical stereo" in state or state.startswith("off (automatic): not with Filter Glossy")
          or state.startswith("off (automatic): not with Fast GI")):
        log.info("Pathlight: Caustic Light Paths %s", state)
    guiding = stats.get("guiding", "")
    if guiding:  # (asked for, off: Fast GI)
        warn(f"Path Guiding {guiding}; rendering without it")


def _report_focus(sess, warn):
    stats = sess.stats()
    state = stats.get("autofocus", "off")
    if state == "hit":
        log.info("Pathlight: autofocus at %.4g (distance along the view axis)",
                 stats["focus_distance"])
    elif state == "miss":
        warn("Autofocus: nothing under the focus point; using the camera's focus distance "
             f"{stats['focus_distance']:.4g}")


def kernel_line(stats):
    """The render log's line naming the integrator kernel the core chose and why: the features
    of the scene and render in use, and those it was compiled without."""
    used = ", ".join(stats.get("features", [])) or "nothing"
    unused = ", ".join(stats.get("unused_features", [])) or "nothing"
    return f"Pathlight: kernel {stats['kernel']} (uses {used}; without {unused})"


def bvh_line(stats):
    """The render log's line on the BVH: spatial splits on or off, and what they did (triangle
    references against triangles: duplicates of cut triangles)."""
    tris, refs = stats.get("blas_triangles", 0), stats.get("blas_references", 0)
    if not stats.get("spatial_splits", False):
        return f"Pathlight: BVH without spatial splits ({tris:,} triangles)"
    extra = 100.0 * (refs - tris) / tris if tris else 0.0
    return (f"Pathlight: BVH with spatial splits ({refs:,} references to {tris:,} triangles, "
            f"+{extra:.1f} %; largest BVH {stats.get('bvh_spatial_splits', 0):,} spatial splits, "
            f"built in {stats.get('bvh_build_ms', 0.0):.0f} ms)")


def _report_kernel(sess):
    stats = sess.stats()
    if "kernel" in stats:  # an older core build has one kernel
        log.info(kernel_line(stats))


def _warner(engine):
    seen = set()

    def warn(msg):
        if msg not in seen:
            seen.add(msg)
            log.warning(msg)
            engine.report({'WARNING'}, msg)
    return warn


def _run(engine, sess, width, height, time_limit, passes=(), bvh_view=False, layer="", aovs=(), final_passes=(),
         groups=(), view="", view_index=0, view_count=1, denoiser=None, noisy_passes=(), warn=None):
    """Streams the session's film (and passes) into the render result (its view `view`, or
    the one view without multiview); returns (samples done, whether the render was
    cancelled). final_passes (Cryptomatte's, sorted per pixel on reading) are written once, at
    the end. groups: the light group passes' names (film_light_group(i) is group i's).
    Progress counts over the views: this is view_index of view_count. denoiser: denoise settings
    ({input_passes, prefilter, quality, catcher}) or None; Combined's last image (also after a
    cancel, as Cycles) is then the denoised one (and the Shadow Catcher pass's, with catchers),
    and noisy_passes (Noisy Image, Noisy Shadow Catcher) get the undenoised ones."""
    # Only the view layer being rendered (render() runs once per layer; "" would give them all).
    # With a render border, Blender's result is the border's size (it crops, or pastes the
    # border into the frame, itself): the film covers exactly that.
    if view:
        result = engine.begin_result(0, 0, width, height, layer=layer, view=view)
    else:
        result = engine.begin_result(0, 0, width, height, layer=layer)
    info = {"samples_done": 0}
    view_info = info
    cancelled = False
    try:
        render_layer = result.layers[0]

        def find(name):  # (a result of one view holds that view's passes only)
            return render_layer.passes.find_by_name(name, view) if view else render_layer.passes.get(name)
        combined = find("Combined")
        targets = [(name, find(name)) for name in passes]
        aov_targets = [(i, find(name)) for i, name in enumerate(aovs)]
        group_targets = [(i, find(name)) for i, name in enumerate(groups)]
        final_targets = [(name, find(name)) for name in final_passes]
        noisy_targets = [(name, find(name)) for name in noisy_passes]
        sess.start()
        shown = -1
        stats_at = -1.0
        while True:
            finished = sess.wait(0.25)
            view_info = _progress_info(sess.progress(), time_limit)
            info = _over_views(view_info, view_index, view_count)
            if view_info["samples_done"] != shown or finished:
                # film(): float32 (H, W, 4), row 0 = bottom, which is also Blender's order.
                image = _bvh_heat_map(engine, sess, finished) if bvh_view else sess.film()
                denoised_passes = {}
                for name, target in noisy_targets if finished else []:
                    if target is not None:  # (Noisy Shadow Catcher: the pass as rendered)
                        target.rect.foreach_set((image if name == NOISY_IMAGE else
                                                 sess.film_pass(oidn.SHADOW_CATCHER)).ravel())
                if finished and denoiser is not None:
                    denoised = _denoised(engine, sess, image, denoiser, warn or _warner(engine), view)
                    if denoised is not None:
                        image, denoised_passes = denoised
                combined.rect.foreach_set(image.ravel())  # ~400x faster than `rect = `
                for name, target in targets + (final_targets if finished else []):
                    if target is not None:  # film_pass(): (H, W, channels), same order
                        pixels = denoised_passes.get(name)
                        target.rect.foreach_set((sess.film_pass(name) if pixels is None else pixels).ravel())
                for i, target in aov_targets:  # film_aov(i): shader AOV slot i
                    if target is not None:
                        target.rect.foreach_set(sess.film_aov(i).ravel())
                for i, target in group_targets:  # film_light_group(i): light group i
                    if target is not None:
                        target.rect.foreach_set(sess.film_light_group(i).ravel())
                engine.update_result(result)
                shown = view_info["samples_done"]
            engine.update_progress(info["samples_done"] / max(info["samples_total"], 1))
            listener = _progress_listener
            # In background mode Blender prints each stats line to stdout: that is the
            # terminal progress, about once a second, unless a listener shows its own.
            now = time.monotonic()
            if not bpy.app.background or (listener is None and (
                    finished or now - stats_at >= 1.0)):
                engine.update_stats("", _status_line(info, sess, view))
                stats_at = now
            cancel = listener is not None and listener(info)  # also sees the final state
            if finished:
                break
            if cancel or engine.test_break():
                sess.cancel()
                cancelled = True
    finally:
        if not sess.is_finished():  # an exception above: stop the worker threads
            sess.cancel()
            sess.wait(5.0)
        engine.end_result(result)
    return view_info["samples_done"], cancelled


def _over_views(info, index, count):
    """Progress info of view `index` of `count` (each with the same sample count) as progress
    over all views: the samples of the views before count as done."""
    if count <= 1:
        return info
    total = info["samples_total"]
    done = index * total + info["samples_done"]
    out = dict(info, samples_done=done, samples_total=count * total)
    if info["eta_s"] is not None and info["samples_done"]:
        per_sample = info["elapsed_s"] / info["samples_done"]
        out["eta_s"] = info["eta_s"] + per_sample * total * (count - 1 - index)
    return out


def _stamp(engine, sample_offset, samples, extra=None):
    """Sample range of the render as image metadata (EXR header attributes, PNG text):
    `python3 build.py merge` weighs partial renders of one frame by it (docs/farm.md).
    extra: more {field: value} (the Cryptomatte manifests, which the compositor reads)."""
    try:
        result = engine.get_result()  # the whole frame's result (a tile's stamp is not saved)
        result.stamp_data_add_field("Pathlight Sample Offset", str(sample_offset))
        result.stamp_data_add_field("Pathlight Samples", str(samples))
        for field, value in (extra or {}).items():
            result.stamp_data_add_field(field, value)
    except (AttributeError, RuntimeError, TypeError, ReferenceError) as e:  # no metadata then
        log.warning("could not stamp the sample range: %s", e)


# The BVH view's colour scale: nodes visited, from none (black) to the image's maximum (red).
HEAT_STOPS = np.array([0.0, 0.2, 0.4, 0.6, 0.8, 1.0], np.float32)
HEAT_COLORS = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 1], [0, 1, 0], [1, 1, 0], [1, 0, 0]], np.float32)
HEAT_SCALE = "black 0, blue, cyan, green, yellow, red = max"


def heat_map(counts, scale_max):
    """RGBA float32 heat map of counts (H, W) on the linear scale 0..scale_max (HEAT_SCALE)."""
    t = np.clip(counts / max(float(scale_max), 1.0), 0.0, 1.0)
    rgb = np.stack([np.interp(t, HEAT_STOPS, HEAT_COLORS[:, c]) for c in range(3)], axis=-1)
    return np.concatenate([rgb, np.ones(t.shape + (1,))], axis=-1).astype(np.float32)


def _bvh_heat_map(engine, sess, finished):
    nodes = sess.film_pass("BVH Nodes")[..., 0]
    peak = float(nodes.max()) if nodes.size else 0.0
    if finished:
        tris = sess.film_pass("BVH Triangles")[..., 0]
        msg = (f"Pathlight BVH view: BVH nodes visited per camera ray, {HEAT_SCALE} = {peak:.0f} "
               f"(mean {nodes.mean():.1f}); triangles tested: max {tris.max():.0f}, "
               f"mean {tris.mean():.1f}. Raw counts in the BVH Nodes / BVH Triangles passes.")
        log.info(msg)
        engine.report({'INFO'}, msg)
    return heat_map(nodes, peak)


def _progress_info(progress, time_limit):
    done, total = progress["samples_done"], progress["samples_total"]
    elapsed = progress["elapsed_s"]
    eta = elapsed / done * (total - done) if done else None
    if time_limit > 0:
        left = max(time_limit - elapsed, 0.0)
        eta = left if eta is None else min(eta, left)
    return {"samples_done": done, "samples_total": total, "elapsed_s": elapsed, "eta_s": eta}


def _status_line(info, sess, view=""):
    parts = [f"Pathlight | Sample {info['samples_done']}/{info['samples_total']}",
             f"{info['elapsed_s']:.1f} s"]
    if view:  # (multiview: the samples count over all views)
        parts.insert(1, f"view {view}")
    if info["eta_s"] is not None and info["samples_done"] < info["samples_total"]:
        parts.append(f"ETA {info['eta_s']:.1f} s")
    stats = sess.stats()
    rays = stats.get("rays_per_s")
    if rays:
        parts.append(f"{rays / 1e6:.1f} Mrays/s")
    if stats.get("autofocus") == "hit":
        parts.append(f"Focus {stats['focus_distance']:.3g}")
    return " | ".join(parts)
