"""Blender Curves objects (hair) → flat numpy arrays (CurvesData, which
scene_writer.add_curves hands to the core's add_curves): control points, radii and per-strand
offsets read with foreach_get (no per-point Python), one entry per evaluated geometry with
every instance's matrix. Particle hair (hair particle systems rendered as paths) has no
vectorised access in bpy: its keys are read with one ParticleSystem.co_hair call per key, as
Cycles' ObtainCacheParticleData reads them, and become the same CurvesData."""

from dataclasses import dataclass, field
from itertools import chain

import numpy as np

from .mesh import _attribute_rgba, is_visible, object_info
from .motion import instance_key, read_velocity

# Blender's CurveType enum (the 'curve_type' attribute on the CURVE domain).
CATMULL_ROM, POLY, BEZIER, NURBS = 0, 1, 2, 3
DEFAULT_RADIUS = 0.005  # what Cycles uses when a Curves object has no 'radius' attribute


@dataclass
class CurvesData:
    name: str
    points: np.ndarray  # (N, 3) float32, object space
    offsets: np.ndarray  # (C + 1,) int32
    radii: np.ndarray  # (N,) float32
    curve_type: str  # 'catmull_rom' or 'poly' (the core's names)
    material: object  # the bpy material of slot 1 (or None)
    matrices: list = field(default_factory=list)  # (4, 4) float32 per instance
    infos: list = field(default_factory=list)  # per instance: mesh.object_info's tuple
    owners: list = field(default_factory=list)  # per instance: its object's name (light linking)
    # Per instance: float32 (K, 4) Object / Instancer attribute values of the first K slots
    # of the scene's (export.object_attributes), or None.
    object_attributes: list = field(default_factory=list)
    # (N, 3) float32: Blender's curve normals, read only for materials with Huang hair (the
    # major axis of its elliptical fibres, as Cycles reads it); else None.
    normals: object = None
    # uv set k -> float32 (C, 2): one uv per strand (particle hair: the emitter's UV at the root)
    uvs: dict = field(default_factory=dict)
    # attribute set k -> float32 (C, 4): one RGBA per strand (particle hair: the emitter's byte
    # colour attribute at the root, linear, as Cycles' per-curve vertex colour)
    colours: dict = field(default_factory=dict)
    # attribute set k -> float32 (N, 4): one RGBA per point (a Curves object's point-domain
    # attribute, linear between a segment's keys as Cycles interpolates them)
    point_attributes: dict = field(default_factory=dict)
    # uv set k -> float32 (N, 2): a point-domain FLOAT2 that a named UV Map node reads
    point_uvs: dict = field(default_factory=dict)
    # Cycles' scene-wide curve shape (scene.cycles_curves.shape): 'thick' or 'ribbon'; ribbons
    # come with Embree's tessellation rate (quads per segment) in `subdivisions`.
    shape: str = 'thick'
    subdivisions: int = 0
    # Motion blur (export.motion fills them): per instance its key across sub-frames and its
    # matrices at the motion steps ((S, 4, 4) float32) or None, as MeshData's; deformation
    # blur of the geometry: the points (S, N, 3) and radii (S, N) at the steps, or None.
    motion_keys: list = field(default_factory=list)
    motions: list = field(default_factory=list)
    motion_points: object = None
    motion_radii: object = None
    velocity: object = None  # (N, 3) float32: a Curves object's 'velocity' attribute, or None
    pass_points: object = None  # (2, N, 3) float32: the points at frame -+ 1 (the Vector pass), or None
    psys_key: object = None  # particle hair: its key in _particle_hair's output (sub-frames)


def curve_material_indices(curves, n_slots):
    """(C,) int32 slot indices from a Curves' 'material_index' attribute (CURVE, INT), clamped
    to [0, n_slots - 1]; None without the attribute or with fewer than 2 slots. Cycles 4.5
    renders every strand of a Curves object with its first slot whatever they say (checked:
    all strands at index 1 render as with slot 1 alone), and so does Pathlight: they are read
    only to warn."""
    n_curves = len(curves.curves)
    if n_slots < 2 or n_curves == 0:
        return None
    attr = _attribute(curves, "material_index", 'CURVE', 'INT')
    if attr is None:
        return None
    idx = np.empty(n_curves, np.int32)
    attr.data.foreach_get("value", idx)
    return np.clip(idx, 0, n_slots - 1).astype(np.int32)


