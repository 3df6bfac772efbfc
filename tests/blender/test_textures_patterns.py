"""Checker, Gradient, Brick and Voronoi Textures against Cycles in the same bpy (issue 21): a
2 m plane filling a 32x32 view emits the texture's outputs (three float outputs packed into R, G
and B by a Combine Color, or one colour output), rendered by each engine with no bounces and a
0.01-pixel filter, so that both shade (nearly) the pixel centres (see CYCLES_FILTER).

Per channel the mean absolute difference must stay under 1e-3 of the channel's value range in
Cycles. A pixel whose centre lies within Pathlight's 0.005-pixel jitter of a discontinuity (a
checker or brick edge, a Voronoi cell border) can take the other side's value, or a mix: such
pixels are allowed only where each engine's value lies within the range the other's image takes
around that pixel (an edge), are counted, and at most 2 % of pixels."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

SIZE = 32
# Cycles' Box filter is always 1 px wide (its width applies to Gaussian and Blackman-Harris
# only): a 0.01 px Gaussian puts its one sample on the pixel centre (measured: 3e-6 px off).
# Pathlight's 0.01 px box jitters within +-0.005 px; four stratified samples average to
# 2e-4 px off the centre.
CYCLES_FILTER = dict(samples=1, pixel_filter_type='GAUSSIAN', filter_width=0.01)
OUR_FILTER = dict(samples=4, pixel_filter_type='BOX', filter_width=0.01)


def pattern_scene(make_color, size=SIZE):
    """A scene whose plane emits make_color(nodes, links) (a colour socket)."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = size
        scene.render.resolution_percentage = 100
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("Pattern")
        e = nodes.new("ShaderNodeEmission")
        links.new(make_color(nodes, links), e.inputs["Color"])
        links.new(e.outputs[0], out.inputs["Surface"])
        ms.add_plane("Plane", 2.0, mat)
        ms.add_camera((0.0, 0.0, 2.4), (0.0, 0.0, 0.0))  # the plane fills the view
        return scene
    return build


def channels(*sockets_fns):
    """make_color for up to three float outputs, packed into R, G, B (unused: 0)."""
    def make(nodes, links):
        comb = nodes.new("ShaderNodeCombineColor")
        for i, fn in enumerate(sockets_fns):
            if fn is not None:
                links.new(fn(nodes, links), comb.inputs[i])
        return comb.outputs["Color"]
    return make


def render_both(make_color):
    build = pattern_scene(make_color)
    ours = render_to_array(build(), "PATHLIGHT", max_bounces=1, **OUR_FILTER)
    cycles = render_to_array(build(), "CYCLES", max_bounces=1, **CYCLES_FILTER)
    return ours[..., :3], cycles[..., :3]


def edge_pixels(ours, cycles, ch, tol):
    """Pixels of channel ch that differ by more than tol, and whether each is explained by a
    discontinuity: Cycles' image jumps (by 2 tol or more) within the pixel's 3x3 neighbourhood
    and our value lies within the range it takes there (one side of the edge, the other, or a
    mix of samples from both)."""
    a, b = ours[..., ch], cycles[..., ch]
    bad = np.argwhere(np.abs(a - b) > tol)
    explained = []
    for y, x in bad:
        around = b[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2]
        explained.append(bool(around.max() - around.min() >= 2 * tol
                              and around.min() - tol <= a[y, x] <= around.max() + tol))
    return bad, explained


def assert_agree(ours, cycles, n_channels=3, label=""):
    """Per channel: mean |difference| < 1e-3 of Cycles' range, edge pixels aside (counted and
    checked to be edges). Returns [(mean abs diff / range, edge pixel count)] per channel."""
    assert np.isfinite(ours).all()
    stats = []
    for ch in range(n_channels):
        b = cycles[..., ch]
        span = float(b.max() - b.min())
        assert span > 1e-3, f"{label} channel {ch}: Cycles shows no pattern (range {span})"
        tol = 0.02 * span
        bad, explained = edge_pixels(ours, cycles, ch, tol)
        off = [(int(y), int(x), float(ours[y, x, ch]), float(b[y, x]))
               for (y, x), e in zip(bad, explained) if not e]
        assert not off, f"{label} channel {ch}: (y, x, ours, Cycles) off any edge: {off}"
        assert len(bad) <= 0.02 * b.size, f"{label} channel {ch}: {len(bad)} edge pixels"
        keep = np.ones(b.shape, bool)
        for y, x in bad:
            keep[y, x] = False
        err = float(np.abs(ours[..., ch] - b)[keep].mean()) / span
        assert err < 1e-3, f"{label} channel {ch}: mean |diff| {err:.2e} of the range {span:.3f}"
        stats.append((err, len(bad)))
    print(f"{label}: (mean |diff| / range, edge pixels) per channel {stats}")
    return stats


