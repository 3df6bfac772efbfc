"""IES Texture in light node trees (point, spot, area): what the add-on exports (the profile from
a Text datablock or a file, a Math factor, missing and broken files warned with Cycles' fallback)
and the rendered light against Cycles 4.5 in the same bpy. The core's reader and lookup:
tests/core/test_ies.py."""

import math

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, Warnings, core_has, load_addon, render_to_array
from light_scenes import add_light, camera, diffuse_material, empty_scene, plane
from test_lights import assert_agrees_with_cycles, export_lights, one_light

load_addon()

needs_ies = pytest.mark.skipif(not core_has("IesProfile", "eval"), reason="the core has no IES profiles")


def ies_text(v, h, cd):
    """A type C LM-63 file: cd[i][j] is the candela at horizontal angle h[i], vertical v[j]."""
    lines = ["IESNA:LM-63-2002", "[TEST] synthetic", "TILT=NONE",
             f"1 1000 1.0 {len(v)} {len(h)} 1 2 0.0 0.0 0.0", "1.0 1.0 100",
             " ".join(map(str, v)), " ".join(map(str, h))]
    return "\n".join(lines + [" ".join(map(str, row)) for row in cd]) + "\n"


# Brighter downward, rotationally symmetric (one horizontal angle).
DOWNWARD = ies_text([0, 15, 30, 45, 60, 75, 90, 120, 180], [0],
                    [[1200, 1150, 1000, 700, 400, 200, 80, 30, 10]])
# Asymmetric: each quarter of the circle its own falloff, dark straight up.
ASYMMETRIC = ies_text([0, 30, 60, 90, 120, 150, 180], [0, 90, 180, 270, 360],
                      [[900, 700, 400, 200, 100, 50, 0], [900, 800, 700, 500, 300, 100, 0],
                       [900, 600, 300, 100, 50, 20, 0], [900, 850, 900, 900, 600, 300, 0],
                       [900, 700, 400, 200, 100, 50, 0]])


def with_ies(obj, text=None, filepath=None, strength=1.0, math_op=None, factor=1.0):
    """obj's light node tree: IES Texture (Fac) [-> Math op factor] -> Emission Strength."""
    data = obj.data
    data.use_nodes = True
    nt = data.node_tree
    ies = nt.nodes.new("ShaderNodeTexIES")
    if filepath is not None:
        ies.mode = 'EXTERNAL'
        ies.filepath = filepath
    else:
        ies.mode = 'INTERNAL'
        if text is not None:
            block = bpy.data.texts.new("profile.ies")
            block.from_string(text)
            ies.ies = block
    ies.inputs["Strength"].default_value = strength
    out = ies.outputs["Fac"]
    if math_op is not None:
        m = nt.nodes.new("ShaderNodeMath")
        m.operation = math_op
        nt.links.new(out, m.inputs[0])
        m.inputs[1].default_value = factor
        out = m.outputs[0]
    nt.links.new(out, nt.nodes["Emission"].inputs["Strength"])
    return ies


# ---------------------------------------------------------------- export (needs the core's reader)

@needs_ies
def test_internal_profile_and_math_factor_are_exported():
    empty_scene(16)
    obj = add_light('SPOT', energy=100.0, spot_size=math.radians(90))
    with_ies(obj, DOWNWARD, strength=2.0, math_op='MULTIPLY', factor=0.5)
    obj.data.node_tree.nodes["Emission"].inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    light, warnings = one_light()
    assert warnings == []
    profile = light.args["ies"]
    # Straight down: 1200 cd in Cycles' units, times the 1.125 of Cycles' unwrapped Catmull-Rom
    # curve halfway round a one-angle profile (0 beyond both ends of its 0..360 interval).
    assert profile.eval((0, 0, -1)) == pytest.approx(1200 * 4 * math.pi / 177.83 * 1.125, rel=1e-4)
    # Colour x IES Strength x the Math factor go into the intensity; the profile stays apart.
    assert light.args["intensity"] == pytest.approx(
        tuple(100.0 / (4 * math.pi) * c for c in (1.0, 0.5, 0.25)), rel=1e-6)


