"""Panoramic cameras against Cycles: each panorama type's mapping per pixel (a smooth
environment seen directly, no lighting noise: every pixel's colour encodes its direction), a
lit room at convergence (mean within 1 %, every region within 3 %, also with depth of field),
and bad input (warned, a fallback, never a crash). Cycles runs with a 1-pixel box filter."""
import math
from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, Warnings, load_addon, render_to_array
from light_scenes import camera, diffuse_material, emission_material, empty_scene, load_image, plane, uv_sphere, world_image
from material_scenes import assert_agree, compare

load_addon()
from addon.export import export_scene  # noqa: E402
from addon.export.camera import panorama_params  # noqa: E402

W, H = 64, 32


def smooth_environment(width=256, height=128):
    """An equirectangular map whose colour varies smoothly with the direction (periodic in u,
    so no seam): red and green encode the longitude, blue the latitude."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    rgb = np.zeros((height, width, 3), np.float32)
    rgb[..., 0] = 0.5 + 0.45 * np.cos(2 * np.pi * u)[None, :]
    rgb[..., 1] = 0.5 + 0.45 * np.sin(2 * np.pi * u)[None, :]
    rgb[..., 2] = (0.05 + 0.9 * v)[:, None]
    return rgb


def pano_camera(ptype, location=(0.0, 0.0, 0.0), rotation=(1.3, 0.2, 0.7), **fields):
    cam = camera(location, rotation=rotation)
    cam.data.type = 'PANO'
    cam.data.panorama_type = ptype
    for key, value in fields.items():
        setattr(cam.data, key, value)
    return cam


def environment_scene(tmp_path, ptype, pixel_aspect=(1.0, 1.0), **fields):
    scene = empty_scene(W, H)
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = pixel_aspect
    world = world_image(load_image(smooth_environment(), directory=tmp_path))
    world.cycles.sampling_method = 'NONE'  # only seen directly: Cycles needs no importance map
    pano_camera(ptype, **fields)
    return scene


MAPPINGS = {
    "equirectangular": ('EQUIRECTANGULAR', dict(shift_x=0.03)),
    "equirectangular-range": ('EQUIRECTANGULAR', dict(latitude_min=-0.5, latitude_max=1.2,
                                                      longitude_min=-2.0, longitude_max=1.0)),
    "cube-face": ('EQUIANGULAR_CUBEMAP_FACE', dict(shift_y=-0.05)),
    "mirror-ball": ('MIRRORBALL', {}),
    "fisheye-equidistant": ('FISHEYE_EQUIDISTANT', dict(fisheye_fov=3.0)),
    "fisheye-equisolid": ('FISHEYE_EQUISOLID', dict(fisheye_fov=3.2, fisheye_lens=8.0)),
    "fisheye-equisolid-vertical": ('FISHEYE_EQUISOLID', dict(fisheye_fov=2.6, fisheye_lens=8.0,
                                                             sensor_fit='VERTICAL', sensor_height=20.0)),
    # Non-square pixels: the fisheye sensor is fitted to the aspect they give the frame.
    "fisheye-equisolid-pixel-aspect": ('FISHEYE_EQUISOLID', dict(fisheye_fov=3.2, fisheye_lens=8.0,
                                                                 pixel_aspect=(1.0, 1.7))),
    "fisheye-polynomial": ('FISHEYE_LENS_POLYNOMIAL', dict(fisheye_fov=2.4, fisheye_polynomial_k1=-0.06)),
    "central-cylindrical": ('CENTRAL_CYLINDRICAL', dict(
        central_cylindrical_range_u_min=-2.0, central_cylindrical_range_u_max=2.5,
        central_cylindrical_range_v_min=-0.8, central_cylindrical_range_v_max=1.5,
        central_cylindrical_radius=1.3)),
    # Reversed ranges: Cycles renders them mirrored; so must we (with a warning).
    "equirectangular-reversed": ('EQUIRECTANGULAR', dict(latitude_min=1.0, latitude_max=-0.6)),
}


def assert_same_mapping(ours, ref, what):
    a, b = ours[..., :3], ref[..., :3]
    lit_a, lit_b = a.max(-1) > 0, b.max(-1) > 0
    # The same pixels get no ray (outside a fisheye's circle or the mirror ball), up to the
    # partly covered ones on the rim, whose samples may all miss in one engine.
    assert np.mean(lit_a != lit_b) < 0.01, f"{what}: {np.mean(lit_a != lit_b):.4f} of pixels lit differently"
    # Away from the rim every pixel agrees: its colour is its direction.
    padded = np.pad(lit_a & lit_b, 1)
    interior = np.lib.stride_tricks.sliding_window_view(padded, (3, 3)).all(axis=(-1, -2))
    assert interior.mean() > 0.3
    diff = np.abs(a - b).max(-1)[interior]
    assert np.percentile(diff, 99) < 0.01 and diff.max() < 0.06, \
        f"{what}: 99th percentile {np.percentile(diff, 99):.4f}, max {diff.max():.4f}"
    np.testing.assert_array_equal(ours[..., 3], 1.0)  # no-ray pixels are black and opaque
    assert_agree(ours, ref, what)


@pytest.mark.parametrize("case", sorted(MAPPINGS))
def test_mapping_matches_cycles_pixel_for_pixel(case, tmp_path):
    ptype, fields = MAPPINGS[case]
    scene = environment_scene(tmp_path, ptype, **fields)
    warnings = Warnings()
    assert export_scene(bpy.context.evaluated_depsgraph_get(), warnings).camera["type"] == 'PANO'
    assert (len(warnings) == 1 and "mirrored" in warnings[0]) if "reversed" in case else warnings == []
    # 128 samples: the partly covered rim pixels of the fisheyes also converge.
    ours = render_to_array(scene, samples=128)
    ref = render_to_array(environment_scene(tmp_path, ptype, **fields), "CYCLES", samples=128, **BOX_FILTER)
    assert_same_mapping(ours, ref, case)


def room(ptype, dof=False, **fields):
    """A closed room under an emitting ceiling: coloured walls, a sphere; the camera inside."""
    scene = empty_scene(W, H)
    plane("ceiling", 6.0, emission_material("sky", (1.0, 0.95, 0.9), 2.0), location=(0, 0, 1.5),
          rotation_euler=(math.pi, 0, 0))
    walls = [((0, 0, -1.5), (0, 0, 0), (0.7, 0.7, 0.7)),
             ((0, 3, 0), (math.pi / 2, 0, 0), (0.2, 0.3, 0.8)),
             ((0, -3, 0), (-math.pi / 2, 0, 0), (0.8, 0.7, 0.2)),
             ((3, 0, 0), (0, -math.pi / 2, 0), (0.2, 0.7, 0.25)),
             ((-3, 0, 0), (0, math.pi / 2, 0), (0.8, 0.2, 0.2))]
    for i, (loc, rot, col) in enumerate(walls):
        plane(f"wall{i}", 6.0, diffuse_material(f"w{i}", col), location=loc, rotation_euler=rot)
    uv_sphere("ball", 0.6, diffuse_material("ball", (0.9, 0.9, 0.9)), location=(1.2, 1.0, -0.9))
    cam = pano_camera(ptype, location=(-0.3, -0.5, 0.1), rotation=(1.45, 0.1, 0.4), **fields)
    if dof:
        cam.data.dof.use_dof = True
        cam.data.dof.focus_distance = 1.5
        cam.data.dof.aperture_fstop = 0.1
    return scene


ROOMS = ['EQUIRECTANGULAR', 'EQUIANGULAR_CUBEMAP_FACE', 'MIRRORBALL', 'FISHEYE_EQUIDISTANT',
         'FISHEYE_EQUISOLID', 'FISHEYE_LENS_POLYNOMIAL', 'CENTRAL_CYLINDRICAL']


@pytest.mark.parametrize("ptype", ROOMS)
def test_lit_room_matches_cycles(ptype):
    ours = render_to_array(room(ptype), samples=256, max_bounces=4)
    ref = render_to_array(room(ptype), "CYCLES", samples=256, max_bounces=4, **BOX_FILTER)
    assert_agree(ours, ref, ptype)


@pytest.mark.parametrize("ptype", ['EQUIRECTANGULAR', 'FISHEYE_EQUISOLID'])
def test_depth_of_field_matches_cycles(ptype):
    # Cycles' panorama lens: a disk across each ray, focused on a sphere around the camera.
    # (512 spp, Cycles 1024, stored: at 256 each the fisheye failed on 1-2 of 3 seeds with either
    # sampler, issue 25)
    ours = render_to_array(room(ptype, dof=True), samples=512, max_bounces=4)
    ref = render_to_array(room(ptype, dof=True), "CYCLES", samples=1024, max_bounces=4, **BOX_FILTER)
    assert_agree(ours, ref, f"{ptype} with depth of field")
    pinhole = render_to_array(room(ptype), samples=64, max_bounces=4)
    assert compare(ours, pinhole)[1] > 0.05  # the blur is visible: the test can fail


def fake_camera(**fields):
    """What panorama_params reads of a bpy Camera: Blender's defaults, then `fields`."""
    cam = bpy.data.cameras.new("defaults")
    values = {p.identifier: getattr(cam, p.identifier) for p in cam.bl_rna.properties
              if p.identifier.startswith(("fisheye", "latitude", "longitude", "central", "sensor", "panorama"))}
    bpy.data.cameras.remove(cam)
    values.update(fields)
    return SimpleNamespace(**values)


