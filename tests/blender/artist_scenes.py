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


# ================================================================ second audit (2026-12-08)
# Four more shots, of kinds the first three did not cover (docs/materials.md, "Compound
# scenes"): archviz daylight, foliage, a night street, a stylised (NPR-ish) shot.

def _link(nodes, links, a, b):
    links.new(a, b)


def _mix_shader(nodes, links, fac, a, b):
    """A Mix Shader: `fac` (a socket or a number), shaders a (fac 0) and b (fac 1)."""
    mix = nodes.new("ShaderNodeMixShader")
    if isinstance(fac, (int, float)):
        mix.inputs["Fac"].default_value = fac
    else:
        links.new(fac, mix.inputs["Fac"])
    links.new(a, mix.inputs[1])
    links.new(b, mix.inputs[2])
    return mix


def _math(nodes, links, op, a, b=None, clamp=False):
    m = nodes.new("ShaderNodeMath")
    m.operation = op
    m.use_clamp = clamp
    for i, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, (int, float)):
            m.inputs[i].default_value = v
        else:
            links.new(v, m.inputs[i])
    return m


def _grid_cylinder(name, radius, depth, material, rings=12, segments=24, **transform):
    """A capped cylinder along z with `rings` rows of quads (enough vertices to displace)."""
    def build(bm):
        uv = bm.loops.layers.uv.new("UVMap")
        rows = []
        for r in range(rings + 1):
            z = -depth / 2 + depth * r / rings
            rows.append([bm.verts.new((radius * math.cos(2 * math.pi * s / segments),
                                       radius * math.sin(2 * math.pi * s / segments), z))
                         for s in range(segments)])
        for r in range(rings):
            for s in range(segments):
                t = (s + 1) % segments
                f = bm.faces.new((rows[r][s], rows[r][t], rows[r + 1][t], rows[r + 1][s]))
                for loop, (u, v) in zip(f.loops, ((s, r), (s + 1, r), (s + 1, r + 1), (s, r + 1))):
                    loop[uv].uv = (u / segments, v / rings)
        bm.faces.new(list(reversed(rows[0])))
        bm.faces.new(rows[-1])
        canonical_order(bm)
    return ms.add_mesh_object(name, build, (material,), smooth=True, **transform)


# ---------------------------------------------------------------- archviz daylight

def wood_image(n=64):
    """A wood-grain texture (numpy): rings along v, distorted by a few sines; sRGB bytes."""
    v, u = np.mgrid[0:n, 0:n] / n
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (6 * v + 0.35 * np.sin(2 * np.pi * 2 * u)
                                            + 0.1 * np.sin(2 * np.pi * 7 * u)))
    planks = (np.floor(u * 4) % 2) * 0.08
    g = 0.55 + 0.3 * rings - planks
    px = np.ones((n, n, 4), np.float32)
    px[..., 0], px[..., 1], px[..., 2] = 0.75 * g, 0.5 * g, 0.3 * g
    return ms.pixel_image("Wood", px)


def wood_floor():
    """Principled floor: an Image Texture through Mapping (UV scaled, rotated), its value as a
    Bump's height."""
    mat, nodes, links, p = _principled("WoodFloor", Roughness=0.35)
    coord = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (2.0, 3.0, 1.0)
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(15))
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = wood_image()
    bump = ms.set_inputs(nodes.new("ShaderNodeBump"), Strength=0.5, Distance=0.02)
    links.new(coord.outputs["UV"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], p.inputs["Base Color"])
    links.new(tex.outputs["Color"], bump.inputs["Height"])
    links.new(bump.outputs["Normal"], p.inputs["Normal"])
    return mat


