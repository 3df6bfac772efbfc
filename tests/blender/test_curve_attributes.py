"""Generic attributes of Curves objects (issue 23) against Cycles in the same bpy: the
Attribute and Color Attribute nodes reading point-domain values (linear along the strand
between its keys) and curve-domain ones (one per strand), the UV of geometry-nodes hair
(`surface_uv_coordinate`, Cycles' standard UV), and a missing attribute, on thick curves and
ribbons; seen directly through emission (test_hair.py's patch of 7 strands, unlit)."""

import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon
import material_scenes as ms
from test_hair import add_hair, assert_channels_agree, hair_scene, unlit

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

STRANDS, KEYS = 7, 5


def add_attributes(obj):
    """Random values on the hair: 'col' (FLOAT_COLOR per point, alpha too), 'bcol'
    (BYTE_COLOR per point), 'vec' (FLOAT_VECTOR per point), 'rand' (FLOAT per strand),
    'surface_uv_coordinate' (FLOAT2 per strand, as geometry-nodes hair has) and 'puv' (FLOAT2
    per point)."""
    rng = np.random.default_rng(23)
    curves = obj.data
    n = STRANDS * KEYS
    for name, kind, domain, field, width, size in (
            ("col", 'FLOAT_COLOR', 'POINT', "color", 4, n), ("bcol", 'BYTE_COLOR', 'POINT', "color", 4, n),
            ("vec", 'FLOAT_VECTOR', 'POINT', "vector", 3, n), ("rand", 'FLOAT', 'CURVE', "value", 1, STRANDS),
            ("surface_uv_coordinate", 'FLOAT2', 'CURVE', "vector", 2, STRANDS),
            ("puv", 'FLOAT2', 'POINT', "vector", 2, n)):
        attr = curves.attributes.new(name, kind, domain)
        attr.data.foreach_set(field, rng.uniform(0.1, 1.0, size * width).astype(np.float32))
    return obj


def scene(material_fn, shape):
    def build():
        s = unlit(hair_scene(material_fn))()
        s.cycles_curves.shape = shape
        s.cycles_curves.subdivisions = 2
        add_attributes(bpy.data.objects["Hair"])
        return s
    return build


def emission(nodes, links, out, color_socket):
    em = nodes.new("ShaderNodeEmission")
    links.new(color_socket, em.inputs["Color"])
    links.new(em.outputs[0], out.inputs["Surface"])


def attribute(nodes, name, kind='GEOMETRY'):
    node = nodes.new("ShaderNodeAttribute")
    node.attribute_name = name
    node.attribute_type = kind
    return node


def point_colour_material():
    """The point colour 'col' along the strands."""
    mat, nodes, links, out = ms.new_material("PointColour")
    emission(nodes, links, out, attribute(nodes, "col").outputs["Color"])
    return mat


def mixed_material():
    """R: the per-strand float 'rand' (Fac); G: the byte colour 'bcol' (Color Attribute node,
    its green); B: the point vector 'vec' (its z)."""
    mat, nodes, links, out = ms.new_material("Mixed")
    bcol = nodes.new("ShaderNodeVertexColor")
    bcol.layer_name = "bcol"
    sep_c = nodes.new("ShaderNodeSeparateXYZ")
    links.new(bcol.outputs["Color"], sep_c.inputs[0])
    sep_v = nodes.new("ShaderNodeSeparateXYZ")
    links.new(attribute(nodes, "vec").outputs["Vector"], sep_v.inputs[0])
    comb = nodes.new("ShaderNodeCombineXYZ")
    links.new(attribute(nodes, "rand").outputs["Fac"], comb.inputs["X"])
    links.new(sep_c.outputs["Y"], comb.inputs["Y"])
    links.new(sep_v.outputs["Z"], comb.inputs["Z"])
    emission(nodes, links, out, comb.outputs[0])
    return mat


def missing_material():
    """An attribute the hair lacks: R its Fac + 0.3, G its Alpha x 0.5 + 0.3 (Cycles: alpha 1),
    B the point alpha of 'col'."""
    mat, nodes, links, out = ms.new_material("Missing")
    nope = attribute(nodes, "nope")
    comb = nodes.new("ShaderNodeCombineXYZ")
    for socket, target in ((nope.outputs["Fac"], "X"), (nope.outputs["Alpha"], "Y")):
        ma = nodes.new("ShaderNodeMath")
        ma.operation = 'MULTIPLY_ADD'
        ma.inputs[1].default_value = 0.5
        ma.inputs[2].default_value = 0.3
        links.new(socket, ma.inputs[0])
        links.new(ma.outputs[0], comb.inputs[target])
    links.new(attribute(nodes, "col").outputs["Alpha"], comb.inputs["Z"])
    emission(nodes, links, out, comb.outputs[0])
    return mat


def unnamed_colour_material():
    """An unnamed Color Attribute node + 0.3: Cycles gives Curves objects no default colour
    attribute (checked: 0, though the hair has two colour attributes)."""
    mat, nodes, links, out = ms.new_material("Unnamed")
    vc = nodes.new("ShaderNodeVertexColor")
    add = nodes.new("ShaderNodeVectorMath")
    add.operation = 'ADD'
    add.inputs[1].default_value = (0.3, 0.3, 0.3)
    links.new(vc.outputs["Color"], add.inputs[0])
    emission(nodes, links, out, add.outputs[0])
    return mat


