"""Point clouds in the core: spheres hit where the analytic sphere is (float64 reference), with
its normal, also tiny or huge ones far from the origin; rays from inside leave where the
sphere does; rays spawned from a hit never hit the sphere they left; bad points are left out."""
import numpy as np
import pytest

from core_scenes import camera, core, render

pytestmark = pytest.mark.sanitize


def _scene(pc, points, radii, matrix=None, **kw):
    s = pc.Scene()
    m = s.add_material("points", base_color=(0.8, 0.8, 0.8))
    s.add_points(np.asarray(points, np.float32).reshape(-1, 3),
                 None if radii is None else np.asarray(radii, np.float32), m, matrix=matrix, **kw)
    s.commit()
    return s


def _rays_at(rng, n, center, spread, dist):
    """Rays from random directions, `dist` away, aimed at random points near `center`."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    target = np.asarray(center, np.float64) + rng.uniform(-spread, spread, size=(n, 3))
    return (target - d * dist).astype(np.float32), d.astype(np.float32)


def _sphere_hits(o, d, c, r):
    """Entry and exit distances of rays on a sphere in float64 (from the float32 inputs)."""
    o, d = o.astype(np.float64), d.astype(np.float64)
    c = np.asarray(c, np.float32).astype(np.float64)
    r = float(np.float32(r))
    f = c - o
    tc = (f * d).sum(1) / (d * d).sum(1)
    perp = f - d * tc[:, None]
    disc = r * r - (perp * perp).sum(1)
    with np.errstate(invalid="ignore"):
        h = np.sqrt(disc / (d * d).sum(1))
    return np.where(disc >= 0, tc - h, np.nan), np.where(disc >= 0, tc + h, np.nan)


@pytest.mark.parametrize("center, r", [((0.3, -0.2, 0.1), 0.5),       # ordinary
                                       ((1e4, -2e3, 5e3), 1e-3),      # tiny, far from the origin
                                       ((-3e3, 1e3, 2e2), 40.0),      # huge, far away
                                       ((0.0, 0.0, 0.0), 1e-5)])      # tiny at the origin
def test_hits_match_analytic_sphere(center, r):
    pc = core()
    rng = np.random.default_rng(3)
    s = _scene(pc, [center], [r])
    o, d = _rays_at(rng, 4000, center, 1.2 * r, dist=20.0 * r + 1.0)
    hit = s.hit_surfaces(o, d)
    t0, _ = _sphere_hits(o, d, center, r)
    inside = np.isfinite(t0)
    assert 500 < inside.sum() < 4000
    # The same rays hit (the reference is exact on the same float32 inputs), at the analytic
    # distance to float32's rounding of t, with the normal to 1e-6 even where the radius is
    # 1e-7 of the distance to the origin (solved in double about the closest approach).
    assert np.array_equal(np.isfinite(hit["t"]), inside)
    assert np.all(hit["point"][inside]) and not np.any(hit["curve"][inside])
    np.testing.assert_allclose(hit["t"][inside], t0[inside], rtol=2.5e-7, atol=0)
    p = o[inside].astype(np.float64) + d[inside].astype(np.float64) * t0[inside, None]
    n_ref = (p - np.asarray(center, np.float32).astype(np.float64)) / np.float32(r)
    assert np.abs(hit["ng"][inside] - n_ref).max() < 1e-6
    # The point lies on the sphere (rebuilt from the normal, not from t's rounding).
    rad = np.linalg.norm(hit["p"][inside].astype(np.float64) - np.asarray(center, np.float32), axis=1)
    assert np.abs(rad - np.float32(r)).max() < 1e-6 * r + 2.5e-7 * np.abs(center).max()


@pytest.mark.parametrize("center, r", [((0.0, 0.0, 0.0), 1.0), ((2e3, 1e3, -4e3), 0.05)])
def test_rays_from_inside_leave_through_the_sphere(center, r):
    """A ray that starts inside a sphere meets it where it leaves, with the outward normal
    along the ray (the viewer sees its back), as Embree's spheres on Cycles' CPU."""
    pc = core()
    rng = np.random.default_rng(4)
    s = _scene(pc, [center], [r])
    o = (np.asarray(center) + rng.uniform(-0.5, 0.5, size=(2000, 3)) * r).astype(np.float32)
    d = rng.normal(size=(2000, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    hit = s.hit_surfaces(o, d)
    _, t1 = _sphere_hits(o, d, center, r)
    assert np.isfinite(hit["t"]).all()
    np.testing.assert_allclose(hit["t"], t1, rtol=1e-5, atol=1e-6 * (1 + np.abs(center).max()))
    assert ((hit["ng"] * d).sum(1) > 0).all()


def test_spawned_rays_skip_their_sphere():
    """From every hit, rays leaving outwards (origin_out) never meet their sphere again, near
    and far from the origin, grazing ones too; rays into it (origin_in, a refraction) that
    carry the sphere they leave, as a path's rays do, find nothing, as in Cycles (its Embree
    filter rejects the point a ray leaves, far side included: docs/design/points.md); without
    it they meet its far side where the analytic sphere has it."""
    pc = core()
    rng = np.random.default_rng(7)
    for center, r in (((0.0, 0.0, 0.0), 0.02), ((300.0, -200.0, 100.0), 0.05), ((1e4, 0.0, 0.0), 0.3)):
        s = _scene(pc, [center], [r])
        o, d = _rays_at(rng, 3000, center, 0.8 * r, dist=2.0)
        hit = s.hit_surfaces(o, d)
        ok = np.isfinite(hit["t"])
        assert ok.sum() > 1000
        n = hit["ng"][ok]
        w = rng.normal(size=n.shape)
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        graze = rng.uniform(size=len(w)) < 0.5  # half within a few degrees of the tangent plane
        w[graze] -= n[graze] * ((w[graze] * n[graze]).sum(1, keepdims=True) * 0.97)
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        w = w.astype(np.float32)
        out = (w * n).sum(1) > 0
        org = np.where(out[:, None], hit["origin_out"][ok], hit["origin_in"][ok]).astype(np.float32)
        away = s.hit_surfaces(org[out], w[out])
        assert np.isinf(away["t"]).all(), f"{np.isfinite(away['t']).sum()} self-hits at {center}"
        assert np.all(hit["strand"][ok] >= 0)
        skipped = s.hit_surfaces(org[~out], w[~out], self_strand=hit["strand"][ok][~out])
        assert np.isinf(skipped["t"]).all(), f"{np.isfinite(skipped['t']).sum()} self-hits at {center}"
        inside = s.hit_surfaces(org[~out], w[~out])
        assert np.all(inside["point"]), f"{(~inside['point']).sum()} inward rays missed at {center}"
        _, t1 = _sphere_hits(org[~out], w[~out], center, r)
        np.testing.assert_allclose(inside["t"], t1, rtol=1e-5, atol=1e-6 * (1.0 + np.abs(center).max()))
        assert np.all((inside["ng"] * w[~out]).sum(1) > 0)
        steep = (w[~out] * n[~out]).sum(1) < -0.5
        assert steep.sum() > 100 and np.all(inside["t"][steep] > r * 0.9)


def test_neighbours_are_hit_and_the_closest_wins():
    """Many spheres: every ray finds the nearest one it crosses (brute force in float64), and
    a ray leaving one sphere still finds an overlapping neighbour's inside."""
    pc = core()
    rng = np.random.default_rng(9)
    c = rng.uniform(-1, 1, size=(300, 3)).astype(np.float32)
    r = rng.uniform(0.01, 0.12, size=300).astype(np.float32)
    s = _scene(pc, c, r)
    assert s.stats()["points"] == 300
    o, d = _rays_at(rng, 3000, (0, 0, 0), 1.0, dist=4.0)
    hit = s.hit_surfaces(o, d)
    best = np.full(len(o), np.inf)
    for k in range(len(c)):
        t0, t1 = _sphere_hits(o, d, c[k], r[k])
        t = np.where(t0 > 0, t0, np.where(t1 > 0, t1, np.nan))
        best = np.fmin(best, np.where(np.isfinite(t), t, np.inf))
    assert np.array_equal(np.isfinite(best), np.isfinite(hit["t"]))
    ok = np.isfinite(best)
    np.testing.assert_allclose(hit["t"][ok], best[ok], rtol=1e-5, atol=1e-6)
    # Occlusion agrees with the closest hit.
    assert np.array_equal(s.occluded(o, d), ok)


