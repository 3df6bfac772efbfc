"""The export's fast path (issue 6): the core triangulates triangles and quads from the mesh's
raw arrays and computes smooth vertex normals, instead of reading Blender's loop triangles and
normals element by element. Both must give what Blender gives: the same triangles with the same
corner order (quad splits included, also of concave and non-planar quads), n-gons' triangles
from Blender, and vertex normals within 1e-6."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, empty_scene_with_camera, load_addon

load_addon()
from addon.export import mesh as mesh_export  # noqa: E402
from test_export_arrays import blender_loops, new_mesh  # noqa: E402

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


@pytest.fixture
def pc():
    empty_scene_with_camera(16)
    from addon.core import get_core
    return get_core()


def blender_arrays(me):
    """Blender's loop-triangle corners, vertex normals, positions, corner verts, face offsets."""
    loops = blender_loops(me)
    vn = np.empty(len(me.vertices) * 3, np.float32)
    me.vertex_normals.foreach_get("vector", vn)
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    cv = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", cv)
    start = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_start", start)
    offsets = np.append(start, len(me.loops)).astype(np.int32)
    return loops.reshape(-1, 3), vn.reshape(-1, 3), co.reshape(-1, 3), cv, offsets


def random_quads(n=3000, seed=2, spread=1.0):
    """Unconnected quads with random corners: planar convex, concave, non-planar and bow-tie
    ones, so both of Blender's quad splits occur many times."""
    rng = np.random.default_rng(seed)
    co = rng.normal(size=(n * 4, 3)) * spread
    co[: n * 2, 2] *= 1e-3  # half of them nearly planar
    return co, np.arange(n * 4).reshape(n, 4)


def grid(n=30, seed=5):
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    z = 0.3 * np.sin(3 * x) * np.cos(2 * y) + 0.05 * rng.standard_normal(x.shape)
    co = np.stack([x, y, z], -1).reshape(-1, 3)
    i = np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]
    return co, np.stack([i, i + 1, i + n + 2, i + n + 1], -1).reshape(-1, 4)


def mixed(seed=3):
    """A grid of quads with triangles (split quads), n-gons (merged quads) and loose vertices."""
    co, quads = grid(16, seed)
    faces = [tuple(q) for q in quads]
    out = []
    for k, f in enumerate(faces):
        if f is None:
            continue
        if k % 7 == 0:
            out += [(f[0], f[1], f[2]), (f[0], f[2], f[3])]
        elif k % 11 == 0 and k + 1 < len(faces) and faces[k + 1][0] == f[1]:
            g = faces[k + 1]
            out.append((f[0], f[1], g[1], g[2], f[2], f[3]))  # a hexagon over two quads
            faces[k + 1] = None
        else:
            out.append(f)
    co = np.concatenate([co, [[5.0, 5.0, 5.0], [0.0, 0.0, 0.0]]])  # loose
    return co, out


@pytest.mark.parametrize("case", ["random_quads", "grid", "mixed", "triangles"])
def test_core_triangulation_is_blenders(pc, case):
    if case == "random_quads":
        co, faces = random_quads()
    elif case == "grid":
        co, faces = grid()
    elif case == "mixed":
        co, faces = mixed()
    else:
        co, quads = grid(12)
        faces = [t for q in quads for t in ((q[0], q[1], q[2]), (q[2], q[3], q[0]))]
    me = new_mesh(co, faces)
    loops, _, pos, cv, offsets = blender_arrays(me)
    corners, verts, ngons = pc.triangulate_polygons(pos, cv, offsets)
    sizes = np.diff(offsets)
    assert ngons == int((sizes > 4).sum())
    tri_sizes = np.repeat(sizes, sizes - 2)
    keep = tri_sizes <= 4
    np.testing.assert_array_equal(corners[keep], loops[keep])
    np.testing.assert_array_equal(verts, cv[corners])
    if case == "random_quads":  # both splits occur
        flipped = (corners[0::2, 2] - corners[0::2, 0]) == 3
        assert 100 < flipped.sum() < len(flipped) - 100
    if case == "mixed":
        assert ngons > 0 and (sizes == 3).any() and (sizes == 4).any()


