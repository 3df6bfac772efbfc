"""Scene inputs against Cycles in the same bpy (issue 21): the Object Info node on plain objects
(colour, alpha, pass index, location, the random number Cycles derives from the object's name)
and on geometry-nodes instances (Blender's per-instance random id); mesh attributes through the
Attribute and Color Attribute nodes (point, corner and face domains; float, vector, 2D and
colour types; byte colours); the Geometry node's True Normal, Incoming, Parametric and
Backfacing; all compared pixel by pixel (samples at the pixel centres). The Light Path node's
outputs drive a floor's colour seen directly, in a mirror, through glass and behind a
transparent card, compared with Cycles at 256 samples by regions."""

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

# Tiny box filter: every sample at the pixel centre, so both engines see the same points.
CENTRES = dict(pixel_filter_type='BOX', filter_width=0.01)


def info_material(output, scale=1.0, name=None, offset=0.0):
    """Emission = Object Info's `output` * `scale` + `offset` (emission is positive in
    Pathlight, Cycles lets it go negative), Material Index from pass_index 3."""
    mat, nodes, links, out = ms.new_material(name or f"Info{output}")
    mat.pass_index = 3
    info = nodes.new("ShaderNodeObjectInfo")
    emit = nodes.new("ShaderNodeEmission")
    src = info.outputs[output]
    if scale != 1.0 or offset != 0.0:
        mul = nodes.new("ShaderNodeVectorMath")
        mul.operation = 'MULTIPLY_ADD'
        mul.inputs[1].default_value = (scale,) * 3
        mul.inputs[2].default_value = (offset,) * 3
        links.new(src, mul.inputs[0])
        src = mul.outputs[0]
    links.new(src, emit.inputs["Color"])
    links.new(emit.outputs[0], out.inputs["Surface"])
    return mat


