"""Vector and colour nodes against Cycles in the same bpy (issue 21): Vector Rotate (every type,
Invert, linked inputs), Blackbody and Wavelength over their whole range, Vector Transform
(points, vectors and normals between world, object and camera space), Texture Coordinate's
Camera and Window (perspective with shift, orthographic), Camera Data (perspective,
orthographic, panoramic, past a mirror), the Geometry node's Tangent and the
Tangent node (radial about each axis, UV map). Each renders planes whose emission is the
node's output (vectors mapped by s v + o to stay positive: Pathlight's emission is), sampled
at the pixel centres with one sample, and compares per pixel in the node's own units."""

import math

import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

CENTRES = dict(pixel_filter_type='BOX', filter_width=0.01)


def new_scene(res_x, res_y=None, camera_type='ORTHO', location=(0.0, 0.0, 6.0),
              rotation=(0.0, 0.0, 0.0), ortho_scale=4.0, shift=(0.0, 0.0)):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_percentage = 100
    scene.render.resolution_x = res_x
    scene.render.resolution_y = res_y or res_x
    ms.set_world((0.0, 0.0, 0.0))
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.type = camera_type
    cam.data.ortho_scale = ortho_scale
    cam.data.lens = 35.0
    cam.data.shift_x, cam.data.shift_y = shift
    cam.location = location
    cam.rotation_euler = rotation
    scene.collection.objects.link(cam)
    scene.camera = cam
    return scene


def emission_material(name, source, scale=1.0, offset=0.0):
    """Emission = source(nodes, links) * scale + offset (per component)."""
    mat, nodes, links, out = ms.new_material(name)
    src = source(nodes, links)
    if scale != 1.0 or offset != 0.0:
        vm = nodes.new("ShaderNodeVectorMath")
        vm.operation = 'MULTIPLY_ADD'
        vm.inputs[1].default_value = (scale,) * 3
        vm.inputs[2].default_value = (offset,) * 3
        links.new(src, vm.inputs[0])
        src = vm.outputs[0]
    emit = nodes.new("ShaderNodeEmission")
    links.new(src, emit.inputs["Color"])
    links.new(emit.outputs[0], out.inputs["Surface"])
    return mat


def render_both(build):
    ours = render_to_array(build(), "PATHLIGHT", samples=1, max_bounces=1, **CENTRES)
    cycles = render_to_array(build(), "CYCLES", samples=1, max_bounces=1, **CENTRES)
    return ours[..., :3], cycles[..., :3]


def assert_matches(ours, cycles, scale=1.0, rel=1e-3, min_std=0.02):
    """Per pixel in the node's units (the image divided by the emission's scale): mean
    absolute difference under `rel` of the value range Cycles shows."""
    a, b = ours / scale, cycles / scale
    value_range = float(b.max() - b.min())
    diff = np.abs(a - b)
    assert value_range > 0.0
    assert diff.mean() < rel * value_range, \
        f"mean abs difference {diff.mean():.3e} of range {value_range:.3f}"
    assert cycles.std() > min_std  # the output varies over the picture
    print(f"  agreement: {diff.mean() / value_range:.2e} of range {value_range:.3f}")  # with -s
    return diff.mean() / value_range


def tex_coord(nodes, output):
    return nodes.new("ShaderNodeTexCoord").outputs[output]


# ---------------------------------------------------------------- Vector Rotate