def test_export_of_mixed_mesh_matches_blender(pc):
    """mesh_arrays: a mesh with n-gons gives exactly Blender's loop triangles (read from
    Blender), a mesh of triangles and quads the core's, also exactly Blender's."""
    for faces in (mixed(), grid()):
        me = new_mesh(*faces)
        loops, _, _, cv, _ = blender_arrays(me)
        _, triangles, _, _, _, corners = mesh_export.mesh_arrays(me)
        np.testing.assert_array_equal(corners.reshape(-1, 3), loops)
        np.testing.assert_array_equal(triangles, cv[loops])


@pytest.mark.parametrize("case", ["grid", "mixed", "random_quads", "sphere"])
def test_core_vertex_normals_are_blenders(pc, case):
    if case == "grid":
        co, faces = grid()
    elif case == "mixed":
        co, faces = mixed()
    elif case == "random_quads":
        co, faces = random_quads(500)
    else:
        bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24)
        me = bpy.context.object.data
        co = np.array([v.co for v in me.vertices])
        faces = [tuple(p.vertices) for p in me.polygons]
    me = new_mesh(co, faces)
    _, vn, pos, cv, offsets = blender_arrays(me)
    normals = pc.polygon_vertex_normals(pos, cv, offsets)
    assert normals.dtype == np.float32 and normals.shape == vn.shape
    np.testing.assert_allclose(normals, vn, atol=1e-6, rtol=0)
    assert np.abs(vn).max() > 0.5  # a real comparison: not all zeros


def test_polygon_input_is_validated(pc):
    co = np.zeros((4, 3), np.float32)
    cv = np.array([0, 1, 2, 3], np.int32)
    for offsets, cv_, msg in (([0, 2, 4], cv, "fewer than 3"), ([1, 4], cv, "start at 0"),
                              ([0, 3], cv, "not at the 4 corners"), ([0, 4], cv + 1, "out of range"),
                              ([0, 4], -cv, "out of range")):
        for fn in (pc.triangulate_polygons, pc.polygon_vertex_normals):
            with pytest.raises(ValueError, match=msg):
                fn(co, cv_, np.array(offsets, np.int32))


def test_smooth_mesh_export_uses_the_core_normals(pc, monkeypatch):
    """A smooth (point-domain) mesh's exported normals are the core's, and equal Blender's;
    without the core the export falls back to Blender's collections, with the same arrays."""
    co, faces = mixed()
    me = new_mesh(co, faces)
    me.shade_smooth()
    assert me.normals_domain == 'POINT'
    used = []

    class Recording:  # the core, recording which of its polygon functions the export calls
        def __getattr__(self, name):
            used.append(name)
            return getattr(pc, name)
    monkeypatch.setattr(mesh_export, "_polygon_core", lambda: Recording())
    fast = mesh_export.mesh_arrays(me)
    assert {"triangulate_polygons", "polygon_vertex_normals"} <= set(used)
    monkeypatch.setattr(mesh_export, "_polygon_core", lambda: None)
    slow = mesh_export.mesh_arrays(me)
    for a, b in zip(fast[:2] + fast[3:], slow[:2] + slow[3:]):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(fast[2], slow[2], atol=1e-6, rtol=0)


def _distance_reference(meshes, camera_matrix):
    """The former float64, filter-first distance_from_origin."""
    far = float(np.linalg.norm(np.asarray(camera_matrix, np.float64)[:3, 3]))
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for mesh in meshes:
        p = np.asarray(mesh.positions, np.float64)
        p = p[np.isfinite(p).all(axis=1)]
        if not len(p) or not mesh.matrices:
            continue
        a, b = p.min(axis=0), p.max(axis=0)
        corners = np.array([[(a, b)[i >> k & 1][k] for k in range(3)] for i in range(8)])
        m = np.asarray(mesh.matrices, np.float64)
        world = (corners @ m[:, :3, :3].transpose(0, 2, 1) + m[:, None, :3, 3]).reshape(-1, 3)
        world = world[np.isfinite(world).all(axis=1)]
        if len(world):
            lo, hi = np.minimum(lo, world.min(axis=0)), np.maximum(hi, world.max(axis=0))
    if np.all(lo <= hi):
        far = max(far, float(np.linalg.norm((lo + hi) / 2)))
    return far