def node(nodes, kind, **settings):
    n = nodes.new(kind)
    for k, v in settings.items():
        if k.startswith("in_"):
            key = k[3:].replace("_", " ")
            (n.inputs[int(key)] if key.isdigit() else
             next(s for s in n.inputs if s.identifier == key)).default_value = v
        else:
            setattr(n, k, v)
    return n


def output(kind, out, links_fn=None, **settings):
    """A channel function: output `out` of a new node of `kind` with `settings` (in_X for
    input values), links_fn(nodes, links, node) adding links into it."""
    def fn(nodes, links):
        n = node(nodes, kind, **settings)
        if links_fn is not None:
            links_fn(nodes, links, n)
        return n.outputs[out]
    return fn


def rotated_object_coords(nodes, links, n):
    """Object coordinates through a rotating, scaling Mapping into the Vector input: z varies
    over the plane, and the Vector input is linked."""
    coord = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0.6, 0.4, 0.3)
    mapping.inputs["Scale"].default_value = (0.8, 0.8, 0.8)
    mapping.inputs["Location"].default_value = (0.3, -0.2, 0.1)
    links.new(coord.outputs["Object"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], n.inputs["Vector"])


# ---------------------------------------------------------------- checker

def test_checker_color_and_fac():
    def color(nodes, links):
        n = node(nodes, "ShaderNodeTexChecker", in_Scale=7.3,
                 in_Color1=(0.9, 0.3, 0.1, 1.0), in_Color2=(0.1, 0.4, 0.8, 1.0))
        return n.outputs["Color"]
    ours, cycles = render_both(color)
    assert_agree(ours, cycles, label="checker color")
    fac = channels(output("ShaderNodeTexChecker", "Fac", in_Scale=4.1),
                   output("ShaderNodeTexChecker", "Fac", rotated_object_coords, in_Scale=3.0),
                   # negative coordinates: the parity of |floor| as Cycles takes it
                   output("ShaderNodeTexChecker", "Fac", lambda nd, lk, n: lk.new(
                       nd.new("ShaderNodeTexCoord").outputs["Object"], n.inputs["Vector"]),
                       in_Scale=2.7))
    ours, cycles = render_both(fac)
    assert_agree(ours, cycles, label="checker fac")


def object_coords(nodes, links, n):
    """Object coordinates (centred on the plane, negative on half of it) into Vector."""
    links.new(nodes.new("ShaderNodeTexCoord").outputs["Object"], n.inputs["Vector"])


# ---------------------------------------------------------------- gradient

def gradient(kind, links_fn=None):
    return output("ShaderNodeTexGradient", "Fac", links_fn, gradient_type=kind)


@pytest.mark.parametrize("kinds", [
    (("LINEAR", None), ("QUADRATIC", None), ("EASING", rotated_object_coords)),
    (("DIAGONAL", None), ("SPHERICAL", object_coords), ("QUADRATIC_SPHERE", object_coords)),
    (("RADIAL", object_coords), ("RADIAL", rotated_object_coords), ("SPHERICAL", None)),
], ids=["linear-quadratic-easing", "diagonal-spherical-quadsphere", "radial"])
def test_gradient_types(kinds):
    ours, cycles = render_both(channels(*(gradient(k, fn) for k, fn in kinds)))
    assert_agree(ours, cycles, label="gradient " + "/".join(k for k, _ in kinds))


