"""Adaptive subdivision (Cycles' Experimental feature set): an object whose Cycles settings say
use_adaptive_subdivision and whose last modifier is a Subdivision Surface is exported as the
cage before that modifier, and the core dices its limit surface for the dicing camera
(`pc.subdivide_mesh`, docs/design/displacement.md#adaptive-subdivision).

Blender facts (4.5, found by experiment and in MOD_subsurf.cc): when the Subdivision Surface is
the last enabled modifier, the depsgraph leaves the evaluated mesh as a "subdivision wrapper":
the cage (earlier modifiers and shape keys applied) plus the settings to subdivide it lazily.
RNA's `Object.data` and `to_mesh()` subdivide it at the Render levels on access (for any
engine); `bpy.types.GeometrySet.from_evaluated_object(obj).mesh_base` hands out the cage itself,
as a copy owned by the GeometrySet (which must outlive every read of it), without touching the
user's data or the evaluated object. Without GeometrySet (older Blender) the cage is the
original mesh, right only without other modifiers and shape keys; otherwise the object is
rendered as the depsgraph subdivides it, with a warning."""

import bpy
import numpy as np

from .tangents import tangent_uv_maps
from .mesh import (MeshData, _bool_attribute, _export_object, _int_attribute, mesh_attributes,
                   mesh_positions, mesh_uvs)

# Blender's edge and vertex crease (0..1) -> OpenSubdiv sharpness, as Cycles hands them over.
CREASE_SCALE = 10.0


def adaptive_modifier(obj, depsgraph):
    """The Subdivision Surface modifier that Cycles would replace by adaptive dicing, or None."""
    cycles = getattr(depsgraph.scene, "cycles", None)
    if cycles is None or getattr(cycles, "feature_set", None) != 'EXPERIMENTAL':
        return None
    original = obj.original
    settings = getattr(original, "cycles", None)
    if settings is None or not getattr(settings, "use_adaptive_subdivision", False):
        return None
    if original.type != 'MESH' or not len(original.modifiers):
        return None
    mod = original.modifiers[-1]
    enabled = mod.show_viewport if depsgraph.mode == 'VIEWPORT' else mod.show_render
    return mod if mod.type == 'SUBSURF' and enabled else None


def dicing_context(depsgraph):
    """What the edge factors are measured with: the dicing camera (or the scene camera) as
    keywords of pc.subdivide_mesh, plus the scene's dicing rate."""
    scene = depsgraph.scene
    cycles = scene.cycles
    rate = cycles.preview_dicing_rate if depsgraph.mode == 'VIEWPORT' else cycles.dicing_rate
    out = {"rate": float(rate), "max_level": int(cycles.max_subdivisions)}
    cam_obj = cycles.dicing_camera or scene.camera
    if cam_obj is None or cam_obj.type != 'CAMERA':  # Cycles without a camera: lengths in units
        out.update(camera_position=(0.0, 0.0, 0.0), pixel_size=1.0, ortho=True)
        return out
    cam = cam_obj.evaluated_get(depsgraph)
    render = scene.render
    scale = render.resolution_percentage / 100.0
    xr = max(render.resolution_x * scale, 1.0)
    yr = max(render.resolution_y * scale, 1.0)
    frame = np.array([tuple(v) for v in cam.data.view_frame(scene=scene)], np.float64)
    width = frame[:, 0].max() - frame[:, 0].min()
    height = frame[:, 1].max() - frame[:, 1].min()
    size = min(width / xr, height / yr)  # Cycles: the shorter of the pixel's two steps
    ortho = cam.data.type == 'ORTHO'
    depth = 1.0 if ortho else max(abs(float(frame[0, 2])), 1e-9)
    size /= depth  # perspective: the frame lies at depth -z; a pixel's size per unit distance
    out.update(camera_position=tuple(cam.matrix_world.translation), pixel_size=float(max(size, 1e-9)),
               ortho=ortho)
    scale = float(getattr(cycles, "offscreen_dicing_scale", 1.0))
    # Cycles: the view's side planes (at unit depth) and the camera's axes, unscaled; panoramic
    # cameras have no off-screen scale there.
    if scale > 1.0 and cam.data.type in ('PERSP', 'ORTHO'):
        rot = np.array(cam.matrix_world.to_3x3().normalized(), np.float64)
        out.update(offscreen_scale=scale,
                   camera_axes=(tuple(rot[:, 0]), tuple(rot[:, 1]), tuple(-rot[:, 2])),
                   frame=(float(frame[:, 0].min() / depth), float(frame[:, 0].max() / depth),
                          float(frame[:, 1].min() / depth), float(frame[:, 1].max() / depth)))
    return out


def _core_has_offscreen(pc):
    return hasattr(pc, "dicing_pixel_size")  # (the same build added offscreen_scale)


