"""World node trees beyond "HDRI -> Background" (export.world.world_program, the core's program
world) against Cycles 4.5 in the same bpy: the camera-ray trick (Light Path Is Camera Ray / Is
Glossy Ray mixing two Backgrounds), an HDRI colour-corrected before the Background, two sources
added and a Strength from a texture, procedural backdrops, Mirror Ball projection and an
Environment Texture in a material. Tolerances as test_principled_cycles: the whole-image mean
within 1 %, every 8x8 region within 3 % (dark regions absolutely against 0.02)."""

import functools
import math

import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_has, load_addon
import material_scenes as ms
from material_scenes import assert_agree

load_addon()
from addon.export.world import export_world  # noqa: E402

render_pair = functools.partial(ms.render_pair, bounces=6)
pytestmark = pytest.mark.skipif(not core_has("Scene", "set_world_program"),
                                reason="the core has no set_world_program")


def hdri(name="HDRI", w=64, h=32):
    """A small float equirectangular sky: a blue gradient, a warm bright patch (the sun) and a
    dark ground, row 0 = bottom."""
    y, x = np.mgrid[0:h, 0:w]
    el = np.pi * ((y + 0.5) / h - 0.5)
    az = 2 * np.pi * ((x + 0.5) / w)
    px = np.zeros((h, w, 4), np.float32)
    sky = np.clip(np.sin(el), 0, 1)[..., None] * np.array([0.3, 0.5, 1.0]) + 0.2
    ground = np.array([0.15, 0.12, 0.1])
    px[..., :3] = np.where((el > 0)[..., None], sky, ground)
    sun = np.exp(-((el - 0.6) ** 2 + (np.angle(np.exp(1j * (az - 2.2))) * np.cos(el)) ** 2) / 0.04)
    px[..., :3] += sun[..., None] * np.array([12.0, 9.0, 6.0])
    px[..., 3] = 1.0
    return ms.pixel_image(name, px, colorspace="Linear Rec.709", float_buffer=True)


def objects(roughness=0.15, spheres=True):
    """A grey floor, a diffuse and a glossy sphere (roughness: 0 a mirror, whose rays are only
    BSDF samples), seen from the side with the sky behind: lit by the world alone."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = 32
    scene.render.resolution_percentage = 100
    ms.add_plane("Floor", 8.0, ms.diffuse("Floor", (0.5, 0.5, 0.5)))
    if spheres:
        ms.add_sphere("Diffuse", 0.6, ms.diffuse("Orange", (0.8, 0.45, 0.2)), location=(-0.7, 0.0, 0.6))
        ms.add_sphere("Glossy", 0.6, ms.glossy("Chrome", roughness=roughness), location=(0.7, 0.0, 0.6))
    ms.add_camera((0.0, -5.0, 1.6), (0.0, 0.0, 0.9), lens=35.0)
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    scene.world = world
    nt = world.node_tree
    nt.nodes.remove(nt.nodes["Background"])
    return scene, nt, nt.nodes["World Output"]


def background(nt, color=None, strength=1.0):
    bg = nt.nodes.new("ShaderNodeBackground")
    if color is not None:
        bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    return bg


def env_texture(nt, image, projection='EQUIRECTANGULAR'):
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = image
    env.projection = projection
    return env


def camera_ray_world(output="Is Camera Ray"):
    """Is Glossy Ray with a mirror: its reflections are BSDF rays alone, so what they see does
    not hinge on the engines' MIS weights (a rough glossy would mix the light samples' HDRI and
    its rays' other colour by them)."""
    def build():
        scene, nt, out = objects(0.15 if output == "Is Camera Ray" else 0.0)
        lit = background(nt)
        nt.links.new(env_texture(nt, hdri()).outputs["Color"], lit.inputs["Color"])
        seen = background(nt, (0.9, 0.3, 0.6), 1.0)
        path = nt.nodes.new("ShaderNodeLightPath")
        mix = nt.nodes.new("ShaderNodeMixShader")
        nt.links.new(path.outputs[output], mix.inputs["Fac"])
        nt.links.new(lit.outputs[0], mix.inputs[1])
        nt.links.new(seen.outputs[0], mix.inputs[2])
        nt.links.new(mix.outputs[0], out.inputs["Surface"])
        return scene
    return build


