"""The Attribute node's Object and Instancer types and the Normal Map node's object and world
spaces, against Cycles in the same bpy (issue 21), pixel by pixel (samples at the pixel
centres): object custom properties (float, vector), built-in RNA paths (the object colour),
the object's data, missing names; instancer properties of collection instances and particle
settings, geometry-nodes instance attributes; and the Normal Map's output in each space on a
rotated, unevenly scaled object (and one lit diffuse comparison)."""

import math

import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon, render_to_array
import material_scenes as ms
from test_scene_inputs import attribute_material, render_both, top_view

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def assert_same(ours, cycles, what=""):
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.mean() < 1e-4, f"{what}: mean abs difference {diff.mean():.2e}"
    assert diff.max() < 1e-3, f"{what}: max abs difference {diff.max():.2e}"


def attr_material(kind, name, output):
    return attribute_material("ShaderNodeAttribute", output, attribute_type=kind, attribute_name=name)


QUADS = [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
TINTS = [(0.9, 0.2, 0.1), (0.1, 0.7, 0.3), (0.2, 0.3, 0.95), (0.5, 0.45, 0.05)]


def quad_values(img):
    return [tuple(np.round(img[y, x, :3], 4)) for y in (8, 24) for x in (8, 24)]


OBJECT_CASES = {  # name read, what each of the four planes holds
    "custom float": ("gain", lambda obj, k: obj.__setitem__("gain", 0.2 + 0.2 * k)),
    "custom int": ("level", lambda obj, k: obj.__setitem__("level", k)),
    "custom vector": ("tint", lambda obj, k: obj.__setitem__("tint", TINTS[k])),
    "custom 4-vector": ("rgba", lambda obj, k: obj.__setitem__("rgba", TINTS[k] + (0.25 * k,))),
    "custom path": ('["tint"]', lambda obj, k: obj.__setitem__("tint", TINTS[k])),
    "object colour": ("color", lambda obj, k: setattr(obj, "color", TINTS[k] + (0.2 * k + 0.1,))),
    "scale": ("scale", lambda obj, k: setattr(obj, "scale", (0.6 + 0.1 * k, 0.9, 0.5))),
    "data property": ("meshval", lambda obj, k: obj.data.__setitem__("meshval", 0.15 * k + 0.1)),
    "data path": ('data["meshval"]', lambda obj, k: obj.data.__setitem__("meshval", 0.15 * k + 0.1)),
    "missing": ("nope", lambda obj, k: None),
}


@pytest.mark.parametrize("output", ["Color", "Vector", "Fac", "Alpha"])
@pytest.mark.parametrize("case", sorted(OBJECT_CASES))
def test_object_attributes_as_cycles_reads_them(case, output):
    name, setup = OBJECT_CASES[case]

    def build():
        scene = top_view(32)
        mat = attr_material('OBJECT', name, output)
        for k, (x, y) in enumerate(QUADS):
            obj = ms.add_plane(f"P{k}", 1.8, mat, location=(x, y, 0.0))
            obj.data = obj.data.copy()  # each its own data (its own data property)
            setup(obj, k)
        return scene
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"{case} {output}")
    if case != "missing" and not (output == "Alpha" and "4-vector" not in case and case != "object colour"):
        assert len(set(quad_values(ours))) >= 3, quad_values(ours)  # the planes tell apart
    if case == "missing":
        assert np.abs(ours[..., :3]).max() == 0.0


def instance_tinted(scene, coll, locations):
    """An empty instancing collection coll at each location, the k-th with the "tint" TINTS[k]."""
    for k, location in enumerate(locations):
        empty = bpy.data.objects.new(f"E{k}", None)
        empty.instance_type = 'COLLECTION'
        empty.instance_collection = coll
        empty.location = location
        empty["tint"] = TINTS[k]
        scene.collection.objects.link(empty)


def _instancer_scene(kind):
    """Four instances of a one-plane collection by four empties with their own "tint" (the
    instanced plane has one too: Instancer reads the empties', Object the plane's)."""
    scene = top_view(32)
    mat = attr_material(kind, "tint", "Color")
    coll = bpy.data.collections.new("Tile")
    tile = ms.add_plane("TilePlane", 1.8, mat)
    tile["tint"] = (0.3, 0.3, 0.3)
    scene.collection.objects.unlink(tile)
    coll.objects.link(tile)
    instance_tinted(scene, coll, [(x, y, 0.0) for x, y in QUADS])
    return scene


