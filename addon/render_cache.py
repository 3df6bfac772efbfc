"""What final renders keep between renders, and for how long: the mesh export cache
(export/mesh_cache.py) and the last committed core scene (CommittedScene).

One module-level cache, because Blender makes a new engine instance for every frame of an
animation unless render.use_persistent_data is on. Each export drops the entries it did not
use, so the cache holds at most the meshes of the last render. When a render job (an
RE_RenderAnim or RE_RenderFrame call) completes or is cancelled:
- in interactive Blender the cache is emptied (the memory goes back to the user), unless the
  scene uses persistent data (then it is kept for the next render, as Cycles keeps its scene);
- in background Blender (`blender -b`, bpy.app.background) it is kept: there every frame of
  `--render-frame A..B` is a job of its own (creator_args.cc arg_handle_frame_render calls
  RE_RenderAnim(frame, frame) once per frame, and each fires render_complete), so clearing
  would re-export every mesh on every frame of a farm chunk. The fingerprint check makes a
  kept entry safe to reuse; loading another file empties the cache.
Preview renders (material thumbnails) never use it, nor do single-frame renders (F12,
`render(write_still=True)`) of scenes without persistent data: no later frame could reuse their
meshes, and the fingerprints cost about half an export (0.4 s of a 1M-triangle mesh's 0.8 s
render in tests/bench/bench_export.py).
"""

import bpy
import numpy as np
from bpy.app.handlers import persistent

from .export.mesh_cache import MeshCache
from .scene_writer import put_material, replace_lights, set_camera, set_instance_transforms, to_core


class CommittedScene:
    """The core scene of the last render that used the mesh cache (animation frames, scenes
    with persistent data), kept so that the next render can skip the BVH build, as Cycles
    keeps its scene with persistent data: when every mesh came from the cache (the same
    arrays) with the same material slots, materials, images and UV sets, the kept scene gets
    this render's camera, lights, world and materials, and the matrices that changed
    (Scene.set_instance_transform); its commit() then rebuilds only the light distribution,
    or the geometry when a merged object moved. Anything else builds a new scene."""

    def __init__(self):
        self.clear()

    def clear(self):
        self.pc = self.data = self.scene = None
        self.image_ids = []
        self.material_ids = []
        self.reused = False  # whether the last scene_for() returned the kept scene
        self.moving = False  # the kept scene has motion blur

    def scene_for(self, pc, data, warn):
        """A core scene (not committed) holding SceneData `data`: the kept one, updated, when
        its geometry is this data's, else a new one. Call keep() once it is committed."""
        self.reused = False
        # Motion blur: instance motion is only set by add_instance, so a scene with motion (or
        # one after a scene with motion) is built anew.
        moving = _has_motion(data)
        if self.scene is not None and self.pc is pc and not moving and not self.moving and \
                _same_geometry(self.data, data):
            scene = self.scene
            self.scene = None  # kept again only after a successful commit
            set_instance_transforms(scene, [
                (i, new) for i, (old, new) in enumerate(zip(_matrices(self.data), _matrices(data)))
                if not np.array_equal(old, new)])
            for core_id, material in zip(self.material_ids, data.materials):
                put_material(scene, material, self.image_ids, core_id)
            replace_lights(scene, data.lights, data, warn)
            set_camera(pc, scene, data.camera)
            self.data, self.reused = data, True
            return scene
        self.clear()
        material_ids, image_ids = [], []
        scene = to_core(pc, data, warn, material_ids=material_ids, image_ids=image_ids)
        self.moving = moving
        self.pc, self.data, self.material_ids, self.image_ids = pc, data, material_ids, image_ids
        return scene

    def keep(self, scene):
        """Keeps a committed scene that scene_for() returned, for the next render."""
        self.scene = scene


def _has_motion(data):
    """Motion blur, or the Vector pass's motion (also only set by add_instance, add_curves and
    add_points)."""
    return any(getattr(mesh, "motion_positions", None) is not None or
               getattr(mesh, "pass_positions", None) is not None or
               any(m is not None for m in getattr(mesh, "motions", [])) or
               any(m is not None for m in getattr(mesh, "pass_motions", None) or []) for mesh in data.meshes) or \
        any(m is not None for entry in list(getattr(data, "curves", [])) + list(getattr(data, "points", []))
            for m in getattr(entry, "pass_motions", None) or [])


def _matrices(data):
    """Every instance matrix of SceneData `data`, in to_core's order (meshes, then matrices)."""
    return [np.asarray(m, np.float32) for mesh in data.meshes for m in mesh.matrices]


