"""Per-scene render settings, shown as `scene.pathlight`.

Threads are not stored here: Blender's own `scene.render.threads_mode` / `threads` are used.
"""

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, PointerProperty


class PathlightSceneSettings(bpy.types.PropertyGroup):
    samples: IntProperty(
        name="Samples", description="Samples per pixel for the final render",
        default=128, min=1, max=1 << 24, soft_max=4096,
    )
    time_limit: FloatProperty(
        name="Time Limit", description="Stop rendering after this time (0 = no limit)",
        default=0.0, min=0.0, step=100.0, unit='TIME_ABSOLUTE',
    )
    max_bounces: IntProperty(
        name="Max Bounces", description="Total maximum number of bounces of a path",
        default=12, min=0, max=1024,
    )
    seed: IntProperty(
        name="Seed", description="Seed of the random number sequences",
        default=0, min=0,
    )
    use_nee: BoolProperty(
        name="Next-Event Estimation",
        description="Sample emissive surfaces directly (with MIS): less noise from small lights",
        default=True,
    )


classes = (PathlightSceneSettings,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.pathlight = PointerProperty(type=PathlightSceneSettings)


def unregister():
    del bpy.types.Scene.pathlight
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
