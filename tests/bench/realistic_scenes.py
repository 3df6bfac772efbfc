"""Realistic bench scenes, built procedurally in bpy (issue 25): what artists render rather than
Cornell boxes. Each builder starts from an empty factory scene and returns it.

- window_room: a closed room lit only by the sun and a Nishita sky through one window, so
  nearly all the light on the walls is indirect.
- window_room_portal: the same room with a light portal in its window.
- lamp_room: a closed room lit by 50 small point lamps of different colours and powers and
  3 spot lights (the light tree's case).
- hdri_model: Blender's Suzanne, subdivided, with procedurally textured Principled materials
  (noise colour ramp, brick bump) on an image-textured floor, under an HDR environment.
- principled_spheres: nine spheres, one per Principled feature that artists use (the untouched
  default, coat over red paint, sheen fabric, subsurface wax, brushed anisotropic metal, rough
  glass, thin-film iridescence, tinted specular, gold), under an HDR environment and a point
  light (issue 24's Principled-heavy scene).
- instanced_forest: 1.3 M triangles as 64 geometry-nodes instances of one subdivided
  icosphere, on a ground under a sun and a sky colour.

Nothing is loaded from outside the repository: the meshes are Blender primitives, the textures
procedural or made with numpy, the HDR synthetic (tests/blender/light_scenes.py)."""
import math
import sys
from pathlib import Path

import bpy
import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
import light_scenes as ls  # noqa: E402
import material_scenes as ms  # noqa: E402

import bmesh  # noqa: E402  (after bpy)

WIDTH, HEIGHT = 96, 72


def _empty(width=WIDTH, height=HEIGHT):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    return scene


def principled(name, color, roughness=0.5, metallic=0.0, **inputs):
    mat, node = ms.bsdf_material(name, "ShaderNodeBsdfPrincipled", Base_Color=(*color, 1.0),
                                 Roughness=roughness, Metallic=metallic)
    ms.set_inputs(node, **inputs)
    return mat


def _quad(bm, corners):
    verts = [bm.verts.new(c) for c in corners]
    bm.faces.new(verts)


def room(name, size, window=None, wall=None, floor=None, ceiling=None):
    """An inward-facing closed box of size (x, y, z) from z = 0, its walls, floor and ceiling
    each a material; window: (x0, x1, z0, z1) cut in the +y wall."""
    sx, sy, sz = size[0] / 2, size[1] / 2, size[2]
    wall = wall or principled(f"{name}Wall", (0.8, 0.78, 0.74), 0.7)
    floor = floor or principled(f"{name}Floor", (0.45, 0.3, 0.18), 0.45)
    ceiling = ceiling or principled(f"{name}Ceiling", (0.85, 0.85, 0.85), 0.8)

    def build(bm):
        # Inward normals: each face wound so that its normal points into the room.
        _quad(bm, [(-sx, -sy, 0), (-sx, sy, 0), (sx, sy, 0), (sx, -sy, 0)])           # floor (up)
        _quad(bm, [(-sx, -sy, sz), (sx, -sy, sz), (sx, sy, sz), (-sx, sy, sz)])       # ceiling (down)
        _quad(bm, [(-sx, -sy, 0), (sx, -sy, 0), (sx, -sy, sz), (-sx, -sy, sz)])       # -y wall
        _quad(bm, [(-sx, -sy, 0), (-sx, -sy, sz), (-sx, sy, sz), (-sx, sy, 0)])       # -x wall
        _quad(bm, [(sx, -sy, 0), (sx, sy, 0), (sx, sy, sz), (sx, -sy, sz)])           # +x wall
        if window is None:
            _quad(bm, [(-sx, sy, 0), (-sx, sy, sz), (sx, sy, sz), (sx, sy, 0)])       # +y wall
        else:  # the +y wall around its window: four quads
            x0, x1, z0, z1 = window
            for a, b, c, d in (((-sx, 0), (-sx, sz), (x0, sz), (x0, 0)),
                               ((x1, 0), (x1, sz), (sx, sz), (sx, 0)),
                               ((x0, 0), (x0, z0), (x1, z0), (x1, 0)),
                               ((x0, z1), (x0, sz), (x1, sz), (x1, z1))):
                _quad(bm, [(a[0], sy, a[1]), (b[0], sy, b[1]), (c[0], sy, c[1]), (d[0], sy, d[1])])
        for i, f in enumerate(bm.faces):
            f.material_index = 0 if i == 0 else (1 if i == 1 else 2)
    bm_mats = (floor, ceiling, wall)
    obj = ms.add_mesh_object(name, build, bm_mats)
    return obj