def corrected_world():
    def build():
        scene, nt, out = objects()
        env = env_texture(nt, hdri())
        hsv = nt.nodes.new("ShaderNodeHueSaturation")
        ms.set_inputs(hsv, Hue=0.55, Saturation=1.4, Value=1.1)
        gamma = ms.set_inputs(nt.nodes.new("ShaderNodeGamma"), Gamma=1.3)
        bc = ms.set_inputs(nt.nodes.new("ShaderNodeBrightContrast"), Bright=0.05, Contrast=0.2)
        curves = nt.nodes.new("ShaderNodeRGBCurve")
        curves.mapping.curves[3].points[1].location = (1.0, 0.8)  # the combined curve, lowered
        curves.mapping.update()
        strength = nt.nodes.new("ShaderNodeMath")
        strength.operation = 'MULTIPLY'
        strength.inputs[0].default_value = 0.75
        strength.inputs[1].default_value = 2.0
        bg = background(nt)
        nt.links.new(env.outputs["Color"], hsv.inputs["Color"])
        nt.links.new(hsv.outputs[0], gamma.inputs["Color"])
        nt.links.new(gamma.outputs[0], bc.inputs["Color"])
        nt.links.new(bc.outputs[0], curves.inputs["Color"])
        nt.links.new(curves.outputs[0], bg.inputs["Color"])
        nt.links.new(strength.outputs[0], bg.inputs["Strength"])
        nt.links.new(bg.outputs[0], out.inputs["Surface"])
        return scene
    return build


def mixed_sources_world():
    def build():
        scene, nt, out = objects()
        a = background(nt, strength=0.6)
        nt.links.new(env_texture(nt, hdri()).outputs["Color"], a.inputs["Color"])
        sky = nt.nodes.new("ShaderNodeTexSky")
        sky.sky_type = 'NISHITA'
        sky.sun_disc = False
        sky.sun_elevation = math.radians(25.0)
        b = background(nt, strength=0.3)
        nt.links.new(sky.outputs["Color"], b.inputs["Color"])
        # A Background whose Strength is a texture: noise over the directions.
        c = background(nt, (0.2, 0.6, 0.3))
        noise = ms.set_inputs(nt.nodes.new("ShaderNodeTexNoise"), Scale=2.0)
        nt.links.new(noise.outputs["Fac"], c.inputs["Strength"])
        add1, add2 = nt.nodes.new("ShaderNodeAddShader"), nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(a.outputs[0], add1.inputs[0])
        nt.links.new(b.outputs[0], add1.inputs[1])
        nt.links.new(add1.outputs[0], add2.inputs[0])
        nt.links.new(c.outputs[0], add2.inputs[1])
        nt.links.new(add2.outputs[0], out.inputs["Surface"])
        return scene
    return build


def procedural_world(kind):
    def build():
        scene, nt, out = objects()
        coords = nt.nodes.new("ShaderNodeTexCoord")
        bg = background(nt, strength=1.5)
        ramp = nt.nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = (0.9, 0.5, 0.2, 1.0)
        ramp.color_ramp.elements[1].color = (0.1, 0.3, 0.9, 1.0)
        ramp.color_ramp.elements.new(0.55).color = (1.0, 0.95, 0.8, 1.0)
        if kind == "gradient":  # Generated's z through a Separate XYZ: the horizon band
            sep = nt.nodes.new("ShaderNodeSeparateXYZ")
            nt.links.new(coords.outputs["Generated"], sep.inputs[0])
            map_range = nt.nodes.new("ShaderNodeMapRange")
            map_range.inputs["From Min"].default_value = -0.3
            nt.links.new(sep.outputs["Z"], map_range.inputs["Value"])
            nt.links.new(map_range.outputs[0], ramp.inputs["Fac"])
        elif kind == "spherical":  # Gradient Texture (spherical) on Object coordinates
            grad = nt.nodes.new("ShaderNodeTexGradient")
            grad.gradient_type = 'QUADRATIC_SPHERE'
            mapping = nt.nodes.new("ShaderNodeMapping")
            mapping.inputs["Location"].default_value = (0.4, 0.0, -0.3)
            nt.links.new(coords.outputs["Object"], mapping.inputs["Vector"])
            nt.links.new(mapping.outputs[0], grad.inputs["Vector"])
            nt.links.new(grad.outputs["Fac"], ramp.inputs["Fac"])
        elif kind == "window":  # Window coordinates (screen space): a backdrop graded across the frame
            sep = nt.nodes.new("ShaderNodeSeparateXYZ")
            nt.links.new(coords.outputs["Window"], sep.inputs[0])
            nt.links.new(sep.outputs["X"], ramp.inputs["Fac"])
        elif kind == "camera":  # Camera coordinates' y: graded with the view's height
            sep = nt.nodes.new("ShaderNodeSeparateXYZ")
            nt.links.new(coords.outputs["Camera"], sep.inputs[0])
            map_range = nt.nodes.new("ShaderNodeMapRange")
            map_range.inputs["From Min"].default_value = -0.8
            map_range.inputs["From Max"].default_value = 0.8
            nt.links.new(sep.outputs["Y"], map_range.inputs["Value"])
            nt.links.new(map_range.outputs[0], ramp.inputs["Fac"])
        else:  # Noise on the direction
            noise = ms.set_inputs(nt.nodes.new("ShaderNodeTexNoise"), Scale=3.0, Detail=4.0)
            nt.links.new(coords.outputs["Generated"], noise.inputs["Vector"])
            nt.links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
        nt.links.new(ramp.outputs["Color"], bg.inputs["Color"])
        nt.links.new(bg.outputs[0], out.inputs["Surface"])
        return scene
    return build


