"""The camera model through the core module (issue 5): thin lens (every ray through a pixel
meets the pinhole ray on the focal plane), aperture shapes, orthographic framing, the pixel
filters' sample distribution (against Cycles' filter profiles integrated numerically),
autofocus, render borders and input validation."""
import math

import numpy as np
import pytest

from core_scenes import add_object, core, look_at_matrix, quad

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif(not hasattr(pc.Camera, "generate_ray"), reason="core without thin lens")]

EYE = np.array([1.0, -7.0, 2.0])
TARGET = np.array([0.3, 0.0, 1.2])


def lens_camera(kind="PERSP", aperture=0.2, focus=6.0, blades=0, rotation=0.0, ratio=1.0):
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix(EYE, TARGET)
    cam.type = kind
    cam.lens = 35.0
    cam.ortho_scale = 5.0
    cam.shift_x, cam.shift_y = 0.1, -0.05
    cam.clip_start = 0.0  # ray origins are then the lens points themselves
    cam.aperture_size, cam.focus_distance = aperture, focus
    cam.aperture_blades, cam.aperture_rotation, cam.aperture_ratio = blades, rotation, ratio
    return cam


def camera_axes(cam):
    m = np.asarray(cam.matrix_world, np.float64)
    return m[:3, 0], m[:3, 1], -m[:3, 2], m[:3, 3]  # right, up, forward, origin


def lens_points(cam, x, y, n=256, res=(64, 48), seed=1):
    rng = np.random.default_rng(seed)
    out = []
    for u in rng.random((n, 2)):
        o, d, _ = cam.generate_ray(res[0], res[1], x, y, (float(u[0]), float(u[1])))
        out.append((np.array(o), np.array(d)))
    return out


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
@pytest.mark.parametrize("blades,ratio", [(0, 1.0), (5, 1.0), (0, 2.0)])
def test_thin_lens_rays_meet_on_focal_plane(kind, blades, ratio):
    cam = lens_camera(kind, blades=blades, ratio=ratio, rotation=0.4)
    right, up, fwd, origin = camera_axes(cam)
    for x, y in ((32.0, 24.0), (3.5, 40.25), (60.0, 2.0)):
        o0, d0, _ = cam.generate_ray(64, 48, x, y)  # pinhole ray (lens centre)
        o0, d0 = np.array(o0), np.array(d0)
        focal = o0 + d0 * ((6.0 - np.dot(o0 - origin, fwd)) / np.dot(d0, fwd))
        assert np.dot(focal - origin, fwd) == pytest.approx(6.0, rel=1e-5)
        spread = []
        for o, d in lens_points(cam, x, y, n=64):
            t = (6.0 - np.dot(o - origin, fwd)) / np.dot(d, fwd)
            assert np.linalg.norm(o + d * t - focal) < 2e-5 * 6.0
            spread.append(np.linalg.norm(o - o0))
        assert max(spread) > 0.1  # the rays do leave from different points of the lens


@pytest.mark.parametrize("blades,rotation,ratio", [(0, 0.0, 1.0), (0, 0.0, 2.5), (6, 0.3, 1.0), (3, 1.0, 1.0)])
def test_aperture_shape(blades, rotation, ratio):
    """Lens points fill Cycles' aperture: a disk of radius aperture_size (x squeezed by the
    ratio), or a regular polygon with unit circumradius, corners at rotation + pi/n + 2 pi k/n."""
    R = 0.2
    cam = lens_camera(aperture=R, blades=blades, rotation=rotation, ratio=ratio)
    right, up, fwd, origin = camera_axes(cam)
    pts = np.array([[np.dot(o - origin, right), np.dot(o - origin, up)]
                    for o, _ in lens_points(cam, 32.0, 24.0, n=4000)])
    pts[:, 0] *= ratio
    assert np.abs(pts.mean(axis=0)).max() < 0.01  # centred
    r = np.linalg.norm(pts, axis=1)
    assert r.max() <= R * (1 + 1e-4)
    if blades == 0:
        assert np.mean(r ** 2) == pytest.approx(R * R / 2, rel=0.05)  # uniform disk
        assert np.mean(r < R / 2) == pytest.approx(0.25, abs=0.03)
        return
    n = blades
    normals = rotation + 2 * np.pi * np.arange(n) / n  # edge midpoints, between corners
    proj = pts @ np.stack([np.cos(normals), np.sin(normals)])
    assert proj.max() <= R * math.cos(math.pi / n) * (1 + 1e-4)  # inside the polygon
    corners = rotation + np.pi / n + 2 * np.pi * np.arange(n) / n
    reach = pts @ np.stack([np.cos(corners), np.sin(corners)])
    assert np.all(reach.max(axis=0) > 0.9 * R)  # and reaching into every corner
    area = 0.5 * n * R * R * math.sin(2 * math.pi / n)
    assert np.mean(r < R / 2) == pytest.approx(math.pi * R * R / 4 / area, abs=0.03)