def curve_shape(scene):
    """('ribbon', quads per segment) where the scene's Cycles curve shape is 'RIBBONS', else
    ('thick', 0). Cycles 4.5 on the CPU hands ribbons to Embree's flat Catmull-Rom curves with
    the tessellation rate 2^subdivisions (1 .. 16) + 1, which Embree clamps to 16."""
    settings = getattr(scene, "cycles_curves", None)
    if settings is None or getattr(settings, "shape", 'THICK') != 'RIBBONS':
        return 'thick', 0
    try:
        level = int(settings.subdivisions)
    except (TypeError, ValueError, AttributeError):
        level = 2
    level = max(0, min(level, 24))
    return 'ribbon', min(16, min(1 << level, 16) + 1)


def _attribute(curves, name, domain, data_type):
    attr = curves.attributes.get(name)
    if attr is None or attr.domain != domain or attr.data_type != data_type:
        return None
    return attr


def curves_arrays(curves, warn, name):
    """(points, offsets, radii, curve_type) of an evaluated bpy.types.Curves, or None when it
    has no strands."""
    n_points, n_curves = len(curves.points), len(curves.curves)
    if n_curves == 0 or n_points == 0:
        return None
    points = np.empty(n_points * 3, np.float32)
    curves.attributes["position"].data.foreach_get("vector", points)
    offsets = np.empty(n_curves + 1, np.int32)
    curves.curve_offset_data.foreach_get("value", offsets)
    attr = _attribute(curves, "radius", 'POINT', 'FLOAT')
    if attr is not None:
        radii = np.empty(n_points, np.float32)
        attr.data.foreach_get("value", radii)
    else:
        radii = np.full(n_points, DEFAULT_RADIUS, np.float32)
    types = _attribute(curves, "curve_type", 'CURVE', 'INT8')
    kind = 'catmull_rom'
    if types is not None:
        t = np.empty(n_curves, np.int32)  # int8 data reads as ints: a smaller buffer overflows
        types.data.foreach_get("value", t)
        present = set(np.unique(t).tolist())
        if present == {POLY}:
            kind = 'poly'  # Cycles traces all-poly curves as linear segments too
        elif present - {CATMULL_ROM}:
            warn(f"Curves '{name}': Bezier, NURBS and mixed curve types are traced as Catmull-Rom "
                 "curves through their control points")
    points = points.reshape(-1, 3)
    if offsets[0] != 0 or offsets[-1] != n_points or np.any(np.diff(offsets) < 0):
        warn(f"Curves '{name}' has inconsistent curve offsets; not rendered")
        return None
    _warn_bad_strands(points, offsets, radii, warn, f"Curves '{name}'")
    return points, offsets, radii, kind


