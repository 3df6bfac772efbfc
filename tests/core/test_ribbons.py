"""Ribbons (Cycles' curve shape 'RIBBONS', Embree's flat Catmull-Rom curves) in the core: a
strand is a flat band of its radius on either side of the curve, turned to face each ray; its
width follows the radius; rays beside it or past its ends miss; the shading normal is Cycles'
rounded one."""
import numpy as np
import pytest

from core_scenes import core

pytestmark = pytest.mark.sanitize


def _scene(pc, points, offsets, radii, subdivisions=4, shape="ribbon", curve_type="catmull_rom"):
    s = pc.Scene()
    m = s.add_material("strand", base_color=(0.8, 0.8, 0.8))
    s.add_curves(np.asarray(points, np.float32), np.asarray(offsets), np.asarray(radii, np.float32), m,
                 curve_type=curve_type, subdivisions=subdivisions, shape=shape)
    s.commit()
    return s


def _line_distance(o, d, p0, p1):
    """Signed distance between each ray's line and the axis p0-p1 (float64) along their common
    perpendicular, and the axial position (0 .. 1) of the closest point on the axis."""
    o, d = o.astype(np.float64), d.astype(np.float64)
    a = (p1 - p0) / np.linalg.norm(p1 - p0)
    w = np.cross(d, a)
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    dist = np.einsum("ij,ij->i", p0 - o, w)
    # The closest point on the axis: where the plane through the ray and w meets it.
    nrm = np.cross(d, w)
    s = np.einsum("ij,ij->i", o - p0, nrm) / (nrm @ a)
    return dist, s / np.linalg.norm(p1 - p0)


def test_ribbon_faces_every_ray():
    """A straight strand of radius r: rays from all directions hit it where their line passes
    within r of its axis (the band turns to face each of them), at the distance where they
    cross the plane of the axis and the common perpendicular; others miss."""
    pc = core()
    p0, p1, r = np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), 0.1
    s = _scene(pc, [p0, p1], [0, 2], [r, r])
    rng = np.random.default_rng(3)
    n = 4000
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[np.abs(d[:, 0]) < 0.9]  # not along the strand
    target = np.c_[rng.uniform(-0.8, 0.8, len(d)), rng.uniform(-0.2, 0.2, len(d)), rng.uniform(-0.2, 0.2, len(d))]
    o = (target - d * 4.0).astype(np.float32)
    d = d.astype(np.float32)
    hs = s.hit_surfaces(o, d)
    dist, u = _line_distance(o, d, p0, p1)
    inside = (np.abs(dist) < r * 0.995) & (u > 0.01) & (u < 0.99)
    outside = np.abs(dist) > r * 1.005
    hit = np.isfinite(hs["t"])
    assert inside.sum() > 300 and outside.sum() > 300
    assert hit[inside].all(), "rays within the radius of the axis must hit the ribbon"
    assert not hit[outside].any(), "rays beyond the radius must miss"
    # The hit lies on the plane through the axis facing the ray, at |v| = distance / r.
    a = (p1 - p0) / 2.0
    wv = np.cross(d[inside].astype(np.float64), a)
    wv /= np.linalg.norm(wv, axis=1, keepdims=True)
    plane_n = np.cross(a, wv)
    t_plane = np.einsum("ij,ij->i", p0 - o[inside], plane_n) / np.einsum("ij,ij->i", d[inside], plane_n)
    np.testing.assert_allclose(hs["t"][inside], t_plane, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.abs(hs["hit"][inside, 1]), np.abs(dist[inside]) / r, atol=2e-3)
    assert (hs["curve"][inside]).all()


def test_ribbon_width_follows_the_radius():
    """A tapered strand (radius 0.05 to 0.15) seen from above: the band's half-width at each
    point along it is the radius there (linear along this straight strand, as the Catmull-Rom
    basis moves position and radius alike); rays past the ends miss."""
    pc = core()
    r0, r1 = 0.05, 0.15
    s = _scene(pc, [[0, 0, 0], [2, 0, 0]], [0, 2], [r0, r1], subdivisions=3)
    xs = np.linspace(0.02, 1.98, 50)
    rx = r0 + (r1 - r0) * xs / 2.0
    for scale, expect in ((0.97, True), (1.03, False)):
        for sign in (1.0, -1.0):
            o = np.c_[xs, sign * scale * rx, np.full_like(xs, 3.0)].astype(np.float32)
            d = np.tile(np.array([0, 0, -1], np.float32), (len(xs), 1))
            hs = s.hit_surfaces(o, d)
            assert (np.isfinite(hs["t"]) == expect).all(), (scale, sign)
            if expect:
                np.testing.assert_allclose(hs["t"], 3.0, rtol=1e-5)
                # v runs from -1 to 1 across the band (a triangle's barycentric, as Embree's:
                # on a tapered quad not quite the fraction of the width).
                np.testing.assert_allclose(np.abs(hs["hit"][:, 1]), scale, atol=0.03)
    # Past either end: nothing.
    o = np.array([[-0.02, 0, 3], [2.02, 0, 3]], np.float32)
    d = np.array([[0, 0, -1], [0, 0, -1]], np.float32)
    assert not np.isfinite(s.hit_surfaces(o, d)["t"]).any()