def box(name, size, material, location, rotation=0.0):
    def build(bm):
        bmesh.ops.create_cube(bm, size=1.0)
        bmesh.ops.scale(bm, vec=size, verts=bm.verts)
    return ms.add_mesh_object(name, build, (material,), location=location,
                              rotation_euler=(0.0, 0.0, rotation))


def furniture(prefix):
    """A sofa, a table with a metal bowl, a glossy cabinet: Principled materials."""
    fabric = principled(f"{prefix}Fabric", (0.25, 0.35, 0.6), 0.9)
    wood = principled(f"{prefix}Wood", (0.55, 0.35, 0.2), 0.35, **{"Specular_IOR_Level": 0.5})
    lacquer = principled(f"{prefix}Lacquer", (0.75, 0.1, 0.08), 0.15, Coat_Weight=0.6, Coat_Roughness=0.05)
    metal = principled(f"{prefix}Metal", (0.9, 0.75, 0.5), 0.25, metallic=1.0)
    box(f"{prefix}Sofa", (2.0, 0.8, 0.45), fabric, (-1.2, -1.4, 0.225))
    box(f"{prefix}SofaBack", (2.0, 0.2, 0.9), fabric, (-1.2, -1.75, 0.45))
    box(f"{prefix}Table", (1.2, 0.7, 0.06), wood, (0.4, 0.1, 0.45))
    for dx in (-0.5, 0.5):
        for dy in (-0.28, 0.28):
            box(f"{prefix}Leg{dx}{dy}", (0.06, 0.06, 0.42), wood, (0.4 + dx, 0.1 + dy, 0.21))
    bowl = ms.add_sphere(f"{prefix}Bowl", 0.18, metal, location=(0.5, 0.1, 0.62), segments=32, rings=16)
    bowl.scale = (1.0, 1.0, 0.6)
    box(f"{prefix}Cabinet", (0.5, 1.4, 1.1), lacquer, (2.2, 0.6, 0.55))


def window_room(width=WIDTH, height=HEIGHT):
    scene = _empty(width, height)
    room("Room", (6.0, 5.0, 2.8), window=(-1.0, 1.2, 0.9, 2.2))
    furniture("W")
    world = bpy.data.worlds.new("Sky")
    world.use_nodes = True
    nt = world.node_tree
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sky_type = 'NISHITA'
    sky.sun_elevation = math.radians(28.0)
    sky.sun_rotation = math.radians(10.0)  # the sun shines in through the +y wall's window
    nt.links.new(sky.outputs["Color"], nt.nodes["Background"].inputs["Color"])
    nt.nodes["Background"].inputs["Strength"].default_value = 0.2
    scene.world = world
    ms.add_camera((-2.4, -2.2, 1.5), (0.6, 1.2, 1.0), lens=22.0)
    return scene


def window_room_portal(width=WIDTH, height=HEIGHT):
    """window_room with a light portal filling its window (Cycles' is_portal area light)."""
    scene = window_room(width, height)
    x0, x1, z0, z1 = -1.0, 1.2, 0.9, 2.2
    ls.add_light('AREA', name="Portal", location=((x0 + x1) / 2, 2.5, (z0 + z1) / 2),
                 rotation=(-math.pi / 2, 0.0, 0.0), shape='RECTANGLE', size=x1 - x0,
                 size_y=z1 - z0).data.cycles.is_portal = True  # lets the sky in along -y
    return scene