@pytest.mark.parametrize("rotation_type", ['AXIS_ANGLE', 'X_AXIS', 'Y_AXIS', 'Z_AXIS', 'EULER_XYZ'])
@pytest.mark.parametrize("invert", [False, True])
def test_vector_rotate_matches_cycles(rotation_type, invert):
    """Object coordinates rotated about a centre; the angle, axis and Euler rotation come from
    links (the generated coordinates), so every input is a varying register."""
    def source(nodes, links):
        rot = nodes.new("ShaderNodeVectorRotate")
        rot.rotation_type = rotation_type
        rot.invert = invert
        links.new(tex_coord(nodes, "Object"), rot.inputs["Vector"])
        rot.inputs["Center"].default_value = (0.3, -0.2, 0.4)
        gen = tex_coord(nodes, "Generated")
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(gen, sep.inputs[0])
        angle = nodes.new("ShaderNodeMath")
        angle.operation = 'MULTIPLY'
        angle.inputs[1].default_value = 4.0
        links.new(sep.outputs[0], angle.inputs[0])
        links.new(angle.outputs[0], next(s for s in rot.inputs if s.identifier == "Angle"))
        axis = nodes.new("ShaderNodeCombineXYZ")
        axis.inputs[0].default_value = 0.4
        axis.inputs[2].default_value = 1.0
        links.new(sep.outputs[1], axis.inputs[1])
        links.new(axis.outputs[0], next(s for s in rot.inputs if s.identifier == "Axis"))
        euler = nodes.new("ShaderNodeVectorMath")
        euler.operation = 'SCALE'
        euler.inputs["Scale"].default_value = 3.0
        links.new(gen, euler.inputs[0])
        links.new(euler.outputs[0], next(s for s in rot.inputs if s.identifier == "Rotation"))
        return rot.outputs[0]

    def build():
        scene = new_scene(32)
        ms.add_plane("P", 3.6, emission_material("Rot", source, 0.15, 0.5),
                     rotation_euler=(0.0, 0.0, 0.3))
        return scene
    ours, cycles = render_both(build)
    assert_matches(ours, cycles, 0.15)


# ---------------------------------------------------------------- Blackbody and Wavelength

@pytest.mark.parametrize("node_type, lo, hi, scale", [
    ("ShaderNodeBlackbody", 500.0, 13000.0, 0.2),  # below 800 K, every band, above 12000 K
    ("ShaderNodeWavelength", 360.0, 800.0, 1.0),   # outside the table on both sides
])
def test_blackbody_and_wavelength_match_cycles(node_type, lo, hi, scale):
    def source(nodes, links):
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(tex_coord(nodes, "Generated"), sep.inputs[0])
        # x and y both vary the input, so every pixel of the 64x8 strip is another value.
        add = nodes.new("ShaderNodeMath")
        add.operation = 'MULTIPLY_ADD'
        add.inputs[1].default_value = 1.0 / 64.0
        links.new(sep.outputs[1], add.inputs[0])
        links.new(sep.outputs[0], add.inputs[2])
        mr = nodes.new("ShaderNodeMapRange")
        mr.clamp = False
        mr.inputs["To Min"].default_value = lo
        mr.inputs["To Max"].default_value = hi
        links.new(add.outputs[0], mr.inputs[0])
        node = nodes.new(node_type)
        links.new(mr.outputs[0], node.inputs[0])
        return node.outputs[0]

    def build():
        scene = new_scene(64, 8, ortho_scale=2.0)
        ms.add_plane("P", 2.0, emission_material("BW", source, scale), scale=(1.0, 0.125, 1.0))
        return scene
    ours, cycles = render_both(build)
    assert_matches(ours, cycles, scale)


# ---------------------------------------------------------------- Vector Transform

SPACES = ['WORLD', 'OBJECT', 'CAMERA']


def perspective_view(res_x=30, res_y=30):
    return new_scene(res_x, res_y, camera_type='PERSP', location=(0.6, -1.4, 7.0),
                     rotation=(0.2, -0.08, 0.35))


@pytest.mark.parametrize("vector_type", ['POINT', 'VECTOR', 'NORMAL'])
def test_vector_transform_matches_cycles(vector_type):
    """Nine tiles, one per (from, to) pair, each a rotated, tilted, non-uniformly scaled
    plane; the input is the world position (points, vectors) or the shading normal."""
    def build():
        scene = perspective_view()
        for i, src in enumerate(SPACES):
            for j, dst in enumerate(SPACES):
                def source(nodes, links, src=src, dst=dst):
                    vt = nodes.new("ShaderNodeVectorTransform")
                    vt.vector_type = vector_type
                    vt.convert_from, vt.convert_to = src, dst
                    geo = nodes.new("ShaderNodeNewGeometry")
                    links.new(geo.outputs["Normal" if vector_type == 'NORMAL' else "Position"],
                              vt.inputs[0])
                    return vt.outputs[0]
                mat = emission_material(f"VT{src}{dst}", source, 0.06, 0.5)
                ms.add_plane(f"P{i}{j}", 1.0, mat, location=(1.2 * (j - 1), 1.2 * (1 - i), 0.0),
                             rotation_euler=(0.25, -0.15, 0.5 + 0.3 * i),
                             scale=(1.1, 0.7 + 0.2 * j, 1.6))
        return scene
    ours, cycles = render_both(build)
    assert_matches(ours, cycles, 0.06, min_std=0.005)


