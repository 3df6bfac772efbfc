"""Motion blur of curves and point clouds in the core (issue 23): a moving or deforming set is hit
at time t exactly where a still set of its geometry at t is (the transform interpolated as
moving instances are, the keys / centres and radii linearly between steps, as Cycles' motion
curves and points); bad motion leaves the set still; still sets draw no ray times."""
import numpy as np
import pytest

from core_scenes import camera, core, render

pytestmark = pytest.mark.sanitize

pc = core()
TIMES = (0.0, 0.3, 0.5, 0.75, 1.0)


def _steps():
    """Three transforms: turning 50 degrees about a tilted axis, drifting and growing 20 %."""
    out = []
    for k, a in enumerate(np.radians([-25.0, 0.0, 25.0])):
        c, s = np.cos(a), np.sin(a)
        rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        rx = np.array([[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]])
        m = np.eye(4)
        m[:3, :3] = rx @ rz * (1.0 + 0.1 * k)
        m[:3, 3] = (-0.4 + 0.4 * k, 0.1 * k, 0.05)
        out.append(m)
    return np.array(out, np.float32)


def _strands(rng, n=12, keys=5):
    """Bent strands across the unit box (object space), radii 0.03-0.07."""
    pts = []
    for _ in range(n):
        a = rng.uniform(-0.8, 0.8, 3)
        b = rng.uniform(-0.8, 0.8, 3)
        t = np.linspace(0.0, 1.0, keys)[:, None]
        bend = np.sin(np.pi * t) * rng.normal(0.0, 0.2, 3)
        pts.append(a + (b - a) * t + bend)
    pts = np.concatenate(pts).astype(np.float32)
    offsets = np.arange(0, n * keys + 1, keys)
    radii = rng.uniform(0.03, 0.07, len(pts)).astype(np.float32)
    return pts, offsets, radii


def _curves_scene(pts, offsets, radii, matrix=None, shape="thick", **kw):
    s = pc.Scene()
    m = s.add_material("strand", base_color=(0.8, 0.8, 0.8))
    s.add_curves(pts, offsets, radii, m, matrix=matrix, curve_type="catmull_rom", subdivisions=4, shape=shape, **kw)
    s.commit()
    return s


def _points_scene(pts, radii, matrix=None, **kw):
    s = pc.Scene()
    m = s.add_material("points", base_color=(0.8, 0.8, 0.8))
    s.add_points(pts, radii, m, matrix=matrix, **kw)
    s.commit()
    return s


def _rays(rng, n=3000):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    target = rng.uniform(-1.2, 1.2, size=(n, 3))
    return (target - 4.0 * d).astype(np.float32), d.astype(np.float32)


def _agree(moving, still, o, d, time, what):
    """The moving scene at `time` against the still one: the same rays hit (but for a few
    grazing ones), at the same distance, with the same normal."""
    a = moving.hit_surfaces(o, d, time=time)
    b = still.hit_surfaces(o, d)
    ha, hb = np.isfinite(a["t"]), np.isfinite(b["t"])
    assert hb.sum() > 200, what  # (the test means something)
    assert (ha != hb).mean() < 0.003, (what, time, int((ha != hb).sum()))
    both = ha & hb
    close = np.abs(a["t"][both] - b["t"][both]) < 1e-3
    assert close.mean() > 0.995, (what, time)
    ng = np.einsum("ij,ij->i", a["ng"][both][close], b["ng"][both][close])
    assert (ng > 0.999).mean() > 0.99, (what, time)
    return ha


@pytest.mark.parametrize("shape", ["thick", "ribbon"])
def test_moving_strands_are_hit_where_the_transform_at_the_ray_time_puts_them(shape):
    rng = np.random.default_rng(1)
    pts, offsets, radii = _strands(rng)
    steps = _steps()
    moving = _curves_scene(pts, offsets, radii, matrix=steps[1], shape=shape, motion=steps)
    o, d = _rays(rng)
    seen = []
    for time in TIMES:
        still = _curves_scene(pts, offsets, radii, matrix=pc.motion_transform(steps, time), shape=shape)
        seen.append(_agree(moving, still, o, d, time, f"moving {shape}"))
    assert (seen[0] != seen[-1]).mean() > 0.05  # (it moves)


def _lerp(steps, time):
    f = time * (len(steps) - 1)
    k = min(int(f), len(steps) - 2)
    w = f - k
    return (steps[k] + (steps[k + 1] - steps[k]) * w).astype(np.float32)


@pytest.mark.parametrize("shape", ["thick", "ribbon"])
@pytest.mark.parametrize("moves", [False, True])
def test_deforming_strands_are_hit_where_their_interpolated_keys_are(shape, moves):
    """Keys and radii at 3 steps (the middle one the frame's), the strands cut from the keys
    interpolated linearly at the ray's time (Cycles' motion curve keys); with the transform
    too when `moves`."""
    rng = np.random.default_rng(2)
    pts, offsets, radii = _strands(rng)
    kp = np.stack([pts + rng.normal(0.0, 0.15, pts.shape), pts, pts + rng.normal(0.0, 0.15, pts.shape)]).astype(np.float32)
    kr = np.stack([radii * 0.6, radii, radii * 1.4]).astype(np.float32)
    steps = _steps() if moves else np.array([np.eye(4)] * 3, np.float32)
    kw = {"motion": steps} if moves else {}
    moving = _curves_scene(pts, offsets, radii, matrix=steps[1], shape=shape, motion_points=kp, motion_radii=kr, **kw)
    assert moving.stats()["motion_rejected"] == 0
    o, d = _rays(rng)
    seen = []
    for time in TIMES:
        m = pc.motion_transform(steps, time) if moves else steps[1]
        still = _curves_scene(_lerp(kp, time), offsets, _lerp(kr, time), matrix=m, shape=shape)
        seen.append(_agree(moving, still, o, d, time, f"deforming {shape}"))
    assert (seen[0] != seen[-1]).mean() > 0.05


