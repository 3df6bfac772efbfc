"""Curves (hair) in the core: round strands hit where an analytic cylinder or cone is, with
its normal; rays spawned from hits never hit the strand they left; bad strands are left out."""
import numpy as np
import pytest

from core_scenes import camera, core, random_rotation, render

pytestmark = pytest.mark.sanitize


def _scene(pc, points, offsets, radii, curve_type="poly", matrix=None, subdivisions=8):
    s = pc.Scene()
    m = s.add_material("strand", base_color=(0.8, 0.8, 0.8))
    s.add_curves(np.asarray(points, np.float32), np.asarray(offsets), None if radii is None else
                 np.asarray(radii, np.float32), m, matrix=matrix, curve_type=curve_type,
                 subdivisions=subdivisions)
    s.commit()
    return s


def _rays_at(rng, n, center, spread, dist=5.0):
    """Rays from random directions aimed at random points near `center`."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    target = np.asarray(center) + rng.uniform(-spread, spread, size=(n, 3))
    return (target - d * dist).astype(np.float32), d.astype(np.float32)


def _cone_hits(o, d, p0, p1, r0, r1):
    """Entering hits of rays on the infinite cone through (p0, r0), (p1, r1), float64, with the
    axial position s in [0, 1]; nan where there is none."""
    o, d = o.astype(np.float64), d.astype(np.float64)
    axis = p1 - p0
    L = np.linalg.norm(axis)
    a = axis / L
    k = (r1 - r0) / L
    w = o - p0
    ws, ds = w @ a, d @ a
    wp, dp = w - np.outer(ws, a), d - np.outer(ds, a)
    rr = r0 + k * ws
    A = (dp * dp).sum(1) - k * k * ds * ds
    B = (wp * dp).sum(1) - k * ds * rr
    C = (wp * wp).sum(1) - rr * rr
    disc = B * B - A * C
    with np.errstate(invalid="ignore"):
        t = (-B - np.sqrt(disc)) / A
    s = (ws + t * ds) / L
    return np.where((disc >= 0) & (A > 0), t, np.nan), s


@pytest.mark.parametrize("r0, r1", [(0.1, 0.1), (0.15, 0.05)])
def test_hits_match_analytic_cone(r0, r1):
    pc = core()
    rng = np.random.default_rng(1)
    rot = random_rotation(3)
    p0, p1 = rot @ np.array([-1.0, 0.0, 0.0]) + 0.3, rot @ np.array([1.0, 0.0, 0.0]) + 0.3
    s = _scene(pc, [p0, p1], [0, 2], [r0, r1])
    o, d = _rays_at(rng, 4000, (p0 + p1) / 2, 0.6)
    hit = s.hit_surfaces(o, d)
    t_ref, s_ref = _cone_hits(o, d, p0, p1, r0, r1)
    # On the body, away from the end caps: same hit distance and normal.
    body = np.isfinite(t_ref) & (s_ref > 0.02) & (s_ref < 0.98)
    assert body.sum() > 500
    assert np.all(np.isfinite(hit["t"][body]))
    np.testing.assert_allclose(hit["t"][body], t_ref[body], atol=2e-5 * 5)
    p = o[body] + d[body] * t_ref[body, None]
    axis = (p1 - p0) / np.linalg.norm(p1 - p0)
    q = p0 + np.outer(s_ref[body] * np.linalg.norm(p1 - p0), axis)
    radial = p - q
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    n_ref = radial - axis * (r1 - r0) / np.linalg.norm(p1 - p0)
    n_ref /= np.linalg.norm(n_ref, axis=1, keepdims=True)
    assert np.abs(hit["ng"][body] - n_ref).max() < 1e-4
    assert np.abs(hit["tangent"][body] - axis).max() < 1e-5
    np.testing.assert_allclose(hit["p"][body], p, atol=1e-5)
    # Rays that miss the cone's body and both end spheres find nothing.
    def sphere_miss(c, r):
        w = o - c
        b = (w * d).sum(1)
        return b * b - ((w * w).sum(1) - r * r) < 0
    miss = ~np.isfinite(t_ref) & sphere_miss(p0, r0) & sphere_miss(p1, r1)
    assert miss.sum() > 500
    assert np.all(np.isinf(hit["t"][miss]))


def test_spawned_rays_do_not_hit_their_strand():
    """From every hit, rays on the outside (from origin_out) and into the strand (origin_in,
    the transmitted lobes of hair) that leave the strand (self, as a path's spawned rays: Cycles
    skips the curve a ray leaves) find nothing: one straight strand, far from the origin too.
    Without self, the rays into the strand meet its inside, on the far wall."""
    pc = core()
    rng = np.random.default_rng(7)
    for offset, r in ((0.0, 0.02), (300.0, 0.05)):
        p0, p1 = np.array([-1.0, 0.2, 0.1]) + offset, np.array([1.0, -0.1, 0.3]) + offset
        s = _scene(pc, [p0, p1], [0, 2], [r, r])
        o, d = _rays_at(rng, 3000, (p0 + p1) / 2, 0.05, dist=2.0)
        hit = s.hit_surfaces(o, d)
        ok = np.isfinite(hit["t"])
        assert ok.sum() > 1000
        n = hit["ng"][ok]
        w = rng.normal(size=n.shape)
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        # Grazing directions too: half of them within a few degrees of the tangent plane.
        graze = rng.uniform(size=len(w)) < 0.5
        w[graze] -= n[graze] * ((w[graze] * n[graze]).sum(1, keepdims=True) * 0.97)
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        out = (w * n).sum(1) > 0
        org = np.where(out[:, None], hit["origin_out"][ok], hit["origin_in"][ok]).astype(np.float32)
        assert np.all(hit["strand"][ok] == 0)
        again = s.hit_surfaces(org, w.astype(np.float32), self_strand=hit["strand"][ok])
        assert np.isinf(again["t"]).all(), f"{np.isfinite(again['t']).sum()} self-hits at offset {offset}"
        # The far wall: leaving the strand (normal along the ray), more than a radius away for
        # steep rays (grazing ones may run along the strand and out of an end).
        steep = ~out & ((w * n).sum(1) < -0.5)
        assert steep.sum() > 100
        inside = s.hit_surfaces(org[steep], w[steep].astype(np.float32))
        assert np.all(inside["strand"] == 0)
        assert np.all((inside["ng"] * w[steep]).sum(1) > 0)
        assert np.all(inside["t"] > r * 0.9)


def test_catmull_rom_surface_follows_the_curve():
    """Hits on a bent Catmull-Rom strand lie one radius from the curve through its keys."""
    pc = core()
    keys = np.array([[-1.0, 0.0, 0.0], [-0.3, 0.4, 0.0], [0.4, -0.2, 0.1], [1.0, 0.3, 0.0]])
    r = 0.05
    s = _scene(pc, keys, [0, 4], [r] * 4, curve_type="catmull_rom", subdivisions=16)
    # The curve densely, with Cycles' clamped end keys.
    pts = []
    for k in range(3):
        a, b, c, e = keys[max(k - 1, 0)], keys[k], keys[k + 1], keys[min(k + 2, 3)]
        t = np.linspace(0, 1, 400)[:, None]
        pts.append(0.5 * ((-t**3 + 2 * t**2 - t) * a + (3 * t**3 - 5 * t**2 + 2) * b +
                          (-3 * t**3 + 4 * t**2 + t) * c + (t**3 - t**2) * e))
    curve = np.concatenate(pts)
    rng = np.random.default_rng(2)
    o, d = _rays_at(rng, 3000, (0.0, 0.1, 0.0), 0.9)
    hit = s.hit_surfaces(o, d)
    ok = np.isfinite(hit["t"])
    # The flat end discs (test_strand_ends_are_flat_discs) lie within a radius of the end keys.
    end = np.minimum(*(np.linalg.norm(hit["p"] - keys[i], axis=1) for i in (0, -1)))
    disc = ok & (np.abs((hit["ng"] * hit["tangent"]).sum(1)) > 0.999) & (end < 1.01 * r)
    ok &= ~disc
    assert ok.sum() > 100
    dist = np.linalg.norm(hit["p"][ok][:, None, :] - curve[None], axis=2).min(axis=1)
    # 16 cones per segment: the chords' sagitta (segment length^2 / 8 bend radius, ~8e-4 here)
    # is what separates them from the true tube.
    assert np.abs(dist - r).max() < 0.03 * r, np.abs(dist - r).max()


def test_instanced_transform_scales_radius():
    pc = core()
    m = np.diag([2.0, 2.0, 2.0, 1.0]).astype(np.float32)
    m[:3, 3] = (0.0, 0.0, 1.0)
    s = _scene(pc, [[-1, 0, 0], [1, 0, 0]], [0, 2], [0.1, 0.1], matrix=m)
    hit = s.hit_surfaces(np.array([[0.0, 0.0, 5.0]], np.float32), np.array([[0.0, 0.0, -1.0]], np.float32))
    assert hit["t"][0] == pytest.approx(5.0 - 1.0 - 0.2, abs=1e-5)


def test_bad_strands_are_left_out():
    """NaN or infinite points, zero and NaN radii, zero length, single points: left out (counted),
    never a crash; the good strand still renders."""
    pc = core()
    nan, inf = float("nan"), float("inf")
    strands = [
        ([[0, 0, 0], [1, 0, 0]], [0.05, 0.05]),      # good
        ([[0, 1, 0], [nan, 1, 0]], [0.05, 0.05]),    # NaN point
        ([[0, 2, 0], [1, 2, inf]], [0.05, 0.05]),    # inf point
        ([[0, 3, 0], [1, 3, 0]], [0.0, 0.0]),        # zero radius
        ([[0, 4, 0], [1, 4, 0]], [nan, 0.05]),       # NaN radius
        ([[0, 5, 0], [0, 5, 0]], [0.05, 0.05]),      # zero length
        ([[0, 6, 0]], [0.05]),                        # one point
    ]
    pts = np.concatenate([np.asarray(p, np.float32) for p, _ in strands])
    rad = np.concatenate([np.asarray(r, np.float32) for _, r in strands])
    offsets = np.concatenate([[0], np.cumsum([len(p) for p, _ in strands])])
    for kind in ("poly", "catmull_rom"):
        s = _scene(pc, pts, offsets, rad, curve_type=kind)
        st = s.stats()
        assert (st["curves"], st["skipped_curves"]) == (1, 6)
        # Rays aimed at every strand's axis: only the good one's hit.
        rng = np.random.default_rng(5)
        target = np.stack([rng.uniform(0.1, 0.9, 700), rng.integers(0, 7, 700), np.zeros(700)], 1)
        d = rng.normal(size=(700, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        hit = s.hit_surfaces((target - 3 * d).astype(np.float32), d.astype(np.float32))
        ok = np.isfinite(hit["t"])
        assert ok[target[:, 1] == 0].all() and (~ok).sum() > 300
        assert np.abs(hit["p"][ok][:, 1]).max() < 0.06  # rays aimed elsewhere may cross it
        assert np.isfinite(hit["p"][ok]).all() and np.isfinite(hit["ng"][ok]).all()
    with pytest.raises(ValueError):
        s = pc.Scene()
        s.add_curves(pts, np.array([0, 3, 2]), rad)
    with pytest.raises(ValueError):
        pc.Scene().add_curves(pts, np.array([0, len(pts) + 1]), rad)
    # Random garbage strands: commit and render without a crash.
    rng = np.random.default_rng(11)
    pts = rng.normal(size=(300, 3)).astype(np.float32)
    pts[rng.uniform(size=300) < 0.05] = np.nan
    rad = np.abs(rng.normal(size=300) * 0.05).astype(np.float32)
    rad[rng.uniform(size=300) < 0.1] = 0.0
    cuts = np.unique(np.concatenate([[0, 300], rng.integers(0, 300, 80)]))
    s = _scene(pc, pts, cuts, rad, curve_type="catmull_rom")
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0, -6, 1), (0, 0, 0)))
    s.commit()
    img, _ = render(pc, s, 16, 16, 4)
    assert np.isfinite(img).all() and img[..., :3].max() > 0.0


def test_curve_uvs_take_one_uv_per_strand():
    """add_curves(uvs=): per uv set one uv per strand (particle hair's emitter UV at the root);
    other shapes and set indices are refused with a ValueError."""
    pc = core()
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    offsets = np.array([0, 2, 4])
    s = pc.Scene()
    s.add_curves(pts, offsets, np.full(4, 0.05, np.float32), uvs={1: np.array([[0.25, 0.5], [np.nan, 1.0]],
                                                                           np.float32)})
    s.commit()
    assert s.stats()["curves"] == 2
    for bad in ({0: np.zeros((3, 2), np.float32)}, {0: np.zeros((2, 3), np.float32)},
                {9: np.zeros((2, 2), np.float32)}):
        with pytest.raises(ValueError):
            pc.Scene().add_curves(pts, offsets, None, uvs=bad)


@pytest.mark.parametrize("kind", ["poly", "catmull_rom"])
def test_strand_ends_are_flat_discs(kind):
    """A strand's root and tip are cut off flat (Cycles' thick curves): rays along the axis hit
    the end disc with the axis as normal; rays beyond an end, where a half-sphere cap would be,
    miss; rays leaving through an end from inside find nothing."""
    pc = core()
    s = _scene(pc, [[0, 0, 0], [0.5, 0, 0], [1, 0, 0]], [0, 3], [0.1, 0.1, 0.05], curve_type=kind)
    rng = np.random.default_rng(3)
    yz = rng.uniform(-1, 1, (400, 2))
    yz = yz[(yz ** 2).sum(1) < 0.9 ** 2]
    n = len(yz)
    for x0, x_end, r, sign in ((-2.0, 0.0, 0.1, 1.0), (3.0, 1.0, 0.05, -1.0)):
        o = np.column_stack([np.full(n, x0), yz * r]).astype(np.float32)
        d = np.tile(np.float32([sign, 0, 0]), (n, 1))
        hit = s.hit_surfaces(o, d)
        assert np.all(np.isfinite(hit["t"]))
        np.testing.assert_allclose(hit["p"][:, 0], x_end, atol=1e-5)
        np.testing.assert_allclose(hit["ng"], np.tile([-sign, 0, 0], (n, 1)), atol=1e-5)
        # Beyond the end, inside the old cap's sphere: nothing to hit.
        o2 = np.column_stack([np.full(n, x_end - sign * 0.5 * r), np.full(n, -1.0), yz[:, 0] * r * 0.5])
        d2 = np.tile(np.float32([0, 1, 0]), (n, 1))
        assert np.all(np.isinf(s.hit_surfaces(o2.astype(np.float32), d2)["t"]))
    # From inside out through the root: no hit (only entering hits count).
    o3 = np.column_stack([np.full(n, 0.3), yz * 0.05]).astype(np.float32)
    assert np.all(np.isinf(s.hit_surfaces(o3, np.tile(np.float32([-1, 0, 0]), (n, 1)))["t"]))


def _tube_exit(o, d, p0, a, r):
    """Where rays from inside an infinite cylinder (point p0, unit axis a, radius r) leave it,
    float64."""
    o, d = o.astype(np.float64), d.astype(np.float64)
    w = o - p0
    wp, dp = w - np.outer(w @ a, a), d - np.outer(d @ a, a)
    A, B, C = (dp * dp).sum(1), (wp * dp).sum(1), (wp * wp).sum(1) - r * r
    return (-B + np.sqrt(B * B - A * C)) / A


def test_rays_inside_a_strand_hit_its_inside():
    """Cycles' thick curves (Embree's round curves, no back-face culling in Blender 4.5) report
    where a ray that starts inside a strand leaves it, unless the ray leaves that strand (self):
    the case of a ray spawned on one strand inside another, interpenetrating one. Analytic
    exit distance and outward normal on a straight strand; on a strand bent at a joint, the exit
    points lie on the union of the two pieces' tubes (none inside the other piece)."""
    pc = core()
    rng = np.random.default_rng(11)
    r = 0.05
    p0, p1 = np.array([-1.0, 0.2, 0.1]), np.array([1.0, -0.1, 0.3])
    a = (p1 - p0) / np.linalg.norm(p1 - p0)
    s = _scene(pc, [p0, p1], [0, 2], [r, r])
    n = 3000
    q = rng.uniform(-1, 1, (n, 3))
    q = q[(q ** 2).sum(1) < 1][:2000]
    o = (0.5 * (p0 + p1) + rng.uniform(-0.3, 0.3, (len(q), 1)) * (p1 - p0) + 0.9 * r * q).astype(np.float32)
    d = rng.normal(size=o.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[np.abs(d @ a) < 0.9].astype(np.float32)  # leaving through the side, not an end
    o = o[: len(d)]
    hit = s.hit_surfaces(o, d)
    assert np.all(np.isfinite(hit["t"])) and np.all(hit["strand"] == 0)
    np.testing.assert_allclose(hit["t"], _tube_exit(o, d, p0, a, r), rtol=1e-4, atol=1e-5)
    radial = hit["p"] - p0 - np.outer((hit["p"] - p0) @ a, a)
    np.testing.assert_allclose(hit["ng"], radial / np.linalg.norm(radial, axis=1, keepdims=True), atol=1e-4)
    assert np.all((hit["ng"] * d).sum(1) > 0)  # the inside: the normal points along the ray
    assert np.all(np.isinf(s.hit_surfaces(o, d, self_strand=np.zeros(len(d), np.int64))["t"]))

    # Bent by 40 degrees at the joint: the exits lie on the union's surface.
    bend = np.radians(40.0)
    pts = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [np.cos(bend), np.sin(bend), 0.0]])
    sb = _scene(pc, pts, [0, 3], [r, r, r])
    q = rng.uniform(-1, 1, (4000, 3))
    q = q[(q ** 2).sum(1) < 1][:2500]
    o = (q * 1.5 * r).astype(np.float32)  # around the joint
    def dist_to_axes(x):
        dd = []
        for u, v in ((pts[0], pts[1]), (pts[1], pts[2])):
            e = v - u
            tt = np.clip(((x - u) @ e) / (e @ e), 0, 1)
            dd.append(np.linalg.norm(x - u - np.outer(tt, e), axis=1))
        return np.minimum(*dd)
    inside = dist_to_axes(o.astype(np.float64)) < 0.98 * r
    o = o[inside]
    d = rng.normal(size=o.shape).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hit = sb.hit_surfaces(o, d)
    ok = np.isfinite(hit["t"])
    assert ok.mean() > 0.9  # (the rest leave through the strand's open ends)
    assert np.abs(dist_to_axes(hit["p"][ok].astype(np.float64)) - r).max() < 1e-4 * r + 1e-6


