"""The shader node compiler (the addon/export/shader/ package): BSDFs, mixes, node groups and
graph structure, UVs through the export and the closures of issue 24; the programs emitted for
node setups are evaluated by shader_compiler_util's small interpreter. Value and texture nodes:
test_shader_compiler_values.py (whose last test hands every program to the core)."""

import math

import bpy
import numpy as np
import pytest
from mathutils import Euler, Matrix, Vector

from blender_util import core_available, load_addon, Warnings
import material_scenes as ms

load_addon()
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402
from addon.export.material import MaterialTable, convert_material  # noqa: E402
from addon.export.shader import MAX_REGISTERS, ImageTable, UvSets, mapping_matrix  # noqa: E402
from shader_reference import _math, _mix  # noqa: E402
from shader_compiler_util import (  # noqa: E402,F401  (empty_scene: the autouse fixture)
    Sym, approx, closures_of, compile_, empty_scene, link, run, weight_of)


# ---------------------------------------------------------------- BSDFs and mixes

@pytest.mark.parametrize("fac", [0.2, 0.5, 1.0])
def test_mix_of_diffuse_and_glossy(fac):
    mat = ms.mix_diffuse_glossy("Mix", fac, color=(0.8, 0.3, 0.2), roughness=0.1)
    closures, warnings, _ = closures_of(mat)
    assert not warnings
    by_kind = {c[0]: c for c in closures}
    if fac == 1.0:  # a zero weight is folded away
        assert list(by_kind) == ["glossy"]
    else:
        assert sorted(by_kind) == ["diffuse", "glossy"]
        assert weight_of(by_kind["diffuse"]) == approx((1 - fac,) * 3)
        assert by_kind["diffuse"][2]["color"][:3] == approx((0.8, 0.3, 0.2))
    assert weight_of(by_kind["glossy"]) == approx((fac,) * 3)
    assert by_kind["glossy"][2]["roughness"][0] == approx(0.1)
    assert by_kind["glossy"][2]["color"][:3] == approx((0.9, 0.9, 0.9))


def test_each_bsdf_node_maps_to_its_closure():
    cases = {
        "ShaderNodeBsdfDiffuse": ("diffuse", dict(Color=(0.1, 0.2, 0.3, 1))),
        "ShaderNodeBsdfGlossy": ("glossy", dict(Color=(0.4, 0.5, 0.6, 1), Roughness=0.25)),
        "ShaderNodeBsdfGlass": ("glass", dict(Roughness=0.1, IOR=1.33)),
        "ShaderNodeBsdfRefraction": ("refraction", dict(Roughness=0.0, IOR=1.7)),
        "ShaderNodeBsdfTransparent": ("transparent", dict(Color=(0.9, 0.8, 0.7, 1))),
        "ShaderNodeEmission": ("emission", dict(Color=(1, 0.5, 0.25, 1), Strength=4.0)),
    }
    for node_type, (kind, inputs) in cases.items():
        mat, node = ms.bsdf_material(node_type, node_type, **inputs)
        if hasattr(node, "distribution"):
            node.distribution = 'GGX'
        (closure,), warnings, _ = closures_of(mat)
        assert not warnings, warnings
        assert closure[0] == kind and closure[1] is None
        params = closure[2]
        if kind == "emission":
            assert params["color"][:3] == approx((4.0, 2.0, 1.0))
            continue
        assert params["color"][:3] == approx(tuple(inputs.get("Color", (1, 1, 1, 1))[:3]))
        if "Roughness" in inputs:
            assert params["roughness"][0] == approx(inputs["Roughness"])
        if "IOR" in inputs:
            assert params["ior"][0] == approx(inputs["IOR"])
        assert "normal" not in params  # unconnected: the shading normal


