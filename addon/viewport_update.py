"""What a viewport change means for the render: depsgraph updates -> an UpdatePlan.

Pure logic, no bpy and no core: `describe_updates` turns `depsgraph.updates` into plain
`Update` records (the only function here that reads Blender objects), and `plan_updates`
decides from those records, the previous `ViewState` and the current settings what must be
redone. The viewport session (viewport.py) carries the plan out.

What Blender reports (checked with depsgraph_update_post in bpy 4.5; tests/blender/test_viewport.py):
- moving an object: its Object with is_updated_transform only (planned as a transform update:
  new instance matrices, the core rebuilds only the top level of its two-level BVH);
- editing a mesh: the Object and its Mesh with is_updated_geometry;
- editing a material (nodes or properties): the Material, and the Objects and Meshes using it
  with is_updated_shading only (no geometry, no transform);
- a light's properties: the light Object with is_updated_geometry and its Light data;
- a camera's lens: the camera Object with is_updated_geometry and its Camera data;
- the world: the World with is_updated_shading;
- selecting objects, changing scene properties: the Scene, with no flags at all;
- hiding an object, adding a material slot: a Collection or the Mesh with is_updated_geometry.
"""

from dataclasses import dataclass, field

# Object types whose evaluated data Pathlight renders as triangles.
GEOMETRY_OBJECTS = frozenset(("MESH", "CURVE", "SURFACE", "FONT", "META", "CURVES",
                              "POINTCLOUD", "VOLUME"))
# Datablocks whose geometry flag means new triangles.
GEOMETRY_DATA = frozenset(("Mesh", "Curve", "TextCurve", "SurfaceCurve", "MetaBall", "Curves",
                           "PointCloud", "Volume", "Collection"))
LIGHT_DATA = frozenset(("Light", "PointLight", "SpotLight", "SunLight", "AreaLight"))


@dataclass(frozen=True)
class Update:
    """One entry of depsgraph.updates, as plain data."""
    id_type: str  # the ID's class name: "Object", "Mesh", "Material", "PointLight", ...
    name: str
    geometry: bool = False
    transform: bool = False
    shading: bool = False
    object_type: str = ""  # for Objects: obj.type ("MESH", "LIGHT", "CAMERA", "EMPTY", ...)
    is_instancer: bool = False  # for Objects: instances other objects (instance_type != NONE)


@dataclass
class ViewState:
    """What the last sync rendered, as far as deciding about updates goes."""
    camera_name: str = ""  # the scene camera (its moves matter in camera view only, but are cheap)
    settings: tuple = ()  # settings_signature() of the last sync
    materials: frozenset = frozenset()  # names of the materials the core scene holds


@dataclass
class UpdatePlan:
    restart: bool = False  # restart the progressive render (anything below implies it)
    camera: bool = False  # re-read the scene camera (no scene edit)
    materials: list = field(default_factory=list)  # material names to recompile and replace
    lights: bool = False  # re-read lights and the world, rebuild the light distribution only
    rebuild_geometry: bool = False  # re-export everything and rebuild the BVH
    # Names of geometry objects that only moved: their instances get new matrices and only the
    # top level of the BVH is rebuilt (the session falls back to a re-export for objects it
    # cannot map to one instance, e.g. the sources of instancers).
    transforms: list = field(default_factory=list)
    settings: bool = False  # render settings changed (samples, bounces, ...): new session only

    @property
    def restart_only(self):
        """Only the render restarts: nothing of the core scene changes."""
        return self.restart and not (self.materials or self.lights or self.rebuild_geometry
                                     or self.transforms)

    @property
    def nothing(self):
        return not self.restart


def describe_updates(updates):
    """Plain Update records of a depsgraph's `updates` collection."""
    out = []
    for u in updates:
        id_ = u.id
        obj_type, instancer = "", False
        if type(id_).__name__ == "Object":
            obj_type = id_.type
            instancer = getattr(id_, "instance_type", "NONE") != "NONE"
        out.append(Update(type(id_).__name__, id_.name, bool(u.is_updated_geometry),
                          bool(u.is_updated_transform), bool(u.is_updated_shading),
                          obj_type, instancer))
    return out


