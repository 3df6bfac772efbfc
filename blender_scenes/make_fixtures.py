"""Build the .blend fixtures used by the add-on tests.

    .venv/bin/python blender_scenes/make_fixtures.py [cornell_box] [hdr_scene]   (default: all)

cornell_box.blend: the classic Cornell box (Blender units: the box spans x, y in [-1, 1] and
z in [0, 2], open towards -y where the camera is). All materials are plain shader nodes, so
Cycles and Pathlight read the same scene. Stored with the CYCLES engine, since PATHLIGHT
exists only while the add-on is registered; renders select the engine themselves.

hdr_scene.blend: a few diffuse objects on a floor lit only by an equirectangular HDR world
(the synthetic sky of tests/blender/light_scenes.py with a hard, captured-style sun disc, packed into
the .blend as a half-float EXR, 512 x 256), 256 x 256: the HDR-lit benchmark scene.
"""

import math
import sys
import tempfile
from pathlib import Path

import bpy
import bmesh  # only importable once bpy is

HERE = Path(__file__).resolve().parent

WHITE = (0.73, 0.73, 0.73)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
LIGHT_COLOR = (1.0, 0.85, 0.65)  # warm white
LIGHT_STRENGTH = 12.0


def diffuse_material(name, color):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    bsdf = nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*color, 1.0)
    mat.node_tree.links.new(bsdf.outputs["BSDF"], nodes["Material Output"].inputs["Surface"])
    mat.diffuse_color = (*color, 1.0)  # viewport colour
    return mat


def emission_material(name, color, strength):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (*color, 1.0)
    emission.inputs["Strength"].default_value = strength
    mat.node_tree.links.new(emission.outputs["Emission"],
                            nodes["Material Output"].inputs["Surface"])
    return mat


def add_object(name, mesh, material, location=(0, 0, 0), rotation=(0, 0, 0), scale=(1, 1, 1)):
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    obj.location, obj.rotation_euler, obj.scale = location, rotation, scale
    bpy.context.scene.collection.objects.link(obj)
    return obj