@pytest.mark.parametrize("kind", ["INSTANCER", "OBJECT"])
def test_collection_instance_attributes(kind):
    ours, cycles = render_both(lambda: _instancer_scene(kind))
    assert_same(ours, cycles, kind)
    expect = 4 if kind == "INSTANCER" else 1
    assert len(set(quad_values(ours))) == expect, quad_values(ours)


def _hair_particles(mat, count, radius):
    """A plane emitting `count` hair particles rendered as a hidden sphere of `radius` with
    material `mat`: returns (sphere, emitter, particle settings)."""
    tile = ms.add_sphere("Tile", radius, mat, segments=12, rings=6, location=(0.0, 0.0, -5.0))
    tile.hide_render = True
    emitter = ms.add_plane("Emitter", 3.0, None)
    emitter.modifiers.new("P", 'PARTICLE_SYSTEM')
    settings = emitter.particle_systems[0].settings
    settings.type = 'HAIR'
    settings.count = count
    settings.hair_length = 0.2
    settings.render_type = 'OBJECT'
    settings.instance_object = tile
    settings.particle_size = 1.0
    settings.use_rotation_instance = False
    emitter.show_instancer_for_render = False
    return tile, emitter, settings


def _particle_scene():
    """Hair particles rendered as a small sphere; the particle settings hold "tint", the
    emitter another (the settings win), the instanced sphere a third."""
    scene = top_view(32)
    tile, emitter, settings = _hair_particles(attr_material('INSTANCER', "tint", "Color"), 6, 0.3)
    tile["tint"] = (0.3, 0.3, 0.3)
    emitter["tint"] = (0.1, 0.1, 0.8)
    settings["tint"] = (0.8, 0.5, 0.1)
    return scene


def test_particle_instance_attributes():
    ours, cycles = render_both(_particle_scene)
    assert_same(ours, cycles, "particles")
    assert np.abs(ours[..., :3] - (0.8, 0.5, 0.1)).max(axis=-1).min() < 1e-4  # the settings' tint


def from_instancer_material(name, output):
    """Emission of the absolute value of the Texture Coordinate node's `output` From Instancer
    (output "UV Map": the UV Map node's From Instancer)."""
    mat, nodes, links, out = ms.new_material(name)
    if output == "UV Map":
        coord = nodes.new("ShaderNodeUVMap")
        output = "UV"
    else:
        coord = nodes.new("ShaderNodeTexCoord")
    coord.from_instancer = True
    absolute = nodes.new("ShaderNodeVectorMath")
    absolute.operation = 'ABSOLUTE'
    emit = nodes.new("ShaderNodeEmission")
    links.new(coord.outputs[output], absolute.inputs[0])
    links.new(absolute.outputs["Vector"], emit.inputs["Color"])
    links.new(emit.outputs[0], out.inputs["Surface"])
    return mat


def _particle_coords_scene(output):
    """Hair particles rendered as small spheres emitting their Texture Coordinate `output`
    From Instancer (through Absolute: Generated is negative), beside a plain sphere with the
    same material (no instance: 0). output "UV Map": the UV Map node's From Instancer."""
    scene = top_view(32)
    mat = from_instancer_material(f"FromInstancer{output}", output)
    _hair_particles(mat, 12, 0.25)
    ms.add_sphere("Plain", 0.3, mat, segments=12, rings=6, location=(1.2, 1.2, 0.3))
    return scene


@pytest.mark.parametrize("output", ["UV", "Generated", "UV Map"])
def test_texture_coordinates_from_instancer(output):
    ours, cycles = render_both(lambda: _particle_coords_scene(output))
    assert_same(ours, cycles, f"{output} from instancer")
    # Each particle reads its own place on the emitter: many different values.
    values = {tuple(v) for v in np.round(ours[..., :3].reshape(-1, 3), 3) if v.max() > 0.0}
    assert len(values) >= 6, values