def test_gradient_color_output():
    def color(nodes, links):
        n = node(nodes, "ShaderNodeTexGradient", gradient_type='DIAGONAL')
        return n.outputs["Color"]
    ours, cycles = render_both(color)
    assert_agree(ours, cycles, label="gradient color")


# ---------------------------------------------------------------- brick

def test_brick_color_default():
    def color(nodes, links):
        n = node(nodes, "ShaderNodeTexBrick", in_Color1=(0.8, 0.2, 0.1, 1.0),
                 in_Color2=(0.2, 0.6, 0.3, 1.0), in_Mortar=(0.05, 0.05, 0.3, 1.0))
        return n.outputs["Color"]
    ours, cycles = render_both(color)
    assert_agree(ours, cycles, label="brick color")


def linked_scale(nodes, links, n):
    """Scale from a Gradient's Fac (between 3 and 6 across the plane): a linked input."""
    g = node(nodes, "ShaderNodeTexGradient", gradient_type='LINEAR')
    m = node(nodes, "ShaderNodeMapRange")
    m.inputs["To Min"].default_value, m.inputs["To Max"].default_value = 3.0, 6.0
    links.new(g.outputs["Fac"], m.inputs["Value"])
    links.new(m.outputs["Result"], n.inputs["Scale"])


def test_brick_fac_offset_squash_mortar():
    ours, cycles = render_both(channels(
        output("ShaderNodeTexBrick", "Fac", offset=0.3, offset_frequency=3, squash=0.6,
               squash_frequency=2, in_Mortar_Size=0.1, in_Mortar_Smooth=0.7),
        output("ShaderNodeTexBrick", "Fac", object_coords, in_Mortar_Smooth=0.0,
               in_Brick_Width=0.3, in_Row_Height=0.15, in_Scale=4.0),
        output("ShaderNodeTexBrick", "Fac", linked_scale, in_Mortar_Size=0.08,
               in_Mortar_Smooth=1.0)))
    assert_agree(ours, cycles, label="brick fac")


def test_brick_color_bias_and_linked_colors():
    def color(nodes, links):
        n = node(nodes, "ShaderNodeTexBrick", in_Bias=-0.3, in_Scale=3.0, squash=1.4,
                 squash_frequency=3, in_Mortar_Size=0.03)
        checker = node(nodes, "ShaderNodeTexChecker", in_Scale=2.0)
        links.new(checker.outputs["Color"], n.inputs["Color1"])
        rotated_object_coords(nodes, links, n)
        return n.outputs["Color"]
    ours, cycles = render_both(color)
    assert_agree(ours, cycles, label="brick bias")


# ---------------------------------------------------------------- voronoi

def linked_w(nodes, links, n):
    """W = 3 x + 1.3 y of the Generated coordinates (varies over the plane)."""
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(nodes.new("ShaderNodeTexCoord").outputs["Generated"], sep.inputs["Vector"])
    mx = node(nodes, "ShaderNodeMath", operation='MULTIPLY', in_1=3.0)
    links.new(sep.outputs["X"], mx.inputs[0])
    madd = node(nodes, "ShaderNodeMath", operation='MULTIPLY_ADD')
    madd.inputs[1].default_value = 1.3
    links.new(sep.outputs["Y"], madd.inputs[0])
    links.new(mx.outputs[0], madd.inputs[2])
    links.new(madd.outputs[0], n.inputs["W"])


def voronoi(dims, feature, out="Distance", metric='EUCLIDEAN', component=None,
            links_fn=None, normalize=False, **inputs):
    """A channel (or colour) function: output `out` of a Voronoi node (component 0-2 of a
    vector output through Separate XYZ); W is linked (linked_w) in 1D and 4D."""
    settings = {"in_" + k: v for k, v in inputs.items()}
    def fn(nodes, links):
        n = node(nodes, "ShaderNodeTexVoronoi", voronoi_dimensions=dims, feature=feature,
                 distance=metric, normalize=normalize, **settings)
        if dims in ('1D', '4D'):
            linked_w(nodes, links, n)
        if links_fn is not None:
            links_fn(nodes, links, n)
        sock = n.outputs[out]
        if component is not None:  # shifted by +1: Pathlight's emission clips negative colours
            sep = nodes.new("ShaderNodeSeparateXYZ")
            links.new(sock, sep.inputs["Vector"])
            add = node(nodes, "ShaderNodeMath", operation='ADD', in_1=1.0)
            links.new(sep.outputs[component], add.inputs[0])
            sock = add.outputs[0]
        return sock
    return fn


