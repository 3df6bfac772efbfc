"""The mesh export cache of final renders (export/mesh_cache.py) and its lifetime.

One module-level cache, because Blender makes a new engine instance for every frame of an
animation unless render.use_persistent_data is on. It lives for one render job (all frames of
an animation) and is emptied when the job completes or is cancelled, unless the scene uses
persistent data (then it is kept for the next render too, as Cycles keeps its scene).
Preview renders (material thumbnails) never use it.
"""

import bpy
from bpy.app.handlers import persistent

from .export.mesh_cache import MeshCache

MESH_CACHE = MeshCache()


@persistent
def _render_ended(scene, *args):
    if scene is None or not scene.render.use_persistent_data:
        MESH_CACHE.clear()


_HANDLERS = (bpy.app.handlers.render_complete, bpy.app.handlers.render_cancel)


def register():
    for handlers in _HANDLERS:
        if _render_ended not in handlers:
            handlers.append(_render_ended)


def unregister():
    for handlers in _HANDLERS:
        if _render_ended in handlers:
            handlers.remove(_render_ended)
    MESH_CACHE.clear()