def _gn_scene():
    """Geometry-nodes instances of a plane on a 4x4 grid, each with an instance attribute
    "tint" made from its index (Store Named Attribute on the Instance domain)."""
    scene = top_view(32)
    mat = attr_material('INSTANCER', "tint", "Color")
    tile = ms.add_plane("Tile", 0.9, mat)
    tile.hide_render = True
    host = ms.add_plane("Host", 0.01, None)
    host["tint"] = (0.0, 0.0, 1.0)  # an instance attribute comes first
    tree = ms.scatter_on_grid(host, tile, 3.0, 4)
    n = tree.nodes
    inst = next(x for x in n if x.bl_idname == "GeometryNodeInstanceOnPoints")
    out = next(x for x in n if x.bl_idname == "NodeGroupOutput")
    store = n.new("GeometryNodeStoreNamedAttribute")
    store.data_type = 'FLOAT_COLOR'
    store.domain = 'INSTANCE'
    store.inputs["Name"].default_value = "tint"
    index = n.new("GeometryNodeInputIndex")
    div = n.new("ShaderNodeMath")
    div.operation = 'DIVIDE'
    div.inputs[1].default_value = 16.0
    comb = n.new("FunctionNodeCombineColor")
    comb.inputs["Green"].default_value = 0.3
    tree.links.new(index.outputs[0], div.inputs[0])
    tree.links.new(div.outputs[0], comb.inputs["Red"])
    tree.links.new(comb.outputs[0], store.inputs["Value"])
    tree.links.new(inst.outputs["Instances"], store.inputs[0])
    tree.links.new(store.outputs[0], out.inputs[0])
    return scene


def test_geometry_nodes_instance_attributes():
    ours, cycles = render_both(_gn_scene)
    assert_same(ours, cycles, "geometry nodes instances")
    centres = np.linspace(4, 28, 4).astype(int)
    reds = {round(float(ours[y, x, 0]), 4) for y in centres for x in centres}
    assert len(reds) == 16, reds


def test_object_attributes_export_without_warnings():
    from addon.export import export_scene
    _instancer_scene('INSTANCER')
    for k, space in enumerate(SPACES):  # and Normal Maps in every non-tangent space
        ms.add_plane(f"N{k}", 0.5, normal_map_material(space, 0.5, emit_normal=False),
                     location=(0.0, 0.0, -1.0 - k))
    warnings = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert not warnings, warnings
    assert data.uv_sets.object_attributes == [('INSTANCER', "tint")]


# ---------------------------------------------------------------- normal map spaces

SPACES = ['OBJECT', 'WORLD', 'BLENDER_OBJECT', 'BLENDER_WORLD']


def normal_map_material(space, strength, emit_normal=True):
    """The Normal Map (space, strength) of a colour that varies over the surface (from the
    generated coordinates); emit_normal: emission n / 2 + 1/2 (else a diffuse BSDF's normal)."""
    mat, nodes, links, out = ms.new_material(f"NM{space}{strength}{emit_normal}")
    coords = nodes.new("ShaderNodeTexCoord")
    sep = nodes.new("ShaderNodeSeparateXYZ")
    comb = nodes.new("ShaderNodeCombineColor")
    links.new(coords.outputs["Generated"], sep.inputs[0])
    links.new(sep.outputs["X"], comb.inputs["Red"])
    links.new(sep.outputs["Y"], comb.inputs["Green"])
    # Facing out in the space's convention (the Blender ones negate z): a normal that
    # Strength blends with the shading one, not one nearly opposite to it.
    comb.inputs["Blue"].default_value = 0.2 if space.startswith("BLENDER") else 0.8
    nm = nodes.new("ShaderNodeNormalMap")
    nm.space = space
    nm.inputs["Strength"].default_value = strength
    links.new(comb.outputs[0], nm.inputs["Color"])
    if emit_normal:
        mad = nodes.new("ShaderNodeVectorMath")
        mad.operation = 'MULTIPLY_ADD'
        mad.inputs[1].default_value = (0.5, 0.5, 0.5)
        mad.inputs[2].default_value = (0.5, 0.5, 0.5)
        links.new(nm.outputs["Normal"], mad.inputs[0])
        emit = nodes.new("ShaderNodeEmission")
        links.new(mad.outputs[0], emit.inputs["Color"])
        links.new(emit.outputs[0], out.inputs["Surface"])
    else:
        d = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.8, 0.8, 0.8, 1.0))
        links.new(nm.outputs["Normal"], d.inputs["Normal"])
        links.new(d.outputs[0], out.inputs["Surface"])
    return mat


