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

import numpy as np

from .export import export_scene
from .export.light import collect_lights
from .export.light_linking import attach_to_lights, light_links
from .export.material import convert_material, view_layer_ids
from .export.mesh import is_visible
from .export.shader import ImageTable, UvSets
from .export.world import world_color, world_texture, world_volume
from .scene_writer import put_material, replace_lights, set_build_options, set_instance_transforms, to_core
from .viewport_update import ViewState, curves_signature, plan_updates, settings_signature

log = logging.getLogger(__name__)

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
        data = export_scene(depsgraph, self.warn, need_camera=False)
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
        from .session import pixel_pattern_settings, render_settings
        scene = depsgraph.scene
        self._base_settings = render_settings(self.pc, scene, viewport=True)
        self._base_settings.samples = scene.pathlight.preview_samples
        self._base_settings.time_limit = 0.0
        self._base_settings.adaptive_threshold = 0.0  # the viewport refines until its samples
        self._base_settings.sample_offset = 0
        for name, value in pixel_pattern_settings(scene.pathlight, None, viewport=True).items():
            setattr(self._base_settings, name, value)
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
        scene = depsgraph.scene

        class _World:  # what set_world reads of SceneData
            world_texture = world_texture(scene.world, self.warn)
            world_color = world_color(scene.world, self.warn)
            world_volume = world_volume(scene.world, self.warn)
        lights = attach_to_lights(collect_lights(depsgraph, self.warn, is_visible), light_links(depsgraph, self.warn))
        replace_lights(self.scene, lights, _World, self.warn)
        self.counters["light_updates"] += 1

    def check_settings(self, depsgraph):
        """Restarts with the scene's current settings when they changed without a depsgraph
        update (a script's change of scene.pathlight tags nothing). Returns True if it did."""
        if self.scene is None:
            return False
        signature = settings_signature(depsgraph.scene)
        if signature == self.state.settings:
            return False
        self.stop()
        if curves_signature(signature) != curves_signature(self.state.settings):
            self._full_export(depsgraph)  # ribbons or round curves: new geometry
        self._read_scene(depsgraph)
        self.state.settings = signature
        self.restart()
        return True

    # ------------------------------------------------------------ view and render

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
                return False
            return True
        return self.low is not None

    def display(self):
        """(film float32 (H, W, 4) row 0 = bottom, samples done) of the best render so far,
        or None before anything rendered."""
        if self.full is not None and self.full.progress()["samples_done"] > 0:
            return self.full.film(), self.full.progress()["samples_done"]
        if self.low is not None and self.low.progress()["samples_done"] > 0:
            return self.low.film(), self.low.progress()["samples_done"]
        return None

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

    def free(self):
        self.stop()
        self.scene = None


def _freeze(camera):
    if camera is None:
        return None
    return tuple((k, v.tobytes() if hasattr(v, "tobytes") else v) for k, v in sorted(camera.items()))