def window_glass():
    """The archviz trick: Glass for every ray but shadow rays, which see Transparent."""
    mat, nodes, links, out = ms.new_material("WindowGlass")
    glass = ms.set_inputs(nodes.new("ShaderNodeBsdfGlass"), IOR=1.5, Roughness=0.0)
    clear = nodes.new("ShaderNodeBsdfTransparent")
    path = nodes.new("ShaderNodeLightPath")
    mix = _mix_shader(nodes, links, path.outputs["Is Shadow Ray"], glass.outputs[0], clear.outputs[0])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def curtain():
    mat, nodes, links, out = ms.new_material("Curtain")
    d = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.85, 0.8, 0.7, 1.0))
    t = ms.set_inputs(nodes.new("ShaderNodeBsdfTranslucent"), Color=(0.9, 0.85, 0.7, 1.0))
    mix = _mix_shader(nodes, links, 0.45, d.outputs[0], t.outputs[0])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def layered_wall():
    """A Principled wall (matte paint) mixed toward a Glossy sheen at grazing angles (Layer
    Weight Facing), the Glossy's colour from a Fresnel."""
    mat, nodes, links, p = _principled("ArchWall", Base_Color=(0.75, 0.73, 0.7, 1.0), Roughness=0.7)
    lw = ms.set_inputs(nodes.new("ShaderNodeLayerWeight"), Blend=0.3)
    fres = ms.set_inputs(nodes.new("ShaderNodeFresnel"), IOR=1.45)
    gl = ms.set_inputs(nodes.new("ShaderNodeBsdfGlossy"), Roughness=0.25)
    links.new(fres.outputs[0], gl.inputs["Color"])
    mix = _mix_shader(nodes, links, lw.outputs["Facing"], p.outputs[0], gl.outputs[0])
    links.new(mix.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def blackbody_emission(name, kelvin, strength):
    mat, nodes, links, out = ms.new_material(name)
    bb = nodes.new("ShaderNodeBlackbody")
    bb.inputs["Temperature"].default_value = kelvin
    em = ms.set_inputs(nodes.new("ShaderNodeEmission"), Strength=strength)
    links.new(bb.outputs[0], em.inputs["Color"])
    links.new(em.outputs[0], out.inputs["Surface"])
    return mat


def archviz():
    """A 3 x 3 x 2.5 m room lit by a hazy sun and a Nishita sky (sun disc off) through a glass
    pane (Glass / Transparent for shadow rays) in a window, a wooden floor (image + Mapping +
    Bump), a translucent curtain beside the window, Layer Weight / Fresnel walls and a
    Blackbody-coloured emissive ceiling lamp. The room is open behind the camera (a loggia):
    closed, the sky through the glass alone left 8 % seed noise in 8x8 regions at 256 samples
    (4 % open), and a sharper, stronger sun more (the glass's refracted paths meet the sun at
    full weight besides the shadow rays' samples, as in Cycles: 8 % at 10 deg, energy 3)."""
    scene = _scene()
    wall = layered_wall()
    ms.add_plane("Floor", 3.0, wood_floor())
    ls.plane("Ceiling", 3.0, wall, location=(0, 0, 2.5), rotation_euler=(math.pi, 0, 0))
    ls.plane("WallW", 1.0, wall, location=(-1.5, 0, 1.25), rotation_euler=(math.pi / 2, 0, -math.pi / 2),
             scale=(3, 2.5, 1))
    ls.plane("WallE", 1.0, wall, location=(1.5, 0, 1.25), rotation_euler=(math.pi / 2, 0, math.pi / 2),
             scale=(3, 2.5, 1))
    w, z0, z1 = 0.6, 0.7, 2.0  # the window's half-width, sill and lintel
    side = 1.5 - w
    up = (math.pi / 2, 0.0, 0.0)
    for name, loc, sc in [("WinL", (-1.5 + side / 2, 1.5, 1.25), (side, 2.5, 1)),
                          ("WinR", (1.5 - side / 2, 1.5, 1.25), (side, 2.5, 1)),
                          ("WinB", (0, 1.5, z0 / 2), (2 * w, z0, 1)),
                          ("WinT", (0, 1.5, (z1 + 2.5) / 2), (2 * w, 2.5 - z1, 1))]:
        ls.plane(name, 1.0, wall, location=loc, rotation_euler=up, scale=sc)
    # The pane: 1 cm thick, 1 cm clear of the opening's edges, 3 cm outside the wall's plane.
    ls.box("Pane", 1.0, window_glass(), location=(0, 1.53, (z0 + z1) / 2),
           scale=(2 * w - 0.02, 0.01, z1 - z0 - 0.02))
    ls.plane("Curtain", 1.0, curtain(), location=(0.55, 1.3, 1.3), rotation_euler=up, scale=(0.5, 1.9, 1))
    sky = bpy.data.worlds.new("Sky")
    sky.use_nodes = True
    tex = sky.node_tree.nodes.new("ShaderNodeTexSky")
    tex.sky_type = 'NISHITA'
    tex.sun_elevation, tex.sun_rotation = math.radians(35), math.radians(160)
    tex.sun_disc = False  # the sun is the lamp below
    sky.node_tree.links.new(tex.outputs["Color"], sky.node_tree.nodes["Background"].inputs["Color"])
    sky.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.6
    scene.world = sky
    # Sun from outside the window (+y), 35 deg up, soft (20 deg): a patch of sun on the floor.
    ls.add_light('SUN', "Sun", rotation=(math.radians(-55), 0, math.radians(15)), energy=1.5,
                 angle=math.radians(20.0), color=(1.0, 0.95, 0.85))
    ms.add_sphere("Lamp", 0.1, blackbody_emission("LampMat", 2700.0, 12.0), segments=16, rings=8,
                  location=(-0.4, -0.2, 2.2))
    ms.add_camera((-0.6, -1.3, 1.3), (0.15, 1.5, 0.8), lens=20.0)
    return scene


# ---------------------------------------------------------------- foliage

def _rnd_value(tree, data_type, lo, hi, seed):
    """A Random Value node of `data_type`, range (lo, hi), `seed`: its enabled output."""
    rnd = tree.nodes.new("FunctionNodeRandomValue")
    rnd.data_type = data_type
    suffix = {"FLOAT_VECTOR": "", "FLOAT": "_001"}[data_type]
    by_id = {s.identifier: s for s in rnd.inputs}
    by_id["Min" + suffix].default_value = lo
    by_id["Max" + suffix].default_value = hi
    by_id["Seed"].default_value = seed
    return next(s for s in rnd.outputs if s.identifier == "Value" + suffix)


def leaf_material():
    """A leaf card: Voronoi cells (Math: Less Than) cut the card through a Mix with a
    Transparent BSDF; the front a Principled, the back Translucent (Geometry Backfacing); the
    green varied per instance by Object Info Random through a Color Ramp."""
    mat, nodes, links, out = ms.new_material("Leaf")
    coord = nodes.new("ShaderNodeTexCoord")
    vor = ms.set_inputs(nodes.new("ShaderNodeTexVoronoi"), Scale=3.0)
    cut = _math(nodes, links, 'LESS_THAN', vor.outputs["Distance"], 0.42)
    info = nodes.new("ShaderNodeObjectInfo")
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.08, 0.3, 0.04, 1.0)
    ramp.color_ramp.elements[1].color = (0.45, 0.55, 0.08, 1.0)
    front = _principled_node(nodes, Roughness=0.5)
    back = nodes.new("ShaderNodeBsdfTranslucent")
    geo = nodes.new("ShaderNodeNewGeometry")
    clear = nodes.new("ShaderNodeBsdfTransparent")
    links.new(coord.outputs["UV"], vor.inputs["Vector"])
    links.new(info.outputs["Random"], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], front.inputs["Base Color"])
    links.new(ramp.outputs["Color"], back.inputs["Color"])
    sides = _mix_shader(nodes, links, geo.outputs["Backfacing"], front.outputs[0], back.outputs[0])
    card = _mix_shader(nodes, links, cut.outputs[0], clear.outputs[0], sides.outputs[0])
    links.new(card.outputs[0], out.inputs["Surface"])
    return mat


