"""Viewport rendering (Rendered shading) below the drawing: a ViewportSession keeps a core
scene in sync with the depsgraph and runs progressive core Sessions that restart on every
change. engine.view_update feeds it depsgraph updates, engine.view_draw feeds it the view and
draws `display()` with the gpu module (draw.py); nothing here needs a viewport, so the tests
drive it headless.

What each change costs (the plan comes from viewport_update.plan_updates):
- view or camera moved: nothing is exported or rebuilt; a new core Session renders the same
  committed scene through an overriding camera (pc.Session(scene, settings, camera=...));
- material edited: the material is recompiled and replaced in the committed scene
  (scene.set_shader), lights/world re-read (scene.clear_lights + add): commit() then rebuilds
  only the light distribution (scene.stats()["geometry_builds"] does not change);
- object moved: the core scene is dynamic (every instance over its mesh's own BVH), so the
  moved objects' instances get their new matrices (scene.set_instance_transform) and commit()
  rebuilds only the top level of the BVH and the lights (stats: top_level_builds, not
  geometry_builds). Objects that are also the source of an instancer (collection instances,
  particles, geometry-node instances) or that do not map to one instance re-export instead;
- mesh edited, object hidden, an instancer moved: full re-export and BVH rebuild.
Every write to the core scene goes through scene_writer.py.

Threads: the core Session renders on its own C++ threads with the GIL released; every method
here runs on Blender's main thread (the engine callbacks), and only polls the session.
"""

import logging
import threading

import numpy as np

from . import denoise as oidn

from .export import export_scene
from .export.light import collect_lights
from .export.light_linking import attach_to_lights, light_links
from .export.material import convert_material, view_layer_ids
from .export.mesh import is_visible
from .export.shader import ImageTable, UvSets
from .export.world import export_world, world_volume
from .scene_writer import put_material, replace_lights, set_build_options, set_instance_transforms, to_core
from .viewport_update import ViewState, curves_signature, plan_updates, settings_signature

log = logging.getLogger(__name__)

# The Render Pass selector (View3DShading.pathlight.render_pass, properties.VIEWPORT_PASS_ITEMS):
# each entry's core pass (session.PASSES' names); LIGHT_GROUP and AOV name theirs, COMBINED none.
VIEW_PASSES = {
    'EMISSION': "Emit", 'BACKGROUND': "Env", 'AO': "AO", 'SHADOW_CATCHER': "Shadow Catcher",
    'DIFFUSE_DIRECT': "DiffDir", 'DIFFUSE_INDIRECT': "DiffInd", 'DIFFUSE_COLOR': "DiffCol",
    'GLOSSY_DIRECT': "GlossDir", 'GLOSSY_INDIRECT': "GlossInd", 'GLOSSY_COLOR': "GlossCol",
    'TRANSMISSION_DIRECT': "TransDir", 'TRANSMISSION_INDIRECT': "TransInd",
    'TRANSMISSION_COLOR': "TransCol", 'VOLUME_DIRECT': "VolumeDir", 'VOLUME_INDIRECT': "VolumeInd",
    'POSITION': "Position", 'NORMAL': "Normal", 'UV': "UV", 'MIST': "Mist", 'DENOISING_ALBEDO': "Denoising Albedo",
    'DENOISING_NORMAL': "Denoising Normal", 'SAMPLE_COUNT': "Sample Count",
}

LOW_RES_DIVIDER = 4  # the first pass after a change renders at 1/4 resolution ...
LOW_RES_SAMPLES = 2  # ... with this many samples, then the full resolution takes over