def curve_attributes(curves, names):
    """The attributes and UV maps that materials read ({set k: UV map name, or ("attr", name)
    / ("color", name)}) from an evaluated Curves object, as Cycles 4.5's attr_create_generic:
    (uvs {k: (C, 2)}, point uvs {k: (N, 2)}, strand attributes {k: (C, 4)}, point attributes
    {k: (N, 4)}, the names it lacks). Point-domain attributes stay per point (the core interpolates them along the
    strand), curve-domain ones per strand; values as the Attribute node reads them
    (mesh._attribute_rgba: floats as grey, vectors with alpha 1, byte colours linear). The
    default UV map ("") is the first FLOAT2 curve attribute (Cycles' standard UV: geometry
    nodes hair's `surface_uv_coordinate`); a named UV map the FLOAT2 attribute of that name
    (per strand or per point). An unnamed Color Attribute node finds none (Cycles gives curves no default colour
    attribute). A missing attribute reads 0, but the Attribute node's Alpha 1 (as Cycles'
    svm_node_attr; the Color Attribute node's Alpha 0), so a missing "attr" set is sent per
    strand as (0, 0, 0, 1)."""
    n_points, n_curves = len(curves.points), len(curves.curves)
    uvs, point_uvs, strand, point, missing = {}, {}, {}, {}, []
    for k, name in names.items():
        if not isinstance(name, tuple):  # a UV map
            if name:
                attr = curves.attributes.get(name)
            else:
                attr = next((a for a in curves.attributes
                             if a.data_type == 'FLOAT2' and a.domain == 'CURVE'), None)
            size = n_points if attr is not None and attr.domain == 'POINT' else n_curves
            if attr is None or attr.data_type != 'FLOAT2' or attr.domain not in ('CURVE', 'POINT') or \
                    len(attr.data) != size:
                missing.append(f"UV map '{name}'" if name else "a FLOAT2 curve attribute (UV)")
                continue
            uv = np.empty(size * 2, np.float32)
            attr.data.foreach_get("vector", uv)
            (point_uvs if attr.domain == 'POINT' else uvs)[k] = uv.reshape(-1, 2)
            continue
        kind, attr_name = name
        attr = curves.attributes.get(attr_name) if attr_name and kind in ("attr", "color") else None
        if kind == "color" and attr is not None and attr.data_type not in ("FLOAT_COLOR", "BYTE_COLOR"):
            attr = None
        values = _attribute_rgba(attr) if attr is not None and attr.domain in ('POINT', 'CURVE') else None
        size = n_points if attr is not None and attr.domain == 'POINT' else n_curves
        if values is None or len(values) != size:
            missing.append(f"attribute '{attr_name}'" if attr_name else "the default colour attribute")
            if kind == "attr":  # Cycles' Attribute node reads a missing one as 0 with alpha 1
                strand[k] = np.tile(np.float32([0.0, 0.0, 0.0, 1.0]), (n_curves, 1))
            continue
        (point if attr.domain == 'POINT' else strand)[k] = np.ascontiguousarray(values)
    return uvs, point_uvs, strand, point, missing
def curve_points_radii(curves):
    """(points (N, 3), radii (N,)) float32 of an evaluated bpy.types.Curves, without checks
    (deformation blur's sub-frames: compared with the frame's arrays by the caller)."""
    n = len(curves.points)
    points = np.empty(n * 3, np.float32)
    if n:
        curves.attributes["position"].data.foreach_get("vector", points)
    attr = _attribute(curves, "radius", 'POINT', 'FLOAT')
    if attr is not None:
        radii = np.empty(n, np.float32)
        attr.data.foreach_get("value", radii)
    else:
        radii = np.full(n, DEFAULT_RADIUS, np.float32)
    return points.reshape(-1, 3), radii


def curve_normals(curves):
    """Blender's evaluated curve normals, (N, 3) float32, or None. bpy 4.5 returns garbage for
    some entries of this computed collection (seen: the first, by foreach_get and by item
    alike): an entry that is no unit vector takes its neighbour's along the array (normals
    vary smoothly along a strand), else zero (the core then uses Cycles' fallback axis)."""
    n = len(curves.points)
    if n == 0 or len(curves.normals) != n:
        return None
    normals = np.zeros(n * 3, np.float32)
    curves.normals.foreach_get("vector", normals)
    normals = normals.reshape(-1, 3).astype(np.float64)
    with np.errstate(all="ignore"):
        good = np.abs(np.linalg.norm(normals, axis=1) - 1.0) < 1e-3
    if not good.any():
        return None
    normals[~good] = 0.0
    for i in np.flatnonzero(~good).tolist()[:10000]:
        for j in (i + 1, i - 1):
            if 0 <= j < n and good[j]:
                normals[i] = normals[j]
                break
    return normals.astype(np.float32)