def test_transform_scales_radius_and_moves_points():
    pc = core()
    m = np.diag([2.0, 2.0, 2.0, 1.0]).astype(np.float32)
    m[:3, 3] = (1.0, 0.0, 0.0)
    s = _scene(pc, [(0.0, 0.0, 0.0)], [0.25], matrix=m)
    hit = s.hit_surfaces(np.array([[1.0, -5.0, 0.0]], np.float32), np.array([[0.0, 1.0, 0.0]], np.float32))
    assert hit["t"][0] == pytest.approx(4.5, abs=1e-5)  # centre (1, 0, 0), radius 0.5


def test_bad_points_are_left_out():
    """NaN or infinite positions, zero, negative, NaN or infinite radii: left out and counted,
    never a crash; the good points still render; an empty cloud is fine."""
    pc = core()
    nan, inf = float("nan"), float("inf")
    pts = [(0, 0, 0), (nan, 1, 0), (0, 2, inf), (0, 3, 0), (0, 4, 0), (0, 5, 0), (0, 6, 0), (0, 7, 0)]
    rad = [0.2, 0.2, 0.2, 0.0, -0.2, nan, inf, 0.2]
    s = _scene(pc, pts, rad)
    st = s.stats()
    assert (st["points"], st["skipped_points"]) == (2, 6)
    o = np.array([[0.0, y, -5.0] for y in range(8)], np.float32)
    d = np.tile(np.array([[0.0, 0.0, 1.0]], np.float32), (8, 1))
    hit = s.hit_surfaces(o, d)
    assert np.isfinite(hit["t"]).tolist() == [True] + [False] * 6 + [True]
    # Shapes that do not fit raise ValueError; an empty cloud and None radii (0.01) work.
    with pytest.raises(ValueError):
        pc.Scene().add_points(np.zeros((3, 2), np.float32))
    with pytest.raises(ValueError):
        pc.Scene().add_points(np.zeros((3, 3), np.float32), np.zeros(2, np.float32))
    with pytest.raises(ValueError):
        pc.Scene().add_points(np.zeros((3, 3), np.float32), point_attributes={0: np.zeros((2, 4), np.float32)})
    e = _scene(pc, np.zeros((0, 3)), np.zeros(0))
    assert e.stats()["points"] == 0 and not np.isfinite(e.hit_surfaces(o, d)["t"]).any()
    dflt = _scene(pc, [(0, 0, 0)], None)
    assert dflt.hit_surfaces(o[:1], d[:1])["t"][0] == pytest.approx(4.99, abs=1e-5)
    # Singular matrix: every point left out.
    sing = _scene(pc, [(0, 0, 0)], [1.0], matrix=np.diag([1.0, 0.0, 1.0, 1.0]).astype(np.float32))
    assert sing.stats()["skipped_points"] == 1
    # Random garbage: commit and render without a crash.
    rng = np.random.default_rng(11)
    pts = rng.normal(size=(400, 3)).astype(np.float32)
    pts[rng.uniform(size=400) < 0.05] = np.nan
    rad = (rng.normal(size=400) * 0.1).astype(np.float32)
    rad[rng.uniform(size=400) < 0.05] = np.inf
    s = _scene(pc, pts, rad)
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0, -6, 1), (0, 0, 0)))
    s.commit()
    img, _ = render(pc, s, 16, 16, 4)
    assert np.isfinite(img).all() and img[..., :3].max() > 0.0


