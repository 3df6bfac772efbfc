"""Motion blur in the core (issue 23): shutter times, moving instances, moving cameras."""
import numpy as np
import pytest

from core_scenes import camera, core, quad, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def affine(linear, shift):
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = shift
    return m.astype(np.float32)


# Three steps (shutter start, middle, end): a turn of 50 then 70 degrees about z, a move along x
# then y, and a scale that grows. Interpolated by hand below: per segment, the angle and the
# translation and scale linearly (slerp about one axis turns at a constant rate).
ANGLES = np.radians([-20.0, 30.0, 100.0])
SHIFTS = np.array([[-0.6, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.5, 0.2]])
SCALES = np.array([0.8, 1.0, 1.3])
STEPS = np.stack([affine(rot_z(a) * k, t) for a, t, k in zip(ANGLES, SHIFTS, SCALES)])


def expected_matrix(time):
    x = time * 2.0
    k = min(int(x), 1)
    f = x - k
    lerp = lambda a: a[k] * (1 - f) + a[k + 1] * f  # noqa: E731
    return affine(rot_z(lerp(ANGLES)) * lerp(SCALES), lerp(SHIFTS))


def box_mesh():
    """An off-centre box (rotation moves it far): 12 triangles."""
    lo, hi = np.array([0.3, -0.2, -0.3]), np.array([0.9, 0.25, 0.35])
    c = np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)], np.float32)
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = np.array([t for a, b, cc, d in faces for t in ((a, b, cc), (a, cc, d))], np.int32)
    return c, tris


def scene_with(matrix, motion=None, mesh=None):
    s = pc.Scene()
    m = s.add_material("m", (0.5, 0.5, 0.5))
    pos, tris = box_mesh() if mesh is None else mesh
    s.add_instance(s.add_mesh(pos, tris, material_slots=[m]), matrix, motion=motion)
    s.commit()
    return s


def rays(n=4000, seed=1, matrix=None):
    """Rays from a sphere of radius 3 towards random points around the box (under `matrix`)."""
    rng = np.random.default_rng(seed)
    org = rng.normal(size=(n, 3))
    org = (org / np.linalg.norm(org, axis=1, keepdims=True) * 3.0).astype(np.float32)
    target = rng.uniform((0.1, -0.4, -0.5), (1.1, 0.45, 0.55), size=(n, 3))
    if matrix is not None:
        target = target @ np.asarray(matrix)[:3, :3].T + np.asarray(matrix)[:3, 3]
    return org, (target - org).astype(np.float32)


def test_interpolated_transform_matches_slerp_and_lerp():
    for time in (0.0, 0.13, 0.5, 0.77, 1.0):
        got = pc.motion_transform(STEPS, time)
        np.testing.assert_allclose(got, expected_matrix(time), atol=2e-5)


