"""Small Blender scenes for the material tests (issue 3): node materials built in code, a
studio (floor, emissive panel, dim world, camera) and per-region comparisons.

Each builder starts from an empty factory scene, so Pathlight and Cycles render the very
same data."""

import math

import bmesh
import bpy
import numpy as np
from mathutils import Vector

from blender_util import BOX_FILTER, canonical_order, render_to_array
# The one region_means (grid x grid region means of RGB, edges cropped): pure numpy, shared
# with the core tests; the Blender tests import it from here.
from core_scenes import region_means  # noqa: F401



# ---------------------------------------------------------------- node materials

def new_material(name):
    """A material with nodes and only a Material Output (returned as (mat, nodes, links, out))."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    return mat, nodes, links, out


def set_inputs(node, **inputs):
    for name, value in inputs.items():
        node.inputs[name.replace("_", " ")].default_value = value
    return node


def bsdf_material(name, node_type, **inputs):
    """A material whose Surface is one node of node_type with constant inputs (input names with
    '_' for ' ', e.g. Base_Color). Returns (mat, node)."""
    mat, nodes, links, out = new_material(name)
    node = set_inputs(nodes.new(node_type), **inputs)
    links.new(node.outputs[0], out.inputs["Surface"])
    return mat, node


def diffuse(name, color):
    return bsdf_material(name, "ShaderNodeBsdfDiffuse", Color=(*color, 1.0))[0]


def emission(name, color, strength):
    return bsdf_material(name, "ShaderNodeEmission", Color=(*color, 1.0), Strength=strength)[0]


def glossy(name, color=(0.9, 0.9, 0.9), roughness=0.0, distribution='GGX'):
    mat, node = bsdf_material(name, "ShaderNodeBsdfGlossy", Color=(*color, 1.0),
                              Roughness=roughness)
    node.distribution = distribution
    return mat


def mix_diffuse_glossy(name, fac, color=(0.8, 0.3, 0.2), roughness=0.1):
    mat, nodes, links, out = new_material(name)
    mix = nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = fac
    d = set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(*color, 1.0))
    g = set_inputs(nodes.new("ShaderNodeBsdfGlossy"), Color=(0.9, 0.9, 0.9, 1.0),
                   Roughness=roughness)
    g.distribution = 'GGX'
    links.new(d.outputs[0], mix.inputs[1])
    links.new(g.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def srgb_linear(c):
    """sRGB-encoded values → linear (the IEC 61966-2-1 curve, as OCIO's sRGB)."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def checker_image(name, n=4, colors=((0.9, 0.9, 0.9), (0.1, 0.2, 0.6)), colorspace="sRGB"):
    """An n x n byte image of alternating colours (given in the image's colour space)."""
    px = np.zeros((n, n, 4), np.float32)
    for y in range(n):
        for x in range(n):
            px[y, x, :3] = colors[(x + y) % 2]
    px[..., 3] = 1.0
    return pixel_image(name, px, colorspace)


def pixel_image(name, px, colorspace="sRGB", float_buffer=False):
    """A packed image of float (H, W, 4) pixels (row 0 = bottom; byte images store them
    as given, in their colour space)."""
    h, w = px.shape[:2]
    img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=float_buffer)
    img.colorspace_settings.name = colorspace  # first: it regenerates a generated image
    img.pixels.foreach_set(np.ascontiguousarray(px, np.float32).ravel())
    img.pack()  # keeps the pixels when the image is read again
    return img


def textured_material(name, image, interpolation='Linear', extension='REPEAT', mapping=None):
    """Diffuse whose colour is an Image Texture (optionally through a Mapping node)."""
    mat, nodes, links, out = new_material(name)
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = interpolation
    tex.extension = extension
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(tex.outputs["Color"], d.inputs["Color"])
    links.new(d.outputs[0], out.inputs["Surface"])
    if mapping is not None:
        coord = nodes.new("ShaderNodeTexCoord")
        mp = nodes.new("ShaderNodeMapping")
        mp.vector_type = mapping.get("type", 'POINT')
        for key in ("Location", "Rotation", "Scale"):
            if key in mapping:
                mp.inputs[key].default_value = mapping[key]
        links.new(coord.outputs["UV"], mp.inputs["Vector"])
        links.new(mp.outputs["Vector"], tex.inputs["Vector"])
    return mat


# ---------------------------------------------------------------- geometry

def add_mesh_object(name, build, materials=(), smooth=False, **transform):
    bm = bmesh.new()
    build(bm)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    for mat in materials:
        mesh.materials.append(mat)
    if smooth:
        mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    for key, value in transform.items():
        setattr(obj, key, value)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def add_plane(name, size, material=None, uv=True, **transform):
    """A square of side `size` in the XY plane facing +Z, with a 0..1 UV map if uv."""
    def build(bm):
        if uv:
            bm.loops.layers.uv.new("UVMap")
        bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=size / 2, calc_uvs=uv)
    obj = add_mesh_object(name, build, (material,) if material else (), **transform)
    return obj


def add_sphere(name, radius, material=None, segments=48, rings=24, **transform):
    def build(bm):
        bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius)
        canonical_order(bm)  # the same face order in every process
    return add_mesh_object(name, build, (material,) if material else (), smooth=True,
                           **transform)