def uses_huang_hair(material, _seen=None):
    """Whether a material's node tree (or a group in it) has a Principled Hair BSDF in Huang's
    model (only then are the curve normals exported)."""
    tree = getattr(material, "node_tree", None) if material is not None else None
    seen = _seen if _seen is not None else set()
    if tree is None or tree.as_pointer() in seen:
        return False
    seen.add(tree.as_pointer())
    for node in tree.nodes:
        if node.type == 'BSDF_HAIR_PRINCIPLED' and node.model == 'HUANG':
            return True
        if node.type == 'GROUP' and node.node_tree is not None:
            if uses_huang_hair(node, seen):
                return True
    return False


def _warn_bad_strands(points, offsets, radii, warn, label):
    """One warning for the strands the core leaves out (non-finite points or radii, fewer than
    two points, no positive radius, zero length), counted with numpy per strand."""
    counts = np.diff(offsets)
    starts = offsets[:-1]
    nonempty = counts > 0
    bad_point = ~np.isfinite(points).all(axis=1) | ~np.isfinite(radii)
    seg = np.zeros(len(points), np.float64)
    seg[1:] = np.linalg.norm(np.diff(points.astype(np.float64), axis=0), axis=1)
    seg[starts[nonempty]] = 0.0  # no length across strands
    idx = starts[nonempty]
    bad = np.ones(len(counts), bool)
    with np.errstate(invalid="ignore"):
        length = np.add.reduceat(np.nan_to_num(seg, nan=0.0, posinf=0.0), idx)
        any_bad = np.add.reduceat(bad_point.astype(np.int64), idx) > 0
        rmax = np.maximum.reduceat(np.nan_to_num(radii, nan=0.0), idx)
    bad[nonempty] = any_bad | (rmax <= 0.0) | ~(length > 0.0) | (counts[nonempty] < 2)
    if bad.any():
        warn(f"{label}: {int(bad.sum())} of {len(counts)} strands have non-finite points or radii, "
             "no positive radius, fewer than 2 points or zero length; they are not rendered")


def collect_curves(depsgraph, warn, material_index=None, object_attributes=None, uv_names=None, layer=None):
    """Every visible Curves object and particle hair system of the depsgraph (instances
    share one CurvesData; an emitter's hair systems one per material).
    material_index(material): compiles a material (numbering the Object / Instancer
    attribute slots it reads) before its instances' values are resolved by
    `object_attributes` (an object_attributes.InstanceAttributes), as collect_meshes does.
    uv_names(materials) -> {uv set: UV map name or attribute key} (MaterialTable.uv_names):
    the emitter UV maps particle hair materials read. layer: the view layer's
    view_layer.LayerSettings (from the depsgraph when None): Material Override, Curves filter."""
    from .view_layer import first_material, layer_settings
    if layer is None:
        layer = layer_settings(depsgraph)
    if not layer.use_strand:  # Filter ▸ Curves off: Cycles syncs hair without curves
        return []
    out = {}
    render = getattr(depsgraph, "mode", 'RENDER') == 'RENDER'
    view_layer = getattr(depsgraph, "view_layer", None)  # (holdout collections)
    shape, quads = curve_shape(getattr(depsgraph, "scene", None))
    for instance in depsgraph.object_instances:
        obj = instance.object
        if obj.type == 'MESH' and getattr(obj, "particle_systems", None) and _shows_particles(instance):
            for key, material, arrays, uvs in _particle_hair(obj, render, warn, uv_names, layer.material_override):
                entry = out.get(key)
                if entry is None:
                    colours = {k: v for k, v in uvs.items() if v.shape[1] == 4}
                    uvs = {k: v for k, v in uvs.items() if v.shape[1] == 2}
                    entry = out[key] = CurvesData(obj.original.name, *arrays, material, uvs=uvs,
                                                  colours=colours, shape=shape, subdivisions=quads,
                                                  psys_key=key)
                    if material_index is not None:
                        material_index(material)
                _add_instance(entry, instance, object_attributes, view_layer)
            continue
        if not is_visible(instance) or obj.type != 'CURVES':
            continue
        material = first_material(obj, layer)
        key = (obj.data.as_pointer(), material.as_pointer() if material is not None else 0)
        entry = out.get(key)
        if entry is None:
            arrays = curves_arrays(obj.data, warn, obj.original.name)
            if arrays is None:
                out[key] = None
                continue
            entry = out[key] = CurvesData(obj.original.name, *arrays, material, shape=shape,
                                          subdivisions=quads)
            indices = curve_material_indices(obj.data, len(obj.material_slots))
            if indices is not None and indices.any():
                warn(f"Curves '{obj.original.name}': its strands' material indices are not used; every "
                     "strand renders with the first material slot, as in Cycles")
            if uses_huang_hair(material):
                entry.normals = curve_normals(obj.data)
            entry.velocity = read_velocity(obj.data, len(entry.points))
            if material_index is not None:
                material_index(material)
            if uv_names is not None:  # only what the material reads, as meshes
                entry.uvs, entry.point_uvs, entry.colours, entry.point_attributes, missing = \
                    curve_attributes(obj.data, uv_names([material]))
                if missing:
                    warn(f"Curves '{obj.original.name}' has no {', '.join(missing)} that its material "
                         "reads; 0 is used, as in Cycles")
        if entry is not None:
            _add_instance(entry, instance, object_attributes, view_layer)
    return [c for c in out.values() if c is not None]


