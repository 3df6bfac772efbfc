"""The RenderEngine: every callback delegates to session.py (Cycles-style thin engine)."""

import bpy

from . import bake, render_cache, session, viewport_draw


class PathlightRenderEngine(bpy.types.RenderEngine):
    bl_idname = "PATHLIGHT"
    bl_label = "Pathlight"
    bl_use_shading_nodes_custom = False  # use Blender's shader nodes (Principled BSDF, ...)
    bl_use_preview = True  # material preview thumbnails render with Pathlight
    bl_use_eevee_viewport = True  # Material Preview shading uses EEVEE
    # Stereoscopy: the camera's Spherical Stereo (panoramic and perspective cameras), which the
    # core's camera does per ray (export/views.py), as Cycles.
    bl_use_spherical_stereo = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)  # required since Blender 4.4
        self._pathlight_viewport = None

    def __del__(self):
        try:
            viewport_draw.free(self)
        except Exception:  # the engine may be half torn down at exit
            pass

    def render(self, depsgraph):
        session.render(self, depsgraph)

    def bake(self, depsgraph, obj, pass_type, pass_filter, width, height):
        bake.bake(self, depsgraph, obj, pass_type, pass_filter, width, height)

    def view_update(self, context, depsgraph):
        viewport_draw.view_update(self, context, depsgraph)

    def view_draw(self, context, depsgraph):
        viewport_draw.view_draw(self, context, depsgraph)

    def update_render_passes(self, scene=None, renderlayer=None):
        session.update_render_passes(self, scene, renderlayer)


classes = (PathlightRenderEngine,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    render_cache.register()


def unregister():
    render_cache.unregister()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
