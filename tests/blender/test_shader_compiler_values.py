"""The shader node compiler's value and texture nodes: images, UVs, Mapping, Normal Map, math,
colour and vector nodes, ramps and curves, bump, light path, volumes; and, last, every program of
both shader-compiler test files handed to the core (when built), which validates it."""

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
import test_shader_compiler as base  # noqa: E402  (its setups, for the core test)


# ---------------------------------------------------------------- textures and coordinates

def textured_principled(name, image, **tex_settings):
    mat, nodes, links, out = ms.new_material(name)
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    for key, value in tex_settings.items():
        setattr(tex, key, value)
    links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    links.new(bsdf.outputs[0], out.inputs["Surface"])
    return mat, tex, bsdf


def test_textured_principled():
    img = ms.checker_image("Checker", 4)
    mat, tex, _ = textured_principled("Tex", img, interpolation='Closest', extension='EXTEND')
    images, uv_sets = ImageTable(), UvSets()
    data, warnings = compile_(mat, images, uv_sets)
    assert not warnings
    ops = {op[0]: op for op in data.program}
    assert ops["uv"][2] == 0 and uv_sets.names == [""] and data.uv_sets == {0: ""}
    image_op = ops["image"]
    assert image_op[2] == ops["uv"][1]  # reads the uv register
    assert image_op[3:] == (0, "CLOSEST", "EXTEND")
    (closure,) = [op for op in data.program if op[0] == "closure"]
    assert closure[3]["base_color"] == image_op[1]
    # The image once, as float RGBA (H, W, 4), row 0 = bottom: a byte sRGB image keeps its
    # encoded bytes (/255) for the core to filter before decoding, as Cycles does.
    (image,) = images.images
    assert image.pixels.shape == (4, 4, 4) and image.pixels.dtype == np.float32
    assert image.srgb
    byte = lambda c: np.round(np.array(c) * 255) / 255  # noqa: E731 (stored as bytes)
    assert image.pixels[0, 0, :3] == approx(byte((0.9, 0.9, 0.9)), rel=1e-6)  # bottom-left texel
    assert image.pixels[0, 1, :3] == approx(byte((0.1, 0.2, 0.6)), rel=1e-6)
    # A second material and node with the same image share it.
    mat2, _, _ = textured_principled("Tex2", img, interpolation='Linear')
    data2, _ = compile_(mat2, images, uv_sets)
    assert len(images.images) == 1
    assert [op for op in data2.program if op[0] == "image"][0][3:] == (0, "LINEAR", "REPEAT")


def test_interpolation_and_extension_pass_through():
    """Cubic, Smart (Cubic in Cycles' CPU kernel) and Mirror reach the core as they are, with no
    warning (they were approximated by Linear / Repeat before)."""
    img = ms.checker_image("C", 2)
    for interp, ext, expect in (('Cubic', 'CLIP', ("CUBIC", "CLIP")), ('Smart', 'MIRROR', ("CUBIC", "MIRROR")),
                                ('Closest', 'MIRROR', ("CLOSEST", "MIRROR"))):
        mat, _, _ = textured_principled(f"M{interp}", img, interpolation=interp, extension=ext)
        data, warnings = compile_(mat)
        assert [op for op in data.program if op[0] == "image"][0][4:] == expect
        assert not warnings, warnings