def mirror_ball_world():
    def build():
        scene, nt, out = objects()
        bg = background(nt)
        nt.links.new(env_texture(nt, hdri(w=48, h=48), 'MIRROR_BALL').outputs["Color"], bg.inputs["Color"])
        nt.links.new(bg.outputs[0], out.inputs["Surface"])
        return scene
    return build


def material_env_texture():
    """A constant world, and an emissive sphere showing an HDRI by its Environment Texture along
    the default vector (the position: a direction from the sphere's centre at the origin)."""
    def build():
        scene, nt, out = objects(spheres=False)
        bg = background(nt, (0.3, 0.3, 0.35))
        nt.links.new(bg.outputs[0], out.inputs["Surface"])
        mat, nodes, links, mout = ms.new_material("EnvSphere")
        env = nodes.new("ShaderNodeTexEnvironment")
        env.image = hdri("HDRI material")
        coords = nodes.new("ShaderNodeTexCoord")
        links.new(coords.outputs["Object"], env.inputs["Vector"])
        em = nodes.new("ShaderNodeEmission")
        links.new(env.outputs["Color"], em.inputs["Color"])
        links.new(em.outputs[0], mout.inputs["Surface"])
        ms.add_sphere("EnvSphere", 0.7, mat, location=(0.0, 0.0, 0.9))
        # (and one by the default vector, the position: directions from the world's origin)
        mat2, nodes, links, mout = ms.new_material("EnvDefault")
        env = nodes.new("ShaderNodeTexEnvironment")
        env.image = bpy.data.images["HDRI material"]
        em = nodes.new("ShaderNodeEmission")
        links.new(env.outputs["Color"], em.inputs["Color"])
        links.new(em.outputs[0], mout.inputs["Surface"])
        ms.add_plane("EnvPlane", 1.0, mat2, location=(1.4, 0.5, 0.9), rotation_euler=(math.pi / 2, 0.0, 0.0))
        return scene
    return build


def exported_program(build):
    scene = build()
    warnings = Warnings()
    color, texture, program = export_world(scene.world, warnings)
    return program, warnings


@pytest.mark.parametrize("output", ["Is Camera Ray", "Is Glossy Ray"])
def test_light_path_mix_of_two_backgrounds(output):
    program, warnings = exported_program(camera_ray_world(output))
    assert program is not None and not warnings, warnings
    ours, cycles = render_pair(camera_ray_world(output), 512)
    assert_agree(ours, cycles, f"world {output}")


def test_colour_corrected_hdri():
    program, warnings = exported_program(corrected_world())
    assert program is not None and not warnings, warnings
    ours, cycles = render_pair(corrected_world(), 512)
    assert_agree(ours, cycles, "colour-corrected HDRI")


def test_hdri_sky_and_textured_strength_added():
    program, warnings = exported_program(mixed_sources_world())
    assert program is not None and not warnings, warnings
    ours, cycles = render_pair(mixed_sources_world(), 512)
    assert_agree(ours, cycles, "HDRI + sky + textured strength")


@pytest.mark.parametrize("kind", ["gradient", "spherical", "noise", "window", "camera"])
def test_procedural_backdrop(kind):
    program, warnings = exported_program(procedural_world(kind))
    assert program is not None and not warnings, warnings
    ours, cycles = render_pair(procedural_world(kind), 512)
    assert_agree(ours, cycles, f"procedural world ({kind})")