def _add_instance(entry, instance, object_attributes, view_layer):
    entry.matrices.append(np.array(instance.matrix_world, np.float32))
    entry.infos.append(object_info(instance, view_layer))
    entry.owners.append(instance.object.name)  # (particle hair: its emitter's)
    entry.motion_keys.append(instance_key(instance))
    if object_attributes is not None:
        entry.object_attributes.append(object_attributes.values(instance))


def _shows_particles(instance):
    """Whether an instance's particle hair renders: the depsgraph's show_particles (False for
    an instance made by another system), and the object not hidden for render (a viewport
    depsgraph still holds those). show_instancer_for_render hides the emitter only."""
    if not getattr(instance, "show_particles", True):
        return False
    return instance.is_instance or not instance.object.original.hide_render


# Above this many strands x keys an export spends seconds in co_hair calls (~3 us a key).
SLOW_PARTICLE_KEYS = 2_000_000


def shape_radius(shape, root, tip, time):
    """Cycles' radius along particle hair (blender/curves.cpp shaperadius): from `root` at
    time 0 to `tip` at 1, `shape` in [-1, 1] bending the profile (0: linear). time: the key's
    fraction of the strand's control-polygon length."""
    r = 1.0 - time
    if shape < 0.0:
        r = r ** (1.0 + shape)
    elif shape > 0.0:
        r = r ** (1.0 / (1.0 - shape))
    return r * (root - tip) + tip


