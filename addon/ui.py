"""Render Properties panels, and Blender's standard panels opened up to Pathlight."""

import bpy


def split(layout):
    """The layout with labels left of the values, as Cycles' panels draw."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout


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
        layout = split(self.layout)
        settings = context.scene.pathlight
        heading = layout.column(align=True, heading="Noise Threshold")
        row = heading.row(align=True)
        row.prop(settings, "use_adaptive_sampling", text="")
        sub = row.row()
        sub.active = settings.use_adaptive_sampling
        sub.prop(settings, "adaptive_threshold", text="")
        col = layout.column(align=True)
        col.prop(settings, "samples", text="Max Samples" if settings.use_adaptive_sampling
                 else "Samples")
        sub = col.column(align=True)
        sub.active = settings.use_adaptive_sampling
        sub.prop(settings, "adaptive_min_samples")
        col.prop(settings, "time_limit")
        col.prop(settings, "preview_samples")
        col = layout.column(align=True)
        col.prop(settings, "sampler")
        col.prop(settings, "pixel_pattern")
        row = col.row(align=True)
        row.prop(settings, "seed")
        row.prop(settings, "use_animated_seed", text="", icon='TIME')
        col.prop(settings, "use_layer_samples")
        col.prop(settings, "sample_offset")
        sub = col.column(align=True)
        sub.active = settings.sample_offset > 0 or settings.frame_samples > 0
        sub.prop(settings, "frame_samples")
        layout.prop(settings, "use_nee")
        layout.prop(settings, "use_guiding")


def draw_denoise(layout, settings, viewport):
    """The Denoise subpanels' fields, as Cycles' (render: denoising_*, viewport: preview_*)."""
    prefix = "preview_denoising_" if viewport else "denoising_"
    layout = split(layout)
    layout.active = settings.use_preview_denoising if viewport else settings.use_denoising
    col = layout.column()
    col.label(text="Denoiser: OpenImageDenoise (CPU)")
    col.prop(settings, prefix + "input_passes", text="Passes")
    sub = col.column()
    sub.active = getattr(settings, prefix + "input_passes") != 'RGB'
    sub.prop(settings, prefix + "prefilter", text="Prefilter")
    col.prop(settings, prefix + "quality", text="Quality")
    if viewport:
        col.prop(settings, "preview_denoising_start_sample", text="Start Sample")


class PATHLIGHT_RENDER_PT_sampling_viewport_denoise(PathlightPanel, bpy.types.Panel):
    """Cycles' Sampling > Viewport > Denoise: the check box in the header."""
    bl_label = "Viewport Denoise"
    bl_parent_id = "PATHLIGHT_RENDER_PT_sampling"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.scene.pathlight, "use_preview_denoising", text="")

    def draw(self, context):
        draw_denoise(self.layout, context.scene.pathlight, viewport=True)


class PATHLIGHT_RENDER_PT_sampling_denoise(PathlightPanel, bpy.types.Panel):
    """Cycles' Sampling > Render > Denoise."""
    bl_label = "Denoise"
    bl_parent_id = "PATHLIGHT_RENDER_PT_sampling"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.scene.pathlight, "use_denoising", text="")

    def draw(self, context):
        draw_denoise(self.layout, context.scene.pathlight, viewport=False)


class PATHLIGHT_RENDER_PT_light_paths(PathlightPanel, bpy.types.Panel):
    bl_label = "Light Paths"

    def draw(self, context):
        layout = split(self.layout)
        settings = context.scene.pathlight
        col = layout.column(align=True)
        col.prop(settings, "max_bounces", text="Total")
        col = layout.column(align=True)
        col.prop(settings, "diffuse_bounces")
        col.prop(settings, "glossy_bounces")
        col.prop(settings, "transmission_bounces")
        col.prop(settings, "volume_bounces")
        col.prop(settings, "transparent_bounces")
        layout.prop(settings, "use_schlick_fresnel")


class PATHLIGHT_RENDER_PT_light_paths_clamping(PathlightPanel, bpy.types.Panel):
    bl_label = "Clamping"
    bl_parent_id = "PATHLIGHT_RENDER_PT_light_paths"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = split(self.layout)
        settings = context.scene.pathlight
        col = layout.column(align=True)
        col.prop(settings, "sample_clamp_direct")
        col.prop(settings, "sample_clamp_indirect")


