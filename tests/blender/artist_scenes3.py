"""Audit 3 (docs/materials.md, "Compound scenes", "Audit 3"): more compound shots that mix
features the way artists do, built procedurally at 64 x 48 from the helpers of artist_scenes.py:
a jewellery close-up, a set of camera models over one stage, sci-fi volumes and a motion-graphics
shot made with geometry nodes. Each builder starts from an empty factory scene, so Pathlight and
Cycles render the very same data."""

import math

import bmesh
import bpy
import numpy as np

from blender_util import canonical_order
import artist_scenes as art
import light_scenes as ls
import material_scenes as ms

W, H = art.W, art.H
_principled = art._principled

# A type C LM-63 profile, brighter downward, each quarter of the circle its own falloff.
IES_PROFILE = "\n".join([
    "IESNA:LM-63-2002", "[TEST] audit3", "TILT=NONE", "1 1000 1.0 7 5 1 2 0.0 0.0 0.0", "1.0 1.0 100",
    "0 30 60 90 120 150 180", "0 90 180 270 360",
    "900 700 400 200 100 50 0", "900 800 700 500 300 100 0", "900 600 300 100 50 20 0",
    "900 850 900 900 600 300 0", "900 700 400 200 100 50 0"]) + "\n"


def _uv_sphere(name, radius, material, location, segments=32, rings=16):
    def build(bm):
        bm.loops.layers.uv.new("UVMap")
        bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius, calc_uvs=True)
        canonical_order(bm)
    return ms.add_mesh_object(name, build, (material,), smooth=True, location=location)