@pytest.mark.parametrize("bad", [None, np.nan, np.inf, -np.inf, "all"])
def test_distance_from_origin_fast_path(bad):
    """The column-wise float32 bounds give the former result, with non-finite vertices too."""
    from types import SimpleNamespace
    from addon.export import distance_from_origin
    rng = np.random.default_rng(1)
    p = (rng.normal(size=(1000, 3)) * 50 + [4e4, -2e4, 10]).astype(np.float32)
    if bad == "all":
        p[:] = np.nan
    elif bad is not None:
        p[::7, 1] = bad
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = (5, 6, 7)
    meshes = [SimpleNamespace(positions=p, matrices=[m, np.eye(4, dtype=np.float32)]),
              SimpleNamespace(positions=np.zeros((0, 3), np.float32), matrices=[m])]
    cam = np.eye(4)
    got, want = distance_from_origin(meshes, cam), _distance_reference(meshes, cam)
    assert got == pytest.approx(want, rel=1e-12)
    assert (got > 1e4) == (bad != "all")


def corner_inputs(me):
    """(corner_edges, edge count, sharp_edges or None, sharp_faces or None) of a bpy Mesh."""
    ce = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("edge_index", ce)
    out = [ce, len(me.edges)]
    for name, n in (("sharp_edge", len(me.edges)), ("sharp_face", len(me.polygons))):
        attr = me.attributes.get(name)
        if attr is None:
            out.append(None)
            continue
        a = np.empty(n, bool)
        attr.data.foreach_get("value", a)
        out.append(a)
    return out


def corner_case(case, rng):
    if case == "sharp_edges":
        co, faces = mixed()
        me = new_mesh(co, faces)
        me.shade_smooth()
        sharp = me.attributes.new("sharp_edge", 'BOOLEAN', 'EDGE')
        sharp.data.foreach_set("value", rng.uniform(size=len(me.edges)) < 0.3)
    elif case == "sharp_faces":
        co, faces = mixed()
        me = new_mesh(co, faces)
        me.shade_smooth()
        me.polygons.foreach_set("use_smooth", rng.uniform(size=len(me.polygons)) < 0.6)
    elif case == "by_angle":  # what Smooth by Angle (auto smooth) leaves: sharp edges over 30 degrees
        bpy.ops.mesh.primitive_cylinder_add(vertices=40)
        src = bpy.context.object.data
        me = new_mesh([v.co[:] for v in src.vertices], [tuple(p.vertices) for p in src.polygons])
        me.shade_smooth()
        me.set_sharp_from_angle(angle=np.radians(30))
    elif case == "non_manifold":  # an edge of three faces, a face wound the other way, a boundary
        co, faces = grid(6)
        faces = [tuple(f) for f in faces]
        faces[7] = faces[7][::-1]
        co = np.concatenate([co, [[0.0, 0.0, 1.0]]])
        a, b = faces[14][0], faces[14][1]
        faces.append((a, b, len(co) - 1))
        me = new_mesh(co, faces)
        me.shade_smooth()
        me.polygons[3].use_smooth = False
    me.update()
    return me


@pytest.mark.parametrize("case", ["sharp_edges", "sharp_faces", "by_angle", "non_manifold"])
def test_core_corner_normals_are_blenders(pc, case):
    me = corner_case(case, np.random.default_rng(11))
    assert me.normals_domain == 'CORNER' and not me.has_custom_normals
    _, _, pos, cv, offsets = blender_arrays(me)
    cn = np.empty(len(me.loops) * 3, np.float32)
    me.corner_normals.foreach_get("vector", cn)
    ce, n_edges, sharp_edges, sharp_faces = corner_inputs(me)
    got = pc.polygon_corner_normals(pos, cv, offsets, ce, n_edges, sharp_edges, sharp_faces)
    np.testing.assert_allclose(got, cn.reshape(-1, 3), atol=1e-6, rtol=0)
    # Not the vertex normals: sharp corners differ.
    vn = np.empty(len(me.vertices) * 3, np.float32)
    me.vertex_normals.foreach_get("vector", vn)
    assert np.abs(got - vn.reshape(-1, 3)[cv]).max() > 0.1


