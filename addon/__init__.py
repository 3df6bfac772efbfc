"""Pathlight: a fast, accurate path tracer as a Blender render engine.

Thin add-on in Cycles' style: engine.py delegates to session.py, which exports the scene
(export/) and drives the compiled core (imported lazily by core.py only).
"""

bl_info = {
    "name": "Pathlight",
    "author": "Pathlight developers",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "Render Properties > Render Engine > Pathlight",
    "description": "Fast, accurate path tracer",
    "category": "Render",
}

import atexit

from . import engine, properties, ui

_modules = (properties, engine, ui)
_registered = False


def register():
    global _registered
    if _registered:
        return
    for module in _modules:
        module.register()
    _registered = True


def unregister():
    global _registered
    if not _registered:
        return
    for module in reversed(_modules):
        module.unregister()
    _registered = False


# The bpy module (pip `bpy`) hangs at interpreter exit while a RenderEngine class is still
# registered; unregistering first avoids that. A no-op in Blender, which disables add-ons first.
atexit.register(unregister)
