"""Lamp-lit scenes with smooth glass and chrome (issue 25, the automatic rule for lamps): what an
artist renders with Blender's lamps, to measure caustic light paths where the environment's sun
rule does not reach. Built procedurally in bpy like realistic_scenes.py (not bench scenes: not in
`build.py bench`); each builder starts from an empty factory scene and returns it.

- sun_interior: a closed room lit by a Sun lamp of Blender's default angle (0.526 degrees)
  through an open window (no pane) and a dim sky colour; on a table in the sun a smooth glass
  tumbler (Glass BSDF, thick base), a smooth Principled glass carafe (Transmission 1, roughness 0)
  and a chrome can (Principled metallic, roughness 0); diffuse and Principled walls, a sofa.
- product_shot: a glass bottle (Glass BSDF, 3 mm walls) and a chrome sphere on a light grey floor
  and backdrop, lit by an area lamp (1 m square) in front and a spot of radius 0.1 behind them
  (the bottle's caustic falls in front of it), a near-black world.

Controls (where the rule would cost without paying):
- product_glossy: product_shot with a glazed ceramic bottle (Principled, roughness 0.2) and a
  satin metal sphere (roughness 0.2): no glass, no mirror.
- sun_interior_offscreen: sun_interior with the camera turned to the sofa: the glass, the chrome
  and their caustics off screen (the glass still in the sun, so the probes find it).
- sun_interior_pane: sun_interior with a 6 mm pane of smooth glass in its window: all the sun's
  light in the room is then a caustic (no shadow ray passes glass).
"""
import math
import sys
from pathlib import Path

import bpy
from mathutils import Vector

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import light_scenes as ls  # noqa: E402
import material_scenes as ms  # noqa: E402
import realistic_scenes as rs  # noqa: E402

import bmesh  # noqa: E402  (after bpy)

WIDTH, HEIGHT = 96, 72
SUN_ANGLE = 0.009180432185530663  # Blender's default Sun angle (0.526 degrees)


def lathe(name, profile, material, segments=48, **transform):
    """A closed solid of revolution about z: profile = [(r, z), ...] from a point on the axis
    (r = 0) round to another on the axis, the rings between with r > 0; smooth-shaded, with
    edges sharper than 40 degrees kept sharp (the tumbler's rim and base)."""
    def build(bm):
        rings = []
        for r, z in profile[1:-1]:
            rings.append([bm.verts.new((r * math.cos(2 * math.pi * k / segments),
                                        r * math.sin(2 * math.pi * k / segments), z))
                          for k in range(segments)])
        bottom = bm.verts.new((0.0, 0.0, profile[0][1]))
        top = bm.verts.new((0.0, 0.0, profile[-1][1]))
        for k in range(segments):
            k1 = (k + 1) % segments
            bm.faces.new((bottom, rings[0][k1], rings[0][k]))
            for a, b in zip(rings, rings[1:]):
                bm.faces.new((a[k], a[k1], b[k1], b[k]))
            bm.faces.new((rings[-1][k], rings[-1][k1], top))
        bmesh.ops.recalc_face_normals(bm, faces=bm.faces)
        ms.canonical_order(bm)
    obj = ms.add_mesh_object(name, build, (material,), smooth=True, **transform)
    obj.data.set_sharp_from_angle(angle=math.radians(40.0))
    return obj


def glass_material(name, ior=1.45):
    return ms.bsdf_material(name, "ShaderNodeBsdfGlass", Color=(1.0, 1.0, 1.0, 1.0), Roughness=0.0, IOR=ior)[0]


def chrome_material(name, roughness=0.0):
    return rs.principled(name, (0.95, 0.95, 0.95), roughness, metallic=1.0)


def tumbler(name, material, radius=0.04, height=0.1, wall=0.003, base=0.012, **transform):
    r, t = radius, wall
    profile = [(0.0, 0.0), (r - 0.004, 0.0), (r, 0.004), (r, height), (r - t, height), (r - t, base),
               (0.0, base)]
    return lathe(name, profile, material, **transform)


def bottle(name, material, radius=0.07, height=0.3, neck=0.018, wall=0.003, **transform):
    """A hollow bottle (walls `wall` thick, closed at the top: its cork is glass too)."""
    r, t, h = radius, wall, height
    outer = [(0.0, 0.0), (r - 0.01, 0.0), (r, 0.01), (r, 0.6 * h), (0.75 * r, 0.72 * h),
             (neck + 0.004, 0.82 * h), (neck, 0.86 * h), (neck, h)]
    inner = [(neck - t, h - t), (neck - t, 0.86 * h), (neck + 0.004 - t, 0.82 * h),
             (0.75 * r - t, 0.72 * h - t), (r - t, 0.6 * h - t), (r - t, 0.01 + t),
             (r - 0.01 - t, t + 0.002), (0.0, t + 0.002)]
    # Outer surface up to the mouth, then the inner one back down: one closed shell whose
    # "inside" is the glass between them.
    return lathe(name, outer + inner, material, segments=48, **transform)


def carafe(name, material, **transform):
    """A solid-walled round carafe: a sphere of 0.07 with a short neck, walls 3 mm."""
    pts_out = [(0.0, 0.0)]
    pts_in = []
    for k in range(1, 12):
        a = -math.pi / 2 + math.pi * 0.8 * k / 11  # up the sphere's side to 54 degrees above its equator
        pts_out.append((0.07 * math.cos(a), 0.07 + 0.07 * math.sin(a)))
    pts_out += [(0.022, 0.15), (0.022, 0.2)]
    pts_in += [(0.019, 0.2 - 0.003), (0.019, 0.15)]
    for k in range(11, 0, -1):
        a = -math.pi / 2 + math.pi * 0.8 * k / 11
        pts_in.append((0.067 * math.cos(a), 0.07 + 0.067 * math.sin(a)))
    pts_in.append((0.0, 0.003))
    return lathe(name, pts_out + pts_in, material, segments=48, **transform)