def test_rough_diffuse_sheen_and_diffuse_roughness_pass_their_inputs():
    # Diffuse BSDF's Roughness (Oren-Nayar in the core): passed when not a constant zero.
    mat, node = ms.bsdf_material("Rough", "ShaderNodeBsdfDiffuse", Roughness=0.6)
    (closure,), warnings, _ = closures_of(mat)
    assert closure[0] == "diffuse" and not warnings
    assert closure[2]["roughness"][0] == approx(0.6)
    node.inputs["Roughness"].default_value = 0.0
    (closure,), _, _ = closures_of(mat)
    assert "roughness" not in closure[2]
    # Sheen BSDF: microfibre by default, Ashikhmin velvet as a flag.
    mat, node = ms.bsdf_material("Sheen", "ShaderNodeBsdfSheen", Color=(0.2, 0.4, 0.6, 1), Roughness=0.3)
    assert node.distribution == 'MICROFIBER'
    (closure,), warnings, _ = closures_of(mat)
    assert closure[0] == "sheen" and not warnings and "velvet" not in closure[2]
    assert closure[2]["color"][:3] == approx((0.2, 0.4, 0.6)) and closure[2]["roughness"][0] == approx(0.3)
    node.distribution = 'ASHIKHMIN'
    (closure,), warnings, _ = closures_of(mat)
    assert closure[2]["velvet"][0] == 1.0 and not warnings
    # Toon BSDF: its Size and Smooth, Glossy as a flag.
    mat, node = ms.bsdf_material("Toon", "ShaderNodeBsdfToon", Size=0.3, Smooth=0.1)
    (closure,), warnings, _ = closures_of(mat)
    assert closure[0] == "toon" and not warnings and "glossy" not in closure[2]
    assert closure[2]["size"][0] == approx(0.3) and closure[2]["smooth"][0] == approx(0.1)
    node.component = 'GLOSSY'
    (closure,), _, _ = closures_of(mat)
    assert closure[2]["glossy"][0] == 1.0
    # Principled Diffuse Roughness and Sheen: passed, no warning.
    mat, node = ms.bsdf_material("P", "ShaderNodeBsdfPrincipled", Diffuse_Roughness=0.7, Sheen_Weight=1.0,
                                 Sheen_Tint=(1.0, 0.5, 0.25, 1))
    (closure,), warnings, _ = closures_of(mat)
    assert not warnings
    assert closure[2]["diffuse_roughness"][0] == approx(0.7)
    assert closure[2]["sheen_tint"][:3] == approx((1.0, 0.5, 0.25))
    # Emission under the sheen travels in the Principled closure (the core dims it), not as
    # an Emission closure of its own; without sheen or coat it stays a plain Emission closure.
    node.inputs["Emission Strength"].default_value = 2.0
    (closure,), warnings, _ = closures_of(mat)
    assert closure[0] == "principled" and not warnings
    assert closure[2]["emission"][:3] == approx((2.0, 2.0, 2.0))
    node.inputs["Sheen Weight"].default_value = 0.0
    kinds = [c[0] for c in closures_of(mat)[0]]
    assert kinds == ["principled", "emission"]


def test_multiscatter_glossy_passes_its_distribution_without_warning():
    # Blender's default distribution: the closure carries the multiscatter flag (a register of
    # 1) that turns on the core's energy compensation; single-scatter GGX carries none.
    mat, node = ms.bsdf_material("Glossy", "ShaderNodeBsdfGlossy", Roughness=0.4)
    assert node.distribution == 'MULTI_GGX'
    (closure,), warnings, _ = closures_of(mat)
    assert closure[0] == "glossy" and not warnings
    assert closure[2]["multiscatter"][0] == 1.0
    node.distribution = 'GGX'
    (closure,), warnings, _ = closures_of(mat)
    assert "multiscatter" not in closure[2] and not warnings
    for node_type, kind in (("ShaderNodeBsdfPrincipled", "principled"), ("ShaderNodeBsdfGlass", "glass")):
        m, n = ms.bsdf_material(kind, node_type, Roughness=0.3)
        assert n.distribution == 'MULTI_GGX'
        closures, _, _ = closures_of(m)
        (c,) = [c for c in closures if c[0] == kind]
        assert c[2]["multiscatter"][0] == 1.0
    # Beckmann and Ashikhmin-Shirley: the core's own lobes, each picked by a flag register of 1
    # (no multiscatter, no warning); Glass, Refraction and Metallic take Beckmann too.
    for dist, key in (('BECKMANN', "beckmann"), ('ASHIKHMIN_SHIRLEY', "ashikhmin_shirley")):
        node.distribution = dist
        (closure,), warnings, _ = closures_of(mat)
        assert not warnings and closure[2][key][0] == 1.0 and "multiscatter" not in closure[2]
    for node_type, kind in (("ShaderNodeBsdfGlass", "glass"), ("ShaderNodeBsdfRefraction", "refraction"),
                            ("ShaderNodeBsdfMetallic", "metallic")):
        m, n = ms.bsdf_material(kind, node_type, Roughness=0.3)
        n.distribution = 'BECKMANN'
        (c,), warnings, _ = closures_of(m)
        assert c[0] == kind and not warnings and c[2]["beckmann"][0] == 1.0
        assert "multiscatter" not in c[2] and "ashikhmin_shirley" not in c[2]
    node.inputs["Roughness"].default_value = 0.0  # a mirror is a mirror in any distribution
    (closure,), warnings, _ = closures_of(mat)
    assert not warnings and "ashikhmin_shirley" not in closure[2]


