"""The vector, colour and traced shader ops through the core module alone (issue 21): analytic
properties (a quarter turn about Z, camera space along the view axis, Window at the frame's
centre, occlusion in the open and over a floor, blackbody and spectral hues) and validation of
the ops' arguments. The per-pixel comparisons with Cycles are in test_vector_nodes.py."""
import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, emission_film, quad, render

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def emission_of(value_ops, size=8, extra=None, cam=None):
    """The film of a 4x4 quad at z = 0 (seen from z = 4, straight down) whose emission is the
    register the ops leave in 10 (their own registers from 0)."""
    img, stats = emission_film(pc, lambda s: value_ops, 10, size, extra or (), cam)
    assert stats["nonfinite_samples"] == 0
    return img[..., :3]


def test_vector_rotate_quarter_turn_about_z():
    img = emission_of([("const", 0, (1.0, 0.25, 0.5, 0.0)), ("const", 1, (0.0, 0.0, 0.0, 0.0)),
                       ("const", 2, (0.0, 0.0, 0.0, 0.0)), ("const", 3, (np.pi / 2,)),
                       ("vector_rotate", 4, 0, 1, 2, 3, 2, "Z_AXIS", False),
                       ("const", 5, (1.0, 1.0, 1.0, 0.0)),
                       ("vector_math", 10, 4, 5, 5, 3, "ADD")])  # + 1: stays emissive
    assert np.allclose(img[4, 4], (1.0 - 0.25, 1.0 + 1.0, 1.0 + 0.5), atol=1e-5), img[4, 4]


def test_camera_space_looks_down_plus_z_and_window_is_centred():
    cam_z = emission_of([("camera_coords", 10, "CAMERA")])
    # Cycles' camera space: +z forward, so the quad 4 units ahead reads z = 4 everywhere.
    assert np.allclose(cam_z[..., 2], 4.0, atol=1e-4)
    window = emission_of([("camera_coords", 10, "WINDOW")], size=8)
    # Pixel centres at (i + 0.5) / 8 across the frame, x to the right (image row 0 = bottom).
    xs = (np.arange(8) + 0.5) / 8
    assert np.allclose(window[0, :, 0], xs, atol=2e-3), window[0, :, 0]
    assert np.allclose(window[:, 0, 1], xs, atol=2e-3), window[:, 0, 1]


def test_camera_data_is_the_shading_point_in_camera_space():
    """Camera Data (Cycles' svm_node_camera): View Z Depth is 4 over the quad 4 units ahead,
    View Distance is the camera-space point's length and View Vector its direction (checked
    against Texture Coordinate's Camera, itself compared with Cycles)."""
    shift = [("const", 11, (5.0, 5.0, 5.0, 0.0))]  # (emission stays positive)

    def value(which):
        return emission_of([("camera_data", 12, which)] + shift + [("vector_math", 10, 12, 11, 11, 3, "ADD")]) - 5.0
    point = emission_of([("camera_coords", 12, "CAMERA")] + shift + [("vector_math", 10, 12, 11, 11, 3, "ADD")]) - 5.0
    depth, dist, vec = value("VIEW_Z_DEPTH"), value("VIEW_DISTANCE"), value("VIEW_VECTOR")
    assert np.allclose(depth, 4.0, atol=1e-4)
    assert np.allclose(dist[..., 0], np.linalg.norm(point, axis=-1), atol=1e-4)
    assert np.all(dist >= depth - 1e-5) and dist.max() > 4.3  # off the axis: farther than the depth
    assert np.allclose(vec * dist[..., :1], point, atol=1e-4)


