"""Compound scenes that mix many features the way an artist's shot does (the accuracy audit,
docs/materials.md "Compound scenes"): a product shot, an interior and a character-like shot,
built procedurally (no downloads) at 64 x 48 from the shared helpers. Each builder starts from
an empty factory scene, so Pathlight and Cycles render the very same data."""

import math

import bmesh
import bpy
import numpy as np

from blender_util import canonical_order
import light_scenes as ls
import material_scenes as ms

W, H = 64, 48


def _scene():
    scene = ls.empty_scene(W, H)
    return scene


def _principled(name, **inputs):
    mat, nodes, links, out = ms.new_material(name)
    p = ms.set_inputs(nodes.new("ShaderNodeBsdfPrincipled"), **inputs)
    links.new(p.outputs[0], out.inputs["Surface"])
    return mat, nodes, links, p


def _cylinder(name, radius, depth, material, segments=32, **transform):
    def build(bm):
        bmesh.ops.create_cone(bm, cap_ends=True, segments=segments, radius1=radius, radius2=radius,
                              depth=depth)
        canonical_order(bm)
    return ms.add_mesh_object(name, build, (material,), smooth=True, **transform)


# ---------------------------------------------------------------- product shot

def product_world():
    """An HDRI made in numpy (saved to a temporary .exr and packed), rotated by a Mapping node
    and colour-corrected, seen by every ray but the camera's: those see a plain backdrop
    (Light Path Is Camera Ray mixing two Backgrounds)."""
    world = bpy.data.worlds.new("Product")
    world.use_nodes = True
    nt = world.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputWorld")
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(70))
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = ls.load_image(ls.synthetic_hdr(64, 32, sun_sigma=0.15, sun_peak=20.0), "product_hdr")
    hsv = ms.set_inputs(nt.nodes.new("ShaderNodeHueSaturation"), Saturation=1.3, Value=0.9)
    lit = ms.set_inputs(nt.nodes.new("ShaderNodeBackground"), Strength=1.2)
    backdrop = ms.set_inputs(nt.nodes.new("ShaderNodeBackground"), Color=(0.6, 0.62, 0.66, 1.0),
                             Strength=1.0)
    path = nt.nodes.new("ShaderNodeLightPath")
    mix = nt.nodes.new("ShaderNodeMixShader")
    L = nt.links.new
    L(coord.outputs["Generated"], mapping.inputs["Vector"])
    L(mapping.outputs["Vector"], env.inputs["Vector"])
    L(env.outputs["Color"], hsv.inputs["Color"])
    L(hsv.outputs["Color"], lit.inputs["Color"])
    L(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
    L(lit.outputs[0], mix.inputs[1])
    L(backdrop.outputs[0], mix.inputs[2])
    L(mix.outputs[0], out.inputs["Surface"])
    bpy.context.scene.world = world
    return world


def product_floor():
    """A Principled floor: Voronoi-tinted base colour, a Noise texture's bump."""
    mat, nodes, links, p = _principled("ProductFloor", Roughness=0.45)
    coord = nodes.new("ShaderNodeTexCoord")
    vor = ms.set_inputs(nodes.new("ShaderNodeTexVoronoi"), Scale=3.0)
    ramp = nodes.new("ShaderNodeMix")
    ramp.data_type = 'RGBA'
    ramp.inputs["A"].default_value = (0.55, 0.5, 0.45, 1.0)
    ramp.inputs["B"].default_value = (0.3, 0.28, 0.26, 1.0)
    noise = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=12.0, Detail=3.0)
    bump = ms.set_inputs(nodes.new("ShaderNodeBump"), Strength=0.4)
    links.new(coord.outputs["Object"], vor.inputs["Vector"])
    links.new(coord.outputs["Object"], noise.inputs["Vector"])
    links.new(vor.outputs["Distance"], ramp.inputs["Factor"])
    links.new(ramp.outputs["Result"], p.inputs["Base Color"])
    links.new(noise.outputs["Fac"], bump.inputs["Height"])
    links.new(bump.outputs["Normal"], p.inputs["Normal"])
    return mat


def bottle_glass():
    """Principled transmission (slightly rough) with a coloured Volume Absorption inside."""
    mat, nodes, links, p = _principled("Bottle", Base_Color=(1.0, 1.0, 1.0, 1.0), Roughness=0.05,
                                       IOR=1.5, Transmission_Weight=1.0)
    absorb = ms.set_inputs(nodes.new("ShaderNodeVolumeAbsorption"), Color=(0.3, 0.8, 0.4, 1.0),
                           Density=2.0)
    links.new(absorb.outputs[0], nodes["Material Output"].inputs["Volume"])
    return mat