def _particle_hair(obj, render, warn, uv_names=None, override=None):
    """[(key, material, (points, offsets, radii, 'catmull_rom'), uvs)] for the hair particle
    systems of the evaluated mesh object `obj` rendered as paths, as Cycles 4.5 exports them:
    the modifier shown for render (or the viewport), only the children when there are any
    (else the parents), (2^render_step) + 1 keys per strand read with co_hair (world space,
    carried to object space), the radius from the hair shape, the material of
    settings.material (its slot, clamped), and per strand the emitter's UV at its root for
    the UV maps the material reads (uv_names, as collect_curves), (C, 2) per uv set, and its
    byte colour attributes there, (C, 4) per attribute set. Systems sharing a material
    share one entry, in modifier order, so Curves Info's Random numbers their strands on as
    Cycles does."""
    name = obj.original.name
    systems = []
    for mod in obj.modifiers:
        if mod.type != 'PARTICLE_SYSTEM' or not (mod.show_render if render else mod.show_viewport):
            continue
        psys = mod.particle_system
        settings = psys.settings if psys is not None else None
        if settings is None or settings.type != 'HAIR' or settings.render_type != 'PATH':
            continue
        systems.append((mod, psys, settings))
    if not systems:
        return []
    slots = obj.material_slots
    matrix = np.array(obj.matrix_world, np.float64)
    det = np.linalg.det(matrix[:3, :3]) if np.isfinite(matrix).all() else 0.0
    if not abs(det) > 1e-30:  # co_hair gives world space: no way back to the object's
        warn(f"Particle hair on '{name}' not rendered: its emitter's matrix is singular (scale 0?)")
        return []
    to_object = np.linalg.inv(matrix)
    groups = {}  # material pointer -> [material, [arrays]]
    for mod, psys, settings in systems:
        arrays = _particle_system_arrays(obj, psys, settings, render, to_object, warn, name)
        if arrays is None:
            continue
        slot = min(max(int(settings.material) - 1, 0), len(slots) - 1) if len(slots) else -1
        material = slots[slot].material if slot >= 0 else None
        key = material.as_pointer() if material is not None else 0  # (motion.py matches by it)
        if override is not None:  # the view layer's Material Override
            material = override
        names = _emitter_uv_names(obj, material, uv_names, warn, name)
        first, arrays = arrays[0], arrays[1:]
        count = len(arrays[1]) - 1
        uvs = {k: _root_uvs(psys, mod, first, count, no) if kind == "uv" else
               _root_colours(psys, mod, first, count, no) for k, (kind, no) in names.items()}
        groups.setdefault(key, [material, []])[1].append(arrays + (uvs,))
    out = []
    for key, (material, parts) in groups.items():
        width = {k: v.shape[1] for p in parts for k, v in p[3].items()}
        uvs = {k: np.concatenate([p[3].get(k, np.zeros((len(p[1]) - 1, w), np.float32)) for p in parts])
               for k, w in width.items()}
        points = np.concatenate([p[0] for p in parts])
        radii = np.concatenate([p[2] for p in parts])
        offsets, base = [np.zeros(1, np.int32)], 0
        for p in parts:
            offsets.append(p[1][1:] + base)
            base += int(p[1][-1])
        offsets = np.concatenate(offsets).astype(np.int32)
        _warn_bad_strands(points, offsets, radii, warn, f"Particle hair on '{name}'")
        out.append((("psys", obj.original.as_pointer(), key), material,
                    (points, offsets, radii, 'catmull_rom'), uvs))
    return out


def _emitter_uv_names(obj, material, uv_names, warn, name):
    """{set k: ("uv", the emitter's UV layer index) or ("colour", its byte colour layer index)}
    for the UV maps and attributes `material` reads on particle hair. Cycles gives particle
    hair the emitter's byte colour attributes on face corners by name (the index is among
    those, as BKE_particle_mcol_on_emitter's); one warning for what is not read (other
    attributes, an unnamed Color Attribute node, missing maps): 0, as in Cycles."""
    if uv_names is None:
        return {}
    mesh = obj.data
    layers = mesh.uv_layers if mesh is not None else []
    active = next((i for i, layer in enumerate(layers) if layer.active_render), None)
    byte_colours = [a.name for a in mesh.attributes if a.data_type == 'BYTE_COLOR' and a.domain == 'CORNER'] \
        if mesh is not None else []
    out, skipped = {}, []
    for k, uv_name in uv_names([material]).items():
        if isinstance(uv_name, tuple):  # Color Attribute / Attribute node sets
            kind, attr_name = uv_name
            if kind in ("color", "attr") and attr_name in byte_colours:
                out[k] = ("colour", byte_colours.index(attr_name))
            else:
                skipped.append(f"attribute '{attr_name}'" if attr_name else "the colour attribute")
            continue
        index = layers.find(uv_name) if uv_name else active
        if index is None or index < 0:
            skipped.append(f"UV map '{uv_name}'" if uv_name else "the active UV map")
            continue
        out[k] = ("uv", index)
    if skipped:
        warn(f"Particle hair on '{name}': {', '.join(skipped)} of the emitter not read for its strands "
             "(as Cycles, particle hair reads only the emitter's UV maps and its byte colour attributes "
             "on face corners, by name); 0 is used")
    return out