def test_mirror_ball_projection():
    program, warnings = exported_program(mirror_ball_world())
    assert program is not None and not warnings, warnings
    ours, cycles = render_pair(mirror_ball_world(), 512)
    assert_agree(ours, cycles, "mirror ball")


def test_environment_texture_in_a_material():
    ours, cycles = render_pair(material_env_texture(), 256)
    assert_agree(ours, cycles, "Environment Texture in a material")


def test_fast_path_unchanged_and_unsupported_nodes_warned():
    # Today's graph (HDRI -> Background) stays an image world, no program.
    def hdri_only():
        scene, nt, out = objects()
        bg = background(nt, strength=1.3)
        nt.links.new(env_texture(nt, hdri()).outputs["Color"], bg.inputs["Color"])
        nt.links.new(bg.outputs[0], out.inputs["Surface"])
        return scene
    scene = hdri_only()
    color, texture, program = export_world(scene.world, Warnings())
    assert program is None and texture is not None
    # A BSDF in a world: named in the warning, black (as Cycles), the rest still rendered.
    scene, nt, out = objects()
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(background(nt, (0.5, 0.5, 0.5)).outputs[0], add.inputs[0])
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.name = "Stray Diffuse"
    nt.links.new(diffuse.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], out.inputs["Surface"])
    warnings = Warnings()
    color, texture, program = export_world(scene.world, warnings)
    assert program is not None
    assert any("Stray Diffuse" in w and "not a world shader" in w for w in warnings), warnings


def test_world_program_sent_again_to_a_kept_scene():
    """The viewport's world edits (scene_writer.replace_lights on a committed scene): a program
    world replaces the constant one, its HDRI added once however often it is sent."""
    from addon import scene_writer
    from addon.core import get_core
    from addon.export import export_scene
    pc = get_core()
    _, nt, out = objects()
    nt.links.new(background(nt, (0.2, 0.2, 0.2)).outputs[0], out.inputs["Surface"])
    data = export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None)
    assert data.world_program is None
    core_scene = scene_writer.to_core(pc, data, lambda m: None)
    core_scene.commit()
    up = np.array([[0.0, 0.0, 1.0]], np.float32)
    np.testing.assert_allclose(core_scene.world_radiance(up, camera_ray=True), [[0.2, 0.2, 0.2]], rtol=1e-6)
    camera_ray_world()()  # (a new file: its world, sent to the kept scene)
    data = export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None)
    assert data.world_program is not None
    images = core_scene.image_count()
    for _ in range(2):
        scene_writer.replace_lights(core_scene, [], data, lambda m: None)
        core_scene.commit()
    assert core_scene.image_count() == images + 1
    seen = core_scene.world_radiance(up, camera_ray=True)[0]
    np.testing.assert_allclose(seen, (0.9, 0.3, 0.6), rtol=1e-6)  # the camera's colour
    lit = core_scene.world_radiance(up, camera_ray=False)[0]
    assert lit[2] > lit[0] > 0.0  # the HDRI's blue sky overhead


# ---------------------------------------------------------------- the leftovers (worldfix)

def _mix_by(nt, out, fac_socket, when_0, when_1):
    """Background of colour when_0 where fac_socket is 0 and when_1 where it is 1, of Strength
    the HDRI's luminance: a sun that light samples find (a world of even luminance leaves them
    next to nothing here, its map compensated for the BSDF rays)."""
    bg = background(nt)
    bw = nt.nodes.new("ShaderNodeRGBToBW")
    nt.links.new(env_texture(nt, hdri()).outputs["Color"], bw.inputs[0])
    nt.links.new(bw.outputs[0], bg.inputs["Strength"])
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = 'RGBA'
    nt.links.new(fac_socket, mix.inputs["Factor"])
    mix.inputs[6].default_value = (*when_0, 1.0)  # A
    mix.inputs[7].default_value = (*when_1, 1.0)  # B
    nt.links.new(mix.outputs[2], bg.inputs["Color"])
    nt.links.new(bg.outputs[0], out.inputs["Surface"])
    return bg