def brushed_cap():
    """Principled metal, anisotropic along a radial Tangent (brushed around the cap's axis)."""
    mat, nodes, links, p = _principled("Cap", Base_Color=(0.9, 0.75, 0.5, 1.0), Metallic=1.0,
                                       Roughness=0.35, Anisotropic=0.7)
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = 'RADIAL'
    tangent.axis = 'Z'
    links.new(tangent.outputs["Tangent"], p.inputs["Tangent"])
    return mat


def coated_plastic():
    return _principled("Plastic", Base_Color=(0.7, 0.08, 0.05, 1.0), Roughness=0.5,
                       Coat_Weight=1.0, Coat_Roughness=0.05, Sheen_Weight=0.6,
                       Sheen_Tint=(0.9, 0.9, 1.0, 1.0))[0]


def product_shot():
    scene = _scene()
    product_world()
    ms.add_plane("Floor", 8.0, product_floor())
    _cylinder("Bottle", 0.35, 1.2, bottle_glass(), location=(-0.45, 0.2, 0.6))
    _cylinder("Cap", 0.25, 0.3, brushed_cap(), location=(0.55, -0.1, 0.15))
    ms.add_sphere("Plastic", 0.35, coated_plastic(), segments=32, rings=16, location=(0.3, 0.75, 0.35))
    ls.add_light('AREA', "Key", location=(1.5, -1.5, 2.5), rotation=(math.radians(45), 0, math.radians(45)),
                 shape='DISK', size=1.0, energy=80.0)
    ms.add_camera((0.0, -3.6, 1.5), (0.0, 0.2, 0.45), lens=40.0)
    return scene


# ---------------------------------------------------------------- interior

def _attribute_wall():
    """Principled walls coloured by a Color Attribute, roughness from a float Attribute."""
    mat, nodes, links, p = _principled("Wall", Roughness=0.8)
    col = nodes.new("ShaderNodeVertexColor")
    col.layer_name = "Paint"
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "wear"
    links.new(col.outputs["Color"], p.inputs["Base Color"])
    links.new(attr.outputs["Fac"], p.inputs["Roughness"])
    return mat


