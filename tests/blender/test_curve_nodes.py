"""Float Curve, Vector Curves and the Normal node against Cycles in the same bpy, on emission
planes and a sphere (the value is the emitted colour), one sample at the pixel centres,
compared per pixel (mean absolute difference under 1e-3 of the range): Cycles bakes each curve
into a 256-entry table over the curves' common range and blends by an unclamped factor, which
the core's ramp op reproduces."""
import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon
import material_scenes as ms
from test_materials import emission_plane_scene
from test_vector_nodes import assert_matches, render_both

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def uv_socket(nodes, links):
    return nodes.new("ShaderNodeTexCoord").outputs["UV"]


def bend(curve, points, extend=None):
    """Moves a curve's two end points and adds the others ((x, y) pairs)."""
    pts = curve.points
    pts[0].location, pts[1].location = points[0], points[-1]
    for p in points[1:-1]:
        pts.new(*p)


@pytest.mark.parametrize("factor", [1.0, 0.6, 1.5])
def test_float_curve(factor):
    def color(nodes, links):
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(uv_socket(nodes, links), sep.inputs["Vector"])
        fc = ms.set_inputs(nodes.new("ShaderNodeFloatCurve"), Factor=factor)
        bend(fc.mapping.curves[0], [(0.0, 0.1), (0.3, 0.9), (0.7, 0.2), (1.0, 0.8)])
        links.new(sep.outputs["X"], fc.inputs["Value"])
        absolute = nodes.new("ShaderNodeMath")  # (Factor 1.5 goes below 0: Pathlight's emission
        absolute.operation = 'ABSOLUTE'          # clamps there, Cycles' does not)
        links.new(fc.outputs["Value"], absolute.inputs[0])
        return absolute.outputs["Value"]
    ours, cycles = render_both(emission_plane_scene(color))
    assert_matches(ours, cycles, min_std=0.1)  # (the curve shows)


@pytest.mark.parametrize("extend", ['HORIZONTAL', 'EXTRAPOLATED'])
def test_vector_curves(extend):
    def color(nodes, links):
        vc = ms.set_inputs(nodes.new("ShaderNodeVectorCurve"), Fac=0.8)
        vc.mapping.extend = extend
        # The X curve (over its default -1..1 range) bent; Y inverted; Z left straight.
        bend(vc.mapping.curves[0], [(-1.0, -1.0), (0.2, 0.7), (1.0, 0.3)])
        bend(vc.mapping.curves[1], [(-1.0, 1.0), (1.0, -1.0)])
        mapping = nodes.new("ShaderNodeMapping")  # uv to -1.5 .. 1.5 (past the curves' range)
        mapping.inputs["Scale"].default_value = (3.0, 3.0, 1.0)
        mapping.inputs["Location"].default_value = (-1.5, -1.5, 0.4)
        links.new(uv_socket(nodes, links), mapping.inputs["Vector"])
        links.new(mapping.outputs["Vector"], vc.inputs["Vector"])
        absolute = nodes.new("ShaderNodeVectorMath")
        absolute.operation = 'ABSOLUTE'
        links.new(vc.outputs["Vector"], absolute.inputs[0])
        return absolute.outputs["Vector"]
    ours, cycles = render_both(emission_plane_scene(color))
    assert_matches(ours, cycles, min_std=0.1)


def test_normal_node_dot_and_direction():
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 32
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("Dot")
        normal = nodes.new("ShaderNodeNormal")
        normal.outputs["Normal"].default_value = (0.3, -0.5, 0.8)
        geo = nodes.new("ShaderNodeNewGeometry")
        links.new(geo.outputs["Normal"], normal.inputs["Normal"])
        comb = nodes.new("ShaderNodeCombineXYZ")  # R: the dot, G, B: the direction's y, z
        links.new(normal.outputs["Dot"], comb.inputs["X"])
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(normal.outputs["Normal"], sep.inputs["Vector"])
        links.new(sep.outputs["Z"], comb.inputs["Z"])
        e = nodes.new("ShaderNodeEmission")
        links.new(comb.outputs["Vector"], e.inputs["Color"])
        links.new(e.outputs[0], out.inputs["Surface"])
        ms.add_sphere("Ball", 0.5, mat)
        ms.add_camera((0.0, -1.6, 0.6), (0.0, 0.0, 0.0))
        return scene
    ours, cycles = render_both(build)
    assert_matches(ours, cycles)
    assert ours[..., 0].max() > 0.8 and abs(ours[16, 16, 2] - 0.8 / np.sqrt(0.98)) < 1e-3


def test_curve_and_normal_nodes_export_without_a_warning():
    from addon.export import export_scene
    for fn in (lambda n, l: n.new("ShaderNodeFloatCurve").outputs[0],
               lambda n, l: n.new("ShaderNodeVectorCurve").outputs[0],
               lambda n, l: n.new("ShaderNodeNormal").outputs["Dot"]):
        emission_plane_scene(fn)()
        warn = Warnings()
        export_scene(bpy.context.evaluated_depsgraph_get(), warn)
        assert not warn, list(warn)