def _principled_node(nodes, **inputs):
    return ms.set_inputs(nodes.new("ShaderNodeBsdfPrincipled"), **inputs)


def bark_material():
    """Principled bark with material displacement (Displacement and Bump) from a Noise."""
    mat, nodes, links, p = _principled("Bark", Base_Color=(0.25, 0.16, 0.1, 1.0), Roughness=0.8)
    coord = nodes.new("ShaderNodeTexCoord")
    noise = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=5.0, Detail=4.0)
    disp = ms.set_inputs(nodes.new("ShaderNodeDisplacement"), Midlevel=0.5, Scale=0.08)
    links.new(coord.outputs["Object"], noise.inputs["Vector"])
    links.new(noise.outputs["Fac"], disp.inputs["Height"])
    links.new(disp.outputs[0], nodes["Material Output"].inputs["Displacement"])
    mat.displacement_method = 'BOTH'
    return mat


def canopy_nodes(leaf, seed=7):
    """Instance on Points: `leaf` on points scattered over an ico sphere, random rotation and
    scale, not realized."""
    tree = bpy.data.node_groups.new("Canopy", 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    n, L = tree.nodes, tree.links.new
    ico = n.new("GeometryNodeMeshIcoSphere")
    ico.inputs["Radius"].default_value = 0.55
    ico.inputs["Subdivisions"].default_value = 2
    dist = n.new("GeometryNodeDistributePointsOnFaces")
    dist.distribute_method = 'RANDOM'
    dist.inputs["Density"].default_value = 35.0
    dist.inputs["Seed"].default_value = seed
    inst = n.new("GeometryNodeInstanceOnPoints")
    info = n.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = leaf
    out = n.new("NodeGroupOutput")
    L(ico.outputs["Mesh"], dist.inputs["Mesh"])
    L(dist.outputs["Points"], inst.inputs["Points"])
    L(info.outputs["Geometry"], inst.inputs["Instance"])
    L(_rnd_value(tree, 'FLOAT_VECTOR', (0.0, 0.0, 0.0), (2 * math.pi,) * 3, 1), inst.inputs["Rotation"])
    L(_rnd_value(tree, 'FLOAT', 0.7, 1.3, 2), inst.inputs["Scale"])
    L(inst.outputs["Instances"], out.inputs[0])
    return tree


def gradient_world(strength=1.5):
    """An HDR-ish gradient sky: the direction's z through Map Range and a Color Ramp (warm
    horizon, blue zenith, dark ground)."""
    world = bpy.data.worlds.new("Gradient")
    world.use_nodes = True
    nt = world.node_tree
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    rng = nt.nodes.new("ShaderNodeMapRange")
    rng.inputs["From Min"].default_value = -0.3
    rng.inputs["From Max"].default_value = 1.0
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    els = ramp.color_ramp.elements
    els[0].color = (0.05, 0.04, 0.03, 1.0)
    els[1].color = (0.2, 0.35, 0.8, 1.0)
    mid = els.new(0.25)
    mid.color = (1.0, 0.75, 0.45, 1.0)
    bg = nt.nodes["Background"]
    bg.inputs["Strength"].default_value = strength
    nt.links.new(coord.outputs["Generated"], sep.inputs[0])
    nt.links.new(sep.outputs["Z"], rng.inputs["Value"])
    nt.links.new(rng.outputs["Result"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bg.inputs["Color"])
    bpy.context.scene.world = world
    return world


def foliage():
    """A small tree: a displaced trunk (Displacement and Bump) through the ground and a canopy of
    alpha-cut, translucent-backed leaf cards instanced by geometry nodes, under a gradient sky
    and a low sun."""
    scene = _scene()
    gradient_world()
    ms.add_plane("Ground", 8.0, ms.diffuse("Grass", (0.2, 0.28, 0.1)))
    _grid_cylinder("Trunk", 0.09, 1.4, bark_material(), rings=20, segments=24, location=(0, 0, 0.6))
    leaf = ms.add_plane("LeafCard", 0.3, leaf_material(), scale=(1.0, 0.55, 1.0))
    leaf.hide_render = True
    host = ms.add_mesh_object("Canopy", lambda bm: None, location=(0.0, 0.0, 1.45))
    host.modifiers.new("Canopy", 'NODES').node_group = canopy_nodes(leaf)
    ls.add_light('SUN', "Sun", rotation=(math.radians(55), 0, math.radians(-40)), energy=3.0,
                 angle=math.radians(2.0), color=(1.0, 0.9, 0.75))
    ms.add_camera((0.4, -2.6, 1.0), (0.0, 0.0, 1.1), lens=35.0)
    return scene


# ---------------------------------------------------------------- night street

def facade_material():
    """Brick facades with windows: a Checker picks the lit windows, whose Emission colour is a
    Brick Texture (warm and cool panes, dark mullions); the rest a diffuse from another Brick."""
    mat, nodes, links, out = ms.new_material("Facade")
    coord = nodes.new("ShaderNodeTexCoord")
    wall = nodes.new("ShaderNodeTexBrick")
    ms.set_inputs(wall, Color1=(0.35, 0.14, 0.08, 1.0), Color2=(0.25, 0.1, 0.06, 1.0),
                  Mortar=(0.5, 0.5, 0.48, 1.0), Scale=8.0)
    panes = nodes.new("ShaderNodeTexBrick")
    ms.set_inputs(panes, Color1=(1.0, 0.65, 0.3, 1.0), Color2=(0.5, 0.65, 1.0, 1.0),
                  Mortar=(0.02, 0.02, 0.02, 1.0), Scale=1.5, Mortar_Size=0.05)
    checker = ms.set_inputs(nodes.new("ShaderNodeTexChecker"), Scale=2.5)
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    glow = ms.set_inputs(nodes.new("ShaderNodeEmission"), Strength=3.0)
    for tex in (wall, panes, checker):
        links.new(coord.outputs["Object"], tex.inputs["Vector"])
    links.new(wall.outputs["Color"], diffuse.inputs["Color"])
    links.new(panes.outputs["Color"], glow.inputs["Color"])
    mix = _mix_shader(nodes, links, checker.outputs["Fac"], diffuse.outputs[0], glow.outputs[0])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def wet_road():
    """Principled asphalt, wet: low roughness from a Noise through Map Range (puddles)."""
    mat, nodes, links, p = _principled("Road", Base_Color=(0.04, 0.04, 0.045, 1.0))
    coord = nodes.new("ShaderNodeTexCoord")
    noise = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=1.5, Detail=3.0)
    rng = nodes.new("ShaderNodeMapRange")
    ms.set_inputs(rng, From_Min=0.4, From_Max=0.6, To_Min=0.08, To_Max=0.3)
    links.new(coord.outputs["Object"], noise.inputs["Vector"])
    links.new(noise.outputs["Fac"], rng.inputs["Value"])
    links.new(rng.outputs["Result"], p.inputs["Roughness"])
    return mat


def night_street():
    """A street between two brick facades with lit windows, two street lamps (spot lights with
    Blackbody colours: a light's Temperature and a node tree's Blackbody, soft blends), a soft
    point light, a wet road, a Volume Scatter haze box and a motion-blurred car."""
    scene = _scene()
    ls.world_color((0.004, 0.005, 0.012))
    ls.plane("Road", 1.0, wet_road(), location=(0, 7, 0), scale=(4, 18, 1))
    facade = facade_material()
    ls.plane("FacadeW", 1.0, facade, location=(-2, 7, 3), rotation_euler=(math.pi / 2, 0, -math.pi / 2),
             scale=(18, 6, 1))
    ls.plane("FacadeE", 1.0, facade, location=(2, 7, 3), rotation_euler=(math.pi / 2, 0, math.pi / 2),
             scale=(18, 6, 1))
    warm = ls.add_light('SPOT', "LampA", location=(-1.2, 3.0, 4.0), energy=400.0, spot_size=math.radians(80),
                        spot_blend=0.4, shadow_soft_size=0.3)
    warm.data.use_temperature = True
    warm.data.temperature = 3000.0
    cool = ls.add_light('SPOT', "LampB", location=(1.2, 8.0, 4.0), energy=500.0, spot_size=math.radians(70),
                        spot_blend=0.8, shadow_soft_size=0.3)
    cool.data.use_nodes = True
    lt = cool.data.node_tree
    bb = lt.nodes.new("ShaderNodeBlackbody")
    bb.inputs["Temperature"].default_value = 4500.0
    lt.links.new(bb.outputs[0], lt.nodes["Emission"].inputs["Color"])
    ls.add_light('POINT', "Door", location=(1.7, 5.0, 2.2), energy=40.0, shadow_soft_size=0.3,
                 color=(0.4, 0.8, 1.0))
    haze, nodes, links, out = ms.new_material("Haze")
    sc = ms.set_inputs(nodes.new("ShaderNodeVolumeScatter"), Density=0.04, Anisotropy=0.3)
    links.new(sc.outputs[0], out.inputs["Volume"])
    ls.box("Haze", 1.0, haze, location=(0, 8.0, 2.4), scale=(4.6, 12.0, 5.2))  # from z -0.2: the road inside
    car = ms.add_mesh_object("Car", lambda bm: bmesh.ops.create_cube(bm, size=1.0),
                             (_principled("CarPaint", Base_Color=(0.6, 0.03, 0.02, 1.0), Roughness=0.2,
                                          Coat_Weight=1.0)[0],),
                             location=(0.7, 5.0, 0.45), scale=(1.6, 0.8, 0.5))
    prefs = bpy.context.preferences.edit
    old = prefs.keyframe_new_interpolation_type
    prefs.keyframe_new_interpolation_type = 'LINEAR'
    try:
        for frame, y in ((1, 5.0), (2, 5.8)):
            car.location.y = y
            car.keyframe_insert("location", frame=frame)
    finally:
        prefs.keyframe_new_interpolation_type = old
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    ms.add_camera((0.3, -1.5, 1.6), (0.0, 8.0, 1.3), lens=24.0)
    return scene


# ---------------------------------------------------------------- stylised

def _store_height_nodes():
    """Geometry nodes storing the position's z as a float point attribute "height"."""
    tree = bpy.data.node_groups.new("StoreHeight", 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    n, L = tree.nodes, tree.links.new
    inp, out = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    store = n.new("GeometryNodeStoreNamedAttribute")
    store.data_type = 'FLOAT'
    store.domain = 'POINT'
    store.inputs["Name"].default_value = "height"
    pos = n.new("GeometryNodeInputPosition")
    sep = n.new("ShaderNodeSeparateXYZ")
    L(pos.outputs[0], sep.inputs[0])
    L(sep.outputs["Z"], store.inputs["Value"])
    L(inp.outputs[0], store.inputs["Geometry"])
    L(store.outputs[0], out.inputs[0])
    return tree


def toon_material():
    """Toon Diffuse + Toon Glossy (Add Shader), the colour from a Color Attribute."""
    mat, nodes, links, out = ms.new_material("Toon")
    col = nodes.new("ShaderNodeVertexColor")
    col.layer_name = "Col"
    diff = ms.set_inputs(nodes.new("ShaderNodeBsdfToon"), Size=0.5, Smooth=0.1)
    gl = ms.set_inputs(nodes.new("ShaderNodeBsdfToon"), Size=0.2, Smooth=0.05,
                       Color=(0.6, 0.6, 0.6, 1.0))
    gl.component = 'GLOSSY'
    add = nodes.new("ShaderNodeAddShader")
    links.new(col.outputs["Color"], diff.inputs["Color"])
    links.new(diff.outputs[0], add.inputs[0])
    links.new(gl.outputs[0], add.inputs[1])
    links.new(add.outputs[0], out.inputs["Surface"])
    return mat


def stylised_ground():
    """A diffuse ground darkened by an Ambient Occlusion node's Color, fading far away to a
    haze emission by Ray Length (Map Range)."""
    mat, nodes, links, out = ms.new_material("StyleGround")
    ao = ms.set_inputs(nodes.new("ShaderNodeAmbientOcclusion"), Color=(0.7, 0.65, 0.55, 1.0), Distance=0.6)
    ao.samples = 8
    d = nodes.new("ShaderNodeBsdfDiffuse")
    haze = ms.set_inputs(nodes.new("ShaderNodeEmission"), Color=(0.55, 0.65, 0.85, 1.0), Strength=1.0)
    path = nodes.new("ShaderNodeLightPath")
    rng = ms.set_inputs(nodes.new("ShaderNodeMapRange"), From_Min=3.0, From_Max=9.0)
    links.new(ao.outputs["Color"], d.inputs["Color"])
    links.new(path.outputs["Ray Length"], rng.inputs["Value"])
    mix = _mix_shader(nodes, links, rng.outputs["Result"], d.outputs[0], haze.outputs[0])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def stylised():
    """A toon-shaded sphere coloured by a Color Attribute, a bevelled cube (Bevel node in the
    normal), a wireframe-lined icosphere (Wireframe node), a pillar coloured through a Color Ramp
    from a geometry-nodes attribute, a backdrop that camera rays see flat (Is Camera Ray), an AO
    and Ray Length ground and a Holdout ball."""
    scene = _scene()
    ls.world_color((0.25, 0.27, 0.3))
    ms.add_plane("Ground", 12.0, stylised_ground())
    # Backdrop: flat colour for the camera, a grey diffuse for everything else.
    mat, nodes, links, out = ms.new_material("Backdrop")
    flat = ms.set_inputs(nodes.new("ShaderNodeEmission"), Color=(0.85, 0.55, 0.6, 1.0), Strength=1.0)
    grey = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.5, 0.5, 0.5, 1.0))
    path = nodes.new("ShaderNodeLightPath")
    links.new(_mix_shader(nodes, links, path.outputs["Is Camera Ray"], grey.outputs[0], flat.outputs[0]).outputs[0],
              out.inputs["Surface"])
    ls.plane("Backdrop", 1.0, mat, location=(0, 3.0, 2.0), rotation_euler=(math.pi / 2, 0, 0), scale=(8, 4, 1))
    # Toon sphere with a per-corner colour attribute.
    toon = ms.add_sphere("ToonBall", 0.45, toon_material(), segments=32, rings=16, location=(-0.9, 0.3, 0.42))
    mesh = toon.data
    n = len(mesh.vertices)
    co = np.empty(n * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3) / 0.45
    col = np.ones((n, 4), np.float32)
    col[:, 0] = 0.5 + 0.45 * co[:, 0]
    col[:, 1] = 0.35 + 0.3 * co[:, 2]
    col[:, 2] = 0.6 - 0.35 * co[:, 0]
    mesh.color_attributes.new("Col", 'FLOAT_COLOR', 'POINT').data.foreach_set("color", col.ravel())
    # Bevelled cube (sunk 5 cm into the ground, turned).
    cmat, cn, cl, cp = _principled("Bevelled", Base_Color=(0.2, 0.45, 0.75, 1.0), Roughness=0.3)
    bev = ms.set_inputs(cn.new("ShaderNodeBevel"), Radius=0.08)
    bev.samples = 8
    cl.new(bev.outputs[0], cp.inputs["Normal"])
    ls.box("Cube", 0.6, cmat, location=(0.25, 0.1, 0.25), rotation_euler=(0, 0, math.radians(30)))
    # Wireframe icosphere, floating.
    wmat, wn, wl, wout = ms.new_material("Wire")
    wire = ms.set_inputs(wn.new("ShaderNodeWireframe"), Size=0.025)
    wire.use_pixel_size = False
    body = ms.set_inputs(wn.new("ShaderNodeBsdfDiffuse"), Color=(0.9, 0.85, 0.3, 1.0))
    line = ms.set_inputs(wn.new("ShaderNodeEmission"), Color=(0.1, 0.1, 0.1, 1.0), Strength=1.0)
    wl.new(_mix_shader(wn, wl, wire.outputs["Fac"], body.outputs[0], line.outputs[0]).outputs[0], wout.inputs["Surface"])
    def ico(bm):
        bmesh.ops.create_icosphere(bm, subdivisions=1, radius=0.3)
        canonical_order(bm)
    ms.add_mesh_object("Wire", ico, (wmat,), location=(1.2, 0.6, 0.6))
    # Pillar coloured by a geometry-nodes "height" through a Color Ramp.
    amat, an, al, ap = _principled("Pillar", Roughness=0.6)
    attr = an.new("ShaderNodeAttribute")
    attr.attribute_type = 'GEOMETRY'
    attr.attribute_name = "height"
    ramp = an.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].position = -0.7
    ramp.color_ramp.elements[0].color = (0.9, 0.2, 0.1, 1.0)
    ramp.color_ramp.elements[1].position = 0.7
    ramp.color_ramp.elements[1].color = (0.1, 0.8, 0.3, 1.0)
    al.new(attr.outputs["Fac"], ramp.inputs["Fac"])
    al.new(ramp.outputs["Color"], ap.inputs["Base Color"])
    pillar = _grid_cylinder("Pillar", 0.18, 1.4, amat, rings=6, segments=16, location=(-0.2, 1.3, 0.65))
    pillar.modifiers.new("StoreHeight", 'NODES').node_group = _store_height_nodes()
    ms.add_sphere("HoldoutBall", 0.2, ms.bsdf_material("Hold", "ShaderNodeHoldout")[0], segments=16, rings=8,
                  location=(0.9, -0.5, 0.3))
    ls.add_light('SUN', "Sun", rotation=(math.radians(40), 0, math.radians(30)), energy=2.5, angle=math.radians(3))
    ls.add_light('AREA', "Fill", location=(-2.0, -1.5, 2.0), rotation=(math.radians(50), 0, math.radians(-50)),
                 size=1.5, energy=100.0)
    ms.add_camera((0.2, -3.6, 1.6), (0.1, 0.6, 0.5), lens=38.0)
    return scene


def archviz_open_window():
    """The archviz shot without its glass pane (the control of the curtain's difference)."""
    scene = archviz()
    bpy.data.objects.remove(bpy.data.objects["Pane"])
    return scene


SCENES2 = {"archviz_open": archviz_open_window, "archviz": archviz, "foliage": foliage, "night_street": night_street, "stylised": stylised}
