"""The mesh export cache of final renders (export/mesh_cache.py) and its lifetime.

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
from bpy.app.handlers import persistent

from .export.mesh_cache import MeshCache

MESH_CACHE = MeshCache()


def keep_between_jobs(scene, background=None):
    """Whether the cache outlives a finished render job of `scene` (background: whether
    Blender runs in background mode; default bpy.app.background)."""
    if scene is not None and scene.render.use_persistent_data:
        return True
    return bool(bpy.app.background if background is None else background)


def cache_for(engine, scene):
    """The cache a render of `scene` by `engine` uses, or None: frames of an animation job
    (`-a`, `-f A..B`: each is an animation job) and scenes with persistent data use it."""
    if engine.is_preview:
        return None
    if engine.is_animation or (scene is not None and scene.render.use_persistent_data):
        return MESH_CACHE
    MESH_CACHE.clear()  # nothing reuses what an earlier job left
    return None


@persistent
def _render_ended(scene, *args):
    if not keep_between_jobs(scene):
        MESH_CACHE.clear()


@persistent
def _file_loading(*args):
    MESH_CACHE.clear()


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
    MESH_CACHE.clear()