def test_image_colour_spaces_and_alpha():
    px = np.zeros((1, 2, 4), np.float32)
    px[0, 0] = (0.5, 0.25, 1.0, 0.5)
    px[0, 1] = (0.2, 0.2, 0.2, 1.0)
    srgb = ms.pixel_image("sRGB", px, "sRGB")
    data = ms.pixel_image("Data", px, "Non-Color")
    flt = ms.pixel_image("Float", px, "Linear Rec.709", float_buffer=True)
    images = ImageTable()
    loaded = {img.name: images.load(img, []) for img in (srgb, data, flt)}
    q = np.round(px * 255)  # byte images are stored as bytes
    # Byte sRGB: kept encoded, associated in bytes as Cycles does ((c * a) / 255, integer).
    assert loaded["sRGB"].srgb and not loaded["Data"].srgb and not loaded["Float"].srgb
    assert loaded["sRGB"].assoc[0, 0, :3] * 255 == approx(q[0, 0, :3] * q[0, 0, 3] // 255, abs=1e-3)
    assert loaded["sRGB"].assoc[0, 0, 3] == approx(q[0, 0, 3] / 255, rel=1e-6)
    assert loaded["sRGB"].assoc[0, 1, :3] == approx(q[0, 1, :3] / 255, rel=1e-6)
    # Non-Color: the raw values, not associated (Cycles does not associate data).
    assert loaded["Data"].assoc[0, 0] == approx(q[0, 0] / 255, rel=1e-5)
    # Float buffers are associated in Blender already: unchanged.
    assert loaded["Float"].assoc[0, 0] == approx(px[0, 0], rel=1e-5)


def test_alpha_output_uses_straight_colour_and_an_alpha_image():
    px = np.ones((2, 2, 4), np.float32)
    px[..., 3] = 0.25
    img = ms.pixel_image("Leaf", px, "sRGB")
    mat, tex, bsdf = textured_principled("Leaf", img)
    link(mat.node_tree, tex.outputs["Alpha"], bsdf.inputs["Alpha"])
    images = ImageTable()
    data, warnings = compile_(mat, images)
    assert not warnings
    assert sorted(i.name for i in images.images) == ["Leaf", "Leaf (alpha)"]
    # Color with Alpha linked: the associated texels, divided by alpha after filtering (the
    # op's last operand), as Cycles' NODE_IMAGE_ALPHA_UNASSOCIATE.
    color = next(k for k, i in enumerate(images.images) if i.name == "Leaf")
    color_op = next(op for op in data.program if op[0] == "image" and op[3] == color)
    assert color_op[-1] is True
    alpha = next(i for i in images.images if i.name == "Leaf (alpha)")
    assert alpha.pixels == approx(np.full((2, 2, 4), 64 / 255, np.float32), rel=1e-5)
    kinds = [c[0] for c in run(data.program)[0]]
    assert sorted(kinds) == ["principled", "transparent"]


def test_missing_image_is_magenta_and_warns():
    mat, tex, _ = textured_principled("NoImage", None)
    (closure,), warnings, _ = closures_of(mat)
    assert closure[2]["base_color"][:3] == (1.0, 0.0, 1.0)
    assert len(warnings) == 1 and "no image" in warnings[0]
    img = bpy.data.images.new("Missing", 4, 4)
    img.source = 'FILE'
    img.filepath = "/nonexistent/pathlight_missing.png"
    mat, tex, _ = textured_principled("Missing", img)
    (closure,), warnings, _ = closures_of(mat)
    assert closure[2]["base_color"][:3] == (1.0, 0.0, 1.0)
    assert len(warnings) == 1 and "cannot be read" in warnings[0]


def test_uv_map_node_and_texture_coordinates():
    mat, tex, _ = textured_principled("UVs", ms.checker_image("C", 2))
    tree = mat.node_tree
    uvmap = tree.nodes.new("ShaderNodeUVMap")
    uvmap.uv_map = "Second"
    link(tree, uvmap.outputs["UV"], tex.inputs["Vector"])
    uv_sets = UvSets()
    uv_sets.index("")  # another material took set 0
    data, warnings = compile_(mat, uv_sets=uv_sets)
    assert not warnings
    assert [op for op in data.program if op[0] == "uv"][0][2] == 1
    assert data.uv_sets == {1: "Second"} and uv_sets.names == ["", "Second"]
    # Texture Coordinate: UV is the active map; Object, Generated and Normal are the object's
    # (per instance in the core); Object coordinates of another object are that object's.
    coord = tree.nodes.new("ShaderNodeTexCoord")
    link(tree, coord.outputs["UV"], tex.inputs["Vector"])
    data, warnings = compile_(mat, uv_sets=uv_sets)
    assert not warnings and data.uv_sets == {0: ""}
    for output, op in (("Object", "object"), ("Generated", "generated"),
                       ("Normal", "object_normal")):
        link(tree, coord.outputs[output], tex.inputs["Vector"])
        data, warnings = compile_(mat, uv_sets=uv_sets)
        assert [op[0] for op in data.program][:2] == [op, "image"] and not warnings
    link(tree, coord.outputs["Object"], tex.inputs["Vector"])
    coord.object = bpy.data.objects.new("Elsewhere", None)  # another object: its inverse matrix
    coord.object.matrix_world = Matrix.Translation((1.0, 2.0, 3.0))
    data, warnings = compile_(mat, uv_sets=uv_sets)
    assert [op[0] for op in data.program][:3] == ["position", "mapping", "image"] and not warnings
    assert data.program[1][3][:, 3] == approx((-1.0, -2.0, -3.0))
    geometry = tree.nodes.new("ShaderNodeNewGeometry")
    link(tree, geometry.outputs["Position"], tex.inputs["Vector"])
    data, warnings = compile_(mat, uv_sets=uv_sets)
    assert not warnings and data.program[0][0] == "position"


@pytest.mark.parametrize("vector_type", ['POINT', 'TEXTURE', 'VECTOR', 'NORMAL'])
def test_mapping_matrix_matches_blender(vector_type):
    loc, rot, scale = (0.3, -0.2, 0.5), (0.4, -0.7, 1.1), (2.0, 0.5, -1.5)
    m = mapping_matrix(vector_type, loc, rot, scale).astype(np.float64)
    v = Vector((0.7, -0.4, 0.25))
    r = Euler(rot, 'XYZ').to_matrix()
    s = Matrix.Diagonal(scale)
    s_inv = Matrix.Diagonal([1 / x for x in scale])
    expected = {
        'POINT': r @ s @ v + Vector(loc),
        'TEXTURE': s_inv @ r.transposed() @ (v - Vector(loc)),
        'VECTOR': r @ s @ v,
        'NORMAL': r @ s_inv @ v,  # Blender normalises it; a Normal input does too
    }[vector_type]
    assert m[:, :3] @ np.array(v) + m[:, 3] == approx(tuple(expected), rel=1e-5)


def test_mapping_node_in_a_program():
    img = ms.checker_image("C", 2)
    mat = ms.textured_material("Mapped", img, mapping={"type": 'POINT', "Scale": (2, 3, 1),
                                                        "Location": (0.5, 0, 0)})
    data, warnings = compile_(mat)
    assert not warnings
    ops = {op[0]: op for op in data.program}
    assert ops["mapping"][2] == ops["uv"][1] and ops["image"][2] == ops["mapping"][1]
    m = np.asarray(ops["mapping"][3])
    assert m.shape == (3, 4) and m[0, 0] == approx(2) and m[1, 1] == approx(3)
    assert m[0, 3] == approx(0.5)


def test_normal_map():
    mat, nodes, links, out = ms.new_material("Bumpy")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = ms.checker_image("N", 2, colorspace="Non-Color")
    nm = nodes.new("ShaderNodeNormalMap")
    nm.uv_map = "Tangents"
    nm.inputs["Strength"].default_value = 0.7
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(tex.outputs["Color"], nm.inputs["Color"])
    links.new(nm.outputs["Normal"], d.inputs["Normal"])
    links.new(d.outputs[0], out.inputs["Surface"])
    uv_sets = UvSets()
    data, warnings = compile_(mat, uv_sets=uv_sets)
    assert not warnings
    ops = [op for op in data.program]
    (nmap,) = [op for op in ops if op[0] == "normal_map"]
    (closure,) = [op for op in ops if op[0] == "closure"]
    assert closure[3]["normal"] == nmap[1]
    assert nmap[4] == uv_sets.names.index("Tangents")
    image = next(op for op in ops if op[0] == "image")
    assert nmap[2] == image[1]
    regs = run(ops[:ops.index(nmap)])[1]  # registers are reused later
    assert regs[nmap[3]][0] == approx(0.7)  # strength
    # The image reads the active UV map, the tangents come from the named one.
    assert data.uv_sets == {0: "", 1: "Tangents"}
    # Strength 0: no normal map at all; object space: its own op, without warnings.
    nm.inputs["Strength"].default_value = 0.0
    data, _ = compile_(mat)
    assert not any(op[0] == "normal_map" for op in data.program)
    nm.inputs["Strength"].default_value = 1.0
    nm.space = 'OBJECT'
    data, warnings = compile_(mat)
    (nmap,) = [op for op in data.program if op[0] == "normal_map"]
    (closure,) = [op for op in data.program if op[0] == "closure"]
    assert closure[3]["normal"] == nmap[1] and nmap[5] == 'OBJECT' and not warnings


# ---------------------------------------------------------------- value nodes

def value_into_diffuse(build):
    """A diffuse whose Color is fed by build(tree, nodes) -> output socket; returns its
    colour register value from the interpreter (or the Sym) and the warnings."""
    mat, nodes, links, out = ms.new_material("Values")
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(d.outputs[0], out.inputs["Surface"])
    links.new(build(mat.node_tree, nodes), d.inputs["Color"])
    (closure,), warnings, data = closures_of(mat)
    return closure[2]["color"], warnings, data


def test_rgb_value_math_mix_invert_rgb_to_bw():
    def rgb(tree, nodes):
        n = nodes.new("ShaderNodeRGB")
        n.outputs[0].default_value = (0.2, 0.4, 0.6, 1)
        return n.outputs[0]
    color, warnings, data = value_into_diffuse(rgb)
    assert color[:3] == approx((0.2, 0.4, 0.6)) and not warnings
    assert [op[0] for op in data.program] == ["const", "closure"]  # folded

    def math(tree, nodes):
        v = nodes.new("ShaderNodeValue")
        v.outputs[0].default_value = 0.5
        m = nodes.new("ShaderNodeMath")
        m.operation = 'POWER'
        tree.links.new(v.outputs[0], m.inputs[0])
        m.inputs[1].default_value = 2.0
        m2 = nodes.new("ShaderNodeMath")
        m2.operation = 'MULTIPLY_ADD'
        tree.links.new(m.outputs[0], m2.inputs[0])
        m2.inputs[1].default_value = 3.0
        m2.inputs[2].default_value = 0.1
        return m2.outputs[0]
    color, warnings, _ = value_into_diffuse(math)
    assert color[:3] == approx((0.85,) * 3) and not warnings

    def mix(tree, nodes):
        n = nodes.new("ShaderNodeMix")
        n.data_type = 'RGBA'
        n.blend_type = 'MULTIPLY'
        n.inputs["Factor"].default_value = 0.5
        n.inputs[6].default_value = (0.8, 0.6, 0.4, 1)  # A (colour)
        n.inputs[7].default_value = (0.5, 0.5, 0.5, 1)  # B (colour)
        return n.outputs[2]
    color, warnings, _ = value_into_diffuse(mix)
    assert color[:3] == approx(tuple(a * (0.5 + 0.5 * 0.5) for a in (0.8, 0.6, 0.4)))

    def invert(tree, nodes):
        n = nodes.new("ShaderNodeInvert")
        n.inputs["Fac"].default_value = 0.75
        n.inputs["Color"].default_value = (0.2, 0.4, 1.0, 1)
        return n.outputs[0]
    color, _, _ = value_into_diffuse(invert)
    assert color[:3] == approx(tuple(0.25 * c + 0.75 * (1 - c) for c in (0.2, 0.4, 1.0)))

    def bw(tree, nodes):
        n = nodes.new("ShaderNodeRGBToBW")
        n.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1)
        return n.outputs[0]
    color, _, _ = value_into_diffuse(bw)
    assert color[:3] == approx((0.2126 * 0.2 + 0.7152 * 0.4 + 0.0722 * 0.6,) * 3)


