"""Evaluated geometry → numpy arrays, one entry per unique mesh with all its instance matrices."""

from dataclasses import dataclass, field

import numpy as np



@dataclass
class MeshData:
    name: str
    positions: np.ndarray  # float32 (V, 3), object space
    triangles: np.ndarray  # int32 (T, 3), indices into positions
    # Shading normals, shared: corner k of triangle t has normals[normal_indices[t, k]]. Per
    # vertex, per face or per corner as the mesh stores them; the core expands them.
    normals: np.ndarray  # float32 (N, 3)
    normal_indices: np.ndarray  # int32 (T, 3)
    material_indices: np.ndarray  # int32 (T,), material slot per triangle
    materials: list  # bpy.types.Material or None per slot
    matrices: list = field(default_factory=list)  # float32 (4, 4) object-to-world, one per instance
    uvs: dict = field(default_factory=dict)  # global uv-set index -> float32 (T, 3, 2) per corner
    missing_uv_maps: list = field(default_factory=list)  # UV map names its materials need
    # Blender's texture space ((location), (size)) for generated coordinates, or None.
    texspace: tuple = None

    @property
    def corner_normals(self):
        """float32 (T, 3, 3): the shading normal of every triangle corner (expanded)."""
        return self.normals[self.normal_indices]


def _int_attribute(mesh, name, size):
    """A raw int attribute (e.g. ".corner_vert", "material_index") read straight from its
    array, or None when the mesh does not store it (material_index is absent when all 0)."""
    attr = mesh.attributes.get(name)
    if attr is None or attr.data_type != 'INT' or len(attr.data) != size:
        return None
    out = np.empty(size, np.int32)
    attr.data.foreach_get("value", out)
    return out


# Relative margin within which the quad-split tests below leave the decision to Blender: far
# wider than the float rounding of Blender's own single-precision tests.
_SPLIT_MARGIN = 1e-4


