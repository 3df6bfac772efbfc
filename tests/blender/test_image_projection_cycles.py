"""Image Texture projections (Box with Blend, Sphere, Tube), Cubic and Smart interpolation and
the Mirror extension, rendered by Pathlight and compared with Cycles (stored references,
tests/cycles_refs/): emissive objects, so every pixel is a texture lookup. The filters at the
image's borders against a numpy model of Cycles' kernel are tests/core/test_core_image_filters.py."""
import numpy as np
import pytest

import bpy

import material_scenes as ms
from blender_util import BOX_FILTER, Warnings, load_addon, render_to_array
from test_image_sources_cycles import (assert_same, folder, nearest_frame, render_both,  # noqa: F401
                                       udim_image, uv_plane_scene)

load_addon()
from addon.export import export_scene  # noqa: E402


def checker_image(n=8):
    """An n x n sRGB byte image: a colour ramp over u and v, every other texel darker, so that
    flips, rotations and the filters show."""
    y, x = np.mgrid[0:n, 0:n] / (n - 1.0)
    px = np.ones((n, n, 4), np.float32)
    px[..., 0], px[..., 1], px[..., 2] = 0.15 + 0.8 * x, 0.15 + 0.8 * y, 0.9 - 0.7 * x * y
    px[(np.indices((n, n)).sum(0) % 2) == 1, :3] *= 0.6
    img = bpy.data.images.new("Ramp", n, n, alpha=True)
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


def object_scene(primitive, projection, coords="Object", blend=0.0, interpolation='Linear',
                 rotation=(0.0, 0.0, 0.0), size=48):
    """build() of an emissive `primitive` (a mesh op) textured by projection `projection` of
    checker_image() over Texture Coordinate `coords`, seen from above at an angle."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = size
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("Projected")
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = checker_image()
        tex.projection = projection
        tex.projection_blend = blend
        tex.interpolation = interpolation
        links.new(nodes.new("ShaderNodeTexCoord").outputs[coords], tex.inputs["Vector"])
        emit = nodes.new("ShaderNodeEmission")
        links.new(tex.outputs["Color"], emit.inputs["Color"])
        links.new(emit.outputs[0], out.inputs["Surface"])
        primitive()
        obj = bpy.context.active_object
        obj.rotation_euler = rotation
        obj.data.materials.append(mat)
        cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
        cam.location = (2.6, -3.4, 2.9)
        cam.rotation_euler = (0.93, 0.0, 0.65)
        scene.collection.objects.link(cam)
        scene.camera = cam
        return scene
    return build


def cube():
    bpy.ops.mesh.primitive_cube_add(size=1.6)


def sphere():
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()


def no_warnings():
    warnings = Warnings()
    export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert not [w for w in warnings if "Image Texture" in w or "projection" in w], warnings


@pytest.mark.parametrize("primitive, blend, rotation", [
    (cube, 0.0, (0.0, 0.0, 0.0)), (sphere, 0.0, (0.0, 0.0, 0.0)), (sphere, 0.35, (0.4, 0.0, 0.7))])
def test_box_projection_matches_cycles(primitive, blend, rotation):
    """Box over Object coordinates: each face its axis' lookup, unflipped on the far sides, the
    object-space normal picking them (a rotated object: its own axes), Blend mixing up to three."""
    build = object_scene(primitive, 'BOX', blend=blend, rotation=rotation)
    build()
    no_warnings()
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"box {primitive.__name__} blend {blend}")
    flat = render_to_array(object_scene(primitive, 'FLAT', rotation=rotation)(), "PATHLIGHT", samples=4,
                           max_bounces=0)[..., :3]
    assert np.abs(ours - flat).mean() > 0.02  # (Box is not the flat lookup of the same vector)


@pytest.mark.parametrize("projection", ['SPHERE', 'TUBE'])
def test_sphere_and_tube_projections_match_cycles(projection):
    build = object_scene(sphere, projection, coords="Generated", rotation=(0.3, 0.0, 0.5))
    build()
    no_warnings()
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"{projection.lower()} projection")


@pytest.mark.parametrize("interp, ext", [('Cubic', 'MIRROR'), ('Smart', 'CLIP'), ('Cubic', 'EXTEND'),
                                         ('Linear', 'MIRROR'), ('Closest', 'MIRROR')])
def test_cubic_and_mirror_match_cycles(interp, ext):
    """A uv plane from (-1.5, -1) to (2.5, 2) over one 8 x 8 image: Mirror's reflected copies,
    Cubic's B-spline (Smart is Cubic in Cycles' CPU kernel) against each extension."""
    build = uv_plane_scene(checker_image, (-1.5, -1.0), (2.5, 2.0), interp, ext)
    build()
    no_warnings()
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"{interp} {ext}")
    if interp != 'Linear':
        linear = render_to_array(uv_plane_scene(checker_image, (-1.5, -1.0), (2.5, 2.0), 'Linear', ext)(),
                                 "PATHLIGHT", samples=16, max_bounces=0)[..., :3]
        assert np.abs(ours - linear).mean() > 0.03 * linear.mean()  # (the texels differ from Linear)


@pytest.mark.parametrize("interp, ext", [('Cubic', 'MIRROR'), ('Cubic', 'CLIP')])
def test_cubic_and_mirror_on_udim_tiles_match_cycles(folder, interp, ext):  # noqa: F811
    build = uv_plane_scene(lambda: udim_image(folder), (-0.5, -0.5), (2.5, 1.5), interp, ext)
    ours, cycles = render_both(build)
    assert_same(ours, cycles, f"UDIM {interp} {ext}")


def test_box_on_udim_tiles_reads_the_first_tile_as_cycles(folder):  # noqa: F811
    """Cycles' Box reads a tile set's first tile (1001) wherever the coordinates fall."""
    def build():
        scene = object_scene(cube, 'BOX')()
        mat = bpy.data.materials["Projected"]
        tex = mat.node_tree.nodes["Image Texture"]
        tex.image = udim_image(folder)
        mapping = mat.node_tree.nodes.new("ShaderNodeMapping")
        mapping.inputs["Scale"].default_value = (2.0, 2.0, 2.0)
        links = mat.node_tree.links
        links.new(mat.node_tree.nodes["Texture Coordinate"].outputs["Object"], mapping.inputs["Vector"])
        links.new(mapping.outputs[0], tex.inputs["Vector"])
        return scene
    ours, cycles = render_both(build)
    assert_same(ours, cycles, "box on UDIM tiles")
    lit = ours[ours.sum(-1) > 0.02]
    assert np.argmax(lit.mean(0)) == 0  # tile 1001's red throughout, no magenta, no green
    assert not np.any(np.all(np.abs(lit - (1.0, 0.0, 1.0)) < 0.05, axis=-1))


def world_sequence_scene(folder, frame, program):  # noqa: F811
    """build() of an empty scene whose world is an Environment Texture of the image sequence
    seq.####.png (3 frames) at scene frame `frame`; program: through a Gamma node (1.0), which
    makes it a world program rather than the equirectangular fast path."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x, scene.render.resolution_y = 32, 16
        world = ms.set_world((0.0, 0.0, 0.0))
        nodes, links = world.node_tree.nodes, world.node_tree.links
        env = nodes.new("ShaderNodeTexEnvironment")
        env.image = bpy.data.images.load(str(folder / "seq.0001.png"))
        env.image.source = 'SEQUENCE'
        env.image_user.frame_duration, env.image_user.frame_start = 3, 1
        colour = env.outputs["Color"]
        if program:
            gamma = nodes.new("ShaderNodeGamma")
            gamma.inputs["Gamma"].default_value = 1.0
            links.new(colour, gamma.inputs["Color"])
            colour = gamma.outputs[0]
        links.new(colour, nodes["Background"].inputs["Color"])
        cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
        cam.data.lens = 12.0
        cam.rotation_euler = (1.5, 0.0, 0.3)
        scene.collection.objects.link(cam)
        scene.camera = cam
        scene.frame_set(frame)
        return scene
    return build