def test_textured_math_emits_ops():
    def build(tree, nodes):
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = ms.checker_image("C", 2)
        m = nodes.new("ShaderNodeMath")
        m.operation = 'MULTIPLY'
        m.use_clamp = True
        tree.links.new(tex.outputs["Color"], m.inputs[0])
        m.inputs[1].default_value = 1.5
        mix = nodes.new("ShaderNodeMixRGB")
        mix.blend_type = 'SCREEN'
        tree.links.new(m.outputs[0], mix.inputs["Fac"])
        tree.links.new(tex.outputs["Color"], mix.inputs["Color1"])
        return mix.outputs[0]
    color, warnings, data = value_into_diffuse(build)
    assert not warnings and isinstance(color, Sym)
    ops = [op for op in data.program if op[0] in ("math", "mix", "image", "rgb_to_bw")]
    assert [op[0] for op in ops] == ["image", "rgb_to_bw", "math", "mix"]
    assert ops[2][4:] == ("MULTIPLY", True) and ops[3][5:] == ("SCREEN", False)


def test_unsupported_blend_warns_and_sine_folds():
    def build(tree, nodes):
        m = nodes.new("ShaderNodeMath")
        m.operation = 'SINE'
        m.inputs[0].default_value = 0.3
        mix = nodes.new("ShaderNodeMixRGB")
        mix.blend_type = 'HUE'
        tree.links.new(m.outputs[0], mix.inputs["Fac"])
        return mix.outputs[0]
    color, warnings, _ = value_into_diffuse(build)
    # Every Math operation is supported now (Sine folds); the Hue blend is not (plain Mix).
    assert len(warnings) == 1 and "Sine" not in warnings[0] and "Hue" in warnings[0]
    f = math.sin(0.3)
    expected = tuple((1 - f) * a + f * b for a, b in zip((0.5, 0.5, 0.5), (0.5, 0.5, 0.5)))
    assert color[:3] == approx(expected)


