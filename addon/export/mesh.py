"""Evaluated geometry → numpy arrays, one entry per unique mesh with all its instance matrices."""

import math
from dataclasses import dataclass, field

import numpy as np

from .motion import instance_key
from .tangents import mesh_tangents, tangent_uv_maps


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
    # Per matrix: (object name, made by an instancer), so live edits can find an object's instance.
    owners: list = field(default_factory=list)
    # Per matrix, what the Object Info node reads: (RGBA colour, pass index, random id), the
    # random id None for a plain object (the core derives it from the name, as Cycles).
    infos: list = field(default_factory=list)
    uvs: dict = field(default_factory=dict)  # global uv-set index -> float32 (T, 3, 2) per corner
    missing_uv_maps: list = field(default_factory=list)  # UV map names its materials need
    # Blender's texture space ((location), (size)) for generated coordinates, or None.
    texspace: tuple = None
    # Motion blur, per matrix: what names its depsgraph instance across sub-frames, and its
    # matrices at the motion steps ((S, 4, 4) float32) or None (export.motion fills them).
    motion_keys: list = field(default_factory=list)
    motions: list = field(default_factory=list)
    # Deformation blur: float32 (S, V, 3) vertex positions at the motion steps, or None.
    motion_positions: np.ndarray = None
    attributes: dict = field(default_factory=dict)  # attribute set k -> float32 (T, 3, 4) RGBA
    missing_attributes: list = field(default_factory=list)  # attribute names its materials read
    # uv set k -> float32 (T, 3, 4) MikkTSpace tangent and sign per corner, for the UV maps
    # whose tangents its materials read; tangent_problem: why there are none, or None.
    tangents: dict = field(default_factory=dict)
    tangent_problem: str = None
    # Per matrix: float32 (K, 4) of the Attribute node's Object / Instancer slots (the first
    # K of the scene's; export.object_attributes), or None.
    object_attributes: list = field(default_factory=list)
    # Volume objects' velocity blur: what export.volume found (velocity_source), and what
    # export.motion makes of it under the shutter ((grid ids, scale, offset, interpolation)).
    volume_velocity: dict = None
    velocity: tuple = None
    # True displacement: bool (T,) flat-shaded triangles (their displaced face's normal), or
    # None (all smooth, or no material displaces).
    flat: np.ndarray = None
    # Adaptive subdivision (export.subdivision): why it was not done (a warning), or None; and
    # what the dicing did ({"level", "max_edge_factor", "capped"}), or None.
    subdivision_problem: str = None
    subdivision: dict = None

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


def _bool_attribute(mesh, name, domain, size):
    """A boolean attribute of `domain` as a bool array, or None when the mesh lacks it."""
    attr = mesh.attributes.get(name)
    if attr is None or attr.data_type != 'BOOLEAN' or attr.domain != domain or len(attr.data) != size:
        return None
    out = np.empty(size, bool)
    attr.data.foreach_get("value", out)
    return out


def mesh_positions(mesh):
    """float32 (V, 3) vertex positions. The "position" attribute's data is read as one raw
    array (under 1 ms for 0.5M vertices); vertices.co goes element by element (about 20 ms)."""
    n = len(mesh.vertices)
    out = np.empty(n * 3, np.float32)
    attr = mesh.attributes.get("position")
    if attr is not None and attr.data_type == 'FLOAT_VECTOR' and attr.domain == 'POINT' and len(attr.data) == n:
        attr.data.foreach_get("vector", out)
    else:
        mesh.vertices.foreach_get("co", out)
    return out.reshape(-1, 3)


def _polygon_core():
    """The core module when it can triangulate polygons and compute their normals, else None
    (then the export reads Blender's triangulation and normals; tests run without the core)."""
    try:
        from ..core import get_core
        pc = get_core()
    except (ImportError, RuntimeError):
        return None
    return pc


