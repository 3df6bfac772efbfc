"""Blender point clouds (POINTCLOUD objects: bpy.data.pointclouds, or the points a Geometry
Nodes modifier makes) → flat numpy arrays (PointsData, which scene_writer.add_points hands to
the core's add_points), read with foreach_get: positions, radii and the point attributes the
materials read. One entry per evaluated geometry (and material) with every instance's matrix.
As Cycles 4.5 (blender/pointcloud.cpp): spheres, a missing 'radius' attribute means 0.01, the
object's first material for every point (per-point material_index is not read), and any point
attribute by name for the Attribute node."""

from dataclasses import dataclass, field

import numpy as np

from .mesh import _attribute_rgba, is_visible, object_info
from .motion import instance_key, read_velocity

DEFAULT_RADIUS = 0.01  # Cycles' radius where a point cloud has no 'radius' attribute


@dataclass
class PointsData:
    name: str
    points: np.ndarray  # (N, 3) float32, object space
    radii: np.ndarray  # (N,) float32
    material: object  # the bpy material of slot 1 (or None)
    matrices: list = field(default_factory=list)  # (4, 4) float32 per instance
    infos: list = field(default_factory=list)  # per instance: mesh.object_info's tuple
    owners: list = field(default_factory=list)  # per instance: its object's name (light linking)
    # Per instance: float32 (K, 4) Object / Instancer attribute values, or None.
    object_attributes: list = field(default_factory=list)
    # attribute set k -> float32 (N, 4): one RGBA per point (the Attribute node's value there)
    attributes: dict = field(default_factory=dict)
    # Transform motion blur, as MeshData's: per instance its key across sub-frames, and its
    # matrices at the motion steps ((S, 4, 4) float32) or None (export.motion fills them).
    motion_keys: list = field(default_factory=list)
    motions: list = field(default_factory=list)
    velocity: object = None  # (N, 3) float32: the 'velocity' attribute (Cycles' point motion), or None
    pass_points: object = None  # (2, N, 3) float32: the points at frame -+ 1 (the Vector pass), or None
    # Deformation blur (export.motion): centres (S, N, 3) and radii (S, N) at the motion steps.
    motion_points: object = None
    motion_radii: object = None


def points_arrays(cloud, warn, name):
    """(points, radii) of an evaluated bpy.types.PointCloud, or None when it has no points.
    Bad points (non-finite positions or radii, radii <= 0) are counted in one warning; the
    core leaves them out."""
    n = len(cloud.points)
    if n == 0:
        warn(f"Point cloud '{name}' has no points; skipped")
        return None
    points = np.empty(n * 3, np.float32)
    cloud.attributes["position"].data.foreach_get("vector", points)
    points = points.reshape(-1, 3)
    attr = cloud.attributes.get("radius")
    if attr is not None and attr.domain == 'POINT' and attr.data_type == 'FLOAT':
        radii = np.empty(n, np.float32)
        attr.data.foreach_get("value", radii)
    else:
        radii = np.full(n, DEFAULT_RADIUS, np.float32)
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(points).all(axis=1) | ~np.isfinite(radii) | ~(radii > 0.0)
    if bad.any():
        warn(f"Point cloud '{name}': {int(bad.sum())} of {n} points have a non-finite position or "
             "radius, or a radius <= 0; they are not rendered")
    return points, radii


def cloud_points_radii(cloud):
    """(points (N, 3), radii (N,)) float32 of an evaluated point cloud, without checks
    (deformation blur's sub-frames)."""
    n = len(cloud.points)
    points = np.empty(n * 3, np.float32)
    if n:
        cloud.attributes["position"].data.foreach_get("vector", points)
    attr = cloud.attributes.get("radius")
    if attr is not None and attr.domain == 'POINT' and attr.data_type == 'FLOAT':
        radii = np.empty(n, np.float32)
        attr.data.foreach_get("value", radii)
    else:
        radii = np.full(n, DEFAULT_RADIUS, np.float32)
    return points.reshape(-1, 3), radii


def point_attributes(cloud, names):
    """{k: float32 (N, 4) per-point RGBA} for the attribute sets among {k: name}
    (("attr", name) or ("color", name), "" = the default colour attribute), and the names the
    cloud lacks (Cycles reads 0 for them, an Attribute node's Alpha 1: sent as (0, 0, 0, 1))."""
    out, missing = {}, []
    for k, name in names.items():
        if not isinstance(name, tuple):
            continue  # a UV map: points have no UVs (Cycles' u, v = 0)
        kind, attr_name = name
        if kind not in ("attr", "color"):
            missing.append(f"{kind} (a mesh attribute)")
            continue
        if kind == "color" and not attr_name:
            colours = getattr(cloud, "color_attributes", None)
            attr_name = (colours.default_color_name or (colours[0].name if len(colours) else "")) \
                if colours is not None else ""
        attr = cloud.attributes.get(attr_name) if attr_name else None
        if kind == "color" and attr is not None and attr.data_type not in ("FLOAT_COLOR", "BYTE_COLOR"):
            attr = None
        values = _attribute_rgba(attr) if attr is not None and attr.domain == 'POINT' else None
        if values is None or len(values) != len(cloud.points):
            missing.append(attr_name or "(default colour attribute)")
            if kind == "attr":  # Cycles' Attribute node reads a missing one as 0 with alpha 1
                out[k] = np.tile(np.float32([0.0, 0.0, 0.0, 1.0]), (len(cloud.points), 1))
            continue
        out[k] = np.ascontiguousarray(values)
    return out, missing


def collect_points(depsgraph, warn, material_index=None, object_attributes=None, uv_names=None, layer=None):
    """Every visible point cloud of the depsgraph (instances of one evaluated geometry with one
    material share one PointsData). material_index(material): compiles a material (numbering
    its Object / Instancer attribute slots) before its instances' values are resolved by
    `object_attributes`, as collect_curves does; uv_names(materials) -> {set: name}: the
    attributes its materials read."""
    from .view_layer import first_material, layer_settings
    if layer is None:  # (its Material Override; Cycles' filters leave point clouds)
        layer = layer_settings(depsgraph)
    out = {}
    view_layer = getattr(depsgraph, "view_layer", None)  # (holdout collections)
    for instance in depsgraph.object_instances:
        obj = instance.object
        if obj.type != 'POINTCLOUD' or not is_visible(instance):
            continue
        material = first_material(obj, layer)
        key = (obj.data.as_pointer(), material.as_pointer() if material is not None else 0)
        entry = out.get(key)
        if key not in out:
            name = obj.original.name if obj.original is not None else obj.name
            arrays = points_arrays(obj.data, warn, name)
            if arrays is None:
                out[key] = None
                continue
            entry = out[key] = PointsData(name, *arrays, material)
            entry.velocity = read_velocity(obj.data, len(entry.points))
            if material_index is not None:
                material_index(material)
            if uv_names is not None:
                entry.attributes, missing = point_attributes(obj.data, uv_names([material]))
                if missing:
                    warn(f"Point cloud '{name}' has no point attribute {', '.join(map(repr, missing))} "
                         "that its material reads; 0 is used")
        if entry is not None:
            entry.matrices.append(np.array(instance.matrix_world, np.float32))
            entry.infos.append(object_info(instance, view_layer))
            entry.owners.append(obj.name)
            entry.motion_keys.append(instance_key(instance))
            if object_attributes is not None:
                entry.object_attributes.append(object_attributes.values(instance))
    return [p for p in out.values() if p is not None]