# ---------------------------------------------------------------- more value nodes (issue 3)

def diffuse_fed_by(name, build):
    """A diffuse material whose Color (or Normal, for vectors) is fed by what build(nodes,
    links) returns (an output socket)."""
    mat, nodes, links, out = ms.new_material(name)
    d = nodes.new("ShaderNodeBsdfDiffuse")
    sock = build(nodes, links)
    links.new(sock, d.inputs["Normal" if sock.type == 'VECTOR' else "Color"])
    links.new(d.outputs[0], out.inputs["Surface"])
    return mat


def uv_x(nodes, links):
    """A varying value: the x of the UV coordinates."""
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(nodes.new("ShaderNodeTexCoord").outputs["UV"], sep.inputs["Vector"])
    return sep.outputs["X"]


def constant_color(mat):
    (closure,), _ = run(compile_(mat)[0].program)
    return closure[2]["color"][:3]


def test_fresnel_and_layer_weight_mix():
    mat, nodes, links, out = ms.new_material("Coated")
    mix = nodes.new("ShaderNodeMixShader")
    fres = nodes.new("ShaderNodeFresnel")
    fres.inputs["IOR"].default_value = 1.45
    d, g = nodes.new("ShaderNodeBsdfDiffuse"), nodes.new("ShaderNodeBsdfGlossy")
    links.new(fres.outputs["Fac"], mix.inputs["Fac"])
    links.new(d.outputs[0], mix.inputs[1])
    links.new(g.outputs[0], mix.inputs[2])
    lw = nodes.new("ShaderNodeLayerWeight")
    lw.inputs["Blend"].default_value = 0.3
    nm = nodes.new("ShaderNodeNormalMap")
    links.new(nm.outputs["Normal"], lw.inputs["Normal"])
    links.new(lw.outputs["Facing"], d.inputs["Color"])
    links.new(mix.outputs[0], out.inputs["Surface"])
    data, warnings = compile_(mat)
    assert not warnings
    ops = data.program
    (f,) = [op for op in ops if op[0] == "fresnel"]
    (w,) = [op for op in ops if op[0] == "layer_weight"]
    (n,) = [op for op in ops if op[0] == "normal_map"]
    assert f[3] is None and w[3] == n[1] and w[4] == "FACING"
    regs = run(ops[:ops.index(f)])[1]
    assert regs[f[2]][0] == approx(1.45)
    # The mix weights read the Fresnel register: glossy by it, diffuse by 1 - it.
    closures = {c[1]: c for c in ops if c[0] == "closure"}
    assert closures["glossy"][2] is not None and closures["diffuse"][3]["color"] == w[1]
    links.new(lw.outputs["Fresnel"], d.inputs["Color"])
    assert [op[4] for op in compile_(mat)[0].program if op[0] == "layer_weight"] == ["FRESNEL"]


def test_bump_compiles_the_height_at_three_points():
    mat, nodes, links, out = ms.new_material("Bumped")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = ms.checker_image("H", 4, colorspace="Non-Color")
    bump = nodes.new("ShaderNodeBump")
    bump.inputs["Distance"].default_value = 0.3
    bump.invert = True
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(tex.outputs["Color"], bump.inputs["Height"])
    links.new(bump.outputs["Normal"], d.inputs["Normal"])
    links.new(d.outputs[0], out.inputs["Surface"])
    data, warnings = compile_(mat)
    assert not warnings
    ops = data.program
    uvs = [op for op in ops if op[0] == "uv"]
    assert sorted(op[3:] for op in uvs) == [(), (1,), (2,)]  # the point and the two offsets
    images = [op for op in ops if op[0] == "image"]
    (b,) = [op for op in ops if op[0] == "bump"]
    assert len(images) == 3 and b[8] is True and b[7] is None  # inverted, shading normal
    # Heights in order (point, x, y): each image reads the uv of its offset.
    by_dst = {op[1]: op for op in ops[:ops.index(b)]}
    lum = [by_dst[r] for r in b[2:5]]
    assert all(op[0] in ("rgb_to_bw", "image") for op in lum)
    regs = run(ops[:ops.index(b)])[1]
    assert regs[b[6]][0] == approx(0.3)  # distance
    closure = next(op for op in ops if op[0] == "closure")
    assert closure[3]["normal"] == b[1]
    # A constant height or strength 0: no bump at all, no warning.
    bump.inputs["Strength"].default_value = 0.0
    assert not any(op[0] == "bump" for op in compile_(mat)[0].program)
    bump.inputs["Strength"].default_value = 1.0
    links.remove(bump.inputs["Height"].links[0])
    bump.inputs["Height"].default_value = 0.7
    data, warnings = compile_(mat)
    assert not warnings and not any(op[0] in ("bump", "image") for op in data.program)


