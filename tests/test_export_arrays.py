"""The mesh export reads Blender's own arrays and works out the split of quads itself
(addon/export/mesh.py: triangle_corners), and hands normals to the core as Blender stores them
(per vertex, face or corner, with an index per triangle corner). It must give exactly what
Blender's per-element collections give: loop_triangles, corner normals, UVs, material indices;
and the core must render the compact normals exactly as the expanded ones."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, empty_scene_with_camera, load_addon

load_addon()
from addon.export import mesh as mesh_export  # noqa: E402
from addon.export.mesh import collect_meshes  # noqa: E402

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


@pytest.fixture
def scene():
    return empty_scene_with_camera(32)


def new_mesh(co, faces, name="M"):
    me = bpy.data.meshes.new(name)
    me.from_pydata(np.asarray(co, np.float64).tolist(), [], [tuple(int(i) for i in f) for f in faces])
    me.update()
    return me


def blender_loops(me):
    """Blender's own triangulation: corner indices of every loop triangle."""
    me.calc_loop_triangles()
    loops = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("loops", loops)
    return loops


def our_loops(me):
    me.calc_loop_triangles()
    pos = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", pos)
    tri_polys = np.empty(len(me.loop_triangles), np.int32)
    me.loop_triangle_polygons.foreach_get("value", tri_polys)
    corner_verts = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", corner_verts)
    return mesh_export.triangle_corners(me, pos.reshape(-1, 3), corner_verts, tri_polys)