def test_nested_mix_and_add_multiply_weights():
    mat, nodes, links, out = ms.new_material("Nested")
    outer = nodes.new("ShaderNodeMixShader")
    outer.inputs["Fac"].default_value = 0.25
    add = nodes.new("ShaderNodeAddShader")
    inner = nodes.new("ShaderNodeMixShader")
    inner.inputs["Fac"].default_value = 0.6
    d = nodes.new("ShaderNodeBsdfDiffuse")
    g = nodes.new("ShaderNodeBsdfGlossy")
    e = nodes.new("ShaderNodeEmission")
    t = nodes.new("ShaderNodeBsdfTransparent")
    link(mat.node_tree, outer.outputs[0], out.inputs["Surface"])
    link(mat.node_tree, add.outputs[0], outer.inputs[1])
    link(mat.node_tree, t.outputs[0], outer.inputs[2])
    link(mat.node_tree, d.outputs[0], add.inputs[0])
    link(mat.node_tree, inner.outputs[0], add.inputs[1])
    link(mat.node_tree, g.outputs[0], inner.inputs[1])
    link(mat.node_tree, e.outputs[0], inner.inputs[2])
    closures, warnings, _ = closures_of(mat)
    assert not warnings
    weights = {c[0]: weight_of(c)[0] for c in closures}
    assert weights == approx({"diffuse": 0.75, "glossy": 0.75 * 0.4, "emission": 0.75 * 0.6,
                              "transparent": 0.25})


def test_textured_mix_factor_is_computed_per_point():
    mat = ms.mix_diffuse_glossy("TexMix", 0.5)
    tree = mat.node_tree
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = ms.checker_image("Fac", 2, colorspace="Non-Color")
    mix = next(n for n in tree.nodes if n.type == 'MIX_SHADER')
    link(tree, tex.outputs["Color"], mix.inputs["Fac"])
    data, warnings = compile_(mat)
    assert not warnings
    names = [op[0] for op in data.program]
    # uv → image → luminance (colour into a value input) → clamp → 1 - fac.
    assert names.count("uv") == 1 and names.count("image") == 1 and "rgb_to_bw" in names
    closures, regs = run(data.program)
    assert all(isinstance(c[1], Sym) for c in closures)


def test_principled_inputs_alpha_and_emission():
    mat, node = ms.bsdf_material(
        "P", "ShaderNodeBsdfPrincipled", Base_Color=(0.8, 0.5, 0.2, 1), Metallic=0.3,
        Roughness=0.35, IOR=1.45, Transmission_Weight=0.5, Specular_IOR_Level=0.7,
        Specular_Tint=(1, 0.9, 0.8, 1), Alpha=0.75, Emission_Color=(1, 0.5, 0, 1),
        Emission_Strength=2.0)
    closures, warnings, _ = closures_of(mat)
    assert not warnings
    by_kind = {c[0]: c for c in closures}
    assert sorted(by_kind) == ["emission", "principled", "transparent"]
    assert weight_of(by_kind["transparent"]) == approx((0.25,) * 3)
    assert weight_of(by_kind["principled"]) == approx((0.75,) * 3)
    assert weight_of(by_kind["emission"]) == approx((0.75,) * 3)
    assert by_kind["emission"][2]["color"][:3] == approx((2.0, 1.0, 0.0))
    p = by_kind["principled"][2]
    assert p["base_color"][:3] == approx((0.8, 0.5, 0.2))
    values = {k: p[k][0] for k in ("metallic", "roughness", "ior", "transmission",
                                   "specular_level")}
    assert values == approx({"metallic": 0.3, "roughness": 0.35, "ior": 1.45,
                             "transmission": 0.5, "specular_level": 0.7})
    assert p["specular_tint"][:3] == approx((1, 0.9, 0.8))


def test_principled_sheen_subsurface_and_coat_are_passed():
    mat, node = ms.bsdf_material("Layers", "ShaderNodeBsdfPrincipled", Coat_Weight=0.5,
                                 Sheen_Weight=0.2, Subsurface_Weight=1.0, Coat_IOR=1.7)
    (closure,), warnings, _ = closures_of(mat)
    assert closure[0] == "principled"
    assert warnings == []  # the core layers the coat and the sheen and walks the subsurface
    p = closure[2]
    assert p["subsurface_weight"][0] == approx(1.0)
    assert p["sheen_weight"][0] == approx(0.2) and p["sheen_roughness"][0] == approx(0.5)
    assert p["coat_weight"][0] == approx(0.5) and p["coat_ior"][0] == approx(1.7)
    assert p["coat_roughness"][0] == approx(0.03) and "coat_normal" not in p
    node.inputs["Coat Weight"].default_value = 0.0  # no coat: none of its inputs
    (closure,), _, _ = closures_of(mat)
    assert not any(k.startswith("coat") for k in closure[2])



