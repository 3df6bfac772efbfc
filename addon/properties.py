"""Per-scene render settings, shown as `scene.pathlight`.

Threads are not stored here: Blender's own `scene.render.threads_mode` / `threads` are used.
"""

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty,
                       PointerProperty, StringProperty)


def _requery_passes(self, context):
    """Pass switches change the compositor's Render Layers sockets: ask Blender to requery them
    (it calls RenderEngine.update_render_passes)."""
    scene = self.id_data
    for view_layer in getattr(scene, "view_layers", ()):
        view_layer.update_render_passes()


# Cycles' items (intern/cycles/blender/addon/properties.py), same identifiers and numbers.
_DENOISE_INPUTS = (
    ('RGB', "None", "Don't use utility passes for denoising", 1),
    ('RGB_ALBEDO', "Albedo", "Use albedo pass for denoising", 2),
    ('RGB_ALBEDO_NORMAL', "Albedo and Normal", "Use albedo and normal passes for denoising", 3),
)
_DENOISE_PREFILTERS = (
    ('NONE', "None", "No prefiltering, use when guiding passes are noise-free", 1),
    ('FAST', "Fast", "Denoise color and guiding passes together. Improves quality when guiding passes "
     "are noisy using least amount of extra processing time", 2),
    ('ACCURATE', "Accurate", "Prefilter noisy guiding passes before denoising color. Improves quality "
     "when guiding passes are noisy using extra processing time", 3),
)
_DENOISE_QUALITIES = (
    ('HIGH', "High", "High quality", 1),
    ('BALANCED', "Balanced", "Balanced between performance and quality", 2),
    ('FAST', "Fast", "High performance", 3),
)


