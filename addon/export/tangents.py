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


def mesh_tangents(mesh, names, loops, wanted):
    """({k: float32 (T, 3, 4)} per-corner tangent (xyz, object space) and bitangent sign (w),
    problem or None) for the uv sets {k: UV map name} whose names are in `wanted`.
    loops: the triangles' corner indices (mesh_arrays). Blender computes tangents of triangles
    and quads only: a mesh with larger faces keeps the core's per-triangle tangents."""
    tangents, cache = {}, {}
    active = next((layer for layer in mesh.uv_layers if layer.active_render), None)
    for k, name in names.items():
        if isinstance(name, tuple) or name not in wanted:  # attribute sets, or no tangents read
            continue
        layer = mesh.uv_layers.get(name) if name else active
        if layer is None:  # (mesh_uvs reports it)
            continue
        if layer.name not in cache:
            try:
                mesh.calc_tangents(uvmap=layer.name)
            except RuntimeError as e:  # n-gons
                return {}, f"no MikkTSpace tangents ({e}); per-triangle tangents are used"
            n = len(mesh.loops)
            corner = np.empty((n, 4), np.float32)
            t = np.empty(n * 3, np.float32)
            mesh.loops.foreach_get("tangent", t)
            corner[:, :3] = t.reshape(-1, 3)
            s = np.empty(n, np.float32)
            mesh.loops.foreach_get("bitangent_sign", s)
            corner[:, 3] = s
            cache[layer.name] = np.ascontiguousarray(corner[loops].reshape(-1, 3, 4))
        tangents[k] = cache[layer.name]
    if cache:
        mesh.free_tangents()
    return tangents, None
