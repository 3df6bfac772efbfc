"""Depth of field, autofocus, pixel filters and render borders through Blender (issue 5),
against Cycles in the same bpy and against the thin-lens model. Emission-only scenes: the only
noise is the pixel and lens sampling, so small renders converge fast."""
import logging
import math

import bpy
import numpy as np
import pytest

from blender_util import (BOX_FILTER, Warnings, core_has, empty_scene_with_camera, load_addon,
                          node_material, render_to_array)

addon = load_addon()
pytestmark = pytest.mark.skipif(not core_has("Camera", "generate_ray"), reason="core without thin lens")

SENSOR, LENS = 36.0, 50.0


def emission(name, color, strength=1.0):
    return node_material(name, "ShaderNodeEmission", Color=(*color, 1.0), Strength=strength)


def add_box(location, size, color):
    bpy.ops.mesh.primitive_cube_add(size=size, location=location)
    obj = bpy.context.active_object
    obj.data.materials.append(emission(f"m{location}", color))
    return obj


def add_half_plane(depth, edge_x=0.0, camera_y=-6.0, name="edge", side=1.0, color=(1.0, 1.0, 1.0)):
    """An emissive plane facing the camera at `depth` along +y, covering x > edge_x (or
    x < edge_x with side=-1)."""
    mesh = bpy.data.meshes.new(name)
    y = camera_y + depth
    far = edge_x + 100 * side
    mesh.from_pydata([(edge_x, y, -50), (far, y, -50), (far, y, 50), (edge_x, y, 50)], [],
                     [(0, 3, 2, 1) if side > 0 else (0, 1, 2, 3)])
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    obj.data.materials.append(emission(name, color))
    return obj


def dof_scene(kind="PERSP", res=(64, 48)):
    """Three emissive boxes at depths 3, 6 and 12 in front of a camera focused at 6."""
    sc = empty_scene_with_camera()
    sc.render.resolution_x, sc.render.resolution_y = res
    cam = sc.camera.data
    cam.lens, cam.sensor_width = LENS, SENSOR
    cam.type = kind
    cam.ortho_scale = 6.0
    cam.dof.use_dof = True
    cam.dof.focus_distance = 6.0
    cam.dof.aperture_fstop = 0.1 if kind == "PERSP" else 1.0
    if kind == "PERSP":
        add_box((-0.6, -3.0, 0.1), 0.5, (1.0, 0.3, 0.1))   # depth 3
        add_box((0.0, 0.0, -0.2), 1.0, (0.2, 1.0, 0.3))    # depth 6: in focus
        add_box((2.5, 6.0, 0.4), 2.0, (0.2, 0.4, 1.0))     # depth 12
    else:
        add_box((-1.8, -3.0, 0.1), 1.0, (1.0, 0.3, 0.1))
        add_box((0.0, 0.0, -0.2), 1.0, (0.2, 1.0, 0.3))
        add_box((1.8, 6.0, 0.4), 1.0, (0.2, 0.4, 1.0))
    return sc