def sun_interior(width=WIDTH, height=HEIGHT, view=True, pane=False):
    scene = rs._empty(width, height)
    rs.room("Room", (5.0, 4.0, 2.6), window=(-0.6, 1.0, 0.9, 2.1),
            wall=rs.principled("SunWall", (0.75, 0.73, 0.68), 0.8),
            floor=rs.principled("SunFloor", (0.4, 0.28, 0.18), 0.4))
    wood = rs.principled("SunWood", (0.5, 0.32, 0.18), 0.35)
    linen = ms.diffuse("SunLinen", (0.85, 0.85, 0.82))
    rs.box("Table", (1.4, 0.8, 0.05), wood, (0.3, 1.0, 0.725))
    rs.box("Cloth", (0.9, 0.55, 0.004), linen, (0.3, 1.0, 0.752))
    for dx in (-0.62, 0.62):
        for dy in (-0.34, 0.34):
            rs.box(f"Leg{dx}{dy}", (0.05, 0.05, 0.7), wood, (0.3 + dx, 1.0 + dy, 0.35))
    fabric = rs.principled("SunFabric", (0.3, 0.4, 0.55), 0.9)
    rs.box("Sofa", (1.8, 0.8, 0.45), fabric, (-1.3, -1.4, 0.225))
    rs.box("SofaBack", (1.8, 0.2, 0.85), fabric, (-1.3, -1.75, 0.425))
    top = 0.754
    tumbler("Tumbler", glass_material("TumblerGlass"), location=(0.18, 1.05, top))
    carafe("Carafe", rs.principled("CarafeGlass", (1.0, 1.0, 1.0), 0.0, Transmission_Weight=1.0, IOR=1.5),
           location=(0.45, 1.12, top))
    lathe("Can", [(0.0, 0.0), (0.032, 0.0), (0.033, 0.002), (0.033, 0.11), (0.03, 0.115), (0.0, 0.115)],
          chrome_material("SunChrome"), location=(0.62, 0.92, top))
    if pane:  # a 6 mm pane of smooth glass filling the window
        rs.box("Pane", (1.6, 0.006, 1.2), glass_material("PaneGlass", 1.52), (0.2, 1.99, 1.5))
    ms.set_world((0.05, 0.07, 0.1))
    sun = ls.add_light('SUN', name="Sun", energy=4.0, angle=SUN_ANGLE)
    ms.look_at(sun, Vector((0.0, 0.0, 0.0)) + Vector((-0.25, -1.0, -0.7)))  # in through the +y window
    if view:
        ms.add_camera((-0.25, 0.25, 1.15), (0.4, 1.0, 0.8), lens=35.0)
    else:
        ms.add_camera((0.8, 0.6, 1.5), (-1.4, -1.6, 0.5), lens=30.0)
    return scene


def sun_interior_offscreen(width=WIDTH, height=HEIGHT):
    return sun_interior(width, height, view=False)


def sun_interior_pane(width=WIDTH, height=HEIGHT):
    return sun_interior(width, height, pane=True)


def product_shot(width=WIDTH, height=HEIGHT, glass=True):
    scene = rs._empty(width, height)
    grey = rs.principled("Sweep", (0.7, 0.7, 0.7), 0.6)
    ms.add_plane("Floor", 10.0, grey)
    ms.add_plane("Backdrop", 10.0, grey, location=(0.0, 1.2, 5.0), rotation_euler=(math.pi / 2, 0.0, 0.0))
    if glass:
        bottle_mat = glass_material("BottleGlass", 1.5)
        metal = chrome_material("ProductChrome")
    else:
        bottle_mat = rs.principled("Ceramic", (0.2, 0.35, 0.5), 0.2)
        metal = chrome_material("ProductSatin", 0.2)
    bottle("Bottle", bottle_mat, location=(-0.12, 0.1, 0.0))
    ms.add_sphere("Sphere", 0.07, metal, location=(0.16, -0.05, 0.07))
    area = ls.add_light('AREA', name="Key", location=(-1.2, -1.4, 1.4), energy=30.0, size=1.0)
    ms.look_at(area, (0.0, 0.0, 0.1))
    spot = ls.add_light('SPOT', name="Rim", location=(0.6, 1.0, 0.9), energy=60.0, shadow_soft_size=0.1,
                        spot_size=math.radians(40.0), spot_blend=0.3)
    ms.look_at(spot, (-0.1, 0.0, 0.0))
    ms.set_world((0.02, 0.02, 0.02))
    ms.add_camera((0.15, -0.85, 0.32), (0.0, 0.0, 0.09), lens=45.0)
    return scene


def product_glossy(width=WIDTH, height=HEIGHT):
    return product_shot(width, height, glass=False)


SCENES = {
    "Room lit by a sun lamp, glass and chrome on a table": sun_interior,
    "Product shot: glass bottle and chrome under an area lamp and a spot": product_shot,
    "Product shot, glazed ceramic and satin metal (no glass or mirror)": product_glossy,
    "Room lit by a sun lamp, the glass off screen": sun_interior_offscreen,
    "Room lit by a sun lamp through a glass pane": sun_interior_pane,
}