class PathlightSceneSettings(bpy.types.PropertyGroup):
    samples: IntProperty(
        name="Samples", description="Samples per pixel for the final render",
        default=128, min=1, max=1 << 24, soft_max=4096,
    )
    use_layer_samples: EnumProperty(
        name="Layer Samples", description="How a view layer's own Samples (View Layer ▸ Samples, "
                                          "0 = the scene's) set its render's sample count",
        items=(('USE', "Use", "The view layer's samples replace the scene's"),
               ('BOUNDED', "Bounded", "The view layer's samples, where fewer than the scene's"),
               ('IGNORE', "Ignore", "The scene's samples for every view layer")),
        default='USE',
    )
    time_limit: FloatProperty(
        name="Time Limit", description="Stop rendering after this time (0 = no limit)",
        default=0.0, min=0.0, step=100.0, unit='TIME_ABSOLUTE',
    )
    max_bounces: IntProperty(
        name="Max Bounces", description="Total maximum number of bounces of a path",
        default=12, min=0, max=1024,
    )
    # Per-type limits with Cycles' defaults; the total above still applies.
    diffuse_bounces: IntProperty(
        name="Diffuse", description="Maximum number of diffuse reflection bounces",
        default=4, min=0, max=1024,
    )
    glossy_bounces: IntProperty(
        name="Glossy", description="Maximum number of glossy reflection bounces",
        default=4, min=0, max=1024,
    )
    transmission_bounces: IntProperty(
        name="Transmission", description="Maximum number of transmission bounces",
        default=12, min=0, max=1024,
    )
    volume_bounces: IntProperty(
        name="Volume", description="Maximum number of volume scattering events (0: only the "
        "direct light of the first scattering, as Cycles' default)",
        default=0, min=0, max=1024,
    )
    transparent_bounces: IntProperty(
        name="Transparent", description="Maximum number of transparent bounces (Transparent BSDF, "
        "Ray Portal, volume boundaries), for camera and shadow rays alike, as Cycles' Transparent "
        "Max Bounces",
        default=8, min=0, max=1024,
    )
    # Clamping, under Cycles' names (Light Paths > Clamping); off by default, unlike Cycles'
    # Clamp Indirect of 10, so that renders stay unbiased unless asked.
    sample_clamp_direct: FloatProperty(
        name="Direct Light",
        description="If non-zero, the most a direct-light sample (light straight from a lamp, "
                    "emitter or the world onto the first surface the camera sees, or seen by the "
                    "camera) may add, as Cycles' Clamp Direct: its red + green + blue at most three "
                    "times this (grey light: this per channel); brighter samples are scaled down: "
                    "fewer fireflies, at the cost of accuracy (biased). 0 = off, Pathlight's "
                    "default: unbiased",
        default=0.0, min=0.0, max=1e8, soft_max=100.0,
    )
    sample_clamp_indirect: FloatProperty(
        name="Indirect Light",
        description="If non-zero, the most an indirect-light sample (light that reached the first "
                    "surface the camera sees by way of other surfaces or volumes, caustics "
                    "included) may add, as Cycles' Clamp Indirect: its red + green + blue at most "
                    "three times this; brighter samples are scaled down: fewer fireflies, at the "
                    "cost of accuracy (biased). 0 = off, Pathlight's default (Cycles' is 10): "
                    "unbiased",
        default=0.0, min=0.0, max=1e8, soft_max=100.0,
    )
    # Caustics, under Cycles' names (Light Paths > Caustics); Filter Glossy off by default,
    # unlike Cycles' 1.0, so that renders stay unbiased unless asked.
    blur_glossy: FloatProperty(
        name="Filter Glossy",
        description="Adaptively blur glossy shaders after blurry bounces, to reduce noise at the "
                    "cost of accuracy, as Cycles' Filter Glossy: after a bounce whose direction was "
                    "unlikely (diffuse, rough glossy), glossy and glass shaders are made rougher "
                    "(biased). 0 = off, Pathlight's default (Cycles' is 1.0): unbiased. Anything "
                    "else turns the caustic light paths off",
        default=0.0, min=0.0, max=10.0,
    )
    caustics_reflective: BoolProperty(
        name="Reflective Caustics",
        description="Use reflective caustics, resulting in a brighter image (more noise but added "
                    "realism), as Cycles: off, glossy reflections are left out where a diffuse "
                    "bounce led (biased). Off turns the caustic light paths off",
        default=True,
    )
    caustics_refractive: BoolProperty(
        name="Refractive Caustics",
        description="Use refractive caustics, resulting in a brighter image (more noise but added "
                    "realism), as Cycles: off, refractions are left out where a diffuse bounce led "
                    "(biased). Off turns the caustic light paths off",
        default=True,
    )
    # Fast GI Approximation, under Cycles' names (Light Paths > Fast GI Approximation); its AO
    # factor and distance are the world's own (world.light_settings), as in Cycles.
    use_fast_gi: BoolProperty(
        name="Fast GI Approximation",
        description="Approximate diffuse indirect light with background tinted ambient occlusion. "
                    "This provides fast alternative to full global illumination, for interactive "
                    "viewport rendering or final renders with reduced quality (as Cycles; turns "
                    "path guiding and the caustic light paths off)",
        default=False,
    )
    fast_gi_method: EnumProperty(
        name="Fast GI Method", description="Fast GI approximation method",
        items=(('REPLACE', "Replace", "Replace global illumination with ambient occlusion after a "
                                      "specified number of bounces"),
               ('ADD', "Add", "Add ambient occlusion to diffuse surfaces")),
        default='REPLACE',
    )
    ao_bounces: IntProperty(
        name="AO Bounces",
        description="After this number of light bounces, use approximate global illumination. 0 "
                    "disables this feature (viewport)",
        default=1, min=0, max=1024,
    )
    ao_bounces_render: IntProperty(
        name="AO Bounces Render",
        description="After this number of light bounces, use approximate global illumination. 0 "
                    "disables this feature (final render)",
        default=1, min=0, max=1024,
    )
    # Motion Blur > Rolling Shutter, under Cycles' names.
    rolling_shutter_type: EnumProperty(
        name="Shutter Type",
        description="Type of rolling shutter effect matching CMOS-based cameras",
        items=(('NONE', "None", "No rolling shutter effect used"),
               ('TOP', "Top-Bottom", "Sensor is being scanned from top to bottom")),
        default='NONE',
    )
    rolling_shutter_duration: FloatProperty(
        name="Rolling Shutter Duration",
        description="Scanline \"exposure\" time for the rolling shutter effect",
        default=0.1, min=0.0, max=1.0,
    )
    # Film > Transparent > Transparent Glass, under Cycles' names.
    film_transparent_glass: BoolProperty(
        name="Transparent Glass",
        description="Render transmissive surfaces as transparent, for compositing glass over "
                    "another background",
        default=False,
    )
    film_transparent_roughness: FloatProperty(
        name="Transparent Roughness Threshold",
        description="For transparent transmission, keep surfaces with roughness above the "
                    "threshold opaque",
        default=0.1, min=0.0, max=1.0,
    )
    seed: IntProperty(
        name="Seed", description="Seed of the random number sequences",
        default=0, min=0,
    )
    sample_offset: IntProperty(
        name="Sample Offset",
        description="Render sample indices [offset, offset + samples): partial renders of one "
                    "frame (e.g. on several farm machines) with consecutive offsets merge into "
                    "one render of all their samples (python3 build.py merge)",
        default=0, min=0, max=(1 << 31) - 1,
    )
    preview_samples: IntProperty(
        name="Viewport Samples", description="Samples per pixel in the viewport's rendered shading",
        default=256, min=1, max=1 << 24, soft_max=4096,
    )
    use_animated_seed: BoolProperty(
        name="Use Animated Seed",
        description="Add the frame number to the seed, so that the noise changes from frame "
                    "to frame (as Cycles' option)",
        default=False,
    )
    # EnumProperty saves an item's number, not its name: each keeps its number, new ones go last.
    sampler: EnumProperty(
        name="Pattern", description="Random number pattern used to sample pixels and paths",
        items=(
            ('SOBOL', "Sobol", "Owen-scrambled Sobol low-discrepancy sequence in 4-D sets, as Cycles: less "
             "noise", 0),
            ('RANDOM', "Random", "Independent pseudo-random numbers", 1),
            # Measurement variants (docs/design/sampling.md, "Random numbers")
            ('SOBOL_DEEP', "Sobol Pairs (All Bounces)", "Sobol Pairs for every bounce, not only the first few",
             2),
            ('SOBOL4D', "Sobol 4-D Sets (Points Last)", "4-D Owen-scrambled Sobol sets with the points on "
             "their last two dimensions", 3),
            ('SOBOL4D_DEEP', "Sobol 4-D Sets (Points Last, All Bounces)", "Sobol 4-D Sets (Points Last) for "
             "every bounce", 4),
            ('SOBOL4D_RR', "Sobol 4-D Sets (Points Last), Own Roulette",
             "Sobol 4-D Sets (Points Last), Russian roulette on a sequence of its own (as Cycles)", 5),
            ('SOBOL4D_CYCLES', "Sobol, Own Roulette", "Sobol with the Russian roulette on a sequence of its own "
             "(as Cycles)", 6),
            ('SOBOL_PAIRS', "Sobol Pairs", "Owen-scrambled Sobol pairs, each 2-D draw its own sequence "
             "(Pathlight's default before 4-D sets)", 7),
        ),
        default='SOBOL',
    )
    pixel_pattern: EnumProperty(
        name="Noise Pattern",
        description="How the pixels share their random sequences (Cycles' sampling pattern)",
        items=(
            ('AUTOMATIC', "Automatic", "Blue-Noise for renders, Blue-Noise (First) in the viewport, as "
             "Cycles' Automatic", 0),
            ('BLUE_NOISE', "Blue-Noise", "Each pixel a consecutive chunk, as long as the frame's samples, of "
             "one sequence that neighbouring pixels share: their errors cancel, so regions and denoised "
             "images converge faster, and no pixel is noisier", 1),
            ('BLUE_NOISE_ROUND', "Blue-Noise (Round)", "Blue-Noise with chunks rounded up to a power of two "
             "samples", 2),
            ('BLUE_NOISE_FIRST', "Blue-Noise (First)", "The first sample blue noise of its own, the rest as "
             "Blue-Noise: a blue-noise first sample for the viewport", 3),
            ('INDEPENDENT', "Independent Pixels", "Each pixel its own sequence: neighbours' errors are "
             "independent (Pathlight's pattern before blue noise)", 4),
        ),
        # (Automatic, Cycles' default, fails Blender tests against Cycles: docs/design/sampling.md)
        default='INDEPENDENT',
    )
    frame_samples: IntProperty(
        name="Frame Samples",
        description="The frame's total samples when it is rendered in pieces with Sample Offset (0: "
                    "Sample Offset + Samples): blue noise lays its chunks out for this many, so that "
                    "the pieces merge into one render",
        default=0, min=0, max=(1 << 31) - 1,
    )
    use_adaptive_sampling: BoolProperty(
        name="Noise Threshold",
        description="Stop sampling pixels whose noise is below the threshold",
        default=True,
    )
    adaptive_threshold: FloatProperty(
        name="Noise Threshold",
        description="Noise level at which a pixel stops being sampled (lower: less noise, "
                    "longer renders)",
        default=0.01, min=0.0, soft_min=0.001, max=1.0, step=0.1, precision=4,
    )
    adaptive_min_samples: IntProperty(
        name="Min Samples",
        description="Samples every pixel gets before adaptive sampling stops any "
                    "(0 = automatic, from the noise threshold)",
        default=0, min=0, max=1 << 24,
    )
    use_guiding: BoolProperty(
        name="Path Guiding",
        description="Learn where light comes from during the first samples (up to half of them, "
                    "at most 255) and aim rough bounces there as well: less noise where light "
                    "arrives indirectly, e.g. a room lit through a window; costs time per sample",
        default=False,
    )
    caustic_light_paths_auto: BoolProperty(
        name="Automatic",
        description="Caustic light paths only where they pay: 0.1 per pixel sample under an "
                    "environment whose bright peak (a sun) holds most of its light, with smooth "
                    "surfaces; 0.25 where lamps with extent (a sun with an angle, a lamp with a "
                    "radius, an area lamp) send most of the light and smooth glass or mirrors "
                    "catch it; else none, silently. Caustic Light Paths, when on, overrides it",
        default=True,
    )
    use_caustic_light_paths: BoolProperty(
        name="Caustic Light Paths",
        description="Trace light paths from the environment and from lamps through smooth "
                    "(mirror-like) surfaces and smooth glass onto rough ones and combine them with "
                    "the camera's paths by multiple importance sampling: far less noise in "
                    "caustics of a bright HDRI (e.g. the sun reflected by chrome onto a floor). "
                    "Any pixel filter; perspective camera (depth of field included), orthographic "
                    "with depth of field, panoramic without it, motion blur too; no volumes; "
                    "Combined pass only",
        default=False,
    )
    caustic_light_paths: FloatProperty(
        name="Light Paths", description="Light paths per pixel sample",
        default=0.1, min=0.01, max=64.0, soft_max=4.0,
    )
    use_schlick_fresnel: BoolProperty(
        name="Schlick Fresnel",
        description="Use Schlick's approximation of the dielectric Fresnel reflectance (glass, "
                    "refraction, Principled specular) instead of the exact formula",
        default=False,
    )
    use_nee: BoolProperty(
        name="Next-Event Estimation",
        description="Sample emissive surfaces directly (with MIS): less noise from small lights",
        default=True,
    )
    # Pixel filter: Cycles' film filter and its default (Blackman-Harris, 1.5 px), so images
    # look the same in both engines.
    filter_type: EnumProperty(
        name="Pixel Filter", description="Pixel filter type",
        items=(
            ('BOX', "Box", "Box filter: sharpest, may alias"),
            ('GAUSSIAN', "Gaussian", "Gaussian filter"),
            ('BLACKMAN_HARRIS', "Blackman-Harris", "Blackman-Harris filter: smooth, little "
                                                   "blurring (Cycles' default)"),
        ),
        default='BLACKMAN_HARRIS',
    )
    filter_width: FloatProperty(
        name="Width", description="Pixel filter width",
        default=1.5, min=0.01, max=10.0, soft_max=3.0, subtype='PIXEL',
    )
    use_autofocus: BoolProperty(
        name="Autofocus",
        description="Focus the camera's depth of field on the surface seen at the focus point "
                    "(instead of the camera's focus distance or object)",
        default=False,
    )
    autofocus_point: FloatVectorProperty(
        name="Focus Point",
        description="Point of the image to focus on (0..1 from the bottom-left; 0.5, 0.5 is "
                    "the centre)",
        size=2, default=(0.5, 0.5), min=0.0, max=1.0, subtype='XYZ',
    )
    film_exposure: FloatProperty(
        name="Exposure",
        description="Image brightness scale: a linear multiplier of the image and the light "
                    "passes (Cycles' film exposure)",
        default=1.0, min=0.0, soft_max=10.0,
    )
    debug_view: EnumProperty(
        name="Debug View", description="Render a picture of the renderer's work instead of the scene",
        items=(
            ('NONE', "None", "Render the scene"),
            ('BVH', "BVH", "Heat map of the BVH nodes each pixel's camera ray visits (one ray through "
                           "each pixel centre); the raw counts go to the BVH Nodes and BVH Triangles passes"),
        ),
        default='NONE', update=_requery_passes,
    )
    use_spatial_splits: BoolProperty(
        name="Spatial Splits",
        description="Build the BVH of final renders with spatial splits (SBVH): triangles may be cut "
                    "between nodes, which makes tracing faster where big or long thin triangles overlap "
                    "other geometry (architecture), at a slower build. The viewport never uses them",
        default=False,
    )
    light_tree: EnumProperty(
        name="Light Tree",
        description="How next-event estimation picks a light in final renders",
        items=(
            ('AUTO', "Auto", "A light tree where the scene has more than 8 lights (sun and world "
                             "aside), else one distribution by power"),
            ('ON', "On", "Always the light tree: lights chosen by their importance at the shading point"),
            ('OFF', "Off", "Always one distribution by power (each light as often everywhere)"),
        ),
        default='AUTO',
    )
    # Denoising with Open Image Denoise (addon/denoise.py), under Cycles' names and meanings.
    use_denoising: BoolProperty(
        name="Denoise",
        description="Denoise the rendered image with Open Image Denoise (Blender's own library, as "
                    "Cycles) after the last sample. Off by default in Pathlight (on in Cycles), so "
                    "that renders stay unchanged unless asked",
        default=False, update=_requery_passes,
    )
    denoising_input_passes: EnumProperty(
        name="Passes", description="Passes used by the denoiser to distinguish noise from shader "
        "and geometry detail",
        items=_DENOISE_INPUTS, default='RGB_ALBEDO_NORMAL',
    )
    denoising_prefilter: EnumProperty(
        name="Prefilter", description="Prefilter the input passes (albedo, normal) before denoising",
        items=_DENOISE_PREFILTERS, default='ACCURATE',
    )
    denoising_quality: EnumProperty(
        name="Quality", description="Overall denoising quality (higher: slower)",
        items=_DENOISE_QUALITIES, default='HIGH',
    )
    use_preview_denoising: BoolProperty(
        name="Viewport Denoise",
        description="Denoise the viewport's image with Open Image Denoise from the start sample on "
                    "(when the samples shown have doubled since the last denoise, and at the last)",
        default=False,
    )
    preview_denoising_input_passes: EnumProperty(
        name="Passes", description="Passes used by the viewport's denoiser",
        items=_DENOISE_INPUTS, default='RGB_ALBEDO',
    )
    preview_denoising_prefilter: EnumProperty(
        name="Prefilter", description="Prefilter the viewport's input passes before denoising",
        items=_DENOISE_PREFILTERS, default='FAST',
    )
    preview_denoising_quality: EnumProperty(
        name="Quality", description="Viewport denoising quality (higher: slower)",
        items=_DENOISE_QUALITIES, default='BALANCED',
    )
    preview_denoising_start_sample: IntProperty(
        name="Start Sample", description="Sample to start denoising the viewport at",
        default=1, min=1, max=1 << 24, soft_max=4096,
    )
    use_general_kernel: BoolProperty(
        name="General Kernel",
        description="Render with the general integrator kernel instead of the one specialised for "
                    "the scene's features (same image, slower; for comparisons)",
        default=False,
    )