def block_means(img, b=8):
    h, w = img.shape[0] // b * b, img.shape[1] // b * b
    return img[:h, :w, :3].reshape(h // b, b, w // b, b, 3).mean(axis=(1, 3))


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_dof_matches_cycles(kind):
    ours = render_to_array(dof_scene(kind), "PATHLIGHT", samples=256)
    cycles = render_to_array(dof_scene(kind), "CYCLES", samples=256, **BOX_FILTER)
    sc = dof_scene(kind)
    sc.camera.data.dof.use_dof = False
    pinhole = render_to_array(sc, "PATHLIGHT", samples=256)
    a, b, p = (block_means(x, 4) for x in (ours, cycles, pinhole))
    assert np.abs(b - p).max() > 0.1  # the blur is visible at this block size
    assert np.abs(a - b).max() < 0.03, np.abs(a - b).max()


def disk_edge(s):
    """Share of the unit disk with x < s."""
    s = np.clip(s, -1.0, 1.0)
    return 0.5 + (s * np.sqrt(1.0 - s * s) + np.arcsin(s)) / np.pi


@pytest.mark.parametrize("depth", [6.0, 12.0, 3.0])
def test_edge_blur_follows_the_circle_of_confusion(depth):
    """An edge at the focus distance stays a one-pixel step; away from it, the blur is the
    aperture disk of the thin lens: radius a |z - f| / (f z) on the view plane at distance 1,
    i.e. R = a |z - f| / (f z dx) pixels, with a = lens / (2 F) (Cycles' aperture)."""
    w, focus, fstop = 128, 6.0, 0.1
    sc = empty_scene_with_camera()
    sc.render.resolution_x, sc.render.resolution_y = w, 8
    cam = sc.camera.data
    cam.lens, cam.sensor_width, cam.sensor_fit = LENS, SENSOR, 'HORIZONTAL'
    cam.dof.use_dof, cam.dof.focus_distance, cam.dof.aperture_fstop = True, focus, fstop
    add_half_plane(depth)
    profile = render_to_array(sc, "PATHLIGHT", samples=256)[..., 0].mean(axis=0)
    c = w // 2  # the edge projects onto the boundary between columns c - 1 and c
    if depth == focus:
        assert profile[c] - profile[c - 1] > 0.99  # sharp: a step, as without a lens
        return
    a = LENS * 1e-3 / (2 * fstop)
    dx = SENSOR / LENS / w
    radius = a * abs(depth - focus) / (focus * depth * dx)
    assert radius > 3.0

    def predicted(r):  # the disk-edge step averaged over each pixel (box filter)
        u = np.arange(w)[:, None] + (np.arange(64)[None, :] + 0.5) / 64 - c
        return disk_edge(u / r).mean(axis=1)

    assert np.abs(profile - predicted(radius)).max() < 0.03
    # The blur radius that fits best is the predicted one.
    radii = radius * np.linspace(0.7, 1.3, 61)
    best = radii[np.argmin([np.sum((profile - predicted(r)) ** 2) for r in radii])]
    assert best == pytest.approx(radius, rel=0.03)


def autofocus_scene(use_autofocus):
    """A camera yawed 8 degrees, focused (wrongly) at 2.5, looking at a half plane whose edge
    passes through the image centre at a depth it does not know."""
    sc = empty_scene_with_camera()
    sc.render.resolution_x, sc.render.resolution_y = 64, 8
    cam_obj = sc.camera
    cam_obj.rotation_euler = (math.pi / 2, 0.0, math.radians(8.0))
    cam = cam_obj.data
    cam.lens, cam.sensor_width, cam.sensor_fit = LENS, SENSOR, 'HORIZONTAL'
    cam.dof.use_dof, cam.dof.focus_distance, cam.dof.aperture_fstop = True, 2.5, 0.1
    bpy.context.view_layer.update()
    m = np.array(cam_obj.matrix_world)
    eye, forward = m[:3, 3], -m[:3, 2]
    plane_y = 1.3
    t = (plane_y - eye[1]) / forward[1]
    hit = eye + forward * t
    add_half_plane(plane_y - eye[1], edge_x=hit[0], camera_y=eye[1])
    # A black half on the other side: the centre ray meets the plane on either side of the edge.
    add_half_plane(plane_y - eye[1], edge_x=hit[0], camera_y=eye[1], name="black", side=-1.0,
                   color=(0.0, 0.0, 0.0))
    sc.pathlight.use_autofocus = use_autofocus
    return sc, float(np.dot(hit - eye, forward))


def test_autofocus_focuses_on_the_centre(caplog):
    sc, depth = autofocus_scene(True)
    with caplog.at_level(logging.INFO, logger="addon.session"):
        img = render_to_array(sc, "PATHLIGHT", samples=64)
    reported = [r.args[0] for r in caplog.records if "autofocus at" in r.getMessage()]
    assert reported and reported[-1] == pytest.approx(depth, rel=1e-4)
    row = img[..., 0].mean(axis=0)
    assert row[32] - row[31] > 0.95  # the edge under the centre is sharp
    sc, _ = autofocus_scene(False)
    blurred = render_to_array(sc, "PATHLIGHT", samples=64)[..., 0].mean(axis=0)
    assert blurred[32] - blurred[31] < 0.5  # and is not without autofocus


def edge_scene():
    sc = empty_scene_with_camera()
    sc.render.resolution_x, sc.render.resolution_y = 32, 8
    sc.camera.data.lens = LENS
    add_half_plane(6.0)
    return sc


@pytest.mark.parametrize("kind,width", [("BLACKMAN_HARRIS", 1.5), ("GAUSSIAN", 1.5), ("BLACKMAN_HARRIS", 3.0)])
def test_filter_edge_profile_matches_cycles(kind, width):
    ours = render_to_array(edge_scene(), "PATHLIGHT", samples=256, filter_type=kind, filter_width=width)
    cycles = render_to_array(edge_scene(), "CYCLES", samples=256, pixel_filter_type=kind, filter_width=width)
    box = render_to_array(edge_scene(), "PATHLIGHT", samples=256, filter_type='BOX', filter_width=1.0)
    a, b, c = (x[..., 0].mean(axis=0) for x in (ours, cycles, box))
    assert np.abs(b - c).max() > 0.05  # the filter shows at the edge
    assert np.abs(a - b).max() < 0.02, np.round(np.c_[a, b][12:20], 3)


def test_default_filter_is_cycles_default():
    sc = empty_scene_with_camera()
    props = sc.pathlight
    assert (props.filter_type, props.filter_width) == ('BLACKMAN_HARRIS', pytest.approx(1.5))
    assert (sc.cycles.pixel_filter_type, sc.cycles.filter_width) == ('BLACKMAN_HARRIS', pytest.approx(1.5))
    pc = addon.core.get_core()
    st = addon.session.render_settings(pc, sc)
    assert (st.filter_type, st.filter_width) == ("blackman_harris", pytest.approx(1.5))


def border_scene(percentage=100):
    sc = dof_scene()
    sc.render.resolution_percentage = percentage
    sc.render.use_border = True
    sc.render.border_min_x, sc.render.border_max_x = 0.23, 0.81
    sc.render.border_min_y, sc.render.border_max_y = 0.12, 0.66
    return sc


@pytest.mark.parametrize("percentage", [100, 50])
def test_border_and_crop_render_the_same_region(percentage):
    sc = border_scene(percentage)
    sc.render.use_border = False
    full = render_to_array(sc, "PATHLIGHT", samples=16, filter_type='BLACKMAN_HARRIS')
    h, w = full.shape[:2]
    assert (w, h) == (64 * percentage // 100, 48 * percentage // 100)
    x0, x1, y0, y1 = int(0.23 * w), int(0.81 * w), int(0.12 * h), int(0.66 * h)
    region = full[h - y1:h - y0, x0:x1]  # image rows run top-down
    sc = border_scene(percentage)
    sc.render.use_crop_to_border = True
    cropped = render_to_array(sc, "PATHLIGHT", samples=16, filter_type='BLACKMAN_HARRIS')
    assert cropped.shape == region.shape
    assert np.array_equal(cropped, region)  # the same samples, bit for bit
    sc = border_scene(percentage)
    sc.render.use_crop_to_border = False
    pasted = render_to_array(sc, "PATHLIGHT", samples=16, filter_type='BLACKMAN_HARRIS')
    assert pasted.shape == full.shape
    assert np.array_equal(pasted[h - y1:h - y0, x0:x1], region)
    outside = pasted.copy()
    outside[h - y1:h - y0, x0:x1] = 0.0
    assert np.abs(outside).max() == 0.0  # nothing rendered outside the border
    assert region[..., :3].max() > 0.5  # and the border sees the boxes


def export_camera(sc):
    warn = Warnings()
    params = addon.export.camera.camera_params(sc, bpy.context.evaluated_depsgraph_get(), warn)
    return params, warn


def test_export_focus_object_and_aperture():
    sc = dof_scene()
    target = bpy.data.objects.new("target", None)
    sc.collection.objects.link(target)
    target.location = (1.5, 2.0, -0.7)  # depth along the view (+y) axis: 8, distance ~8.17
    sc.camera.data.dof.focus_object = target
    sc.camera.data.dof.aperture_blades = 6
    sc.camera.data.dof.aperture_ratio = 1.5
    params, warn = export_camera(sc)
    assert not warn
    assert params["focus_distance"] == pytest.approx(8.0, rel=1e-5)
    assert params["aperture_size"] == pytest.approx(LENS * 1e-3 / (2 * 0.1), rel=1e-5)
    assert (params["aperture_blades"], params["aperture_ratio"]) == (6, pytest.approx(1.5))
    sc.camera.data.type = 'ORTHO'
    params, _ = export_camera(sc)
    assert params["type"] == "ORTHO" and params["aperture_size"] == pytest.approx(1 / (2 * 0.1))


def test_bad_camera_settings_warn_and_render():
    sc = dof_scene()
    cam = sc.camera.data
    cam.dof.aperture_fstop = 0.0
    params, warn = export_camera(sc)
    assert "aperture_size" not in params and any("F-stop" in m for m in warn)
    cam.dof.aperture_fstop = 2.0
    cam.dof.focus_distance = 0.0
    params, warn = export_camera(sc)
    assert "aperture_size" not in params and any("focus distance" in m for m in warn)
    cam.dof.focus_distance = 5.0
    target = bpy.data.objects.new("flat", None)
    sc.collection.objects.link(target)
    target.location = (1.0, -6.0, 0.3)  # in the camera's plane
    cam.dof.focus_object = target
    params, warn = export_camera(sc)
    assert params["focus_distance"] == pytest.approx(5.0) and any("plane" in m for m in warn)
    cam.type = 'CUSTOM'  # (PANO is supported since the panoramic cameras)
    params, warn = export_camera(sc)
    assert params["type"] == "PERSP" and any("projection" in m for m in warn)
    cam.dof.aperture_fstop = 0.0
    sc.pathlight.use_autofocus = True
    params, warn = export_camera(sc)
    assert not params["use_autofocus"] and any("autofocus needs" in m for m in warn)
    img = render_to_array(sc, "PATHLIGHT", samples=2)  # renders, with warnings only
    assert np.isfinite(img).all() and img[..., :3].max() > 0.5



def bokeh_scene(blades, rotation, ratio):
    """A small bright emitter far before the focal plane: its image is the aperture's shape
    (widened by the emitter's own ~3 pixels)."""
    sc = empty_scene_with_camera(48)
    cam = sc.camera.data
    cam.lens, cam.sensor_width = LENS, SENSOR
    cam.dof.use_dof, cam.dof.focus_distance, cam.dof.aperture_fstop = True, 20.0, 0.1
    cam.dof.aperture_blades, cam.dof.aperture_rotation, cam.dof.aperture_ratio = blades, rotation, ratio
    bpy.ops.mesh.primitive_plane_add(size=0.07, location=(0.0, -4.5, 0.0), rotation=(math.pi / 2, 0, 0))
    bpy.context.active_object.data.materials.append(emission("dot", (1.0, 1.0, 1.0), 10.0))
    return sc


def harmonics(img, orders):
    """Normalised angular harmonics sum(w z^m) / sum(w |z|^m) of an image about its centroid:
    m = 2 sees elongation, m = n the orientation of an n-gon."""
    y, x = np.mgrid[:img.shape[0], :img.shape[1]] + 0.5
    w = img / img.sum()
    z = (x - (w * x).sum()) + 1j * (y - (w * y).sum())
    return np.array([(w * z ** m).sum() / (w * np.abs(z) ** m).sum() for m in orders])


@pytest.mark.parametrize("blades,rotation,ratio", [(5, 0.5, 1.0), (0, 0.0, 1.6), (6, -0.3, 0.7)])
def test_bokeh_shape_matches_cycles(blades, rotation, ratio):
    ours = render_to_array(bokeh_scene(blades, rotation, ratio), "PATHLIGHT", samples=1024)[..., 0]
    cycles = render_to_array(bokeh_scene(blades, rotation, ratio), "CYCLES", samples=1024, **BOX_FILTER)[..., 0]
    orders = [2, blades] if blades else [2]
    a, b = harmonics(ours, orders), harmonics(cycles, orders)
    assert np.abs(a - b).max() < 0.2 * np.abs(b).max()
    assert np.abs(b).max() > 0.02  # the shape is not a round disk: the harmonics mean something
    assert ours.sum() == pytest.approx(cycles.sum(), rel=0.02)  # the same light, spread alike


def test_depth_of_field_panels_are_shown():
    from bl_ui import properties_data_camera as panels
    for name in ("DATA_PT_camera_dof", "DATA_PT_camera_dof_aperture", "DATA_PT_lens"):
        assert "PATHLIGHT" in getattr(panels, name).COMPAT_ENGINES, name
    assert hasattr(bpy.types, "PATHLIGHT_RENDER_PT_pixel_filter")
    assert hasattr(bpy.types, "PATHLIGHT_RENDER_PT_autofocus")