def _same_geometry(old, new):
    """Whether SceneData `new` has exactly `old`'s meshes (the same cached arrays) and material
    table (slots, names, images, UV sets), so that a core scene of `old` can render `new` after
    its matrices, materials, lights, world and camera are set."""
    if old is None or len(old.meshes) != len(new.meshes) or old.material_slots != new.material_slots:
        return False
    if getattr(old, "curves", None) or getattr(new, "curves", None):
        return False  # curves are exported afresh each time: a new scene
    if getattr(old, "points", None) or getattr(new, "points", None):
        return False  # point clouds too
    if getattr(old, "volume_grids", None) or getattr(new, "volume_grids", None):
        return False  # volume grids are read afresh (a frame may change them): a new scene
    if old.material_names != new.material_names or len(old.materials) != len(new.materials):
        return False
    if getattr(old, "light_links", {}) != getattr(new, "light_links", {}):
        return False  # add_instance sets the objects' light sets
    if getattr(old, "light_groups", []) != getattr(new, "light_groups", []):
        return False  # and their light groups' indices (the objects' names: in infos)
    if any(getattr(m, "displacement", None) for m in old.materials + new.materials):
        return False  # displaced vertices follow the materials and the transforms: a new scene
    if getattr(old.uv_sets, "names", None) != getattr(new.uv_sets, "names", None):
        return False
    if len(old.images) != len(new.images) or any(
            a.srgb != b.srgb or getattr(a, "tiles", ()) != getattr(b, "tiles", ())
            or (a.pixels is None) != (b.pixels is None)
            or (a.pixels is not None and not np.array_equal(a.pixels, b.pixels))
            for a, b in zip(old.images, new.images)):
        return False
    for a, b in zip(old.meshes, new.meshes):
        if len(a.matrices) != len(b.matrices) or a.uvs.keys() != b.uvs.keys() or a.infos != b.infos:
            return False
        if not _same_values(getattr(a, "object_attributes", []), getattr(b, "object_attributes", [])):
            return False  # add_instance sets them: an animated custom property needs a new scene
        arrays = [(a.positions, b.positions), (a.triangles, b.triangles), (a.normals, b.normals),
                  (a.normal_indices, b.normal_indices), (a.material_indices, b.material_indices)]
        arrays += [(a.uvs[k], b.uvs[k]) for k in a.uvs]
        if a.attributes.keys() != b.attributes.keys():
            return False
        arrays += [(a.attributes[k], b.attributes[k]) for k in a.attributes]
        if a.tangents.keys() != b.tangents.keys():
            return False
        arrays += [(a.tangents[k], b.tangents[k]) for k in a.tangents]
        # `is`: the mesh cache hands out its own arrays, never copies.
        if not all(x is y for x, y in arrays) or a.texspace != b.texspace:
            return False
    return True


def _same_values(a, b):
    """Whether two per-instance lists of arrays (or None) hold the same values."""
    return len(a) == len(b) and all(
        (x is None) == (y is None) and (x is None or np.array_equal(x, y)) for x, y in zip(a, b))


MESH_CACHE = MeshCache()
SCENE_CACHE = CommittedScene()


def clear():
    """Empties both caches (the memory goes back to the user)."""
    MESH_CACHE.clear()
    SCENE_CACHE.clear()


def keep_between_jobs(scene, background=None):
    """Whether the cache outlives a finished render job of `scene` (background: whether
    Blender runs in background mode; default bpy.app.background)."""
    if scene is not None and scene.render.use_persistent_data:
        return True
    return bool(bpy.app.background if background is None else background)


def cache_for(engine, depsgraph):
    """The cache a render of `depsgraph` by `engine` uses, or None: frames of an animation job
    (`-a`, `-f A..B`: each is an animation job) and scenes with persistent data use it. Call it
    first in the render: it reads what the depsgraph updated (see MeshCache.begin_export)."""
    if engine.is_preview:
        return None
    scene = depsgraph.scene
    persistent = scene.render.use_persistent_data
    if engine.is_animation or persistent:
        # Persistent data keeps one depsgraph between renders of one view layer; with several,
        # Blender switches that depsgraph's view layer, and its updates list the switch.
        layers = 1 if scene.render.use_single_layer else sum(1 for vl in scene.view_layers if vl.use)
        MESH_CACHE.begin_export(depsgraph, tracked=persistent and layers == 1)
        return MESH_CACHE
    clear()  # nothing reuses what an earlier job left
    return None


@persistent
def _render_ended(scene, *args):
    if not keep_between_jobs(scene):
        clear()


@persistent
def _file_loading(*args):
    clear()


_HANDLERS = ((bpy.app.handlers.render_complete, _render_ended),
             (bpy.app.handlers.render_cancel, _render_ended),
             (bpy.app.handlers.load_pre, _file_loading))


def register():
    for handlers, func in _HANDLERS:
        if func not in handlers:
            handlers.append(func)


def unregister():
    for handlers, func in _HANDLERS:
        if func in handlers:
            handlers.remove(func)
    clear()
