"""Small scenes built with bpy for the light, world and sampling tests (issue 4)."""

import math
import tempfile
from pathlib import Path

import bpy
import numpy as np
import OpenEXR

from blender_util import canonical_order


def empty_scene(size=32, height=None):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x = size
    scene.render.resolution_y = height or size
    scene.render.resolution_percentage = 100
    scene.world = None
    return scene


def diffuse_material(name, albedo):
    rgb = albedo if isinstance(albedo, tuple) else (albedo,) * 3
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    bsdf = nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*rgb, 1.0)
    mat.node_tree.links.new(bsdf.outputs["BSDF"], nodes["Material Output"].inputs["Surface"])
    return mat


def emission_material(name, rgb, strength=1.0):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    node = nodes.new("ShaderNodeEmission")
    node.inputs["Color"].default_value = (*rgb, 1.0)
    node.inputs["Strength"].default_value = strength
    mat.node_tree.links.new(node.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def mesh_object(name, build, material=None, smooth=False, **transform):
    import bmesh
    bm = bmesh.new()
    build(bm)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    if smooth:
        mesh.shade_smooth()
    if material is not None:
        mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    for key, value in transform.items():
        setattr(obj, key, value)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def plane(name, size, material=None, **transform):
    import bmesh
    return mesh_object(name, lambda bm: bmesh.ops.create_grid(
        bm, x_segments=1, y_segments=1, size=size / 2), material, **transform)


def box(name, size, material=None, **transform):
    import bmesh
    return mesh_object(name, lambda bm: bmesh.ops.create_cube(bm, size=size), material,
                       **transform)


def uv_sphere(name, radius, material=None, segments=48, **transform):
    import bmesh
    def build(bm):
        bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=segments // 2, radius=radius)
        canonical_order(bm)  # the same face order in every process
    return mesh_object(name, build, material, smooth=True, **transform)


def camera(location, rotation=(0.0, 0.0, 0.0), lens=50.0, look_at=None):
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.lens = lens
    cam.location = location
    if look_at is not None:
        from mathutils import Vector
        direction = Vector(look_at) - Vector(location)
        cam.rotation_euler = direction.to_track_quat('-Z', 'Y').to_euler()
    else:
        cam.rotation_euler = rotation
    scene = bpy.context.scene
    scene.collection.objects.link(cam)
    scene.camera = cam
    return cam


def add_light(kind, name="Light", location=(0, 0, 0), rotation=(0, 0, 0), scale=(1, 1, 1),
              collection=None, **props):
    """A light object of Blender type `kind`, with its data properties set from props."""
    data = bpy.data.lights.new(name, kind)
    for key, value in props.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(name, data)
    obj.location, obj.rotation_euler, obj.scale = location, rotation, scale
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def world_color(rgb, strength=1.0):
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*rgb, 1.0)
    bg.inputs["Strength"].default_value = strength
    bpy.context.scene.world = world
    return world


def world_image(image, strength=1.0, rotation=None, vector_type='POINT'):
    """World = Environment Texture(image) [through Texture Coordinate → Mapping(rotation)]
    → Background × strength."""
    world = bpy.data.worlds.new("HDR World")
    world.use_nodes = True
    nt = world.node_tree
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    bg = nt.nodes["Background"]
    bg.inputs["Strength"].default_value = strength
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    if rotation is not None:
        coords = nt.nodes.new("ShaderNodeTexCoord")
        mapping = nt.nodes.new("ShaderNodeMapping")
        mapping.vector_type = vector_type
        mapping.inputs["Rotation"].default_value = rotation
        nt.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
        nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    bpy.context.scene.world = world
    return world