def randomness_from_gradient(nodes, links, n):
    g = node(nodes, "ShaderNodeTexGradient", gradient_type='DIAGONAL')
    links.new(g.outputs["Fac"], n.inputs["Randomness"])


DIMS = ['1D', '2D', '3D', '4D']


@pytest.mark.parametrize("dims", DIMS)
def test_voronoi_features_and_metrics(dims):
    ours, cycles = render_both(channels(
        voronoi(dims, 'F1', Scale=6.0),
        voronoi(dims, 'F2', metric='MANHATTAN', Scale=5.0),
        voronoi(dims, 'SMOOTH_F1', metric='CHEBYCHEV', Scale=5.0, Smoothness=0.7)))
    assert_agree(ours, cycles, label=f"voronoi {dims} F1/F2/smooth")
    ours, cycles = render_both(channels(
        voronoi(dims, 'DISTANCE_TO_EDGE', Scale=5.0),
        voronoi(dims, 'N_SPHERE_RADIUS', out="Radius", Scale=4.0, Randomness=0.9),
        voronoi(dims, 'F1', metric='MINKOWSKI', Scale=5.0, Exponent=1.5)))
    assert_agree(ours, cycles, label=f"voronoi {dims} edge/radius/minkowski")


@pytest.mark.parametrize("dims", DIMS)
def test_voronoi_color_position_w(dims):
    ours, cycles = render_both(voronoi(dims, 'F1', out="Color", Scale=5.0,
                                       links_fn=randomness_from_gradient))
    assert_agree(ours, cycles, label=f"voronoi {dims} color")
    last = (voronoi(dims, 'F1', out="W", Scale=4.0) if dims in ('1D', '4D') else
            voronoi(dims, 'F1', out="Position", component=int(dims[0]) - 1, Scale=4.0,
                    links_fn=rotated_object_coords))
    if dims == '1D':
        first = voronoi(dims, 'F2', out="W", Scale=3.0)
        second = voronoi(dims, 'SMOOTH_F1', out="W", Scale=3.0, Smoothness=0.5)
    else:
        first = voronoi(dims, 'F2', out="Position", component=0, Scale=4.0)
        second = voronoi(dims, 'SMOOTH_F1', out="Position", component=1, Scale=4.0,
                         Smoothness=0.5)
    ours, cycles = render_both(channels(first, second, last))
    assert_agree(ours, cycles, label=f"voronoi {dims} position/w")


@pytest.mark.parametrize("dims", DIMS)
def test_voronoi_fractal(dims):
    ours, cycles = render_both(channels(
        voronoi(dims, 'F1', Scale=3.0, Detail=2.5, Roughness=0.6, Lacunarity=2.2,
                normalize=True),
        voronoi(dims, 'DISTANCE_TO_EDGE', Scale=3.0, Detail=1.7, Roughness=0.8,
                normalize=True),
        voronoi(dims, 'SMOOTH_F1', metric='MANHATTAN', Scale=3.0, Detail=1.0,
                Roughness=0.7, Lacunarity=3.0, Smoothness=0.4)))
    assert_agree(ours, cycles, label=f"voronoi {dims} fractal")


# ---------------------------------------------------------------- compiling (no rendering)

def compile_patterns(make_color):
    from addon.export.material import convert_material
    from blender_util import Warnings
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    mat, nodes, links, out = ms.new_material("Compiled")
    e = nodes.new("ShaderNodeEmission")
    links.new(make_color(nodes, links), e.inputs["Color"])
    links.new(e.outputs[0], out.inputs["Surface"])
    warnings = Warnings()
    data = convert_material(mat, warnings)
    return data.program, list(warnings)


