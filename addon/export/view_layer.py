"""What the rendered view layer changes in the export, read as Cycles' BlenderSync reads it
(sync_view_layer, find_used_shaders, sync_world): Material Override, World Override, the
Filter toggles. Plain values read once per export; nothing here is kept between exports, so a
layer's override never reaches the next layer's or the next render's scene (the mesh cache
keys its entries by the materials' names, see mesh_cache.MeshCache._key)."""

from dataclasses import dataclass


@dataclass(frozen=True)
class LayerSettings:
    material_override: object = None  # bpy Material every object's slots render with, or None
    world: object = None  # the world the layer renders: its World Override, else the scene's
    use_sky: bool = True  # Filter ▸ Environment: off, the world is black everywhere
    use_solid: bool = True  # Filter ▸ Surfaces: off, no mesh geometry at all (not only hidden)
    use_strand: bool = True  # Filter ▸ Curves: off, no curves objects and no particle hair
    use_volumes: bool = True  # Filter ▸ Volumes: off, no volume objects (volume materials stay)
    use_motion_blur: bool = True  # Filter ▸ Motion Blur (and the scene's own toggle)


def _evaluated(id_data, depsgraph):
    """The depsgraph's copy of an ID (animated values), else the ID itself."""
    if id_data is None or depsgraph is None:
        return id_data
    try:
        return id_data.evaluated_get(depsgraph)
    except (AttributeError, RuntimeError, TypeError, ReferenceError):
        return id_data


def layer_settings(depsgraph, preview=False):
    """The LayerSettings of the depsgraph's view layer. preview: material thumbnails, which
    render their own preview scene as Cycles does (defaults)."""
    scene = depsgraph.scene
    view_layer = getattr(depsgraph, "view_layer", None)
    if preview or view_layer is None:
        return LayerSettings(world=scene.world)
    world = getattr(view_layer, "world_override", None)
    world = _evaluated(world, depsgraph) if world is not None else scene.world
    return LayerSettings(
        material_override=_evaluated(getattr(view_layer, "material_override", None), depsgraph),
        world=world,
        use_sky=bool(getattr(view_layer, "use_sky", True)),
        use_solid=bool(getattr(view_layer, "use_solid", True)),
        use_strand=bool(getattr(view_layer, "use_strand", True)),
        use_volumes=bool(getattr(view_layer, "use_volumes", True)),
        use_motion_blur=bool(getattr(view_layer, "use_motion_blur", True)))


def layer_world(depsgraph):
    """The world a render of the depsgraph's view layer shades with (its World Override, else
    the scene's), before the Environment filter; None without one."""
    return layer_settings(depsgraph).world


def lit_world(settings):
    """The world whose shader renders (None: black everywhere): Cycles' Background uses its
    empty shader when the layer's Environment filter is off (no light, no world volume)."""
    return settings.world if settings.use_sky else None


def slot_materials(slots, settings):
    """The materials of an object's slots as the layer renders them: with a Material Override
    every slot takes it, and an object without slots too (Cycles' find_used_shaders)."""
    override = settings.material_override
    if override is None:
        return [slot.material for slot in slots]
    return [override] * max(1, len(slots))


def first_material(obj, settings):
    """The material of an object's first slot (curves, point clouds, volumes), overridden."""
    if settings.material_override is not None:
        return settings.material_override
    return obj.material_slots[0].material if len(obj.material_slots) else None