def light_path_world(output, threshold=0.5, sampling='AUTOMATIC', transparent=False):
    """A world that is one colour where Light Path `output` exceeds `threshold` and another
    below, over the floor and spheres. Ray Depth: Cycles evaluates a background one bounce
    further (camera rays and a first vertex's light samples read 1), so a world that is warm at
    depth 0 and blue from 1 on is blue for every ray and light sample in Cycles. Transparent
    Depth: a Transparent plane before the camera makes it 1 at every vertex, for light samples
    as for the rays. sampling: World ▸ Settings ▸ Sampling Method."""
    def build():
        scene, nt, out = objects()
        scene.world.cycles.sampling_method = sampling
        path = nt.nodes.new("ShaderNodeLightPath")
        gt = nt.nodes.new("ShaderNodeMath")
        gt.operation = 'GREATER_THAN'
        gt.inputs[1].default_value = threshold
        nt.links.new(path.outputs[output], gt.inputs[0])
        _mix_by(nt, out, gt.outputs[0], (1.0, 0.5, 0.1), (0.2, 0.45, 1.0))
        if transparent:
            mat, nodes, links, mout = ms.new_material("Veil")
            links.new(nodes.new("ShaderNodeBsdfTransparent").outputs[0], mout.inputs["Surface"])
            ms.add_plane("Veil", 6.0, mat, location=(0.0, -4.0, 1.2), rotation_euler=(math.pi / 2, 0.0, 0.0))
        return scene
    return build


@pytest.mark.parametrize("output,transparent", [("Ray Depth", False), ("Transparent Depth", True)])
def test_light_path_counts_in_light_samples(output, transparent):
    """A world's Light Path counts in light samples: Cycles evaluates them with the sampling
    vertex's counts and Ray Depth one further (light_sample_shader_eval, PATH_RAY_EMISSION),
    as escaped rays (shade_background); the map has no counts."""
    build = light_path_world(output, transparent=transparent)
    program, warnings = exported_program(build)
    assert program is not None and not warnings, warnings
    ours, cycles = render_pair(build, 512)
    assert_agree(ours, cycles, f"world by {output} in light samples")


def test_sampling_method_none_is_no_light():
    """World ▸ Settings ▸ Sampling Method None: Cycles adds no background light, so a world
    that shows diffuse rays one colour and everything else (light samples too) another lights
    the diffuse surfaces by the first alone."""
    build = light_path_world("Is Diffuse Ray", sampling='NONE')
    program, warnings = exported_program(build)
    assert program is not None and not warnings, warnings
    ours, cycles = render_pair(build, 512)
    assert_agree(ours, cycles, "Sampling Method None (program world)")


def test_sampling_method_none_fast_path():
    """None with the fast path's HDRI: found by the rays alone, with weight 1."""
    def build():
        scene, nt, out = objects()
        scene.world.cycles.sampling_method = 'NONE'
        bg = background(nt)
        nt.links.new(env_texture(nt, hdri()).outputs["Color"], bg.inputs["Color"])
        nt.links.new(bg.outputs[0], out.inputs["Surface"])
        return scene
    scene = build()
    color, texture, program = export_world(scene.world, Warnings())
    assert program is None and texture is not None
    ours, cycles = render_pair(build, 1024)
    assert_agree(ours, cycles, "Sampling Method None (HDRI)")


def test_window_coordinates_of_an_orthographic_camera():
    """Window under an orthographic camera: a camera ray's is its pixel (the ray's origin),
    any other ray's the direction itself projected (no camera offset), as Cycles'
    svm_node_tex_coord."""
    def build():
        scene = procedural_world("window")()
        cam = scene.camera.data
        cam.type = 'ORTHO'
        cam.ortho_scale = 4.0
        return scene
    program, warnings = exported_program(build)
    assert program is not None and not warnings, warnings
    ours, cycles = render_pair(build, 512)
    assert_agree(ours, cycles, "Window, orthographic camera")


def test_manual_map_resolution_sizes_the_map():
    """Sampling Method Manual: its Map Resolution sizes a program world's map (Cycles'
    map_resolution, width x width / 2); Automatic: the largest Environment Texture image."""
    scene = camera_ray_world()()
    scene.world.cycles.sampling_method = 'MANUAL'
    scene.world.cycles.sample_map_resolution = 256
    color, texture, program = export_world(scene.world, Warnings())
    assert (program.width, program.height) == (256, 128)
    scene.world.cycles.sampling_method = 'AUTOMATIC'
    color, texture, program = export_world(scene.world, Warnings())
    assert (program.width, program.height) == (64, 32)  # the HDRI's size
