"""The mesh export hands normals to the core as Blender stores them (per vertex, face or
corner, with an index per triangle corner: addon/export/mesh.py) and reads UVs through the
triangles' corner indices it already has. It must give exactly what Blender's per-element
collections give (loop triangles, corner normals, UVs, material indices), and the core must
render the shared normals exactly as the expanded ones."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, empty_scene_with_camera, load_addon

load_addon()
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
    """A bumpy grid of quads (with some triangles and an n-gon) set up for one export path."""
    rng = np.random.default_rng(7)
    n = 24
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    z = 0.2 * np.sin(3 * x) * np.cos(2 * y) + 0.02 * rng.standard_normal(x.shape)
    co = np.stack([x, y, z], -1).reshape(-1, 3)
    i = np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]
    faces = [tuple(q) for q in np.stack([i, i + 1, i + n + 2, i + n + 1], -1).reshape(-1, 4)]
    faces = faces[:-20] + [f[:3] for f in faces[-20:]]  # a few triangles
    ang = np.linspace(0, 2 * np.pi, 6)[:-1]  # and an n-gon (a pentagon) beside the grid
    co = np.concatenate([co, np.stack([1.5 + 0.3 * np.cos(ang), 0.3 * np.sin(ang), 0.1 * np.cos(2 * ang)], 1)])
    faces.append(tuple(range(len(co) - 5, len(co))))
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
    if kind == "flat":
        # Flat triangles are shaded by their own normal, as Cycles does (Blender's corner normals
        # give the polygon's, which differs on the grid's non-planar quads and pentagon); planar
        # faces keep the polygon's, equal to it within FLAT_NORMAL_TOLERANCE.
        p = data.positions[tris].astype(np.float64)
        ng = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        corner_normals = np.repeat((ng / np.linalg.norm(ng, axis=1, keepdims=True))[:, None], 3, 1)
        np.testing.assert_allclose(data.corner_normals, corner_normals, atol=1e-5, rtol=0)
    else:
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
    from core_scenes import render_lit_mesh
    pc = get_core()
    obj = grid_object("smooth")
    dg = bpy.context.evaluated_depsgraph_get()
    (data,) = collect_meshes(dg)
    images = []
    for variant in ("expanded", "shared", "strided"):
        tris = data.triangles.astype(index_dtype)
        if variant == "expanded":
            kw = dict(corner_normals=data.corner_normals)
        elif variant == "shared":
            kw = dict(normals=data.normals, normal_indices=data.normal_indices.astype(index_dtype))
        else:  # every other column of a wider array: not contiguous
            wide = np.repeat(data.normal_indices.astype(index_dtype), 2, axis=1)[:, ::2]
            assert not wide.flags.c_contiguous
            kw = dict(normals=data.normals, normal_indices=wide)
        images.append(render_lit_mesh(pc, data.positions, tris, **kw))
    assert images[0][..., :3].mean() > 0.05
    np.testing.assert_array_equal(images[1], images[0])
    np.testing.assert_array_equal(images[2], images[0])