def test_camera_data_past_a_mirror_reads_the_point_not_the_ray():
    """Seen in a mirror (z = 0, the camera 4 above it), a plane at z = 8 is met at (3 x, 3 y, 8)
    by the camera ray that reflected at (x, y, 0): its View Distance is sqrt(9 (x^2 + y^2) + 16)
    = sqrt(9 d^2 - 128) for the mirror point's own distance d, not the path's length 3 d."""
    def film(mirror):
        s = pc.Scene()
        emit = s.add_shader("e", [("camera_data", 0, "VIEW_DISTANCE"),
                                  ("closure", "emission", None, {"color": 0})])
        if mirror:
            m = s.add_shader("mirror", closure("glossy", color=(1.0, 1.0, 1.0), roughness=0.0))
            add_object(s, *quad((-10, -10, 0), (20, 0, 0), (0, 20, 0)), m)
            add_object(s, *quad((-20, -20, 8), (40, 0, 0), (0, 40, 0)), emit)
        else:
            add_object(s, *quad((-10, -10, 0), (20, 0, 0), (0, 20, 0)), emit)
        s.set_world_color((0.0, 0.0, 0.0))
        s.set_camera(camera(pc, (0.0, 0.0, 4.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
        img, stats = render(pc, s, 8, 8, samples=1, max_bounces=2, filter_width=0.01)
        assert stats["nonfinite_samples"] == 0
        return img[..., 0]
    d, seen = film(False), film(True)
    assert np.allclose(seen, np.sqrt(9.0 * d ** 2 - 128.0), rtol=1e-3), (seen, d)


def test_camera_data_in_lights_and_volumes_reads_the_scene_camera():
    """Programs no camera ray reaches: a point light whose strength is its View Distance shines
    |light - camera| times the plain light; a world Volume whose density is View Z Depth has
    that depth at every point (the camera 4 above z = 0, looking down)."""
    from test_core_lights import H_CAM, W, check, expected, plane_scene, point_radiance
    light = np.array([0.3, -0.2, 1.0])  # (3.02 from the camera, 1.06 from the origin)
    s = plane_scene()
    s.add_point_light(light, (10.0, 10.0, 10.0), shader=[("camera_data", 0, "VIEW_DISTANCE"),
                                                          ("closure", "emission", None, {"color": 0})])
    img, _ = render(pc, s, W, W, samples=16)
    r = np.linalg.norm(light - (0.0, 0.0, H_CAM))
    check(img, expected(lambda p: point_radiance(p, light, 10.0) * r), tol=0.005)

    s = pc.Scene()
    s.set_world_volume([("camera_data", 0, "VIEW_Z_DEPTH"), ("closure", "volume", None, {"sigma_s": 0})])
    s.set_camera(camera(pc, (0.0, 0.0, 4.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), s.add_material("grey", (0.5, 0.5, 0.5)))
    s.commit()
    for p in ((0.0, 0.0, 1.0), (0.5, -0.3, -0.5), (-0.2, 0.7, 3.5)):
        assert s.medium_at(-1, 0, p)["sigma_s"] == pytest.approx((4.0 - p[2],) * 3, rel=1e-5)


def test_ambient_occlusion_in_the_open_and_over_a_floor():
    def ops(inside, only_local):
        return [("const", 0, (1.0, 1.0, 1.0, 1.0)), ("const", 1, (0.5,)),
                ("ambient_occlusion", 10, 0, 1, None, 8, inside, only_local, "AO")]
    assert np.allclose(emission_of(ops(False, False)), 1.0)
    # Inside turns the rays below the quad, to a floor h = 0.1 away that reaches beyond the
    # AO distance d = 0.5 around the centre: a cosine-distributed ray escapes it only within
    # cos < h / d, with probability (h / d)^2 = 0.04. Only Local ignores that other object.
    floor = quad((-3, -3, -0.1), (6, 0, 0), (0, 6, 0))
    assert np.allclose(emission_of(ops(False, False), extra=[floor]), 1.0)
    img = emission_of(ops(True, False), size=16, extra=[floor])
    escaped = img[4:12, 4:12, 0].mean()  # 512 rays: 0.04 +- 0.009
    assert abs(escaped - 0.04) < 0.03, escaped
    assert np.allclose(emission_of(ops(True, True), extra=[floor]), 1.0)


def test_blackbody_and_wavelength_hues():
    def colour(op, x):
        return emission_of([("const", 0, (x,)), (op, 10, 0)], size=2)[0, 0]
    warm, cool = colour("blackbody", 2000.0), colour("blackbody", 11000.0)
    assert warm[0] > warm[1] > warm[2] and cool[2] > cool[0]
    green, red = colour("wavelength", 530.0), colour("wavelength", 640.0)
    assert green[1] > green[0] and green[1] > green[2] and red[0] > red[1]
    assert np.all(colour("wavelength", 900.0) == 0.0)


@pytest.mark.parametrize("op", [
    ("vector_rotate", 1, 0, 0, 0, 0, 0, "SIDEWAYS", False),
    ("vector_transform", 1, 0, "POINT", "WORLD", "NOWHERE"),
    ("camera_coords", 1, "SCREEN"),
    ("tangent", 1, "W", 0),
    ("tangent", 1, "UV_MAP", 9),
    ("tex_gabor", 1, 0, 0, 0, 0, 0, 0, "4D", "VALUE"),
    ("ambient_occlusion", 1, 0, 0, None, -1, False, False, "AO"),
    ("blackbody", 1),
])
def test_bad_vector_ops_are_rejected(op):
    s = pc.Scene()
    with pytest.raises(ValueError):
        s.add_shader("bad", [("const", 0, (1.0,)), op])