class PathlightViewLayerSettings(bpy.types.PropertyGroup):
    """Passes Blender's view layer has no switch for (the others use view_layer.use_pass_*)."""
    use_pass_denoising_data: BoolProperty(
        name="Denoising Data",
        description="Denoising Normal and Denoising Albedo passes, for the compositor's Denoise node; "
                    "with Denoise on, also the Noisy Image pass (Combined before denoising)",
        default=False, update=_requery_passes,
    )
    use_pass_sample_count: BoolProperty(
        name="Sample Count",
        description="Samples taken in each pixel (differs per pixel with adaptive sampling)",
        default=False, update=_requery_passes,
    )
    use_pass_volume_direct: BoolProperty(
        name="Volume Direct",
        description="Light samples and emission that reach a path's first scattering in a volume (Cycles' VolumeDir)",
        default=False, update=_requery_passes,
    )
    use_pass_volume_indirect: BoolProperty(
        name="Volume Indirect",
        description="The rest of the light of paths that first scatter in a volume (Cycles' VolumeInd)",
        default=False, update=_requery_passes,
    )
    use_pass_shadow_catcher: BoolProperty(
        name="Shadow Catcher",
        description="Cycles' Shadow Catcher pass: the light shadow catchers receive with the other objects over "
                    "what they would without them (multiply the backdrop by it); Combined is then the matte alone",
        default=False, update=_requery_passes,
    )
    use_denoising: BoolProperty(
        name="Denoising",
        description="Denoise this view layer when Sampling ▸ Denoise is on (Cycles' View Layer ▸ Denoising; "
                    "Cycles' own switch, where set off, turns it off too)",
        default=True, update=_requery_passes,
    )