def lamp_room(width=WIDTH, height=HEIGHT):
    scene = _empty(width, height)
    room("Hall", (6.0, 5.0, 2.8))
    furniture("L")
    ms.set_world((0.0, 0.0, 0.0))
    rng = np.random.default_rng(25)
    for i in range(50):  # small lamps of different colours and powers, mostly near the ceiling
        loc = (rng.uniform(-2.8, 2.8), rng.uniform(-2.3, 2.3), rng.uniform(1.6, 2.7))
        ls.add_light('POINT', name=f"Lamp{i}", location=tuple(loc), energy=float(rng.uniform(2.0, 15.0)),
                     color=tuple(rng.uniform(0.5, 1.0, 3)), shadow_soft_size=0.03)
    for i, (loc, target) in enumerate((((-2.0, 2.0, 2.7), (-1.2, -1.4, 0.5)),
                                       ((2.0, -2.0, 2.7), (0.4, 0.1, 0.5)),
                                       ((0.0, 2.2, 2.7), (2.2, 0.6, 0.5)))):
        spot = ls.add_light('SPOT', name=f"Spot{i}", location=loc, energy=120.0, shadow_soft_size=0.05)
        ms.look_at(spot, target)
        spot.data.spot_size = math.radians(40.0)
        spot.data.spot_blend = 0.3
    ms.add_camera((-2.4, -2.2, 1.6), (0.8, 1.0, 0.6), lens=22.0)
    return scene


def _checker_image(name, n=512, tiles=16):
    y, x = np.mgrid[0:n, 0:n] * tiles // n
    c = ((x + y) % 2).astype(np.float32)
    rgb = np.stack([0.2 + 0.55 * c, 0.2 + 0.5 * c, 0.22 + 0.4 * c], axis=-1)
    px = np.concatenate([rgb, np.ones((n, n, 1), np.float32)], -1)
    return ms.pixel_image(name, px, colorspace="Linear Rec.709", float_buffer=True)


def _textured_principled(name):
    """Principled with a noise colour ramp as Base Color and a brick height as bump."""
    mat, nodes, links, out = ms.new_material(name)
    p = nodes.new("ShaderNodeBsdfPrincipled")
    p.inputs["Roughness"].default_value = 0.35
    noise = nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 6.0
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.6, 0.25, 0.08, 1.0)
    ramp.color_ramp.elements[1].color = (0.95, 0.8, 0.4, 1.0)
    brick = nodes.new("ShaderNodeTexBrick")
    brick.inputs["Scale"].default_value = 12.0
    bump = nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 0.3
    links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], p.inputs["Base Color"])
    links.new(brick.outputs["Fac"], bump.inputs["Height"])
    links.new(bump.outputs["Normal"], p.inputs["Normal"])
    links.new(p.outputs[0], out.inputs["Surface"])
    return mat


def hdri_model(width=WIDTH, height=HEIGHT):
    scene = _empty(width, height)
    bpy.ops.mesh.primitive_monkey_add(size=1.6, location=(0.0, 0.0, 0.9))
    monkey = bpy.context.active_object
    monkey.rotation_euler = (0.0, 0.0, math.radians(20.0))
    monkey.modifiers.new("Subsurf", 'SUBSURF').levels = 2
    monkey.data.shade_smooth()
    monkey.data.materials.append(_textured_principled("Gilded"))
    floor = ms.textured_material("Tiles", _checker_image("TileImage"))
    ms.add_plane("Floor", 8.0, floor)
    ms.add_sphere("Chrome", 0.35, principled("Chrome", (0.95, 0.95, 0.95), 0.05, metallic=1.0),
                  location=(1.3, 0.4, 0.35))
    ls.world_image(ls.load_image(ls.synthetic_hdr(256, 128, sun_peak=200.0), name="BenchHDR"))
    ms.add_camera((0.0, -4.6, 2.0), (0.0, 0.0, 0.8), lens=45.0)
    return scene