def _corner_interpolate(values, offsets, tri_face, tri_sub, tri_uv):
    """Per-corner values (C, d) of the cage -> (T, 3, d) at the diced corners: bilinear over the
    patch's corners (an n-gon's sub-patch k: corner k, the next edge's middle, the face's
    centre, the previous edge's middle), as the patch coordinates of each corner say."""
    sizes = np.diff(offsets)
    start = offsets[:-1][tri_face]
    n = sizes[tri_face]
    k = tri_sub
    centre = np.add.reduceat(values, offsets[:-1], axis=0) / sizes[:, None]
    a = values[start + k]
    nxt = values[start + (k + 1) % n]
    prv = values[start + (k + n - 1) % n]
    quad = (n == 4)[:, None]
    b = np.where(quad, nxt, 0.5 * (a + nxt))
    c = np.where(quad, values[start + (k + 2) % n], centre[tri_face])
    d = np.where(quad, prv, 0.5 * (a + prv))
    u = tri_uv[..., 0:1]
    v = tri_uv[..., 1:2]
    a, b, c, d = (x[:, None, :] for x in (a, b, c, d))
    return np.ascontiguousarray(((1 - u) * (1 - v) * a + u * (1 - v) * b + u * v * c + (1 - u) * v * d)
                                .astype(np.float32))


def cage_mesh(obj, depsgraph):
    """(cage, owner, problem): the mesh before obj's last Subdivision Surface modifier with the
    other modifiers and shape keys applied, and what keeps it alive (hold it while reading);
    or (None, None, why not)."""
    original = obj.original
    geometry_set = getattr(bpy.types, "GeometrySet", None)
    if depsgraph is not None and geometry_set is not None and hasattr(geometry_set, "mesh_base"):
        try:
            evaluated = original.evaluated_get(depsgraph)
            owner = geometry_set.from_evaluated_object(evaluated)
            mesh = owner.mesh_base
        except (TypeError, RuntimeError, ReferenceError) as exc:  # not evaluated, not a mesh...
            return None, None, f"its evaluated cage could not be read ({exc})"
        if mesh is None:
            return None, None, "no evaluated mesh"
        # The wrapper holds the cage; a subdivided mesh here would mean Blender subdivided
        # anyway (checkable where nothing else changes the topology).
        others = [m for m in original.modifiers[:-1] if _enabled(m, depsgraph)]
        if not others and len(mesh.polygons) != len(original.data.polygons) and not original.data.is_editmode:
            return None, None, "an evaluated cage that was already subdivided"
        return mesh, owner, None
    others = [m.name for m in original.modifiers[:-1] if _enabled(m, depsgraph)]
    if others:
        return None, None, f"modifiers before its Subdivision Surface ({', '.join(others)}) in this Blender"
    if original.data.shape_keys is not None:
        return None, None, "shape keys in this Blender"
    return original.data, None, None


def _enabled(mod, depsgraph):
    viewport = depsgraph is not None and depsgraph.mode == 'VIEWPORT'
    return mod.show_viewport if viewport else mod.show_render


def adaptive_mesh_data(obj, mod, materials, uv_names, dicing, depsgraph=None):
    """The MeshData of obj diced by the core (or, where the cage cannot be read, the
    depsgraph's mesh with `subdivision_problem` set), or None without faces."""
    from ..core import get_core
    pc = get_core()
    original = obj.original
    mesh, owner, problem = cage_mesh(obj, depsgraph)
    if problem is None and not hasattr(pc, "subdivide_mesh"):
        problem = "a core without subdivide_mesh"
    if problem is not None:
        data = _export_object(obj, materials, uv_names)
        if data is not None:
            data.subdivision_problem = (f"adaptive subdivision is not done with {problem}; rendered "
                                        "with the Subdivision Surface modifier's Render levels")
        return data
    data = _diced_mesh_data(pc, original, mesh, mod, materials, uv_names, dicing, obj)
    del mesh, owner  # (the cage is freed with its GeometrySet: nothing reads it after this)
    return data