def test_ribbon_normal_is_rounded_towards_the_viewer():
    """Cycles' ribbon normal: sin(v) across the band, cos(v) towards the viewer, so the band
    shades like a round fibre; the tangent runs along the strand."""
    pc = core()
    r = 0.1
    s = _scene(pc, [[-1, 0, 0], [1, 0, 0]], [0, 2], [r, r])
    ys = np.linspace(-0.095, 0.095, 21)
    o = np.c_[np.zeros_like(ys), ys, np.full_like(ys, 3.0)].astype(np.float32)
    d = np.tile(np.array([0, 0, -1], np.float32), (len(ys), 1))
    hs = s.hit_surfaces(o, d)
    v = hs["hit"][:, 1]
    n = hs["ng"]
    np.testing.assert_allclose(np.abs(v), np.abs(ys) / r, atol=1e-3)
    np.testing.assert_allclose(n[:, 2], np.sqrt(1 - v ** 2), atol=1e-4)  # towards the viewer (+z)
    np.testing.assert_allclose(np.abs(n[:, 1]), np.abs(v), atol=1e-4)
    assert (np.sign(n[np.abs(ys) > 0.01, 1]) == np.sign(ys[np.abs(ys) > 0.01])).all(), "normal leans to the hit's side"
    np.testing.assert_allclose(np.abs(hs["tangent"][:, 0]), 1.0, atol=1e-5)


def test_bent_ribbon_follows_the_curve_and_its_tessellation():
    """A bent Catmull-Rom strand seen from above: the curve's own points (numpy's Catmull-Rom
    with clamped ends) are inside the band at 5 and 16 quads per segment, points a radius and
    a half beside them miss; 16 quads follow the curve within 5 % of the radius; at one quad
    per segment the band is the chords' (the curve's middle points off it)."""
    pc = core()
    keys = np.array([[0, 0, 0], [1, 0.6, 0], [2, 0, 0], [3, 0.6, 0]], np.float64)
    r = 0.05

    def cr(a, b, c, d, t):
        t2, t3 = t * t, t * t * t
        return 0.5 * ((-t3 + 2 * t2 - t) * a + (3 * t3 - 5 * t2 + 2) * b + (-3 * t3 + 4 * t2 + t) * c + (t3 - t2) * d)

    def dcr(a, b, c, d, t):
        t2 = t * t
        return 0.5 * ((-3 * t2 + 4 * t - 1) * a + (9 * t2 - 10 * t) * b + (-9 * t2 + 8 * t + 1) * c + (3 * t2 - 2 * t) * d)

    pts, nrm = [], []
    for k in range(3):
        a, b, c, d = keys[max(k - 1, 0)], keys[k], keys[k + 1], keys[min(k + 2, 3)]
        for t in np.linspace(0.05, 0.95, 19):
            pts.append(cr(a, b, c, d, t))
            tg = dcr(a, b, c, d, t)
            nrm.append(np.array([-tg[1], tg[0], 0]) / np.hypot(tg[0], tg[1]))
    pts, nrm = np.array(pts), np.array(nrm)
    down = np.tile(np.array([0, 0, -1], np.float32), (len(pts), 1))
    for sub in (5, 16):
        s = _scene(pc, keys, [0, 4], [r] * 4, subdivisions=sub)
        centre = s.hit_surfaces((pts + [0, 0, 2]).astype(np.float32), down)
        assert np.isfinite(centre["t"]).all(), sub
        for side in (1.5, -1.5):
            beside = s.hit_surfaces((pts + side * r * nrm + [0, 0, 2]).astype(np.float32), down)
            assert not np.isfinite(beside["t"]).any(), (sub, side)
    # At 16 quads a segment the band's edge is within 5 % of the radius of the curve's offset.
    s = _scene(pc, keys, [0, 4], [r] * 4, subdivisions=16)
    assert np.isfinite(s.hit_surfaces((pts + 0.95 * r * nrm + [0, 0, 2]).astype(np.float32), down)["t"]).all()
    assert not np.isfinite(s.hit_surfaces((pts + 1.05 * r * nrm + [0, 0, 2]).astype(np.float32), down)["t"]).any()
    s = _scene(pc, keys, [0, 4], [r] * 4, subdivisions=1)
    mid = np.abs(np.linspace(0.05, 0.95, 19) - 0.5) < 0.1
    bends = np.r_[mid, np.zeros_like(mid), mid]  # (the middle segment is nearly its chord)
    assert not np.isfinite(s.hit_surfaces((pts + [0, 0, 2]).astype(np.float32), down)["t"][bends]).any()


