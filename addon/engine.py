"""The RenderEngine: every callback delegates to session.py (Cycles-style thin engine)."""

import bpy

from . import session


class PathlightRenderEngine(bpy.types.RenderEngine):
    bl_idname = "PATHLIGHT"
    bl_label = "Pathlight"
    bl_use_shading_nodes_custom = False  # use Blender's shader nodes (Principled BSDF, ...)
    bl_use_preview = False  # no material previews yet
    bl_use_eevee_viewport = True  # Material Preview shading uses EEVEE

    def render(self, depsgraph):
        session.render(self, depsgraph)

    def update_render_passes(self, scene=None, renderlayer=None):
        session.update_render_passes(self, scene, renderlayer)


classes = (PathlightRenderEngine,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
