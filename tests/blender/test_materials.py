"""Materials against Cycles in the same bpy (issue 3): each shader node setup rendered by both
engines from the same Blender scene, compared by per-region means (8x8 grid) and the whole
image. Small (64x64) renders; Cycles uses a 1-pixel box filter like Pathlight and both trace
up to 64 bounces (glass needs more than Pathlight's default 12).

Tolerances come from the noise measured at these sample counts: region errors between two
converged engines stay under ~2.5 % here (seeds are fixed, so the renders are deterministic);
limits are 5 % per region and 1.5 % for the whole image unless a test says otherwise."""

import functools
import math

import bpy
from mathutils import Matrix
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()
# This file's bar: 64 bounces; glass and caustics leave more noise in 8x8 regions.
render_pair = functools.partial(ms.render_pair, bounces=64)
assert_agree = functools.partial(ms.assert_agree, region=0.05, whole=0.015)

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

CAMERA = ((0.0, -3.6, 1.5), (0.0, 0.0, 0.55))  # a close look at one 0.55 m sphere
WIDE = ((0.0, -5.0, 2.2), (0.0, 0.0, 0.5))  # three spheres side by side


def sphere_scene(material_fn, radius=0.55, camera=CAMERA, **studio):
    def build():
        scene = ms.studio(camera=camera, **studio)
        ms.add_sphere("Ball", radius, material_fn(), location=(0.0, 0.0, radius))
        return scene
    return build


def glass(name, roughness=0.0, ior=1.5, absorption=None):
    mat, node = ms.bsdf_material(name, "ShaderNodeBsdfGlass", Roughness=roughness, IOR=ior)
    node.distribution = 'GGX'
    if absorption is not None:
        color, density = absorption
        va = mat.node_tree.nodes.new("ShaderNodeVolumeAbsorption")
        va.inputs["Color"].default_value = (*color, 1.0)
        va.inputs["Density"].default_value = density
        mat.node_tree.links.new(va.outputs[0],
                                mat.node_tree.nodes["Material Output"].inputs["Volume"])
    return mat


def principled(name, **inputs):
    mat, node = ms.bsdf_material(name, "ShaderNodeBsdfPrincipled", **inputs)
    node.distribution = 'GGX'  # single-scatter (Blender's default Multiscatter GGX: test_principled_cycles)
    return mat


# ---------------------------------------------------------------- conductors

def test_mirror_sphere():
    ours, cycles = render_pair(sphere_scene(lambda: ms.glossy("Mirror", roughness=0.0)), 256)
    assert_agree(ours, cycles)


def test_rough_conductor():
    # Cycles' node set to single-scatter GGX, as the core's (Blender's default is multiscatter).
    ours, cycles = render_pair(
        sphere_scene(lambda: ms.glossy("Rough", (0.9, 0.6, 0.3), roughness=0.4)), 256)
    assert_agree(ours, cycles)


@pytest.mark.parametrize("fac", [0.2, 0.5, 1.0])
def test_mix_of_diffuse_and_glossy(fac):
    build = sphere_scene(lambda: ms.mix_diffuse_glossy(f"Mix {fac}", fac, roughness=0.1))
    ours, cycles = render_pair(build, 256)
    assert_agree(ours, cycles)


# ---------------------------------------------------------------- dielectrics

def test_glass_sphere_with_caustics():
    ours, cycles = render_pair(sphere_scene(lambda: glass("Glass")), 512)
    assert_agree(ours, cycles)
    # The caustic: the floor under the ball, lit through it, is brighter than the floor around.
    for img in (ours, cycles):
        under = img[44:52, 26:38, :3].mean()
        beside = img[44:52, 4:14, :3].mean()
        assert under > 1.5 * beside, (under, beside)


def test_rough_glass():
    ours, cycles = render_pair(sphere_scene(lambda: glass("Rough Glass", roughness=0.3)), 512)
    assert_agree(ours, cycles)