def test_point_attributes_read_per_point():
    """An Attribute node on points reads the point's own value (Cycles' per-point attributes),
    seen through an emission shader."""
    pc = core()
    s = pc.Scene()
    m = s.add_shader("attr", [("attribute", 0, 0, "COLOR"), ("closure", "emission", None, {"color": 0})])
    cols = np.array([[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]], np.float32)
    s.add_points(np.array([[-1, 0, 0], [0, 0, 0], [1, 0, 0]], np.float32), np.full(3, 0.3, np.float32), m,
                 point_attributes={0: cols})
    s.set_camera(camera(pc, (0, -6, 0), (0, 0, 0), lens=50.0))
    s.commit()
    img, _ = render(pc, s, 48, 16, 4)
    row = img[8, :, :3]
    left, mid, right = row[:16].max(0), row[16:32].max(0), row[32:].max(0)
    assert left.argmax() == 0 and mid.argmax() == 1 and right.argmax() == 2
    assert left[0] == pytest.approx(1.0, abs=0.05)


def test_uneven_scale_makes_ellipsoids():
    """A cloud whose matrix scales unevenly is intersected in its object space, as Cycles does:
    each point is the ellipsoid M (sphere), hit where the analytic quadric is (float64), with
    Cycles' point normal, the direction from the centre to the hit; its bounds hold it."""
    pc = core()
    rng = np.random.default_rng(12)
    a, b = np.radians(30.0), np.radians(-20.0)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    lin = rz @ rx @ np.diag([2.0, 0.5, 1.3])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = lin, (0.3, -0.2, 0.5)
    m = m.astype(np.float32)
    s = _scene(pc, [(0.1, 0.2, -0.1)], [0.4], matrix=m)
    c = m[:3, :3].astype(np.float64) @ np.array([0.1, 0.2, -0.1]) + m[:3, 3]
    o, d = _rays_at(rng, 4000, c, 0.5, dist=6.0)
    hit = s.hit_surfaces(o, d)
    inv = np.linalg.inv(m[:3, :3].astype(np.float64))
    fo = (inv @ (o.astype(np.float64) - c).T).T
    do = (inv @ d.astype(np.float64).T).T
    A = (do * do).sum(1)
    B = (fo * do).sum(1)
    C = (fo * fo).sum(1) - 0.4 ** 2
    disc = B * B - A * C
    with np.errstate(invalid="ignore"):
        t_ref = (-B - np.sqrt(disc)) / A
    ok = disc > 0
    assert 1000 < ok.sum() < 4000
    assert np.array_equal(np.isfinite(hit["t"]), ok)
    np.testing.assert_allclose(hit["t"][ok], t_ref[ok], rtol=1e-6)
    p = o[ok].astype(np.float64) + d[ok].astype(np.float64) * t_ref[ok, None]
    radial = (p - c) / np.linalg.norm(p - c, axis=1, keepdims=True)
    assert np.abs(hit["ng"][ok] - radial).max() < 1e-5
    np.testing.assert_allclose(hit["p"][ok], p, atol=2e-6)
    # Spawned rays: outward ones leave it, inward ones meet its inside, or nothing where they
    # carry the ellipsoid they leave.
    inward = -hit["ng"][ok]
    assert np.isinf(s.hit_surfaces(hit["origin_out"][ok], -inward)["t"]).all()
    far = s.hit_surfaces(hit["origin_in"][ok], inward)
    assert np.all(np.isfinite(far["t"])) and np.all((far["ng"] * inward).sum(1) > 0)
    again = s.hit_surfaces(hit["origin_in"][ok], inward, self_strand=hit["strand"][ok])
    assert np.isinf(again["t"]).all()