def test_subsurface_inputs_and_method_reach_the_core():
    # Principled: the group's inputs and the method (Burley 0, Random Walk 1, Skin 2); the
    # Subsurface Scattering node: a closure of its own.
    mat, node = ms.bsdf_material("Skin", "ShaderNodeBsdfPrincipled", Subsurface_Weight=0.7, Subsurface_Scale=0.2)
    node.subsurface_method = "RANDOM_WALK_SKIN"  # (Subsurface IOR is only found by name then)
    node.inputs["Subsurface IOR"].default_value = 1.3
    for method, number in (("RANDOM_WALK", 1.0), ("RANDOM_WALK_SKIN", 2.0), ("BURLEY", 0.0)):
        node.subsurface_method = method
        (closure,), warnings, _ = closures_of(mat)
        p = closure[2]
        assert p["subsurface_method"][0] == number
        assert p["subsurface_scale"][0] == approx(0.2)
        assert method != "RANDOM_WALK_SKIN" or p["subsurface_ior"][0] == approx(1.3)
        assert p["subsurface_radius"][:3] == approx(tuple(node.inputs["Subsurface Radius"].default_value))
        assert not warnings
    mat, node = ms.bsdf_material("Wax", "ShaderNodeSubsurfaceScattering", Scale=0.3, IOR=1.5, Roughness=0.4,
                                 Anisotropy=0.2)
    (closure,), warnings, _ = closures_of(mat)
    assert closure[0] == "subsurface" and not warnings
    values = {k: closure[2][k][0] for k in ("scale", "ior", "roughness", "anisotropy", "method")}
    assert values == approx({"scale": 0.3, "ior": 1.5, "roughness": 0.4, "anisotropy": 0.2, "method": 1.0})
    node.falloff = "RANDOM_WALK_SKIN"  # no Roughness: the entry's is fixed
    (closure,), warnings, _ = closures_of(mat)
    assert closure[2]["method"][0] == 2.0 and "roughness" not in closure[2] and not warnings


def test_principled_coat_normal_is_its_own():
    # A normal map on Coat Normal only: the coat gets it, the base keeps the shading normal.
    mat, node = ms.bsdf_material("Coat normal", "ShaderNodeBsdfPrincipled", Coat_Weight=1.0)
    tree = mat.node_tree
    nm = tree.nodes.new("ShaderNodeNormalMap")
    nm.inputs["Color"].default_value = (0.7, 0.5, 1.0, 1.0)
    tree.links.new(nm.outputs["Normal"], node.inputs["Coat Normal"])
    data, warnings = compile_(mat, uv_sets=UvSets())
    (nmap,) = [op for op in data.program if op[0] == "normal_map"]
    (closure,) = [op for op in data.program if op[0] == "closure"]
    assert closure[3]["coat_normal"] == nmap[1] and "normal" not in closure[3]


# ---------------------------------------------------------------- graph structure

def make_group(name="Tint"):
    """A node group: Color in → Mix (multiply by a constant, Fac from a second input) → out."""
    group = bpy.data.node_groups.new(name, "ShaderNodeTree")
    group.interface.new_socket("Color", in_out='INPUT', socket_type='NodeSocketColor')
    group.interface.new_socket("Amount", in_out='INPUT', socket_type='NodeSocketFloat')
    group.interface.new_socket("Color", in_out='OUTPUT', socket_type='NodeSocketColor')
    gin = group.nodes.new("NodeGroupInput")
    gout = group.nodes.new("NodeGroupOutput")
    mix = group.nodes.new("ShaderNodeMixRGB")
    mix.blend_type = 'MULTIPLY'
    mix.inputs["Color2"].default_value = (0.5, 0.25, 1.0, 1)
    group.links.new(gin.outputs[0], mix.inputs["Color1"])
    group.links.new(gin.outputs[1], mix.inputs["Fac"])
    group.links.new(mix.outputs[0], gout.inputs[0])
    return group


def test_node_groups_are_flattened_and_nest():
    group = make_group()
    mat, nodes, links, out = ms.new_material("Grouped")
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(d.outputs[0], out.inputs["Surface"])
    g = nodes.new("ShaderNodeGroup")
    g.node_tree = group
    g.inputs[0].default_value = (0.8, 0.8, 0.8, 1)
    g.inputs[1].default_value = 1.0
    links.new(g.outputs[0], d.inputs["Color"])
    (closure,), warnings, _ = closures_of(mat)
    assert not warnings
    assert closure[2]["color"][:3] == approx((0.4, 0.2, 0.8))
    # A group inside a group, its input linked from the outer tree.
    outer = bpy.data.node_groups.new("Outer", "ShaderNodeTree")
    outer.interface.new_socket("C", in_out='INPUT', socket_type='NodeSocketColor')
    outer.interface.new_socket("C", in_out='OUTPUT', socket_type='NodeSocketColor')
    oin, oout = outer.nodes.new("NodeGroupInput"), outer.nodes.new("NodeGroupOutput")
    inner = outer.nodes.new("ShaderNodeGroup")
    inner.node_tree = group
    inner.inputs[1].default_value = 0.5
    outer.links.new(oin.outputs[0], inner.inputs[0])
    outer.links.new(inner.outputs[0], oout.inputs[0])
    g.node_tree = outer
    links.new(g.outputs[0], d.inputs["Color"])  # new sockets: link again
    rgb = nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (1.0, 1.0, 0.5, 1)
    links.new(rgb.outputs[0], g.inputs[0])
    (closure,), warnings, _ = closures_of(mat)
    assert not warnings
    expected = tuple(c * (0.5 + 0.5 * k) for c, k in zip((1.0, 1.0, 0.5), (0.5, 0.25, 1.0)))
    assert closure[2]["color"][:3] == approx(expected)