def quad_mesh(name, corners):
    """One quad; corners counter-clockwise seen from the side its normal points to."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(corners, [], [(0, 1, 2, 3)])
    return mesh


def bmesh_mesh(name, build):
    bm = bmesh.new()
    build(bm)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    return mesh


def make_cornell_box(path):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    white, red, green = (diffuse_material(n, c) for n, c in
                         (("White", WHITE), ("Red", RED), ("Green", GREEN)))

    # Walls, normals pointing into the box.
    walls = {
        "Floor": ([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], white),
        "Ceiling": ([(-1, -1, 2), (-1, 1, 2), (1, 1, 2), (1, -1, 2)], white),
        "Back": ([(-1, 1, 0), (1, 1, 0), (1, 1, 2), (-1, 1, 2)], white),
        "Left": ([(-1, -1, 0), (-1, 1, 0), (-1, 1, 2), (-1, -1, 2)], red),
        "Right": ([(1, -1, 0), (1, -1, 2), (1, 1, 2), (1, 1, 0)], green),
    }
    for name, (corners, mat) in walls.items():
        add_object(name, quad_mesh(name, corners), mat)

    # Area light: an emissive quad just below the ceiling, facing down.
    s = 0.25
    light = quad_mesh("Light", [(-s, -s, 0), (-s, s, 0), (s, s, 0), (s, -s, 0)])
    add_object("Light", light, emission_material("Light", LIGHT_COLOR, LIGHT_STRENGTH),
               location=(0, 0.1, 1.98))

    box = bmesh_mesh("Box", lambda bm: bmesh.ops.create_cube(bm, size=1.0))
    add_object("Box", box, white, location=(-0.35, 0.3, 0.6),
               rotation=(0, 0, math.radians(28)), scale=(0.55, 0.55, 1.2))

    sphere = bmesh_mesh("Sphere", lambda bm: bmesh.ops.create_uvsphere(
        bm, u_segments=48, v_segments=24, radius=0.35))
    sphere.shade_smooth()
    add_object("Sphere", sphere, white, location=(0.42, -0.3, 0.35))

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 50.0
    camera = bpy.data.objects.new("Camera", cam_data)
    camera.location = (0.0, -4.0, 1.0)
    camera.rotation_euler = (math.radians(90), 0.0, 0.0)  # look along +y
    scene.collection.objects.link(camera)
    scene.camera = camera

    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0, 0, 0, 1)
    world.color = (0, 0, 0)
    scene.world = world

    save_fixture(scene, path)


def save_fixture(scene, path):
    """The render settings every fixture shares (256x256, Standard view), then a compressed save.
    The engine stays CYCLES: PATHLIGHT exists only once the add-on is registered."""
    render = scene.render
    render.engine = 'CYCLES'
    render.resolution_x = render.resolution_y = 256
    render.resolution_percentage = 100
    render.film_transparent = False
    scene.view_settings.view_transform = 'Standard'
    scene.view_settings.look = 'None'
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True)


def make_hdr_scene(path):
    sys.path.insert(0, str(HERE.parent / "tests" / "blender"))
    import numpy as np
    import OpenEXR
    from light_scenes import synthetic_hdr

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    grey, red, blue, yellow = (diffuse_material(n, c) for n, c in (
        ("Grey", (0.6, 0.6, 0.6)), ("Red", (0.7, 0.12, 0.08)), ("Blue", (0.12, 0.22, 0.6)),
        ("Yellow", (0.75, 0.6, 0.15))))
    add_object("Floor", bmesh_mesh("Floor", lambda bm: bmesh.ops.create_grid(
        bm, x_segments=1, y_segments=1, size=6.0)), grey)
    add_object("Box", bmesh_mesh("Box", lambda bm: bmesh.ops.create_cube(bm, size=1.0)), red,
               location=(-0.9, 0.4, 0.5), rotation=(0, 0, math.radians(25)))
    sphere = bmesh_mesh("Sphere", lambda bm: bmesh.ops.create_uvsphere(
        bm, u_segments=48, v_segments=24, radius=0.55))
    sphere.shade_smooth()
    add_object("Sphere", sphere, blue, location=(0.75, -0.1, 0.55))
    cylinder = bmesh_mesh("Cylinder", lambda bm: bmesh.ops.create_cone(
        bm, cap_ends=True, segments=32, radius1=0.3, radius2=0.3, depth=1.4))
    add_object("Cylinder", cylinder, yellow, location=(0.1, 1.3, 0.7))

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 35.0
    camera = bpy.data.objects.new("Camera", cam_data)
    camera.location = (0.0, -5.5, 2.2)
    camera.rotation_euler = (math.radians(73), 0.0, 0.0)
    scene.collection.objects.link(camera)
    scene.camera = camera

    # The sky: written as a half-float EXR (Blender's image.save() would apply the view
    # transform to a generated image), loaded and packed, so the .blend is self-contained.
    pixels = synthetic_hdr(512, 256, sun_disc=(0.03, 2000.0))
    with tempfile.TemporaryDirectory() as tmp:
        exr = Path(tmp) / "pathlight_sky.exr"
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        OpenEXR.File(header, {"RGB": np.ascontiguousarray(pixels[::-1], np.float16)}).write(
            str(exr))
        image = bpy.data.images.load(str(exr))
        image.pack()
    image.filepath_raw = "//pathlight_sky.exr"  # packed: the file itself is not needed
    world = bpy.data.worlds.new("Sky")
    world.use_nodes = True
    nt = world.node_tree
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    coords = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(-40))  # sun behind-left
    nt.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    nt.links.new(env.outputs["Color"], nt.nodes["Background"].inputs["Color"])
    scene.world = world

    save_fixture(scene, path)


FIXTURES = {"cornell_box": make_cornell_box, "hdr_scene": make_hdr_scene}

if __name__ == "__main__":
    for name in sys.argv[1:] or FIXTURES:
        FIXTURES[name](HERE / f"{name}.blend")