def test_beers_law_glass():
    absorption = ((0.9, 0.4, 0.2), 1.0)
    # Cycles at 4x (stored: no test time): against its 256 the worst region was 3.9 % in the
    # median over 208 seeds and over 5 % on 23 % of them, Cycles' own noise (the seeds' mean
    # image was still 3.8 % off); the suite's seed had passed by chance (docs/design/sampling.md
    # "Blue-noise pattern").
    ours, cycles = render_pair(sphere_scene(lambda: glass("Beer", absorption=absorption)), 256,
                               cycles_samples=1024)
    assert_agree(ours, cycles)
    # Absorption is visible: the ball's blue is well below its red (clear glass is grey).
    ball = ms.region_means(ours)[2:6, 3:5].reshape(-1, 3).mean(0)
    assert ball[2] < 0.7 * ball[0], ball


def test_schlick_fresnel_option():
    """scene.pathlight.use_schlick_fresnel (the seed's approximation) reaches the core: the
    glass reflections change a little, the image as a whole hardly (no Cycles counterpart)."""
    build = sphere_scene(lambda: glass("Glass"))
    renders = []
    for schlick in (False, True):
        scene = build()
        scene.pathlight.use_schlick_fresnel = schlick
        renders.append(render_to_array(scene, "PATHLIGHT", samples=64, max_bounces=64))
    ratio, worst, _ = ms.compare(renders[1], renders[0])
    assert abs(ratio - 1) < 0.01 and 0.01 < worst < 0.15, (ratio, worst)


def test_refraction_bsdf():
    def refraction():
        mat, node = ms.bsdf_material("Refraction", "ShaderNodeBsdfRefraction", Roughness=0.0,
                                     IOR=1.45)
        node.distribution = 'GGX'
        return mat
    ours, cycles = render_pair(sphere_scene(refraction), 256)
    assert_agree(ours, cycles)


# ---------------------------------------------------------------- Principled

@pytest.mark.parametrize("metallic", [0.0, 1.0])
def test_principled_opaque(metallic):
    build = sphere_scene(lambda: principled(f"Principled {metallic}", Base_Color=(0.8, 0.5, 0.2, 1),
                                            Metallic=metallic, Roughness=0.3))
    ours, cycles = render_pair(build, 256)
    assert_agree(ours, cycles)


def test_principled_transmission():
    build = sphere_scene(lambda: principled("Principled glass", Base_Color=(0.8, 0.5, 0.2, 1),
                                            Roughness=0.3, Transmission_Weight=1.0))
    # 1024 samples: at 256 the caustic under the ball left one region's difference at 2-6 % over
    # Pathlight's seeds (Cycles' noise and ours; 0.6-1.6 % at 1024, same tolerance).
    ours, cycles = render_pair(build, 1024)
    assert_agree(ours, cycles)


def test_principled_transmission_untinted():
    # With a white Base Color, Principled transmission is plain (rough) glass in both.
    build = sphere_scene(lambda: principled("Principled clear", Base_Color=(1, 1, 1, 1),
                                            Roughness=0.2, Transmission_Weight=1.0))
    ours, cycles = render_pair(build, 256)
    assert_agree(ours, cycles)


def test_principled_emission():
    build = sphere_scene(lambda: principled("Glow", Base_Color=(0.2, 0.6, 0.3, 1),
                                            Emission_Color=(1.0, 0.5, 0.1, 1),
                                            Emission_Strength=0.8, Roughness=0.5))
    ours, cycles = render_pair(build, 256)
    assert_agree(ours, cycles)


def ghost():
    return principled("Ghost", Base_Color=(0.2, 0.6, 0.3, 1), Alpha=0.4, Roughness=0.5)