def caustics_in_effect(settings):
    """The Caustics panel's line: which of its settings the render follows."""
    tricks = (settings.blur_glossy > 0.0 or not settings.caustics_reflective
              or not settings.caustics_refractive)
    if tricks and (settings.use_caustic_light_paths or settings.caustic_light_paths_auto):
        return "Off: not with Filter Glossy or Reflective / Refractive off"
    if settings.use_caustic_light_paths:
        return f"On: {settings.caustic_light_paths:g} light paths per sample"
    if settings.caustic_light_paths_auto:
        return "Automatic: 0.1 per sample under an environment's sun, 0.25 for lamps over glass"
    return "Off"


class PATHLIGHT_RENDER_PT_light_paths_caustics(PathlightPanel, bpy.types.Panel):
    bl_label = "Caustics"
    bl_parent_id = "PATHLIGHT_RENDER_PT_light_paths"

    def draw(self, context):
        layout = split(self.layout)
        settings = context.scene.pathlight
        # Cycles' own three first, as its Caustics panel lays them out; then Pathlight's light paths.
        col = layout.column()
        col.prop(settings, "blur_glossy")
        col = layout.column(heading="Caustics", align=True)
        col.prop(settings, "caustics_reflective", text="Reflective")
        col.prop(settings, "caustics_refractive", text="Refractive")
        layout.separator()
        layout.prop(settings, "use_caustic_light_paths")
        sub = layout.column()
        sub.active = settings.use_caustic_light_paths
        sub.prop(settings, "caustic_light_paths")
        sub = layout.column()
        sub.active = not settings.use_caustic_light_paths
        sub.prop(settings, "caustic_light_paths_auto")
        self.layout.label(text=caustics_in_effect(settings))


class PATHLIGHT_RENDER_PT_light_paths_fast_gi(PathlightPanel, bpy.types.Panel):
    """Cycles' Fast GI Approximation panel, laid out as Cycles lays it out."""
    bl_label = "Fast GI Approximation"
    bl_parent_id = "PATHLIGHT_RENDER_PT_light_paths"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.scene.pathlight, "use_fast_gi", text="")

    def draw(self, context):
        layout = split(self.layout)
        settings = context.scene.pathlight
        world = context.scene.world
        layout.active = settings.use_fast_gi
        col = layout.column(align=True)
        col.prop(settings, "fast_gi_method", text="Method")
        if world:
            light = world.light_settings
            col = layout.column(align=True)
            col.prop(light, "ao_factor", text="AO Factor")
            col.prop(light, "distance", text="AO Distance")
        if settings.fast_gi_method == 'REPLACE':
            col = layout.column(align=True)
            col.prop(settings, "ao_bounces", text="Viewport Bounces")
            col.prop(settings, "ao_bounces_render", text="Render Bounces")


class PATHLIGHT_RENDER_PT_motion_blur(PathlightPanel, bpy.types.Panel):
    """Cycles' Motion Blur panel (Blender's own settings, and the rolling shutter under
    Cycles' names)."""
    bl_label = "Motion Blur"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.scene.render, "use_motion_blur", text="")

    def draw(self, context):
        layout = split(self.layout)
        rd = context.scene.render
        settings = context.scene.pathlight
        layout.active = rd.use_motion_blur
        col = layout.column()
        col.prop(rd, "motion_blur_position", text="Position")
        col.prop(rd, "motion_blur_shutter")
        col.separator()
        col.prop(settings, "rolling_shutter_type", text="Rolling Shutter")
        sub = col.column()
        sub.active = settings.rolling_shutter_type != 'NONE'
        sub.prop(settings, "rolling_shutter_duration")


class PATHLIGHT_RENDER_PT_film(PathlightPanel, bpy.types.Panel):
    bl_label = "Film"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = split(self.layout)
        layout.prop(context.scene.pathlight, "film_exposure")


class PATHLIGHT_RENDER_PT_film_transparency(PathlightPanel, bpy.types.Panel):
    """Film > Transparent, with Transparent Glass under it as in Cycles."""
    bl_label = "Transparent"
    bl_parent_id = "PATHLIGHT_RENDER_PT_film"

    def draw_header(self, context):
        self.layout.prop(context.scene.render, "film_transparent", text="")

    def draw(self, context):
        layout = split(self.layout)
        rd = context.scene.render
        settings = context.scene.pathlight
        layout.active = rd.film_transparent
        col = layout.column()
        col.prop(settings, "film_transparent_glass", text="Transparent Glass")
        sub = col.column()
        sub.active = rd.film_transparent and settings.film_transparent_glass
        sub.prop(settings, "film_transparent_roughness", text="Roughness Threshold")