# ---------------------------------------------------------------- Camera and Window

@pytest.mark.parametrize("output", ["Camera", "Window"])
@pytest.mark.parametrize("camera_type", ['PERSP', 'ORTHO'])
def test_camera_and_window_coordinates_match_cycles(output, camera_type):
    """A wide frame (the sensor fits its width), a shifted camera turned about every axis, a
    tilted plane filling the view: camera space has +z forward, Window is 0..1 over the frame."""
    scale, offset = (0.08, 0.5) if output == "Camera" else (0.5, 0.25)

    def build():
        scene = new_scene(40, 24, camera_type=camera_type, location=(0.5, -0.6, 5.0),
                          rotation=(0.15, -0.1, 0.3), ortho_scale=4.5, shift=(0.1, -0.05))
        mat = emission_material(f"C{output}", lambda nodes, links: tex_coord(nodes, output),
                                scale, offset)
        ms.add_plane("P", 12.0, mat, rotation_euler=(0.2, 0.1, 0.0))
        return scene
    ours, cycles = render_both(build)
    assert_matches(ours, cycles, scale)
    if output == "Window":  # bottom-left to top-right of the frame (row 0 = top)
        w = (ours - offset) / scale
        assert w[-1, 0, 0] < 0.05 and w[-1, 0, 1] < 0.05, w[-1, 0]
        assert w[0, -1, 0] > 0.95 and w[0, -1, 1] > 0.95, w[0, -1]


# ---------------------------------------------------------------- Camera Data

@pytest.mark.parametrize("output", ["View Vector", "View Z Depth", "View Distance"])
@pytest.mark.parametrize("camera_type", ['PERSP', 'ORTHO', 'PANO'])
def test_camera_data_matches_cycles(output, camera_type):
    """Camera Data (Cycles' svm_node_camera): the shading point in the camera's space (a
    panorama's own axes), its direction, z and length, on a tilted plane below a turned camera
    (an equirectangular panorama sees it below its horizon)."""
    scale, offset = {"View Vector": (0.5, 0.5), "View Z Depth": (0.05, 2.0),
                     "View Distance": (0.1, 0.0)}[output]

    def build():
        scene = new_scene(40, 24, camera_type=camera_type, location=(0.5, -0.6, 5.0),
                          rotation=(0.15, -0.1, 0.3), ortho_scale=4.5)
        if camera_type == 'PANO':
            scene.camera.data.panorama_type = 'EQUIRECTANGULAR'
        mat = emission_material(f"D{output}", lambda nodes, links: nodes.new("ShaderNodeCameraData").outputs[output],
                                scale, offset)
        ms.add_plane("P", 30.0, mat, rotation_euler=(0.2, 0.1, 0.0))
        return scene
    ours, cycles = render_both(build)
    assert_matches(ours, cycles, scale, min_std=0.005)


