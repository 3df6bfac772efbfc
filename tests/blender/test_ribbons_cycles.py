"""Ribbons (scene.cycles_curves.shape = 'RIBBONS', issue 23) against Cycles in the same bpy:
flat strands turned to face every ray, as CPU Cycles traces them (Embree's flat Catmull-Rom
curves), on test_hair.py's patch of sagging strands under an area light."""

import functools

import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon, render_to_array
import material_scenes as ms
from test_hair import add_hair, assert_channels_agree, curves_info_material, principled_hair, unlit

load_addon()
render_pair = ms.render_pair
assert_agree = functools.partial(ms.assert_agree, floor=0.05)

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def ribbon_scene(material_fn, size=48, subdivisions=2, **hair):
    def build():
        scene = ms.studio(size=size, world=(0.05, 0.05, 0.05), light_strength=8.0, light_size=2.0,
                          camera=((0.0, -2.2, 1.6), (0.0, 0.0, 0.45)), lens=50.0)
        scene.cycles_curves.shape = 'RIBBONS'
        scene.cycles_curves.subdivisions = subdivisions
        add_hair("Hair", material_fn(), **hair)
        return scene
    return build


def test_ribbon_shape_is_exported():
    """The scene's curve shape and subdivisions reach the curves' export: ribbons with Embree's
    tessellation rate 2^subdivisions + 1 (at most 16) quads a segment; THICK stays round."""
    from addon.export.curves import collect_curves
    for level, quads in ((0, 2), (2, 5), (3, 9), (4, 16), (6, 16)):
        ribbon_scene(lambda: ms.diffuse("H", (0.5, 0.5, 0.5)), size=16, subdivisions=level, strands=2)()
        (c,) = collect_curves(bpy.context.evaluated_depsgraph_get(), Warnings())
        assert (c.shape, c.subdivisions) == ('ribbon', quads)
    bpy.context.scene.cycles_curves.shape = 'THICK'
    (c,) = collect_curves(bpy.context.evaluated_depsgraph_get(), Warnings())
    assert c.shape == 'thick'


def test_ribbon_curves_info_matches_cycles():
    """Intercept, Random and Thickness seen directly on tapering ribbons: the band's outline
    (its width, where strands cover the pixels) and the hit's position along the strand."""
    radii = np.tile(np.linspace(0.06, 0.03, 5), 7).astype(np.float32)
    ours, cycles = render_pair(unlit(ribbon_scene(lambda: curves_info_material("Info"), radii=radii)), 64)
    assert_channels_agree(ours, cycles)


def test_ribbon_tessellation_matches_cycles():
    """Strongly bent strands (3 keys) at subdivisions 0: each segment is 2^0 + 1 = 2 quads in
    Cycles (Embree's tessellation rate); the outline matches Cycles' only with the same count."""
    def bent(size=48):
        base = ribbon_scene(lambda: curves_info_material("Info"), size=size, subdivisions=0,
                            strands=4, keys=3, sag=0.6, spacing=0.3, radius=0.06)
        return unlit(base)
    ours, cycles = render_pair(bent(), 64)
    assert_channels_agree(ours, cycles)


def test_diffuse_ribbons_match_cycles():
    """A Diffuse BSDF on ribbons: lit through Cycles' rounded normal (sin v across the band,
    cos v towards the viewer), which also decides the side light may come from."""
    ours, cycles = render_pair(ribbon_scene(lambda: ms.diffuse("Hair", (0.8, 0.5, 0.3))), 256)
    assert_agree(ours, cycles, what="diffuse ribbons")


def principled_bsdf(name):
    return ms.bsdf_material(name, "ShaderNodeBsdfPrincipled", Base_Color=(0.7, 0.45, 0.25, 1.0), Roughness=0.4)[0]


def test_principled_bsdf_ribbons_match_cycles():
    ours, cycles = render_pair(ribbon_scene(lambda: principled_bsdf("Hair")), 512)
    assert_agree(ours, cycles, what="Principled BSDF ribbons")


def test_principled_hair_ribbons_match_cycles():
    """Principled Hair (Chiang) on ribbons: h is Cycles' -v across the band."""
    inputs = dict(Melanin=0.3, Melanin_Redness=0.6, Roughness=0.4, Coat=0.3)
    ours, cycles = render_pair(ribbon_scene(lambda: principled_hair("Hair", "MELANIN", **inputs)), 1024)
    assert_agree(ours, cycles, what="Principled Hair ribbons")


def test_particle_hair_ribbons_match_cycles():
    """Particle hair follows the scene's shape too (Cycles' particle hair takes it): the hidden
    emitter's strands, roots and tips in view, as ribbons: Intercept, Random, Thickness."""
    from test_particle_hair import info_scene
    base = info_scene(True, root=4.0, tip=1.0, close_tip=False)

    def build():
        scene = base()
        scene.cycles_curves.shape = 'RIBBONS'
        return scene
    ours, cycles = render_pair(build, 256)
    assert_channels_agree(ours, cycles)


def test_poly_ribbons_match_cycles():
    """Poly Curves with 'RIBBONS': Cycles 4.5 traces them as Catmull-Rom ribbons through their
    points (not as the poly lines of its THICK shape): bent 3-key strands seen directly."""
    build = unlit(ribbon_scene(lambda: curves_info_material("Info"), curve_type='POLY', strands=4, keys=3,
                               sag=0.6, spacing=0.3, radius=0.06))
    ours, cycles = render_pair(build, 64)
    assert_channels_agree(ours, cycles)


def test_hair_bsdf_ribbons_match_cycles():
    """The Hair BSDF node (Reflection and Transmission mixed, rough, with Offset) on ribbons:
    its N is the rounded normal, its T the strand's dP/du, as on round curves."""
    from test_hair import hair_bsdf_material
    inputs = dict(Color=(0.5, 0.6, 0.8, 1.0), RoughnessU=0.35, RoughnessV=0.4, Offset=0.12)
    ours, cycles = render_pair(ribbon_scene(lambda: hair_bsdf_material("Hair", **inputs)), 1024)
    assert_agree(ours, cycles, what="Hair BSDF ribbons")