def _wall(name, material, size, **transform):
    """A 4 x 4 grid of `size` (x, y) with a per-vertex colour "Paint" and float "wear"."""
    def build(bm):
        bmesh.ops.create_grid(bm, x_segments=4, y_segments=4, size=0.5)
    obj = ms.add_mesh_object(name, build, (material,), scale=(*size, 1.0), **transform)
    mesh = obj.data
    n = len(mesh.vertices)
    co = np.empty(n * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    paint = np.ones((n, 4), np.float32)
    paint[:, 0] = 0.75 - 0.3 * (co[:, 0] + 0.5) * (co[:, 1] + 0.5)
    paint[:, 1] = 0.7
    paint[:, 2] = 0.55 + 0.3 * (co[:, 1] + 0.5)
    mesh.color_attributes.new("Paint", 'FLOAT_COLOR', 'POINT').data.foreach_set("color", paint.ravel())
    wear = (0.5 + 0.4 * np.sin(6.0 * co[:, 0])).astype(np.float32)
    mesh.attributes.new("wear", 'FLOAT', 'POINT').data.foreach_set("value", wear)
    return obj


def interior():
    """A 4 x 4 x 2.5 m room: a window in +y with a portal and a Nishita sky, an area light with
    spread, a soft point and a soft spot light, an emissive strip, attribute-painted walls, a
    Random Walk subsurface sphere and a noise-driven Principled Volume cube; lights in groups."""
    scene = _scene()
    wall = _attribute_wall()
    floor = ms.diffuse("FloorMat", (0.5, 0.42, 0.35))
    up = (math.pi / 2, 0.0, 0.0)
    ls.plane("Floor", 1.0, floor, scale=(4, 4, 1))
    _wall("Ceiling", wall, (4, 4), location=(0, 0, 2.5), rotation_euler=(math.pi, 0, 0))
    _wall("WallS", wall, (4, 2.5), location=(0, -2, 1.25), rotation_euler=(-math.pi / 2, 0, 0))
    _wall("WallW", wall, (4, 2.5), location=(-2, 0, 1.25), rotation_euler=(math.pi / 2, 0, -math.pi / 2))
    _wall("WallE", wall, (4, 2.5), location=(2, 0, 1.25), rotation_euler=(math.pi / 2, 0, math.pi / 2))
    w, z0, z1 = 0.7, 0.8, 2.0  # window half-width, sill and lintel heights
    side = 2 - w
    for name, loc, sc in [("WinL", (-2 + side / 2, 2, 1.25), (side, 2.5)), ("WinR", (2 - side / 2, 2, 1.25), (side, 2.5)),
                          ("WinB", (0, 2, z0 / 2), (2 * w, z0)), ("WinT", (0, 2, (z1 + 2.5) / 2), (2 * w, 2.5 - z1))]:
        _wall(name, wall, sc, location=loc, rotation_euler=up)
    sky = bpy.data.worlds.new("Sky")
    sky.use_nodes = True
    tex = sky.node_tree.nodes.new("ShaderNodeTexSky")
    tex.sky_type = 'NISHITA'
    tex.sun_elevation, tex.sun_rotation = math.radians(25), math.radians(200)
    tex.sun_disc = False  # a sun through the window: far beyond the test's sample budget
    sky.node_tree.links.new(tex.outputs["Color"], sky.node_tree.nodes["Background"].inputs["Color"])
    sky.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
    scene.world = sky
    portal = ls.add_light('AREA', "Portal", location=(0, 2, (z0 + z1) / 2), rotation=(-math.pi / 2, 0, 0),
                          shape='RECTANGLE', size=2 * w, size_y=z1 - z0)
    portal.data.cycles.is_portal = True
    vl = scene.view_layers[0]
    for g in ("key", "practical"):
        vl.lightgroups.add(name=g)
    area = ls.add_light('AREA', "Softbox", location=(-1.2, -1.0, 2.3), rotation=(math.radians(20), 0, 0),
                        shape='SQUARE', size=0.8, energy=120.0, spread=math.radians(60),
                        color=(1.0, 0.9, 0.8))
    area.lightgroup = "key"
    lamp = ls.add_light('POINT', "Lamp", location=(1.3, 0.8, 1.2), energy=25.0, shadow_soft_size=0.15,
                        color=(1.0, 0.7, 0.4))
    spot = ls.add_light('SPOT', "Spot", location=(0.8, -1.5, 2.3), rotation=(math.radians(35), 0, math.radians(20)),
                        energy=150.0, shadow_soft_size=0.1, spot_size=math.radians(50), spot_blend=0.4)
    lamp.lightgroup = spot.lightgroup = "practical"
    ls.box("Strip", 1.0, ms.emission("StripMat", (0.6, 0.8, 1.0), 6.0), location=(-1.95, 0.6, 1.8),
           scale=(0.04, 1.2, 0.04))
    skin = _principled("Wax", Base_Color=(0.85, 0.8, 0.6, 1.0), Subsurface_Weight=1.0,
                       Subsurface_Radius=(1.0, 0.5, 0.25), Subsurface_Scale=0.1, Roughness=0.4)
    skin[3].subsurface_method = 'RANDOM_WALK'
    ms.add_sphere("Wax", 0.35, skin[0], segments=32, rings=16, location=(0.7, 0.6, 0.35))
    fog, nodes, links, out = ms.new_material("Smoke")
    pv = ms.set_inputs(nodes.new("ShaderNodeVolumePrincipled"), Color=(0.8, 0.8, 0.85, 1.0))
    noise = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=2.5, Detail=2.0)
    dens = nodes.new("ShaderNodeMath")
    dens.operation = 'MULTIPLY'
    dens.inputs[1].default_value = 4.0
    links.new(noise.outputs["Fac"], dens.inputs[0])
    links.new(dens.outputs[0], pv.inputs["Density"])
    links.new(pv.outputs[0], out.inputs["Volume"])
    # Lifted 2 cm off the floor: a volume's face coplanar with a surface differs from Cycles
    # (docs/materials.md, "Known differences"; smoke_on_floor() below keeps that case).
    ls.box("Smoke", 0.8, fog, location=(-0.6, 0.7, 0.42))
    ls.camera((0.2, -1.8, 1.3), look_at=(0.0, 1.5, 0.8), lens=18.0)
    return scene


# ---------------------------------------------------------------- character