def _cross(a, b):
    """Row-wise cross products of two (N, 3) arrays (np.cross is several times slower)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _quad_flips(mesh, loops, quad_first, corners, size):
    """(flip, unsure) per quad: whether Blender cuts it along 1-3, and where that is too close
    to call here (unsure is None when the whole array should be read from Blender). corners:
    the quads' four corner positions, (Q, 3) each; size: the largest |coordinate| of the mesh.

    Blender has two versions of the quad-flip test and picks one by what it has cached, so
    where they disagree a few quads are read back to see which one this mesh got."""
    d01, d02, d03 = corners[1] - corners[0], corners[2] - corners[0], corners[3] - corners[0]
    ca, cb = _cross(d01, d02), _cross(d03, d02)
    caa, cbb, dot = _dot(ca, ca), _dot(cb, cb), _dot(ca, cb)
    own = _SPLIT_MARGIN * (caa + cbb)  # this float32 arithmetic's own error, generously
    # is_quad_flip_v3_first_third_fast: flip when (v1-v0)x(v2-v0) . (v3-v0)x(v2-v0) > 0.
    m1 = _SPLIT_MARGIN * np.sqrt(caa * cbb) + own
    fast_flip, fast_keep = dot > m1, dot < -m1
    # is_quad_flip_v3_first_third_fast_with_normal: n = (v0-v2)x(v1-v3) (normal_quad_v3,
    # normalised), t = (v2-v0)x n; the 0-2 cut is kept where (v3-v0).t < 0 < (v1-v0).t. With
    # n = ca - cb those are (ca.cb - |cb|^2) / |n| and (|ca|^2 - ca.cb) / |n|. Blender dots the
    # absolute positions with t (|t| = |v2-v0|): rounding of the order of |position| |t|.
    n_len = np.sqrt(np.maximum(caa + cbb - 2 * dot, 0))
    m2 = _SPLIT_MARGIN * 3.0 * size * np.sqrt(_dot(d02, d02)) * n_len + own
    a3, a1 = dot - cbb, caa - dot
    normal_keep = (a3 < -m2) & (a1 > m2)
    normal_flip = (a3 > m2) | (a1 < -m2)
    disagree = np.flatnonzero((fast_flip & normal_keep) | (fast_keep & normal_flip))
    use_fast = use_normal = True
    if len(disagree):
        blender = mesh.loop_triangles
        for i in disagree[:8]:
            flipped = blender[int(quad_first[i])].loops[2] == loops[quad_first[i] + 1, 2]
            use_fast &= bool(flipped) == bool(fast_flip[i])
            use_normal &= bool(flipped) == bool(normal_flip[i])
        if use_fast == use_normal:  # both or neither explain Blender's cuts
            return None, None
    if use_fast and use_normal:  # no disagreement: certain where both are
        return fast_flip & normal_flip, ~((fast_flip & normal_flip) | (fast_keep & normal_keep))
    if use_fast:
        return fast_flip, ~(fast_flip | fast_keep)
    return normal_flip, ~(normal_flip | normal_keep)


def triangle_corners(mesh, positions, corner_verts, tri_polys):
    """int32 (T * 3,): the corner (loop) indices of mesh.loop_triangles, in their order.

    Reading loop_triangles.loops goes through RNA one element at a time (about 0.2 s for 1M
    triangles), so where every face is a triangle or a quad the split is worked out here, as
    Blender's tessellation does it: a quad is cut along its 0-2 diagonal unless the quad-flip
    test says that diagonal lies outside it, then along 1-3 (mesh_tessellate.cc). Blender uses
    one of two versions of that test (with or without the face normal, depending on what it has
    cached); quads where either is close to its threshold, or where they disagree, are read
    from Blender one by one. Meshes with n-gons read the whole array from Blender."""
    n_tris = len(tri_polys)
    n_faces = len(mesh.polygons)
    tris_per_face = np.bincount(tri_polys, minlength=n_faces)
    if n_tris == 0 or tris_per_face.max() > 2 or tris_per_face.min() < 1:
        loops = np.empty(n_tris * 3, np.int32)
        mesh.loop_triangles.foreach_get("loops", loops)
        return loops
    # Faces are contiguous runs of corners in face order (Blender's face offsets).
    sizes = tris_per_face + 2
    starts = np.zeros(n_faces, np.int32)
    np.cumsum(sizes[:-1], out=starts[1:])
    s = starts[tri_polys]  # each triangle's face start
    # The first triangle of a quad is (0, 1, 2), the second (0, 2, 3): k-th triangle of its face.
    second = np.zeros(n_tris, bool)
    second[1:] = tri_polys[1:] == tri_polys[:-1]
    loops = np.empty((n_tris, 3), np.int32)
    loops[:, 0] = s
    loops[:, 1] = s + 1 + second
    loops[:, 2] = s + 2 + second
    quad_first = np.flatnonzero(sizes[tri_polys] == 4)
    quad_first = quad_first[~second[quad_first]]
    if len(quad_first):
        qs = s[quad_first]
        size = float(np.abs(positions).max()) if len(positions) else 0.0
        with np.errstate(invalid="ignore", over="ignore"):  # non-finite corners: unsure, Blender decides
            flip, unsure = _quad_flips(mesh, loops, quad_first, [positions[corner_verts[qs + k]] for k in range(4)],
                                       size if np.isfinite(size) else np.inf)
        if unsure is None or np.count_nonzero(unsure) * 50 > n_tris:
            # Reading quads one by one costs about 50 times a triangle of the whole array.
            loops = np.empty(n_tris * 3, np.int32)
            mesh.loop_triangles.foreach_get("loops", loops)
            return loops
        f = quad_first[flip & ~unsure]
        loops[f, 2] = loops[f + 1, 2]  # (0, 1, 3)
        loops[f + 1, 0] = loops[f, 1]  # (1, 2, 3)
        if unsure.any():
            blender = mesh.loop_triangles
            for i in quad_first[unsure]:
                loops[i] = blender[int(i)].loops
                loops[i + 1] = blender[int(i) + 1].loops
    return loops.ravel()


def mesh_arrays(mesh):
    """(positions, triangles, normals, normal_indices, material_indices, corners) of a bpy Mesh,
    via foreach_get; corners: int32 (T * 3,) corner (loop) index of every triangle corner.

    Only the mesh's own arrays are read (no per-element RNA collections where avoidable), and
    normals stay as Blender stores them (per vertex, face or corner) with an index per triangle
    corner: the core expands them (tests/bench/bench_export.py times this)."""
    mesh.calc_loop_triangles()
    n_tris = len(mesh.loop_triangles)
    n_corners = len(mesh.loops)

    positions = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", positions)
    positions = positions.reshape(-1, 3)
    tri_polys = np.empty(n_tris, np.int32)
    mesh.loop_triangle_polygons.foreach_get("value", tri_polys)

    corner_verts = _int_attribute(mesh, ".corner_vert", n_corners)
    if corner_verts is None:
        corner_verts = np.empty(n_corners, np.int32)
        mesh.loops.foreach_get("vertex_index", corner_verts)
    loops = triangle_corners(mesh, positions, corner_verts, tri_polys)
    triangles = corner_verts[loops].reshape(-1, 3)

    poly_materials = _int_attribute(mesh, "material_index", len(mesh.polygons))
    material_indices = (poly_materials[tri_polys] if poly_materials is not None
                        else np.zeros(n_tris, np.int32))

    # Per-corner normals encode smooth/flat faces, sharp edges and custom normals; when the mesh
    # says its normals live on points or faces, those (cheaper) arrays give the same vectors.
    domain = mesh.normals_domain
    if domain == 'POINT':
        normals = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertex_normals.foreach_get("vector", normals)
        normal_indices = triangles
    elif domain == 'FACE':
        normals = np.empty(len(mesh.polygons) * 3, np.float32)
        mesh.polygon_normals.foreach_get("vector", normals)
        normal_indices = np.repeat(tri_polys, 3).reshape(-1, 3)
    else:
        normals = np.empty(len(mesh.corner_normals) * 3, np.float32)
        mesh.corner_normals.foreach_get("vector", normals)
        normal_indices = loops.reshape(-1, 3)

    return (positions, np.ascontiguousarray(triangles, np.int32), normals.reshape(-1, 3),
            np.ascontiguousarray(normal_indices, np.int32), material_indices, loops)


def mesh_uvs(mesh, names, loops):
    """{k: float32 (T, 3, 2) per-corner UVs} for {k: UV map name} ("" = the active render UV
    map), and the names the mesh lacks. loops: the triangles' corner indices (mesh_arrays)."""
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
            entry.matrices.append(np.array(instance.matrix_world, np.float32))
    if cache is not None:
        cache.end_export()
    return [m for m in meshes.values() if m is not None]


def _export_object(obj, materials, uv_names=None):
    try:
        mesh = obj.to_mesh()
        if mesh is None or len(mesh.polygons) == 0:
            return None
        positions, triangles, normals, normal_indices, material_indices, loops = mesh_arrays(mesh)
        if not materials:
            materials = list(mesh.materials)
        uvs, missing = mesh_uvs(mesh, uv_names(materials), loops) if uv_names else ({}, [])
        # The evaluated mesh's texture space (automatic: its bounding box), as Cycles uses it;
        # non-finite vertices make it non-finite: then the core's own box of the finite ones.
        texspace = (tuple(mesh.texspace_location), tuple(mesh.texspace_size))
        if not np.isfinite(texspace).all():
            texspace = None
    finally:
        obj.to_mesh_clear()
    # Blender and Cycles clamp out-of-range material indices to the last slot.
    np.clip(material_indices, 0, max(len(materials) - 1, 0), out=material_indices)
    return MeshData(obj.original.name, positions, triangles, normals, normal_indices, material_indices, materials,
                    uvs=uvs, missing_uv_maps=missing, texspace=texspace)