def test_camera_data_past_a_mirror_matches_cycles():
    """In a mirror the node reads the point the reflected ray found, not the camera ray's hit
    or the path's length (Cycles' sd->P)."""
    def build():
        scene = new_scene(32, location=(0.0, -3.0, 2.0), rotation=(math.radians(60.0), 0.0, 0.0),
                          camera_type='PERSP')
        mat, nodes, links, out = ms.new_material("Mirror")
        glossy = nodes.new("ShaderNodeBsdfGlossy")
        glossy.inputs["Roughness"].default_value = 0.0
        links.new(glossy.outputs[0], out.inputs["Surface"])
        ms.add_plane("Mirror", 20.0, mat)
        wall = emission_material("Dist", lambda nodes, links: nodes.new("ShaderNodeCameraData").outputs["View Distance"],
                                 0.1)
        ms.add_plane("Wall", 30.0, wall, location=(0.0, 6.0, 0.0), rotation_euler=(math.radians(90.0), 0.0, 0.0))
        return scene
    ours = render_to_array(build(), "PATHLIGHT", samples=1, max_bounces=2, **CENTRES)[..., :3]
    cycles = render_to_array(build(), "CYCLES", samples=1, max_bounces=2, **CENTRES)[..., :3]
    assert_matches(ours, cycles, 0.1, min_std=0.005)


# ---------------------------------------------------------------- tangents

@pytest.mark.parametrize("kind", ["Geometry", "X", "Y", "Z", "UV_MAP"])
def test_tangents_match_cycles(kind):
    """Radial tangents about each object axis on a rotated, scaled sphere (and planes, about
    Z); the UV
    map's tangent on rotated planes (flat: Cycles' MikkTSpace tangent is the triangle's)."""
    def source(nodes, links):
        if kind == "Geometry":
            return nodes.new("ShaderNodeNewGeometry").outputs["Tangent"]
        t = nodes.new("ShaderNodeTangent")
        if kind == "UV_MAP":
            t.direction_type = 'UV_MAP'
            t.uv_map = "UVMap"
        else:
            t.direction_type = 'RADIAL'
            t.axis = kind
        return t.outputs[0]

    def build():
        scene = perspective_view(32, 32)
        mat = emission_material(f"T{kind}", source, 0.5, 0.5)
        if kind not in ("X", "Y"):  # a plane's X or Y radial tangent is its normal: undefined
            ms.add_plane("A", 1.6, mat, location=(-1.0, 0.6, 0.0), rotation_euler=(0.3, 0.2, 0.7),
                         scale=(1.0, 0.6, 1.0))
            ms.add_plane("B", 1.6, mat, location=(1.0, -0.8, 0.2), rotation_euler=(-0.4, 0.1, 2.2))
        if kind != "UV_MAP":
            ms.add_sphere("S", 0.8, mat, segments=24, rings=12, location=(0.9, 0.9, 0.3),
                          rotation_euler=(0.5, 0.3, 0.2), scale=(1.0, 1.3, 0.8))
        return scene
    ours, cycles = render_both(build)
    assert_matches(ours, cycles, 0.5)


def test_pointiness_matches_cycles():
    """Pointiness per vertex from the mesh's curvature (welded duplicates, one-ring edge
    directions against the normal, a one-ring blur), interpolated: Suzanne (smooth) and a
    cube with its faces split apart (duplicate vertices welded), per pixel."""
    import bmesh

    def build():
        scene = perspective_view(40, 32)
        mat = emission_material("Pointy", lambda nodes, links:
                                nodes.new("ShaderNodeNewGeometry").outputs["Pointiness"])
        ms.add_mesh_object("Suzanne", lambda bm: bmesh.ops.create_monkey(bm), (mat,),
                           smooth=True, location=(-0.9, 0.3, 0.6), rotation_euler=(1.2, 0.0, 0.4))

        def split_cube(bm):
            bmesh.ops.create_cube(bm, size=1.4)
            bmesh.ops.split_edges(bm, edges=bm.edges[:])  # every face its own vertices
        ms.add_mesh_object("Cube", split_cube, (mat,), location=(1.2, -0.6, 0.5),
                           rotation_euler=(0.4, 0.3, 0.9))
        return scene
    ours, cycles = render_both(build)
    assert_matches(ours, cycles, min_std=0.01)


# ---------------------------------------------------------------- Gabor