def test_point_info_reads_centre_radius_and_random():
    """Point Info: the centre (world), the radius (Cycles' point_radius: the object radius along
    (1, 1, 1) / sqrt 3 through the matrix) and Cycles' random number of the point's index in
    its cloud (hash_uint2_to_float(i, 0), as Curves Info's Random), seen through Emission."""
    pc = core()
    out = {}
    pts = np.array([[-1.0, 0.0, 0.0], [np.nan, 0, 0], [1.0, 0.0, 0.0]], np.float32)
    m = np.diag([0.75, 0.75, 0.75, 1.0]).astype(np.float32)
    m[0, 3] = 1.0  # centres at x = 0.25 and 1.75 (Emission clamps negative colours)
    for which in ("POSITION", "RADIUS", "RANDOM"):
        s = pc.Scene()
        mat = s.add_shader("pi", [("point_info", 0, which), ("closure", "emission", None, {"color": 0})])
        s.add_points(pts, np.array([0.6, 0.3, 0.4], np.float32), mat, matrix=m)
        s.set_camera(camera(pc, (1, -8, 0), (1, 0, 0), lens=50.0))
        s.commit()
        img, _ = render(pc, s, 48, 16, 4)
        out[which] = img[8, :, :3]
    # The pixels at the two centres' images (x = 0.25 and 1.75 seen from x = 1, 8 away, a
    # 36 mm sensor at 50 mm: columns 17 and 30), well inside the spheres (radii 3.7 and 2.5
    # pixels), and a background pixel: zeros off points.
    (l, r, bg) = (17, 30, 2)
    assert out["POSITION"][l, 0] == pytest.approx(0.25, abs=1e-5)
    assert out["POSITION"][r, 0] == pytest.approx(1.75, abs=1e-5)
    assert out["RADIUS"][l, 0] == pytest.approx(0.45, rel=1e-5)
    assert out["RADIUS"][r, 0] == pytest.approx(0.3, rel=1e-5)
    assert all(out[k][bg].max() == 0.0 for k in out)
    # Of the input index (the NaN point keeps its number, as Cycles drops no points).
    assert out["RANDOM"][l, 0] == pytest.approx(_hash_uint2_to_float(0, 0), abs=1e-6)
    assert out["RANDOM"][r, 0] == pytest.approx(_hash_uint2_to_float(2, 0), abs=1e-6)
    assert _hash_uint2_to_float(0, 0) != _hash_uint2_to_float(2, 0)