def quads(kind, n=3000, seed=3):
    """n separate quads of one kind: corner positions (n * 4, 3)."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(-1, 1, (n, 1, 3))
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    if kind == "convex":
        q = base + square * rng.uniform(0.1, 2, (n, 1, 1))
    elif kind == "concave_and_bowtie":  # random planar quads: many concave or self-crossing
        q = base + rng.uniform(-1, 1, (n, 4, 3)) * [1, 1, 0]
    elif kind == "nonplanar":
        q = base + square + rng.uniform(-0.8, 0.8, (n, 4, 3))
    elif kind == "degenerate":  # all four corners at one point, or on one line
        q = np.repeat(base, 4, axis=1)
        q[::2, 2] += 0.5
    elif kind == "far_from_origin":  # tiny quads where float rounding is large
        q = 1000.0 + base * 1e-3 + rng.uniform(-1e-3, 1e-3, (n, 4, 3))
    else:
        raise ValueError(kind)
    return q.reshape(-1, 3)


@pytest.mark.parametrize("cached_normals", [False, True])
@pytest.mark.parametrize("kind", ["convex", "concave_and_bowtie", "nonplanar", "degenerate", "far_from_origin"])
def test_quad_split_matches_blender(scene, kind, cached_normals):
    co = quads(kind)
    me = new_mesh(co, np.arange(len(co)).reshape(-1, 4))
    if cached_normals:  # Blender then splits with its other quad-flip test (the one with the normal)
        fn = np.empty(len(me.polygons) * 3, np.float32)
        me.polygon_normals.foreach_get("vector", fn)
    ref = blender_loops(me)
    if kind in ("concave_and_bowtie", "nonplanar"):
        first = ref.reshape(-1, 2, 3)[:, 0]
        assert (first[:, 2] % 4 == 3).sum() > 50  # many quads are cut along 1-3: the test sees both cuts
    np.testing.assert_array_equal(our_loops(me), ref)


def test_mixed_faces_and_ngons_match_blender(scene):
    rng = np.random.default_rng(1)
    # Triangles and quads interleaved, then a mesh with an n-gon (read from Blender whole).
    co = rng.uniform(-1, 1, (700, 3))
    faces = []
    i = 0
    while i + 4 <= len(co):
        size = 3 if rng.uniform() < 0.4 else 4
        faces.append(range(i, i + size))
        i += size
    me = new_mesh(co, faces)
    np.testing.assert_array_equal(our_loops(me), blender_loops(me))
    ngon = new_mesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0.5, 1.5, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]],
                    [(0, 1, 2, 3, 4), (1, 5, 6, 2)], "Ngon")
    np.testing.assert_array_equal(our_loops(ngon), blender_loops(ngon))


def reference(me, uv=False):
    """What the export used to build from Blender's per-element collections: (triangles,
    corner normals, material indices, uvs) per loop triangle."""
    loops = blender_loops(me)
    corner_verts = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", corner_verts)
    cn = np.empty(len(me.loops) * 3, np.float32)
    me.corner_normals.foreach_get("vector", cn)
    mat = np.empty(len(me.loop_triangles), np.int32)
    me.loop_triangles.foreach_get("material_index", mat)
    uvs = None
    if uv:
        corner_uv = np.empty(len(me.loops) * 2, np.float32)
        me.uv_layers.active.uv.foreach_get("vector", corner_uv)
        uvs = corner_uv.reshape(-1, 2)[loops].reshape(-1, 3, 2)
    return corner_verts[loops].reshape(-1, 3), cn.reshape(-1, 3)[loops].reshape(-1, 3, 3), mat, uvs


def grid_object(kind):
    """A bumpy grid of quads (with some triangles) set up for one export path."""
    rng = np.random.default_rng(7)
    n = 24
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    z = 0.2 * np.sin(3 * x) * np.cos(2 * y) + 0.02 * rng.standard_normal(x.shape)
    co = np.stack([x, y, z], -1).reshape(-1, 3)
    i = np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]
    faces = [tuple(q) for q in np.stack([i, i + 1, i + n + 2, i + n + 1], -1).reshape(-1, 4)]
    faces = faces[:-20] + [f[:3] for f in faces[-20:]]  # a few triangles
    me = new_mesh(co, faces, kind)
    if kind == "smooth":
        me.shade_smooth()
    elif kind == "flat":
        me.shade_flat()
    elif kind == "sharp_edges":
        me.shade_smooth()
        sharp = me.attributes.new("sharp_edge", 'BOOLEAN', 'EDGE')
        sharp.data.foreach_set("value", rng.uniform(size=len(me.edges)) < 0.3)
    elif kind == "custom_normals":
        me.shade_smooth()
        normals = rng.normal(size=(len(me.loops), 3)) * 0.3 + [0, 0, 1]
        me.normals_split_custom_set((normals / np.linalg.norm(normals, axis=1, keepdims=True)).tolist())
    elif kind == "uv_multi_material":
        me.shade_smooth()
        for k in range(3):
            me.materials.append(bpy.data.materials.new(f"M{k}"))
        me.polygons.foreach_set("material_index", rng.integers(0, 3, len(me.polygons)).astype(np.int32))
        layer = me.uv_layers.new(name="UVMap")
        layer.uv.foreach_set("vector", rng.uniform(size=len(me.loops) * 2).astype(np.float32))
    me.update()
    obj = bpy.data.objects.new(kind, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


EXPECTED_DOMAIN = {"smooth": "POINT", "flat": "FACE", "sharp_edges": "CORNER", "custom_normals": "CORNER",
                   "uv_multi_material": "POINT"}


@pytest.mark.parametrize("kind", list(EXPECTED_DOMAIN))
def test_export_matches_blender_collections(scene, kind):
    obj = grid_object(kind)
    assert obj.data.normals_domain == EXPECTED_DOMAIN[kind]  # each export path is taken
    uv = kind == "uv_multi_material"
    dg = bpy.context.evaluated_depsgraph_get()
    (data,) = collect_meshes(dg, uv_names=(lambda materials: {0: ""}) if uv else None)
    tris, corner_normals, mat, uvs = reference(obj.evaluated_get(dg).data, uv)
    np.testing.assert_array_equal(data.triangles, tris)
    assert data.normals.dtype == np.float32 and data.normal_indices.dtype == np.int32
    assert data.normal_indices.shape == tris.shape
    np.testing.assert_allclose(data.corner_normals, corner_normals, atol=1e-6, rtol=0)
    np.testing.assert_array_equal(data.material_indices, mat)
    if uv:
        assert len(np.unique(mat)) == 3
        np.testing.assert_array_equal(data.uvs[0], uvs)


@needs_core
@pytest.mark.parametrize("index_dtype", [np.int32, np.int64])
def test_core_expands_shared_normals_like_corner_normals(scene, index_dtype):
    """add_mesh(normals=, normal_indices=) renders exactly as add_mesh(corner_normals=) with the
    expanded array, with int32 or int64 indices, contiguous or not."""
    from addon.core import get_core
    from core_scenes import look_at_matrix
    pc = get_core()
    obj = grid_object("smooth")
    dg = bpy.context.evaluated_depsgraph_get()
    (data,) = collect_meshes(dg)
    images = []
    for variant in ("expanded", "shared", "strided"):
        s = pc.Scene()
        mat = s.add_material("grey", base_color=(0.8, 0.8, 0.8))
        tris = data.triangles.astype(index_dtype)
        if variant == "expanded":
            kw = dict(corner_normals=data.corner_normals)
        elif variant == "shared":
            kw = dict(normals=data.normals, normal_indices=data.normal_indices.astype(index_dtype))
        else:  # every other column of a wider array: not contiguous
            wide = np.repeat(data.normal_indices.astype(index_dtype), 2, axis=1)[:, ::2]
            assert not wide.flags.c_contiguous
            kw = dict(normals=data.normals, normal_indices=wide)
        s.add_instance(s.add_mesh(data.positions, tris, material_slots=[mat], **kw), np.eye(4, dtype=np.float32))
        s.add_sun_light((0.3, -0.5, 0.8), (2.0, 2.0, 2.0))
        cam = pc.Camera()
        cam.matrix_world = look_at_matrix((0.0, -2.5, 2.0), (0.0, 0.0, 0.0))
        s.set_camera(cam)
        st = pc.RenderSettings()
        st.width = st.height = 24
        st.samples = 4
        sess = pc.Session(s, st)
        sess.start()
        while not sess.wait(1.0):
            pass
        images.append(sess.film())
    assert images[0][..., :3].mean() > 0.05
    np.testing.assert_array_equal(images[1], images[0])
    np.testing.assert_array_equal(images[2], images[0])


@needs_core
def test_shared_normals_are_validated():
    from addon.core import get_core
    pc = get_core()
    s = pc.Scene()
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    tri = np.array([[0, 1, 2]], np.int32)
    n = np.array([[0, 0, 1]], np.float32)
    with pytest.raises(ValueError, match="normal index 1 out of range"):
        s.add_mesh(pos, tri, normals=n, normal_indices=np.array([[0, 0, 1]], np.int32))
    with pytest.raises(ValueError, match="normal index -1"):
        s.add_mesh(pos, tri, normals=n, normal_indices=np.array([[0, 0, -1]], np.int64))
    with pytest.raises(ValueError, match="normal_indices must have shape"):
        s.add_mesh(pos, tri, normals=n, normal_indices=np.zeros((2, 3), np.int32))
    with pytest.raises(ValueError, match="normals need normal_indices"):
        s.add_mesh(pos, tri, normals=n)
    with pytest.raises(ValueError, match="normal_indices need normals"):
        s.add_mesh(pos, tri, normal_indices=np.zeros((1, 3), np.int32))
    with pytest.raises(ValueError, match="not both"):
        s.add_mesh(pos, tri, corner_normals=np.zeros((1, 3, 3), np.float32), normals=n,
                   normal_indices=np.zeros((1, 3), np.int32))
    with pytest.raises(ValueError, match="triangle index 3 out of range for 3 vertices"):
        s.add_mesh(pos, np.array([[0, 1, 3]], np.int32))
    assert s.add_mesh(pos, tri, normals=n, normal_indices=np.zeros((1, 3), np.int32)) == 0  # none half-added