def veil():
    """Mix of 0.4 Diffuse and 0.6 Transparent."""
    mat, nodes, links, out = ms.new_material("Veil")
    mix = nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.6
    d = nodes.new("ShaderNodeBsdfDiffuse")
    t = nodes.new("ShaderNodeBsdfTransparent")
    links.new(d.outputs[0], mix.inputs[1])
    links.new(t.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def test_mix_with_transparent_without_nee():
    # Without NEE (noisier: looser regions) the engines agree too.
    ours, cycles = render_pair(sphere_scene(veil), 256, pathlight=dict(use_nee=False))
    assert_agree(ours, cycles, region=0.08, whole=0.015)


def test_mix_with_transparent():
    ours, cycles = render_pair(sphere_scene(veil), 256)
    assert_agree(ours, cycles)


def test_principled_back_face():
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 32
        ms.set_world((0.5, 0.5, 0.5))
        mat = principled("Back", Base_Color=(0.2, 0.6, 0.3, 1), Roughness=0.5)
        ms.add_plane("Plane", 2.0, mat, rotation_euler=(math.pi, 0.0, 0.0))  # facing away
        ms.add_camera((0.0, -1.0, 2.0), (0.0, 0.0, 0.0))
        return scene
    ours, cycles = render_pair(build, 128, bounces=8)
    assert_agree(ours, cycles, region=0.03, whole=0.015)


def test_principled_alpha():
    ours, cycles = render_pair(sphere_scene(ghost), 256)
    assert_agree(ours, cycles)


def test_transparent_bsdf():
    build = sphere_scene(lambda: ms.bsdf_material("Veil", "ShaderNodeBsdfTransparent",
                                                  Color=(0.5, 0.5, 0.5, 1))[0])
    ours, cycles = render_pair(build, 256)
    assert_agree(ours, cycles)


# ---------------------------------------------------------------- textures

def texture_scene(image_fn, interpolation, mapping=None):
    """A 1 m plane with a 4x4 texture seen from above under a white world: each pixel is the
    (interpolated) texel colour, with almost no noise."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 64
        ms.set_world((1.0, 1.0, 1.0))
        mat = ms.textured_material("Texture", image_fn(), interpolation, mapping=mapping)
        ms.add_plane("Plane", 1.0, mat)
        ms.add_camera((0.1, 0.05, 1.6), (0.1, 0.05, 0.0))
        return scene
    return build


def test_textured_plane_closest_vs_linear():
    """Closest and Linear give different pixel statistics and each matches Cycles. The
    texture is Non-Color (no colour-space decoding: see the sRGB test below)."""
    image = lambda: ms.checker_image("Checker", 4, colorspace="Non-Color")  # noqa: E731
    closest = render_pair(texture_scene(image, 'Closest'), 16)
    linear = render_pair(texture_scene(image, 'Linear'), 16)
    for ours, cycles in (closest, linear):
        assert_agree(ours, cycles, region=0.01, whole=0.005)
        assert np.abs(ours - cycles)[..., :3].mean() < 0.005
    # Closest: the texel colours only (edges aside); Linear: a ramp of values in between.
    c, l = closest[0][8:56, 8:56, 0].ravel(), linear[0][8:56, 8:56, 0].ravel()
    near = lambda v, x: np.abs(v - x) < 0.02  # noqa: E731
    assert (near(c, 0.9) | near(c, 0.1)).mean() > 0.75  # texel edges are box-filtered
    assert (near(l, 0.9) | near(l, 0.1)).mean() < 0.3
    assert c.std() > l.std() * 1.2


def test_textured_plane_srgb_closest_and_mapping():
    image = lambda: ms.checker_image("Checker", 4)  # noqa: E731  (byte, sRGB)
    ours, cycles = render_pair(texture_scene(image, 'Closest'), 64)
    assert_agree(ours, cycles, region=0.02, whole=0.005)
    mapped = texture_scene(image, 'Closest', mapping={"type": 'POINT', "Scale": (2.0, 3.0, 1.0),
                                                       "Rotation": (0.0, 0.0, 0.3),
                                                       "Location": (0.1, 0.0, 0.0)})
    ours, cycles = render_pair(mapped, 64)
    assert_agree(ours, cycles, region=0.03, whole=0.005)


def test_textured_plane_float_linear():
    px = np.zeros((4, 4, 4), np.float32)
    px[..., 3] = 1.0
    px[..., 0] = np.linspace(0.0, 2.0, 16).reshape(4, 4)  # HDR values too
    px[..., 1] = 0.3
    px[..., 2] = np.eye(4)
    image = lambda: ms.pixel_image("Float", px, "Linear Rec.709", float_buffer=True)  # noqa: E731
    ours, cycles = render_pair(texture_scene(image, 'Linear'), 16)
    assert_agree(ours, cycles, region=0.01, whole=0.005)


def test_textured_plane_srgb_linear():
    # Cycles interpolates 8-bit sRGB textures in sRGB and decodes afterwards (compress_as_srgb);
    # so does the core (interpolating linear values was up to 0.19 brighter here).
    image = lambda: ms.checker_image("Checker", 4)  # noqa: E731
    ours, cycles = render_pair(texture_scene(image, 'Linear'), 16)
    assert_agree(ours, cycles, region=0.02, whole=0.005)


# ---------------------------------------------------------------- normal maps

def normal_map_scene(tilts, strength=1.0, sun=True, bsdf="ShaderNodeBsdfDiffuse", **inputs):
    """A diffuse (or `bsdf`) plane seen from above whose tangent-space normal map has vertical
    stripes tilted by `tilts` (degrees about the tangent's bitangent axis, + towards +u), lit
    by a sun from the +x side (and a dim world), or by a white world only."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 64
        ms.set_world((0.1, 0.1, 0.1) if sun else (1.0, 1.0, 1.0))
        n = len(tilts)
        px = np.ones((2, n, 4), np.float32)
        for x, tilt in enumerate(tilts):
            t = math.radians(tilt)
            px[:, x, :3] = np.array([math.sin(t), 0.0, math.cos(t)]) * 0.5 + 0.5
        mat, nodes, links, out = ms.new_material("Bumpy")
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = ms.pixel_image("Normals", px, "Non-Color", float_buffer=True)
        tex.interpolation = 'Closest'
        nm = nodes.new("ShaderNodeNormalMap")
        nm.inputs["Strength"].default_value = strength
        d = nodes.new(bsdf)
        d.inputs["Color" if "Color" in d.inputs else "Base Color"].default_value = (0.8, 0.8, 0.8, 1.0)
        ms.set_inputs(d, **inputs)
        if hasattr(d, "distribution"):
            d.distribution = 'GGX'  # the core's single-scatter GGX
        links.new(tex.outputs["Color"], nm.inputs["Color"])
        links.new(nm.outputs["Normal"], d.inputs["Normal"])
        links.new(d.outputs[0], out.inputs["Surface"])
        # Rotated, so that the tangent frame is not the world's.
        ms.add_plane("Plane", 1.0, mat, rotation_euler=(0.0, 0.0, 0.3))
        if sun:
            ms.add_sun(3.0, 50.0)
        ms.add_camera((0.0, 0.0, 1.6), (0.0, 0.0, 0.0))
        return scene
    return build


def test_normal_mapped_plane():
    ours, cycles = render_pair(normal_map_scene([20.0, -20.0, 0.0, 10.0]), 128)
    assert_agree(ours, cycles, region=0.025, whole=0.01)
    # The stripes facing the sun are brighter than those facing away, by the expected cosines.
    plane = ours[12:52, 12:52, 0]
    assert plane.max() > 1.3 * np.percentile(plane, 10)


def test_normal_map_strength():
    ours, cycles = render_pair(normal_map_scene([35.0, -35.0, 0.0, 15.0], strength=0.5), 128)
    assert_agree(ours, cycles, region=0.025, whole=0.01)


@pytest.mark.parametrize("tilt", [35.0, 60.0])
def test_strongly_tilted_normal_map_in_a_white_world(tilt):
    # Cycles' bump shadowing term for diffuse lobes with bent normals (was 0.910 vs Cycles'
    # 0.839 at 35 degrees, 0.750 vs 0.566 at 60, before the core had it).
    ours, cycles = render_pair(normal_map_scene([tilt, tilt], sun=False), 64)
    assert_agree(ours, cycles, region=0.025, whole=0.01)


@pytest.mark.parametrize("sun", [False, True])
def test_strongly_tilted_normal_map_on_a_glossy_plane(sun):
    # Cycles lifts glossy normals whose mirror reflection of the view would go below the
    # surface (ensure_valid_specular_reflection).
    build = normal_map_scene([60.0, -35.0], sun=sun, bsdf="ShaderNodeBsdfGlossy", Roughness=0.3)
    ours, cycles = render_pair(build, 128)
    assert_agree(ours, cycles, region=0.03, whole=0.01)


# ---------------------------------------------------------------- value nodes (issue 3)

def fresnel_mix(name, layer_weight=False):
    """Diffuse under a glossy coat mixed by Fresnel (IOR 1.45), or by Layer Weight's Fresnel."""
    mat, nodes, links, out = ms.new_material(name)
    mix = nodes.new("ShaderNodeMixShader")
    d = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.8, 0.25, 0.1, 1.0))
    g = ms.set_inputs(nodes.new("ShaderNodeBsdfGlossy"), Roughness=0.2)
    g.distribution = 'GGX'
    if layer_weight:
        f = ms.set_inputs(nodes.new("ShaderNodeLayerWeight"), Blend=0.3)
        links.new(f.outputs["Fresnel"], mix.inputs["Fac"])
    else:
        f = ms.set_inputs(nodes.new("ShaderNodeFresnel"), IOR=1.45)
        links.new(f.outputs["Fac"], mix.inputs["Fac"])
    links.new(d.outputs[0], mix.inputs[1])
    links.new(g.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


@pytest.mark.parametrize("layer_weight", [False, True])
def test_fresnel_mixed_coat(layer_weight):
    ours, cycles = render_pair(sphere_scene(lambda: fresnel_mix("Coat", layer_weight)), 256)
    assert_agree(ours, cycles)
    # The rim (grazing view) is more glossy than the centre: brighter relative to the diffuse
    # red than the ball's middle, where the coat is faint.
    rim, mid = ours[14:18, 29:35, :3].mean(0).mean(0), ours[30:36, 28:36, :3].mean(0).mean(0)
    assert rim[2] / rim[0] > mid[2] / mid[0]


def emission_plane_scene(color_fn):
    """A 1 m plane seen from above, emitting colour_fn(nodes, links) (a colour socket) with
    its UV coordinates available; noise-free (the camera sees the emission only)."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 32
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("Emitter")
        e = nodes.new("ShaderNodeEmission")
        links.new(color_fn(nodes, links), e.inputs["Color"])
        links.new(e.outputs[0], out.inputs["Surface"])
        ms.add_plane("Plane", 1.0, mat)
        ms.add_camera((0.0, 0.0, 1.6), (0.0, 0.0, 0.0))
        return scene
    return build


def uv_x_socket(nodes, links):
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(nodes.new("ShaderNodeTexCoord").outputs["UV"], sep.inputs["Vector"])
    return sep.outputs["X"]


@pytest.mark.parametrize("interpolation", ['EASE', 'CONSTANT'])
def test_color_ramp_over_uv(interpolation):
    def colors(nodes, links):
        ramp = nodes.new("ShaderNodeValToRGB")
        r = ramp.color_ramp
        r.interpolation = interpolation
        r.elements[0].color = (0.9, 0.1, 0.05, 1.0)
        r.elements[1].position = 0.8
        r.elements[1].color = (0.05, 0.2, 0.9, 1.0)
        mid = r.elements.new(0.4)
        mid.color = (0.2, 0.9, 0.1, 1.0)
        links.new(uv_x_socket(nodes, links), ramp.inputs["Fac"])
        return ramp.outputs["Color"]
    ours, cycles = render_pair(emission_plane_scene(colors), 32, bounces=1)
    assert_agree(ours, cycles, region=0.02, whole=0.005)
    assert np.abs(ours - cycles)[8:24, 8:24, :3].mean() < 0.01
    # The ramp shows: red on the left, blue on the right.
    assert ours[16, 5, 0] > ours[16, 5, 2] and ours[16, 27, 2] > ours[16, 27, 0]  # u ~ 0.1, 0.9


def test_hue_saturation_value_and_separate_combine():
    def colors(nodes, links):
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = ms.checker_image("Checker", 4)
        tex.interpolation = 'Closest'
        hsv = ms.set_inputs(nodes.new("ShaderNodeHueSaturation"), Hue=0.3, Saturation=1.5,
                            Value=0.8, Fac=0.9)
        links.new(tex.outputs["Color"], hsv.inputs["Color"])
        sep = nodes.new("ShaderNodeSeparateColor")
        sep.mode = 'HSV'
        comb = nodes.new("ShaderNodeCombineColor")
        comb.mode = 'HSV'
        links.new(hsv.outputs["Color"], sep.inputs["Color"])
        links.new(sep.outputs[0], comb.inputs[0])
        links.new(sep.outputs[2], comb.inputs[1])  # value as saturation: a visible change
        links.new(sep.outputs[2], comb.inputs[2])
        gamma = ms.set_inputs(nodes.new("ShaderNodeGamma"), Gamma=1.4)
        links.new(comb.outputs["Color"], gamma.inputs["Color"])
        return gamma.outputs["Color"]
    ours, cycles = render_pair(emission_plane_scene(colors), 32, bounces=1)
    assert_agree(ours, cycles, region=0.02, whole=0.005)
    assert np.abs(ours - cycles)[8:24, 8:24, :3].mean() < 0.01


def bump_scene(distance, invert=False):
    """A diffuse plane whose height is a smooth 8x8 float texture (Linear), through a Bump
    node, lit by a low sun: the slopes facing the sun are brighter."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 64
        ms.set_world((0.05, 0.05, 0.05))
        y, x = np.mgrid[0:8, 0:8] / 7.0
        px = np.ones((8, 8, 4), np.float32)
        px[..., :3] = (0.5 + 0.5 * np.sin(2 * np.pi * x) * np.cos(np.pi * y))[..., None]
        mat, nodes, links, out = ms.new_material("Bumped")
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = ms.pixel_image("Height", px, "Non-Color", float_buffer=True)
        bump = ms.set_inputs(nodes.new("ShaderNodeBump"), Distance=distance)
        bump.invert = invert
        d = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.8, 0.8, 0.8, 1.0))
        links.new(tex.outputs["Color"], bump.inputs["Height"])
        links.new(bump.outputs["Normal"], d.inputs["Normal"])
        links.new(d.outputs[0], out.inputs["Surface"])
        ms.add_plane("Plane", 1.0, mat, rotation_euler=(0.0, 0.0, 0.3))
        ms.add_sun(3.0, 55.0)
        ms.add_camera((0.0, 0.0, 1.6), (0.0, 0.0, 0.0))
        return scene
    return build