@pytest.mark.parametrize("moves", [False, True])
def test_deforming_points_are_hit_where_their_interpolated_centres_are(moves):
    rng = np.random.default_rng(3)
    pts = rng.uniform(-0.8, 0.8, (200, 3)).astype(np.float32)
    radii = rng.uniform(0.03, 0.08, 200).astype(np.float32)
    kp = np.stack([pts - rng.normal(0.0, 0.1, pts.shape), pts, pts + rng.normal(0.0, 0.1, pts.shape)]).astype(np.float32)
    kr = np.stack([radii * 0.7, radii, radii * 1.3]).astype(np.float32)
    steps = _steps() if moves else np.array([np.eye(4)] * 3, np.float32)
    kw = {"motion": steps} if moves else {}
    moving = _points_scene(pts, radii, matrix=steps[1], motion_points=kp, motion_radii=kr, **kw)
    o, d = _rays(rng)
    seen = []
    for time in TIMES:
        m = pc.motion_transform(steps, time) if moves else steps[1]
        still = _points_scene(_lerp(kp, time), _lerp(kr, time), matrix=m)
        seen.append(_agree(moving, still, o, d, time, "deforming points"))
    assert (seen[0] != seen[-1]).mean() > 0.05
    # Without radii steps the frame's radii hold at every step (velocity blur).
    velocity = _points_scene(pts, radii, motion_points=kp)
    still = _points_scene(_lerp(kp, 0.25), radii)
    _agree(velocity, still, o, d, 0.25, "points, frame radii")


def test_bad_motion_leaves_the_sets_still():
    """NaN keys or centres, a step that cuts into other pieces (a strand's radius 0 at a step),
    singular transforms: counted in motion_rejected, the set rendered as the frame; wrong
    shapes raise ValueError."""
    rng = np.random.default_rng(4)
    pts, offsets, radii = _strands(rng, n=6)
    o, d = _rays(rng, 1500)
    frame = _curves_scene(pts, offsets, radii)
    still_t = frame.hit_surfaces(o, d)["t"]
    nan = np.stack([pts, pts, pts])
    nan[0, 3] = np.nan
    thin = np.stack([radii, radii, radii])
    thin[2, :5] = 0.0  # the whole first strand at the last step: it would be left out there
    singular = np.array([np.eye(4)] * 3, np.float32)
    singular[0, :3, :3] = 0.0
    moved = np.stack([pts + 0.3, pts, pts - 0.3]).astype(np.float32)
    for kw in ({"motion_points": nan}, {"motion_points": moved, "motion_radii": thin}, {"motion": singular}):
        s = _curves_scene(pts, offsets, radii, **kw)
        assert s.stats()["motion_rejected"] == 1, kw.keys()
        for time in (0.0, 1.0):
            np.testing.assert_array_equal(s.hit_surfaces(o, d, time=time)["t"], still_t)
    p = rng.uniform(-0.5, 0.5, (50, 3)).astype(np.float32)
    r = np.full(50, 0.05, np.float32)
    bad = np.stack([p, p, p])
    bad[1, 7] = np.inf
    s = _points_scene(p, r, motion_points=bad)
    assert s.stats()["motion_rejected"] == 1
    np.testing.assert_array_equal(s.hit_surfaces(o, d, time=0.0)["t"], _points_scene(p, r).hit_surfaces(o, d)["t"])
    with pytest.raises(ValueError):
        _curves_scene(pts, offsets, radii, motion_points=np.stack([pts[:-1]] * 3))
    with pytest.raises(ValueError):
        _points_scene(p, r, motion_points=np.stack([p] * 3), motion_radii=np.stack([r[:-1]] * 3))


def test_still_sets_draw_no_time_and_render_bit_for_bit():
    """Steps equal to the frame's (transform or deformation) leave the sets still: no 'motion
    blur' feature (no time drawn per camera ray) and the very image of a scene without them;
    a deforming set turns the feature on."""
    rng = np.random.default_rng(5)
    pts, offsets, radii = _strands(rng, n=8)
    p = rng.uniform(-0.6, 0.6, (40, 3)).astype(np.float32)
    r = np.full(40, 0.06, np.float32)

    def scene(**kw):
        s = pc.Scene()
        m = s.add_material("grey", base_color=(0.8, 0.8, 0.8))
        s.add_curves(pts, offsets, radii, m, **kw.get("curves", {}))
        s.add_points(p, r, m, **kw.get("points", {}))
        s.add_sun_light((0.3, -0.5, 0.8), (2.0, 2.0, 2.0))
        s.set_camera(camera(pc, (0.0, -3.0, 1.0), (0.0, 0.0, 0.0)))
        s.commit()
        return s

    plain, plain_stats = render(pc, scene(), 24, 24, 4)
    same = np.array([np.eye(4)] * 3, np.float32)
    still, stats = render(pc, scene(curves={"motion": same, "motion_points": np.stack([pts] * 3)},
                                    points={"motion": same, "motion_points": np.stack([p] * 3)}), 24, 24, 4)
    assert "motion blur" not in plain_stats["features"] and "motion blur" not in stats["features"]
    np.testing.assert_array_equal(plain, still)
    _, moving = render(pc, scene(points={"motion_points": np.stack([p - 0.1, p, p + 0.1])}), 24, 24, 4)
    assert "motion blur" in moving["features"]