RENDER = SimpleNamespace(resolution_x=W, resolution_y=H, pixel_aspect_x=1.0, pixel_aspect_y=1.0)


@pytest.mark.parametrize("field, value", [
    ("fisheye_fov", float("nan")), ("fisheye_fov", 0.0), ("fisheye_lens", -2.0),
    ("latitude_max", float("inf")), ("central_cylindrical_radius", 0.0),
])
def test_unusable_values_warn_and_fall_back_to_blenders_defaults(field, value):
    warnings = Warnings()
    params = panorama_params(fake_camera(**{field: value}), "Cam", RENDER, warnings)
    assert len(warnings) == 1 and field in warnings[0]
    default = fake_camera()
    assert params[field] == pytest.approx(getattr(default, field))


def test_non_finite_polynomial_falls_back():
    warnings = Warnings()
    params = panorama_params(fake_camera(panorama_type='FISHEYE_LENS_POLYNOMIAL',
                                         fisheye_polynomial_k2=float("nan")), "Cam", RENDER, warnings)
    assert any("polynomial" in w for w in warnings)
    assert all(math.isfinite(k) for k in params["fisheye_polynomial"])


def test_nan_field_of_view_renders_with_the_default(tmp_path):
    scene = environment_scene(tmp_path, 'FISHEYE_EQUIDISTANT')
    ref = render_to_array(scene, samples=4)
    scene.camera.data.fisheye_fov = float("nan")  # RNA takes it
    warnings = Warnings()
    export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert any("fisheye_fov" in w for w in warnings)
    img = render_to_array(scene, samples=4)
    np.testing.assert_allclose(img, ref, atol=1e-6)