def face_offsets(tri_polys, n_faces, n_corners, pc=None):
    """int32 (F + 1,) start corner of every face (and the corner count), from the face of each
    of Blender's triangles (a face of k corners has k - 2 of them; one fast raw-array read
    instead of polygons.loop_start's per-element one); None if they do not add up or a face
    has no triangle (an invalid mesh: then Blender's own collections are read). pc: the core,
    which does it in one pass over Blender's face-ordered triangles (numpy's bincount and
    cumsum take ~10 ms and ~14 MB of temporaries for 1M triangles)."""
    if pc is not None:
        return pc.polygon_face_offsets(tri_polys, n_faces, n_corners)
    sizes = np.bincount(tri_polys, minlength=n_faces)
    if len(sizes) != n_faces or (n_faces and sizes.min() == 0):  # a face of under 3 corners
        return None
    offsets = np.empty(n_faces + 1, np.int64)
    offsets[0] = 0
    np.cumsum(sizes + 2, out=offsets[1:])
    if offsets[-1] != n_corners or n_corners > np.iinfo(np.int32).max:
        return None
    return offsets.astype(np.int32)


def triangle_corners(mesh, pc, positions, corner_verts, offsets, n_tris, corners=True):
    """(corners, triangles): int32 (T * 3,) corner index and int32 (T, 3) vertex indices of
    every triangle corner, Blender's triangulation. The core triangulates meshes of triangles
    and quads (as Blender does, tested against loop_triangles); meshes with n-gons are read from
    Blender's loop_triangles. corners=False: the core may skip the corner indices (None)."""
    if pc is not None and offsets is not None:
        loops, triangles, ngons = pc.triangulate_polygons(positions, corner_verts, offsets, corners=corners)
        if not ngons:
            return (loops.reshape(-1) if loops is not None else None), triangles
    # Meshes with n-gons (Blender's polyfill + beautify is not reproduced by the core): the
    # whole triangulation, read through RNA one element at a time (about 0.14 s for 1M
    # triangles); patching only the n-gons' triangles would need a per-element Python loop.
    loops = np.empty(n_tris * 3, np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    return loops, corner_verts[loops].reshape(-1, 3)


def mesh_arrays(mesh, corners=True, slots=None):
    """(positions, triangles, normals, normal_indices, material_indices, corners) of a bpy Mesh,
    via foreach_get; corners: int32 (T * 3,) corner (loop) index of every triangle corner, or
    None when corners=False and the normals do not need them (only UV maps do then).
    slots: the number of material slots; indices beyond them are clamped to the last one.

    Everything is read from the mesh's raw arrays (positions, corner vertices, the face of each
    triangle, material indices, corner edges, sharp flags): triangles and quads are
    triangulated by the core, and smooth (point-domain) and sharp-edged (corner-domain)
    normals are computed there too; only the triangulation of meshes with n-gons, flat
    (face-domain) normals and custom normals come from Blender's own (per-element or lazily
    computed) collections.
    Normals stay as stored (per vertex, face or corner) with an index per triangle corner, and
    the core keeps them shared: no per-corner gather in numpy (bench_export.py)."""
    mesh.calc_loop_triangles()
    n_tris = len(mesh.loop_triangles)
    n_corners = len(mesh.loops)
    n_faces = len(mesh.polygons)

    positions = mesh_positions(mesh)
    tri_polys = np.empty(n_tris, np.int32)
    mesh.loop_triangle_polygons.foreach_get("value", tri_polys)

    corner_verts = _int_attribute(mesh, ".corner_vert", n_corners)
    if corner_verts is None:
        corner_verts = np.empty(n_corners, np.int32)
        mesh.loops.foreach_get("vertex_index", corner_verts)
    pc = _polygon_core()
    offsets = face_offsets(tri_polys, n_faces, n_corners, pc) if pc is not None else None
    # Per-corner normals encode smooth/flat faces, sharp edges and custom normals; when the mesh
    # says its normals live on points or faces, those (cheaper) arrays give the same vectors.
    domain = mesh.normals_domain
    loops, triangles = triangle_corners(mesh, pc, positions, corner_verts, offsets, n_tris,
                                        corners or domain not in ('POINT', 'FACE'))

    poly_materials = _int_attribute(mesh, "material_index", n_faces)
    if poly_materials is None:
        material_indices = np.zeros(n_tris, np.int32)
    else:
        if slots is not None:  # per face, before the per-triangle gather
            np.clip(poly_materials, 0, max(slots - 1, 0), out=poly_materials)
        material_indices = poly_materials[tri_polys]

    if domain == 'POINT':
        if offsets is not None:  # Blender's formula, multi-threaded (Blender's: ~80 ms per 1M)
            normals = pc.polygon_vertex_normals(positions, corner_verts, offsets)
        else:
            normals = np.empty(len(mesh.vertices) * 3, np.float32)
            mesh.vertex_normals.foreach_get("vector", normals)
        normal_indices = triangles
    elif domain == 'FACE':
        normals = np.empty(n_faces * 3, np.float32)
        mesh.polygon_normals.foreach_get("vector", normals)
        normal_indices = np.repeat(tri_polys, 3).reshape(-1, 3)
    elif offsets is not None and not mesh.has_custom_normals and pc is not None:
        # Sharp edges/faces (e.g. Smooth by Angle): Blender's fans, computed by the core.
        n_edges = len(mesh.edges)
        corner_edges = _int_attribute(mesh, ".corner_edge", n_corners)
        if corner_edges is None:
            corner_edges = np.empty(n_corners, np.int32)
            mesh.loops.foreach_get("edge_index", corner_edges)
        normals = pc.polygon_corner_normals(positions, corner_verts, offsets, corner_edges, n_edges,
                                            _bool_attribute(mesh, "sharp_edge", 'EDGE', n_edges),
                                            _bool_attribute(mesh, "sharp_face", 'FACE', n_faces))
        normal_indices = loops.reshape(-1, 3)
    else:  # custom normals: Blender's
        normals = np.empty(len(mesh.corner_normals) * 3, np.float32)
        mesh.corner_normals.foreach_get("vector", normals)
        normal_indices = loops.reshape(-1, 3)
    normals = normals.reshape(-1, 3)

    # Cycles shades a flat triangle by its own normal, not its polygon's; custom normals it
    # reads as they are, on flat faces too (measured in tests/blender/test_flat_faces_cycles.py).
    if domain == 'FACE' or (domain == 'CORNER' and not mesh.has_custom_normals):
        flat = (np.ones(n_faces, bool) if domain == 'FACE'
                else _bool_attribute(mesh, "sharp_face", 'FACE', n_faces))
        if flat is not None:
            normals, normal_indices = flat_triangle_normals(positions, triangles, tri_polys, flat,
                                                            normals, normal_indices)

    return (positions, np.ascontiguousarray(triangles, np.int32), normals,
            np.ascontiguousarray(normal_indices, np.int32), material_indices, loops)


# A flat face's triangle keeps the face's normal unless they differ by more than this (per
# component): planar faces (float rounding, ~1e-7) stay bit for bit as before.
FLAT_NORMAL_TOLERANCE = 1e-5


def flat_triangle_normals(positions, triangles, tri_polys, flat_faces, normals, normal_indices):
    """(normals, normal_indices) where every triangle of a flat-shaded face (flat_faces: bool
    per face) that is not planar gets its own geometric normal, as Cycles shades a flat
    triangle by its own normal (Ng) where Blender gives every corner the polygon's normal. A
    triangle whose normal equals its face's (within FLAT_NORMAL_TOLERANCE) keeps the face's,
    so planar faces are unchanged; the new normals are appended and only their triangles'
    indices change (normal_indices is copied, never written through)."""
    # Faces of one triangle are planar: only triangles of faces with more than one can differ
    # (Blender's triangles come in face order, so a face's are neighbours).
    flat_faces = np.asarray(flat_faces, bool)
    multi = np.zeros(len(tri_polys), bool)
    if len(tri_polys) > 1:
        same = tri_polys[1:] == tri_polys[:-1]
        multi[1:] = same
        multi[:-1] |= same
    if not flat_faces.all():
        multi &= flat_faces[tri_polys]
    candidates = np.flatnonzero(multi)
    if len(candidates) == 0:
        return normals, normal_indices
    # Component by component on flat arrays (np.cross, (C, 3, 3) gathers and reductions along
    # the short axis are several times slower): n = (v1 - v0) x (v2 - v0), normalised.
    tri = triangles[candidates]
    i0, i1, i2 = tri[:, 0], tri[:, 1], tri[:, 2]
    v = [np.ascontiguousarray(positions[:, k]) for k in range(3)]
    e1 = [v[k][i1] - v[k][i0] for k in range(3)]
    e2 = [v[k][i2] - v[k][i0] for k in range(3)]
    n = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    changed = np.isfinite(inv)  # (a degenerate triangle keeps its face's normal)
    face_n = normals[normal_indices[candidates, 0]]
    far = np.zeros(len(candidates), bool)
    for k in range(3):
        n[k] *= inv
        far |= np.abs(n[k] - face_n[:, k]) > FLAT_NORMAL_TOLERANCE
    changed &= far
    if not changed.any():
        return normals, normal_indices
    which = candidates[changed]
    normal_indices = np.array(normal_indices, np.int32)  # (a copy: corner indices may be a view of loops)
    normal_indices[which] = (len(normals) + np.arange(len(which), dtype=np.int32))[:, None]
    n = np.stack([n[k][changed] for k in range(3)], 1)
    return np.concatenate([normals, n]), normal_indices


def mesh_uvs(mesh, names, loops):
    """{k: float32 (T, 3, 2) per-corner UVs} for {k: UV map name} ("" = the active render UV
    map), and the names the mesh lacks. loops: the triangles' corner indices (mesh_arrays)."""
    uvs, missing, cache = {}, [], {}
    active = next((layer for layer in mesh.uv_layers if layer.active_render), None)
    for k, name in names.items():
        if isinstance(name, tuple):  # an attribute set (mesh_attributes)
            continue
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


# Attribute data types: foreach_get field and values per element (all read as float32).
_ATTRIBUTE_TYPES = {"FLOAT": ("value", 1), "INT": ("value", 1), "INT8": ("value", 1),
                    "BOOLEAN": ("value", 1), "FLOAT2": ("vector", 2), "INT32_2D": ("value", 2),
                    "FLOAT_VECTOR": ("vector", 3), "FLOAT_COLOR": ("color", 4),
                    "BYTE_COLOR": ("color", 4), "QUATERNION": ("value", 4)}


def _attribute_rgba(attr):
    """float32 (N, 4) of an attribute's values as Cycles reads them: one value as grey, 2D
    vectors with z = 0, alpha 1 unless it is a colour (byte colours come linear from `color`).
    None for types without a meaning as a colour (matrices, strings)."""
    kind = _ATTRIBUTE_TYPES.get(attr.data_type)
    if kind is None:
        return None
    field, width = kind
    n = len(attr.data)
    raw = np.empty(n * width, np.float32 if attr.data_type not in ("INT", "INT8", "INT32_2D", "BOOLEAN")
                   else (bool if attr.data_type == "BOOLEAN" else np.int32))
    attr.data.foreach_get(field, raw)
    raw = raw.reshape(n, width).astype(np.float32, copy=False)
    out = np.ones((n, 4), np.float32)
    if width == 1:
        out[:, :3] = raw
    else:
        out[:, :width] = raw
        if width == 2:
            out[:, 2] = 0.0
    return out


def _corner_verts(mesh):
    corner_verts = _int_attribute(mesh, ".corner_vert", len(mesh.loops))
    if corner_verts is None:
        corner_verts = np.empty(len(mesh.loops), np.int32)
        mesh.loops.foreach_get("vertex_index", corner_verts)
    return corner_verts


def vertex_pointiness(mesh):
    """float32 per vertex: Cycles' Pointiness (its attr_create_pointiness, vectorised):
    vertices at the same position welded, the angle between each welded vertex's normal and
    the mean direction of its unique edges (over pi), then averaged with its edge neighbours.
    Cycles also welds vertices closer than ~3e-4; exact duplicates only here."""
    n = len(mesh.vertices)
    if n == 0:
        return np.zeros(0, np.float32)
    pos = mesh_positions(mesh)
    vnorm = np.empty(n * 3, np.float32)
    mesh.vertex_normals.foreach_get("vector", vnorm)
    vnorm = vnorm.reshape(-1, 3)
    edges = np.empty(len(mesh.edges) * 2, np.int32)
    mesh.edges.foreach_get("vertices", edges)
    _, first, inverse = np.unique(pos, axis=0, return_index=True, return_inverse=True)
    orig = first[inverse.reshape(-1)].astype(np.int64)  # each vertex's representative
    acc = np.zeros((n, 3), np.float32)
    np.add.at(acc, orig, vnorm)
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = acc / np.linalg.norm(acc, axis=1, keepdims=True)
    pairs = np.sort(orig[edges.reshape(-1, 2)], axis=1)
    pairs = np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)
    v0, v1 = pairs[:, 0], pairs[:, 1]
    e = pos[v1] - pos[v0]
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    edge_sum = np.zeros((n, 3), np.float32)
    np.add.at(edge_sum, v0, e)
    np.add.at(edge_sum, v1, -e)
    count = np.bincount(v0, minlength=n) + np.bincount(v1, minlength=n)
    raw = np.zeros(n, np.float32)
    sel = (orig == np.arange(n)) & (count > 0)
    mean_dir = edge_sum[sel] / count[sel, None].astype(np.float32)
    cosine = np.clip(np.einsum("ij,ij->i", normal[sel], mean_dir), -1.0, 1.0)
    raw[sel] = np.arccos(cosine) * np.float32(1.0 / np.pi)
    data = raw.copy()
    np.add.at(data, v0, raw[v1])
    np.add.at(data, v1, raw[v0])
    data /= (count + 1).astype(np.float32)
    out = data[orig]
    return np.where(np.isfinite(out), out, 0.0).astype(np.float32)