class PATHLIGHT_RENDER_PT_debug(PathlightPanel, bpy.types.Panel):
    bl_label = "Debug"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = split(self.layout)
        layout.prop(context.scene.pathlight, "debug_view")
        layout.prop(context.scene.pathlight, "use_general_kernel")


class PATHLIGHT_VIEWLAYER_PT_passes(PathlightPanel, bpy.types.Panel):
    """The passes Pathlight renders; the rest of Blender's pass switches do nothing for it."""
    bl_label = "Passes"
    bl_context = "view_layer"

    def draw(self, context):
        layout = split(self.layout)
        view_layer = context.view_layer
        col = layout.column(heading="Data", align=True)
        col.prop(view_layer, "use_pass_combined")
        col.prop(view_layer, "use_pass_z")
        col.prop(view_layer, "use_pass_position")
        col.prop(view_layer, "use_pass_normal")
        col.prop(view_layer.pathlight, "use_pass_denoising_data")
        col.prop(view_layer.pathlight, "use_pass_sample_count")
        col.prop(view_layer, "use_pass_mist")
        col.prop(view_layer, "use_pass_object_index")
        col.prop(view_layer, "use_pass_material_index")
        col = layout.column(heading="Light", align=True)
        for kind in ("diffuse", "glossy", "transmission"):
            row = col.row(align=True)
            row.label(text=kind.capitalize())
            for part, text in (("direct", "Direct"), ("indirect", "Indirect"), ("color", "Color")):
                row.prop(view_layer, f"use_pass_{kind}_{part}", text=text, toggle=True)
        row = col.row(align=True)
        row.label(text="Volume")
        row.prop(view_layer.pathlight, "use_pass_volume_direct", text="Direct", toggle=True)
        row.prop(view_layer.pathlight, "use_pass_volume_indirect", text="Indirect", toggle=True)
        col = layout.column(heading="Other", align=True)
        col.prop(view_layer, "use_pass_emit", text="Emission")
        col.prop(view_layer, "use_pass_environment")
        col.prop(view_layer, "use_pass_ambient_occlusion", text="Ambient Occlusion")
        col.prop(view_layer.pathlight, "use_pass_shadow_catcher")


class PATHLIGHT_LIGHT_PT_light(PathlightPanel, bpy.types.Panel):
    """Below Blender's DATA_PT_light (which shows only the light type for other engines)."""
    bl_label = "Light"
    bl_context = "data"
    bl_options = {'HIDE_HEADER'}

    @classmethod
    def poll(cls, context):
        return context.light is not None and super().poll(context)

    def draw(self, context):
        layout = split(self.layout)
        light = context.light
        col = layout.column()
        row = col.row(align=True, heading="Temperature")
        row.prop(light, "use_temperature", text="")
        sub = row.row()
        sub.active = light.use_temperature
        sub.prop(light, "temperature", text="")
        col.prop(light, "color", text="Tint" if light.use_temperature else "Color")
        col = layout.column()
        col.prop(light, "energy")
        col.prop(light, "exposure")
        col.prop(light, "normalize")
        col = layout.column()
        if light.type in {'POINT', 'SPOT'}:
            col.prop(light, "shadow_soft_size", text="Radius")
            col.prop(light, "use_soft_falloff")
        elif light.type == 'SUN':
            col.prop(light, "angle")
        elif light.type == 'AREA':
            cycles = getattr(light, "cycles", None)  # Cycles' portal flag, which Pathlight reads
            if cycles is not None and hasattr(cycles, "is_portal"):
                col.prop(cycles, "is_portal", text="Portal")
            col.prop(light, "shape")
            sub = col.column(align=True)
            if light.shape in {'SQUARE', 'DISK'}:
                sub.prop(light, "size")
            else:
                sub.prop(light, "size", text="Size X")
                sub.prop(light, "size_y", text="Y")
            col.prop(light, "spread")
        col.prop(light, "use_shadow", text="Cast Shadow")
        cycles = getattr(light, "cycles", None)  # Cycles' Max Bounces, which Pathlight reads
        if cycles is not None and hasattr(cycles, "max_bounces"):
            col.prop(cycles, "max_bounces")


class PATHLIGHT_RENDER_PT_pixel_filter(PathlightPanel, bpy.types.Panel):
    bl_label = "Pixel Filter"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = split(self.layout)
        settings = context.scene.pathlight
        col = layout.column()
        col.prop(settings, "filter_type", text="Type")
        col.prop(settings, "filter_width")