ROTATED = dict(rotation_euler=(0.35, -0.25, 0.6), scale=(1.3, 0.7, 1.0))


@pytest.mark.parametrize("strength", [1.0, 0.5])
@pytest.mark.parametrize("space", SPACES)
def test_normal_map_spaces_as_cycles(space, strength):
    def build():
        scene = top_view(32)
        ms.add_plane("Rotated", 2.6, normal_map_material(space, strength), **ROTATED)
        return scene
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"{space} {strength}")
    assert ours[..., :3].std() > 0.02  # the normal varies over the plane


def test_normal_map_spaces_differ():
    """Object space turns with the object, world space does not; the Blender variants flip."""
    images = {}
    for space in SPACES:
        def build():
            scene = top_view(16)
            ms.add_plane("Rotated", 2.6, normal_map_material(space, 1.0), **ROTATED)
            return scene
        images[space] = render_to_array(build(), "PATHLIGHT", samples=1, max_bounces=1,
                                        pixel_filter_type='BOX', filter_width=0.01)[8, 8, :3]
    values = {tuple(np.round(v, 3)) for v in images.values()}
    assert len(values) == 4, images


def test_normal_map_object_space_lit_as_cycles():
    """A diffuse sphere under a sun with an object-space normal map, rotated: the shading
    agrees with Cycles by regions."""
    def build():
        scene = top_view(48)
        ms.set_world((0.05, 0.05, 0.05))
        ms.add_sphere("Ball", 1.5, normal_map_material('OBJECT', 0.8, emit_normal=False),
                      segments=32, rings=16, rotation_euler=(0.4, 0.3, 1.1))
        sun = ms.add_sun(3.0)
        sun.rotation_euler = (math.radians(35.0), 0.0, math.radians(-30.0))
        return scene
    ours, cycles = ms.render_pair(build, 64, bounces=2)
    ms.assert_agree(ours, cycles, "object-space normal map, lit", region=0.05, whole=0.02)


def test_persistent_data_takes_a_changed_object_attribute():
    """A kept core scene (persistent data) holds the instances' attribute values: a changed
    custom property renders its new value, as a fresh render does."""
    from addon import render_cache
    render_cache.clear()
    scene = top_view(16)
    obj = ms.add_plane("P", 3.0, attr_material('OBJECT', "gain", "Color"))
    obj["gain"] = 0.25
    scene.render.use_persistent_data = True
    try:
        first = render_to_array(scene, samples=1, pixel_filter_type='BOX', filter_width=0.01)
        obj["gain"] = 0.75
        obj.update_tag(refresh={"OBJECT"})  # as the UI tags it (not the geometry)
        second = render_to_array(scene, samples=1, pixel_filter_type='BOX', filter_width=0.01)
    finally:
        scene.render.use_persistent_data = False
        render_cache.clear()
    assert np.allclose(first[8, 8, :3], 0.25, atol=1e-5), first[8, 8]
    assert np.allclose(second[8, 8, :3], 0.75, atol=1e-5), second[8, 8]


# ---------------------------------------------------------------- Curves objects (hair)

BANDS = [-1.5 + k + 0.0625 for k in range(4)]  # on pixel centres: strand edges 0.025 from the next