def look_at(obj, target):
    direction = Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat('-Z', 'Y').to_euler()


def add_camera(location, target, lens=50.0):
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.lens = lens
    cam.location = location
    bpy.context.scene.collection.objects.link(cam)
    look_at(cam, target)
    bpy.context.scene.camera = cam
    return cam


def add_sun(energy=3.0, tilt_deg=0.0):
    """A sharp sun (angle 0) tilted about Y by tilt_deg from straight down."""
    light = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    light.data.energy = energy
    light.data.angle = 0.0
    light.rotation_euler = (0.0, math.radians(tilt_deg), 0.0)
    bpy.context.scene.collection.objects.link(light)
    return light


def set_world(color):
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    bpy.context.scene.world = world
    return world


def studio(size=64, floor=None, world=(0.05, 0.05, 0.05), light_strength=6.0,
           light_size=2.5, camera=((0.0, -5.0, 2.2), (0.0, 0.0, 0.7)), lens=50.0):
    """Empty scene: a 10 m diffuse floor (grey 0.5 unless `floor` is a material), an emissive
    panel above it facing down, a dim constant world and a camera. Returns the scene."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    add_plane("Floor", 10.0, floor or diffuse("Floor", (0.5, 0.5, 0.5)))
    add_plane("Light", light_size, emission("Light", (1.0, 1.0, 1.0), light_strength),
              uv=False, location=(0.5, 0.5, 4.0), rotation_euler=(math.pi, 0.0, 0.0))
    set_world(world)
    add_camera(*camera, lens=lens)
    return scene


def scatter_on_grid(host, source, size, vertices, scale=None, name="Scatter"):
    """A geometry-nodes modifier on `host` that instances the object `source` on the points of
    a vertices x vertices grid of the given size, optionally scaled at random in (min, max)
    `scale`. Returns the node group (instances, as an artist's scatter setup makes them)."""
    tree = bpy.data.node_groups.new(name, 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    n = tree.nodes
    grid = n.new("GeometryNodeMeshGrid")
    grid.inputs["Size X"].default_value = grid.inputs["Size Y"].default_value = size
    grid.inputs["Vertices X"].default_value = grid.inputs["Vertices Y"].default_value = vertices
    inst = n.new("GeometryNodeInstanceOnPoints")
    info = n.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = source
    out = n.new("NodeGroupOutput")
    tree.links.new(grid.outputs["Mesh"], inst.inputs["Points"])
    tree.links.new(info.outputs["Geometry"], inst.inputs["Instance"])
    if scale is not None:
        rnd = n.new("FunctionNodeRandomValue")
        rnd.data_type = 'FLOAT'
        rnd.inputs["Min"].default_value, rnd.inputs["Max"].default_value = scale
        tree.links.new(rnd.outputs[1], inst.inputs["Scale"])
    tree.links.new(inst.outputs["Instances"], out.inputs[0])
    host.modifiers.new(name, 'NODES').node_group = tree
    return tree


# ---------------------------------------------------------------- comparisons

def compare(ours, cycles, grid=8, floor=0.02):
    """(whole-image mean ratio, max relative region error, per-region relative errors) of
    grey-level region means; regions darker than `floor` compare absolutely against it."""
    a, b = region_means(ours, grid).mean(-1), region_means(cycles, grid).mean(-1)
    rel = np.abs(a - b) / np.maximum(b, floor)
    ratio = ours[..., :3].mean() / cycles[..., :3].mean()
    return ratio, rel.max(), rel


def render_pair(build, samples, bounces=16, pathlight=None, cycles_samples=None, **settings):
    """(Pathlight, Cycles) renders of the scene that build() makes, built afresh for each, with
    Cycles' box filter; `settings` go to both engines, `pathlight` (a dict) to Pathlight only;
    Cycles at `cycles_samples` where given (its images are stored: more costs no test time)."""
    ours = render_to_array(build(), "PATHLIGHT", samples=samples, max_bounces=bounces,
                           **settings, **(pathlight or {}))
    cycles = render_to_array(build(), "CYCLES", samples=cycles_samples or samples, max_bounces=bounces,
                             **BOX_FILTER, **settings)
    return ours, cycles


def assert_agree(ours, cycles, what="", region=0.03, whole=0.01, floor=0.02):
    """The issues' agreement bar: whole-image mean within `whole`, every 8x8 region within
    `region` (regions darker than `floor` compared absolutely). Returns (ratio, worst)."""
    ratio, worst, rel = compare(ours, cycles, floor=floor)
    print(f"\n{what}: mean ratio {ratio:.4f}, worst region {worst:.4f} "
          f"(means {ours[..., :3].mean():.4f} / {cycles[..., :3].mean():.4f})")  # pytest -s
    assert np.isfinite(ours).all(), f"{what}: non-finite pixels"
    assert abs(ratio - 1.0) < whole, f"{what}: image mean ratio {ratio:.4f}"
    assert worst < region, f"{what}: worst region {worst:.3f}\n{np.round(rel, 3)}"
    return ratio, worst