@pytest.mark.parametrize("gabor_type", ['2D', '3D'])
@pytest.mark.parametrize("output", ["Value", "Phase", "Intensity"])
def test_gabor_texture_matches_cycles(gabor_type, output):
    """Gabor on a tilted plane (3D reads z too), partly anisotropic, the orientation linked.
    Features stay several pixels wide: the 0.01 px box still lets Cycles' one sample move by
    up to 0.005 px, which on a fine pattern alone exceeds the limit (as for the noise
    textures). Phase is an angle: compared modulo 1, where it wraps."""
    def source(nodes, links):
        g = nodes.new("ShaderNodeTexGabor")
        g.gabor_type = gabor_type
        g.inputs["Scale"].default_value = 1.2
        g.inputs["Frequency"].default_value = 1.5
        g.inputs["Anisotropy"].default_value = 0.6
        sep = nodes.new("ShaderNodeSeparateXYZ")
        links.new(tex_coord(nodes, "Object"), sep.inputs[0])
        links.new(tex_coord(nodes, "Object"), g.inputs["Vector"])
        if gabor_type == '2D':
            links.new(sep.outputs[0], next(s for s in g.inputs if s.identifier == "Orientation 2D"))
        else:
            ori = nodes.new("ShaderNodeCombineXYZ")
            ori.inputs[0].default_value = 0.4
            ori.inputs[2].default_value = 0.7
            links.new(sep.outputs[1], ori.inputs[1])
            links.new(ori.outputs[0], next(s for s in g.inputs if s.identifier == "Orientation 3D"))
        return g.outputs[output]

    def build():
        scene = new_scene(48)
        ms.add_plane("P", 4.0, emission_material(f"G{gabor_type}{output}", source),
                     rotation_euler=(0.3, 0.2, 0.1))
        return scene
    ours, cycles = render_both(build)
    if output == "Phase":
        d = ours - cycles
        ours = cycles + (d - np.round(d))  # the nearest of the phases one turn apart
    assert_matches(ours, cycles)


# ---------------------------------------------------------------- Ambient Occlusion

@pytest.mark.parametrize("setting", ["plain", "inside", "only_local", "color"])
def test_ambient_occlusion_matches_cycles_statistically(setting):
    """A ball resting on a floor by a wall, each emitting its Ambient Occlusion (4 rays per
    shading point, distance 1.5): the contact shadows, the corner, Inside (the ball occludes
    itself from within: dark; the floor's rays go into the ground: light) and Only Local (the
    floor ignores the ball and wall). Region means at 64 samples against Cycles'."""
    def source(nodes, links):
        ao = nodes.new("ShaderNodeAmbientOcclusion")
        ao.samples = 4
        ao.inside = setting == "inside"
        ao.only_local = setting == "only_local"
        ao.inputs["Distance"].default_value = 1.5
        ao.inputs["Color"].default_value = (0.9, 0.5, 0.2, 1.0)
        return ao.outputs["Color" if setting == "color" else "AO"]

    def build():
        scene = new_scene(32, 32, camera_type='PERSP', location=(0.0, -5.0, 3.0),
                          rotation=(math.radians(58), 0.0, 0.0))
        mat = emission_material(f"AO{setting}", source)
        ms.add_plane("Floor", 6.0, mat)
        ms.add_plane("Wall", 6.0, mat, location=(0.0, 1.5, 3.0), rotation_euler=(math.pi / 2, 0, 0))
        ms.add_sphere("Ball", 0.7, mat, segments=24, rings=12, location=(-0.3, 0.2, 0.7))
        return scene
    ours = render_to_array(build(), "PATHLIGHT", samples=64, max_bounces=1)[..., :3]
    cycles = render_to_array(build(), "CYCLES", samples=64, max_bounces=1,
                             pixel_filter_type='BOX', filter_width=1.0)[..., :3]
    ratio, worst, rel = ms.compare(ours, cycles, grid=4, floor=0.05)
    print(f"  AO {setting}: mean ratio {ratio:.4f}, worst 8x8 region {worst:.4f}")
    assert abs(ratio - 1.0) < 0.02, f"image mean ratio {ratio:.4f}"
    assert worst < 0.05, f"worst region {worst:.3f}\n{np.round(rel, 3)}"
    assert cycles.std() > 0.05  # occlusion varies over the picture