class ViewportSession:
    """The viewport's core scene and its progressive render. `counters` says what work was
    done (exports, camera-only restarts, material replacements, ...), for tests and stats."""

    def __init__(self, pc, warn=None):
        self.pc = pc
        self.warn = warn or (lambda msg: log.warning(msg))
        self.scene = None  # pc.Scene, committed
        self.state = ViewState()
        self.material_ids = {}  # bpy material name -> core material id
        self.uv_sets = None
        self.scene_camera = None  # pc.Camera fields of the scene camera (for camera view)
        self.view = None  # (camera fields, width, height) of the viewport
        self._view_camera = None  # pc.Camera fields of the view (None: the scene camera)
        self._base_settings = None  # pc.RenderSettings of the scene, viewport samples
        self.low = self.full = None  # the running low-resolution and full sessions
        self.counters = dict(exports=0, restarts=0, camera_restarts=0, material_updates=0,
                             light_updates=0, transform_updates=0)
        # Object name -> its core instance (objects the depsgraph lists once, not through an
        # instancer), and the names that instancers also use (those re-export when moved).
        self.instance_index = {}
        self.instanced_names = frozenset()
        # Viewport denoising (Open Image Denoise): its settings (None: off), and the last denoised
        # image (session, samples it shows, image), redone when the samples shown have doubled
        # since and at the last sample: a denoise costs about as much as many samples.
        # The denoise runs on a worker thread (ctypes releases the GIL; a 1920x1080 one takes
        # seconds here), so that Blender's UI never waits for it: the image drawn meanwhile is
        # the last denoised one (the noisy film before the first). denoise_async False: in the
        # draw call (tests).
        self.denoiser = None
        self.denoise_start = 1
        self.denoise_async = True
        self._denoised = None
        self._job = None  # [session, samples, thread, result or exception]
        self.counters["denoises"] = 0
        # The Render Pass asked for (render_pass id, light group or AOV name), what it resolved
        # to at the last restart (None: Combined; ("pass", name), ("group", i), ("aov", i, channels)),
        # and the view layer's light groups and shader AOVs of the last export.
        self.pass_request = ('COMBINED', "")
        self.shown = None
        self.light_groups = ()
        self.aovs = ()
        self._layer = None
        self._fallbacks = set()
        # The UV pass needs every mesh's active render UV map exported: only while UV is shown.
        self.uv_exported = False
        self.uv_pass_set = None

    # ------------------------------------------------------------ scene sync

    def sync(self, depsgraph, updates=None):
        """Brings the core scene up to date: a full export the first time (or when updates is
        None), else only what `updates` (viewport_update.Update records) require. Returns the
        UpdatePlan carried out (None for a full export)."""
        scene = depsgraph.scene
        signature = settings_signature(scene)
        if self.scene is None or updates is None:
            self._full_export(depsgraph)
            self.state.settings = signature
            self.restart()
            return None
        plan = plan_updates(updates, self.state, signature)
        if _layer_signature(depsgraph) != self._layer:
            # New light groups or AOVs: new group indices and AOV slots in the materials.
            plan.rebuild_geometry = plan.lights = plan.restart = True
        if plan.nothing:
            return plan
        self.stop()
        if plan.rebuild_geometry or (plan.transforms and not self._move_objects(depsgraph, plan.transforms)):
            self._full_export(depsgraph)
        else:
            for name in plan.materials:
                if not self._replace_material(depsgraph, name):
                    self._full_export(depsgraph)  # the change needs new geometry data
                    break
            else:
                if plan.lights:
                    self._replace_lights(depsgraph)
                if plan.materials or plan.lights or plan.transforms:
                    # The light distribution (and the top level for moved objects) only.
                    self.scene.commit()
        if plan.camera or plan.settings:
            self._read_scene(depsgraph)
        self.state.settings = signature
        if plan.restart_only or (plan.camera and not plan.rebuild_geometry):
            self.counters["camera_restarts"] += 1
        self.restart()
        return plan

    def _full_export(self, depsgraph):
        from .session import shader_aovs
        view_layer = getattr(depsgraph, "view_layer", None)
        # The view layer's AOVs, as a final render exports them (AOV Output nodes write only
        # when a session asks for the AOV: nothing else changes).
        self.aovs = tuple(shader_aovs(view_layer)) if view_layer is not None else ()
        uv_pass = self.pass_request[0] == 'UV'
        data = export_scene(depsgraph, self.warn, need_camera=False, uv_pass=uv_pass,
                            aovs=[(a[0], 'COLOR' if a[1] == 4 else 'VALUE') for a in self.aovs])
        self.uv_exported = uv_pass
        self.uv_pass_set = data.uv_sets.names.index("") if uv_pass and "" in data.uv_sets.names else None
        self.light_groups = tuple(getattr(data, "light_groups", None) or ())
        self._layer = _layer_signature(depsgraph)
        ids = []
        scene = to_core(self.pc, data, self.warn, material_ids=ids)
        # Every instance its own transform: moves rebuild the top level only.
        set_build_options(scene, dynamic=True)
        scene.commit()
        self._map_instances(data)
        self.scene = scene
        self.material_ids = {name: i for name, i in zip(data.material_names, ids) if name}
        self.volume_materials = data.volume_material_names
        self.uv_sets = data.uv_sets
        self.scene_camera = data.camera or None
        self.state.materials = frozenset(self.material_ids) | self.volume_materials
        self.state.camera_name = depsgraph.scene.camera.name if depsgraph.scene.camera else ""
        self._read_scene(depsgraph)
        self.counters["exports"] += 1

    def _map_instances(self, data):
        """Core instance index of each plain object, in to_core's order (meshes, then matrices)."""
        index, seen, instanced = {}, set(), set()
        i = 0
        for mesh in data.meshes:
            owners = getattr(mesh, "owners", None) or [(None, True)] * len(mesh.matrices)
            for name, by_instancer in owners:
                if by_instancer:
                    instanced.add(name)
                elif name in seen:
                    index.pop(name, None)  # listed twice: not one instance
                else:
                    seen.add(name)
                    index[name] = i
                i += 1
        self.instance_index = index
        self.instanced_names = frozenset(instanced)

    def _move_objects(self, depsgraph, names):
        """Gives the moved objects' instances their new matrices; False when one cannot be mapped
        (the caller then re-exports)."""
        if not self.scene.dynamic:
            return False
        moves = []
        for name in names:
            idx = self.instance_index.get(name)
            obj = depsgraph.objects.get(name)
            if idx is None or name in self.instanced_names or obj is None:
                return False
            moves.append((idx, np.array(obj.matrix_world, np.float32)))
        set_instance_transforms(self.scene, moves)
        self.counters["transform_updates"] += 1
        return True

    def _read_scene(self, depsgraph):
        from .export.camera import camera_params
        from .export.view_layer import layer_world
        from .session import pixel_pattern_settings, render_settings
        scene = depsgraph.scene
        self._base_settings = render_settings(self.pc, scene, viewport=True, world=layer_world(depsgraph))
        self._base_settings.samples = scene.pathlight.preview_samples
        self._base_settings.time_limit = 0.0
        self._base_settings.adaptive_threshold = 0.0  # the viewport refines until its samples
        self._base_settings.sample_offset = 0
        for name, value in pixel_pattern_settings(scene.pathlight, None, viewport=True).items():
            setattr(self._base_settings, name, value)
        self.denoiser = oidn.settings(scene.pathlight, viewport=True)
        self.denoise_start = scene.pathlight.preview_denoising_start_sample
        if self.denoiser is not None:  # the guides it reads
            self._base_settings.passes = oidn.aux_passes(self.denoiser["input_passes"])
            # (with shadow catchers: how the film composes Combined, composed again when denoised)
            self.denoiser["catcher"] = oidn.catcher_mode(self._base_settings.passes,
                                                         self._base_settings.film_transparent)
        try:
            self.scene_camera = camera_params(scene, depsgraph, self.warn)
        except Exception:  # no active camera: only the free view can be shown
            self.scene_camera = None

    def _replace_material(self, depsgraph, name):
        """Recompiles material `name` into its core id; False when that needs a re-export
        (textures: new images; new UV maps the meshes did not export)."""
        import bpy
        mat = bpy.data.materials.get(name)
        core_id = self.material_ids.get(name)
        if mat is None or core_id is None or name in getattr(self, "volume_materials", ()):
            return False  # (a volume object's compile of it reads its grids: re-export)
        uv_sets = UvSets()
        uv_sets.names = list(self.uv_sets.names) if self.uv_sets is not None else []
        uv_sets.aovs = dict(getattr(self.uv_sets, "aovs", None) or {})  # (the AOV slots of the export)
        images = ImageTable()
        use_schlick = getattr(depsgraph.scene.pathlight, "use_schlick_fresnel", False)
        data = convert_material(mat, self.warn, images, uv_sets, use_schlick, view_layer_ids(depsgraph),
                                depsgraph)
        if images.images or len(uv_sets.names) != len(self.uv_sets.names if self.uv_sets else []):
            return False
        put_material(self.scene, data, [], core_id)  # no images: checked above
        self.counters["material_updates"] += 1
        return True

    def _replace_lights(self, depsgraph):
        """Lights and the world read again; no geometry touched."""
        from .export import world_lightgroup as read_world_lightgroup
        from .export.world import world_sampled as read_world_sampled
        from .export.view_layer import layer_settings, lit_world
        world = lit_world(layer_settings(depsgraph))  # (World Override, Environment filter)
        groups = list(self.light_groups)

        w_color, w_texture, w_program = export_world(world, self.warn, depsgraph.scene.frame_current)

        class _World:  # what set_world (and add_lights: the light groups) read of SceneData
            world_texture = w_texture
            world_color = w_color
            world_program = w_program
            world_volume = world_volume(world, self.warn)
            light_groups = groups
            world_lightgroup = read_world_lightgroup(world)
            world_sampled = read_world_sampled(world)
        lights = attach_to_lights(collect_lights(depsgraph, self.warn, is_visible), light_links(depsgraph, self.warn))
        replace_lights(self.scene, lights, _World, self.warn)
        self.counters["light_updates"] += 1

    def check_settings(self, depsgraph):
        """Restarts with the scene's current settings when they changed without a depsgraph
        update (a script's change of scene.pathlight tags nothing). Returns True if it did."""
        if self.scene is None:
            return False
        signature = settings_signature(depsgraph.scene)
        if signature == self.state.settings and _layer_signature(depsgraph) == self._layer:
            return False
        self.stop()
        if (curves_signature(signature) != curves_signature(self.state.settings)
                or _layer_signature(depsgraph) != self._layer):
            self._full_export(depsgraph)  # ribbons or round curves, light groups, AOVs: re-export
        self._read_scene(depsgraph)
        self.state.settings = signature
        self.restart()
        return True

    # ------------------------------------------------------------ view and render

    def set_pass(self, render_pass, name="", depsgraph=None):
        """The Render Pass shown (a VIEW_PASSES id, 'COMBINED', or 'LIGHT_GROUP' / 'AOV' with the
        group's or AOV's name); restarts the render when what it shows changed. Returns True if
        it restarted. To UV and back re-exports the scene from `depsgraph` (the UV map)."""
        request = (render_pass, name if render_pass in ('LIGHT_GROUP', 'AOV') else "")
        if request == self.pass_request:
            return False
        self.pass_request = request
        if self.scene is None or self.view is None:
            return False  # (restart() resolves it, against the exported view layer)
        if depsgraph is not None and (render_pass == 'UV') != self.uv_exported:
            self.stop()
            self._full_export(depsgraph)
            self.restart()
            return True
        if self._resolve() == self.shown:  # (an unknown name shows Combined, as before)
            return False
        self.restart()
        return True

    def _resolve(self):
        """What pass_request shows with the exported view layer: see `shown`. An unknown light
        group or AOV, or a pass this core lacks, shows Combined, with one message."""
        render_pass, name = self.pass_request
        if render_pass in VIEW_PASSES:
            core_pass = VIEW_PASSES[render_pass]
            if core_pass in self.pc.render_passes():
                return ("pass", core_pass)
            self._fallback(f"the {core_pass} pass is not rendered by this core; the viewport shows Combined")
        elif render_pass == 'LIGHT_GROUP':
            if name in self.light_groups:
                return ("group", self.light_groups.index(name))
            self._fallback(f"light group '{name}' is not one of the view layer's light groups; "
                           "the viewport shows Combined")
        elif render_pass == 'AOV':
            names = [a[0] for a in self.aovs]
            if name in names:
                i = names.index(name)
                return ("aov", i, self.aovs[i][1])
            self._fallback(f"shader AOV '{name}' is not one of the view layer's shader AOVs; "
                           "the viewport shows Combined")
        return None

    def _fallback(self, msg):
        if msg not in self._fallbacks:
            self._fallbacks.add(msg)
            self.warn(msg)

    def set_view(self, camera, width, height):
        """The viewport's camera (pc.Camera fields, or None = the scene camera) and region
        size; restarts the render when they changed. Returns True if it restarted."""
        view = (_freeze(camera), int(width), int(height))
        if view == self.view:
            return False
        self.view = view
        self._view_camera = camera
        if self.scene is not None:
            self.counters["camera_restarts"] += 1
            self.restart()
        return True

    def restart(self):
        """Cancels the running render and starts again: a low-resolution pass first."""
        self.stop()
        if self.scene is None or self.view is None:
            return
        self.shown = self._resolve()
        self.counters["restarts"] += 1
        _, width, height = self.view
        if min(width, height) >= 8 * LOW_RES_DIVIDER:  # tiny regions skip the low pass
            self.low = self._start(width // LOW_RES_DIVIDER, height // LOW_RES_DIVIDER,
                                   min(LOW_RES_SAMPLES, self._base_settings.samples))
        else:
            self.full = self._start(width, height, self._base_settings.samples)

    def _start(self, width, height, samples):
        st = self._base_settings
        settings = self.pc.RenderSettings()
        for name in dir(st):
            if not name.startswith("_"):
                try:
                    setattr(settings, name, getattr(st, name))
                except (AttributeError, TypeError):
                    pass
        settings.width, settings.height, settings.samples = width, height, samples
        # Only the pass shown (Combined alone: no pass buffer at all). A light group or AOV
        # asks for the slots up to its own, which keep the final render's numbering.
        kind = self.shown[0] if self.shown else None
        if kind == "pass" and self.shown[1] != "Sample Count":  # (the core always counts samples)
            settings.passes = [self.shown[1]]
            if self._denoises_shown_pass():  # (and the guides it is denoised with)
                settings.passes += oidn.aux_passes(self.denoiser["input_passes"])
            if self.shown[1] == "UV" and self.uv_pass_set is not None:
                settings.uv_pass_set = self.uv_pass_set
        elif kind == "group":
            settings.light_groups = self.shown[1] + 1
        elif kind == "aov":
            settings.shader_aovs = [a[1] for a in self.aovs[:self.shown[1] + 1]]
        camera = self._camera()
        sess = self.pc.Session(self.scene, settings, camera=camera)
        sess.start()
        return sess

    def _camera(self):
        fields = self._view_camera if self._view_camera is not None else self.scene_camera
        if fields is None:
            return None
        cam = self.pc.Camera()
        for name, value in fields.items():
            setattr(cam, name, value)
        return cam

    def poll(self):
        """Advances the render (low resolution done -> start the full one). Raises the core's
        RuntimeError when a render failed. Returns True while more is to come (keep
        redrawing)."""
        if self.low is not None and self.full is None and self.low.is_finished():
            self.low.wait(0.0)  # raises if the render failed
            _, width, height = self.view
            self.full = self._start(width, height, self._base_settings.samples)
        if self.full is not None:
            if self.full.is_finished():
                self.full.wait(0.0)
                return self.denoising() or self._denoise_due(self.full)  # (its last denoise drawn)
            return True
        return self.low is not None

    def _denoise_due(self, sess):
        """Whether the finished session's last image is still to be denoised and drawn."""
        if self.denoiser is None or (self.shown and not self._denoises_shown_pass()):
            return False  # (a pass shown as it is: nothing to wait for)
        done = sess.progress()["samples_done"]
        last = self._denoised
        return done >= self.denoise_start and not (last is not None and last[0] is sess and last[1] == done)

    def display(self):
        """(film float32 (H, W, 4) row 0 = bottom, samples done) of the best render so far,
        or None before anything rendered: Combined, or the pass shown as display_pass makes it.
        With Viewport Denoise, from the start sample on, Combined denoised (see _denoise)."""
        for sess in (self.full, self.low):
            if sess is not None:
                done = sess.progress()["samples_done"]
                if done > 0:
                    if self.shown:  # a pass other than Combined, as it is (not denoised)
                        film = self._pass_film(sess, done)
                        if self._denoises_shown_pass() and done >= self.denoise_start:
                            film = self._denoise(sess, film, done, use_albedo=False)
                        return film, done
                    film = sess.film()
                    if self.denoiser is not None and done >= self.denoise_start:
                        film = self._denoise(sess, film, done)
                    return film, done
        return None

    def _denoises_shown_pass(self):
        """Whether the pass shown is denoised: the Shadow Catcher pass, as Cycles' viewport
        shows its denoised variant (the only pass besides Combined that Cycles denoises)."""
        return self.denoiser is not None and self.shown == ("pass", oidn.SHADOW_CATCHER)

    def _denoise(self, sess, film, done, use_albedo=True):
        """The film denoised: again when the samples shown have doubled since the last denoise
        of this session, or it has finished; in between the last denoised image. On a failure the
        noisy film, with one warning, and no more tries until the settings change. use_albedo
        False: the Shadow Catcher pass shown (a 0.5 albedo, no catcher composite)."""
        self._collect()
        if self.denoiser is None:  # (failed just now)
            return film
        last = self._denoised if self._denoised is not None and self._denoised[0] is sess else None
        due = last is None or done >= 2 * last[1] or (sess.is_finished() and done != last[1])
        if due and (self._job is None or self._job[0] is not sess):
            # The guides are read here (the core's film_pass copies); the filter runs on its own.
            guides = {name: sess.film_pass(name) for name in oidn.aux_passes(self.denoiser["input_passes"])}
            opts = dict(self.denoiser)
            if not use_albedo:
                opts.update(catcher=None, use_albedo=False)
            if opts.get("catcher") is not None:
                try:  # the shadow catchers' planes, where the scene has catchers
                    guides.update({name: sess.film_pass(name) for name in oidn.catcher_pass_names(opts["catcher"])})
                except ValueError:  # (none in the scene: the core keeps no such planes)
                    opts["catcher"] = None
            job = [sess, done, None, None]

            def work():
                try:
                    job[3] = oidn.denoise_film(film, guides.__getitem__, **opts)[0]
                except Exception as e:  # (handed to the drawing thread by _collect)
                    job[3] = e
            if self.denoise_async:
                job[2] = threading.Thread(target=work, name="pathlight-viewport-denoise", daemon=True)
                self._job = job
                job[2].start()
            else:
                work()
                self._job = job
            self._collect()
            last = self._denoised if self._denoised is not None and self._denoised[0] is sess else None
        return film if last is None else last[2]

    def _collect(self):
        """Takes the finished denoise's image (or its failure: one warning, denoising off)."""
        job = self._job
        if job is None or (job[2] is not None and job[2].is_alive()):
            return
        self._job = None
        if isinstance(job[3], Exception):
            self.warn(f"Viewport denoising failed, the image is not denoised: {job[3]}")
            self.denoiser = None
        elif job[3] is not None and (job[0] is self.full or job[0] is self.low):
            self.counters["denoises"] += 1
            self._denoised = (job[0], job[1], job[3])

    def denoising(self):
        """True while a denoise runs (the viewport keeps redrawing to show its image)."""
        return self._job is not None and self._job[2] is not None and self._job[2].is_alive()

    def _pass_film(self, sess, samples):
        kind = self.shown[0] if self.shown else None
        if kind is None:
            return sess.film()
        if kind == "group":
            return display_pass(sess.film_light_group(self.shown[1]))
        if kind == "aov":
            return display_pass(sess.film_aov(self.shown[1]))
        name = self.shown[1]
        return display_pass(sess.film_pass(name), 1.0 / samples if name == "Sample Count" else 1.0)

    def stop(self):
        """Cancels the running sessions and drops them (which unlocks the scene for edits)."""
        for sess in (self.low, self.full):
            if sess is not None:
                sess.cancel()
                try:
                    sess.wait(5.0)
                except RuntimeError as e:  # a failed render: nothing more to stop
                    log.warning("viewport render failed: %s", e)
        self.low = self.full = None
        self._denoised = self._job = None  # (a denoise still running is dropped when done)

    def free(self):
        self.stop()
        self.scene = None