def test_orthographic_framing():
    cam = lens_camera("ORTHO", aperture=0.0)
    cam.shift_x, cam.shift_y = 0.2, -0.1
    right, up, fwd, origin = camera_axes(cam)
    w, h = 50, 30
    o00, d00, _ = cam.generate_ray(w, h, 0.0, 0.0)
    o11, d11, _ = cam.generate_ray(w, h, float(w), float(h))
    for d in (d00, d11):
        assert np.allclose(d, fwd, atol=1e-6)
    # Horizontal fit: ortho_scale spans the width; shift moves by shift * ortho_scale.
    lo = np.array([np.dot(np.array(o00) - origin, right), np.dot(np.array(o00) - origin, up)])
    hi = np.array([np.dot(np.array(o11) - origin, right), np.dot(np.array(o11) - origin, up)])
    assert hi[0] - lo[0] == pytest.approx(5.0, rel=1e-5)
    assert hi[1] - lo[1] == pytest.approx(5.0 * h / w, rel=1e-5)
    assert (hi + lo)[0] / 2 == pytest.approx(0.2 * 5.0, abs=1e-5)
    assert (hi + lo)[1] / 2 == pytest.approx(-0.1 * 5.0, abs=1e-5)


def filter_profile(kind, width, x):
    """Cycles' filter functions (scene/film.cpp) as functions of the offset in pixels."""
    if kind == "box":
        return (np.abs(x) <= width / 2).astype(float)
    if kind == "gaussian":
        return np.where(np.abs(x) <= 1.5 * width, np.exp(-2.0 * (2.0 * x / width) ** 2), 0.0)
    v = 2 * np.pi * (x / (2 * width) + 0.5)
    bh = 0.35875 - 0.48829 * np.cos(v) + 0.14128 * np.cos(2 * v) - 0.01168 * np.cos(3 * v)
    return np.where(np.abs(x) <= width, bh, 0.0)