def _torus(name, major, minor, material, nu=32, nv=12, **transform):
    """A torus around Z from numpy (no operator): nu x nv quads, smooth."""
    u = np.arange(nu) * 2 * np.pi / nu
    v = np.arange(nv) * 2 * np.pi / nv
    uu, vv = np.meshgrid(u, v, indexing="ij")
    r = major + minor * np.cos(vv)
    co = np.stack([r * np.cos(uu), r * np.sin(uu), minor * np.sin(vv)], -1).reshape(-1, 3)
    faces = [(i * nv + j, ((i + 1) % nu) * nv + j, ((i + 1) % nu) * nv + (j + 1) % nv, i * nv + (j + 1) % nv)
             for i in range(nu) for j in range(nv)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(co.tolist(), [], faces)
    mesh.materials.append(material)
    mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    for key, value in transform.items():
        setattr(obj, key, value)
    bpy.context.scene.collection.objects.link(obj)
    return obj


# ---------------------------------------------------------------- jewellery close-up

def iridescent_gem():
    """A dark dielectric with a thin film (soap-bubble colours)."""
    return _principled("Film", Base_Color=(0.05, 0.05, 0.06, 1.0), Roughness=0.25,
                       Thin_Film_Thickness=450.0, Thin_Film_IOR=1.4)[0]


def brushed_ring(direction='UV_MAP'):
    """Brushed silver: anisotropic metal along a Tangent node (UV map or radial about Z)."""
    mat, nodes, links, p = _principled("Brushed" + direction, Base_Color=(0.9, 0.9, 0.92, 1.0),
                                       Metallic=1.0, Roughness=0.4, Anisotropic=0.8,
                                       Anisotropic_Rotation=0.1)
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = direction
    if direction == 'UV_MAP':
        tangent.uv_map = "UVMap"
    else:
        tangent.axis = 'Z'
    links.new(tangent.outputs["Tangent"], p.inputs["Tangent"])
    return mat


def coated_enamel():
    """Blue enamel under a tinted coat with its own normal map (the numpy bumps)."""
    mat, nodes, links, p = _principled("Enamel", Base_Color=(0.1, 0.25, 0.7, 1.0), Roughness=0.4,
                                       Coat_Weight=1.0, Coat_Roughness=0.08, Coat_IOR=1.6,
                                       Coat_Tint=(1.0, 0.75, 0.5, 1.0))
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = art.normal_map_image()
    nmap = ms.set_inputs(nodes.new("ShaderNodeNormalMap"), Strength=1.0)
    nmap.uv_map = "UVMap"
    uv = nodes.new("ShaderNodeUVMap")
    uv.uv_map = "UVMap"
    links.new(uv.outputs["UV"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], nmap.inputs["Color"])
    links.new(nmap.outputs["Normal"], p.inputs["Coat Normal"])
    return mat


def velvet():
    return _principled("Velvet", Base_Color=(0.35, 0.04, 0.08, 1.0), Roughness=0.9,
                       Sheen_Weight=1.0, Sheen_Roughness=0.3, Sheen_Tint=(1.0, 0.6, 0.7, 1.0))[0]


def gold_f82():
    """Metallic with a Specular Tint: Cycles' F82 tint of the edge colour."""
    return _principled("Gold", Base_Color=(1.0, 0.78, 0.34, 1.0), Metallic=1.0, Roughness=0.35,
                       Specular_Tint=(0.9, 0.5, 0.3, 1.0))[0]


def jewellery():
    """A close-up on a velvet cushion: an iridescent gem, two brushed rings (UV and radial
    tangents), a coated enamel bead, an F82 gold bead; an ellipse area light with spread, a
    disk area light, a spot light with an IES profile and a wave-textured point light."""
    scene = ls.empty_scene(W, H)
    ls.world_color((0.03, 0.03, 0.035))
    ls.plane("Cushion", 6.0, velvet(), location=(0, 0, -0.02))
    _uv_sphere("Gem", 0.22, iridescent_gem(), (-0.55, 0.1, 0.25), segments=8, rings=6)
    ring_uv = _torus("RingUV", 0.28, 0.07, brushed_ring('UV_MAP'), location=(0.05, 0.35, 0.3),
                     rotation_euler=(math.radians(70), 0, math.radians(15)))
    ring_uv.data.uv_layers.new(name="UVMap")
    _uv_layer_torus(ring_uv.data, 32, 12)
    _torus("RingRadial", 0.25, 0.06, brushed_ring('RADIAL'), location=(0.55, -0.15, 0.08))
    _uv_sphere("Bead", 0.16, coated_enamel(), (-0.1, -0.35, 0.18))
    _uv_sphere("GoldBead", 0.13, gold_f82(), (0.6, 0.35, 0.15))
    ls.add_light('AREA', "Softbox", location=(-1.2, -1.0, 1.6), rotation=(math.radians(40), 0, math.radians(-50)),
                 shape='ELLIPSE', size=1.0, size_y=0.5, energy=15.0, spread=math.radians(70))
    ls.add_light('AREA', "Rim", location=(1.0, 1.3, 1.0), rotation=(math.radians(-55), 0, math.radians(-140)),
                 shape='DISK', size=0.5, energy=8.0, color=(0.8, 0.9, 1.0))
    spot = ls.add_light('SPOT', "IesSpot", location=(0.3, -0.8, 1.8), rotation=(math.radians(25), 0, 0),
                        energy=10.0, shadow_soft_size=0.3, spot_size=math.radians(70), spot_blend=0.3)
    spot.data.use_nodes = True
    nt = spot.data.node_tree
    ies = nt.nodes.new("ShaderNodeTexIES")
    ies.mode = 'INTERNAL'
    block = bpy.data.texts.new("audit3.ies")
    block.from_string(IES_PROFILE)
    ies.ies = block
    nt.links.new(ies.outputs["Fac"], nt.nodes["Emission"].inputs["Strength"])
    gobo = ls.add_light('POINT', "Gobo", location=(-0.4, 0.9, 1.2), energy=6.0, shadow_soft_size=0.3,
                        color=(1.0, 0.85, 0.6))
    gobo.data.use_nodes = True
    nt = gobo.data.node_tree
    coord = nt.nodes.new("ShaderNodeTexCoord")
    wave = ms.set_inputs(nt.nodes.new("ShaderNodeTexWave"), Scale=4.0, Distortion=2.0)
    nt.links.new(coord.outputs["Normal"], wave.inputs["Vector"])
    nt.links.new(wave.outputs["Color"], nt.nodes["Emission"].inputs["Color"])
    ms.add_camera((0.0, -1.9, 1.1), (0.0, 0.05, 0.15), lens=45.0)
    return scene


def _uv_layer_torus(mesh, nu, nv):
    """UVs of _torus's quads: u along the ring, v around the tube (for the UV tangent)."""
    uv = np.empty((len(mesh.loops), 2), np.float32)
    loop_vert = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", loop_vert)
    i, j = loop_vert // nv, loop_vert % nv
    uv[:, 0], uv[:, 1] = i / nu, j / nv
    # A quad's wrapped corner gets 1.0, not 0.0 (a seam, as an artist's unwrap has).
    poly_start = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_start", poly_start)
    for corner in range(1, 4):
        idx = poly_start + corner
        first = poly_start
        uv[idx, 0] = np.where(uv[idx, 0] < uv[first, 0], uv[idx, 0] + 1.0, uv[idx, 0])
        uv[idx, 1] = np.where(uv[idx, 1] < uv[first, 1], uv[idx, 1] + 1.0, uv[idx, 1])
    mesh.uv_layers["UVMap"].data.foreach_set("uv", uv.ravel())


# ---------------------------------------------------------------- cameras

def camera_stage():
    """One stage for every camera model: a checker floor, coloured spheres around the camera
    (in front, at the sides and behind: the panoramas see them), a sky-blue to warm gradient
    world and a sun."""
    scene = ls.empty_scene(W, H)
    world = bpy.data.worlds.new("Gradient")
    world.use_nodes = True
    nt = world.node_tree
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    ramp = nt.nodes.new("ShaderNodeMapRange")
    ramp.data_type = 'FLOAT_VECTOR'
    by_id = {s.identifier: s for s in ramp.inputs}
    by_id["From_Min_FLOAT3"].default_value = (-1.0, -1.0, -1.0)
    by_id["To_Min_FLOAT3"].default_value = (0.9, 0.6, 0.35)
    by_id["To_Max_FLOAT3"].default_value = (0.2, 0.4, 1.0)
    nt.links.new(coord.outputs["Generated"], sep.inputs[0])
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    nt.links.new(sep.outputs["Z"], comb.inputs[0])
    nt.links.new(sep.outputs["Z"], comb.inputs[1])
    nt.links.new(sep.outputs["Z"], comb.inputs[2])
    nt.links.new(comb.outputs[0], by_id["Vector"])
    nt.links.new({s.identifier: s for s in ramp.outputs}["Vector"], nt.nodes["Background"].inputs["Color"])
    scene.world = world
    floor, nodes, links, out = ms.new_material("Checker")
    chk = ms.set_inputs(nodes.new("ShaderNodeTexChecker"), Scale=8.0, Color1=(0.8, 0.8, 0.8, 1.0),
                        Color2=(0.1, 0.1, 0.12, 1.0))
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(chk.outputs["Color"], d.inputs["Color"])
    links.new(d.outputs[0], out.inputs["Surface"])
    ms.add_plane("Floor", 12.0, floor, location=(0, 0, -0.01))
    colours = [(0.8, 0.2, 0.1), (0.1, 0.7, 0.2), (0.15, 0.3, 0.9), (0.9, 0.8, 0.1), (0.7, 0.2, 0.8), (0.9, 0.9, 0.9)]
    for k, c in enumerate(colours):
        a = 2 * math.pi * k / len(colours) + 0.3
        r = 1.6 + 0.5 * (k % 2)
        ms.add_sphere(f"Ball{k}", 0.4, ms.diffuse(f"Ball{k}", c), segments=24, rings=12,
                      location=(r * math.cos(a), r * math.sin(a), 0.45))
    ms.add_sphere("Mirror", 0.3, ms.glossy("Mirror", (0.9, 0.9, 0.9), roughness=0.3), segments=24,
                  rings=12, location=(0.0, 0.6, 0.35))
    ls.add_light('SUN', "Sun", rotation=(math.radians(40), 0, math.radians(30)), energy=3.0, angle=math.radians(5))
    return scene


def _stage_camera(location=(0.0, -0.9, 0.8), target=(0.0, 0.6, 0.35), lens=30.0):
    return ms.add_camera(location, target, lens=lens)


def cam_fisheye_equisolid():
    scene = camera_stage()
    cam = _stage_camera()
    cam.data.type = 'PANO'
    cam.data.panorama_type = 'FISHEYE_EQUISOLID'
    cam.data.fisheye_lens = 8.0
    cam.data.fisheye_fov = math.radians(180)
    cam.data.sensor_width = 36.0
    return scene


def cam_fisheye_equidistant():
    scene = camera_stage()
    cam = _stage_camera()
    cam.data.type = 'PANO'
    cam.data.panorama_type = 'FISHEYE_EQUIDISTANT'
    cam.data.fisheye_fov = math.radians(200)
    return scene


def cam_equirectangular():
    scene = camera_stage()
    cam = ms.add_camera((0.0, 0.0, 0.7), (0.0, 1.0, 0.6))
    cam.data.type = 'PANO'
    cam.data.panorama_type = 'EQUIRECTANGULAR'
    cam.data.latitude_min, cam.data.latitude_max = math.radians(-60), math.radians(80)
    cam.data.longitude_min, cam.data.longitude_max = math.radians(-150), math.radians(170)
    return scene


def cam_ortho_shift():
    scene = camera_stage()
    cam = _stage_camera((1.5, -4.0, 3.0), (0.0, 0.3, 0.3))
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = 4.0
    cam.data.shift_x, cam.data.shift_y = 0.15, -0.1
    return scene


def cam_dof_blades_motion():
    """Perspective with lens shift, depth of field through a rotated, stretched hexagonal
    aperture, and the camera moving (motion blur)."""
    scene = camera_stage()
    cam = _stage_camera(lens=35.0)
    cam.data.shift_x = -0.1
    dof = cam.data.dof
    dof.use_dof = True
    dof.focus_distance = 1.5
    dof.aperture_fstop = 0.8
    dof.aperture_blades = 6
    dof.aperture_rotation = math.radians(20)
    dof.aperture_ratio = 1.8
    prefs = bpy.context.preferences.edit
    old = prefs.keyframe_new_interpolation_type
    prefs.keyframe_new_interpolation_type = 'LINEAR'
    try:
        for frame, x in ((1, 0.0), (2, 0.25)):
            cam.location.x = x
            cam.keyframe_insert("location", frame=frame)
    finally:
        prefs.keyframe_new_interpolation_type = old
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    return scene


CAMERAS = {"fisheye_equisolid": cam_fisheye_equisolid, "fisheye_equidistant": cam_fisheye_equidistant,
           "equirectangular": cam_equirectangular, "ortho_shift": cam_ortho_shift,
           "dof_blades_motion": cam_dof_blades_motion}


# ---------------------------------------------------------------- sci-fi volumes

def fire_material():
    """Principled Volume: density, blackbody temperature and emission from a Noise texture."""
    mat, nodes, links, out = ms.new_material("Plasma")
    pv = ms.set_inputs(nodes.new("ShaderNodeVolumePrincipled"), Color=(0.6, 0.6, 0.7, 1.0),
                       Density=3.0, Blackbody_Intensity=0.6, Emission_Color=(0.2, 0.8, 1.0, 1.0))
    noise = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=3.0, Detail=2.0)
    temp = nodes.new("ShaderNodeMapRange")
    temp.inputs["To Min"].default_value = 800.0
    temp.inputs["To Max"].default_value = 2400.0
    glow = nodes.new("ShaderNodeMath")
    glow.operation = 'MULTIPLY'
    glow.inputs[1].default_value = 3.0
    links.new(noise.outputs["Fac"], temp.inputs["Value"])
    links.new(noise.outputs["Fac"], glow.inputs[0])
    links.new(temp.outputs["Result"], pv.inputs["Temperature"])
    links.new(glow.outputs[0], pv.inputs["Emission Strength"])
    links.new(noise.outputs["Color"], pv.inputs["Color"])
    links.new(pv.outputs[0], out.inputs["Volume"])
    return mat


