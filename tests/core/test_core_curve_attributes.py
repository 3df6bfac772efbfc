"""Curve attributes in the core (issue 23): point-domain values linear between a segment's keys
at the hit's segment parameter (Cycles' curve_attribute_float4 on curve keys), curve-domain
values held per strand, sets a strand lacks reading 0."""
import numpy as np
import pytest

from core_scenes import camera, core, render

pytestmark = pytest.mark.sanitize

KEYS_X = np.array([0.5, 0.8, 1.9, 2.5])  # unevenly spaced: each segment has its own scale
KEY_R = np.array([0.0, 1.0, 0.2, 0.9])


def _strand_scene(pc, program, shape="thick"):
    s = pc.Scene()
    m = s.add_shader("attr", program)
    pts = np.column_stack([KEYS_X, np.zeros(4), np.zeros(4)]).astype(np.float32)
    point = np.column_stack([KEY_R, np.full(4, 0.5), np.zeros(4), np.ones(4)]).astype(np.float32)
    extra = {"shape": "ribbon", "subdivisions": 5} if shape == "ribbon" else {}
    # uv set 3 per point: (R, 1 - R) at the keys.
    uvs = np.column_stack([KEY_R, 1.0 - KEY_R]).astype(np.float32)
    s.add_curves(pts, np.array([0, 4]), np.full(4, 0.1, np.float32), m, curve_type="poly",
                 point_attributes={0: point}, strand_attributes={1: np.float32([[0.25, 0.5, 0.75, 1.0]])},
                 point_uvs={3: uvs}, **extra)
    s.set_camera(camera(pc, (1.5, -4.0, 0.0), (1.5, 0.0, 0.0), lens=50.0))
    s.commit()
    return s


def _segment_parameter(x, shape):
    """The strand's key coordinate (segment k + parameter t) at world x: poly pieces are the
    segments themselves; ribbons are Catmull-Rom through the keys (clamped ends), cut into 5
    straight quads per segment, so x is linear between those cuts."""
    if shape != "ribbon":
        return np.interp(x, KEYS_X, np.arange(4.0))
    n, xs, ss = len(KEYS_X), [], []
    for k in range(n - 1):
        a, b, c, d = KEYS_X[max(k - 1, 0)], KEYS_X[k], KEYS_X[k + 1], KEYS_X[min(k + 2, n - 1)]
        for t in np.linspace(0.0, 1.0, 6)[:-1]:
            xs.append(0.5 * ((-t**3 + 2 * t**2 - t) * a + (3 * t**3 - 5 * t**2 + 2) * b
                             + (-3 * t**3 + 4 * t**2 + t) * c + (t**3 - t**2) * d))
            ss.append(k + t)
    return np.interp(x, xs + [KEYS_X[-1]], ss + [n - 1.0])


@pytest.mark.parametrize("shape", ["thick", "ribbon"])
def test_point_attributes_are_linear_between_keys(shape):
    """Seen through emission on a straight poly strand (its segment parameter linear in x):
    set 0 (per point) follows the keys' values piecewise linearly in x, set 1 (per strand) is
    constant, set 2 (absent) reads 0, uv set 3 (per point) is interpolated as set 0. The world x of each pixel comes from a second render."""
    pc = core()
    emit = lambda reg: ("closure", "emission", None, {"color": reg})  # noqa: E731
    point = _strand_scene(pc, [("attribute", 0, 0, "COLOR"), emit(0)], shape)
    strand = _strand_scene(pc, [("attribute", 0, 1, "COLOR"), emit(0)], shape)
    absent = _strand_scene(pc, [("attribute", 0, 2, "COLOR"), emit(0)], shape)
    where = _strand_scene(pc, [("position", 0), emit(0)], shape)
    cover = _strand_scene(pc, [("const", 0, (1.0, 1.0, 1.0, 1.0)), emit(0)], shape)
    size = (96, 16)
    img, _ = render(pc, point, *size, 16)
    x_img, _ = render(pc, where, *size, 16)
    c_img, _ = render(pc, cover, *size, 16)
    row = 8  # across the strand's middle
    x = x_img[row, :, 0]
    # Whole pixels on the strand, away from its ends.
    on = (c_img[row, :, 0] > 0.999) & (x > KEYS_X[0] + 0.05) & (x < KEYS_X[-1] - 0.05)
    # Pixels across a key average both segments' slopes: left out.
    on &= np.min(np.abs(x[:, None] - KEYS_X[None, 1:-1]), axis=1) > 0.04
    assert on.sum() > 40
    expected = np.interp(_segment_parameter(x[on], shape), np.arange(4.0), KEY_R)
    np.testing.assert_allclose(img[row, on, 0], expected, atol=0.02)
    np.testing.assert_allclose(img[row, on, 1], 0.5, atol=0.01)
    uv = _strand_scene(pc, [("uv", 0, 3), emit(0)], shape)
    uv_img, _ = render(pc, uv, *size, 16)
    np.testing.assert_allclose(uv_img[row, on, 0], expected, atol=0.02)
    np.testing.assert_allclose(uv_img[row, on, 1], 1.0 - expected, atol=0.02)
    s_img, _ = render(pc, strand, *size, 4)
    np.testing.assert_allclose(s_img[row, on, :3], np.tile([0.25, 0.5, 0.75], (on.sum(), 1)), atol=0.01)
    a_img, _ = render(pc, absent, *size, 4)
    assert np.all(a_img[row, :, :3] == 0.0)


def test_point_attributes_of_a_bad_shape_are_refused():
    pc = core()
    pts = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.float32)
    for bad in ({0: np.zeros((2, 4), np.float32)}, {0: np.zeros((3, 3), np.float32)},
                {8: np.zeros((3, 4), np.float32)}):
        with pytest.raises(ValueError):
            pc.Scene().add_curves(pts, np.array([0, 3]), None, point_attributes=bad)
    for bad in ({0: np.zeros((2, 2), np.float32)}, {0: np.zeros((3, 4), np.float32)},
                {-1: np.zeros((3, 2), np.float32)}):
        with pytest.raises(ValueError):
            pc.Scene().add_curves(pts, np.array([0, 3]), None, point_uvs=bad)
    # Non-finite values read 0; strands left out (too short) leave the others' values alone.
    s = pc.Scene()
    m = s.add_shader("attr", [("attribute", 0, 0, "COLOR"), ("closure", "emission", None, {"color": 0})])
    vals = np.array([[np.nan, 1, 1, 1], [1, 1, 1, 1], [0, 0, 0, 0], [0, 1, 0, 1], [0, 1, 0, 1]], np.float32)
    s.add_curves(np.array([[0, 0, 0], [1, 0, 0], [5, 0, 0], [0, 0, 0.5], [1, 0, 0.5]], np.float32),
                 np.array([0, 2, 3, 5]), np.full(5, 0.1, np.float32), m, point_attributes={0: vals})
    s.set_camera(camera(pc, (0.5, -4.0, 0.25), (0.5, 0.0, 0.25)))
    s.commit()
    assert s.stats()["curves"] == 2 and s.stats()["skipped_curves"] == 1
    img, _ = render(pc, s, 32, 32, 4)
    assert np.isfinite(img).all()
    assert img[..., 1].max() > 0.5