@pytest.mark.parametrize("time", [0.0, 0.21, 0.5, 0.64, 0.93, 1.0])
def test_moving_instance_hits_as_static_one_at_its_time(time):
    org, d = rays(matrix=expected_matrix(time))
    moving = scene_with(STEPS[1], STEPS)
    static = scene_with(expected_matrix(time))
    assert moving.stats()["motion_instances"] == 1
    t_m, prim_m, b1_m, b2_m = moving.intersect(org, d, time=time)
    t_s, prim_s, b1_s, b2_s = static.intersect(org, d)
    hit = np.isfinite(t_s)
    assert 0.15 < hit.mean() < 0.9  # the rays test the object, not the background
    # Same hits (up to rays grazing an edge), same distances and barycentrics.
    same = (prim_m == prim_s)
    assert same.mean() > 0.998
    both = same & hit
    np.testing.assert_allclose(t_m[both], t_s[both], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(b1_m[both], b1_s[both], atol=1e-3)
    # A different time moves it: the hits change.
    other = scene_with(expected_matrix((time + 0.5) % 1.0))
    assert (other.intersect(org, d)[1] != prim_s).mean() > 0.05
    # Shadow rays see the same.
    occ_m = moving.occluded(org, d, 1.0, time=time)
    occ_s = static.occluded(org, d, 1.0)
    assert (occ_m == occ_s).mean() > 0.998


def test_motion_bounds_hold_the_object_at_every_time():
    """Rays aimed at the moving box at many times (the top level must never cull them): every
    ray that hits the static box at that time hits the moving one."""
    big = [affine(rot_z(a), (0.0, 0.0, 0.0)) for a in np.radians([0.0, 170.0])]  # a half turn
    moving = scene_with(big[0], np.stack(big))
    for time in np.linspace(0.0, 1.0, 11):
        static = scene_with(pc.motion_transform(np.stack(big), float(time)))
        org, d = rays(2000, seed=3, matrix=pc.motion_transform(np.stack(big), float(time)))
        hit_s = np.isfinite(static.intersect(org, d)[0])
        hit_m = np.isfinite(moving.intersect(org, d, time=float(time))[0])
        assert hit_s.sum() > 50
        assert (hit_s == hit_m).mean() > 0.998


def test_bad_motion_is_dropped_not_fatal():
    bad = STEPS.copy()
    bad[2, 0, 3] = np.nan
    s = scene_with(STEPS[1], bad)
    st = s.stats()
    assert st["motion_rejected"] == 1 and st["motion_instances"] == 0
    org, d = rays(500)
    static = scene_with(STEPS[1])
    np.testing.assert_array_equal(s.intersect(org, d, time=0.0)[1], static.intersect(org, d)[1])
    singular = STEPS.copy()
    singular[0, :3, :3] = 0.0
    assert scene_with(STEPS[1], singular).stats()["motion_rejected"] == 1
    # Equal steps are no motion at all.
    assert scene_with(STEPS[1], np.stack([STEPS[1]] * 3)).stats()["motion_instances"] == 0
    with pytest.raises(ValueError):
        scene_with(STEPS[1], STEPS[:1])  # one step is not a motion


def ks_statistic(samples, cdf):
    x = np.sort(samples)
    n = len(x)
    f = cdf(x)
    return max(np.max(np.arange(1, n + 1) / n - f), np.max(f - np.arange(n) / n))


def test_shutter_time_follows_the_curve():
    cam = pc.Camera()
    u = np.random.default_rng(7).uniform(size=3000)
    crit = 1.63 / np.sqrt(len(u)) + 1.0 / 256  # KS at 1 %, plus the table's own resolution
    # Box shutter (no curve): uniform times.
    t = np.array([cam.shutter_time(float(x)) for x in u])
    assert ks_statistic(t, lambda x: x) < crit
    # A ramp: density 2t, CDF t^2.
    cam.shutter_curve = list(np.linspace(0.0, 1.0, 256))
    t = np.array([cam.shutter_time(float(x)) for x in u])
    assert ks_statistic(t, lambda x: x * x) < crit
    assert ks_statistic(t, lambda x: x) > 3 * crit  # the test can tell the two apart
    # A bad curve is a box, not a crash.
    cam.shutter_curve = [float("nan")] * 16
    assert 0.0 <= cam.shutter_time(0.3) <= 1.0


BAR = 0.4  # the bar's width


def moving_bar_scene(curve=None, camera_motion=False):
    """An emissive vertical bar that sweeps from x = -1 to x = 1 over the shutter (or a still bar
    and a camera that sweeps the other way), seen head-on by an orthographic camera 2.4 wide."""
    s = pc.Scene()
    light = s.add_material("bar", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    pos, tris = quad((-BAR / 2, -1.0, 0.0), (BAR, 0.0, 0.0), (0.0, 2.0, 0.0))
    sweep = np.stack([affine(np.eye(3), (x, 0.0, 0.0)) for x in (-1.0, 0.0, 1.0)])
    mesh = s.add_mesh(pos, tris, material_slots=[light])
    s.add_instance(mesh, sweep[1], motion=None if camera_motion else sweep)
    cam = camera(pc, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    cam.type = "ORTHO"
    cam.ortho_scale = 2.4
    if camera_motion:
        m = np.asarray(cam.matrix_world)
        cam.motion = np.stack([affine(m[:3, :3], m[:3, 3] - (x, 0.0, 0.0)) for x in (-1.0, 0.0, 1.0)])
    if curve is not None:
        cam.shutter_curve = curve
    s.set_camera(cam)
    return s


def column_profile(scene, samples):
    st = pc.RenderSettings()
    st.width, st.height, st.samples = 48, 16, samples
    st.filter_type, st.filter_width = "box", 1.0
    sess = pc.Session(scene, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    assert "motion blur" in sess.stats()["features"]
    return sess.film()[..., 0].mean(axis=0)


@pytest.mark.parametrize("camera_motion", [False, True])
def test_rendered_exposure_follows_the_shutter_curve(camera_motion):
    """Each column of the sweep is exposed for as long as the bar covers it, weighted by the
    shutter curve at that time: the image's column profile is the curve's time density."""
    ramp = list(np.linspace(0.0, 1.0, 256))
    prof = column_profile(moving_bar_scene(ramp, camera_motion), 32)
    # Column centres in world x, and the time the bar's centre is there (x = 2 t - 1). A point
    # is covered for BAR / 2 of the shutter (speed 2): with density 2 t, its exposure is BAR t
    # (exactly, for a linear density, where the bar stays inside the sweep).
    x = (np.arange(48) + 0.5) / 48 * 2.4 - 1.2
    inside = np.abs(x) < 1.0 - BAR / 2 - 0.05
    t = (x[inside] + 1.0) / 2.0
    expected = BAR * t
    assert np.abs(prof[inside] - expected).mean() < 0.03 * expected.mean(), (prof[inside], expected)
    # A box shutter: BAR / 2 everywhere inside (and a flat profile, not the ramp).
    box = column_profile(moving_bar_scene(None, camera_motion), 32)
    assert np.abs(box[inside] - BAR / 2).mean() < 0.03 * BAR / 2, box[inside]


def rolling_rows(duration, rows=16, samples=8):
    """Per row of the moving bar's image (row 0 = the bottom) with Cycles' rolling shutter: the
    bar's centre (world x, the brightness-weighted mean of the column centres)."""
    s = moving_bar_scene()
    cam = camera(pc, (0.0, 0.0, 5.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    cam.type = "ORTHO"
    cam.ortho_scale = 2.4
    if duration is not None:
        cam.rolling_shutter = True
        cam.rolling_shutter_duration = duration
    s.set_camera(cam)
    st = pc.RenderSettings()
    st.width, st.height, st.samples = 48, rows, samples
    st.filter_type, st.filter_width = "box", 1.0
    sess = pc.Session(s, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    img = np.asarray(sess.film())[..., 0].astype(np.float64)
    x = (np.arange(48) + 0.5) / 48 * 2.4 - 1.2
    return (img * x).sum(axis=1) / img.sum(axis=1), img


def test_rolling_shutter_times_each_row_as_cycles():
    """Cycles' camera_sample with the rolling shutter 'TOP': row y (of H, from the bottom) reads
    at r = 1 - y / H, mixed with the shutter's own time t by the duration d: (t - 1/2) d +
    (r - 1/2)(1 - d) + 1/2. The bar (x = 2 time - 1) then leans across the rows: with d = 0 each
    row sees it at one instant, its centre at 2 r - 1; with d = 1/2 the mean time is the same
    halfway to 1/2; with d = 1 every row is the plain motion-blurred one."""
    rows = 16
    r = 1.0 - np.arange(rows) / rows
    centre, img = rolling_rows(0.0, rows)
    assert np.abs(centre - (2.0 * r - 1.0)).max() < 0.02, centre
    # One instant per row: the bar is sharp there (BAR wide, 8 of the 48 columns lit).
    assert np.all((img > 0.5).sum(axis=1) <= 9)
    half, _ = rolling_rows(0.5, rows, samples=64)
    assert np.abs(half - ((r - 0.5) * 0.5 + 0.5) * 2.0 + 1.0).max() < 0.04, half
    plain, plain_img = rolling_rows(None, rows, samples=32)
    full, full_img = rolling_rows(1.0, rows, samples=32)
    assert np.abs(plain).max() < 0.04 and np.abs(full).max() < 0.04
    # (the same times up to float rounding, which may move a sample across the bar's edge)
    assert np.abs(full_img - plain_img).mean() < 1e-3


def test_rolling_shutter_duration_is_validated():
    cam = pc.Camera()
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="rolling_shutter_duration"):
            cam.rolling_shutter_duration = bad
    cam.rolling_shutter_duration = 0.25
    assert cam.rolling_shutter_duration == pytest.approx(0.25)


def deform_steps():
    """The box's vertices at three steps: stretched along x, then sheared along y."""
    pos, tris = box_mesh()
    p = pos.astype(np.float64)
    a = p * (0.7, 1.0, 1.0)
    b = p.copy()
    c = p * (1.4, 1.0, 1.0) + np.outer(p[:, 0], (0.0, 0.6, 0.0))
    return pos, tris, np.stack([a, b, c]).astype(np.float32)


def deformed_at(steps, time):
    x = time * (len(steps) - 1)
    k = min(int(x), len(steps) - 2)
    f = x - k
    return (steps[k] * (1 - f) + steps[k + 1] * f).astype(np.float32)


@pytest.mark.parametrize("time", [0.0, 0.3, 0.5, 0.85, 1.0])
@pytest.mark.parametrize("moving", [False, True])
def test_deforming_mesh_hits_as_static_one_at_its_time(time, moving):
    """Deformation blur (alone, and with the transform's own motion): the hit at time t is the
    static mesh's with its vertices interpolated to t."""
    pos, tris, steps = deform_steps()
    s = pc.Scene()
    m = s.add_material("m", (0.5, 0.5, 0.5))
    mesh = s.add_mesh(pos, tris, material_slots=[m])
    s.set_mesh_motion(mesh, steps)
    s.add_instance(mesh, STEPS[1], motion=STEPS if moving else None)
    s.commit()
    assert s.stats()["deforming_instances"] == 1
    matrix = expected_matrix(time) if moving else STEPS[1]
    static = scene_with(matrix, mesh=(deformed_at(steps, time), tris))
    org, d = rays(matrix=matrix)
    t_m, prim_m, b1_m, _ = s.intersect(org, d, time=time)
    t_s, prim_s, b1_s, _ = static.intersect(org, d)
    hit = np.isfinite(t_s)
    assert 0.15 < hit.mean() < 0.95
    same = prim_m == prim_s
    assert same.mean() > 0.998
    both = same & hit
    np.testing.assert_allclose(t_m[both], t_s[both], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(b1_m[both], b1_s[both], atol=1e-3)
    assert (s.occluded(org, d, 1.0, time=time) == static.occluded(org, d, 1.0)).mean() > 0.998


def test_bad_deformation_is_dropped():
    pos, tris, steps = deform_steps()
    s = pc.Scene()
    m = s.add_material("m", (0.5, 0.5, 0.5))
    mesh = s.add_mesh(pos, tris, material_slots=[m])
    bad = steps.copy()
    bad[1, 3, 0] = np.inf
    s.set_mesh_motion(mesh, bad)
    s.set_mesh_motion(mesh, steps[:, :5])  # another vertex count
    s.add_instance(mesh, np.eye(4, dtype=np.float32))
    s.commit()
    st = s.stats()
    assert st["motion_rejected"] == 2 and st["deforming_instances"] == 0
    s2 = pc.Scene()
    mesh2 = s2.add_mesh(pos, tris, material_slots=[s2.add_material("m", (0.5, 0.5, 0.5))])
    s2.add_instance(mesh2, np.eye(4, dtype=np.float32))
    s2.commit()
    org, d = rays(500)
    np.testing.assert_array_equal(s.intersect(org, d, time=1.0)[1], s2.intersect(org, d)[1])