def display_pass(values, scale=1.0):
    """A pass (H, W, channels) as the RGBA film the viewport draws, as Cycles' viewport shows
    passes: 1 channel as grey, 3 as RGB, both with alpha 1; 4 as they are. scale: Sample Count's
    1 / samples (Cycles shows the share of the samples a pixel took)."""
    values = np.asarray(values, np.float32)
    if values.ndim == 2:
        values = values[..., None]
    h, w, c = values.shape
    if c == 4:
        out = values.copy()
    else:
        out = np.ones((h, w, 4), np.float32)
        out[..., :3] = values if c == 3 else values[..., :1]
    if scale != 1.0:
        out[..., :3] *= np.float32(scale)
    return out


def _layer_signature(depsgraph):
    """The view layer's light groups and shader AOVs (group indices, AOV slots), and its
    overrides and filters (Cycles' viewport renders the view layer too): a change re-exports."""
    from .export import view_layer_lightgroups
    from .export.view_layer import layer_settings
    from .session import shader_aovs
    view_layer = getattr(depsgraph, "view_layer", None)
    if view_layer is None:
        return ((), ())
    layer = layer_settings(depsgraph)
    overrides = tuple(x.name if x is not None else "" for x in (layer.material_override, layer.world)) + (
        layer.use_sky, layer.use_solid, layer.use_strand, layer.use_volumes) + _collection_flags(view_layer)
    return tuple(view_layer_lightgroups(view_layer)), tuple(shader_aovs(view_layer)), overrides


def _collection_flags(view_layer):
    """(name, holdout, indirect only) of the view layer's collections that have either set."""
    out, stack = [], list(getattr(getattr(view_layer, "layer_collection", None), "children", ()))
    while stack:
        lc = stack.pop()
        if lc.holdout or lc.indirect_only:
            out.append((lc.name, lc.holdout, lc.indirect_only))
        stack.extend(lc.children)
    return tuple(sorted(out))


def _freeze(camera):
    if camera is None:
        return None
    return tuple((k, v.tobytes() if hasattr(v, "tobytes") else v) for k, v in sorted(camera.items()))
