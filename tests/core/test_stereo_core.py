"""Spherical stereo in the core's camera (Camera::spherical_stereo; docs/design/stereo.md): each
ray of a panorama (in its own space, z up) or of a perspective camera (in the world, z up) starts
half the interocular distance to its own side, -left +right, and turns toward the point at the
convergence distance along its mono direction (not at all: parallel); pole merge fades the
offset between two altitudes. Checked against Cycles' spherical_stereo_transform written out
here in float64, pixel by pixel; an interocular distance of 0 renders the mono image bit for
bit; the caustic light paths turn off with the reason."""
import math

import numpy as np
import pytest

from core_scenes import core, look_at_matrix
from test_caustic_light_paths import LAMP_CAM, lens_renders, lensed, mirror_scene

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif(not hasattr(pc.Camera, "stereo_eye"), reason="core without stereo")]

EYE = np.array([0.5, -3.0, 1.5])
W, H = 64, 32
IOD, CONV = 0.3, 2.5  # large, to see the offsets


def camera(kind="EQUIRECTANGULAR", target=(1.0, 2.0, 1.8), eye="NONE", **fields):
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix(EYE, np.array(target))
    if kind == "PERSP":
        cam.type = "PERSP"
    else:
        cam.type, cam.panorama_type = "PANO", kind
    cam.clip_start, cam.clip_end = 0.1, 1000.0
    cam.stereo_eye = eye
    cam.interocular_distance, cam.convergence_distance = IOD, CONV
    for k, v in fields.items():
        setattr(cam, k, v)
    return cam


def ray(cam, x, y):
    o, d, t = cam.generate_ray(W, H, x, y, None)
    return np.array(o, np.float64), np.array(d, np.float64), t


def pano_axes(cam):
    """World axes of Cycles' panorama space: x forward, y left, z up."""
    m = np.asarray(cam.matrix_world, np.float64)
    return np.stack([-m[:3, 2], -m[:3, 0], m[:3, 1]]), m[:3, 3]


def cycles_stereo(P, D, offset, conv, pole=None):
    """Cycles' spherical_stereo_transform (kernel/camera/projection.h) in float64."""
    if pole is not None:
        lo, hi = pole
        alt = abs(math.asin(np.clip(D[2], -1.0, 1.0)))
        if alt > hi:
            offset = 0.0
        elif alt > lo:
            offset *= math.cos((alt - lo) / (hi - lo) * math.pi / 2)
    side = np.cross(D, [0.0, 0.0, 1.0])
    s = side / np.linalg.norm(side) * offset
    P = P + s
    if math.isfinite(conv):
        D = conv * D - s
        D = D / np.linalg.norm(D)
    return P, D


def expected_pano(cam, eye, x, y, raw=None, pole=None, conv=CONV):
    """The stereo ray of panorama `cam` at (x, y) from its mono ray: the mono direction in
    panorama space (raw: the map's un-normalised direction from it), Cycles' transform, back to
    the world, clipped along the ray."""
    mono = camera(cam.panorama_type, eye="NONE", **_pano_fields(cam))
    mono.matrix_world = cam.matrix_world
    _, d0, _ = ray(mono, x, y)
    axes, origin = pano_axes(cam)
    D = axes @ d0
    if raw is not None:
        D = raw(D)
    off = (-0.5 if eye == "LEFT" else 0.5) * IOD
    P, D = cycles_stereo(np.zeros(3), D, off, conv, pole)
    dw = axes.T @ D
    dw /= np.linalg.norm(dw)
    return origin + axes.T @ P + dw * cam.clip_start, dw


def _pano_fields(cam):
    keys = ("central_cylindrical_range_u_min", "central_cylindrical_range_u_max",
            "central_cylindrical_range_v_min", "central_cylindrical_range_v_max",
            "central_cylindrical_radius", "latitude_min", "latitude_max")
    return {k: getattr(cam, k) for k in keys}


PIXELS = [(0.5, 0.5), (10.3, 7.9), (31.9, 16.1), (45.2, 25.7), (63.5, 31.5), (20.0, 2.2)]


@pytest.mark.parametrize("eye", ["LEFT", "RIGHT"])
def test_equirectangular_rays_follow_cycles_formula(eye):
    cam = camera(eye=eye)
    for x, y in PIXELS:
        o, d, t = ray(cam, x, y)
        want_o, want_d = expected_pano(cam, eye, x, y)
        np.testing.assert_allclose(o, want_o, atol=2e-5)
        np.testing.assert_allclose(d, want_d, atol=2e-5)
        assert t > 0


def test_the_left_eye_is_left_the_right_eye_right_and_both_look_at_the_convergence_point():
    target = (1.0, 2.0, 1.5)  # level: the frame's centre ray is horizontal
    m = look_at_matrix(EYE, np.array(target)).astype(np.float64)
    right, fwd = m[:3, 0], -m[:3, 2]
    for eye, sign in (("LEFT", -1.0), ("RIGHT", 1.0)):
        for kind in ("EQUIRECTANGULAR", "PERSP"):
            cam = camera(kind, target=target, eye=eye, clip_start=0.0)
            o, d, _ = ray(cam, W / 2, H / 2)
            np.testing.assert_allclose(o - EYE, sign * 0.5 * IOD * right, atol=2e-6)
            # toed in: the ray passes through the mono centre ray's point at CONV
            p = EYE + CONV * fwd
            t = (p - o) @ d
            np.testing.assert_allclose(o + t * d, p, atol=2e-5)


def test_parallel_convergence_keeps_the_mono_directions():
    mono = camera()
    cam = camera(eye="RIGHT", convergence_distance=math.inf)
    for x, y in PIXELS:
        o, d, _ = ray(cam, x, y)
        o0, d0, _ = ray(mono, x, y)
        np.testing.assert_allclose(d, d0, atol=1e-6)  # (up to normalising twice)
        assert abs(np.linalg.norm(o - o0) - 0.5 * IOD) < 2e-5