@needs_ies
def test_external_relative_path_is_resolved_as_blender_does(tmp_path):
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "lamp.ies").write_text(ASYMMETRIC)
    empty_scene(16)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    obj = add_light('POINT', energy=10.0)
    with_ies(obj, filepath="//profiles/lamp.ies", math_op='DIVIDE', factor=4.0)
    light, warnings = one_light()
    assert warnings == [] and "ies" in light.args and "ies_matrix" in light.args
    assert light.args["intensity"][0] == pytest.approx(10.0 / (4 * math.pi) / 4.0)


@needs_ies
@pytest.mark.parametrize("case", ["missing file", "garbage", "no text"])
def test_unusable_profiles_warn_and_use_cycles_fallback(case, tmp_path):
    empty_scene(16)
    obj = add_light('AREA', energy=10.0, size=1.0)
    if case == "missing file":
        with_ies(obj, filepath=str(tmp_path / "nowhere.ies"))
    elif case == "garbage":
        with_ies(obj, "this is not an IES file\nTILT=NONE\n1 2 3\n")
    else:
        with_ies(obj)
    light, warnings = one_light()
    assert "ies" not in light.args
    assert len(warnings) == 1 and "IES Texture without a usable profile" in warnings[0], warnings
    # Cycles' kernel gives 100 where a slot has no profile (measured: the same image).
    assert light.args["radiance"][0] == pytest.approx(100 * 10.0 / math.pi, rel=1e-6)


@needs_ies
def test_ies_on_a_sun_becomes_a_light_program():
    # Beyond the IES-only pattern, the tree is compiled as any light tree (test_light_nodes.py).
    empty_scene(16)
    sun = add_light('SUN', name="Sun", energy=2.0)
    with_ies(sun, DOWNWARD)
    lights, warnings = export_lights()
    assert len(lights) == 1 and "ies" not in lights[0].args and not warnings, warnings
    assert any(op[0] == "tex_ies" for op in lights[0].args["shader"])
    assert lights[0].args["irradiance"][0] == pytest.approx(2.0)


# ---------------------------------------------------------------- against Cycles

def floor_and_wall(width=64, height=48):
    scene = empty_scene(width, height)
    white = diffuse_material("White", 0.7)
    plane("Floor", 12.0, white)
    plane("Wall", 12.0, diffuse_material("Grey", 0.5), location=(0, 2.0, 3.0),
          rotation_euler=(math.pi / 2, 0, 0))
    camera((0.0, -5.0, 2.2), look_at=(0.0, 0.8, 0.9), lens=30.0)
    return scene


IES_CASES = {
    # (light type, light properties, profile, node settings)
    "spot_downward": ('SPOT', dict(location=(-0.6, 0.6, 2.4), rotation=(0.35, 0.0, 0.2), energy=3.0,
                                   spot_size=math.radians(130), spot_blend=0.2, shadow_soft_size=0.05),
                      DOWNWARD, dict(strength=0.8)),
    "point_asymmetric": ('POINT', dict(location=(0.4, 0.9, 1.6), rotation=(0.0, 0.0, 0.7), energy=2.0,
                                       shadow_soft_size=0.1),
                         ASYMMETRIC, dict(math_op='MULTIPLY', factor=0.7)),
    "area_asymmetric": ('AREA', dict(location=(0.0, 0.5, 2.0), rotation=(0.3, 0.0, -0.4), energy=3.0,
                                     shape='RECTANGLE', size=0.6, size_y=0.3),
                        ASYMMETRIC, dict()),
}


@needs_ies
@pytest.mark.parametrize("case", list(IES_CASES))
def test_ies_light_agrees_with_cycles(case):
    kind, props, profile, node = IES_CASES[case]
    scene = floor_and_wall()
    with_ies(add_light(kind, **props), profile, **node)
    # At 1024 spp the worst 8 x 8 regions differ from Cycles by 2.1 / 1.2 / 0.8 % (Cycles from
    # itself with another seed: 1.3 / 1.2 / 0.8 %); at 256 spp Cycles' seeds alone differ by 4.7 %.
    ours = render_to_array(scene, samples=1024, max_bounces=2)
    ref = render_to_array(scene, "CYCLES", samples=1024, max_bounces=2, **BOX_FILTER)
    assert_agrees_with_cycles(ours, ref, region_tol=0.03, mean_tol=0.01)
