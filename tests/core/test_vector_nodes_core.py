"""The vector, colour and traced shader ops through the core module alone (issue 21): analytic
properties (a quarter turn about Z, camera space along the view axis, Window at the frame's
centre, occlusion in the open and over a floor, blackbody and spectral hues) and validation of
the ops' arguments. The per-pixel comparisons with Cycles are in test_vector_nodes.py."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, render

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def emission_of(value_ops, size=8, extra=None, cam=None):
    """The film of a 4x4 quad at z = 0 (seen from z = 4, straight down) whose emission is the
    register the ops leave in 10 (their own registers from 0)."""
    s = pc.Scene()
    prog = list(value_ops) + [("closure", "emission", None, {"color": 10})]
    m = s.add_shader("m", prog)
    pos, tris = quad((-2, -2, 0), (4, 0, 0), (0, 4, 0))
    add_object(s, pos, tris, m)
    for p, t in extra or ():
        add_object(s, p, t, s.add_material("grey", (0.5, 0.5, 0.5)))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(cam or camera(pc, (0.0, 0.0, 4.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
    # One sample at each pixel's centre (the smallest box filter).
    img, stats = render(pc, s, size, size, samples=1, max_bounces=0, filter_width=0.01)
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