def test_world_image_sequence_follows_the_frame_as_cycles(folder):  # noqa: F811
    """A world program's Environment Texture of an image sequence shows the node's frame at the
    scene frame, as Cycles."""
    for frame in (2, 3):
        ours, cycles = render_both(world_sequence_scene(folder, frame, True))
        assert_same(ours, cycles, f"world program sequence frame {frame}")
        assert nearest_frame(ours) == frame


def test_world_fast_path_sequence_reads_the_frames_file(folder):  # noqa: F811
    """The equirectangular fast path renders a sequence at frame N exactly as the still image
    of frame N's file. (Its filtering of byte images differs from Cycles' before this change:
    it decodes sRGB before filtering; the program path above is the one compared with Cycles.)"""
    for frame in (2, 3):
        scene = world_sequence_scene(folder, frame, False)()
        seq = render_to_array(scene, "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
        env = bpy.context.scene.world.node_tree.nodes["Environment Texture"]
        env.image = bpy.data.images.load(str(folder / f"seq.{frame:04d}.png"))
        still = render_to_array(scene, "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
        assert nearest_frame(seq) == frame
        assert np.array_equal(seq, still)


@pytest.mark.parametrize("program", [False, True])
def test_world_sequence_follows_the_frame_in_an_animation(folder, program):  # noqa: F811
    """Two frames of one animation (the kept scene of render_cache: persistent data) show the
    world sequence's two frames."""
    scene = world_sequence_scene(folder, 2, program)()
    scene.render.use_persistent_data = True
    second = render_to_array(scene, "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
    scene.frame_set(3)
    third = render_to_array(scene, "PATHLIGHT", samples=4, max_bounces=0)[..., :3]
    assert (nearest_frame(second), nearest_frame(third)) == (2, 3)