def sci_fi_volumes():
    """A glowing plasma torus and sphere (Principled Volume, blackbody and emission driven by a
    Noise texture), a forward-scattering beam (Volume Scatter, anisotropy 0.7) lit by a spot,
    a tinted Volume Absorption sphere, all inside a thin Volume Scatter world."""
    scene = ls.empty_scene(W, H)
    world = ls.world_color((0.02, 0.025, 0.04))
    fog = ms.set_inputs(world.node_tree.nodes.new("ShaderNodeVolumeScatter"), Density=0.04,
                        Anisotropy=0.3)
    world.node_tree.links.new(fog.outputs[0], world.node_tree.nodes["World Output"].inputs["Volume"])
    ms.add_plane("Deck", 10.0, ms.diffuse("Deck", (0.3, 0.3, 0.32)), location=(0, 0, -0.05))
    plasma = fire_material()
    _torus("Ring", 0.55, 0.16, plasma, location=(-0.5, 0.6, 0.5), rotation_euler=(math.radians(60), 0, 0))
    ms.add_sphere("Core", 0.3, plasma, segments=24, rings=12, location=(0.7, 0.9, 0.4))
    beam, nodes, links, out = ms.new_material("Beam")
    sc = ms.set_inputs(nodes.new("ShaderNodeVolumeScatter"), Color=(0.9, 0.9, 0.9, 1.0), Density=1.5,
                       Anisotropy=0.7)
    links.new(sc.outputs[0], out.inputs["Volume"])
    ls.box("Beam", 1.0, beam, location=(0.3, 0.1, 0.8), scale=(0.35, 1.2, 0.35))
    tint, nodes, links, out = ms.new_material("Tint")
    ab = ms.set_inputs(nodes.new("ShaderNodeVolumeAbsorption"), Color=(0.9, 0.3, 0.2, 1.0), Density=4.0)
    links.new(ab.outputs[0], out.inputs["Volume"])
    ms.add_sphere("Tint", 0.3, tint, segments=24, rings=12, location=(-0.6, -0.3, 0.45))
    ls.add_light('SPOT', "Spot", location=(0.3, -1.8, 0.8), rotation=(math.radians(90), 0, 0),
                 energy=200.0, shadow_soft_size=0.05, spot_size=math.radians(25), spot_blend=0.2,
                 color=(1.0, 0.9, 0.7))
    ls.add_light('AREA', "Fill", location=(-1.0, -1.5, 2.5), rotation=(math.radians(35), 0, math.radians(-30)),
                 shape='SQUARE', size=1.0, energy=60.0)
    ms.add_camera((0.2, -2.8, 1.3), (0.0, 0.4, 0.5), lens=32.0)
    return scene