def add_strands(name, mat, ys=(-0.25, 0.0, 0.25), length=6.0, radius=0.1, link=True, **transform):
    """A Curves object of straight poly strands along x through each local y of `ys`, longer
    than the frame (no strand ends in view), their edges between pixel centres."""
    curves = bpy.data.hair_curves.new(name)
    curves.add_curves([2] * len(ys))
    pts = np.array([[(-length / 2, y, 0.0), (length / 2, y, 0.0)] for y in ys], np.float32)
    curves.attributes["position"].data.foreach_set("vector", pts.ravel())
    r = curves.attributes.new("radius", 'FLOAT', 'POINT')
    r.data.foreach_set("value", np.full(2 * len(ys), radius, np.float32))
    curves.set_types(type='POLY')
    curves.materials.append(mat)
    obj = bpy.data.objects.new(name, curves)
    for k, v in transform.items():
        setattr(obj, k, v)
    if link:
        bpy.context.scene.collection.objects.link(obj)
    return obj


def curves_view(resolution=32):
    scene = top_view(resolution)
    scene.cycles_curves.shape = 'THICK'  # Cycles' 3D curves, as Pathlight traces them
    return scene


def band_values(img):
    """The distinct non-black colours of an image (rounded)."""
    px = np.round(img[..., :3].reshape(-1, 3).astype(np.float64), 4)
    return {tuple(float(x) for x in v) for v in px if v.max() > 0.0}


@pytest.mark.parametrize("case", ["custom vector", "custom float", "object colour", "data property", "missing"])
def test_curves_object_attributes_as_cycles(case):
    """Four Curves objects (bands of strands), each with its own value: Object attributes on
    strands read their object's, as Cycles' do."""
    name, setup = OBJECT_CASES[case]

    def build():
        scene = curves_view()
        mat = attr_material('OBJECT', name, "Color")
        for k, y in enumerate(BANDS):
            setup(add_strands(f"H{k}", mat, location=(0.0, y, 0.0)), k)
        return scene
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"curves {case}")
    if case == "missing":
        assert np.abs(ours[..., :3]).max() == 0.0
    else:
        assert len(band_values(ours)) == 4, band_values(ours)


def _curves_collection_scene(kind):
    """Four collection instances of a Curves object by empties with their own "tint" (the
    Curves object has one too)."""
    scene = curves_view()
    coll = bpy.data.collections.new("Tuft")
    tile = add_strands("Tuft", attr_material(kind, "tint", "Color"), link=False)
    tile["tint"] = (0.3, 0.3, 0.3)
    coll.objects.link(tile)
    instance_tinted(scene, coll, [(0.0, y, 0.0) for y in BANDS])
    return scene


@pytest.mark.parametrize("kind", ["INSTANCER", "OBJECT"])
def test_curves_collection_instance_attributes(kind):
    ours, cycles = render_both(lambda: _curves_collection_scene(kind))
    assert_same(ours, cycles, f"curves {kind}")
    values = band_values(ours)
    if kind == "INSTANCER":
        assert values == set(TINTS), values
    else:
        assert values == {(0.3, 0.3, 0.3)}, values


def store_index_colour(tree, geometry, name, scale, green):
    """Store Named Attribute `name` on the Instance domain of `geometry` (a socket): the colour
    (index * scale, green, 0). Returns the node."""
    n, link = tree.nodes, tree.links.new
    store = n.new("GeometryNodeStoreNamedAttribute")
    store.data_type = 'FLOAT_COLOR'
    store.domain = 'INSTANCE'
    store.inputs["Name"].default_value = name
    index = n.new("GeometryNodeInputIndex")
    mul = n.new("ShaderNodeMath")
    mul.operation = 'MULTIPLY'
    mul.inputs[1].default_value = scale
    comb = n.new("FunctionNodeCombineColor")
    comb.inputs["Green"].default_value = green
    link(index.outputs[0], mul.inputs[0])
    link(mul.outputs[0], comb.inputs["Red"])
    link(comb.outputs[0], store.inputs["Value"])
    link(geometry, store.inputs[0])
    return store