def test_pattern_nodes_compile_to_their_ops_without_warnings():
    """Each node is supported (no 'not supported' fallback), reads Generated coordinates when
    its Vector is unlinked (1D Voronoi reads W only), is emitted even with constant inputs
    (the core evaluates a program that reads nothing from the point once), and the core's
    parser takes every op."""
    program, warnings = compile_patterns(channels(
        output("ShaderNodeTexChecker", "Fac"),
        output("ShaderNodeTexBrick", "Fac"),
        output("ShaderNodeTexGradient", "Fac", gradient_type='RADIAL')))
    assert warnings == []
    names = [op[0] for op in program]
    assert {"checker", "brick", "gradient"} <= set(names) and names.count("generated") == 1
    program_v, warnings = compile_patterns(channels(
        voronoi('4D', 'SMOOTH_F1', out="Distance"), voronoi('1D', 'F2', out="W"),
        voronoi('3D', 'N_SPHERE_RADIUS', out="Radius")))
    assert warnings == []
    ops = [op for op in program_v if op[0] == "voronoi"]
    assert [op[11:] for op in ops] == [('4D', 'SMOOTH_F1', 'EUCLIDEAN', False, 'DISTANCE'),
                                       ('1D', 'F2', 'EUCLIDEAN', False, 'W'),
                                       ('3D', 'N_SPHERE_RADIUS', 'EUCLIDEAN', False, 'RADIUS')]
    assert ops[1][2] is None and ops[1][3] is not None  # 1D: no vector, a W
    assert ops[2][3] is None  # 3D: no W
    # Constant inputs everywhere: the ops are still emitted, not folded.
    const_program, _ = compile_patterns(lambda nodes, links: node(
        nodes, "ShaderNodeTexChecker").outputs["Color"])
    assert "checker" in [op[0] for op in const_program]
    pc = load_addon().core.get_core()
    scene = pc.Scene()
    for p in (program, program_v, const_program):
        scene.add_shader("m", p)


def test_pattern_ops_reject_bad_settings():
    pc = load_addon().core.get_core()
    scene = pc.Scene()
    good = [("const", 0, (0.5, 0.5, 0.5)),
            ("voronoi", 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, "3D", "F1", "EUCLIDEAN", False, "COLOR"),
            ("closure", "emission", None, {"color": 1})]
    scene.add_shader("ok", good)
    for bad in (("voronoi", 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, "5D", "F1", "EUCLIDEAN", False, "COLOR"),
                ("voronoi", 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, "3D", "F3", "EUCLIDEAN", False, "COLOR"),
                ("gradient", 1, 0, "CONICAL"), ("checker", 1, 0, 0, 0, 0, "ALPHA"),
                ("brick", 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0.5, 0, 1.0, 2, "FAC"),
                ("checker", 1, 0, 0, 0, 99, "FAC")):
        with pytest.raises((ValueError, TypeError)):
            scene.add_shader("bad", [good[0], bad, good[2]])


def test_texture_mapping_settings_warn():
    def color(nodes, links):
        n = node(nodes, "ShaderNodeTexChecker")
        n.texture_mapping.scale = (2.0, 1.0, 1.0)
        return n.outputs["Color"]
    _, warnings = compile_patterns(color)
    assert len(warnings) == 1 and "Texture Mapping" in warnings[0]


# ---------------------------------------------------------------- lit materials