def test_polynomial_that_sees_nothing_warns_and_renders_black(tmp_path):
    # theta > fov / 2 everywhere: Cycles gives every pixel no ray; so do we, with a warning.
    scene = environment_scene(tmp_path, 'FISHEYE_LENS_POLYNOMIAL', fisheye_polynomial_k0=-3.0,
                              fisheye_polynomial_k1=0.0, fisheye_fov=1.0)
    warnings = Warnings()
    export_scene(bpy.context.evaluated_depsgraph_get(), warnings)
    assert any("no pixel" in w for w in warnings)
    img = render_to_array(scene, samples=2)
    assert np.isfinite(img).all()
    np.testing.assert_array_equal(img[..., :3], 0.0)
    ref = render_to_array(scene, "CYCLES", samples=2, **BOX_FILTER)
    np.testing.assert_array_equal(ref[..., :3], 0.0)


@pytest.mark.parametrize("region, zoom", [((64, 32), 1.0), ((160, 64), 1.0), ((128, 64), 0.5)])
def test_viewport_camera_view_renders_the_panorama_inside_the_border(region, zoom):
    # Looking through a panoramic camera, the viewport maps the panorama to the camera border
    # (Cycles' viewport does the same): a region pixel's ray is the final render's ray through
    # the same place of the frame, with the fisheye sensor fitted to the render, not the region.
    import types

    from addon import viewport_draw
    from addon.core import get_core
    scene = empty_scene(W, H)
    cam = pano_camera('FISHEYE_EQUISOLID', location=(0.5, -2.0, 1.0), fisheye_fov=3.0, fisheye_lens=9.0)
    dg = bpy.context.evaluated_depsgraph_get()
    width, height = region
    window = np.array(cam.calc_matrix_camera(dg, x=width, y=height))
    window[:2] *= zoom  # zoomed out: the border covers part of the region
    context = types.SimpleNamespace(
        region=types.SimpleNamespace(width=width, height=height), scene=scene,
        evaluated_depsgraph_get=lambda: dg,
        region_data=types.SimpleNamespace(view_matrix=np.array(cam.matrix_world.inverted()),
                                          window_matrix=window, is_perspective=True,
                                          view_perspective='CAMERA'))
    reports = []
    engine = types.SimpleNamespace(report=lambda kind, msg: reports.append(msg))
    fields, w, h = viewport_draw.view_camera(engine, context)
    assert reports == [] and (w, h) == region and fields["type"] == 'PANO'
    left, right, bottom, top = fields["pano_viewplane"]
    if region == (W, H) and zoom == 1.0:
        np.testing.assert_allclose(fields["pano_viewplane"], (0, 1, 0, 1), atol=1e-5)
    pc = get_core()

    def core_camera(f):
        c = pc.Camera()
        for key, value in f.items():
            setattr(c, key, value)
        return c

    view_cam = core_camera(fields)
    final_cam = core_camera(panorama_free_export(scene))
    rng = np.random.default_rng(4)
    checked = 0
    for x, y in rng.random((60, 2)) * (width, height):
        u = left + x / width * (right - left)
        v = bottom + y / height * (top - bottom)
        o1, d1, t1 = view_cam.generate_ray(width, height, x, y)
        o2, d2, t2 = final_cam.generate_ray(W, H, u * W, v * H)
        assert (t1 > 0) == (t2 > 0)
        if t1 > 0:
            np.testing.assert_allclose(d1, d2, atol=2e-5)
            checked += 1
    assert checked > 10