def test_the_cylinders_unnormalised_direction_converges_as_cycles():
    # Central cylindrical: Cycles' map gives (cos, sin, z), not unit; its stereo scales that by
    # the convergence distance (the convergence point lies farther up the cylinder's wall).
    fields = dict(central_cylindrical_range_v_min=-1.5, central_cylindrical_range_v_max=1.5)
    cam = camera("CENTRAL_CYLINDRICAL", eye="LEFT", **fields)

    def raw(D):
        return D / math.hypot(D[0], D[1])
    for x, y in PIXELS:
        o, d, _ = ray(cam, x, y)
        want_o, want_d = expected_pano(cam, "LEFT", x, y, raw=raw)
        np.testing.assert_allclose(o, want_o, atol=2e-5)
        np.testing.assert_allclose(d, want_d, atol=2e-5)


def test_pole_merge_fades_the_offset_toward_the_poles():
    lo, hi = math.radians(30.0), math.radians(60.0)
    cam = camera(eye="RIGHT", use_pole_merge=True, pole_merge_angle_from=lo, pole_merge_angle_to=hi,
                 target=(0.5, 2.0, 1.5), clip_start=0.0)  # level: the rows' altitudes are the latitudes
    mono = camera(target=(0.5, 2.0, 1.5), clip_start=0.0)
    seen = set()
    for y in np.linspace(0.5, H - 0.5, 24):
        x = 13.7
        o, d, _ = ray(cam, x, y)
        want_o, want_d = expected_pano(cam, "RIGHT", x, y, pole=(lo, hi))
        np.testing.assert_allclose(o, want_o, atol=2e-5)
        np.testing.assert_allclose(d, want_d, atol=2e-5)
        alt = abs(math.asin(ray(mono, x, y)[1][2]))
        o0 = ray(mono, x, y)[0]
        off = np.linalg.norm(o - o0)
        if alt > hi:
            assert off < 1e-5
            seen.add("merged")
        elif alt < lo:
            assert abs(off - 0.5 * IOD) < 1e-4
            seen.add("full")
        else:
            assert 1e-4 < off < 0.5 * IOD - 1e-4
            seen.add("fading")
    assert seen == {"merged", "full", "fading"}


def test_perspective_spherical_stereo_moves_each_ray_in_the_world():
    # Cycles' perspective spherical stereo works on the world direction, world z up.
    cam = camera("PERSP", eye="LEFT", lens=20.0)
    mono = camera("PERSP", lens=20.0)
    for x, y in PIXELS:
        o, d, _ = ray(cam, x, y)
        _, d0, _ = ray(mono, x, y)
        P, D = cycles_stereo(EYE.copy(), d0, -0.5 * IOD, CONV)
        m = np.asarray(cam.matrix_world, np.float64)
        cos = d0 @ -m[:3, 2]
        np.testing.assert_allclose(d, D, atol=2e-5)
        np.testing.assert_allclose(o, P + D * (0.1 / cos), atol=2e-5)


def test_an_orthographic_camera_ignores_it():
    cam = camera("PERSP", eye="LEFT")
    cam.type, cam.ortho_scale = "ORTHO", 4.0
    mono = camera("PERSP")
    mono.type, mono.ortho_scale = "ORTHO", 4.0
    for x, y in PIXELS:
        for a, b in zip(ray(cam, x, y), ray(mono, x, y)):
            np.testing.assert_array_equal(a, b)


def test_interocular_zero_renders_the_mono_image_bit_for_bit():
    s = mirror_scene()
    mono = lensed(LAMP_CAM, 3.0, aperture=0.0)
    mono.type, mono.panorama_type = "PANO", "EQUIRECTANGULAR"
    zero = lensed(LAMP_CAM, 3.0, aperture=0.0)
    zero.type, zero.panorama_type = "PANO", "EQUIRECTANGULAR"
    zero.stereo_eye, zero.interocular_distance = "LEFT", 0.0
    a, _ = lens_renders(s, mono, 2, (1,), 24, 16)
    b, _ = lens_renders(s, zero, 2, (1,), 24, 16)
    assert np.array_equal(a, b)
    zero.interocular_distance = 0.065
    c, _ = lens_renders(s, zero, 2, (1,), 24, 16)
    assert not np.array_equal(a, c)


def test_caustic_light_paths_stay_off_with_spherical_stereo_and_say_why():
    s = mirror_scene()
    cam = lensed(LAMP_CAM, 3.0, aperture=0.0)
    cam.type, cam.panorama_type = "PANO", "EQUIRECTANGULAR"
    _, st = lens_renders(s, cam, 2, (1,), 24, 16, caustic_light_paths=1.0)
    assert st["caustics"] == "on"
    cam.stereo_eye = "RIGHT"
    _, st = lens_renders(s, cam, 2, (1,), 24, 16, caustic_light_paths=1.0)
    assert st["caustics"].startswith("off: not with spherical stereo")
    _, st = lens_renders(s, cam, 2, (1,), 24, 16, caustic_light_paths_auto=True)
    assert "spherical stereo" in st["caustics"]


def test_bad_stereo_values_are_refused():
    s = mirror_scene()
    for field, value in (("interocular_distance", -0.1), ("interocular_distance", math.nan),
                         ("convergence_distance", 0.0), ("pole_merge_angle_to", math.inf)):
        cam = camera(eye="LEFT")
        setattr(cam, field, value)
        with pytest.raises(ValueError):
            s.set_camera(cam)
    with pytest.raises(ValueError):
        camera().stereo_eye = "CENTRE"