def edge_scene(width):
    """Orthographic camera, one world unit per pixel, a white emitter over x > 0."""
    s = pc.Scene()
    white = s.add_material("white", (0, 0, 0), (1, 1, 1))
    pos, tris = quad((0.0, 10.0, -50.0), (0.0, 0.0, 100.0), (50.0, 0.0, 0.0))
    add_object(s, pos, tris, white)
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix((0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    cam.type = "ORTHO"
    cam.ortho_scale = float(width)
    s.set_camera(cam)
    return s


@pytest.mark.parametrize("kind,width", [("box", 1.0), ("box", 2.0), ("gaussian", 1.5),
                                        ("blackman_harris", 1.5), ("blackman_harris", 3.0)])
def test_pixel_filter_edge_profile(kind, width):
    """Each pixel of a sharp edge sees the share of its filter beyond the edge: the rendered
    profile is the filter's CDF (Cycles' profiles integrated here numerically)."""
    w = 24
    st = pc.RenderSettings()
    st.width, st.height, st.samples = w, 4, 512
    st.filter_type, st.filter_width = kind, width
    sess = pc.Session(edge_scene(w), st)
    sess.start()
    while not sess.wait(1.0):
        pass
    got = sess.film()[..., 0].mean(axis=0)
    xs = np.linspace(-3 * width, 3 * width, 20001)
    f = filter_profile(kind, width, xs)
    cdf = np.cumsum(f) / f.sum()
    # Pixel i's centre is at i + 0.5; the edge at w / 2: value = P(centre + offset > w / 2).
    want = np.array([1.0 - np.interp(w / 2 - (i + 0.5), xs, cdf) for i in range(w)])
    assert np.abs(got - want).max() < 0.01, np.round(np.c_[got, want][w // 2 - 4:w // 2 + 4], 3)
    if kind == "box" and width == 1.0:
        assert set(np.unique(got)) == {0.0, 1.0}  # the 1-pixel box: the seed's jitter


def autofocus_scene(point=(0.5, 0.5), focus=3.0):
    """A tilted plane through (0, 4, 0) under a camera looking along +y from a tilted pose."""
    s = pc.Scene()
    m = s.add_material("grey", (0.5, 0.5, 0.5))
    pos, tris = quad((-1.5, 4.0 - 0.75, -1.5), (3.0, 1.5, 0.0), (0.0, 0.0, 3.0))
    add_object(s, pos, tris, m)
    eye = np.array([0.4, -2.0, 0.7])
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix(eye, (0.1, 4.0, 0.1))
    cam.aperture_size, cam.focus_distance = 0.1, focus
    cam.use_autofocus = True
    cam.autofocus_x, cam.autofocus_y = point
    s.set_camera(cam)
    s.commit()
    return s, cam


@pytest.mark.parametrize("point", [(0.5, 0.5), (0.3, 0.7)])
def test_autofocus_focuses_on_the_surface_under_the_point(point):
    s, cam = autofocus_scene(point)
    w, h = 40, 30
    o, d, _ = cam.generate_ray(w, h, point[0] * w, point[1] * h)  # the pinhole ray
    (t,), (prim,), _, _ = s.intersect(np.array([o], np.float32), np.array([d], np.float32))
    assert prim >= 0
    _, _, fwd, origin = camera_axes(cam)
    want = float(np.dot(np.array(o) + np.array(d) * t - origin, fwd))
    assert abs(want - 3.0) > 1.0  # the plane is far from the camera's own focus distance
    st = pc.RenderSettings()
    st.width, st.height, st.samples = w, h, 1
    sess = pc.Session(s, st)
    stats = sess.stats()
    assert stats["autofocus"] == "hit"
    assert stats["focus_distance"] == pytest.approx(want, rel=1e-5)


def test_autofocus_miss_keeps_the_focus_distance():
    s, _ = autofocus_scene((0.0, 1.0), focus=3.25)  # the top-left corner sees the sky
    st = pc.RenderSettings()
    st.width, st.height, st.samples = 40, 30, 1
    stats = pc.Session(s, st).stats()
    assert stats["autofocus"] == "miss"
    assert stats["focus_distance"] == pytest.approx(3.25)


def test_border_renders_exactly_its_part_of_the_frame():
    s, _ = autofocus_scene()
    st = pc.RenderSettings()
    st.width, st.height, st.samples, st.seed = 40, 30, 4, 7
    st.filter_type = "blackman_harris"
    with_passes = hasattr(st, "passes")
    if with_passes:
        st.passes = ["Depth", "Normal"]
    full = pc.Session(s, st)
    full.start()
    while not full.wait(1.0):
        pass
    st.border_x, st.border_y, st.border_width, st.border_height = 9, 5, 17, 20
    part = pc.Session(s, st)
    part.start()
    while not part.wait(1.0):
        pass
    img = part.film()
    assert img.shape == (20, 17, 4)
    assert part.sample_counts().shape == (20, 17)
    assert np.array_equal(img, full.film()[5:25, 9:26])  # same sample streams, bit for bit
    if with_passes:
        for name in ("Depth", "Normal"):
            assert np.array_equal(part.film_pass(name), full.film_pass(name)[5:25, 9:26]), name


def test_camera_and_settings_validation():
    s, cam = autofocus_scene()
    for field, value in (("focus_distance", 0.0), ("aperture_size", -1.0), ("aperture_ratio", 0.0),
                         ("aperture_blades", -2), ("autofocus_x", 1.5), ("focus_distance", float("nan"))):
        bad, _ = autofocus_scene()
        c = lens_camera()
        setattr(c, field, value)
        with pytest.raises(ValueError):
            bad.set_camera(c)
    c = lens_camera("ORTHO")
    c.ortho_scale = 0.0
    with pytest.raises(ValueError):
        s.set_camera(c)
    with pytest.raises(ValueError):
        cam.type = "CUSTOM"  # (PANO is supported since the panoramic cameras)
    st = pc.RenderSettings()
    with pytest.raises(ValueError):
        st.filter_type = "mitchell"
    st.width, st.height = 40, 30
    for fields in (dict(filter_width=0.0), dict(filter_width=float("nan")),
                   dict(border_x=30, border_y=0, border_width=20, border_height=10),
                   dict(border_x=0, border_y=0, border_width=-1, border_height=10)):
        bad = pc.RenderSettings()
        bad.width, bad.height = 40, 30
        for k, v in fields.items():
            setattr(bad, k, v)
        with pytest.raises(ValueError):
            pc.Session(s, bad)


@pytest.mark.parametrize("fields", [
    dict(aperture_size=1e30, focus_distance=1e-30),
    dict(aperture_size=3e38, aperture_ratio=1e-38, focus_distance=3e38),
    dict(type="ORTHO", ortho_scale=1e30, aperture_size=1e20, aperture_blades=1024),
    dict(type="ORTHO", ortho_scale=1e-30, aperture_size=1e-30, focus_distance=1e-30),
    dict(aperture_size=0.5, aperture_blades=3, aperture_rotation=1e30, use_autofocus=True),
])
def test_absurd_lens_values_render_without_crashing(fields):
    cam = lens_camera()
    for k, v in fields.items():
        setattr(cam, k, v)
    s2 = pc.Scene()
    m = s2.add_material("grey", (0.5, 0.5, 0.5))
    pos, tris = quad((-1.5, 2.0, -1.5), (3.0, 0.0, 0.0), (0.0, 0.0, 3.0))
    add_object(s2, pos, tris, m)
    s2.set_world_color((0.2, 0.2, 0.2))
    s2.set_camera(cam)
    st = pc.RenderSettings()
    st.width, st.height, st.samples = 16, 12, 4
    st.filter_type, st.filter_width = "blackman_harris", 100.0
    sess = pc.Session(s2, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    img = sess.film()
    assert np.isfinite(img).all() and img.min() >= 0.0
