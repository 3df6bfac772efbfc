"""Panoramic cameras through the core module: the direction of each raster point against the
projections written out here from Cycles' definitions (equirectangular with its latitude and
longitude range, equiangular cube face, mirror ball, the three fisheyes with their fitted
sensor, central cylindrical), the camera's axes, clipping along the ray, no ray outside a
fisheye's circle, depth of field on the focal sphere, the Depth pass (a panorama's distance)
and input validation."""
import math

import numpy as np
import pytest

from core_scenes import add_object, core, look_at_matrix, run_session, uv_sphere

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif(not hasattr(pc.Camera, "panorama_type"), reason="core without panoramas")]

EYE = np.array([0.5, -3.0, 1.5])
TARGET = np.array([1.0, 2.0, 1.8])
W, H = 64, 32


def pano(ptype, **fields):
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix(EYE, TARGET)
    cam.type = "PANO"
    cam.panorama_type = ptype
    cam.clip_start, cam.clip_end = 0.0, 1000.0
    for k, v in fields.items():
        setattr(cam, k, v)
    return cam


def axes(cam):
    m = np.asarray(cam.matrix_world, np.float64)
    return m[:3, 0], m[:3, 1], -m[:3, 2], m[:3, 3]  # right, up, forward, origin


def ray(cam, x, y, w=W, h=H, lens=None):
    o, d, t = cam.generate_ray(w, h, x, y, lens)
    return np.array(o), np.array(d), t


def local(cam, d):
    """A world direction in (right, up, forward) of the camera."""
    right, up, fwd, _ = axes(cam)
    return np.array([d @ right, d @ up, d @ fwd])


def angle_from_axis(cam, d):
    return math.acos(np.clip(local(cam, d)[2], -1.0, 1.0))


@pytest.mark.parametrize("ptype", ["EQUIRECTANGULAR", "EQUIANGULAR_CUBEMAP_FACE", "MIRRORBALL",
                                   "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID",
                                   "FISHEYE_LENS_POLYNOMIAL", "CENTRAL_CYLINDRICAL"])
def test_the_frame_centre_looks_forward_right_is_right_and_up_is_up(ptype):
    cam = pano(ptype, fisheye_polynomial=(0.0, -0.05, 0.0, 0.0, 0.0))
    _, d, t = ray(cam, W / 2, H / 2)
    assert t > 0
    np.testing.assert_allclose(local(cam, d), [0, 0, 1], atol=1e-5)
    _, d_right, _ = ray(cam, W / 2 + 4, H / 2)
    _, d_up, _ = ray(cam, W / 2, H / 2 + 4)
    assert local(cam, d_right)[0] > 0.05 and abs(local(cam, d_right)[1]) < 1e-5
    assert local(cam, d_up)[1] > 0.05 and abs(local(cam, d_up)[0]) < 1e-5


def test_equirectangular_longitude_and_latitude_ranges():
    lat0, lat1, lon0, lon1 = -0.4, 1.1, -2.5, 1.5
    cam = pano("EQUIRECTANGULAR", latitude_min=lat0, latitude_max=lat1, longitude_min=lon0,
               longitude_max=lon1, shift_x=0.05, shift_y=-0.1)
    rng = np.random.default_rng(3)
    for x, y in rng.random((40, 2)) * (W, H):
        u, v = x / W + 0.05, y / H - 0.1
        lon, lat = lon0 + (lon1 - lon0) * u, lat0 + (lat1 - lat0) * v  # lon: to the right
        want = [math.cos(lat) * math.sin(lon), math.sin(lat), math.cos(lat) * math.cos(lon)]
        _, d, _ = ray(cam, x, y)
        np.testing.assert_allclose(local(cam, d), want, atol=2e-5)


def test_equiangular_cube_face_spans_a_right_angle_evenly():
    cam = pano("EQUIANGULAR_CUBEMAP_FACE")
    for x in np.linspace(0.0, W, 9):
        _, d, _ = ray(cam, x, H / 2)
        # Equal steps of raster, equal steps of angle, 90 degrees across the frame.
        assert math.atan2(local(cam, d)[0], local(cam, d)[2]) == pytest.approx((x / W - 0.5) * math.pi / 2, abs=1e-5)


def test_mirror_ball_reflects_the_view_on_a_ball():
    cam = pano("MIRRORBALL")
    # At radius s of the ball's image the normal leans by asin(s); the reflected ray by twice that.
    for s in (0.1, 0.5, 0.9):
        _, d, t = ray(cam, W / 2 + s * W / 2, H / 2)
        assert t > 0
        assert angle_from_axis(cam, d) == pytest.approx(2 * math.asin(s), abs=1e-4)
        assert local(cam, d)[0] > 0
    assert ray(cam, 1.0, 1.0)[2] == 0.0  # a corner: off the ball, no ray