def test_bump_of_a_position_height_offsets_the_position():
    def build(nodes, links):
        geo = nodes.new("ShaderNodeNewGeometry")
        sep = nodes.new("ShaderNodeSeparateXYZ")
        bump = nodes.new("ShaderNodeBump")
        links.new(geo.outputs["Position"], sep.inputs["Vector"])
        links.new(sep.outputs["X"], bump.inputs["Height"])
        return bump.outputs["Normal"]
    data, warnings = compile_(diffuse_fed_by("Slope", build))
    assert not warnings
    positions = sorted(op[2:] for op in data.program if op[0] == "position")
    assert positions == [(), (1,), (2,)]


def test_color_ramp_bakes_blenders_evaluation():
    def build(nodes, links, fac=None, interpolation='LINEAR', output="Color"):
        ramp = nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.interpolation = interpolation
        e0, e1 = ramp.color_ramp.elements
        e0.position, e0.color = 0.2, (1.0, 0.0, 0.0, 1.0)
        e1.position, e1.color = 0.8, (0.0, 0.5, 1.0, 0.4)
        if fac is None:
            links.new(uv_x(nodes, links), ramp.inputs["Fac"])
        else:
            ramp.inputs["Fac"].default_value = fac
        return ramp, ramp.outputs[output]
    for interpolation in ('LINEAR', 'EASE', 'CONSTANT', 'B_SPLINE'):
        for fac in (0.1, 0.35, 0.5, 0.79, 0.95):
            holder = {}
            mat = diffuse_fed_by("R", lambda n, l: (holder.setdefault("r", build(
                n, l, fac, interpolation)))[1])
            expect = tuple(holder["r"][0].color_ramp.evaluate(fac))[:3]
            # The 256-entry table (as Cycles) against Blender's exact evaluation.
            assert constant_color(mat) == approx(expect, abs=5e-3), (interpolation, fac)
    mat = diffuse_fed_by("Varying", lambda n, l: build(n, l)[1])
    data, warnings = compile_(mat)
    assert not warnings
    (r,) = [op for op in data.program if op[0] == "ramp"]
    assert r[3].shape == (256, 4) and r[4:] == (True, False, 0.0, 1.0, False)
    assert r[3][0] == approx((1.0, 0.0, 0.0, 1.0)) and r[3][-1] == approx((0.0, 0.5, 1.0, 0.4))
    mat = diffuse_fed_by("Alpha", lambda n, l: build(n, l, output="Alpha")[1])
    (r,) = [op for op in compile_(mat)[0].program if op[0] == "ramp"]
    assert r[3][-1] == approx((0.4,) * 4)


def test_rgb_curves_bake_the_combined_and_channel_curves():
    def build(nodes, links):
        curves = nodes.new("ShaderNodeRGBCurve")
        c = curves.mapping.curves[3].points  # the combined curve: x -> x^2-ish
        c[1].location = (1.0, 0.5)
        curves.inputs["Color"].default_value = (0.5, 0.25, 1.0, 1.0)
        return curves.outputs["Color"]
    mat = diffuse_fed_by("Curves", build)
    node = next(n for n in mat.node_tree.nodes if n.type == 'CURVE_RGB')
    node.mapping.initialize()
    m = node.mapping
    expect = [m.evaluate(m.curves[i], m.evaluate(m.curves[3], x))
              for i, x in enumerate((0.5, 0.25, 1.0))]
    assert constant_color(mat) == approx(expect, abs=2e-3)
    assert expect[2] == approx(0.5, abs=1e-3)  # the combined curve halves white
    # Fac is not clamped (as Cycles): 1.5 goes past the curve.
    node.inputs["Fac"].default_value = 1.5
    color = np.array((0.5, 0.25, 1.0))
    assert constant_color(mat) == approx(color + 1.5 * (np.array(expect) - color), abs=3e-3)
    link(mat.node_tree, uv_x(mat.node_tree.nodes, mat.node_tree.links), node.inputs["Fac"])
    data, warnings = compile_(mat)
    assert not warnings
    # (curved - color is constant here, folded)
    assert [op[6] for op in data.program if op[0] == "vector_math"] == ["MULTIPLY_ADD"]