def test_aov_outputs_inside_nested_groups():
    """AOV Output nodes in node groups, nested and unlinked ones too, write as Cycles' expanded
    groups do, each group's Group Input reading its own node's inputs; a muted group's do not."""
    inner = bpy.data.node_groups.new("AovInner", "ShaderNodeTree")
    inner.interface.new_socket("C", in_out='INPUT', socket_type='NodeSocketColor')
    iin = inner.nodes.new("NodeGroupInput")
    col = inner.nodes.new("ShaderNodeOutputAOV")
    col.aov_name = "col"
    inner.links.new(iin.outputs[0], col.inputs["Color"])
    outer = bpy.data.node_groups.new("AovOuter", "ShaderNodeTree")
    outer.interface.new_socket("V", in_out='INPUT', socket_type='NodeSocketFloat')
    oin = outer.nodes.new("NodeGroupInput")
    val = outer.nodes.new("ShaderNodeOutputAOV")
    val.aov_name = "val"
    outer.links.new(oin.outputs[0], val.inputs["Value"])
    nested = outer.nodes.new("ShaderNodeGroup")
    nested.node_tree = inner
    nested.inputs[0].default_value = (0.1, 0.2, 0.3, 1.0)
    mat, nodes, links, out = ms.new_material("AovGroups")
    links.new(nodes.new("ShaderNodeBsdfDiffuse").outputs[0], out.inputs["Surface"])
    g = nodes.new("ShaderNodeGroup")  # linked to nothing: Cycles still writes its AOVs
    g.node_tree = outer
    g.inputs[0].default_value = 0.75
    uv_sets = UvSets()
    uv_sets.aovs = {"col": (0, 'COLOR'), "val": (1, 'VALUE')}

    def written(data):  # (slot, kind, the value's register just before the op)
        return sorted((op[3], op[4], run(data.program[:i])[1][op[2]])
                      for i, op in enumerate(data.program) if op[0] == "aov_output")

    data, warnings = compile_(mat, uv_sets=uv_sets)
    assert not warnings
    assert written(data) == [(0, 'COLOR', approx((0.1, 0.2, 0.3, 1.0))), (1, 'VALUE', approx((0.75,) * 3 + (1.0,)))]
    # The same group twice: each instance writes with its own inputs.
    g2 = nodes.new("ShaderNodeGroup")
    g2.node_tree = outer
    g2.inputs[0].default_value = 0.25
    data, _ = compile_(mat, uv_sets=uv_sets)
    assert [w[2][0] for w in written(data) if w[1] == 'VALUE'] == approx(sorted([0.75, 0.25]))
    g2.mute = True
    nested.mute = True
    data, _ = compile_(mat, uv_sets=uv_sets)
    assert written(data) == [(1, 'VALUE', approx((0.75,) * 3 + (1.0,)))]


def test_shader_group_and_reroutes_and_muting():
    group = bpy.data.node_groups.new("Shaders", "ShaderNodeTree")
    group.interface.new_socket("Fac", in_out='INPUT', socket_type='NodeSocketFloat')
    group.interface.new_socket("Shader", in_out='OUTPUT', socket_type='NodeSocketShader')
    gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    mix = group.nodes.new("ShaderNodeMixShader")
    d = group.nodes.new("ShaderNodeBsdfDiffuse")
    g = group.nodes.new("ShaderNodeBsdfGlossy")
    group.links.new(gin.outputs[0], mix.inputs["Fac"])
    group.links.new(d.outputs[0], mix.inputs[1])
    group.links.new(g.outputs[0], mix.inputs[2])
    group.links.new(mix.outputs[0], gout.inputs[0])
    mat, nodes, links, out = ms.new_material("ShaderGroup")
    node = nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.inputs[0].default_value = 0.3
    # Surface ← reroute ← reroute ← group
    r1, r2 = nodes.new("NodeReroute"), nodes.new("NodeReroute")
    links.new(node.outputs[0], r1.inputs[0])
    links.new(r1.outputs[0], r2.inputs[0])
    links.new(r2.outputs[0], out.inputs["Surface"])
    closures, warnings, _ = closures_of(mat)
    assert not warnings
    assert {c[0]: weight_of(c)[0] for c in closures} == approx({"diffuse": 0.7, "glossy": 0.3})
    # A muted Mix Shader passes its first shader input through.
    mix.mute = True
    closures, warnings, _ = closures_of(mat)
    assert [c[0] for c in closures] == ["diffuse"] and weight_of(closures[0]) == (1, 1, 1)
    mix.mute = False
    # A muted link is no link: the Fac default (0.5) applies.
    group.links[0].is_muted = True
    closures, _, _ = closures_of(mat)
    assert {c[0]: weight_of(c)[0] for c in closures} == approx({"diffuse": 0.5, "glossy": 0.5})


