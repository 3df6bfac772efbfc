"""A renderable scene from a Wavefront OBJ (+MTL): Blender's own importer, a camera framing the
model and a constant world light. Used by `build.py render model.obj`.

Blender's OBJ importer turns each MTL material into a Principled BSDF (Kd → Base Color or a
map_Kd Image Texture, Ns → Roughness, Ks → Specular IOR Level, Ni → IOR, d → Alpha,
Tf → Transmission Weight, Ke → Emission; illum 3 to 9 → Metallic 1), which the add-on's shader
compiler handles like any node material.
"""

import math
from pathlib import Path

import bpy
from mathutils import Vector

WORLD_COLOR = (0.8, 0.8, 0.8)  # a neutral, even light from every direction
RESOLUTION = (800, 600)
VIEW_DIRECTION = Vector((0.55, -1.0, 0.5)).normalized()  # from the front right, above


class ObjSceneError(RuntimeError):
    pass


def load_obj_scene(path, resolution=RESOLUTION):
    """Replace the open file by an empty scene holding the OBJ at `path` (imported with
    Blender's importer, materials from its MTL), a camera framing it and a constant world.
    Returns the scene. Raises ObjSceneError if the file cannot be imported or holds no
    geometry."""
    path = Path(path)
    if not path.is_file():
        raise ObjSceneError(f"OBJ file not found: {path}")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    try:
        result = bpy.ops.wm.obj_import(filepath=str(path.resolve()))
    except RuntimeError as e:
        raise ObjSceneError(f"could not import {path.name}: {str(e).strip()}") from e
    if "FINISHED" not in result:
        raise ObjSceneError(f"could not import {path.name}: the importer returned {sorted(result)}")
    lo, hi = _world_bounds(scene)
    if lo is None:
        raise ObjSceneError(f"{path.name} holds no geometry")
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    _add_camera(scene, lo, hi)
    _set_world(scene)
    bpy.context.view_layer.update()  # matrix_world of the new camera
    return scene


def _world_bounds(scene):
    """(min, max) world-space corners of all mesh objects, or (None, None)."""
    lo = hi = None
    for obj in scene.objects:
        if obj.type != 'MESH' or len(obj.data.vertices) == 0:
            continue
        for corner in obj.bound_box:
            p = obj.matrix_world @ Vector(corner)
            lo = p.copy() if lo is None else Vector(map(min, lo, p))
            hi = p.copy() if hi is None else Vector(map(max, hi, p))
    return lo, hi


def _add_camera(scene, lo, hi, margin=1.08):
    """A 50 mm camera looking from VIEW_DIRECTION at the bounding box, as close as lets the
    whole box into the frame (with a small margin), the box's image centred with the lens
    shift."""
    data = bpy.data.cameras.new("Camera")
    cam = bpy.data.objects.new("Camera", data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    center = (lo + hi) / 2
    radius = max((hi - lo).length / 2, 1e-3)
    width, height = scene.render.resolution_x, scene.render.resolution_y
    # Sensor fit AUTO: the sensor width spans the larger image dimension.
    tan_large = data.sensor_width / 2 / data.lens
    tan_x = tan_large if width >= height else tan_large * width / height
    tan_y = tan_large if height >= width else tan_large * height / width
    forward = -VIEW_DIRECTION  # from the camera towards the model
    rotation = forward.to_track_quat('-Z', 'Y')
    right, up = rotation @ Vector((1, 0, 0)), rotation @ Vector((0, 1, 0))
    corners = [Vector((x, y, z)) - center
               for x in (lo.x, hi.x) for y in (lo.y, hi.y) for z in (lo.z, hi.z)]

    def extents(d):
        """Image-plane (tan) extents of the box from distance d: (min x, max x, min y, max y)."""
        xs = [right.dot(p) / (d + forward.dot(p)) for p in corners]
        ys = [up.dot(p) / (d + forward.dot(p)) for p in corners]
        return min(xs), max(xs), min(ys), max(ys)

    def fits(d):
        x0, x1, y0, y1 = extents(d)
        return (x1 - x0) * margin <= 2 * tan_x and (y1 - y0) * margin <= 2 * tan_y

    near = max(-forward.dot(p) for p in corners) + radius * 1e-2  # all corners in front
    far = near + radius / math.sin(math.atan(min(tan_x, tan_y))) * margin + radius
    for _ in range(60):  # bisection: the box's image shrinks with the distance
        mid = (near + far) / 2
        near, far = (near, mid) if fits(mid) else (mid, far)
    distance = far
    x0, x1, y0, y1 = extents(distance)
    cam.location = center - forward * distance
    cam.rotation_euler = rotation.to_euler()
    data.shift_x = (x0 + x1) / 2 / (2 * tan_large)  # in units of the larger image dimension
    data.shift_y = (y0 + y1) / 2 / (2 * tan_large)
    data.clip_start = max(distance - radius * 1.5, distance * 1e-3)
    data.clip_end = distance + radius * 1.5
    return cam


def _set_world(scene):
    world = bpy.data.worlds.new("OBJ World")
    world.use_nodes = True
    background = world.node_tree.nodes.get("Background")
    background.inputs["Color"].default_value = (*WORLD_COLOR, 1.0)
    background.inputs["Strength"].default_value = 1.0
    world.color = WORLD_COLOR
    scene.world = world
    return world