@pytest.mark.parametrize("fov", [math.pi, 3.8])
def test_fisheye_equidistant_angle_grows_with_radius_and_stops_at_the_circle(fov):
    cam = pano("FISHEYE_EQUIDISTANT", fisheye_fov=fov)
    for r in (0.0, 0.3, 0.7, 0.99):  # of the half-height: the circle fills the frame's height
        _, d, t = ray(cam, W / 2, H / 2 + r * H / 2)
        assert t > 0
        assert angle_from_axis(cam, d) == pytest.approx(r * fov / 2, abs=1e-4)
    # The circle is in units of the frame on each axis (an ellipse on a wide frame).
    assert ray(cam, W / 2 + 0.99 * W / 2, H / 2)[2] > 0
    assert ray(cam, W / 2, H - 0.05)[2] > 0 and ray(cam, W - 1, H - 1)[2] == 0.0


@pytest.mark.parametrize("fit, size", [("AUTO", (36.0, 24.0)), ("VERTICAL", (36.0, 24.0)),
                                       ("HORIZONTAL", (30.0, 50.0))])
def test_fisheye_equisolid_on_the_fitted_sensor(fit, size):
    lens, fov = 8.0, 3.3
    cam = pano("FISHEYE_EQUISOLID", fisheye_lens=lens, fisheye_fov=fov, sensor_fit=fit,
               sensor_width=size[0], sensor_height=size[1])
    # Cycles fits the sensor to the frame: the fitted side gets the sensor's size.
    if fit == "VERTICAL":
        sh = size[1]
        sw = sh * W / H
    else:
        sw = size[0]
        sh = sw * H / W
    rmax = 2 * lens * math.sin(fov / 4)
    for x, y in [(40.0, 20.0), (10.0, 25.0), (33.0, 3.0), (60.0, 30.0), (5.0, 2.0)]:
        du, dv = (x / W - 0.5) * sw, (y / H - 0.5) * sh
        r = math.hypot(du, dv)
        _, d, t = ray(cam, x, y)
        if r > rmax:
            assert t == 0.0
            continue
        assert t > 0
        assert angle_from_axis(cam, d) == pytest.approx(2 * math.asin(r / (2 * lens)), abs=1e-4)
        loc = local(cam, d)
        assert math.atan2(loc[1], loc[0]) == pytest.approx(math.atan2(dv, du), abs=1e-4)


def test_fisheye_lens_polynomial():
    k = (0.01, -0.09, 0.0004, -2e-5, 1e-7)
    cam = pano("FISHEYE_LENS_POLYNOMIAL", fisheye_polynomial=k, fisheye_fov=2.5,
               sensor_width=36.0)
    sw, sh = 36.0, 36.0 * H / W
    seen = blocked = 0
    for x, y in np.random.default_rng(5).random((60, 2)) * (W, H):
        du, dv = (x / W - 0.5) * sw, (y / H - 0.5) * sh
        r = math.hypot(du, dv)
        theta = -(k[0] + k[1] * r + k[2] * r**2 + k[3] * r**3 + k[4] * r**4)
        _, d, t = ray(cam, x, y)
        if abs(theta) > 1.25:
            assert t == 0.0
            blocked += 1
            continue
        seen += 1
        assert angle_from_axis(cam, d) == pytest.approx(abs(theta), abs=2e-4)
    assert seen > 5 and blocked > 5


def test_central_cylindrical_heights_over_the_radius():
    cam = pano("CENTRAL_CYLINDRICAL", central_cylindrical_range_u_min=-1.0,
               central_cylindrical_range_u_max=2.0, central_cylindrical_range_v_min=-0.5,
               central_cylindrical_range_v_max=1.5, central_cylindrical_radius=2.0)
    for x, y in np.random.default_rng(7).random((30, 2)) * (W, H):
        u, v = x / W, y / H
        theta, z = -1.0 + 3.0 * u, (-0.5 + 2.0 * v) / 2.0  # angle to the right, height / radius
        want = np.array([math.sin(theta), z, math.cos(theta)])
        _, d, _ = ray(cam, x, y)
        np.testing.assert_allclose(local(cam, d), want / np.linalg.norm(want), atol=2e-5)


def test_clipping_is_along_the_ray():
    cam = pano("EQUIRECTANGULAR", clip_start=0.5, clip_end=20.0)
    for x, y in ((5.0, 5.0), (40.0, 28.0)):
        o, d, t = ray(cam, x, y)
        np.testing.assert_allclose(o, EYE + d * 0.5, atol=1e-5)
        assert t == pytest.approx(19.5)