def test_ribbon_ignores_hits_nearer_than_two_radii():
    """Embree's self-intersection avoidance (factor 2, as Cycles' CPU and GPU ribbons): a ray
    that starts within two radii of the band does not see it; one from farther does."""
    pc = core()
    r = 0.1
    s = _scene(pc, [[-1, 0, 0], [1, 0, 0]], [0, 2], [r, r])
    o = np.array([[0, 0, 1.9 * r], [0, 0, 2.1 * r]], np.float32)
    d = np.array([[0, 0, -1], [0, 0, -1]], np.float32)
    t = s.hit_surfaces(o, d)["t"]
    assert not np.isfinite(t[0]) and np.isfinite(t[1])


def test_ribbon_shape_validation_and_poly_strands_are_catmull_rom_ribbons():
    """shape takes 'thick' or 'ribbon' (else ValueError); poly strands become Catmull-Rom
    ribbons through their points (as Cycles 4.5 renders poly Curves with 'RIBBONS'): the same
    hits as Catmull-Rom ones, unlike their round poly lines."""
    pc = core()
    with pytest.raises(ValueError):
        _scene(pc, [[0, 0, 0], [1, 0, 0]], [0, 2], [0.1, 0.1], shape="flat")
    pts = [[-1, 0, 0], [0, 0.3, 0], [1, 0, 0]]
    a = _scene(pc, pts, [0, 3], [0.1] * 3, curve_type="poly", shape="ribbon")
    b = _scene(pc, pts, [0, 3], [0.1] * 3, curve_type="catmull_rom", shape="ribbon")
    c = _scene(pc, pts, [0, 3], [0.1] * 3, curve_type="poly", shape="thick")
    rng = np.random.default_rng(5)
    d = rng.normal(size=(500, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    o = (rng.uniform(-0.5, 0.5, (500, 3)) - d * 3).astype(np.float32)
    ta = a.hit_surfaces(o, d)["t"]
    np.testing.assert_array_equal(ta, b.hit_surfaces(o, d)["t"])
    assert (np.isfinite(ta) != np.isfinite(c.hit_surfaces(o, d)["t"])).any()


def test_ribbon_shading_is_finite_and_spawned_rays_leave_the_strand():
    """Paths on ribbons: rays spawned from a hit (the path's origins on both sides) skip their
    strand; degenerate strands (zero radius, NaN) are left out as for round ones."""
    pc = core()
    s = _scene(pc, [[-1, 0, 0], [0, 0.2, 0], [1, 0, 0], [0, 0, 0], [0, 0, 0], [np.nan, 0, 0], [1, 1, 1]],
               [0, 3, 5, 7], [0.1, 0.1, 0.1, 0.0, 0.0, 0.1, 0.1])
    assert s.stats()["skipped_curves"] == 2
    rng = np.random.default_rng(9)
    d = rng.normal(size=(300, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    o = (np.c_[rng.uniform(-0.9, 0.9, 300), rng.uniform(0, 0.2, 300), np.zeros(300)] - d * 3).astype(np.float32)
    hs = s.hit_surfaces(o, d)
    hit = np.isfinite(hs["t"])
    assert hit.sum() > 20
    assert np.isfinite(hs["ng"][hit]).all() and np.isfinite(hs["p"][hit]).all()
    for origin in ("origin_out", "origin_in"):
        again = s.hit_surfaces(hs[origin][hit], -d[hit], self_strand=hs["strand"][hit])
        assert not np.isfinite(again["t"]).any()