def _curves_gn_scene():
    """A Curves object instanced by geometry nodes on a column of four points (the bands), as
    an object (Object Info's As Instance: instanced as geometry, Blender 4.5 makes legacy
    curves of them, which neither engine renders as hair), each instance with an instance
    attribute "tint" from its index."""
    scene = curves_view()
    tile = add_strands("Tuft", attr_material('INSTANCER', "tint", "Color"))
    tile.hide_render = True
    host = ms.add_plane("Host", 0.01, None, location=(0.0, 0.0625, 0.0))
    tree = ms.scatter_on_grid(host, tile, 3.0, 4)
    inst = next(x for x in tree.nodes if x.bl_idname == "GeometryNodeInstanceOnPoints")
    line = tree.nodes.new("GeometryNodeMeshLine")  # the points: a column, not the grid
    line.inputs["Count"].default_value = 4
    line.inputs["Start Location"].default_value = (0.0, -1.5, 0.0)
    line.inputs["Offset"].default_value = (0.0, 1.0, 0.0)
    tree.links.new(line.outputs[0], inst.inputs["Points"])
    info = next(x for x in tree.nodes if x.bl_idname == "GeometryNodeObjectInfo")
    info.inputs["As Instance"].default_value = True
    out = next(x for x in tree.nodes if x.bl_idname == "NodeGroupOutput")
    store = store_index_colour(tree, inst.outputs["Instances"], "tint", 0.25, 0.3)
    tree.links.new(store.outputs[0], out.inputs[0])
    return scene


def test_curves_geometry_nodes_instance_attributes():
    ours, cycles = render_both(_curves_gn_scene)
    assert_same(ours, cycles, "curves geometry nodes instances")
    assert band_values(ours) == {(round(0.25 * k, 4), 0.3, 0.0) for k in range(4)}, band_values(ours)


def _curves_particle_coords_scene(output):
    """Hair particles rendered as a short Curves tuft emitting their Texture Coordinate
    `output` From Instancer (through Absolute)."""
    scene = curves_view()
    mat = from_instancer_material(f"CurvesFromInstancer{output}", output)
    tuft = add_strands("Tuft", mat, ys=(0.0,), length=0.5, radius=0.06, location=(0.0, 0.0, -5.0))
    tuft.hide_render = True
    emitter = ms.add_plane("Emitter", 3.0, None)
    emitter.modifiers.new("P", 'PARTICLE_SYSTEM')
    settings = emitter.particle_systems[0].settings
    settings.type = 'HAIR'
    settings.count = 12
    settings.hair_length = 1.0  # (the instances' scale: the tuft lies flat along world y)
    settings.render_type = 'OBJECT'
    settings.instance_object = tuft
    settings.particle_size = 1.0
    settings.use_rotation_instance = False
    emitter.show_instancer_for_render = False
    return scene


@pytest.mark.parametrize("output", ["UV", "Generated"])
def test_curves_texture_coordinates_from_instancer(output):
    """Where both engines hit a strand they read the same From Instancer value; the strands'
    round ends may differ by a pixel (at most 2 % of the image)."""
    ours, cycles = render_both(lambda: _curves_particle_coords_scene(output))
    hit_ours, hit_cycles = ours[..., :3].max(-1) > 0.0, cycles[..., :3].max(-1) > 0.0
    assert (hit_ours != hit_cycles).mean() <= 0.02, (hit_ours != hit_cycles).mean()
    both = hit_ours & hit_cycles
    assert both.sum() >= 40, both.sum()
    diff = np.abs(ours[both][:, :3] - cycles[both][:, :3])
    assert diff.max() < 1e-3, diff.max()
    assert len(band_values(ours)) >= 6, band_values(ours)  # each particle its own place


# ---------------------------------------------------------------- nested geometry-nodes instances

