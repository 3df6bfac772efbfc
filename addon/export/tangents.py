"""Blender's MikkTSpace tangents of the UV maps that a mesh's materials read tangents of (a
tangent-space Normal Map, a Tangent node of direction UV Map), as Cycles uses them."""

import numpy as np


def _tangent_uv_maps(tree, found, seen):
    for node in tree.nodes:
        kind = node.bl_idname
        if kind == "ShaderNodeNormalMap" and node.space == "TANGENT":
            found.add(node.uv_map)
        elif kind == "ShaderNodeTangent" and node.direction_type == "UV_MAP":
            found.add(node.uv_map)
        elif kind == "ShaderNodeVectorDisplacement" and node.space == "TANGENT":
            found.add("")  # (the active render UV map's, as Cycles)
        elif getattr(node, "node_tree", None) is not None and node.node_tree.as_pointer() not in seen:
            seen.add(node.node_tree.as_pointer())  # node groups, each once
            _tangent_uv_maps(node.node_tree, found, seen)


def tangent_uv_maps(materials):
    """The UV map names ("" = the active render one) whose tangents the materials' node trees
    read, as a sorted tuple (hashable: part of the mesh cache's key)."""
    found = set()
    for mat in materials:
        if mat is not None and mat.use_nodes and mat.node_tree is not None:
            _tangent_uv_maps(mat.node_tree, found, set())
    return tuple(sorted(found))


def _corner_tangents(mesh):
    """float32 (corners, 4): the tangent and sign of every corner (after calc_tangents)."""
    n = len(mesh.loops)
    corner = np.empty((n, 4), np.float32)
    t = np.empty(n * 3, np.float32)
    mesh.loops.foreach_get("tangent", t)
    corner[:, :3] = t.reshape(-1, 3)
    s = np.empty(n, np.float32)
    mesh.loops.foreach_get("bitangent_sign", s)
    corner[:, 3] = s
    return corner


def _triangle_tangents(mesh, loops, layer, normals=None, vertex_normals=False):
    """float32 (T, 3, 4) tangents of the triangles `loops` (corner indices) computed on a
    temporary mesh of those triangles with the mesh's positions and uvs, as Cycles computes them
    on its triangles (MikkTSpace on the quads gives other tangents where a quad is not planar:
    up to 7.4e-4 in the mapped normal). normals: the shading normals Cycles hands MikkTSpace,
    float32 per vertex (vertex_normals) or (T * 3, 3) per triangle corner; None: Blender's
    corner normals."""
    import bpy  # (only here: the rest of the export module works on plain arrays)
    n_tris = len(loops) // 3
    tmp = bpy.data.meshes.new("pathlight tangents")
    try:
        co = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", co)
        corner_verts = np.empty(len(mesh.loops), np.int32)
        mesh.loops.foreach_get("vertex_index", corner_verts)
        tmp.vertices.add(len(mesh.vertices))
        tmp.vertices.foreach_set("co", co)
        tmp.loops.add(3 * n_tris)
        tmp.loops.foreach_set("vertex_index", corner_verts[loops])
        tmp.polygons.add(n_tris)
        tmp.polygons.foreach_set("loop_start", np.arange(0, 3 * n_tris, 3, dtype=np.int32))
        tmp.update(calc_edges=True)
        tmp.polygons.foreach_set("use_smooth", np.ones(n_tris, bool))  # custom normals everywhere
        uv = np.empty(len(mesh.loops) * 2, np.float32)
        layer.uv.foreach_get("vector", uv)
        tmp.uv_layers.new(name="UVMap").uv.foreach_set("vector", uv.reshape(-1, 2)[loops].ravel())
        if normals is not None and vertex_normals:
            tmp.normals_split_custom_set_from_vertices(np.asarray(normals, np.float32).reshape(-1, 3))
        else:
            if normals is None:
                corner = np.empty(len(mesh.loops) * 3, np.float32)
                mesh.corner_normals.foreach_get("vector", corner)
                normals = corner.reshape(-1, 3)[loops]
            tmp.normals_split_custom_set(np.asarray(normals, np.float32).reshape(-1, 3))
        tmp.calc_tangents(uvmap="UVMap")
        return np.ascontiguousarray(_corner_tangents(tmp).reshape(-1, 3, 4))
    finally:
        bpy.data.meshes.remove(tmp)


def mesh_tangents(mesh, names, loops, wanted, normals=None, vertex_normals=False):
    """({k: float32 (T, 3, 4)} per-corner tangent (xyz, object space) and bitangent sign (w),
    problem or None) for the uv sets {k: UV map name} whose names are in `wanted`.
    loops: the triangles' corner indices (mesh_arrays); normals, vertex_normals: the shading
    normals (_triangle_tangents). MikkTSpace runs on the triangles, as Cycles runs it (on quads
    Blender's calc_tangents differs where they are not planar); should it fail, the core's
    per-triangle tangents are used and the problem says so."""
    tangents, cache = {}, {}
    # Names, not layers: calc_tangents adds a corner layer, which leaves earlier uv layer
    # references dangling.
    active = next((layer.name for layer in mesh.uv_layers if layer.active_render), None)
    for k, name in names.items():
        if isinstance(name, tuple) or name not in wanted:  # attribute sets, or no tangents read
            continue
        uv_name = name or active
        if uv_name is None or mesh.uv_layers.get(uv_name) is None:  # (mesh_uvs reports it)
            continue
        if uv_name not in cache:
            try:
                cache[uv_name] = _triangle_tangents(mesh, loops, mesh.uv_layers[uv_name], normals, vertex_normals)
            except (RuntimeError, ValueError, TypeError) as e:
                return {}, f"no MikkTSpace tangents ({e}); per-triangle tangents are used"
        tangents[k] = cache[uv_name]
    return tangents, None
