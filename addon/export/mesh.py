"""Evaluated geometry → numpy arrays, one entry per unique mesh with all its instance matrices."""

from dataclasses import dataclass, field

import numpy as np



@dataclass
class MeshData:
    name: str
    positions: np.ndarray  # float32 (V, 3), object space
    triangles: np.ndarray  # int32 (T, 3), indices into positions
    corner_normals: np.ndarray  # float32 (T, 3, 3), shading normal per triangle corner
    material_indices: np.ndarray  # int32 (T,), material slot per triangle
    materials: list  # bpy.types.Material or None per slot
    matrices: list = field(default_factory=list)  # float32 (4, 4) object-to-world, one per instance
    # Per matrix: (object name, made by an instancer), so live edits can find an object's instance.
    owners: list = field(default_factory=list)
    uvs: dict = field(default_factory=dict)  # global uv-set index -> float32 (T, 3, 2) per corner
    missing_uv_maps: list = field(default_factory=list)  # UV map names its materials need
    # Blender's texture space ((location), (size)) for generated coordinates, or None.
    texspace: tuple = None


def _int_attribute(mesh, name, size):
    """A raw int attribute (e.g. ".corner_vert", "material_index") read straight from its
    array, or None when the mesh does not store it (material_index is absent when all 0)."""
    attr = mesh.attributes.get(name)
    if attr is None or attr.data_type != 'INT' or len(attr.data) != size:
        return None
    out = np.empty(size, np.int32)
    attr.data.foreach_get("value", out)
    return out


def mesh_arrays(mesh):
    """(positions, triangles, corner_normals, material_indices) of a bpy Mesh, via foreach_get.

    Only the triangles' corner indices go through the loop-triangle collection (slow per
    element); vertex indices, material indices and normals come from the mesh's own arrays and
    are gathered with numpy: 1M triangles export about twice as fast (tests/bench/bench_export.py)."""
    mesh.calc_loop_triangles()
    tris = mesh.loop_triangles
    n_tris = len(tris)
    n_corners = len(mesh.loops)

    positions = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", positions)
    loops = np.empty(n_tris * 3, np.int32)
    tris.foreach_get("loops", loops)
    tri_polys = np.empty(n_tris, np.int32)
    mesh.loop_triangle_polygons.foreach_get("value", tri_polys)

    corner_verts = _int_attribute(mesh, ".corner_vert", n_corners)
    if corner_verts is None:
        corner_verts = np.empty(n_corners, np.int32)
        mesh.loops.foreach_get("vertex_index", corner_verts)
    triangles = corner_verts[loops].reshape(-1, 3)

    poly_materials = _int_attribute(mesh, "material_index", len(mesh.polygons))
    material_indices = (poly_materials[tri_polys] if poly_materials is not None
                        else np.zeros(n_tris, np.int32))

    # Per-corner normals encode smooth/flat faces, sharp edges and custom normals; when the mesh
    # says its normals live on points or faces, those (cheaper) arrays give the same vectors.
    domain = mesh.normals_domain
    if domain == 'POINT':
        vn = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertex_normals.foreach_get("vector", vn)
        corner_normals = vn.reshape(-1, 3)[triangles].reshape(n_tris, 3, 3)
    elif domain == 'FACE':
        fn = np.empty(len(mesh.polygons) * 3, np.float32)
        mesh.polygon_normals.foreach_get("vector", fn)
        corner_normals = np.repeat(fn.reshape(-1, 3)[tri_polys][:, None, :], 3, axis=1)
    else:
        cn = np.empty(len(mesh.corner_normals) * 3, np.float32)
        mesh.corner_normals.foreach_get("vector", cn)
        corner_normals = cn.reshape(-1, 3)[loops].reshape(n_tris, 3, 3)

    return (positions.reshape(-1, 3), np.ascontiguousarray(triangles, np.int32),
            np.ascontiguousarray(corner_normals, np.float32), material_indices)


