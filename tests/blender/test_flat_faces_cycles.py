"""Flat-shaded faces that are not planar (a twisted quad, a non-planar n-gon, as proportional
editing leaves them in low-poly models), Pathlight against Cycles in the same bpy: Cycles shades
each triangle of a flat face by the triangle's own normal, where Blender's corner normals give
every corner the polygon's (docs/design/export-and-cache.md)."""
import math

import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_multilayer_pair
import light_scenes as ls
import material_scenes as ms

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

RES = 64


def twisted_meshes(mode="flat"):
    """A twisted quad (two opposite corners lifted) and a non-planar octagon (its corners up and
    down in turn), side by side. mode: "flat" (sharp faces), "planar" (the same faces flattened:
    z = 0, flat) or "custom" (flat, with custom normals set, as an imported model has)."""
    lift = 0.0 if mode == "planar" else 1.0
    quad = [(-1.9, -0.7, 0.0), (-0.5, -0.7, 0.45 * lift), (-0.5, 0.7, 0.0), (-1.9, 0.7, 0.45 * lift)]
    octagon = [(1.1 + 0.8 * math.cos(math.pi * k / 4 + 0.2), 0.8 * math.sin(math.pi * k / 4 + 0.2),
                (0.3 if k % 2 else -0.15) * lift) for k in range(8)]
    me = bpy.data.meshes.new("Twisted")
    me.from_pydata(quad + octagon, [], [(0, 1, 2, 3), tuple(range(4, 12))])
    me.shade_flat()
    if mode == "mixed":
        me.polygons[1].use_smooth = True
    if mode == "custom":
        me.normals_split_custom_set([(0.0, 0.0, 1.0)] * len(me.loops))
    me.update()
    return me


def flat_scene(mode="flat"):
    scene = ls.empty_scene(RES)
    ms.set_world((0.0, 0.0, 0.0))
    mat = ms.diffuse("Flat", (0.8, 0.8, 0.8))
    me = twisted_meshes(mode)
    me.materials.append(mat)
    obj = bpy.data.objects.new("Twisted", me)
    obj.rotation_euler = (0.0, 0.0, 0.3)
    scene.collection.objects.link(obj)
    sun = ms.add_sun(3.0)
    sun.rotation_euler = (math.radians(50.0), 0.0, math.radians(30.0))  # a light at an angle
    ms.add_camera((0.0, -1.2, 4.6), (0.0, 0.0, 0.0), lens=42.0)
    scene.view_layers[0].use_pass_normal = True
    scene.render.film_transparent = True
    return scene


def render_flat(tmp_path, mode):
    # Direct light only (no bounces, black world): each pixel inside a triangle is one value.
    return render_multilayer_pair(flat_scene(mode), tmp_path, samples=16, bounces=0)


def interior(channels):
    """Pixels fully on the mesh (alpha 1) whose 3x3 neighbours are too: the pixel filter's
    samples of a pixel on a triangle's edge fall on both sides, at each engine's own positions."""
    a = channels["Combined.A"] >= 1.0
    n = np.stack([channels[f"Normal.{c}"] for c in "XYZ"], -1)
    inner = a.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            b = np.roll(np.roll(a, dy, 0), dx, 1) & (np.abs(np.roll(np.roll(n, dy, 0), dx, 1) - n).max(-1) < 1e-5)
            inner &= b
    return inner


@pytest.mark.parametrize("mode", ["flat", "mixed", "custom"])
def test_non_planar_flat_faces_match_cycles(tmp_path, mode):
    """Normal pass and image of the twisted quad and octagon against Cycles, pixel by pixel.
    Measured: Normal max 2.4e-7, image max 1.2e-7 (before, with the polygon's normal on every
    triangle: Normal up to 0.17, image up to 0.064)."""
    cycles, ours = render_flat(tmp_path, mode)
    inside = interior(cycles) & interior(ours)
    assert inside.sum() > 400
    n_c = np.stack([cycles[f"Normal.{c}"] for c in "XYZ"], -1)[inside]
    n_p = np.stack([ours[f"Normal.{c}"] for c in "XYZ"], -1)[inside]
    rgb_c = np.stack([cycles[f"Combined.{c}"] for c in "RGB"], -1)[inside]
    rgb_p = np.stack([ours[f"Combined.{c}"] for c in "RGB"], -1)[inside]
    dn, di = np.abs(n_p - n_c).max(), np.abs(rgb_p - rgb_c).max()
    print(f"\n{mode}: Normal max |diff| {dn:.3g}, image max |diff| {di:.3g} over {inside.sum()} px")
    assert dn < 1e-4, dn
    assert di < 1e-4, di


def test_planar_flat_faces_keep_the_face_normal():
    """Planar flat faces keep the polygon's normal, bit for bit (the export adds no normals);
    non-planar ones get one per triangle, the triangles' geometric normals."""
    from addon.export.mesh import mesh_arrays
    load_addon()
    # The lifted faces' triangles that tilt: the quad's 2 and 4 of the octagon's 6 (its other 2
    # join raised corners only: level, as the polygon's normal, so they keep it).
    for mode, extra in (("planar", 0), ("flat", 6), ("mixed", 2), ("custom", 0)):
        me = twisted_meshes(mode)
        positions, triangles, normals, normal_indices, _, _ = mesh_arrays(me)
        face = np.array([p.normal[:] for p in me.polygons], np.float32)
        stored = {"planar": len(me.polygons), "flat": len(me.polygons)}.get(mode, len(me.loops))
        assert len(normals) == stored + extra, (mode, len(normals))
        if mode == "planar":
            np.testing.assert_array_equal(normals, face)
        if mode == "custom":  # Blender's corner normals, on flat faces too (as Cycles reads them)
            np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (len(normals), 1)), atol=1e-6)
            bpy.data.meshes.remove(me)
            continue
        if mode == "mixed":  # (the smooth octagon's corners keep their normals)
            triangles, normal_indices = triangles[:2], normal_indices[:2]
        p = positions[triangles].astype(np.float64)
        ng = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        ng /= np.linalg.norm(ng, axis=1, keepdims=True)
        np.testing.assert_allclose(normals[normal_indices], np.repeat(ng[:, None], 3, 1), atol=1e-6)
        bpy.data.meshes.remove(me)