# The viewport's Render Pass (Rendered shading): Cycles 4.5's list (its
# enum_view3d_shading_render_pass, same identifiers), plus a light group and a shader
# AOV of the view layer, named in light_group / aov_name (as EEVEE's View3DShading.aov_name).
VIEWPORT_PASS_ITEMS = (
    ('', "General", ""),
    ('COMBINED', "Combined", "Show the Combined render pass"),
    ('EMISSION', "Emission", "Show the Emission render pass"),
    ('BACKGROUND', "Background", "Show the Background render pass"),
    ('AO', "Ambient Occlusion", "Show the Ambient Occlusion render pass"),
    ('SHADOW_CATCHER', "Shadow Catcher", "Show the Shadow Catcher render pass"),
    ('', "Light", ""),
    ('DIFFUSE_DIRECT', "Diffuse Direct", "Show the Diffuse Direct render pass"),
    ('DIFFUSE_INDIRECT', "Diffuse Indirect", "Show the Diffuse Indirect render pass"),
    ('DIFFUSE_COLOR', "Diffuse Color", "Show the Diffuse Color render pass"),
    ('GLOSSY_DIRECT', "Glossy Direct", "Show the Glossy Direct render pass"),
    ('GLOSSY_INDIRECT', "Glossy Indirect", "Show the Glossy Indirect render pass"),
    ('GLOSSY_COLOR', "Glossy Color", "Show the Glossy Color render pass"),
    ('', "", ""),
    ('TRANSMISSION_DIRECT', "Transmission Direct", "Show the Transmission Direct render pass"),
    ('TRANSMISSION_INDIRECT', "Transmission Indirect", "Show the Transmission Indirect render pass"),
    ('TRANSMISSION_COLOR', "Transmission Color", "Show the Transmission Color render pass"),
    ('VOLUME_DIRECT', "Volume Direct", "Show the Volume Direct render pass"),
    ('VOLUME_INDIRECT', "Volume Indirect", "Show the Volume Indirect render pass"),
    ('LIGHT_GROUP', "Light Group", "Show one light group's pass (View Layer > Light Groups)"),
    ('', "Data", ""),
    ('POSITION', "Position", "Show the Position render pass"),
    ('NORMAL', "Normal", "Show the Normal render pass"),
    ('UV', "UV", "Show the UV render pass"),
    ('MIST', "Mist", "Show the Mist render pass"),
    ('DENOISING_ALBEDO', "Denoising Albedo", "Albedo pass used by denoiser"),
    ('DENOISING_NORMAL', "Denoising Normal", "Normal pass used by denoiser"),
    ('SAMPLE_COUNT', "Sample Count", "Per-pixel number of samples"),
    ('AOV', "Shader AOV", "Show one shader AOV (View Layer > Shader AOV)"),
)


class PathlightView3DShadingSettings(bpy.types.PropertyGroup):
    """The 3D viewport's Render Pass (View3DShading.pathlight, as Cycles' View3DShading.cycles)."""
    render_pass: EnumProperty(
        name="Render Pass", description="Render pass to show in the 3D Viewport",
        items=VIEWPORT_PASS_ITEMS, default='COMBINED',
    )
    light_group: StringProperty(
        name="Light Group", description="The view layer's light group shown (Render Pass: Light Group)",
    )
    aov_name: StringProperty(
        name="Shader AOV", description="The view layer's shader AOV shown (Render Pass: Shader AOV)",
    )


classes = (PathlightSceneSettings, PathlightViewLayerSettings, PathlightView3DShadingSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.pathlight = PointerProperty(type=PathlightSceneSettings)
    bpy.types.ViewLayer.pathlight = PointerProperty(type=PathlightViewLayerSettings)
    bpy.types.View3DShading.pathlight = PointerProperty(type=PathlightView3DShadingSettings)


def unregister():
    del bpy.types.View3DShading.pathlight
    del bpy.types.ViewLayer.pathlight
    del bpy.types.Scene.pathlight
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