def textured_principled_scene():
    """A plane under a sun whose Principled BSDF takes its Base Color from a Brick texture
    (Checker-coloured bricks) and its Roughness from a Voronoi distance."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 64
        ms.set_world((0.05, 0.05, 0.05))
        mat, nodes, links, out = ms.new_material("Textured")
        bsdf = node(nodes, "ShaderNodeBsdfPrincipled", distribution='GGX')
        checker = node(nodes, "ShaderNodeTexChecker", in_Scale=3.0,
                       in_Color1=(0.8, 0.25, 0.1, 1.0), in_Color2=(0.2, 0.5, 0.7, 1.0))
        bricks = node(nodes, "ShaderNodeTexBrick", in_Scale=4.0, in_Mortar_Size=0.04,
                      in_Mortar=(0.7, 0.7, 0.65, 1.0), in_Color2=(0.3, 0.3, 0.3, 1.0))
        links.new(checker.outputs["Color"], bricks.inputs["Color1"])
        cells = node(nodes, "ShaderNodeTexVoronoi", in_Scale=6.0)
        rough = node(nodes, "ShaderNodeMapRange")
        rough.inputs["To Min"].default_value, rough.inputs["To Max"].default_value = 0.2, 0.8
        links.new(cells.outputs["Distance"], rough.inputs["Value"])
        links.new(bricks.outputs["Color"], bsdf.inputs["Base Color"])
        links.new(rough.outputs["Result"], bsdf.inputs["Roughness"])
        links.new(bsdf.outputs[0], out.inputs["Surface"])
        ms.add_plane("Plane", 4.0, mat)
        ms.add_sun(3.0, 35.0)
        # Steep enough to keep grazing views (where the core's Principled is approximate) out.
        ms.add_camera((0.0, -1.8, 2.8), (0.0, 0.2, 0.0))
        return scene
    return build


def test_textured_principled_plane_under_a_sun():
    build = textured_principled_scene()
    ours = render_to_array(build(), "PATHLIGHT", samples=32, max_bounces=4,
                           pixel_filter_type='BOX', filter_width=1.0)
    cycles = render_to_array(build(), "CYCLES", samples=32, max_bounces=4,
                             pixel_filter_type='BOX', filter_width=1.0)
    ratio, worst, rel = ms.compare(ours, cycles)
    print(f"textured principled: image mean ratio {ratio:.4f}, worst 8x8 region {worst:.4f}")
    assert abs(ratio - 1.0) < 0.01, f"image mean ratio {ratio:.4f}"
    assert worst < 0.03, f"worst region {worst:.3f}\n{np.round(rel, 3)}"
    # The textures show: the image is far from uniform (bricks, mortar, checker colours).
    assert cycles[..., :3].std() > 0.1 * cycles[..., :3].mean()


def test_bump_of_a_voronoi_distance():
    """The Bump node differentiates a texture through its coordinates' offsets (the Generated
    op at each Bump offset): Voronoi cells shaded by a low sun as in Cycles."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 64
        ms.set_world((0.05, 0.05, 0.05))
        mat, nodes, links, out = ms.new_material("Bumped")
        cells = node(nodes, "ShaderNodeTexVoronoi", in_Scale=3.0)
        bump = node(nodes, "ShaderNodeBump", in_Distance=0.1)
        d = node(nodes, "ShaderNodeBsdfDiffuse", in_Color=(0.8, 0.8, 0.8, 1.0))
        links.new(cells.outputs["Distance"], bump.inputs["Height"])
        links.new(bump.outputs["Normal"], d.inputs["Normal"])
        links.new(d.outputs[0], out.inputs["Surface"])
        ms.add_plane("Plane", 2.0, mat)
        ms.add_sun(3.0, 55.0)
        ms.add_camera((0.0, 0.0, 2.4), (0.0, 0.0, 0.0))
        return scene
    ours = render_to_array(build(), "PATHLIGHT", samples=32, max_bounces=4,
                           pixel_filter_type='BOX', filter_width=1.0)
    cycles = render_to_array(build(), "CYCLES", samples=32, max_bounces=4,
                             pixel_filter_type='BOX', filter_width=1.0)
    ratio, worst, rel = ms.compare(ours, cycles)
    print(f"voronoi bump: image mean ratio {ratio:.4f}, worst 8x8 region {worst:.4f}")
    assert abs(ratio - 1.0) < 0.01 and worst < 0.03, f"{ratio:.4f} {worst:.4f}"
    # The bump shows: a flat plane under the sun would be one grey (std ~0.001 from noise).
    assert ours[..., 0].std() > 0.02


# ---------------------------------------------------------------- every input linked

def from_gradient(*names, lo=0.0, hi=1.0, kind='LINEAR'):
    """A links_fn feeding inputs `names` from a Gradient's Fac mapped to [lo, hi]."""
    def fn(nodes, links, n):
        g = node(nodes, "ShaderNodeTexGradient", gradient_type=kind)
        m = node(nodes, "ShaderNodeMapRange")
        m.inputs["To Min"].default_value, m.inputs["To Max"].default_value = lo, hi
        links.new(g.outputs["Fac"], m.inputs["Value"])
        for name in names:
            links.new(m.outputs["Result"], next(s for s in n.inputs if s.identifier == name))
    return fn


