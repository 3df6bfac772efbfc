"""Render Properties panels, and Blender's standard panels opened up to Pathlight."""

import bpy


class PathlightPanel:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "render"
    COMPAT_ENGINES = {'PATHLIGHT'}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


class PATHLIGHT_RENDER_PT_sampling(PathlightPanel, bpy.types.Panel):
    bl_label = "Sampling"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.pathlight
        col = layout.column()
        col.prop(settings, "samples")
        col.prop(settings, "time_limit")
        col.prop(settings, "seed")
        col = layout.column()
        col.prop(settings, "max_bounces")
        col.prop(settings, "use_nee")


class PATHLIGHT_RENDER_PT_performance(PathlightPanel, bpy.types.Panel):
    bl_label = "Performance"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        rd = context.scene.render
        col = layout.column()
        col.prop(rd, "threads_mode")
        sub = col.column()
        sub.enabled = rd.threads_mode == 'FIXED'
        sub.prop(rd, "threads")


classes = (PATHLIGHT_RENDER_PT_sampling, PATHLIGHT_RENDER_PT_performance)

# Pathlight uses Blender's engine-agnostic panels (those listing 'BLENDER_RENDER', as Cycles
# does: output, camera, lens, light, world context, ...) plus EEVEE's node-based material and
# world surface panels, since Pathlight reads the same shader nodes.
EXTRA_PANELS = {
    "EEVEE_MATERIAL_PT_context_material",
    "EEVEE_MATERIAL_PT_surface",
    "MATERIAL_PT_preview",
    "EEVEE_WORLD_PT_surface",
}
# Light previews need bl_use_preview.
EXCLUDED_PANELS = {"DATA_PT_preview"}


def compat_panels():
    """Blender's own panels that Pathlight adds itself to."""
    panels = []
    for panel in bpy.types.Panel.__subclasses__():
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if engines is None or panel.__name__ in EXCLUDED_PANELS:
            continue
        if 'BLENDER_RENDER' in engines or panel.__name__ in EXTRA_PANELS:
            panels.append(panel)
    return panels


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for panel in compat_panels():
        panel.COMPAT_ENGINES.add('PATHLIGHT')


def unregister():
    for panel in compat_panels():
        panel.COMPAT_ENGINES.discard('PATHLIGHT')
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