def uv_material():
    """R: Texture Coordinate UV's u; G: the UV Map node named 'surface_uv_coordinate', its v;
    B: a UV Map node named 'puv' (per point, interpolated), its u."""
    mat, nodes, links, out = ms.new_material("HairUV")
    tc = nodes.new("ShaderNodeTexCoord")
    uvmap = nodes.new("ShaderNodeUVMap")
    uvmap.uv_map = "surface_uv_coordinate"
    sep_t = nodes.new("ShaderNodeSeparateXYZ")
    sep_u = nodes.new("ShaderNodeSeparateXYZ")
    links.new(tc.outputs["UV"], sep_t.inputs[0])
    links.new(uvmap.outputs["UV"], sep_u.inputs[0])
    comb = nodes.new("ShaderNodeCombineXYZ")
    links.new(sep_t.outputs["X"], comb.inputs["X"])
    links.new(sep_u.outputs["Y"], comb.inputs["Y"])
    puv = nodes.new("ShaderNodeUVMap")
    puv.uv_map = "puv"
    sep_p = nodes.new("ShaderNodeSeparateXYZ")
    links.new(puv.outputs["UV"], sep_p.inputs[0])
    links.new(sep_p.outputs["X"], comb.inputs["Z"])
    emission(nodes, links, out, comb.outputs[0])
    return mat


def uv_texture_material():
    """An Image Texture (a smooth 16x16 gradient, Linear) at each strand's
    `surface_uv_coordinate`: the emitter's texture, as geometry-nodes hair is coloured."""
    mat, nodes, links, out = ms.new_material("HairTexture")
    y, x = np.mgrid[0:16, 0:16] / 15.0
    px = np.stack([x, y, 0.5 + 0.4 * np.sin(6.0 * x * y), np.ones_like(x)], -1)
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = ms.pixel_image("HairGradient", px)
    links.new(nodes.new("ShaderNodeTexCoord").outputs["UV"], tex.inputs["Vector"])
    emission(nodes, links, out, tex.outputs["Color"])
    return mat


def test_curve_attributes_export_arrays():
    """Only what the material reads: point attributes (N, 4) per point, curve ones (C, 4) per
    strand, the standard UV from the FLOAT2 curve attribute; a missing name warns once."""
    from addon.export.curves import collect_curves
    ms.studio(size=16)
    obj = add_attributes(add_hair("Hair", mixed_material(), strands=STRANDS, keys=KEYS))
    names = {0: ("attr", "col"), 1: ("color", "bcol"), 2: ("attr", "rand"), 3: "", 4: ("attr", "nope"),
             5: ("color", "rand"), 6: "puv"}
    warn = Warnings()
    (c,) = collect_curves(bpy.context.evaluated_depsgraph_get(), warn, uv_names=lambda materials: names)
    n = STRANDS * KEYS
    assert sorted(c.point_attributes) == [0, 1] and sorted(c.colours) == [2, 4] and sorted(c.uvs) == [3]
    # A missing Attribute node attribute: 0 with alpha 1 (Cycles' svm_node_attr).
    np.testing.assert_array_equal(c.colours[4], np.tile([0.0, 0.0, 0.0, 1.0], (STRANDS, 1)))
    col = np.empty(n * 4, np.float32)
    obj.data.attributes["col"].data.foreach_get("color", col)
    np.testing.assert_array_equal(c.point_attributes[0], col.reshape(n, 4))
    assert c.point_attributes[1].shape == (n, 4) and c.point_attributes[1].dtype == np.float32
    rand = np.empty(STRANDS, np.float32)
    obj.data.attributes["rand"].data.foreach_get("value", rand)
    np.testing.assert_array_equal(c.colours[2], np.column_stack([rand, rand, rand, np.ones(STRANDS)]))
    uv = np.empty(STRANDS * 2, np.float32)
    obj.data.attributes["surface_uv_coordinate"].data.foreach_get("vector", uv)
    np.testing.assert_array_equal(c.uvs[3], uv.reshape(-1, 2))
    puv = np.empty(n * 2, np.float32)
    obj.data.attributes["puv"].data.foreach_get("vector", puv)
    assert sorted(c.point_uvs) == [6]
    np.testing.assert_array_equal(c.point_uvs[6], puv.reshape(-1, 2))
    # 'nope' does not exist and 'rand' is no colour attribute: one warning naming both.
    assert len(warn) == 1 and "'nope'" in list(warn)[0] and "'rand'" in list(warn)[0], list(warn)
    # Without a material that reads them, nothing is exported.
    (c,) = collect_curves(bpy.context.evaluated_depsgraph_get(), Warnings(), uv_names=lambda materials: {})
    assert not c.point_attributes and not c.colours and not c.uvs and not c.point_uvs


@pytest.mark.parametrize("shape", ['THICK', 'RIBBONS'])
@pytest.mark.parametrize("case", ["point_colour", "mixed", "missing", "unnamed_colour", "uv",
                                  "uv_texture"])
def test_curve_attributes_match_cycles(case, shape):
    material = {"point_colour": point_colour_material, "mixed": mixed_material,
                "missing": missing_material, "unnamed_colour": unnamed_colour_material,
                "uv": uv_material, "uv_texture": uv_texture_material}[case]
    ours, cycles = ms.render_pair(scene(material, shape), 32)
    assert_channels_agree(ours, cycles)