def _diced_mesh_data(pc, original, mesh, mod, materials, uv_names, dicing, obj):
    if len(mesh.polygons) == 0:
        return None
    if not materials:
        materials = list(mesh.materials)
    n_corners, n_faces, n_edges = len(mesh.loops), len(mesh.polygons), len(mesh.edges)
    positions = mesh_positions(mesh)
    corner_verts = _int_attribute(mesh, ".corner_vert", n_corners)
    if corner_verts is None:
        corner_verts = np.empty(n_corners, np.int32)
        mesh.loops.foreach_get("vertex_index", corner_verts)
    starts = np.empty(n_faces, np.int32)
    mesh.polygons.foreach_get("loop_start", starts)
    offsets = np.append(starts, np.int32(n_corners)).astype(np.int32)
    crease = {}
    if mod.use_creases:
        edge_crease = mesh.attributes.get("crease_edge")
        if edge_crease is not None and edge_crease.domain == 'EDGE' and edge_crease.data_type == 'FLOAT':
            values = np.empty(n_edges, np.float32)
            edge_crease.data.foreach_get("value", values)
            edges = np.empty(n_edges * 2, np.int32)
            mesh.edges.foreach_get("vertices", edges)
            keep = values > 0
            if keep.any():
                crease["crease_edges"] = edges.reshape(-1, 2)[keep]
                crease["crease_sharpness"] = values[keep] * CREASE_SCALE
        vert_crease = mesh.attributes.get("crease_vert")
        if vert_crease is not None and vert_crease.domain == 'POINT' and vert_crease.data_type == 'FLOAT':
            values = np.empty(len(mesh.vertices), np.float32)
            vert_crease.data.foreach_get("value", values)
            if (values > 0).any():
                crease["vertex_sharpness"] = values * CREASE_SCALE
    rate = max(0.1, float(getattr(original.cycles, "dicing_rate", 1.0)) * dicing["rate"])
    offscreen = {k: dicing[k] for k in ("offscreen_scale", "camera_axes", "frame") if k in dicing}
    if offscreen and not _core_has_offscreen(pc):
        offscreen = {}
    matrix = np.array(obj.matrix_world, np.float32)
    diced = pc.subdivide_mesh(positions, corner_verts, offsets, matrix, dicing["camera_position"],
                              dicing["pixel_size"], ortho=dicing["ortho"], dicing_rate=rate,
                              max_level=dicing["max_level"],
                              catmull_clark=mod.subdivision_type == 'CATMULL_CLARK',
                              **offscreen, **crease)  # (corners smooth whatever boundary_smooth says: Cycles' too)
    tris = diced["triangles"]
    tri_face = diced["triangle_faces"]
    tri_sub = diced["triangle_subpatches"]
    tri_uv = diced["triangle_uvs"]
    n_tris = len(tris)
    poly_materials = _int_attribute(mesh, "material_index", n_faces)
    if poly_materials is None:
        material_indices = np.zeros(n_tris, np.int32)
    else:
        material_indices = np.clip(poly_materials, 0, max(len(materials) - 1, 0))[tri_face].astype(np.int32)
    # Smooth faces: the diced mesh's vertex normals; flat ones (sharp_face): their triangles'.
    pts = diced["positions"]
    tri_offsets = np.arange(0, 3 * n_tris + 1, 3, dtype=np.int32)
    vertex_normals = pc.polygon_vertex_normals(pts, tris.reshape(-1), tri_offsets)
    normals, normal_indices = vertex_normals, tris
    sharp = _bool_attribute(mesh, "sharp_face", 'FACE', n_faces)
    flat = None
    if sharp is not None and sharp.any():
        flat = sharp[tri_face]
        p = pts[tris]
        face_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-30)
        normals = np.concatenate([vertex_normals, face_n.astype(np.float32)])
        normal_indices = np.where(flat[:, None], (len(vertex_normals) + np.arange(n_tris))[:, None], tris)
    if not any(getattr(m, "displacement_method", 'BUMP') != 'BUMP' for m in materials if m is not None):
        flat = None
    names = uv_names(materials) if uv_names else {}
    uvs, attributes, missing, missing_attributes = {}, {}, [], []
    if names:
        loops = np.repeat(np.arange(n_corners, dtype=np.int32), 3)  # one "triangle" per corner
        base_uvs, missing = mesh_uvs(mesh, names, loops)
        uvs = {k: _corner_interpolate(x[:, 0], offsets, tri_face, tri_sub, tri_uv) for k, x in base_uvs.items()}
        base_attrs, missing_attributes = mesh_attributes(mesh, names, loops)
        attributes = {k: _corner_interpolate(x[:, 0], offsets, tri_face, tri_sub, tri_uv)
                      for k, x in base_attrs.items()}
    texspace = (tuple(mesh.texspace_location), tuple(mesh.texspace_size))
    if not np.isfinite(texspace).all():
        texspace = None
    data = MeshData(original.name, pts, np.ascontiguousarray(tris, np.int32), normals,
                    np.ascontiguousarray(normal_indices, np.int32), material_indices, materials,
                    uvs=uvs, missing_uv_maps=missing, texspace=texspace, attributes=attributes,
                    missing_attributes=missing_attributes, flat=flat)
    if names and tangent_uv_maps(materials):
        data.tangent_problem = ("tangents of adaptively subdivided meshes are not exported; "
                                "the triangles' UV tangents are used")
    data.subdivision = {"level": int(diced["level"]), "max_edge_factor": int(diced["max_edge_factor"]),
                        "capped": bool(diced["capped"])}
    if diced["capped"]:
        data.subdivision_problem = ("adaptive subdivision was capped at "
                                    f"{diced['level']} levels to bound memory")
    return data