def write_exr(path, rgb):
    """Write float32 (H, W, 3) scene-linear RGB, row 0 = BOTTOM (Blender's order), as EXR."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": np.ascontiguousarray(rgb[::-1], np.float32)}).write(str(path))


def load_image(rgb, name="env", directory=None):
    """A bpy Image holding rgb (H, W, 3; row 0 = bottom), read from an EXR file that is
    written to `directory` (default: a new temporary one) and packed into the .blend."""
    directory = Path(directory or tempfile.mkdtemp(prefix="pathlight_env_"))
    path = directory / f"{name}.exr"
    write_exr(path, rgb)
    image = bpy.data.images.load(str(path))
    image.pack()
    return image


def synthetic_hdr(width=128, height=64, sun_sigma=0.08, sun_peak=300.0, sun_disc=None):
    """An outdoor-like HDR (row 0 = bottom): a blue-to-white sky, a brown ground, a few
    coloured patches that make rotations and mirrorings visible, and a sun at (u, v) =
    (0.3, 0.8) holding most of the light: a Gaussian of `sun_sigma` radians and peak
    `sun_peak`, or with sun_disc=(radius, radiance) a hard disc as in captured HDRs (a few
    texels of extreme values: the hard case for importance sampling)."""
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    elevation = (v - 0.5) * np.pi  # +pi/2 straight up
    img = np.zeros((height, width, 3), np.float32)
    sky = np.stack([0.35 + 0.4 * np.cos(elevation), 0.5 + 0.3 * np.cos(elevation),
                    np.full_like(v, 0.95)], axis=1)
    ground = np.array([0.25, 0.18, 0.1])
    img[:] = np.where((elevation > 0)[:, None], sky, ground)[:, None, :]
    h, w = height / 64, width / 128
    img[int(34 * h): int(38 * h), int(width * 0.10): int(width * 0.18)] = (2.0, 0.1, 0.1)
    img[int(36 * h): int(42 * h), int(width * 0.55): int(width * 0.60)] = (0.1, 1.5, 0.2)
    sun_u, sun_v = 0.3, 0.8
    du = np.minimum(np.abs(u - sun_u), 1 - np.abs(u - sun_u))[None, :] * 2 * np.pi * np.cos(
        (sun_v - 0.5) * np.pi)
    dv = (v - sun_v)[:, None] * np.pi
    dist = np.hypot(du, dv)  # ~ angle from the sun
    tint = np.array([1.0, 0.88, 0.7], np.float32)
    if sun_disc is not None:
        radius, radiance = sun_disc
        img += (dist < radius)[..., None] * (radiance * tint)
    else:
        img += (sun_peak * np.exp(-0.5 * (dist / sun_sigma) ** 2))[..., None] * tint
    return img.astype(np.float32)


def diffuse_set(size=64):
    """A small diffuse set: floor, back wall, a box and a sphere, camera looking at them."""
    scene = empty_scene(size)
    white, red, blue = (diffuse_material(n, c) for n, c in
                        (("White", 0.7), ("Red", (0.7, 0.15, 0.1)), ("Blue", (0.15, 0.25, 0.6))))
    plane("Floor", 12.0, white)
    plane("Wall", 12.0, white, location=(0, 2.5, 3.0), rotation_euler=(math.pi / 2, 0, 0))
    box("Box", 1.0, red, location=(-0.8, 0.6, 0.5), rotation_euler=(0, 0, 0.5))
    uv_sphere("Sphere", 0.5, blue, location=(0.8, -0.2, 0.5))
    camera((0.0, -6.0, 2.5), look_at=(0.0, 0.3, 0.6), lens=35.0)
    return scene


def write_hdr(path, rgb):
    """Write float (H, W, 3) RGB, row 0 = BOTTOM, as a flat (uncompressed) Radiance .hdr.
    (Blender's own image.save() would apply the view transform to a generated image.)"""
    rgb = np.maximum(np.asarray(rgb, np.float64)[::-1], 0.0)  # the file is top row first
    peak = rgb.max(axis=2)
    mantissa, exponent = np.frexp(peak)  # peak = mantissa * 2^exponent, mantissa in [0.5, 1)
    scale = np.where(peak > 1e-32, 256.0 / np.exp2(exponent), 0.0)
    rgbe = np.empty(rgb.shape[:2] + (4,), np.uint8)
    rgbe[..., :3] = np.clip(np.floor(rgb * scale[..., None]), 0, 255)
    rgbe[..., 3] = np.where(peak > 1e-32, exponent + 128, 0)
    h, w = peak.shape
    with open(path, "wb") as f:
        f.write(f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {h} +X {w}\n".encode())
        f.write(rgbe.tobytes())