def test_separate_and_combine_colors_and_vectors_fold():
    import colorsys
    def combine_hsv(nodes, links):
        comb = nodes.new("ShaderNodeCombineColor")
        comb.mode = 'HSV'
        for k, v in zip(("Red", "Green", "Blue"), (0.6, 0.5, 0.8)):
            comb.inputs[k].default_value = v
        return comb.outputs["Color"]
    assert constant_color(diffuse_fed_by("HSV", combine_hsv)) == approx(
        colorsys.hsv_to_rgb(0.6, 0.5, 0.8))

    def separate_hsl(nodes, links):
        sep = nodes.new("ShaderNodeSeparateColor")
        sep.mode = 'HSL'
        sep.inputs["Color"].default_value = (0.2, 0.4, 0.9, 1.0)
        comb = nodes.new("ShaderNodeCombineXYZ")
        for i, k in enumerate("XYZ"):
            links.new(sep.outputs[i], comb.inputs[k])
        sxyz = nodes.new("ShaderNodeSeparateXYZ")
        links.new(comb.outputs[0], sxyz.inputs[0])
        comb2 = nodes.new("ShaderNodeCombineColor")  # RGB: back to a colour, channels kept
        for i in range(3):
            links.new(sxyz.outputs[i], comb2.inputs[i])
        return comb2.outputs["Color"]
    h, l_, s = colorsys.rgb_to_hls(0.2, 0.4, 0.9)
    assert constant_color(diffuse_fed_by("HSL", separate_hsl)) == approx((h, s, l_))

    def varying(nodes, links):
        comb = nodes.new("ShaderNodeCombineColor")
        comb.mode = 'HSV'
        links.new(uv_x(nodes, links), comb.inputs["Red"])
        return comb.outputs["Color"]
    data, warnings = compile_(diffuse_fed_by("Var", varying))
    assert not warnings
    names = [op[0] for op in data.program]
    assert "combine" in names and "separate" in names
    assert next(op for op in data.program if op[0] == "color_space")[3] == "HSV_TO_RGB"


def test_colour_adjustments_fold_as_cycles():
    import colorsys
    def hsv(nodes, links):
        n = nodes.new("ShaderNodeHueSaturation")
        n.inputs["Color"].default_value = (0.8, 0.3, 0.2, 1.0)
        ms.set_inputs(n, Hue=0.6, Saturation=0.5, Value=1.2, Fac=0.75)
        return n.outputs["Color"]
    h, s, v = colorsys.rgb_to_hsv(0.8, 0.3, 0.2)
    shifted = colorsys.hsv_to_rgb((h + 0.1) % 1.0, s * 0.5, v * 1.2)
    expect = [0.75 * a + 0.25 * b for a, b in zip(shifted, (0.8, 0.3, 0.2))]
    assert constant_color(diffuse_fed_by("HSV node", hsv)) == approx(expect)

    def gamma(nodes, links):
        n = nodes.new("ShaderNodeGamma")
        n.inputs["Color"].default_value = (0.25, 0.5, 0.0, 1.0)
        n.inputs["Gamma"].default_value = 2.2
        return n.outputs["Color"]
    assert constant_color(diffuse_fed_by("Gamma", gamma)) == approx((0.25 ** 2.2, 0.5 ** 2.2, 0.0))

    def bright(nodes, links):
        n = nodes.new("ShaderNodeBrightContrast")
        n.inputs["Color"].default_value = (0.25, 0.5, 0.05, 1.0)
        ms.set_inputs(n, Bright=0.1, Contrast=0.4)
        return n.outputs["Color"]
    assert constant_color(diffuse_fed_by("BC", bright)) == approx(
        [max(1.4 * c + 0.1 - 0.2, 0.0) for c in (0.25, 0.5, 0.05)])


@pytest.mark.parametrize("mode, clamp, value, expect", [
    ('LINEAR', True, 0.75, 3.0 + 0.5 * 4.0), ('LINEAR', True, 2.0, 7.0),
    ('LINEAR', False, 2.0, 3.0 + 3.0 * 4.0),
    ('STEPPED', False, 0.6, 3.0 + 4.0 * math.floor(0.2 * 5.0) / 4.0),
    ('SMOOTHSTEP', False, 0.75, 3.0 + 4.0 * 0.5), ('SMOOTHERSTEP', False, 0.5, 3.0)])
def test_map_range_and_clamp_fold(mode, clamp, value, expect):
    def build(nodes, links):
        n = nodes.new("ShaderNodeMapRange")
        n.interpolation_type = mode
        n.clamp = clamp
        by_id = {s.identifier: s for s in n.inputs}
        for k, v in (("Value", value), ("From Min", 0.5), ("From Max", 1.0), ("To Min", 3.0),
                     ("To Max", 7.0), ("Steps", 4.0)):
            by_id[k].default_value = v
        c = nodes.new("ShaderNodeClamp")
        c.clamp_type = 'RANGE'
        ms.set_inputs(c, Min=100.0, Max=-100.0)  # Range: either order
        links.new(n.outputs["Result"], c.inputs["Value"])
        return c.outputs["Result"]
    assert constant_color(diffuse_fed_by("Map", build)) == approx((expect,) * 3)


@pytest.mark.parametrize("op, expect", [
    ("CROSS_PRODUCT", (0.0 * 1 - 3.0 * 0.5, 3.0 * 2.0 - 1.0 * 1, 1.0 * 0.5 - 0.0 * 2.0)),
    ("DOT_PRODUCT", (1.0 * 2.0 + 0.0 + 3.0,) * 3), ("LENGTH", (math.sqrt(10.0),) * 3),
    ("PROJECT", tuple(np.array([2.0, 0.5, 1.0]) * (5.0 / 5.25))),
    ("WRAP", (1.0, 1.5, 1.5)),  # into [0.5, 2): x - 1.5 * floor((x - 0.5) / 1.5)
    ("SCALE", (0.5, 0.0, 1.5))])
def test_vector_math_folds(op, expect):
    def build(nodes, links):
        n = nodes.new("ShaderNodeVectorMath")
        n.operation = op
        n.inputs[0].default_value = (1.0, 0.0, 3.0)
        n.inputs[1].default_value = (2.0, 0.5, 1.0) if op != "WRAP" else (2.0, 2.0, 2.0)
        n.inputs[2].default_value = (0.5, 0.5, 0.5)
        n.inputs[3].default_value = 0.5
        out_name = "Value" if op in ("DOT_PRODUCT", "LENGTH") else "Vector"
        rgb = nodes.new("ShaderNodeMix")  # any node that turns the result into a colour
        rgb.data_type = 'RGBA'
        rgb.inputs["Factor"].default_value = 1.0
        links.new(n.outputs[out_name], [s for s in rgb.inputs if s.identifier == "B_Color"][0])
        return [s for s in rgb.outputs if s.identifier == "Result_Color"][0]
    got = constant_color(diffuse_fed_by(f"VM {op}", build))
    assert got == approx(expect)