def _hash_uint2_to_float(kx, ky):
    """Cycles' hash_uint2_to_float (Bob Jenkins' lookup3 final mix), in Python."""
    mask = 0xFFFFFFFF

    def rot(x, k):
        return ((x << k) | (x >> (32 - k))) & mask

    a = b = c = (0xDEADBEEF + (2 << 2) + 13) & mask
    a, b = (a + kx) & mask, (b + ky) & mask
    c ^= b; c = (c - rot(b, 14)) & mask  # noqa: E702
    a ^= c; a = (a - rot(c, 11)) & mask  # noqa: E702
    b ^= a; b = (b - rot(a, 25)) & mask  # noqa: E702
    c ^= b; c = (c - rot(b, 16)) & mask  # noqa: E702
    a ^= c; a = (a - rot(c, 4)) & mask  # noqa: E702
    b ^= a; b = (b - rot(a, 14)) & mask  # noqa: E702
    c ^= b; c = (c - rot(b, 24)) & mask  # noqa: E702
    return c / float(mask)


def test_moving_cloud_is_hit_where_it_is_at_the_ray_time():
    """Transform motion blur: a cloud moving 2 units along x and turning over the shutter is
    hit where its transform at the ray's time puts each sphere (interpolated as moving
    instances are); rays spawned on it skip their sphere; its bounds hold it all the shutter."""
    pc = core()
    steps = []
    for k, a in enumerate(np.linspace(0.0, 0.6, 3)):
        m = np.eye(4)
        m[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        m[:3, 3] = (-1.0 + k, 0.0, 0.0)
        steps.append(m)
    steps = np.array(steps, np.float32)
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]], np.float32)
    s = _scene(pc, pts, [0.1, 0.1], matrix=steps[1], motion=steps)
    assert s.stats()["points"] == 2
    for time, k in ((0.0, 0), (0.5, 1), (1.0, 2)):
        for p in pts:
            c = steps[k, :3, :3] @ p + steps[k, :3, 3]
            o = np.array([[c[0], c[1], 5.0]], np.float32)
            d = np.array([[0.0, 0.0, -1.0]], np.float32)
            t = s.intersect(o, d, time=time)[0][0]
            assert t == pytest.approx(4.9, abs=1e-4), (time, p)
            hit = s.hit_surfaces(o, d)  # (time 0.5)
            if k == 1:
                assert hit["point"][0] and np.allclose(hit["ng"][0], (0, 0, 1), atol=1e-4)
                through = s.hit_surfaces(hit["origin_in"], d)  # its far side, a diameter on
                assert through["t"][0] == pytest.approx(0.2, abs=1e-4)
                again = s.hit_surfaces(hit["origin_in"], d, self_strand=hit["strand"])
                assert np.isinf(again["t"][0])
    # Halfway between steps 0 and 1 (time 0.25) the first sphere is at x = -0.5.
    o = np.array([[-0.5, 0.0, 5.0], [-1.0, 0.0, 5.0]], np.float32)
    t = s.intersect(o, np.tile(np.array([[0.0, 0.0, -1.0]], np.float32), (2, 1)), time=0.25)[0]
    assert t[0] == pytest.approx(4.9, abs=1e-4) and np.isinf(t[1])
    # Singular steps: the cloud stays static at its matrix.
    bad = steps.copy()
    bad[0, :3, :3] = 0.0
    st = _scene(pc, pts, [0.1, 0.1], matrix=steps[1], motion=bad)
    c = steps[1, :3, 3]
    assert st.intersect(np.array([[c[0], 0, 5]], np.float32), np.array([[0, 0, -1.0]], np.float32), time=0.0)[0][0] \
        == pytest.approx(4.9, abs=1e-4)


def test_hash_uint2_is_cycles_lookup3():
    """The core's hash_uint2 (a view's seed under multiview, addon/export/views.py) is the
    reference lookup3 above, on the words' edges and a spread of others."""
    pc = core()
    rng = np.random.default_rng(5)
    pairs = [(0, 0), (1, 0), (0, 1), (0xFFFFFFFF, 0xFFFFFFFF)] + [tuple(int(v) for v in p)
                                                                for p in rng.integers(0, 2**32, (64, 2))]
    for a, b in pairs:
        assert pc.hash_uint2(a, b) / float(0xFFFFFFFF) == _hash_uint2_to_float(a, b), (a, b)
