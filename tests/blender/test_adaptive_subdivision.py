"""Adaptive subdivision (Cycles' Experimental feature set, the object's Adaptive Subdivision on
its last Subdivision Surface modifier): the export reads the cage before the modifier and the
core dices its Catmull-Clark limit surface to about the dicing rate in pixels. Against Cycles in
the same bpy (a displaced cube and a plain one), and the export: watertight, denser nearer the
camera, the modifier kept where Cycles keeps it, a warning where the cage cannot be read."""
import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon
import material_scenes as ms
from test_true_displacement import disp_material

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

W, H = 64, 48


def scene(method="DISPLACEMENT", distance=2.2, feature_set='EXPERIMENTAL', before=False, shape="cube"):
    """A unit cube (8 corners of valence 3: the limit surface's extraordinary points) with an
    adaptive Catmull-Clark modifier, Noise displacement or none, under a grazing sun."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.resolution_x, sc.render.resolution_y = W, H
    sc.cycles.feature_set = feature_set
    sc.cycles.preview_dicing_rate = sc.cycles.dicing_rate  # (exports below use the viewport's)
    ms.set_world((0.05, 0.05, 0.05))
    mat = disp_material(f"cube-{method}", method, "noise", 0.1) if method else None
    import bmesh  # (after bpy)
    if shape == "cube":
        def build(bm):
            bmesh.ops.create_cube(bm, size=1.0)
    else:  # a hexagonal prism: two n-gons
        def build(bm):
            bmesh.ops.create_cone(bm, cap_ends=True, cap_tris=False, segments=6, radius1=0.5, radius2=0.5,
                                  depth=1.0)
    obj = ms.add_mesh_object("Cube", build, (mat,) if mat else (), smooth=True, rotation_euler=(0.3, 0.2, 0.5))
    if before:
        obj.modifiers.new("Bevel", 'BEVEL')
    mod = obj.modifiers.new("Subdivision", 'SUBSURF')
    mod.levels = mod.render_levels = 1  # (what Cycles ignores when it dices)
    obj.cycles.use_adaptive_subdivision = True
    ms.add_camera((0.0, -distance, 0.6 * distance / 2.2), (0.0, 0.0, 0.0))
    ms.add_sun(4.0, 60.0)
    return sc


CASES = {  # displacement method (None: no displacement), cage, samples
    "cube-noise-displacement": ("DISPLACEMENT", "cube", 128),
    "cube-limit-surface": (None, "cube", 64),
    "prism-noise-displacement": ("DISPLACEMENT", "prism", 128),  # n-gon caps
}


@pytest.mark.converged
@pytest.mark.parametrize("case", list(CASES))
def test_adaptive_subdivision_matches_cycles(case):
    method, shape, samples = CASES[case]
    ours, cycles = ms.render_pair(lambda: scene(method, shape=shape), samples)
    ms.assert_agree(ours, cycles, case)


def export(**kw):
    from addon.export import export_scene
    scene(**kw)
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    (mesh,) = data.meshes
    return mesh, warn


def assert_watertight(tris):
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    directed = {tuple(x) for x in e.tolist()}
    assert len(directed) == len(e) and all((b, a) in directed for a, b in directed), "cracks"


def test_export_dices_the_cage_watertight_and_by_distance():
    near, warn = export()
    assert near.subdivision is not None and not warn, list(warn)
    assert_watertight(near.triangles)
    prism, _ = export(shape="prism")
    assert prism.subdivision is not None
    assert_watertight(prism.triangles)
    # The cage's corners sit on the limit surface, well inside the unit cube's corners.
    assert np.abs(near.positions).max() < 0.5
    far, _ = export(distance=4.4)
    assert 2.5 < len(near.triangles) / len(far.triangles) < 6.0


def test_supported_feature_set_keeps_the_modifier():
    mesh, warn = export(feature_set='SUPPORTED')
    assert mesh.subdivision is None
    assert len(mesh.triangles) == 6 * 4 * 2  # the modifier's level 1, as Blender evaluates it


def test_a_modifier_before_it_is_warned_and_falls_back():
    mesh, warn = export(before=True)
    assert mesh.subdivision is None and len(mesh.triangles) > 0
    assert any("adaptive subdivision is not done" in w and "Bevel" in w for w in warn), list(warn)


def test_corner_values_follow_the_patches():
    """UVs and corner attributes: bilinear over a quad's corners; an n-gon's sub-patch k spans
    corner k, the next edge's middle, the centre and the previous edge's middle."""
    from addon.export.subdivision import _corner_interpolate
    values = np.float32([[0, 0], [1, 0], [1, 1], [0, 1], [5, 5], [7, 5], [6, 8]])
    offsets = np.int32([0, 4, 7])
    faces, subs = np.int32([0, 1, 1]), np.int32([0, 0, 2])
    uv = np.float32([[[0, 0], [1, 0], [0.25, 0.75]],   # quad: corners and a point inside
                     [[0, 0], [1, 0], [1, 1]],         # triangle, sub-patch 0
                     [[0, 0], [0, 1], [1, 1]]])        # triangle, sub-patch 2
    out = _corner_interpolate(values, offsets, faces, subs, uv)
    np.testing.assert_allclose(out[0], [[0, 0], [1, 0], [0.25, 0.75]], atol=1e-6)
    np.testing.assert_allclose(out[1], [[5, 5], [6, 5], [6, 6]], atol=1e-6)
    np.testing.assert_allclose(out[2], [[6, 8], [6.5, 6.5], [6, 6]], atol=1e-6)


def test_no_ray_passes_between_displaced_patches():
    """A camera inside the displaced, diced cube (scaled up around it): every pixel hits the
    surface (transparent film: alpha 1), so no crack opens between patches diced with different
    edge factors."""
    from blender_util import render_to_array
    sc = scene("DISPLACEMENT")
    cube = sc.objects["Cube"]
    cube.scale = (4.0, 4.0, 4.0)
    cam = sc.camera
    cam.location = (0.3, -0.2, 0.1)
    cam.data.lens = 12.0  # wide: edges, corners and the faces' middles in view
    sc.render.film_transparent = True
    img = render_to_array(sc, "PATHLIGHT", samples=1, resolution_x=48, resolution_y=48)
    assert img[..., 3].min() == 1.0, f"{int((img[..., 3] < 1).sum())} pixels see through"
