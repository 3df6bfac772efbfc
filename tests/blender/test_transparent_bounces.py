"""Transparent Max Bounces against Cycles: stacks of 1, 2 and 6 faintly tinted Transparent cards
over the studio floor, under its panel light, at a limit of 2, and an absorbing volume sphere
over the 1-card stack. The camera sees the floor through the stacks of 1 and 2, and the 6-card
stack ends at its 4th card (black: Cycles' kernel limit is the setting + 1); the floor's light
samples pass at most 2 - (cards the camera ray crossed) cards, so under the 2-card stack only the
BSDF rays that hit the panel light it (with their MIS weight), as in Cycles. The volume's
boundaries are not transparent bounces (Cycles' volume_bounds_bounce)."""

import numpy as np
import pytest

from blender_util import BOX_FILTER, core_available, load_addon, render_to_array
import material_scenes as ms
from material_scenes import assert_agree

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def stacks_scene():
    scene = ms.studio(48, camera=((0.0, -3.5, 4.0), (0.0, 0.0, 0.3)))
    card = ms.bsdf_material("Card", "ShaderNodeBsdfTransparent", Color=(0.95, 0.9, 0.85, 1.0))[0]
    for x, n in ((-1.2, 1), (0.0, 2), (1.2, 6)):
        for i in range(n):
            ms.add_plane(f"Card{x}_{i}", 0.9, card, location=(x, 0.0, 0.4 + 0.15 * i))
    fog, nodes, links, out = ms.new_material("Fog")
    absorb = nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Density"].default_value = 0.8
    links.new(absorb.outputs[0], out.inputs["Volume"])
    ms.add_sphere("Fog", 0.4, fog, location=(-1.2, -0.3, 1.3))
    return scene


def test_transparent_max_bounces_agree_with_cycles():
    ours = render_to_array(stacks_scene(), "PATHLIGHT", samples=256, max_bounces=8, transparent_bounces=2)
    cycles = render_to_array(stacks_scene(), "CYCLES", samples=256, max_bounces=8, transparent_max_bounces=2,
                             **BOX_FILTER)
    # What the limit does shows: the middle of the 6-card stack is black in both (12x12 blocks).
    blocks = cycles[..., :3].mean(-1).reshape(12, 4, 12, 4).mean((1, 3))
    assert blocks[4:6, 9:11].max() < 1e-3 and blocks[4:6, 9:11].max() < 0.01 * blocks.mean()
    assert_agree(ours, cycles, "transparent max bounces 2")