def principled_spheres(width=WIDTH, height=HEIGHT):
    scene = _empty(width, height)
    features = [
        ("Default", principled("Default", (0.8, 0.8, 0.8))),
        ("Car paint", principled("Car paint", (0.6, 0.02, 0.02), 0.4, Coat_Weight=1.0, Coat_Roughness=0.05)),
        ("Velvet", principled("Velvet", (0.15, 0.1, 0.4), 0.8, Sheen_Weight=1.0, Sheen_Roughness=0.4,
                              Sheen_Tint=(0.9, 0.8, 1.0, 1.0))),
        ("Wax", principled("Wax", (0.9, 0.75, 0.55), 0.4, Subsurface_Weight=1.0, Subsurface_Scale=0.1)),
        ("Brushed", principled("Brushed", (0.9, 0.9, 0.92), 0.35, metallic=1.0, Anisotropic=0.8)),
        ("Frosted glass", principled("Frosted glass", (0.95, 0.98, 1.0), 0.2, Transmission_Weight=1.0)),
        ("Soap film", principled("Soap film", (0.05, 0.05, 0.05), 0.1, Thin_Film_Thickness=500.0,
                                 Thin_Film_IOR=1.33)),
        ("Tinted specular", principled("Tinted specular", (0.1, 0.3, 0.2), 0.3, Specular_IOR_Level=0.8,
                                       Specular_Tint=(1.0, 0.7, 0.3, 1.0))),
        ("Gold", principled("Gold", (1.0, 0.77, 0.34), 0.25, metallic=1.0)),
    ]
    for i, (name, mat) in enumerate(features):
        x, y = (i % 3 - 1) * 1.1, (i // 3 - 1) * 1.1
        ms.add_sphere(name, 0.45, mat, location=(x, y, 0.45))
    ms.add_plane("Floor", 10.0, principled("Floor", (0.5, 0.5, 0.5), 0.6))
    ls.world_image(ls.load_image(ls.synthetic_hdr(256, 128, sun_peak=50.0), name="BenchHDR"))
    bpy.ops.object.light_add(type='POINT', location=(2.0, -2.5, 3.5))
    bpy.context.active_object.data.energy = 300.0
    bpy.context.active_object.data.shadow_soft_size = 0.2
    ms.add_camera((0.0, -5.2, 3.6), (0.0, 0.0, 0.3), lens=40.0)
    return scene


def instanced_forest(width=WIDTH, height=HEIGHT):
    scene = _empty(width, height)
    bark = principled("Bark", (0.3, 0.45, 0.2), 0.6)
    def ico(bm):
        # 20 480 triangles (bmesh counts the icosahedron itself as 1: 5 made 5 120)
        bmesh.ops.create_icosphere(bm, subdivisions=6, radius=0.35)
    tree = ms.add_mesh_object("Crown", ico, (bark,), smooth=True)
    tree.hide_render = True
    host = ms.add_plane("Host", 0.01, None)
    ms.scatter_on_grid(host, tree, 6.0, 8, scale=(0.6, 1.3), name="Forest")
    ms.add_plane("Ground", 12.0, principled("Ground", (0.35, 0.3, 0.22), 0.8), location=(0.0, 0.0, -0.3))
    ms.set_world((0.35, 0.45, 0.6))
    sun = ms.add_sun(energy=3.0, tilt_deg=35.0)
    sun.rotation_euler = (math.radians(30.0), math.radians(35.0), 0.0)
    ms.add_camera((0.0, -7.5, 3.2), (0.0, 0.0, 0.0), lens=35.0)
    return scene


SCENES = {
    "Room lit through a window (sun and sky)": window_room,
    "Room lit through a window with a portal": window_room_portal,
    "Room lit by 50 lamps and 3 spots": lamp_room,
    "Textured model under an HDRI": hdri_model,
    "Principled spheres under an HDRI and a point light": principled_spheres,
    "1.3 M triangles in 64 instances": instanced_forest,
}
