"""Blender Curves objects (hair) → flat numpy arrays (CurvesData, which
scene_writer.add_curves hands to the core's add_curves): control points, radii and per-strand
offsets read with foreach_get (no per-point Python), one entry per evaluated geometry with
every instance's matrix. Particle hair has no vectorised access in bpy (only per-particle,
per-key calls), so it is reported, not exported."""

from dataclasses import dataclass, field

import numpy as np

from .mesh import is_visible, object_info

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
    # Per instance: float32 (K, 4) Object / Instancer attribute values of the first K slots
    # of the scene's (export.object_attributes), or None.
    object_attributes: list = field(default_factory=list)
    # (N, 3) float32: Blender's curve normals, read only for materials with Huang hair (the
    # major axis of its elliptical fibres, as Cycles reads it); else None.
    normals: object = None


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
    _warn_bad_strands(points, offsets, radii, warn, name)
    return points, offsets, radii, kind


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


def _warn_bad_strands(points, offsets, radii, warn, name):
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
        warn(f"Curves '{name}': {int(bad.sum())} of {len(counts)} strands have non-finite points or radii, "
             "no positive radius, fewer than 2 points or zero length; they are not rendered")


def collect_curves(depsgraph, warn, material_index=None, object_attributes=None):
    """Every visible Curves object of the depsgraph (instances share one CurvesData), and one
    warning per object with particle hair (not exported). material_index(material): compiles
    a material (numbering the Object / Instancer attribute slots it reads) before its
    instances' values are resolved by `object_attributes` (an
    object_attributes.InstanceAttributes), as collect_meshes does."""
    out = {}
    warned = set()
    for instance in depsgraph.object_instances:
        obj = instance.object
        if not is_visible(instance):
            continue
        if obj.type == 'MESH':
            _warn_particle_hair(obj, warn, warned)
            continue
        if obj.type != 'CURVES':
            continue
        material = obj.material_slots[0].material if len(obj.material_slots) else None
        key = (obj.data.as_pointer(), material.as_pointer() if material is not None else 0)
        entry = out.get(key)
        if entry is None:
            arrays = curves_arrays(obj.data, warn, obj.original.name)
            if arrays is None:
                out[key] = None
                continue
            entry = out[key] = CurvesData(obj.original.name, *arrays, material)
            if uses_huang_hair(material):
                entry.normals = curve_normals(obj.data)
            if material_index is not None:
                material_index(material)
        if entry is not None:
            entry.matrices.append(np.array(instance.matrix_world, np.float32))
            entry.infos.append(object_info(instance))
            if object_attributes is not None:
                entry.object_attributes.append(object_attributes.values(instance))
    return [c for c in out.values() if c is not None]


def _warn_particle_hair(obj, warn, warned):
    systems = getattr(obj, "particle_systems", None)
    if not systems or obj.original.name in warned:
        return
    for ps in systems:
        settings = ps.settings
        if settings is not None and settings.type == 'HAIR' and settings.render_type == 'PATH':
            warned.add(obj.original.name)
            warn(f"Particle hair on '{obj.original.name}' is not rendered: convert it to a Curves "
                 "object (Object > Convert > Curves) for Pathlight")
            return