def test_cycle_warns_once_and_falls_back():
    mat, nodes, links, out = ms.new_material("Loop")
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(d.outputs[0], out.inputs["Surface"])
    a, b = nodes.new("ShaderNodeMixRGB"), nodes.new("ShaderNodeMixRGB")
    links.new(a.outputs[0], b.inputs["Color1"])
    links.new(b.outputs[0], a.inputs["Color1"])
    links.new(a.outputs[0], d.inputs["Color"])
    closures, warnings, _ = closures_of(mat)
    assert len(warnings) == 1 and "Loop" in warnings[0]
    assert len(closures) == 1 and closures[0][0] == "diffuse"


def test_unsupported_nodes_warn_once_naming_each_and_fall_back():
    mat, nodes, links, out = ms.new_material("Odd")
    mix = nodes.new("ShaderNodeMixShader")
    spec = nodes.new("ShaderNodeEeveeSpecular")  # EEVEE only: no closure (black), as Cycles
    spec.inputs["Base Color"].default_value = (0.1, 0.6, 0.2, 1)
    hair = nodes.new("ShaderNodeBackground")  # a world shader in a material: has a Color input too
    d = nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (0.3, 0.3, 0.3, 1)
    hue = nodes.new("ShaderNodeAmbientOcclusion")  # supported: traced, no fallback
    hue.inputs["Color"].default_value = (0.9, 0.1, 0.1, 1)
    links.new(hue.outputs["Color"], d.inputs["Color"])
    ramp = nodes.new("ShaderNodeShaderToRGB")  # EEVEE only: dropped, as in Cycles (the Fac's own value)
    links.new(ramp.outputs["Alpha"], mix.inputs["Fac"])
    mix.inputs["Fac"].default_value = 0.4
    add = nodes.new("ShaderNodeAddShader")
    links.new(spec.outputs[0], add.inputs[0])
    links.new(d.outputs[0], add.inputs[1])
    links.new(add.outputs[0], mix.inputs[1])
    links.new(hair.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    closures, warnings, _ = closures_of(mat)
    assert len(warnings) == 1
    for name in ("Odd", "Specular BSDF", "Background", "Shader to RGB"):
        assert name in warnings[0], (name, warnings[0])
    assert "Ambient Occlusion" not in warnings[0]
    traced = [c for c in closures if isinstance(c[2]["color"], Sym)]
    assert len(traced) == 1 and traced[0][2]["color"].op[0] == "ambient_occlusion"
    colors = sorted((tuple(round(x, 4) for x in c[2]["color"][:3]), round(weight_of(c)[0], 4))
                    for c in closures if c not in traced)
    assert all(c[0] == "diffuse" for c in closures)
    assert colors == [(tuple(round(x, 4) for x in hair.inputs["Color"].default_value[:3]), 0.4)]


def test_point_density_on_a_surface_warns_and_reads_zero():
    """The Point Density texture works in volumes only, as in Cycles 4.5: on a surface one
    warning names the rule and it reads Density 0 / Color black, not its consumer's own value
    (test_point_density.py covers it in volumes)."""
    mat, nodes, links, out = ms.new_material("Smoke")
    vol = nodes.new("ShaderNodeVolumePrincipled")
    pd = nodes.new("ShaderNodeTexPointDensity")
    links.new(pd.outputs["Density"], vol.inputs["Density"])
    links.new(pd.outputs["Color"], vol.inputs["Color"])
    links.new(vol.outputs[0], out.inputs["Volume"])
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(pd.outputs["Color"], d.inputs["Color"])
    links.new(d.outputs[0], out.inputs["Surface"])
    (closure,), warnings, _ = closures_of(mat)
    assert len(warnings) == 1 and "Point Density texture works in volumes only" in warnings[0], warnings
    assert closure[0] == "diffuse" and tuple(closure[2]["color"][:3]) == approx((0.0, 0.0, 0.0))


def test_value_into_shader_socket_is_emission_and_no_output_is_black():
    mat, nodes, links, out = ms.new_material("Glow")
    rgb = nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (0.5, 1.0, 2.0, 1)
    links.new(rgb.outputs[0], out.inputs["Surface"])
    (closure,), warnings, _ = closures_of(mat)
    assert closure[0] == "emission" and closure[2]["color"][:3] == approx((0.5, 1.0, 2.0))
    mat.node_tree.nodes.remove(out)
    data, warnings = compile_(mat)
    assert data.program == [] and not warnings
    # Inactive outputs and EEVEE-only outputs are skipped.
    mat, nodes, links, out = ms.new_material("Targets")
    out.target = 'EEVEE'
    cyc = nodes.new("ShaderNodeOutputMaterial")
    cyc.target = 'CYCLES'
    links.new(nodes.new("ShaderNodeBsdfGlossy").outputs[0], cyc.inputs["Surface"])
    links.new(nodes.new("ShaderNodeBsdfDiffuse").outputs[0], out.inputs["Surface"])
    (closure,), _, _ = closures_of(mat)
    assert closure[0] == "glossy"


def test_volume_absorption_and_unsupported_volumes():
    mat, node = ms.bsdf_material("Beer", "ShaderNodeBsdfGlass")
    va = mat.node_tree.nodes.new("ShaderNodeVolumeAbsorption")
    va.inputs["Color"].default_value = (0.9, 0.4, 0.2, 1)
    va.inputs["Density"].default_value = 2.5
    mat.node_tree.links.new(va.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Volume"])
    data, warnings = compile_(mat)
    assert not warnings
    color, density = data.volume_absorption
    assert color == approx((0.9, 0.4, 0.2)) and density == approx(2.5)
    pv = mat.node_tree.nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Blackbody Intensity"].default_value = 0.5
    mat.node_tree.links.new(pv.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Volume"])
    data, warnings = compile_(mat)
    assert data.volume_absorption is None and data.volume is not None
    # Blackbody (constant temperature, 1000 K): folded into a homogeneous, reddish emission.
    assert not warnings and data.volume["emission"][0] > data.volume["emission"][2] >= 0.0
    info = mat.node_tree.nodes.new("ShaderNodeHoldout")  # no volume meaning
    mat.node_tree.links.new(info.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Volume"])
    data, warnings = compile_(mat)
    assert data.volume is None and len(warnings) == 1 and "Holdout" in warnings[0]


def test_register_allocation_reuses_registers():
    mat, nodes, links, out = ms.new_material("Long")
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(d.outputs[0], out.inputs["Surface"])
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = ms.checker_image("C", 2)
    prev = tex.outputs["Color"]
    for i in range(150):  # a long chain: far more values than registers, few live at once
        m = nodes.new("ShaderNodeMath")
        m.operation = 'ADD'
        m.inputs[1].default_value = 0.001 * i
        links.new(prev, m.inputs[0])
        prev = m.outputs[0]
    links.new(prev, d.inputs["Color"])
    data, warnings = compile_(mat)
    assert not warnings
    regs = {op[1] for op in data.program if op[0] != "closure"}
    assert max(regs) < MAX_REGISTERS
    assert sum(op[0] == "math" for op in data.program) == 150


def test_schlick_option_and_scene_export():
    mat = ms.mix_diffuse_glossy("Mix", 0.5)
    scene = bpy.context.scene
    scene.pathlight.use_schlick_fresnel = True
    ms.add_plane("P", 1.0, mat)
    ms.add_camera((0, 0, 3), (0, 0, 0))
    warnings = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    (m,) = [m for m in data.materials if m.name == "Mix"]
    assert m.use_schlick is True and m.program


# ---------------------------------------------------------------- UVs through the export

def test_mesh_export_gathers_uvs_per_corner():
    img = ms.checker_image("C", 2)
    mat = ms.textured_material("T", img)
    obj = ms.add_plane("P", 2.0, mat)
    second = obj.data.uv_layers.new(name="Second")
    uv = np.array([[0.1 * i, 0.2 * i] for i in range(len(second.uv))], np.float32)
    second.uv.foreach_set("vector", uv.ravel())
    nm = mat.node_tree.nodes.new("ShaderNodeNormalMap")
    nm.uv_map = "Second"
    d = next(n for n in mat.node_tree.nodes if n.type == 'BSDF_DIFFUSE')
    mat.node_tree.links.new(nm.outputs[0], d.inputs["Normal"])
    ms.add_plane("NoUV", 1.0, mat, uv=False, location=(3, 0, 0))
    ms.add_camera((0, 0, 3), (0, 0, 0))
    warnings = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    mesh = next(m for m in data.meshes if m.name == "P")
    assert sorted(mesh.uvs) == [0, 1]
    tris = obj.data.loop_triangles
    loops = np.array([t.loops[:] for t in tris])
    active = np.array([obj.data.uv_layers["UVMap"].uv[i].vector[:] for i in loops.ravel()])
    assert mesh.uvs[0].shape == (len(tris), 3, 2) and mesh.uvs[0].dtype == np.float32
    assert mesh.uvs[0].reshape(-1, 2) == approx(active)
    assert mesh.uvs[1].reshape(-1, 2) == approx(uv[loops.ravel()])
    # The mesh without UV maps: one warning naming it, no uvs (the core reads (0, 0)).
    bare = next(m for m in data.meshes if m.name == "NoUV")
    assert bare.uvs == {}
    assert [w for w in warnings if "NoUV" in w and "UV map" in w]


def test_metallic_translucent_and_holdout_compile_without_fallbacks():
    mat, nodes, links, out = ms.new_material("Closures")
    metal = nodes.new("ShaderNodeBsdfMetallic")
    metal.fresnel_type = 'PHYSICAL_CONDUCTOR'
    mix = nodes.new("ShaderNodeMixShader")
    add = nodes.new("ShaderNodeAddShader")
    links.new(metal.outputs[0], mix.inputs[1])
    links.new(nodes.new("ShaderNodeBsdfTranslucent").outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], add.inputs[0])
    links.new(nodes.new("ShaderNodeHoldout").outputs[0], add.inputs[1])
    links.new(add.outputs[0], out.inputs["Surface"])
    data, warnings = compile_(mat)
    assert not warnings
    kinds = [op[1] for op in data.program if op[0] == "closure"]
    assert sorted(kinds) == ["holdout", "metallic", "translucent"]
    (params,) = [op[3] for op in data.program if op[0] == "closure" and op[1] == "metallic"]
    assert {"ior", "extinction", "physical", "multiscatter"} <= set(params)
    metal.inputs["Anisotropy"].default_value = 0.5
    metal.distribution = 'BECKMANN'
    data, warnings = compile_(mat)
    # Anisotropy is rendered (its tangent: Cycles' default, radial about Z), and Beckmann too.
    assert not warnings
    (params,) = [op[3] for op in data.program if op[0] == "closure" and op[1] == "metallic"]
    assert {"anisotropy", "rotation", "tangent", "beckmann"} <= set(params)
    (tangent,) = [op for op in data.program if op[0] == "tangent"]
    assert tangent[1] == params["tangent"] and tangent[2] == "Z"


def test_anisotropy_compiles_with_its_tangent():
    # Principled: the anisotropy group's keys, the linked Tangent node's tangent; Glossy: its own
    # keys and, unlinked, Cycles' default tangent. Neither warns; zero anisotropy adds nothing.
    mat, nodes, links, out = ms.new_material("Brushed")
    p = ms.set_inputs(nodes.new("ShaderNodeBsdfPrincipled"), Anisotropic=0.7, Anisotropic_Rotation=0.1)
    t = nodes.new("ShaderNodeTangent")
    t.direction_type = 'RADIAL'
    t.axis = 'X'
    links.new(t.outputs["Tangent"], p.inputs["Tangent"])
    g = ms.set_inputs(nodes.new("ShaderNodeBsdfGlossy"), Anisotropy=-0.4)
    mix = nodes.new("ShaderNodeMixShader")
    links.new(p.outputs[0], mix.inputs[1])
    links.new(g.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    data, warnings = compile_(mat)
    assert not warnings
    closures = {op[1]: op[3] for op in data.program if op[0] == "closure"}
    tangents = {op[1]: op[2] for op in data.program if op[0] == "tangent"}
    assert {"anisotropic", "anisotropic_rotation", "tangent"} <= set(closures["principled"])
    assert tangents[closures["principled"]["tangent"]] == "X"
    assert {"anisotropy", "rotation", "tangent"} <= set(closures["glossy"])
    assert tangents[closures["glossy"]["tangent"]] == "Z"
    p.inputs["Anisotropic"].default_value = 0.0
    g.inputs["Anisotropy"].default_value = 0.0
    data, warnings = compile_(mat)
    closures = {op[1]: op[3] for op in data.program if op[0] == "closure"}
    assert not warnings and "tangent" not in closures["principled"] and "tangent" not in closures["glossy"]


def test_thin_film_compiles_without_a_warning():
    mat, p = ms.bsdf_material("Bubble", "ShaderNodeBsdfPrincipled", Thin_Film_Thickness=500.0,
                              Thin_Film_IOR=1.4)
    data, warnings = compile_(mat)
    assert not warnings
    (params,) = [op[3] for op in data.program if op[0] == "closure"]
    assert {"thin_film_thickness", "thin_film_ior"} <= set(params)
    consts = {op[1]: op[2] for op in data.program if op[0] == "const"}
    assert consts[params["thin_film_thickness"]][0] == 500.0
    p.inputs["Thin Film Thickness"].default_value = 0.0
    data, warnings = compile_(mat)
    (params,) = [op[3] for op in data.program if op[0] == "closure"]
    assert not warnings and "thin_film_thickness" not in params


@pytest.mark.parametrize("parametrization", ["COLOR", "MELANIN", "ABSORPTION"])
def test_huang_hair_compiles_its_own_inputs(parametrization):
    # Huang's node hides Radial Roughness and Coat (bpy then cannot find them by name: the
    # compiler once raised KeyError here); it compiles to the core's Huang closure with Aspect
    # Ratio and the three lobe weights, without a warning (it used to fall back to Chiang's).
    mat, node = ms.bsdf_material("H", "ShaderNodeBsdfHairPrincipled")
    node.model = 'HUANG'
    node.parametrization = parametrization
    ms.set_inputs(node, Aspect_Ratio=0.7, Reflection=0.5, Transmission=0.25, Secondary_Reflection=2.0)
    (closure,), warnings, _ = closures_of(mat)
    mode = {"COLOR": "color", "MELANIN": "melanin", "ABSORPTION": "absorption"}[parametrization]
    assert closure[0] == "principled_hair_huang_" + mode
    params = closure[2]
    assert "radial_roughness" not in params and "coat" not in params
    assert params["aspect_ratio"][0] == approx(0.7) and params["r"][0] == approx(0.5)
    assert params["tt"][0] == approx(0.25) and params["trt"][0] == approx(2.0)
    assert not warnings