def test_depth_of_field_focuses_on_a_sphere():
    cam = pano("EQUIRECTANGULAR", aperture_size=0.1, focus_distance=4.0)
    rng = np.random.default_rng(2)
    for x, y in ((20.0, 16.0), (50.0, 6.0)):
        _, d0, _ = ray(cam, x, y)
        focal = EYE + d0 * 4.0  # where the pinhole ray meets the focal sphere
        spread = 0.0
        for u in rng.random((32, 2)):
            o, d, _ = ray(cam, x, y, lens=(float(u[0]), float(u[1])))
            # The lens point lies within the aperture, across the ray; the ray meets the focus.
            assert np.linalg.norm(o - EYE) <= 0.1 + 1e-5
            assert abs((o - EYE) @ d0) < 1e-5
            t = (focal - o) @ d
            assert np.linalg.norm(o + d * t - focal) < 1e-4
            spread = max(spread, np.linalg.norm(o - EYE))
        assert spread > 0.05


def enclosing_sphere_scene(cam, radius=5.0):
    s = pc.Scene()
    grey = s.add_material("grey", (0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
    pos, tris, nrm = uv_sphere(radius, center=tuple(EYE), inward=True)
    add_object(s, pos, tris, grey, nrm)
    s.set_camera(cam)
    return s


def test_depth_pass_is_the_distance_and_no_ray_pixels_are_black():
    # Inside a sphere around the camera: a panorama's Depth is the distance (Cycles'
    # camera_z_depth), equal to the Position pass's distance; outside the fisheye circle the
    # pixels get no ray: black and opaque, as in Cycles.
    cam = pano("FISHEYE_EQUIDISTANT", fisheye_fov=math.pi)
    sess = run_session(pc, enclosing_sphere_scene(cam), W, H, 1, threads=2, passes=["Depth", "Position"])
    film = sess.film()
    depth = sess.film_pass("Depth")[..., 0]
    dist = np.linalg.norm(sess.film_pass("Position") - EYE, axis=-1)
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot((xx + 0.5) / W - 0.5, (yy + 0.5) / H - 0.5) * 2
    inside, outside = r < 0.9, r > 1.1
    np.testing.assert_allclose(depth[inside], dist[inside], rtol=1e-4)
    assert np.all(np.abs(depth[inside] - 5.0) < 0.05)  # the tessellated sphere
    assert np.all(film[inside][:, :3] > 0.3)
    np.testing.assert_array_equal(film[outside][:, :3], 0.0)
    np.testing.assert_array_equal(film[outside][:, 3], 1.0)


@pytest.mark.parametrize("field, value, match", [
    ("fisheye_fov", 0.0, "fisheye_fov"),
    ("fisheye_fov", float("nan"), "finite"),
    ("fisheye_lens", -1.0, "fisheye_lens"),
    ("latitude_min", float("inf"), "finite"),
    ("central_cylindrical_radius", 0.0, "radius"),
    ("pano_viewplane", (0.0, 0.0, 0.0, 1.0), "pano_viewplane"),
])
def test_bad_panorama_fields_are_value_errors(field, value, match):
    cam = pano("EQUIRECTANGULAR")
    setattr(cam, field, value)
    s = pc.Scene()
    with pytest.raises(ValueError, match=match):
        s.set_camera(cam)


def test_unknown_panorama_type_and_wrong_polynomial_length():
    cam = pc.Camera()
    with pytest.raises(ValueError, match="panorama_type"):
        cam.panorama_type = "FISHEYE"
    with pytest.raises(ValueError, match="5 values"):
        cam.fisheye_polynomial = (1.0, 2.0)


def test_bvh_view_counts_nothing_outside_the_circle():
    cam = pano("FISHEYE_EQUIDISTANT", fisheye_fov=math.pi)
    sess = run_session(pc, enclosing_sphere_scene(cam), W, H, 1, threads=2, debug_view="bvh")
    nodes = sess.film_pass("BVH Nodes")[..., 0]
    yy, xx = np.mgrid[0:H, 0:W]
    r = np.hypot((xx + 0.5) / W - 0.5, (yy + 0.5) / H - 0.5) * 2
    assert np.all(nodes[r < 0.9] > 0)
    np.testing.assert_array_equal(nodes[r > 1.1], 0.0)


def test_autofocus_of_a_panorama_takes_the_distance():
    # A panorama focuses on a sphere: autofocus sets its radius, the distance to the surface.
    cam = pano("EQUIRECTANGULAR", aperture_size=0.05, focus_distance=1.0)
    cam.use_autofocus = True
    cam.autofocus_x, cam.autofocus_y = 0.3, 0.7
    s = enclosing_sphere_scene(cam)
    s.commit()
    o, d, _ = ray(cam, 0.3 * W, 0.7 * H)
    (t,), _, _, _ = s.intersect(np.array([o], np.float32), np.array([d], np.float32))
    st = pc.RenderSettings()
    st.width, st.height, st.samples = W, H, 1
    stats = pc.Session(s, st).stats()
    assert stats["autofocus"] == "hit"
    assert stats["focus_distance"] == pytest.approx(float(np.linalg.norm(np.array(o) + np.array(d) * t - EYE)), rel=1e-5)
    assert stats["focus_distance"] == pytest.approx(5.0, abs=0.05)
