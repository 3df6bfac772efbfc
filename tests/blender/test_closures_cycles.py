"""Cycles' small closures against Cycles 4.5 in the same bpy (issue 24): Holdout (the film's alpha
and RGB where it is seen directly, alone and mixed with a diffuse shader, with and without the
transparent film). Tolerances as test_principled_cycles: the whole-image mean within 1 %, every
8x8 region within 3 % (dark regions absolutely against 0.02); alpha regions within 0.02.
Measured agreement numbers are printed (pytest -s)."""

import functools

import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms
from material_scenes import assert_agree

load_addon()
render_pair = functools.partial(ms.render_pair, bounces=8)

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def alpha_regions(img, grid=8):
    h, w = img.shape[:2]
    a = img[: h // grid * grid, : w // grid * grid, 3]
    return a.reshape(grid, h // grid, grid, w // grid).mean(axis=(1, 3))


def holdout_scene():
    """A full holdout sphere and a Mix (Fac 0.4: 60 % holdout) of a red diffuse and a holdout, on
    the studio floor: the floor shows them as black (a holdout reflects nothing)."""
    def build():
        scene = ms.studio(48)
        mat, nodes, links, out = ms.new_material("Holdout")
        links.new(nodes.new("ShaderNodeHoldout").outputs[0], out.inputs["Surface"])
        ms.add_sphere("Full", 0.6, mat, location=(-0.7, 0.0, 0.6))
        mat, nodes, links, out = ms.new_material("Partial")
        mix = nodes.new("ShaderNodeMixShader")
        mix.inputs["Fac"].default_value = 0.4
        links.new(nodes.new("ShaderNodeHoldout").outputs[0], mix.inputs[1])
        diffuse = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.8, 0.2, 0.1, 1.0))
        links.new(diffuse.outputs[0], mix.inputs[2])
        links.new(mix.outputs[0], out.inputs["Surface"])
        ms.add_sphere("Partial", 0.6, mat, location=(0.7, 0.0, 0.6))
        return scene
    return build


@pytest.mark.parametrize("film_transparent", [False, True])
def test_holdout_alpha_and_colour(film_transparent):
    # (1024 spp, both: at 256 the RGB's worst region was 4.1 % at one seed of three with the 4-D
    # sets, tolerance 3 %; now 1.3-2.1 % with them, 1.4-1.6 % with the pairs, seeds 0-2)
    ours, cycles = render_pair(holdout_scene(), 1024, film_transparent=film_transparent)
    a, b = alpha_regions(ours), alpha_regions(cycles)
    print(f"\nholdout alpha (film_transparent={film_transparent}): mean {ours[..., 3].mean():.4f} / "
          f"{cycles[..., 3].mean():.4f}, worst region {np.abs(a - b).max():.4f}")
    assert cycles[..., 3].min() < 0.05 and 0.3 < cycles[..., 3].max()  # the scene shows holdouts
    assert np.abs(a - b).max() < 0.02, np.round(a - b, 3)
    assert_agree(ours, cycles, f"holdout RGB (film_transparent={film_transparent})")


def test_translucent_sphere_and_card():
    # A translucent sphere (light crosses it twice, diffusely) and a translucent card lit from
    # above, seen from above: what it shows is the floor's light transmitted through it.
    def build():
        scene = ms.studio(48)
        mat = ms.bsdf_material("Translucent", "ShaderNodeBsdfTranslucent", Color=(0.8, 0.6, 0.3, 1.0))[0]
        ms.add_sphere("Sphere", 0.6, mat, location=(-0.7, 0.0, 0.6))
        card = ms.bsdf_material("Card", "ShaderNodeBsdfTranslucent", Color=(0.3, 0.7, 0.9, 1.0))[0]
        ms.add_plane("Card", 1.0, card, location=(0.8, 0.0, 1.0), rotation_euler=(0.3, 0.0, 0.0))
        return scene
    ours, cycles = render_pair(build, 256)
    assert_agree(ours, cycles, "translucent")


def metallic_scene(distribution):
    """Metallic BSDF spheres: F82 Tint (Blender's defaults; a coloured one, rougher) and Physical
    Conductor (the default IOR/Extinction; a copper-like one, smoother)."""
    def build():
        scene = ms.studio(48, camera=((0.0, -6.0, 2.4), (0.0, 0.0, 0.7)))
        cases = [
            ("F82", {}),
            ("F82", {"Base_Color": (0.9, 0.5, 0.2, 1.0), "Edge_Tint": (0.3, 0.9, 1.0, 1.0), "Roughness": 0.7}),
            ("PHYSICAL_CONDUCTOR", {}),
            ("PHYSICAL_CONDUCTOR", {"IOR": (0.27, 0.68, 1.22), "Extinction": (3.6, 2.6, 2.3), "Roughness": 0.3}),
        ]
        for i, (mode, inputs) in enumerate(cases):
            mat, nodes, links, out = ms.new_material(f"Metal{i}")
            node = nodes.new("ShaderNodeBsdfMetallic")
            node.fresnel_type = mode  # first: only the mode's sockets can be found by name
            node.distribution = distribution
            ms.set_inputs(node, **inputs)
            links.new(node.outputs[0], out.inputs["Surface"])
            ms.add_sphere(f"S{i}", 0.45, mat, location=(-1.5 + i, 0.0, 0.45 + 0.5 * (i % 2)))
        return scene
    return build


@pytest.mark.parametrize("distribution", ["MULTI_GGX", "GGX", "BECKMANN"])
def test_metallic_bsdf(distribution):
    ours, cycles = render_pair(metallic_scene(distribution), 1024)
    assert_agree(ours, cycles, f"metallic {distribution}")