def _nested_gn_scene(material_name, ids=False):
    """Geometry-nodes instances of instances: a plane instanced on a 2x2 grid (inner attribute
    "tint" from the inner index, and "inner"), that group instanced on a 2x2 grid (an outer
    "tint" that the inner one hides, and "outer"): 16 planes. ids: the outer points carry an
    "id" attribute (as scattered points do), which Blender's persistent ids then hold instead
    of the index."""
    scene = top_view(32)
    tile = ms.add_plane("Tile", 0.45, attr_material('INSTANCER', material_name, "Color"))
    tile.hide_render = True
    host = ms.add_plane("Host", 0.01, None)
    host["tint"] = (0.0, 0.0, 1.0)  # instance attributes come first
    tree = bpy.data.node_groups.new("Nested", 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    n, link = tree.nodes, tree.links.new

    def grid(size):
        g = n.new("GeometryNodeMeshGrid")
        g.inputs["Size X"].default_value = g.inputs["Size Y"].default_value = size
        g.inputs["Vertices X"].default_value = g.inputs["Vertices Y"].default_value = 2
        return g
    inner_grid, outer_grid = grid(1.0), grid(2.0)
    inner = n.new("GeometryNodeInstanceOnPoints")
    info = n.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = tile
    link(inner_grid.outputs["Mesh"], inner.inputs["Points"])
    link(info.outputs["Geometry"], inner.inputs["Instance"])
    s1 = store_index_colour(tree, inner.outputs["Instances"], "tint", 0.25, 0.1)
    s2 = store_index_colour(tree, s1.outputs[0], "inner", 0.25, 0.2)
    outer = n.new("GeometryNodeInstanceOnPoints")
    points = outer_grid.outputs["Mesh"]
    if ids:
        store_id = n.new("GeometryNodeStoreNamedAttribute")
        store_id.data_type = 'INT'
        store_id.domain = 'POINT'
        store_id.inputs["Name"].default_value = "id"
        index = n.new("GeometryNodeInputIndex")
        scramble = n.new("ShaderNodeMath")  # 40 - 9 index: ids unlike any index
        scramble.operation = 'MULTIPLY_ADD'
        scramble.inputs[1].default_value = -9.0
        scramble.inputs[2].default_value = 40.0
        link(index.outputs[0], scramble.inputs[0])
        link(scramble.outputs[0], store_id.inputs["Value"])
        link(points, store_id.inputs[0])
        points = store_id.outputs[0]
    link(points, outer.inputs["Points"])
    link(s2.outputs[0], outer.inputs["Instance"])
    s3 = store_index_colour(tree, outer.outputs["Instances"], "tint", 0.1, 0.9)
    s4 = store_index_colour(tree, s3.outputs[0], "outer", 0.2, 0.9)
    out = n.new("NodeGroupOutput")
    link(s4.outputs[0], out.inputs[0])
    host.modifiers.new("Nested", 'NODES').node_group = tree
    return scene


@pytest.mark.parametrize("name, expect, ids", [
    ("tint", {(0.25 * i, 0.1, 0.0) for i in range(4)}, False),  # the inner level's hides the outer's
    ("inner", {(0.25 * i, 0.2, 0.0) for i in range(4)}, False),
    ("outer", {(0.2 * j, 0.9, 0.0) for j in range(4)}, False),  # only the outer level has it
    ("tint", {(0.25 * i, 0.1, 0.0) for i in range(4)}, True),
    ("outer", {(0.2 * j, 0.9, 0.0) for j in range(4)}, True),
])
def test_nested_geometry_nodes_instance_attributes(name, expect, ids):
    ours, cycles = render_both(lambda: _nested_gn_scene(name, ids))
    assert_same(ours, cycles, f"nested {name}")
    got = band_values(ours)
    assert got == {tuple(round(x, 4) for x in v) for v in expect}, got


def _face_instances_scene():
    """A plane instanced on the faces of a 2x2 grid (legacy face instancing, no geometry
    nodes) whose "id" property the material reads as an Instancer attribute: bpy's evaluated
    geometry lists these instances with an "id" attribute of their own, which Cycles does not
    read (only geometry-nodes instances have instance attributes)."""
    import bmesh
    scene = top_view(32)
    me = bpy.data.meshes.new("Grid")
    bm = bmesh.new()
    bmesh.ops.create_grid(bm, x_segments=2, y_segments=2, size=1.5)
    bm.to_mesh(me)
    bm.free()
    parent = bpy.data.objects.new("Faces", me)
    scene.collection.objects.link(parent)
    parent.instance_type = 'FACES'
    parent.show_instancer_for_render = False
    parent["id"] = 0.7
    child = ms.add_plane("Child", 1.2, attr_material('INSTANCER', "id", "Color"))
    child.parent = parent
    return scene


def test_face_instances_read_the_instancer_not_legacy_ids():
    ours, cycles = render_both(_face_instances_scene)
    assert_same(ours, cycles, "face instances")
    assert band_values(ours) == {(0.7, 0.7, 0.7)}, band_values(ours)