class PATHLIGHT_RENDER_PT_autofocus(PathlightPanel, bpy.types.Panel):
    bl_label = "Autofocus"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.scene.pathlight, "use_autofocus", text="")

    def draw(self, context):
        layout = split(self.layout)
        settings = context.scene.pathlight
        col = layout.column()
        col.active = settings.use_autofocus
        col.prop(settings, "autofocus_point")
        cam = context.scene.camera
        if settings.use_autofocus and cam is not None and cam.type == 'CAMERA' \
                and not cam.data.dof.use_dof:
            col.label(text="Turn on the camera's Depth of Field", icon='INFO')


class PATHLIGHT_RENDER_PT_performance(PathlightPanel, bpy.types.Panel):
    bl_label = "Performance"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = split(self.layout)
        rd = context.scene.render
        col = layout.column()
        col.prop(rd, "threads_mode")
        sub = col.column()
        sub.enabled = rd.threads_mode == 'FIXED'
        sub.prop(rd, "threads")
        col = layout.column(heading="Acceleration Structure")
        col.prop(context.scene.pathlight, "use_spatial_splits")
        col = layout.column(heading="Lights")
        col.prop(context.scene.pathlight, "light_tree")


class PATHLIGHT_OBJECT_PT_shadow_catcher(PathlightPanel, bpy.types.Panel):
    """Cycles' Object ▸ Visibility ▸ Mask ▸ Shadow Catcher (Blender's own Visibility panel shows
    Holdout only)."""
    bl_label = "Shadow Catcher"
    bl_context = "object"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.object is not None

    def draw(self, context):
        layout = split(self.layout)
        layout.prop(context.object, "is_shadow_catcher")

class PATHLIGHT_OBJECT_PT_fast_gi(PathlightPanel, bpy.types.Panel):
    """Cycles' Object ▸ Visibility ▸ Fast GI Approximation: the object's own AO Distance
    (Cycles' object.cycles.ao_distance, which Pathlight reads)."""
    bl_label = "Fast GI Approximation"
    bl_context = "object"
    bl_parent_id = "OBJECT_PT_visibility"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        ob = context.object
        return super().poll(context) and ob is not None and ob.type != 'LIGHT' and \
            hasattr(getattr(ob, "cycles", None), "ao_distance")

    def draw(self, context):
        layout = split(self.layout)
        layout.active = context.scene.pathlight.use_fast_gi
        layout.prop(context.object.cycles, "ao_distance")


try:  # Blender's own list of the view layer's light groups (Cycles draws it with this helper)
    from bl_ui.properties_view_layer import ViewLayerLightgroupsPanelHelper
except ImportError:  # (an older Blender: no light groups)
    ViewLayerLightgroupsPanelHelper = None


def _lightgroup_field(layout, owner, view_layer):
    """Cycles' Light Group field: the name, searched among the view layer's groups (any name
    may be typed; one not in the list renders in no group), and + to add it to the list."""
    row = layout.row(align=True)
    row.use_property_decorate = False
    sub = row.column(align=True)
    sub.prop_search(owner, "lightgroup", view_layer, "lightgroups", text="Light Group",
                    results_are_suggestions=True)
    sub = row.column(align=True)
    sub.enabled = bool(owner.lightgroup) and not any(g.name == owner.lightgroup for g in view_layer.lightgroups)
    sub.operator("scene.view_layer_add_lightgroup", icon='ADD', text="").name = owner.lightgroup


class PATHLIGHT_OBJECT_PT_lightgroup(PathlightPanel, bpy.types.Panel):
    """Cycles' Object ▸ Shading ▸ Light Group (Blender's Shading panel is engine-agnostic; the
    field is drawn by Cycles' add-on)."""
    bl_label = "Light Group"
    bl_parent_id = "OBJECT_PT_shading"
    bl_context = "object"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.object is not None and hasattr(context.object, "lightgroup")

    def draw(self, context):
        layout = split(self.layout)
        _lightgroup_field(layout, context.object, context.view_layer)


class PATHLIGHT_WORLD_PT_lightgroup(PathlightPanel, bpy.types.Panel):
    """Cycles' World ▸ Settings ▸ Light Group."""
    bl_label = "Light Group"
    bl_context = "world"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.world is not None and hasattr(context.world, "lightgroup")

    def draw(self, context):
        layout = split(self.layout)
        _lightgroup_field(layout, context.world, context.view_layer)