@pytest.mark.parametrize("case", ["sharp_edges", "sharp_faces", "by_angle", "custom"])
def test_corner_domain_export_uses_the_core_unless_custom_normals(pc, monkeypatch, case):
    """Corner-domain meshes export the core's corner normals (Blender's within 1e-6, same
    arrays otherwise); custom normals are read from Blender."""
    me = corner_case("sharp_edges" if case == "custom" else case, np.random.default_rng(3))
    if case == "custom":
        rng = np.random.default_rng(4)
        normals = rng.normal(size=(len(me.loops), 3)) * 0.3 + [0, 0, 1]
        me.normals_split_custom_set((normals / np.linalg.norm(normals, axis=1, keepdims=True)).tolist())
    assert me.normals_domain == 'CORNER'
    used = []

    class Recording:
        def __getattr__(self, name):
            used.append(name)
            return getattr(pc, name)
    monkeypatch.setattr(mesh_export, "_polygon_core", lambda: Recording())
    fast = mesh_export.mesh_arrays(me)
    assert ("polygon_corner_normals" in used) == (case != "custom")
    monkeypatch.setattr(mesh_export, "_polygon_core", lambda: None)
    slow = mesh_export.mesh_arrays(me)
    for a, b in zip(fast[:2] + fast[3:], slow[:2] + slow[3:]):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(fast[2], slow[2], atol=1e-6, rtol=0)


def test_face_offsets_refuse_faces_without_triangles():
    """A face of under 3 corners has no loop triangle: no offsets (the export then reads
    Blender's collections instead of raising in the core)."""
    np.testing.assert_array_equal(mesh_export.face_offsets(np.array([0, 0, 1], np.int32), 2, 7), [0, 4, 7])
    assert mesh_export.face_offsets(np.array([0, 0, 2], np.int32), 3, 9) is None  # face 1: no triangle
    assert mesh_export.face_offsets(np.array([0, 0, 1], np.int32), 2, 8) is None  # corners do not add up
    # The core's one-pass version (the export's) agrees, refusals included.
    from addon.core import get_core
    pc = get_core()
    for args in (([0, 0, 1], 2, 7), ([0, 0, 2], 3, 9), ([0, 0, 1], 2, 8), ([0, 1, 1, 1, 2], 3, 11)):
        a = mesh_export.face_offsets(np.array(args[0], np.int32), *args[1:])
        b = mesh_export.face_offsets(np.array(args[0], np.int32), *args[1:], pc)
        assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))


@pytest.mark.parametrize("case", ["smooth", "flat", "sharp_edges", "ngons"])
def test_corner_indices_only_when_needed(pc, case):
    """mesh_arrays(corners=False) skips the triangles' corner indices where the normals do not
    need them (smooth and flat meshes of triangles and quads; n-gon meshes read them from
    Blender anyway) and gives the same arrays otherwise; slots= clamps material indices per
    face as the per-triangle clamp did."""
    if case == "sharp_edges":
        me = corner_case("sharp_edges", np.random.default_rng(5))
    else:
        co, faces = mixed() if case == "ngons" else grid(20)
        me = new_mesh(co, faces)
        if case != "flat":
            me.shade_smooth()
    mi = me.attributes.new("material_index", 'INT', 'FACE')
    mi.data.foreach_set("value", np.arange(len(me.polygons), dtype=np.int32) % 5 - 1)
    full = mesh_export.mesh_arrays(me)
    lean = mesh_export.mesh_arrays(me, corners=False, slots=3)
    needs = case in ("sharp_edges", "ngons")
    assert (lean[5] is None) != needs
    for k in range(4):
        np.testing.assert_array_equal(lean[k], full[k])
    if needs:
        np.testing.assert_array_equal(lean[5], full[5])
    assert full[4].min() == -1 and full[4].max() == 3  # unclamped without slots
    np.testing.assert_array_equal(lean[4], np.clip(full[4], 0, 2))