def panorama_free_export(scene):
    warnings = Warnings()
    fields = export_scene(bpy.context.evaluated_depsgraph_get(), warnings).camera
    assert warnings == []
    return fields


def test_camera_motion_blur_matches_cycles(tmp_path):
    # A turning panoramic camera under a blocky environment: the blur smears the blocks along
    # the longitude as Cycles' (the panorama's axes turn with the camera's interpolated frame).
    def build(blur=True):
        scene = empty_scene(W, H)
        blocks = np.random.default_rng(1).uniform(0.05, 1.0, (8, 16, 3))
        env = np.repeat(np.repeat(blocks, 8, axis=0), 8, axis=1).astype(np.float32)
        world = world_image(load_image(env, directory=tmp_path))
        world.cycles.sampling_method = 'NONE'
        cam = pano_camera('EQUIRECTANGULAR', rotation=(1.3, 0.2, 0.3))
        cam.keyframe_insert("rotation_euler", frame=0)
        cam.rotation_euler = (1.3, 0.2, 1.1)
        cam.keyframe_insert("rotation_euler", frame=2)
        scene.frame_set(1)
        scene.render.use_motion_blur = blur
        return scene
    ours = render_to_array(build(), samples=128)
    ref = render_to_array(build(), "CYCLES", samples=128, **BOX_FILTER)
    assert_agree(ours, ref, "turning equirectangular camera")
    still = render_to_array(build(blur=False), samples=16)
    assert compare(ours, still)[1] > 0.02  # the blur is visible (4 %): the test can fail


def texture_coordinate_material(output):
    """Emission = the Texture Coordinate node's `output` (Camera scaled into 0..1)."""
    mat = bpy.data.materials.new(output)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out, em = nt.nodes.new("ShaderNodeOutputMaterial"), nt.nodes.new("ShaderNodeEmission")
    coords, mapping = nt.nodes.new("ShaderNodeTexCoord"), nt.nodes.new("ShaderNodeMapping")
    if output == "Camera":
        mapping.inputs["Scale"].default_value = (0.1, 0.1, 0.1)
        mapping.inputs["Location"].default_value = (0.5, 0.5, 0.5)
    nt.links.new(coords.outputs[output], mapping.inputs[0])
    nt.links.new(mapping.outputs[0], em.inputs["Color"])
    nt.links.new(em.outputs[0], out.inputs["Surface"])
    return mat


@pytest.mark.parametrize("output", ["Window", "Camera"])
def test_window_and_camera_coordinates_match_cycles(output):
    # Cycles' panorama camera space (x forward, y left, z up) and its Window (the direction's
    # (u, v)), on an emitting sphere around the camera: per pixel.
    def build():
        scene = empty_scene(W, H)
        uv_sphere("s", 4.0, texture_coordinate_material(output), segments=64, location=(0.3, 0.2, -0.1))
        pano_camera('EQUIRECTANGULAR')
        return scene
    ours = render_to_array(build(), samples=16)
    ref = render_to_array(build(), "CYCLES", samples=16, **BOX_FILTER)
    diff = np.abs(ours - ref)[..., :3].max(-1)
    assert diff.max() < 0.01, diff.max()
    assert ref[..., :3].std() > 0.05  # the coordinates vary over the image