def test_light_path_outputs_are_ops():
    def build(nodes, links, output):
        lp = nodes.new("ShaderNodeLightPath")
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = 'RGBA'
        links.new(lp.outputs[output], mix.inputs["Factor"])
        [s for s in mix.inputs if s.identifier == "A_Color"][0].default_value = (0.1, 0.1, 0.1, 1)
        [s for s in mix.inputs if s.identifier == "B_Color"][0].default_value = (0.9, 0.5, 0.2, 1)
        return [s for s in mix.outputs if s.identifier == "Result_Color"][0]
    # Every output the core's path state knows: one op each, no warning.
    for output in ("Is Shadow Ray", "Is Camera Ray", "Is Diffuse Ray", "Is Singular Ray",
                   "Is Volume Scatter Ray", "Ray Length", "Ray Depth", "Transparent Depth",
                   "Transmission Depth"):
        data, warnings = compile_(diffuse_fed_by(output, lambda n, l: build(n, l, output)))
        assert not warnings, warnings
        assert [op[2] for op in data.program if op[0] == "light_path"] == \
            [output.upper().replace(" ", "_")]


@pytest.mark.parametrize("op, a, b, c, expect", [
    ("FLOORED_MODULO", -1.25, 1.0, 0.0, 0.75), ("MODULO", -1.25, 1.0, 0.0, -0.25),
    ("PINGPONG", 2.5, 1.0, 0.0, 0.5), ("WRAP", 2.5, 1.0, 0.0, 0.5),
    ("SMOOTH_MIN", 0.3, 0.4, 0.2, 0.3 - (0.1 / 0.2) ** 3 * 0.2 / 6.0),
    ("COMPARE", 0.3, 0.35, 0.1, 1.0), ("ARCTAN2", 1.0, -1.0, 0.0, 0.75 * math.pi),
    ("LOGARITHM", 8.0, 2.0, 0.0, 3.0), ("SIGN", -0.2, 0.0, 0.0, -1.0),
    ("INVERSE_SQRT", 0.25, 0.0, 0.0, 2.0), ("SNAP", 0.77, 0.25, 0.0, 0.75)])
def test_math_node_operations_fold(op, a, b, c, expect):
    def build(nodes, links):
        m = nodes.new("ShaderNodeMath")
        m.operation = op
        for i, v in enumerate((a, b, c)):
            m.inputs[i].default_value = v
        return m.outputs[0]
    data, warnings = compile_(diffuse_fed_by(f"Math {op}", build))
    assert not warnings
    (closure,), _ = run(data.program)
    got = closure[2]["color"][0]
    assert got == approx(expect)


def test_math_node_with_a_third_value_emits_math3():
    def build(nodes, links):
        m = nodes.new("ShaderNodeMath")
        m.operation = 'SMOOTH_MAX'
        links.new(uv_x(nodes, links), m.inputs[0])
        m.inputs[2].default_value = 0.3
        return m.outputs[0]
    data, warnings = compile_(diffuse_fed_by("Smooth", build))
    assert not warnings
    (op,) = [op for op in data.program if op[0] == "math3"]
    assert op[5:] == ("SMOOTH_MAX", False)
    regs = run(data.program[:data.program.index(op)])[1]
    assert regs[op[4]][0] == approx(0.3)


def test_map_range_vector_folds_and_emits():
    def build(nodes, links, varying=False):
        n = nodes.new("ShaderNodeMapRange")
        n.data_type = 'FLOAT_VECTOR'
        n.interpolation_type = 'LINEAR'
        by_id = {s.identifier: s for s in n.inputs}
        by_id["Vector"].default_value = (0.75, 0.0, 2.0)
        by_id["From_Min_FLOAT3"].default_value = (0.5, 0.0, 1.0)
        by_id["From_Max_FLOAT3"].default_value = (1.0, 0.0, 3.0)
        by_id["To_Max_FLOAT3"].default_value = (2.0, 5.0, 1.0)
        if varying:
            links.new(nodes.new("ShaderNodeTexCoord").outputs["UV"], by_id["Vector"])
        rgb = nodes.new("ShaderNodeMix")  # into a colour (a vector would feed the Normal)
        rgb.data_type = 'RGBA'
        rgb.inputs["Factor"].default_value = 1.0
        links.new(n.outputs["Vector"], [s for s in rgb.inputs if s.identifier == "B_Color"][0])
        return [s for s in rgb.outputs if s.identifier == "Result_Color"][0]
    # x: half way to 2; y: a zero range gives To Min (0); z: half way to 1.
    assert constant_color(diffuse_fed_by("MRV", build)) == approx((1.0, 0.0, 0.5))
    data, warnings = compile_(diffuse_fed_by("MRV2", lambda n, l: build(n, l, True)))
    assert not warnings and [op[8:] for op in data.program if op[0] == "map_range_vector"] == [
        ("LINEAR", True)]


def volume_material(name, build):
    """A material whose Volume is build(nodes, links) (its output socket) and no Surface."""
    mat, nodes, links, out = ms.new_material(name)
    links.new(build(nodes, links), out.inputs["Volume"])
    return mat