def test_bump_from_a_texture():
    ours, cycles = render_pair(bump_scene(0.05), 64)
    assert_agree(ours, cycles, region=0.03, whole=0.01)
    flat, _ = render_pair(bump_scene(0.0), 16)
    # The bump shows: the plane's shading varies far more than without it.
    assert ours[12:52, 12:52, 0].std() > 3 * flat[12:52, 12:52, 0].std() + 0.02


# ---------------------------------------------------------------- texture coordinates

def texture_coordinate_scene(output, other=False):
    """Two instances (differently moved, rotated and scaled) of one off-centre sphere mesh,
    emitting their Texture Coordinate `output` (Object and Normal through Absolute, as
    emission shows positive values only): a noise-free picture of the coordinates. other:
    the node's Object is another object (an empty, moved, turned and scaled unevenly)."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 32
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("Coords")
        coord = nodes.new("ShaderNodeTexCoord")
        if other:
            empty = bpy.data.objects.new("Reference", None)
            empty.location, empty.rotation_euler, empty.scale = (0.3, -0.4, 0.2), (0.5, -0.3, 1.2), (0.6, 1.3, 0.9)
            scene.collection.objects.link(empty)
            coord.object = empty
        e = nodes.new("ShaderNodeEmission")
        sock = coord.outputs[output]
        if output != "Generated":
            absolute = nodes.new("ShaderNodeVectorMath")
            absolute.operation = 'ABSOLUTE'
            links.new(sock, absolute.inputs[0])
            sock = absolute.outputs["Vector"]
        links.new(sock, e.inputs["Color"])
        links.new(e.outputs[0], out.inputs["Surface"])
        a = ms.add_sphere("A", 0.5, mat, segments=24, rings=12, location=(-0.7, 0.0, 0.5),
                          rotation_euler=(0.3, 0.2, 0.9), scale=(1.0, 0.8, 1.2))
        a.data.transform(Matrix.Translation((0.25, -0.1, 0.0)))  # off-centre texture space
        b = bpy.data.objects.new("B", a.data)  # a second instance of the same mesh
        b.location, b.rotation_euler, b.scale = (0.7, 0.2, 0.4), (-0.5, 0.1, 2.0), (0.7, 0.7, 0.7)
        scene.collection.objects.link(b)
        ms.add_camera((0.0, -3.0, 1.2), (0.0, 0.0, 0.45))
        return scene
    return build


@pytest.mark.parametrize("output", ["Generated", "Object", "Normal", "Object of another"])
def test_object_generated_and_normal_coordinates(output):
    other = output == "Object of another"
    ours, cycles = render_pair(texture_coordinate_scene("Object" if other else output, other), 128, bounces=1)
    # Silhouette regions carry the anti-aliasing noise (up to ~3 %); inside, regions agree
    # within 1 %, and world positions in place of object space would be far off.
    assert_agree(ours, cycles, region=0.05, whole=0.01)
    assert np.abs(ours - cycles)[..., :3].mean() < 0.005


def test_light_path_shadow_ray_card():
    """A card that is red diffuse to every ray but shadow rays, for which it is transparent
    (Mix Shader by Is Shadow Ray): the floor under it is lit as if it were not there."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 32
        ms.set_world((0.05, 0.05, 0.05))
        mat, nodes, links, out = ms.new_material("Card")
        mix = nodes.new("ShaderNodeMixShader")
        lp = nodes.new("ShaderNodeLightPath")
        d = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.8, 0.1, 0.1, 1.0))
        links.new(lp.outputs["Is Shadow Ray"], mix.inputs["Fac"])
        links.new(d.outputs[0], mix.inputs[1])
        links.new(nodes.new("ShaderNodeBsdfTransparent").outputs[0], mix.inputs[2])
        links.new(mix.outputs[0], out.inputs["Surface"])
        ms.add_plane("Floor", 6.0, ms.diffuse("Floor", (0.5, 0.5, 0.5)))
        ms.add_plane("Card", 0.8, mat, location=(0.6, 0.0, 0.5))
        ms.add_sun(3.0)  # straight down: the card's shadow is below it
        ms.add_camera((0.0, -3.0, 2.5), (0.2, 0.0, 0.2))
        return scene
    ours, cycles = render_pair(build, 64, bounces=8)
    # With the card casting its shadow (Is Shadow Ray read as 0) the image is 5 % darker.
    assert_agree(ours, cycles, region=0.05, whole=0.015)