def _root_uvs(psys, mod, first, count, uv_no):
    """float32 (C, 2): the emitter's UV at each strand's root, as Cycles' ObtainCacheParticleUV
    (one uv_on_emitter call per strand; children pass the first parent's data, as Cycles)."""
    particles = psys.particles
    if len(particles) == 0:
        return np.zeros((count, 2), np.float32)
    uv = psys.uv_on_emitter
    flat = np.fromiter(chain.from_iterable(
        uv(mod, particle=particles[p] if p < len(particles) else particles[0], particle_no=p, uv_no=uv_no)
        for p in range(first, first + count)), np.float64, count * 2)
    return flat.reshape(count, 2).astype(np.float32)


def _root_colours(psys, mod, first, count, vcol_no):
    """float32 (C, 4): the emitter's byte colour attribute `vcol_no` at each strand's root,
    linear RGB and alpha 1, as Cycles' ObtainCacheParticleVcol (one mcol_on_emitter call per
    strand, sRGB-decoded)."""
    particles = psys.particles
    out = np.zeros((count, 4), np.float32)
    out[:, 3] = 1.0
    if len(particles) == 0:
        return out
    mcol = psys.mcol_on_emitter
    flat = np.fromiter(chain.from_iterable(
        mcol(mod, particle=particles[p] if p < len(particles) else particles[0], particle_no=p, vcol_no=vcol_no)
        for p in range(first, first + count)), np.float64, count * 3).reshape(count, 3)
    flat = np.where(np.isfinite(flat), flat, 0.0)
    out[:, :3] = np.where(flat < 0.04045, np.maximum(flat, 0.0) / 12.92, ((flat + 0.055) / 1.055) ** 2.4)
    return out


def _particle_system_arrays(obj, psys, settings, render, to_object, warn, name):
    """(first particle number, points (N, 3) float32 object space, offsets, radii) of one
    hair system, or None."""
    parents = len(psys.particles)
    children = len(psys.child_particles)
    if not render:  # Cycles' viewport count: the display percentage of the children
        children = int(children * settings.display_percentage / 100.0)
    first = parents if settings.child_type != 'NONE' and children else 0
    count = parents + children - first
    if count <= 0:
        warn(f"Particle hair '{psys.name}' on '{name}' has no strands; nothing to render")
        return None
    step = settings.render_step if render else settings.display_step
    keys = (1 << int(step)) + 1
    if settings.kink == 'SPIRAL':
        keys += int(settings.kink_extra_steps)
    if count * keys > SLOW_PARTICLE_KEYS:
        warn(f"Particle hair '{psys.name}' on '{name}': {count} strands x {keys} keys are read one "
             "key per call (bpy has no array access to particle keys), which takes seconds; "
             "fewer children or a lower render step (or a Curves object) exports faster")
    co = psys.co_hair
    # One call per key (no vectorised access); fromiter flattens the Vectors without lists.
    flat = np.fromiter(chain.from_iterable(co(obj, particle_no=p, step=k)
                                           for p in range(first, first + count) for k in range(keys)),
                       np.float64, count * keys * 3)
    world = flat.reshape(-1, 3)
    points = world @ to_object[:3, :3].T + to_object[:3, 3]
    strands = points.reshape(count, keys, 3)
    seg = np.linalg.norm(np.diff(strands, axis=1), axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        time = np.concatenate([np.zeros((count, 1)), np.cumsum(seg, axis=1)], axis=1)
        total = time[:, -1:]
        time = np.where(total > 0.0, time / np.where(total > 0.0, total, 1.0), 0.0)
    half = 0.5 * float(settings.radius_scale)  # Cycles: radius_scale x 0.5 x root / tip
    root, tip = half * float(settings.root_radius), half * float(settings.tip_radius)
    radii = shape_radius(float(settings.shape), root, tip, np.clip(np.nan_to_num(time), 0.0, 1.0))
    if settings.use_close_tip:
        radii[:, -1] = 0.0
    offsets = (np.arange(count + 1, dtype=np.int64) * keys).astype(np.int32)
    return first, points.astype(np.float32), offsets, radii.astype(np.float32).ravel()