def mesh_uvs(mesh, names):
    """{k: float32 (T, 3, 2) per-corner UVs} for {k: UV map name} ("" = the active render UV
    map), and the names the mesh lacks. Call after mesh_arrays (loop triangles computed)."""
    tris = mesh.loop_triangles
    loops = np.empty(len(tris) * 3, np.int32)
    tris.foreach_get("loops", loops)
    uvs, missing, cache = {}, [], {}
    active = next((layer for layer in mesh.uv_layers if layer.active_render), None)
    for k, name in names.items():
        layer = mesh.uv_layers.get(name) if name else active
        if layer is None:
            missing.append(name or "(active render UV map)")
            continue
        if layer.name not in cache:
            corner = np.empty(len(layer.uv) * 2, np.float32)
            layer.uv.foreach_get("vector", corner)
            cache[layer.name] = np.ascontiguousarray(corner.reshape(-1, 2)[loops].reshape(-1, 3, 2))
        uvs[k] = cache[layer.name]
    return uvs, missing


def is_visible(instance):
    if instance.is_instance:
        return True  # the instancer's visibility was already applied by the depsgraph
    if not instance.show_self:
        return False  # e.g. an instancer that hides itself
    # A viewport depsgraph still holds objects hidden for render.
    return not instance.object.original.hide_render


class ExportCancelled(Exception):
    """The user cancelled the render while the scene was being exported."""


def collect_meshes(depsgraph, uv_names=None, cache=None, should_stop=None):
    """All visible geometry of the depsgraph. Instances of the same evaluated geometry (and
    materials) share one MeshData and add only their matrix_world. uv_names(materials) ->
    {global uv-set index: UV map name} says which UV maps to export (none if None).
    cache: a mesh_cache.MeshCache that keeps meshes whose evaluated geometry did not change.
    should_stop(): asked before each mesh is exported; True raises ExportCancelled."""
    export = cache.export if cache is not None else _export_object
    meshes = {}
    for instance in depsgraph.object_instances:
        obj = instance.object
        # Curves, surfaces, text and metaballs are listed too, as MESH instances of their
        # evaluated surface, next to the original object (which we skip, as Cycles does).
        if obj.type != 'MESH' or not is_visible(instance):
            continue
        materials = [slot.material for slot in obj.material_slots]
        # The evaluated data is shared by all instances of one geometry (and by objects sharing
        # an unmodified mesh); materials can differ per object when slots link to the object.
        key = (obj.data.as_pointer(), tuple(m.as_pointer() if m else 0 for m in materials))
        entry = meshes.get(key)
        if entry is None:
            if should_stop is not None and should_stop():
                raise ExportCancelled()
            entry = meshes[key] = export(obj, materials, uv_names)
            if entry is not None:
                entry.owners = []  # this export's (a cached entry may carry an older list)
        if entry is not None:
            entry.matrices.append(np.array(instance.matrix_world, np.float32))
            entry.owners.append((obj.name, bool(instance.is_instance)))
    if cache is not None:
        cache.end_export()
    return [m for m in meshes.values() if m is not None]


def _export_object(obj, materials, uv_names=None):
    try:
        mesh = obj.to_mesh()
        if mesh is None or len(mesh.polygons) == 0:
            return None
        positions, triangles, normals, material_indices = mesh_arrays(mesh)
        if not materials:
            materials = list(mesh.materials)
        uvs, missing = mesh_uvs(mesh, uv_names(materials)) if uv_names else ({}, [])
        # The evaluated mesh's texture space (automatic: its bounding box), as Cycles uses it;
        # non-finite vertices make it non-finite: then the core's own box of the finite ones.
        texspace = (tuple(mesh.texspace_location), tuple(mesh.texspace_size))
        if not np.isfinite(texspace).all():
            texspace = None
    finally:
        obj.to_mesh_clear()
    # Blender and Cycles clamp out-of-range material indices to the last slot.
    np.clip(material_indices, 0, max(len(materials) - 1, 0), out=material_indices)
    return MeshData(obj.original.name, positions, triangles, normals, material_indices, materials,
                    uvs=uvs, missing_uv_maps=missing, texspace=texspace)