def test_volumes_compile_to_cycles_coefficients():
    def scatter_plus_absorption(nodes, links):
        sc = ms.set_inputs(nodes.new("ShaderNodeVolumeScatter"), Color=(0.8, 0.6, 0.4, 1), Density=2.0,
                           Anisotropy=0.3)
        ab = ms.set_inputs(nodes.new("ShaderNodeVolumeAbsorption"), Color=(0.5, 1.0, 0.0, 1), Density=4.0)
        add = nodes.new("ShaderNodeAddShader")
        links.new(sc.outputs[0], add.inputs[0])
        links.new(ab.outputs[0], add.inputs[1])
        return add.outputs[0]
    (closure,), warnings, data = closures_of(volume_material("Fog", scatter_plus_absorption))
    assert not warnings
    assert closure[0] == "transparent" and weight_of(closure) == approx((1, 1, 1))  # pass-through
    v = data.volume
    assert v["sigma_s"] == approx((1.6, 1.2, 0.8)) and v["g"] == approx(0.3)
    assert v["sigma_a"] == approx((2.0, 0.0, 4.0)) and v["emission"] == approx((0, 0, 0))

    def principled(nodes, links):
        return ms.set_inputs(nodes.new("ShaderNodeVolumePrincipled"), Color=(0.5, 0.25, 1.0, 1), Density=2.0,
                             Anisotropy=-0.2, Absorption_Color=(0.25, 0.0, 1.0, 1), Emission_Strength=3.0,
                             Emission_Color=(1.0, 0.5, 0.0, 1)).outputs[0]
    _, warnings, data = closures_of(volume_material("PV", principled))
    assert not warnings
    v = data.volume
    # Cycles: sigma_s = colour * density, sigma_t = (colour + (1 - colour)(1 - sqrt(absorption))) * density
    assert v["sigma_s"] == approx((1.0, 0.5, 2.0)) and v["g"] == approx(-0.2)
    assert v["sigma_a"] == approx((0.5, 1.5, 0.0)) and v["emission"] == approx((3.0, 1.5, 0.0))


def test_bad_volume_inputs_warn_and_clamp():
    def bad(density):
        return lambda nodes, links: ms.set_inputs(nodes.new("ShaderNodeVolumeScatter"), Color=(0.5, 0.5, 0.5, 1),
                                                  Density=density).outputs[0]
    _, warnings, data = closures_of(volume_material("Neg", bad(-3.0)))
    assert len(warnings) == 1 and "clamped" in warnings[0]
    assert data.volume is None  # nothing left: no medium
    _, warnings, data = closures_of(volume_material("NaN", bad(float("nan"))))
    assert data.volume is None or all(math.isfinite(x) for x in data.volume["sigma_s"])


# ---------------------------------------------------------------- the core takes them all

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


@needs_core
def test_core_accepts_every_compiled_program():
    """Every node setup of both shader-compiler test files (rebuilt in one scene) compiles to a
    program that the core's parser validates, with images and uv sets through to_core."""
    base.test_mesh_export_gathers_uvs_per_corner()
    for fn, args in ((base.test_mix_of_diffuse_and_glossy, (0.3,)),
                     (base.test_principled_inputs_alpha_and_emission, ()),
                     (test_alpha_output_uses_straight_colour_and_an_alpha_image, ()),
                     (test_normal_map, ()), (base.test_node_groups_are_flattened_and_nest, ()),
                     (base.test_unsupported_nodes_warn_once_naming_each_and_fall_back, ()),
                     (base.test_register_allocation_reuses_registers, ()),
                     (base.test_volume_absorption_and_unsupported_volumes, ()),
                     (test_textured_math_emits_ops, ())):
        fn(*args)
    # The value nodes of issue 3.
    for fn in ("test_fresnel_and_layer_weight_mix", "test_bump_of_a_position_height_offsets_the_position",
               "test_color_ramp_bakes_blenders_evaluation", "test_rgb_curves_bake_the_combined_and_channel_curves",
               "test_separate_and_combine_colors_and_vectors_fold", "test_colour_adjustments_fold_as_cycles",
               "test_light_path_outputs_are_ops"):
        globals()[fn]()
    test_map_range_and_clamp_fold('SMOOTHSTEP', False, 0.75, 5.0)
    test_vector_math_folds("SCALE", (0.5, 0.0, 1.5))
    pc = load_addon().core.get_core()
    table = MaterialTable(Warnings())
    for mat in bpy.data.materials:
        table.index(mat)
    scene = pc.Scene()
    from addon.scene_writer import add_materials
    ids = add_materials(scene, table.materials, table.images.images, Warnings())
    assert len(set(ids)) == len(ids) == len(bpy.data.materials)
    core_scene = to_core(pc, export_scene(bpy.context.evaluated_depsgraph_get(), Warnings()))
    core_scene.commit()


def test_reroute_loop_on_the_surface_terminates():
    # Output.Surface <- Reroute A <- Reroute B <- Reroute A: Blender marks the closing link
    # invalid but keeps it. No closure (nothing feeds the loop), no hang.
    mat, nodes, links, out = ms.new_material("Loop of reroutes")
    a, b = nodes.new("NodeReroute"), nodes.new("NodeReroute")
    links.new(a.outputs[0], out.inputs["Surface"])
    links.new(b.outputs[0], a.inputs[0])
    links.new(a.outputs[0], b.inputs[0])
    data, warnings = compile_(mat)
    assert data.program == [] and data.base_color == (0.0, 0.0, 0.0)