def chain(*fns):
    def fn(nodes, links, n):
        for f in fns:
            f(nodes, links, n)
    return fn


def test_voronoi_linked_inputs():
    ours, cycles = render_both(channels(
        voronoi('3D', 'F1', Scale=3.0, normalize=True, links_fn=chain(
            from_gradient("Detail", lo=0.0, hi=3.0), from_gradient("Roughness", kind='DIAGONAL'),
            from_gradient("Lacunarity", lo=1.5, hi=3.0, kind='EASING'))),
        voronoi('2D', 'SMOOTH_F1', Scale=4.0, links_fn=from_gradient("Smoothness")),
        voronoi('4D', 'F2', metric='MINKOWSKI', Scale=3.0,
                links_fn=from_gradient("Exponent", lo=0.6, hi=3.0))))
    assert_agree(ours, cycles, label="voronoi linked inputs")


def test_brick_and_checker_linked_inputs():
    def color(nodes, links):
        n = node(nodes, "ShaderNodeTexBrick", in_Scale=3.0)
        chain(from_gradient("Mortar Size", lo=0.01, hi=0.1),
              from_gradient("Mortar Smooth", lo=0.0, hi=1.0, kind='DIAGONAL'),
              from_gradient("Bias", lo=-0.5, hi=0.5, kind='EASING'),
              from_gradient("Brick Width", lo=0.3, hi=0.7, kind='RADIAL'),
              from_gradient("Row Height", lo=0.2, hi=0.3, kind='QUADRATIC'))(nodes, links, n)
        checker = node(nodes, "ShaderNodeTexChecker", in_Scale=3.0)
        g = node(nodes, "ShaderNodeTexGradient", gradient_type='DIAGONAL')
        links.new(g.outputs["Color"], checker.inputs["Color2"])
        links.new(g.outputs["Fac"], checker.inputs["Scale"])
        links.new(checker.outputs["Color"], n.inputs["Mortar"])
        links.new(checker.outputs["Color"], n.inputs["Color2"])
        return n.outputs["Color"]
    ours, cycles = render_both(color)
    assert_agree(ours, cycles, label="brick and checker linked inputs")


def test_degenerate_inputs_render_finite():
    """Zero sizes and exponents, huge scales, out-of-range settings: finite values (no NaN
    or crash; Cycles' own results there are not compared)."""
    build = pattern_scene(channels(
        output("ShaderNodeTexBrick", "Fac", in_Row_Height=0.0, in_Brick_Width=0.0,
               in_Mortar_Size=0.0, in_Scale=1e30),
        voronoi('4D', 'F1', metric='MINKOWSKI', Exponent=0.0, Scale=1e30, Lacunarity=0.0,
                Detail=3.0, normalize=True),
        voronoi('2D', 'DISTANCE_TO_EDGE', Scale=-1e-30, Randomness=-5.0, Detail=40.0,
                Roughness=7.0, normalize=True)))
    img = render_to_array(build(), "PATHLIGHT", samples=1, max_bounces=1)
    assert np.isfinite(img).all()


@pytest.mark.parametrize("dims", DIMS)
def test_voronoi_smooth_and_f2_colors(dims):
    """Colour components (through Separate XYZ) of Smooth F1 (blended cell colours), F2, and
    a fractal Smooth F1 whose Normalize divides the colour too."""
    ours, cycles = render_both(channels(
        voronoi(dims, 'SMOOTH_F1', out="Color", component=0, Scale=4.0, Smoothness=0.6),
        voronoi(dims, 'F2', out="Color", component=1, Scale=4.0),
        voronoi(dims, 'SMOOTH_F1', out="Color", component=2, Scale=3.0, Smoothness=0.3,
                Detail=1.5, Roughness=0.7, normalize=True)))
    assert_agree(ours, cycles, label=f"voronoi {dims} smooth/F2 colours")