# ---------------------------------------------------------------- motion graphics

def _mograph_tree():
    """Geometry nodes: a spiral swept by a circle (Curve to Mesh) with a Store Named Attribute
    "glow" (the curve's factor), and ico spheres instanced on a circle's points, half realised."""
    tree = bpy.data.node_groups.new("Mograph", 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    n, L = tree.nodes, tree.links.new
    spiral = ms.set_inputs(n.new("GeometryNodeCurveSpiral"), Resolution=24, Rotations=3.0,
                           Start_Radius=0.6, End_Radius=0.25, Height=1.0)
    profile = n.new("GeometryNodeCurvePrimitiveCircle")
    profile.inputs["Resolution"].default_value = 8
    profile.inputs["Radius"].default_value = 0.05
    factor = n.new("GeometryNodeSplineParameter")
    store = n.new("GeometryNodeStoreNamedAttribute")
    store.data_type = 'FLOAT'
    store.domain = 'POINT'
    store.inputs["Name"].default_value = "glow"
    L(spiral.outputs[0], store.inputs["Geometry"])
    L(factor.outputs["Factor"], store.inputs["Value"])
    sweep = n.new("GeometryNodeCurveToMesh")
    sweep.inputs["Fill Caps"].default_value = True
    L(store.outputs[0], sweep.inputs["Curve"])
    L(profile.outputs["Curve"], sweep.inputs["Profile Curve"])
    smooth = n.new("GeometryNodeSetShadeSmooth")
    L(sweep.outputs[0], smooth.inputs["Geometry"])
    ring = n.new("GeometryNodeCurvePrimitiveCircle")
    ring.inputs["Resolution"].default_value = 10
    ring.inputs["Radius"].default_value = 1.0
    ico = n.new("GeometryNodeMeshIcoSphere")
    ico.inputs["Radius"].default_value = 0.12
    ico.inputs["Subdivisions"].default_value = 1
    inst = n.new("GeometryNodeInstanceOnPoints")
    L(ring.outputs["Curve"], inst.inputs["Points"])
    L(ico.outputs["Mesh"], inst.inputs["Instance"])
    idx = n.new("GeometryNodeInputIndex")
    half = n.new("FunctionNodeCompare")
    half.data_type = 'INT'
    half.operation = 'LESS_THAN'
    half.inputs[3].default_value = 5  # B (INT)
    L(idx.outputs[0], half.inputs[2])  # A (INT)
    realize = n.new("GeometryNodeRealizeInstances")
    L(inst.outputs[0], realize.inputs["Geometry"])
    L(half.outputs[0], realize.inputs["Selection"])
    join = n.new("GeometryNodeJoinGeometry")
    L(smooth.outputs[0], join.inputs[0])
    L(realize.outputs[0], join.inputs[0])
    out = n.new("NodeGroupOutput")
    L(join.outputs[0], out.inputs[0])
    return tree


def _glow_material():
    """Emission + diffuse mixed by the stored "glow" attribute through a Map Range."""
    mat, nodes, links, out = ms.new_material("Glow")
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "glow"
    mr = nodes.new("ShaderNodeMapRange")
    mr.interpolation_type = 'SMOOTHSTEP'
    mr.inputs["From Min"].default_value = 0.2
    mr.inputs["From Max"].default_value = 0.9
    em = ms.set_inputs(nodes.new("ShaderNodeEmission"), Color=(1.0, 0.3, 0.6, 1.0), Strength=4.0)
    d = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.2, 0.6, 0.8, 1.0))
    mix = nodes.new("ShaderNodeMixShader")
    links.new(attr.outputs["Fac"], mr.inputs["Value"])
    links.new(mr.outputs["Result"], mix.inputs["Fac"])
    links.new(d.outputs[0], mix.inputs[1])
    links.new(em.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def _island_material():
    """Random Per Island and Pointiness into a Principled base colour, White Noise roughness."""
    mat, nodes, links, p = _principled("Islands", Roughness=0.4)
    geo = nodes.new("ShaderNodeNewGeometry")
    hsv = nodes.new("ShaderNodeCombineHSV")
    hsv.inputs["S"].default_value = 0.7
    hsv.inputs["V"].default_value = 0.8
    links.new(geo.outputs["Random Per Island"], hsv.inputs["H"])
    links.new(hsv.outputs[0], p.inputs["Base Color"])
    white = nodes.new("ShaderNodeTexWhiteNoise")
    white.noise_dimensions = '3D'
    coord = nodes.new("ShaderNodeTexCoord")
    vm = nodes.new("ShaderNodeVectorMath")
    vm.operation = 'SNAP'
    vm.inputs[1].default_value = (0.25, 0.25, 0.25)
    links.new(coord.outputs["Object"], vm.inputs[0])
    links.new(vm.outputs[0], white.inputs["Vector"])
    rough = nodes.new("ShaderNodeMapRange")
    rough.inputs["To Min"].default_value = 0.2
    rough.inputs["To Max"].default_value = 0.7
    links.new(white.outputs["Value"], rough.inputs["Value"])
    links.new(rough.outputs["Result"], p.inputs["Roughness"])
    return mat


def _pointy_material():
    """Pointiness through a Map Range into a diffuse colour mix (cavities darker)."""
    mat, nodes, links, out = ms.new_material("Pointy")
    geo = nodes.new("ShaderNodeNewGeometry")
    mr = nodes.new("ShaderNodeMapRange")
    mr.inputs["From Min"].default_value = 0.45
    mr.inputs["From Max"].default_value = 0.55
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = 'RGBA'
    mix.inputs["A"].default_value = (0.1, 0.1, 0.15, 1.0)
    mix.inputs["B"].default_value = (0.9, 0.8, 0.3, 1.0)
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(geo.outputs["Pointiness"], mr.inputs["Value"])
    links.new(mr.outputs["Result"], mix.inputs["Factor"])
    links.new(mix.outputs["Result"], d.inputs["Color"])
    links.new(d.outputs[0], out.inputs["Surface"])
    return mat


def _texture_floor():
    """Wave bands distorted by a Magic texture, mixed with a Gradient."""
    mat, nodes, links, out = ms.new_material("MoFloor")
    coord = nodes.new("ShaderNodeTexCoord")
    magic = ms.set_inputs(nodes.new("ShaderNodeTexMagic"), Scale=2.0, Distortion=1.5)
    magic.turbulence_depth = 3
    vm = nodes.new("ShaderNodeVectorMath")
    vm.operation = 'MULTIPLY_ADD'
    vm.inputs[1].default_value = (0.3, 0.3, 0.3)
    wave = ms.set_inputs(nodes.new("ShaderNodeTexWave"), Scale=3.0, Distortion=1.0, Detail=2.0)
    wave.wave_profile = 'SAW'
    grad = nodes.new("ShaderNodeTexGradient")
    grad.gradient_type = 'SPHERICAL'
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = 'RGBA'
    mix.blend_type = 'MULTIPLY'
    mix.inputs["Factor"].default_value = 0.8
    d = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(coord.outputs["Object"], magic.inputs["Vector"])
    links.new(magic.outputs["Color"], vm.inputs[0])
    links.new(coord.outputs["Object"], vm.inputs[2])
    links.new(vm.outputs[0], wave.inputs["Vector"])
    links.new(coord.outputs["Object"], grad.inputs["Vector"])
    links.new(wave.outputs["Color"], mix.inputs["A"])
    links.new(grad.outputs["Color"], mix.inputs["B"])
    links.new(mix.outputs["Result"], d.inputs["Color"])
    links.new(d.outputs[0], out.inputs["Surface"])
    return mat


def _gradient_world():
    world = bpy.data.worlds.new("MoWorld")
    world.use_nodes = True
    nt = world.node_tree
    coord = nt.nodes.new("ShaderNodeTexCoord")
    grad = nt.nodes.new("ShaderNodeTexGradient")
    grad.gradient_type = 'QUADRATIC'
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.05, 0.02, 0.1, 1.0)
    ramp.color_ramp.elements[1].color = (0.4, 0.5, 0.9, 1.0)
    nt.links.new(coord.outputs["Generated"], grad.inputs["Vector"])
    nt.links.new(grad.outputs["Fac"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], nt.nodes["Background"].inputs["Color"])
    bpy.context.scene.world = world
    return world


