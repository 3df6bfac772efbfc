"""Adaptive subdivision (Cycles' Experimental feature set, the object's Adaptive Subdivision on
its last Subdivision Surface modifier): the export reads the cage before the modifier and the
core dices its Catmull-Clark limit surface to about the dicing rate in pixels. Against Cycles in
the same bpy (a displaced cube and a plain one), and the export: watertight, denser nearer the
camera, the modifier kept where Cycles keeps it, the cage evaluated with other modifiers and
shape keys, a warning where the cage cannot be read."""
import math

import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon
import material_scenes as ms
from test_true_displacement import disp_material

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

W, H = 64, 48


def scene(method="DISPLACEMENT", distance=2.2, feature_set='EXPERIMENTAL', before=False, shape="cube",
          cage=None):
    """A unit cube (8 corners of valence 3: the limit surface's extraordinary points) with an
    adaptive Catmull-Clark modifier, Noise displacement or none, under a grazing sun. cage:
    "array" (a half-size cube and an Array modifier's copy of it before the Subdivision
    Surface) or "shape-key" (a key that lifts and widens the top, at 0.7)."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
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
    if cage == "array":
        obj.scale = (0.4, 0.4, 0.4)
        obj.location.x = -0.4
        array = obj.modifiers.new("Array", 'ARRAY')
        array.count, array.relative_offset_displace = 2, (2.0, 0.0, 0.0)
    elif cage == "shape-key":
        obj.shape_key_add(name="Basis")
        key = obj.shape_key_add(name="Lift")
        for point in key.data:
            if point.co.z > 0:
                point.co = (point.co.x * 1.4, point.co.y * 1.4, point.co.z + 0.3)
        key.value = 0.7
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
    # The cage as the depsgraph evaluates it before the modifier (GeometrySet.mesh_base).
    "array-noise-displacement": ("DISPLACEMENT", "cube", 128, "array"),
    "shape-key-noise-displacement": ("DISPLACEMENT", "cube", 128, "shape-key"),
}


@pytest.mark.converged
@pytest.mark.parametrize("case", list(CASES))
def test_adaptive_subdivision_matches_cycles(case):
    method, shape, samples, *cage = CASES[case]
    # (Cycles at 4x, stored: at equal samples the array case failed at one seed of three with the
    # 4-D sets, 3.3 % against 3 %; Cycles' own noise is half of each region's difference)
    ours, cycles = ms.render_pair(lambda: scene(method, shape=shape, cage=(cage or [None])[0]), samples,
                                  cycles_samples=4 * samples)
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


@pytest.mark.parametrize("cage", ["bevel", "array", "shape-key"])
def test_the_cage_is_evaluated_before_the_modifier(cage):
    """Modifiers before the Subdivision Surface and shape keys are applied to the cage (the
    evaluated mesh before the modifier), which is diced without a warning; the user's mesh
    is left as it was."""
    mesh, warn = export(before=cage == "bevel", cage=None if cage == "bevel" else cage)
    assert mesh.subdivision is not None and not warn, list(warn)
    assert_watertight(mesh.triangles)
    original = bpy.context.scene.objects["Cube"].data
    assert len(original.vertices) == 8 and len(original.polygons) == 6
    p = mesh.positions
    plain = export()[0].positions
    if cage == "array":  # two limit cubes, the copy 2 (local) along x
        assert p[:, 0].max() - p[:, 0].min() > plain[:, 0].max() - plain[:, 0].min() + 1.9
    elif cage == "shape-key":  # the top lifted by 0.7 x 0.3 (the limit surface pulls it in)
        assert p[:, 2].max() > plain[:, 2].max() + 0.1
        assert abs(p[:, 2].min() - plain[:, 2].min()) < 0.05
    else:  # the bevel's narrow faces keep the limit surface closer to the cube's corners
        assert np.abs(p).max() > np.abs(plain).max() + 0.02


def test_without_geometry_set_a_modifier_before_it_is_warned(monkeypatch):
    """Where Blender has no GeometrySet.mesh_base (before 4.5), the cage can only be the
    original mesh: another modifier is warned and the depsgraph's subdivision is rendered."""
    import types
    from addon.export import subdivision
    monkeypatch.setattr(subdivision, "bpy", types.SimpleNamespace(types=types.SimpleNamespace()))
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


def mirror_scene(offscreen=4.0):
    """The displaced cube behind the camera, seen only in a mirror in front of it, diced at a
    coarse 2 px: Cycles' offscreen_dicing_scale dices it several times coarser than if it were
    in view (it is about as far from the view as from the camera), and the Noise sampled at
    fewer vertices changes its reflected shape."""
    sc = scene("DISPLACEMENT", cage=None)
    sc.cycles.dicing_rate = sc.cycles.preview_dicing_rate = 2.0
    sc.cycles.offscreen_dicing_scale = offscreen
    cube = sc.objects["Cube"]
    cube.location = (0.0, -3.6, -1.2)  # behind the camera (it looks along +y), big in the mirror
    cube.scale = (2.0, 2.0, 2.0)
    cube.data.materials[0].node_tree.nodes["Displacement"].inputs["Scale"].default_value = 0.3
    ms.add_plane("Mirror", 6.0, ms.glossy("Mirror", roughness=0.0), location=(0.0, 1.0, 0.6),
                 rotation_euler=(math.pi / 2, 0.0, 0.0))
    return sc


@pytest.mark.converged
def test_offscreen_dicing_follows_cycles_in_a_mirror():
    """The scale matters here (Cycles with and without it differs by 17 %); with it the worst
    region is under half of what dicing the cube as if in view leaves, and the mean agrees.
    Not the 3 % bar: the worst region stays a little above it and above Cycles' noise
    (docs/design/displacement.md#off-screen-dicing)."""
    ours, cycles = ms.render_pair(mirror_scene, 64)
    ratio, worst, _ = ms.compare(ours, cycles, floor=0.02)
    from blender_util import render_to_array
    in_view = render_to_array(mirror_scene(offscreen=1.0), "PATHLIGHT", samples=64, max_bounces=16)
    ratio_in_view, worst_in_view, _ = ms.compare(in_view, cycles, floor=0.02)
    print(f"\noffscreen-mirror: mean {ratio:.4f}, worst {worst:.4f}; "
          f"as if in view: mean {ratio_in_view:.4f}, worst {worst_in_view:.4f}")
    assert abs(ratio - 1.0) < 0.01
    assert worst < 0.5 * worst_in_view, (worst, worst_in_view)