def top_view(resolution):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_percentage = 100
    scene.render.resolution_x = scene.render.resolution_y = resolution
    ms.set_world((0.0, 0.0, 0.0))
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = 4.0
    cam.location = (0.0, 0.0, 5.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    return scene


PLANES = [  # name, location, colour, pass index
    ("Alpha", (-1.0, -1.0, 0.0), (0.9, 0.2, 0.1, 0.25), 2),
    ("Beta", (1.0, -1.0, 0.0), (0.1, 0.7, 0.3, 0.5), 5),
    ("Gamma Ω", (-1.0, 1.0, 0.0), (0.2, 0.3, 0.95, 0.75), 7),  # a non-ASCII name
    ("Delta.001", (1.0, 1.0, 0.0), (0.5, 0.5, 0.5, 1.0), 0),
]


def planes_scene(output, scale, offset):
    def build():
        scene = top_view(32)
        mat = info_material(output, scale, offset=offset)
        for name, loc, color, index in PLANES:
            obj = ms.add_plane(name, 1.8, mat, location=loc)
            obj.color = color
            obj.pass_index = index
        return scene
    return build


def render_both(build, samples=1):
    ours = render_to_array(build(), "PATHLIGHT", samples=samples, max_bounces=1, **CENTRES)
    cycles = render_to_array(build(), "CYCLES", samples=samples, max_bounces=1, **CENTRES)
    return ours, cycles


@pytest.mark.parametrize("output, scale, offset", [
    ("Color", 1.0, 0.0), ("Alpha", 1.0, 0.0), ("Object Index", 0.1, 0.0),
    ("Material Index", 0.1, 0.0), ("Random", 1.0, 0.0), ("Location", 0.4, 0.5),
])
def test_object_info_of_plain_objects(output, scale, offset):
    ours, cycles = render_both(planes_scene(output, scale, offset))
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.mean() < 1e-4, f"mean abs difference {diff.mean():.2e}"
    assert diff.max() < 1e-3, f"max abs difference {diff.max():.2e}"
    if output != "Material Index":  # the planes tell apart
        quads = [ours[8, 8, :3], ours[8, 24, :3], ours[24, 8, :3], ours[24, 24, :3]]
        assert len({tuple(np.round(q, 4)) for q in quads}) == 4, quads
    else:
        assert np.allclose(ours[8, 8, :3], 0.3, atol=1e-6)


def instances_scene():
    """A 4x4 grid of small planes as geometry-nodes instances on one object."""
    scene = top_view(32)
    mat = info_material("Random", name="InstRandom")
    # The instanced plane: a separate object, hidden, referenced by the node tree.
    tile = ms.add_plane("Tile", 0.9, mat)
    tile.hide_render = True
    host = ms.add_plane("Host", 0.01, None)
    ms.scatter_on_grid(host, tile, 3.0, 4)
    return scene


def test_object_info_random_of_instances():
    ours, cycles = render_both(instances_scene)
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.mean() < 1e-4, f"mean abs difference {diff.mean():.2e}"
    # Sixteen instances, sixteen different random numbers.
    centres = np.linspace(4, 28, 4).astype(int)
    values = {round(float(ours[y, x, 0]), 5) for y in centres for x in centres}
    assert len(values) == 16, values


def test_object_random_id_is_cycles_name_hash():
    pc = load_addon().core.get_core()
    # The same name, the same id; a different name, another one (the render test above checks
    # the values against Cycles, a non-ASCII name included).
    assert pc.object_random_id("Cube") == pc.object_random_id("Cube")
    ids = {pc.object_random_id(n) for n in ("Cube", "Cube.001", "Gamma Ω", "")}
    assert len(ids) == 4


# ---------------------------------------------------------------- attributes

def attribute_grid(name="Grid", size=3.6, cuts=5):
    """A subdivided plane with attributes on every domain, deterministic pseudo-random values."""
    obj = ms.add_mesh_object(name, lambda bm: __import__("bmesh").ops.create_grid(
        bm, x_segments=cuts, y_segments=cuts, size=size / 2))
    mesh = obj.data
    rng = np.random.default_rng(7)

    def fill(attr_name, data_type, domain, width, field):
        attr = mesh.attributes.new(attr_name, data_type, domain)
        vals = rng.uniform(0.05, 0.95, len(attr.data) * width).astype(np.float32)
        attr.data.foreach_set(field, vals)
        return attr
    byte = mesh.color_attributes.new("Paint", 'BYTE_COLOR', 'CORNER')
    byte.data.foreach_set("color", rng.uniform(0.0, 1.0, len(byte.data) * 4).astype(np.float32))
    mesh.color_attributes.new("Other", 'FLOAT_COLOR', 'POINT')  # not the render one
    mesh.color_attributes.render_color_index = 0
    fill("pcol", 'FLOAT_COLOR', 'POINT', 4, "color")
    fill("pfloat", 'FLOAT', 'POINT', 1, "value")
    fill("fvec", 'FLOAT_VECTOR', 'FACE', 3, "vector")
    fill("cuv", 'FLOAT2', 'CORNER', 2, "vector")
    return obj


def attribute_material(node_type, output, **props):
    mat, nodes, links, out = ms.new_material(f"A{node_type}{output}{sorted(props.items())}")
    node = nodes.new(node_type)
    for k, v in props.items():
        setattr(node, k, v)
    emit = nodes.new("ShaderNodeEmission")
    links.new(node.outputs[output], emit.inputs["Color"])
    links.new(emit.outputs[0], out.inputs["Surface"])
    return mat


@pytest.mark.parametrize("node_type, output, props", [
    ("ShaderNodeVertexColor", "Color", {}),  # the render colour attribute (byte, corners)
    ("ShaderNodeVertexColor", "Alpha", {}),
    ("ShaderNodeVertexColor", "Color", {"layer_name": "pcol"}),
    ("ShaderNodeAttribute", "Color", {"attribute_name": "pcol"}),
    ("ShaderNodeAttribute", "Alpha", {"attribute_name": "pcol"}),
    ("ShaderNodeAttribute", "Fac", {"attribute_name": "pfloat"}),
    ("ShaderNodeAttribute", "Color", {"attribute_name": "pfloat"}),
    ("ShaderNodeAttribute", "Vector", {"attribute_name": "fvec"}),
    ("ShaderNodeAttribute", "Fac", {"attribute_name": "fvec"}),
    ("ShaderNodeAttribute", "Vector", {"attribute_name": "cuv"}),
    ("ShaderNodeAttribute", "Color", {"attribute_name": "Paint"}),
])
def test_mesh_attributes_as_cycles_reads_them(node_type, output, props):
    def build():
        scene = top_view(32)
        grid = attribute_grid()
        grid.data.materials.append(attribute_material(node_type, output, **props))
        return scene
    ours, cycles = render_both(build)
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.mean() < 2e-4, f"mean abs difference {diff.mean():.2e}"
    assert diff.max() < 2e-3, f"max abs difference {diff.max():.2e}"
    assert ours[..., :3].std() > 0.05  # the values vary over the grid


def test_missing_attribute_reads_zero_with_a_warning():
    from blender_util import Warnings
    from addon.export import export_scene
    def build():
        scene = top_view(16)
        grid = attribute_grid()
        grid.data.materials.append(attribute_material("ShaderNodeAttribute", "Color",
                                                      attribute_name="nope"))
        return scene
    ours, cycles = render_both(build)
    assert np.abs(ours[..., :3]).max() == 0.0 and np.abs(cycles[..., :3]).max() == 0.0
    warnings = Warnings()
    export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert any("no attribute 'nope'" in w for w in warnings), warnings



@pytest.mark.parametrize("node_type, output, props", [
    ("ShaderNodeAttribute", "Alpha", {"attribute_name": "nope"}),
    ("ShaderNodeAttribute", "Fac", {"attribute_name": "nope"}),
    ("ShaderNodeAttribute", "Color", {"attribute_name": "nope"}),
    ("ShaderNodeVertexColor", "Alpha", {"layer_name": "nope"}),
])
def test_missing_mesh_attribute_outputs_as_cycles(node_type, output, props):
    """Cycles' svm_node_attr reads a missing attribute as 0 but the Attribute node's Alpha as 1
    (the Color Attribute node's as 0)."""
    def build():
        scene = top_view(16)
        ms.add_sphere("Ball", 1.5, attribute_material(node_type, output, **props), segments=16, rings=8)
        return scene
    ours, cycles = render_both(build)
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.max() < 1e-3, f"max abs difference {diff.max():.2e}"
    expect = 1.0 if (node_type, output) == ("ShaderNodeAttribute", "Alpha") else 0.0
    assert np.isclose(ours[8, 8, :3], expect, atol=1e-4).all(), ours[8, 8]

VIEW_LAYER_PROPS = {  # where the property is set, its name and value
    "view layer float": ("view_layer", "vl_gain", 0.35),
    "view layer vector": ("view_layer", "vl_tint", [0.2, 0.55, 0.9]),
    "view layer 4-vector": ("view_layer", "vl_rgba", [0.6, 0.3, 0.1, 0.4]),
    "scene int": ("scene", "sc_count", 3),
    "scene bool": ("scene", "sc_flag", True),
    "world custom": ("world", "wd_level", 0.7),
    "shadowed by the view layer": ("both", "shared", 0.25),
}


@pytest.mark.parametrize("output", ["Color", "Fac", "Alpha", "Vector"])
@pytest.mark.parametrize("case", sorted(VIEW_LAYER_PROPS) + ["built-in world colour", "missing"])
def test_view_layer_attributes_as_cycles_reads_them(case, output):
    def build():
        scene = top_view(16)
        world = scene.world or bpy.data.worlds.new("World")
        scene.world = world
        world.color = (0.15, 0.45, 0.65)
        name = {"built-in world colour": "color", "missing": "nope"}.get(case)
        if name is None:
            where, name, value = VIEW_LAYER_PROPS[case]
            holders = {"view_layer": [scene.view_layers[0]], "scene": [scene], "world": [world],
                       "both": [scene.view_layers[0], scene]}[where]
            for k, h in enumerate(holders):
                h[name] = value if k == 0 else 0.9  # the first holder's value wins
        grid = attribute_grid()
        grid.data.materials.append(attribute_material("ShaderNodeAttribute", output,
                                                      attribute_type='VIEW_LAYER', attribute_name=name))
        return scene
    ours, cycles = render_both(build)
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.max() < 2e-3, f"{case} {output}: ours {ours[8, 8, :3]}, Cycles {cycles[8, 8, :3]}"
    if case != "missing":  # Cycles found the property: the comparison is not of two zeros
        assert cycles[..., :3].max() > 0.05


# ---------------------------------------------------------------- light path and geometry

def driven_material(name, output_of, node_type="ShaderNodeLightPath", scale=1.0):
    """Diffuse whose colour mixes dark grey into orange by a node's output (times `scale`)."""
    mat, nodes, links, out = ms.new_material(name)
    src = nodes.new(node_type)
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = 'RGBA'
    mix.clamp_factor = True
    fac = src.outputs[output_of]
    if scale != 1.0:
        mul = nodes.new("ShaderNodeMath")
        mul.operation = 'MULTIPLY'
        mul.inputs[1].default_value = scale
        links.new(fac, mul.inputs[0])
        fac = mul.outputs[0]
    links.new(fac, mix.inputs["Factor"])
    [s for s in mix.inputs if s.identifier == "A_Color"][0].default_value = (0.15, 0.15, 0.15, 1)
    [s for s in mix.inputs if s.identifier == "B_Color"][0].default_value = (0.9, 0.6, 0.3, 1)
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new([s for s in mix.outputs if s.identifier == "Result_Color"][0], d.inputs["Color"])
    links.new(d.outputs[0], out.inputs["Surface"])
    return mat


def light_path_scene(output, scale):
    """A floor whose colour follows a Light Path output, seen directly, in a mirror ball,
    through a glass ball and behind a half-transparent card, lit by a panel."""
    def build():
        scene = ms.studio(size=48, world=(0.1, 0.1, 0.1),
                          camera=((0.0, -4.5, 2.4), (0.0, 0.0, 0.4)))
        bpy.data.objects["Floor"].data.materials[0] = driven_material("Driven", output, scale=scale)
        ms.add_sphere("Mirror", 0.45, ms.glossy("Mirror", roughness=0.0), location=(-0.8, 0.3, 0.45))
        glass, node = ms.bsdf_material("Glass", "ShaderNodeBsdfGlass", Roughness=0.0, IOR=1.45)
        node.distribution = 'GGX'
        ms.add_sphere("Glass", 0.45, glass, location=(0.8, 0.3, 0.45))
        card, nodes, links, out = ms.new_material("Card")
        mix = nodes.new("ShaderNodeMixShader")
        mix.inputs["Fac"].default_value = 0.5
        links.new(nodes.new("ShaderNodeBsdfTransparent").outputs[0], mix.inputs[1])
        links.new(ms.set_inputs(nodes.new("ShaderNodeBsdfGlossy"), Roughness=0.3).outputs[0],
                  mix.inputs[2])
        links.new(mix.outputs[0], out.inputs["Surface"])
        ms.add_plane("Card", 0.7, card, location=(0.0, -1.2, 0.5), rotation_euler=(1.4, 0.0, 0.0))
        return scene
    return build


@pytest.mark.parametrize("output, scale", [
    ("Is Camera Ray", 1.0), ("Is Diffuse Ray", 1.0), ("Is Glossy Ray", 1.0),
    ("Is Singular Ray", 1.0), ("Is Reflection Ray", 1.0), ("Is Transmission Ray", 1.0),
    ("Ray Length", 0.2), ("Ray Depth", 0.5), ("Diffuse Depth", 0.5), ("Glossy Depth", 0.5),
    ("Transparent Depth", 1.0), ("Transmission Depth", 0.5),
])
def test_light_path_outputs_match_cycles(output, scale):
    build = light_path_scene(output, scale)
    ours = render_to_array(build(), "PATHLIGHT", samples=256, max_bounces=8)
    cycles = render_to_array(build(), "CYCLES", samples=256, max_bounces=8, **BOX_FILTER)
    ratio, worst, rel = ms.compare(ours, cycles, grid=6)
    assert abs(ratio - 1.0) < 0.02, f"image mean ratio {ratio:.4f}"
    assert worst < 0.06, f"worst region {worst:.3f}\n{np.round(rel, 3)}"


@pytest.mark.parametrize("output", ["True Normal", "Incoming", "Parametric", "Backfacing"])
def test_geometry_outputs_match_cycles(output):
    """Emission = a Geometry output (vectors mapped by 0.5 v + 0.5) on a smooth sphere and a
    plane seen from behind, per pixel at the pixel centres."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 32
        scene.render.resolution_percentage = 100
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("Geo")
        geo = nodes.new("ShaderNodeNewGeometry")
        emit = nodes.new("ShaderNodeEmission")
        src = geo.outputs[output]
        if output != "Backfacing":
            vm = nodes.new("ShaderNodeVectorMath")
            vm.operation = 'MULTIPLY_ADD'
            vm.inputs[1].default_value = (0.5, 0.5, 0.5)
            vm.inputs[2].default_value = (0.5, 0.5, 0.5)
            links.new(src, vm.inputs[0])
            src = vm.outputs[0]
        links.new(src, emit.inputs["Color"])
        links.new(emit.outputs[0], out.inputs["Surface"])
        ms.add_sphere("Ball", 0.6, mat, segments=16, rings=8, location=(-0.7, 0.0, 0.6))
        ms.add_plane("Back", 1.2, mat, location=(0.8, 0.0, 0.6), rotation_euler=(-1.2, 0.0, 0.3))
        ms.add_camera((0.0, -4.0, 1.2), (0.0, 0.0, 0.6))
        return scene
    ours, cycles = render_both(build)
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.mean() < 1e-3, f"mean abs difference {diff.mean():.2e}"


def test_random_per_island_matches_cycles():
    """Geometry ▸ Random Per Island as emission on one mesh of nine separate islands (cubes and
    a grid, joined in an order that makes the disjoint set's roots non-trivial), per pixel: the
    same random number per island as Cycles (its union-by-rank roots, hashed)."""
    import bmesh  # after bpy

    def build():
        scene = top_view(48)
        mat, nodes, links, out = ms.new_material("Island")
        geo = nodes.new("ShaderNodeNewGeometry")
        emit = nodes.new("ShaderNodeEmission")
        links.new(geo.outputs["Random Per Island"], emit.inputs["Color"])
        links.new(emit.outputs[0], out.inputs["Surface"])

        def islands(bm):
            for i in range(8):
                x, y = -1.5 + (i % 4), -0.6 + 1.2 * (i // 4)
                m = bmesh.ops.create_cube(bm, size=0.7)
                bmesh.ops.translate(bm, vec=(x, y, 0.0), verts=m["verts"])
            g = bmesh.ops.create_grid(bm, x_segments=3, y_segments=2, size=0.3)
            bmesh.ops.translate(bm, vec=(0.0, 0.0, 0.6), verts=g["verts"])
        ms.add_mesh_object("Islands", islands, (mat,))
        return scene
    ours, cycles = render_both(build)
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.mean() < 1e-4, f"mean abs difference {diff.mean():.2e}"
    assert diff.max() < 1e-3, f"max abs difference {diff.max():.2e}"
    values = {round(float(v), 5) for v in ours[..., 0].ravel() if v > 0.0}
    assert len(values) >= 8, values  # the islands differ
