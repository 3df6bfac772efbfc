"""The pinhole camera frames the scene exactly as Blender does: sensor fit, focal length,
shift, pixel aspect and clipping, compared with Cycles on an emission-only scene (no lighting
noise: only edge anti-aliasing differs, so images must agree almost pixel for pixel)."""
import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, load_addon, node_material, render_to_array

load_addon()


def emissive_material(name, color):
    return node_material(name, "ShaderNodeEmission", Color=(*color, 1.0), Strength=1.0)


def target_scene(res, fit, shift, aspect, lens=35.0, clip=(0.1, 100.0), ortho_scale=None):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = aspect
    # A grid of coloured cubes at several depths: their silhouettes pin down the projection.
    colors = [(1, 0.2, 0.2), (0.2, 1, 0.2), (0.2, 0.2, 1), (1, 1, 0.2)]
    for i, x in enumerate((-3.0, -1.0, 1.0, 3.0)):
        for j, z in enumerate((-2.0, 0.0, 2.0)):
            bpy.ops.mesh.primitive_cube_add(size=0.8, location=(x, 2.0 * j, z))
            bpy.context.active_object.data.materials.append(emissive_material(f"m{i}{j}", colors[(i + j) % 4]))
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = lens
    cam_data.sensor_fit = fit
    cam_data.sensor_width, cam_data.sensor_height = 36.0, 20.0
    cam_data.shift_x, cam_data.shift_y = shift
    cam_data.clip_start, cam_data.clip_end = clip
    if ortho_scale is not None:
        cam_data.type = 'ORTHO'
        cam_data.ortho_scale = ortho_scale
    cam = bpy.data.objects.new("Camera", cam_data)
    scene.collection.objects.link(cam)
    cam.location = (0.5, -12.0, 0.5)
    cam.rotation_euler = (np.radians(88.0), 0.0, np.radians(3.0))
    cam.scale = (2.0, 2.0, 2.0)  # Blender ignores the camera's scale
    scene.camera = cam
    return scene


CASES = {
    "auto-landscape": ((96, 64), "AUTO", (0.0, 0.0), (1, 1)),
    "auto-portrait-shift": ((64, 96), "AUTO", (0.15, -0.1), (1, 1)),
    "horizontal-aspect": ((96, 64), "HORIZONTAL", (0.0, 0.1), (2, 1)),
    "vertical-shift": ((80, 80), "VERTICAL", (-0.2, 0.0), (1, 1.5)),
    "near-clip": ((96, 64), "AUTO", (0.0, 0.0), (1, 1)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_framing_matches_cycles(case):
    res, fit, shift, aspect = CASES[case]
    clip = (14.0, 100.0) if case == "near-clip" else (0.1, 100.0)  # clips the nearest row of cubes
    ours = render_to_array(target_scene(res, fit, shift, aspect, clip=clip), "PATHLIGHT", samples=64)
    cycles = render_to_array(target_scene(res, fit, shift, aspect, clip=clip), "CYCLES", samples=64)
    cycles_scene = bpy.context.scene
    assert cycles_scene.cycles.filter_width > 0  # Cycles keeps its own pixel filter; edges differ slightly
    diff = np.abs(ours[..., :3] - cycles[..., :3]).max(-1)
    # Interior pixels agree exactly (constant emission); only anti-aliased edge pixels differ.
    assert np.mean(diff > 0.25) < 0.01, f"{np.mean(diff > 0.25):.3f} of pixels differ"
    assert abs(ours[..., :3].mean() - cycles[..., :3].mean()) < 0.01 * max(cycles[..., :3].mean(), 0.05)
    assert ours[..., :3].max() > 0.5  # the cubes are in view


# Orthographic and shifted cameras, with the same 1-pixel box filter in both engines: the
# coverage of every pixel must then agree up to sampling noise.
SAME_FILTER_CASES = {
    "ortho-landscape": ((96, 64), "AUTO", (0.0, 0.0), (1, 1), 9.0, (0.1, 100.0)),
    "ortho-portrait-shift": ((64, 96), "AUTO", (0.2, -0.15), (1, 1), 12.0, (0.1, 100.0)),
    "ortho-vertical-aspect-clip": ((96, 64), "VERTICAL", (-0.1, 0.05), (1, 1.5), 7.0, (13.0, 100.0)),
    "persp-shift": ((96, 64), "HORIZONTAL", (0.25, 0.1), (1, 1), None, (0.1, 100.0)),
}


@pytest.mark.parametrize("case", sorted(SAME_FILTER_CASES))
def test_ortho_and_shift_framing_match_cycles_pixel_for_pixel(case):
    res, fit, shift, aspect, scale, clip = SAME_FILTER_CASES[case]
    ours = render_to_array(target_scene(res, fit, shift, aspect, clip=clip, ortho_scale=scale),
                           "PATHLIGHT", samples=64, **BOX_FILTER)
    cycles = render_to_array(target_scene(res, fit, shift, aspect, clip=clip, ortho_scale=scale),
                             "CYCLES", samples=64, **BOX_FILTER)
    diff = np.abs(ours[..., :3] - cycles[..., :3]).max(-1)
    # Coverage masks agree (edge pixels are partly covered: noise only), values almost so.
    assert np.mean((ours[..., :3].max(-1) > 0.5) != (cycles[..., :3].max(-1) > 0.5)) < 0.005
    assert np.mean(diff > 0.15) < 0.005, f"{np.mean(diff > 0.15):.4f} of pixels differ"
    assert ours[..., :3].max() > 0.5 and (ours[..., :3].max(-1) < 0.05).mean() > 0.2  # cubes and gaps