def normal_map_image():
    """A tangent-space normal map of bumps (numpy), row 0 = bottom, non-colour."""
    n = 32
    v, u = np.mgrid[0:n, 0:n] / n
    hx = 0.35 * np.cos(2 * np.pi * 6 * u) * np.sin(2 * np.pi * 3 * v)
    hy = 0.35 * np.sin(2 * np.pi * 6 * u) * np.cos(2 * np.pi * 3 * v)
    nrm = np.stack([-hx, -hy, np.ones_like(hx)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    px = np.ones((n, n, 4), np.float32)
    px[..., :3] = nrm * 0.5 + 0.5
    return ms.pixel_image("Bumps", px, colorspace="Non-Color", float_buffer=True)


def skin():
    mat, nodes, links, p = _principled("Skin", Base_Color=(0.8, 0.55, 0.45, 1.0), Roughness=0.45,
                                       Subsurface_Weight=1.0, Subsurface_Radius=(1.0, 0.35, 0.2),
                                       Subsurface_Scale=0.05)
    p.subsurface_method = 'RANDOM_WALK'
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = normal_map_image()
    nmap = ms.set_inputs(nodes.new("ShaderNodeNormalMap"), Strength=0.8)
    nmap.uv_map = "UVMap"
    uv = nodes.new("ShaderNodeUVMap")
    uv.uv_map = "UVMap"
    links.new(uv.outputs["UV"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], nmap.inputs["Color"])
    links.new(nmap.outputs["Normal"], p.inputs["Normal"])
    return mat


def add_scalp_hair(name, material, center, radius, strands=120, keys=5, length=0.5, seed=3):
    """Curves strands rooted on the upper cap of a sphere, growing outwards and drooping."""
    rng = np.random.default_rng(seed)
    curves = bpy.data.hair_curves.new(name)
    curves.add_curves([keys] * strands)
    z = rng.uniform(0.35, 0.95, strands)
    phi = rng.uniform(0, 2 * np.pi, strands)
    root = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1)
    t = np.linspace(0, 1, keys)[None, :, None]
    pts = (np.asarray(center) + root[:, None] * radius * (1 + 0.02)
           + root[:, None] * length * t - np.array([0, 0, 1.0]) * length * 0.8 * t ** 2)
    curves.attributes["position"].data.foreach_set("vector", pts.astype(np.float32).ravel())
    r = curves.attributes.new("radius", 'FLOAT', 'POINT')
    r.data.foreach_set("value", np.tile(np.linspace(0.012, 0.004, keys), strands).astype(np.float32))
    curves.materials.append(material)
    obj = bpy.data.objects.new(name, curves)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def hair_material(model='CHIANG'):
    mat, nodes, links, out = ms.new_material("HairMat")
    node = nodes.new("ShaderNodeBsdfHairPrincipled")
    node.model = model
    node.parametrization = 'MELANIN'
    ms.set_inputs(node, Melanin=0.6, Melanin_Redness=0.5, Roughness=0.4)
    links.new(node.outputs[0], out.inputs["Surface"])
    return mat


def character():
    """A subsurface, normal-mapped head with Principled Hair (Chiang) curves, depth of field
    focused on it, and a small sphere moving fast (motion blur) in front of a backdrop."""
    scene = _scene()
    scene.cycles_curves.shape = 'THICK'
    ls.world_color((0.12, 0.14, 0.18))
    ms.add_plane("Floor", 8.0, ms.diffuse("Backdrop", (0.45, 0.45, 0.45)))
    ls.plane("Back", 8.0, ms.diffuse("BackWall", (0.4, 0.45, 0.5)), location=(0, 2.0, 2.0),
             rotation_euler=(math.pi / 2, 0, 0))
    def head(bm):
        bm.loops.layers.uv.new("UVMap")
        bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=0.5, calc_uvs=True)
        canonical_order(bm)
    ms.add_mesh_object("Head", head, (skin(),), smooth=True, location=(0.0, 0.0, 0.7))
    add_scalp_hair("Hair", hair_material(), (0.0, 0.0, 0.7), 0.5)
    ball = ms.add_sphere("Ball", 0.15, ms.glossy("Ball", (0.2, 0.5, 0.9), roughness=0.3), segments=24,
                         rings=12, location=(-0.9, -0.6, 0.3))
    prefs = bpy.context.preferences.edit
    old = prefs.keyframe_new_interpolation_type
    prefs.keyframe_new_interpolation_type = 'LINEAR'
    try:
        for frame, x in ((1, -0.9), (2, -0.5)):
            ball.location.x = x
            ball.keyframe_insert("location", frame=frame)
    finally:
        prefs.keyframe_new_interpolation_type = old
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    ls.add_light('AREA', "Key", location=(-1.5, -1.5, 2.2), rotation=(math.radians(50), 0, math.radians(-45)),
                 shape='RECTANGLE', size=1.2, size_y=0.8, energy=150.0)
    ls.add_light('AREA', "Rim", location=(1.2, 1.5, 1.8), rotation=(math.radians(-60), 0, math.radians(-140)),
                 shape='DISK', size=0.6, energy=60.0, color=(0.8, 0.9, 1.0))
    cam = ms.add_camera((0.0, -3.0, 1.1), (-0.2, 0.0, 0.7), lens=40.0)
    cam.data.dof.use_dof = True
    cam.data.dof.focus_distance = 2.6  # just behind the ball: the head and the wall blur
    cam.data.dof.aperture_fstop = 0.5
    return scene


def smoke_on_floor():
    """The interior with its smoke box resting on the floor (its bottom face coplanar with it)."""
    scene = interior()
    bpy.data.objects["Smoke"].location.z = 0.4
    return scene


SCENES = {"product": product_shot, "interior": interior, "character": character}