class PATHLIGHT_WORLD_PT_sampling(PathlightPanel, bpy.types.Panel):
    """Cycles' World ▸ Settings ▸ Surface ▸ Sampling: Method (None: the world is no light to
    sample, rays alone find it) and Manual's Map Resolution (a node-tree world's sampling map)."""
    bl_label = "Sampling"
    bl_context = "world"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.world is not None and hasattr(context.world, "cycles")

    def draw(self, context):
        layout = split(self.layout)
        cworld = context.world.cycles
        layout.prop(cworld, "sampling_method", text="Sampling")
        if cworld.sampling_method == 'MANUAL':
            layout.prop(cworld, "sample_map_resolution")


light_group_classes = (PATHLIGHT_OBJECT_PT_lightgroup, PATHLIGHT_WORLD_PT_lightgroup, PATHLIGHT_WORLD_PT_sampling)
if ViewLayerLightgroupsPanelHelper is not None:
    class PATHLIGHT_VIEWLAYER_PT_lightgroups(PathlightPanel, ViewLayerLightgroupsPanelHelper, bpy.types.Panel):
        """View Layer ▸ Passes ▸ Light Groups, Blender's list (its helper, as Cycles' panel)."""
        bl_label = "Light Groups"
        bl_parent_id = "PATHLIGHT_VIEWLAYER_PT_passes"
        bl_context = "view_layer"
    light_group_classes += (PATHLIGHT_VIEWLAYER_PT_lightgroups,)

class PATHLIGHT_VIEWLAYER_PT_denoising(PathlightPanel, bpy.types.Panel):
    """Cycles' View Layer ▸ Denoising: whether this view layer's render is denoised."""
    bl_label = "Denoising"
    bl_context = "view_layer"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.view_layer.pathlight, "use_denoising", text="")

    def draw(self, context):
        self.layout.active = context.view_layer.pathlight.use_denoising
        self.layout.label(text="With Sampling ▸ Denoise on (its settings)")


class PATHLIGHT_VIEW3D_PT_shading_render_pass(PathlightPanel, bpy.types.Panel):
    """The shading popover's Render Pass in Rendered mode, as Cycles' CYCLES_VIEW3D_PT_shading_render_pass."""
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'HEADER'
    bl_parent_id = 'VIEW3D_PT_shading'
    bl_label = "Render Pass"

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES and context.space_data.shading.type == 'RENDERED'

    def draw(self, context):
        settings = context.space_data.shading.pathlight
        layout = self.layout
        layout.prop(settings, "render_pass", text="")
        view_layer = context.view_layer
        if settings.render_pass == 'LIGHT_GROUP':
            layout.prop_search(settings, "light_group", view_layer, "lightgroups", text="")
        elif settings.render_pass == 'AOV':
            layout.prop_search(settings, "aov_name", view_layer, "aovs", text="")


classes = (PATHLIGHT_RENDER_PT_sampling, PATHLIGHT_RENDER_PT_sampling_viewport_denoise,
           PATHLIGHT_RENDER_PT_sampling_denoise, PATHLIGHT_RENDER_PT_light_paths, PATHLIGHT_RENDER_PT_light_paths_caustics,
           PATHLIGHT_RENDER_PT_light_paths_clamping, PATHLIGHT_RENDER_PT_light_paths_fast_gi,
           PATHLIGHT_RENDER_PT_motion_blur,
           PATHLIGHT_RENDER_PT_film, PATHLIGHT_RENDER_PT_film_transparency,
           PATHLIGHT_RENDER_PT_pixel_filter, PATHLIGHT_RENDER_PT_autofocus,
           PATHLIGHT_RENDER_PT_performance, PATHLIGHT_RENDER_PT_debug, PATHLIGHT_LIGHT_PT_light,
           PATHLIGHT_VIEWLAYER_PT_passes, PATHLIGHT_VIEWLAYER_PT_denoising, PATHLIGHT_OBJECT_PT_shadow_catcher,
           PATHLIGHT_OBJECT_PT_fast_gi,
           PATHLIGHT_VIEW3D_PT_shading_render_pass) + light_group_classes

# Pathlight uses Blender's engine-agnostic panels (those listing 'BLENDER_RENDER', as Cycles
# does: output, camera, lens, light, world context, ...) plus EEVEE's node-based material and
# world surface panels, since Pathlight reads the same shader nodes, and the camera's depth of
# field panels.
EXTRA_PANELS = {
    "EEVEE_MATERIAL_PT_context_material",
    "EEVEE_MATERIAL_PT_surface",
    "MATERIAL_PT_preview",
    "EEVEE_WORLD_PT_surface",
    "DATA_PT_camera_dof",  # depth of field: Pathlight reads Blender's own DOF settings
    "DATA_PT_camera_dof_aperture",
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