@pytest.mark.parametrize("shape", ["thick", "ribbon"])
def test_strands_take_their_own_materials(shape):
    """add_curves(materials=): a material per strand (Cycles' per-curve material index), here
    emitters of three colours seen directly: each strand shows its own; an id not in the scene
    falls back to the set's material; a wrong length is a ValueError."""
    pc = core()
    s = pc.Scene()
    ids = [s.add_material(n, base_color=(0, 0, 0), emission=e)
           for n, e in (("red", (1, 0, 0)), ("green", (0, 1, 0)), ("blue", (0, 0, 1)))]
    x = np.array([-0.6, -0.2, 0.2, 0.6])
    pts = np.concatenate([[[xi, 0.0, -1.0], [xi, 0.0, 1.0]] for xi in x]).astype(np.float32)
    offsets = np.arange(0, 9, 2)
    with pytest.raises(ValueError):
        s.add_curves(pts, offsets, np.full(8, 0.08, np.float32), ids[0], materials=np.array([0, 1]), shape=shape)
    s.add_curves(pts, offsets, np.full(8, 0.08, np.float32), ids[2], curve_type="poly", shape=shape,
                 materials=np.array([ids[1], ids[0], 99, ids[1]]))
    s.set_camera(camera(pc, (0.0, -5.0, 0.0), (0.0, 0.0, 0.0), lens=50.0))
    s.commit()
    img, _ = render(pc, s, 64, 16, 4)
    row = img[8, :, :3]
    cols = [int(round(32 + xi / (36.0 / 50.0 * 5.0) * 64)) for xi in x]  # (36 mm film, 50 mm lens)
    got = [int(np.argmax(row[c])) for c in cols]
    assert got == [1, 0, 2, 1], (got, row[cols])