def plan_updates(updates, state, settings=None):
    """UpdatePlan for a list of Update records since the last sync described by `state`.
    settings: the current settings_signature(), compared with state.settings when the Scene
    itself was updated (that also happens on a mere selection change)."""
    plan = UpdatePlan()
    materials = []
    transforms = []
    for u in updates:
        if u.id_type == "Object":
            moved = u.geometry or u.transform
            if u.object_type in GEOMETRY_OBJECTS:
                # Shading-only updates of an object come with its material's own update.
                if u.transform and not u.geometry and not u.is_instancer:
                    if u.name not in transforms:
                        transforms.append(u.name)  # moved: new matrix, top level only
                else:
                    # New triangles, or an instancer whose instance set may have changed.
                    plan.rebuild_geometry |= moved
            elif u.object_type == "LIGHT":
                plan.lights |= moved or u.shading
            elif u.object_type == "CAMERA":
                plan.camera |= moved
            elif u.is_instancer:
                plan.rebuild_geometry |= moved
            # Other empties, armatures, ...: their effect arrives as updates of the objects
            # they move or deform.
        elif u.id_type in GEOMETRY_DATA:
            plan.rebuild_geometry |= u.geometry
        elif u.id_type == "Material":
            if u.name in state.materials:
                if u.name not in materials:
                    materials.append(u.name)
            else:
                # Not rendered yet (a new material): it arrives with the geometry update of
                # the slot it was put into; nothing to replace.
                pass
        elif u.id_type in LIGHT_DATA or u.id_type == "World":
            plan.lights = True
        elif u.id_type == "Camera":
            plan.camera = True
        elif u.id_type == "Image":
            # Images reach materials and the world: re-export everything.
            plan.rebuild_geometry = True
            plan.lights = True
        elif u.id_type == "Scene":
            if settings is not None and settings != state.settings:
                plan.settings = True
                plan.camera = True  # resolution, active camera, pixel aspect live here too
                plan.lights = True  # the world is assigned here
                # Cycles' curve shape (ribbons or round) changes the curves' geometry.
                plan.rebuild_geometry |= curves_signature(settings) != curves_signature(state.settings)
    if plan.rebuild_geometry:
        plan.lights = True  # a full re-export reads everything again
        materials = []  # ... materials included
        transforms = []  # ... and matrices
    plan.materials = materials
    plan.transforms = transforms
    plan.restart = (plan.camera or plan.lights or plan.rebuild_geometry or plan.settings
                    or bool(plan.materials) or bool(plan.transforms))
    return plan


def curves_signature(settings):
    """The curve shape part of a settings_signature() (its last entry), or None."""
    last = settings[-1] if settings else None
    return last if isinstance(last, tuple) and last[:1] == ("curves",) else None


def settings_signature(scene):
    """The scene values whose change must restart the viewport render (bpy Scene in, tuple out);
    the last entry, ("curves", shape, subdivisions), needs the curves exported again."""
    props = scene.pathlight
    names = ("samples", "preview_samples", "max_bounces", "diffuse_bounces", "glossy_bounces",
             "transmission_bounces", "volume_bounces", "transparent_bounces", "sample_clamp_direct",
             "sample_clamp_indirect", "blur_glossy", "caustics_reflective", "caustics_refractive",
             "seed", "sampler", "pixel_pattern", "use_nee", "use_schlick_fresnel",
             "use_adaptive_sampling", "adaptive_threshold", "adaptive_min_samples", "use_guiding",
             "use_preview_denoising", "preview_denoising_input_passes", "preview_denoising_prefilter",
             "preview_denoising_quality", "preview_denoising_start_sample",
             "use_fast_gi", "fast_gi_method", "ao_bounces", "film_transparent_glass",
             "film_transparent_roughness")
    r = scene.render
    curves = getattr(scene, "cycles_curves", None)
    return (tuple(getattr(props, n, None) for n in names)
            + (scene.camera.name if scene.camera else "", scene.world.name if scene.world else "",
               # (the world's AO factor and distance: Fast GI's and the AO pass's)
               tuple(getattr(scene.world.light_settings, n) for n in ("ao_factor", "distance"))
               if scene.world else (),
               r.pixel_aspect_x, r.pixel_aspect_y, r.threads,
               ("curves", getattr(curves, "shape", None), getattr(curves, "subdivisions", None))))
