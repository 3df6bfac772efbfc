"""Checker, Gradient, Brick and Voronoi Textures against Cycles in the same bpy (issue 21): a
2 m plane filling a 32x32 view emits the texture's outputs (three float outputs packed into R, G
and B by a Combine Color, or one colour output), rendered once by each engine with one sample,
no bounces and a 0.01-pixel box filter, so that both shade (nearly) the pixel centres.

Per channel the mean absolute difference must stay under 1e-3 of the channel's value range in
Cycles. A pixel whose centre lies within the filter's 0.005-pixel jitter of a discontinuity
(a checker or brick edge, a Voronoi cell border) can land on the other side in one engine: such
pixels are allowed only where the other engine's own image shows that value within the 3x3
neighbourhood (the same edge, one side or the other), are counted, and at most 2 % of pixels."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

SIZE = 32
FILTER = dict(pixel_filter_type='BOX', filter_width=0.01)


def pattern_scene(make_color, size=SIZE):
    """A scene whose plane emits make_color(nodes, links) (a colour socket)."""
    def build():
        bpy.ops.wm.read_factory_settings(use_empty=True)
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
    ours = render_to_array(build(), "PATHLIGHT", samples=1, max_bounces=1, **FILTER)[..., :3]
    cycles = render_to_array(build(), "CYCLES", samples=1, max_bounces=1, **FILTER)[..., :3]
    return ours, cycles


def edge_pixels(ours, cycles, ch, tol):
    """Pixels of channel ch that differ by more than tol, and whether each is explained by a
    discontinuity: some 3x3 neighbour in Cycles' image holds our value, and some neighbour in
    ours holds Cycles' value."""
    a, b = ours[..., ch], cycles[..., ch]
    bad = np.argwhere(np.abs(a - b) > tol)
    explained = []
    for y, x in bad:
        ys, xs = slice(max(y - 1, 0), y + 2), slice(max(x - 1, 0), x + 2)
        explained.append(bool(np.abs(b[ys, xs] - a[y, x]).min() <= tol
                              and np.abs(a[ys, xs] - b[y, x]).min() <= tol))
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
        assert all(explained), f"{label} channel {ch}: differences off any edge at {bad.tolist()}"
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
            n.inputs[k[3:].replace("_", " ")].default_value = v
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