def motion_graphics():
    """A geometry-nodes spiral and a ring of instanced (half realised) ico spheres with a stored
    attribute driving emission, a Text object, a cube of loose islands (Random Per Island), a
    low-poly sphere shaded by Pointiness, a Wave/Magic/Gradient floor and a Gradient world."""
    scene = ls.empty_scene(W, H)
    _gradient_world()
    ms.add_plane("Floor", 8.0, _texture_floor(), location=(0, 0, -0.02))
    host = ms.add_plane("Host", 0.1, None, location=(0.0, 0.8, 0.15))
    host.modifiers.new("Mograph", 'NODES').node_group = _mograph_tree()
    host.data.materials.append(_glow_material())
    text_data = bpy.data.curves.new("Title", 'FONT')
    text_data.body = "PL"
    text_data.extrude = 0.06
    text_data.size = 0.6
    text_data.materials.append(_principled("TextMat", Base_Color=(0.9, 0.9, 0.9, 1.0), Metallic=1.0,
                                           Roughness=0.25)[0])
    text = bpy.data.objects.new("Title", text_data)
    text.location = (-1.2, -0.3, 0.3)
    text.rotation_euler = (math.radians(80), 0, math.radians(10))
    bpy.context.scene.collection.objects.link(text)

    def islands(bm):
        for k in range(8):
            m = bmesh.ops.create_cube(bm, size=0.18)
            off = ((k % 2) * 0.22, ((k // 2) % 2) * 0.22, (k // 4) * 0.22)
            bmesh.ops.translate(bm, verts=m["verts"], vec=off)
        canonical_order(bm)
    ms.add_mesh_object("Islands", islands, (_island_material(),), location=(0.7, -0.4, 0.12),
                       rotation_euler=(0, 0, math.radians(30)))

    def lumpy(bm):
        bmesh.ops.create_icosphere(bm, subdivisions=2, radius=0.28)
        canonical_order(bm)
        for v in bm.verts:
            v.co *= 1.0 + 0.25 * math.sin(7.0 * v.co.x) * math.cos(5.0 * v.co.y)
    ms.add_mesh_object("Lumpy", lumpy, (_pointy_material(),), smooth=True, location=(-0.35, -0.5, 0.32))
    ls.add_light('AREA', "Key", location=(-1.5, -1.8, 2.5), rotation=(math.radians(40), 0, math.radians(-40)),
                 shape='RECTANGLE', size=1.2, size_y=0.6, energy=120.0)
    ms.add_camera((0.3, -3.0, 1.6), (0.0, 0.2, 0.35), lens=32.0)
    return scene


SCENES = {"jewellery": jewellery, "sci_fi_volumes": sci_fi_volumes, "motion_graphics": motion_graphics}