# A missing attribute as the Attribute node reads it (Cycles' svm_node_attr: 0, Alpha 1); the
# Color Attribute node's missing one reads 0 with Alpha 0 (no set sent).
_MISSING_ATTRIBUTE = np.float32([0.0, 0.0, 0.0, 1.0])


def mesh_attributes(mesh, names, loops):
    """{k: float32 (T, 3, 4) per-corner RGBA} for the attribute sets among {k: name}
    (("attr", name) or ("color", name), "" = the render colour attribute), and the names the
    mesh lacks (an Attribute node's as (0, 0, 0, 1), Cycles' Alpha 1). Point, corner and face
    attributes; loops: the triangles' corner indices."""
    out, missing = {}, []
    wanted = {k: n for k, n in names.items() if isinstance(n, tuple)}
    if not wanted:
        return out, missing
    corner_verts = tri_faces = None
    for k, (kind, name) in wanted.items():
        if kind == "pointiness":  # Geometry ▸ Pointiness, per vertex, in every channel
            p = vertex_pointiness(mesh)
            if corner_verts is None:
                corner_verts = _corner_verts(mesh)
            out[k] = np.ascontiguousarray(np.repeat(p[:, None], 4, 1)[corner_verts[loops]]
                                          .reshape(-1, 3, 4))
            continue
        if kind == "island":  # Geometry ▸ Random Per Island: per triangle, from its first vertex
            if corner_verts is None:
                corner_verts = _corner_verts(mesh)
            edges = np.empty(len(mesh.edges) * 2, np.int32)
            mesh.edges.foreach_get("vertices", edges)
            from ..core import get_core
            per_vertex = get_core().island_random(len(mesh.vertices), edges.reshape(-1, 2))
            tri = per_vertex[corner_verts[loops].reshape(-1, 3)[:, 0]]
            out[k] = np.ascontiguousarray(np.broadcast_to(tri[:, None, None], (len(tri), 3, 4)),
                                          dtype=np.float32)
            continue
        if kind == "color" and not name:
            name = mesh.color_attributes.default_color_name or \
                (mesh.color_attributes[0].name if len(mesh.color_attributes) else "")
        attr = mesh.attributes.get(name) if name else None
        if kind == "color" and attr is not None and attr.data_type not in ("FLOAT_COLOR", "BYTE_COLOR"):
            attr = None
        values = _attribute_rgba(attr) if attr is not None and attr.domain != 'EDGE' else None
        if values is None:
            missing.append(name or "(render colour attribute)")
            if kind == "attr":  # Cycles' Attribute node reads a missing one as 0 with alpha 1
                out[k] = np.tile(_MISSING_ATTRIBUTE, (len(loops) // 3, 3, 1))
            continue
        if attr.domain == 'CORNER':
            index = loops
        elif attr.domain == 'POINT':
            if corner_verts is None:
                corner_verts = _corner_verts(mesh)
            index = corner_verts[loops]
        else:  # FACE
            if tri_faces is None:
                tri_faces = np.empty(len(mesh.loop_triangles), np.int32)
                mesh.loop_triangle_polygons.foreach_get("value", tri_faces)
            index = np.repeat(tri_faces, 3)
        out[k] = np.ascontiguousarray(values[index].reshape(-1, 3, 4))
    return out, missing


def is_visible(instance):
    if instance.is_instance:
        return True  # the instancer's visibility was already applied by the depsgraph
    if not instance.show_self:
        return False  # e.g. an instancer that hides itself
    # A viewport depsgraph still holds objects hidden for render.
    return not instance.object.original.hide_render


class ExportCancelled(Exception):
    """The user cancelled the render while the scene was being exported."""


def collect_meshes(depsgraph, uv_names=None, cache=None, should_stop=None, object_attributes=None, layer=None):
    """All visible geometry of the depsgraph. Instances of the same evaluated geometry (and
    materials) share one MeshData and add only their matrix_world. uv_names(materials) ->
    {global uv-set index: UV map name} says which UV maps to export (none if None).
    cache: a mesh_cache.MeshCache that keeps meshes whose evaluated geometry did not change.
    should_stop(): asked before each mesh is exported; True raises ExportCancelled.
    object_attributes: an object_attributes.InstanceAttributes whose slots the instances'
    values are resolved for (uv_names compiles a mesh's materials, numbering their slots,
    when its entry is made). layer: the view layer's view_layer.LayerSettings (read from the
    depsgraph when None): its Material Override and its Surfaces filter."""
    from .subdivision import adaptive_mesh_data, adaptive_modifier, dicing_context
    from .view_layer import layer_settings, slot_materials
    if layer is None:
        layer = layer_settings(depsgraph)
    if not layer.use_solid:  # Filter ▸ Surfaces off: Cycles syncs meshes without geometry
        if cache is not None:
            cache.end_export()
        return []
    meshes = {}
    dicing = None  # export.subdivision's camera, made at the first adaptive object
    generated = {}  # instancer -> how many generated geometries of it were exported so far
    view_layer = getattr(depsgraph, "view_layer", None)
    for instance in depsgraph.object_instances:
        obj = instance.object
        # Curves, surfaces, text and metaballs are listed too, as MESH instances of their
        # evaluated surface, next to the original object (which we skip, as Cycles does).
        if obj.type != 'MESH' or not is_visible(instance):
            continue
        materials = slot_materials(obj.material_slots, layer)
        # The evaluated data is shared by all instances of one geometry (and by objects sharing
        # an unmodified mesh); materials can differ per object when slots link to the object.
        key = (obj.data.as_pointer(), tuple(m.as_pointer() if m else 0 for m in materials))
        entry = meshes.get(key)
        if entry is None:
            if should_stop is not None and should_stop():
                raise ExportCancelled()
            modifier = adaptive_modifier(obj, depsgraph)
            if modifier is not None:  # (diced for this camera: never from the cache)
                if dicing is None:
                    dicing = dicing_context(depsgraph)
                entry = adaptive_mesh_data(obj, modifier, materials, uv_names, dicing, depsgraph)
            elif cache is None:
                entry = _export_object(obj, materials, uv_names)
            else:
                # Geometry nodes' generated instances have their instancer as `original`: each
                # gets its ordinal among the instancer's (the same while it is not re-evaluated).
                ordinal = 0
                if instance.is_instance and instance.parent is not None and \
                        instance.parent.original == obj.original:
                    instancer = obj.original.as_pointer()
                    ordinal = generated[instancer] = generated.get(instancer, 0) + 1
                entry = cache.export(obj, materials, uv_names, generated=ordinal)
            meshes[key] = entry
            if entry is not None:
                entry.owners = []  # this export's (a cached entry may carry older lists)
                entry.infos = []
                entry.motion_keys = []
                entry.motions = []
                entry.motion_positions = None
                entry.object_attributes = []
        if entry is not None:
            entry.matrices.append(np.array(instance.matrix_world, np.float32))
            entry.owners.append((obj.name, bool(instance.is_instance)))
            entry.infos.append(object_info(instance, view_layer))
            entry.motion_keys.append(instance_key(instance))
            if object_attributes is not None:  # (the entry's export compiled its materials)
                entry.object_attributes.append(object_attributes.values(instance))
    if cache is not None:
        cache.end_export()
    return [m for m in meshes.values() if m is not None]


def object_info(instance, view_layer=None):
    """(RGBA colour, pass index, random id or None, shadow terminator geometry offset,
    Cryptomatte names, shadow catcher, holdout, light group name, AO distance, indirect only) of
    a depsgraph object instance. The names are
    (object, asset) as Cycles gives them: the object's name and its top parent's (its own
    without a parent). Holdout is the object's own or, given the depsgraph's view layer, its
    collection's there too (Cycles' holdout_get); indirect only (invisible to camera rays) its
    collection's Indirect Only there, unless it is held out (Cycles' sync_object)."""
    obj = instance.object
    random_id = (instance.random_id & 0xFFFFFFFF) if instance.is_instance else None
    terminator = float(getattr(obj, "shadow_terminator_geometry_offset", 0.0))
    top = obj
    while top.parent is not None:
        top = top.parent
    catcher = bool(getattr(obj, "is_shadow_catcher", False))
    from .light import object_lightgroup
    holdout = _holdout(instance, view_layer)
    return (tuple(obj.color), int(obj.pass_index), random_id, terminator, (obj.name, top.name), catcher,
            holdout, object_lightgroup(instance), ao_distance(instance),
            not holdout and _indirect_only(instance, view_layer))


def ao_distance(instance):
    """Cycles' object AO Distance (Object ▸ Visibility ▸ Fast GI Approximation,
    object.cycles.ao_distance): the object's own, else its instancer's (BlenderSync::sync_object),
    0 (the world's) where neither has one or Cycles' add-on is not there."""
    def own(obj):
        try:
            d = float(getattr(getattr(obj, "cycles", None), "ao_distance", 0.0))
        except (TypeError, ValueError, ReferenceError):
            return 0.0
        return d if math.isfinite(d) and d > 0.0 else 0.0
    obj = instance.object
    d = own(obj)
    if d == 0.0 and instance.is_instance:
        parent = instance.parent
        if parent is not None and parent != obj:
            d = own(parent)
    return d


def _holdout(instance, view_layer):
    """Object ▸ Visibility ▸ Holdout, or a holdout collection of the view layer. Only the
    depsgraph being exported may give the view layer: one kept from an earlier export may be
    freed (a reloaded file), and holdout_get on it crashed Blender."""
    obj = instance.object
    if view_layer is not None:
        try:
            parent = instance.parent if instance.is_instance and instance.parent is not None else obj
            return bool(parent.original.holdout_get(view_layer=view_layer))
        except (AttributeError, TypeError, RuntimeError, ReferenceError):
            pass
    return bool(getattr(obj, "is_holdout", False))


def _indirect_only(instance, view_layer):
    """Whether the instance's object (an instancer's, for its instances) is in an Indirect Only
    collection of the view layer (Cycles' indirect_only_get); as _holdout, only with the
    depsgraph being exported."""
    if view_layer is None:
        return False
    try:
        parent = instance.parent if instance.is_instance and instance.parent is not None else instance.object
        return bool(parent.original.indirect_only_get(view_layer=view_layer))
    except (AttributeError, TypeError, RuntimeError, ReferenceError):
        return False


def _export_object(obj, materials, uv_names=None):
    try:
        return mesh_data(obj, obj.to_mesh(), materials, uv_names)
    finally:
        obj.to_mesh_clear()


def mesh_data(obj, mesh, materials, uv_names=None):
    """The MeshData of obj's evaluated mesh `mesh` (obj.to_mesh(); the caller clears it), or
    None when it has no faces."""
    if mesh is None or len(mesh.polygons) == 0:
        return None
    if not materials:
        materials = list(mesh.materials)
    names = uv_names(materials) if uv_names else {}
    # Blender and Cycles clamp out-of-range material indices to the last slot. Triangle corner
    # indices only for UV maps (and corner normals): 12 bytes per triangle less otherwise.
    positions, triangles, normals, normal_indices, material_indices, loops = mesh_arrays(
        mesh, corners=bool(names), slots=len(materials))
    uvs, missing = mesh_uvs(mesh, names, loops) if names else ({}, [])
    attributes, missing_attributes = mesh_attributes(mesh, names, loops) if names else ({}, [])
    wanted = tangent_uv_maps(materials) if names else ()
    tangents, tangent_problem = ({}, None)
    if wanted:  # (MikkTSpace with the normals Pathlight shades with, as Cycles)
        per_vertex = mesh.normals_domain == 'POINT'
        tangents, tangent_problem = mesh_tangents(
            mesh, names, loops, wanted, normals if per_vertex else normals[normal_indices].reshape(-1, 3), per_vertex)
    # The evaluated mesh's texture space (automatic: its bounding box), as Cycles uses it;
    # non-finite vertices make it non-finite: then the core's own box of the finite ones.
    texspace = (tuple(mesh.texspace_location), tuple(mesh.texspace_size))
    if not np.isfinite(texspace).all():
        texspace = None
    return MeshData(obj.original.name, positions, triangles, normals, normal_indices, material_indices, materials,
                    uvs=uvs, missing_uv_maps=missing, texspace=texspace, attributes=attributes,
                    missing_attributes=missing_attributes, tangents=tangents, tangent_problem=tangent_problem,
                    flat=flat_triangles(mesh, materials, len(triangles)))


def flat_triangles(mesh, materials, n_tris):
    """bool (T,): the flat-shaded triangles of a mesh whose materials use true displacement
    (their normals become the displaced faces'), or None (all smooth, or nothing displaces)."""
    if not any(getattr(m, "displacement_method", 'BUMP') != 'BUMP' for m in materials if m is not None):
        return None
    domain = mesh.normals_domain
    if domain == 'POINT':
        return None
    if domain == 'FACE':
        return np.ones(n_tris, bool)
    sharp = _bool_attribute(mesh, "sharp_face", 'FACE', len(mesh.polygons))
    if sharp is None:
        return None
    tri_polys = np.empty(n_tris, np.int32)
    mesh.loop_triangle_polygons.foreach_get("value", tri_polys)
    return np.asarray(sharp, bool)[tri_polys]
