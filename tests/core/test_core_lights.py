"""Analytic lights, the environment, the sampler and adaptive sampling, tested through the
core module against closed forms evaluated in numpy over the same pixels."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, cornell, quad, region_means, render, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
W = 32          # image size of the plane tests
H_CAM = 4.0     # camera height above the plane z = 0, looking straight down
ALBEDO = 0.5


def plane_scene():
    s = pc.Scene()
    m = s.add_material("plane", (ALBEDO, ALBEDO, ALBEDO))
    pos, tris = quad((-50, -50, 0), (100, 0, 0), (0, 100, 0))
    add_object(s, pos, tris, m)
    cam = pc.Camera()
    mw = np.eye(4, dtype=np.float32)
    mw[2, 3] = H_CAM  # identity rotation: looks down -Z with +Y up
    cam.matrix_world = mw
    s.set_camera(cam)
    return s


def plane_points(sub=8):
    """World points on the plane seen through each pixel, sub x sub per pixel: (W, W, sub*sub, 3),
    row 0 = bottom (the film's order), using Blender's view plane for a 50 mm lens, 36 mm sensor."""
    half = 0.5 * 36.0 / 50.0
    o = (np.arange(sub) + 0.5) / sub
    px = (np.arange(W)[:, None] + o[None, :]).reshape(-1)
    coord = (-half + px * (2 * half / W)) * H_CAM
    x = coord.reshape(W, sub)
    X = np.broadcast_to(x[None, :, None, :], (W, W, sub, sub))
    Y = np.broadcast_to(x[:, None, :, None], (W, W, sub, sub))
    pts = np.stack([X, Y, np.zeros_like(X)], -1).reshape(W, W, sub * sub, 3)
    return pts


def expected(radiance_fn):
    return radiance_fn(plane_points()).mean(axis=2)


def check(img, exp, tol=0.01):
    got = img[..., 0]
    mask = exp > 0.02 * exp.max()
    rel = np.abs(got[mask] - exp[mask]) / exp[mask]
    assert rel.max() < tol, f"max relative error {rel.max():.4f}"


def point_radiance(p, light, intensity):
    d = light - p
    r2 = (d**2).sum(-1)
    cos = d[..., 2] / np.sqrt(r2)
    return ALBEDO / np.pi * intensity * np.maximum(cos, 0) / r2


def test_point_light_irradiance_is_intensity_cos_over_r2():
    s = plane_scene()
    light = np.array([0.7, -0.4, 2.0])
    s.add_point_light(light, (10.0, 10.0, 10.0))
    img, stats = render(pc, s, W, W, samples=64)
    check(img, expected(lambda p: point_radiance(p, light, 10.0)), tol=0.005)
    assert stats["nonfinite_samples"] == 0


def test_soft_point_light_matches_its_point_limit():
    light = np.array([0.2, 0.1, 2.5])
    s = plane_scene()
    s.add_point_light(light, (10.0, 10.0, 10.0), radius=0.05)
    img, _ = render(pc, s, W, W, samples=256)
    check(img, expected(lambda p: point_radiance(p, light, 10.0)), tol=0.01)


def test_sun_irradiance_and_angle():
    theta = np.radians(30.0)
    direction = (np.sin(theta), 0.0, np.cos(theta))
    for angle in (0.0, np.radians(10.0)):
        s = plane_scene()
        s.add_sun_light(direction, (3.0, 3.0, 3.0), angle=angle)
        img, _ = render(pc, s, 16, 16, samples=256)
        # Cycles' distant light: radiance E / (pi sin^2 h) over a cone of half-angle h, which
        # gives exactly E cos(theta) on the plane.
        exp = ALBEDO / np.pi * 3.0 * np.cos(theta)
        assert abs(img[..., 0].mean() / exp - 1.0) < 0.005, (angle, img[..., 0].mean(), exp)


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_area_light_matches_numerical_integration():
    center, sx, sy = np.array([0.3, 0.0, 1.5]), 1.2, 0.6
    radiance = 4.0
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = center  # local -Z points down at the plane
    for ellipse in (False, True):
        s = plane_scene()
        s.add_area_light(m, sx, sy, (radiance,) * 3, ellipse=ellipse)
        img, _ = render(pc, s, W, W, samples=512)
        # E(x) = L * integral of cos_x cos_l / r^2 over the light, on a fine grid.
        g = (np.arange(80) + 0.5) / 80 - 0.5
        U, V = np.meshgrid(g * sx, g * sy, indexing="ij")
        inside = np.ones_like(U, bool) if not ellipse else (U / sx) ** 2 + (V / sy) ** 2 <= 0.25
        lp = np.stack([U[inside] + center[0], V[inside] + center[1], np.full(inside.sum(), center[2])], -1)
        dA = (sx / 80) * (sy / 80)

        def rad(p):
            d = lp[None, None, None] - p[..., None, :]  # (W, W, S, L, 3)
            r2 = (d**2).sum(-1)
            cos2 = d[..., 2] ** 2 / r2  # cos at the plane times cos at the light (both vertical)
            return ALBEDO / np.pi * radiance * (cos2 / r2).sum(-1) * dA

        pts = plane_points(sub=2)
        exp = np.stack([rad(pts[i : i + 4]) for i in range(0, W, 4)]).reshape(W, W, -1).mean(-1)
        check(img, exp, tol=0.03 if ellipse else 0.02)  # the grid's own error is ~1 %
        assert abs(img[..., 0].mean() / exp.mean() - 1) < 0.01


# A large emissive triangle standing on the plane (in x = 0, its base 2 cm above z = 0): the
# plane's points next to the base see it at close range, where area sampling of the triangle
# has a 1/r^2 tail and solid-angle sampling does not.
NEAR_TRI = np.array([[0.0, -1.2, 0.02], [0.0, 1.2, 0.02], [0.0, 0.3, 1.4]], np.float32)
NEAR_L = 3.0
NEAR_COLS = np.abs(np.arange(W) - (W - 1) / 2) > 1.0  # pixels off the columns through x = 0


def near_triangle_scene(solid_angle=True):
    s = plane_scene()
    m = s.add_material("light", (0.0, 0.0, 0.0), (NEAR_L,) * 3)
    add_object(s, NEAR_TRI, np.array([[0, 1, 2]], np.int32), m)
    s.solid_angle_triangle_sampling = solid_angle
    return s


def triangle_radiance(p):
    """Plane radiance under NEAR_TRI (valid as the whole triangle is above the plane)."""
    return polygon_radiance(p, NEAR_TRI, NEAR_L)


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_emissive_triangle_near_a_plane_matches_its_form_factor():
    exp = expected(triangle_radiance)[:, NEAR_COLS]
    # max_bounces 0: the light sample alone (its pdf); 1: light sample and BSDF hits under MIS.
    for bounces in (0, 1):
        img, stats = render(pc, near_triangle_scene(), W, W, samples=512, max_bounces=bounces)
        got = img[:, NEAR_COLS, 0]
        rel = np.abs(got - exp) / exp
        assert rel.max() < 0.03, (bounces, rel.max())
        assert abs(got.mean() / exp.mean() - 1) < 0.005, (bounces, got.mean() / exp.mean())
        assert stats["nonfinite_samples"] == 0
    # The area-sampling fallback estimates the same image (noisier: only the mean is checked).
    img, _ = render(pc, near_triangle_scene(False), W, W, samples=512, max_bounces=1)
    assert abs(img[:, NEAR_COLS, 0].mean() / exp.mean() - 1) < 0.01


def test_solid_angle_sampling_lowers_variance_near_a_triangle_light():
    exp = expected(triangle_radiance)[:, NEAR_COLS]
    rel_var = {}
    for solid_angle in (True, False):
        imgs = np.stack([render(pc, near_triangle_scene(solid_angle), W, W, samples=4, seed=seed,
                                max_bounces=0)[0][:, NEAR_COLS, 0] for seed in range(16)])
        rel_var[solid_angle] = imgs.var(axis=0, ddof=1) / exp**2
    # Measured: about 30x lower on average, 4x in the median pixel.
    assert rel_var[True].mean() < 0.25 * rel_var[False].mean(), {k: v.mean() for k, v in rel_var.items()}
    assert np.median(rel_var[True]) < 0.5 * np.median(rel_var[False])


def solid_angle_ref(p, tri):
    """Van Oosterom & Strackee in numpy float64 (libm's arctan2), from the same float32 inputs."""
    a, b, c = (np.asarray(v, np.float64) - np.asarray(p, np.float64) for v in tri)
    a, b, c = (v / np.linalg.norm(v) for v in (a, b, c))
    triple = abs(np.dot(a, np.cross(b, c)))
    return 2.0 * np.arctan2(triple, 1.0 + a @ b + b @ c + c @ a)


def spherical_configs():
    """(point, triangle) pairs: random ones from 1e-7 sr to nearly a hemisphere, and near-degenerate
    ones (nearly edge-on, tiny and far, needles)."""
    rng = np.random.default_rng(7)
    out = []
    for _ in range(300):
        tri = rng.uniform(-1, 1, (3, 3)) * 10.0 ** rng.uniform(-3, 1)
        p = rng.uniform(-1, 1, 3) * 10.0 ** rng.uniform(-2, 3)
        out.append((p, tri))
    base = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0]], np.float64)
    for h in (1e-4, 1e-3, 1e-2):  # just above the plane, beside the triangle: nearly edge-on
        out.append((np.array([2.0, 0.5, h]), base))
    for d in (1e2, 3e2, 1e3):  # tiny solid angles
        out.append((np.array([0.3, 0.3, d]), base))
    for h in (1e-3, 1e-2, 0.05, 0.5):  # over the middle of a big one: 6.28 to 6.11 sr
        out.append((np.array([0.4, 0.3, h]), base * 50 - [20, 20, 0]))
    out.append((np.array([0.5, 0.0, 0.5]), np.array([[0, 0, 0], [1, 0, 0], [0.5, 1e-3, 0]])))  # needle
    return [(np.float32(p), np.float32(t)) for p, t in out]


def test_spherical_triangle_solid_angle_matches_double_reference():
    # The core's solid angle uses its own inline atan (Cephes' rational fit), not libm's. Below
    # 1e-6 sr (area sampling takes over at 2e-4) the triple product's cancellation, not the atan,
    # sets the agreement: measured 4e-12 relative above 1e-6 sr, 2e-6 down to 5e-13 sr.
    worst = {True: 0.0, False: 0.0}
    for p, tri in spherical_configs():
        omega, _, _ = pc.spherical_triangle_sample(tuple(map(float, p)), tri, np.zeros((0, 2), np.float32))
        ref = solid_angle_ref(p, tri)
        assert ref > 0.0
        worst[ref > 1e-6] = max(worst[ref > 1e-6], abs(omega - ref) / ref)
    assert worst[True] < 1e-10, worst
    assert worst[False] < 1e-4, worst
    # Uniforms outside [0, 1] or NaN (never drawn by the renderer) give no sample, not undefined
    # behaviour.
    p, tri = spherical_configs()[-3]
    _, _, ok = pc.spherical_triangle_sample(tuple(map(float, p)), tri, np.float32([[np.nan, 0.5], [-1.0, 0.5], [0.5, 0.5]]))
    assert ok.tolist() == [False, False, True]


@pytest.mark.parametrize("case", ["near", "far", "needle", "edge_on", "hemisphere"])
def test_spherical_triangle_samples_are_uniform_in_solid_angle(case):
    base = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0]], np.float64)
    p, tri = {
        "near": ([0.4, 0.3, 0.3], base),
        "far": ([0.3, 0.3, 40.0], base),         # about 3e-4 sr: just above the area-sampling switch
        "needle": ([0.5, 0.0, 0.5], np.array([[0, 0, 0], [1, 0, 0], [0.5, 1e-3, 0]])),
        "edge_on": ([2.0, 0.5, 1e-2], base),
        "hemisphere": ([0.4, 0.3, 0.5], base * 50 - [20, 20, 0]),  # 6.11 sr (spherical up to 6.2)
    }[case]
    p, tri = np.float32(p), np.float32(tri)
    n = 256
    rng = np.random.default_rng(3)
    g = (np.stack(np.meshgrid(np.arange(n), np.arange(n)), -1).reshape(-1, 2) + rng.random((n * n, 2))) / n
    omega, dirs, ok = pc.spherical_triangle_sample(tuple(map(float, p)), tri, g.astype(np.float32))
    assert ok.all()
    assert np.abs(np.linalg.norm(dirs, axis=1) - 1).max() < 1e-12
    # Where the directions meet the triangle's plane: barycentrics, all inside (to rounding).
    p64, t64 = p.astype(np.float64), tri.astype(np.float64)
    e1, e2 = t64[1] - t64[0], t64[2] - t64[0]
    nrm = np.cross(e1, e2)
    t = ((t64[0] - p64) @ nrm) / (dirs @ nrm)
    assert (t > 0).all()
    r = p64 + dirs * t[:, None] - t64[0]
    b1 = (np.cross(r, e2) @ nrm) / (nrm @ nrm)
    b2 = (np.cross(e1, r) @ nrm) / (nrm @ nrm)
    assert min(b1.min(), b2.min(), (1 - b1 - b2).min()) > -1e-6
    # Uniform in solid angle: the four midpoint sub-triangles get samples in proportion to the
    # solid angles they subtend (5 sigma of a binomial count; the stratified grid does better).
    m01, m12, m20 = (t64[0] + t64[1]) / 2, (t64[1] + t64[2]) / 2, (t64[2] + t64[0]) / 2
    subs = [(t64[0], m01, m20), (m01, t64[1], m12), (m20, m12, t64[2]), (m01, m12, m20)]
    b0 = 1 - b1 - b2
    which = np.where(b0 > 0.5, 0, np.where(b1 > 0.5, 1, np.where(b2 > 0.5, 2, 3)))
    assert abs(omega / solid_angle_ref(p, tri) - 1) < 1e-9
    for k, sub in enumerate(subs):
        f = solid_angle_ref(p64, sub) / omega
        got = np.mean(which == k)
        assert abs(got - f) < 5 * np.sqrt(f * (1 - f) / len(g)) + 1e-6, (k, got, f)


# A rectangle light 25 cm above the plane: next to it, area sampling has the 1/r^2 tail that
# spherical-rectangle sampling (uniform in solid angle) does not.
NEAR_RECT_C, NEAR_RECT_SX, NEAR_RECT_SY, NEAR_RECT_L = np.array([0.3, 0.0, 0.25]), 1.2, 0.6, 4.0


def near_rect_scene(solid_angle=True):
    s = plane_scene()
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = NEAR_RECT_C  # local -Z points down at the plane
    s.add_area_light(m, NEAR_RECT_SX, NEAR_RECT_SY, (NEAR_RECT_L,) * 3)
    s.solid_angle_rect_sampling = solid_angle
    return s


def polygon_radiance(p, corners, radiance):
    """Plane radiance under a convex polygon light facing it, by Lambert's formula (its form
    factor): E = L/2 |sum over edges of theta_i n . unit(a_i x a_(i+1))|."""
    a = corners[None, None, None] - p[..., None, :]
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.roll(a, -1, axis=-2)
    c = np.cross(a, b)
    theta = np.arccos(np.clip((a * b).sum(-1), -1.0, 1.0))
    return ALBEDO / np.pi * radiance * 0.5 * np.abs((theta * c[..., 2] / np.linalg.norm(c, axis=-1)).sum(-1))


def near_rect_radiance(p):
    hx, hy = NEAR_RECT_SX / 2, NEAR_RECT_SY / 2
    corners = NEAR_RECT_C + np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]])
    return polygon_radiance(p, corners, NEAR_RECT_L)


def test_rect_light_near_a_plane_matches_its_form_factor():
    exp = expected(near_rect_radiance)
    mask = exp > 0.02 * exp.max()
    # max_bounces 0: the light sample alone; 1: with a BSDF ray after it, which can never hit
    # the light, so the light sample must keep its full weight (it lost 37 % of the light here
    # when it was MIS-weighted against the BSDF pdf).
    for bounces in (0, 1):
        img, stats = render(pc, near_rect_scene(), W, W, samples=256, max_bounces=bounces)
        got = img[..., 0]
        rel = np.abs(got[mask] - exp[mask]) / exp[mask]
        assert rel.max() < 0.02, (bounces, rel.max())  # measured 1.1 %
        assert abs(got[mask].mean() / exp[mask].mean() - 1) < 0.005, (bounces, got[mask].mean() / exp[mask].mean())
        assert stats["nonfinite_samples"] == 0
    # Area sampling estimates the same image (noisier: only the mean is checked).
    img, _ = render(pc, near_rect_scene(False), W, W, samples=256, max_bounces=1)
    assert abs(img[..., 0][mask].mean() / exp[mask].mean() - 1) < 0.01


def test_solid_angle_sampling_lowers_variance_near_a_rect_light():
    exp = expected(near_rect_radiance)
    mask = exp > 0.02 * exp.max()
    rel_var = {}
    for solid_angle in (True, False):
        imgs = np.stack([render(pc, near_rect_scene(solid_angle), W, W, samples=4, seed=seed,
                                max_bounces=0)[0][..., 0][mask] for seed in range(16)])
        rel_var[solid_angle] = imgs.var(axis=0, ddof=1) / exp[mask] ** 2
    # Measured: about 60x lower on average.
    assert rel_var[True].mean() < 0.1 * rel_var[False].mean(), {k: v.mean() for k, v in rel_var.items()}
    assert np.median(rel_var[True]) < 0.25 * np.median(rel_var[False])


def test_area_light_is_one_sided():
    s = plane_scene()
    m = np.diag([1.0, -1.0, -1.0, 1.0]).astype(np.float32)  # flipped: local -Z points up
    m[:3, 3] = (0.0, 0.0, 1.0)
    s.add_area_light(m, 1.0, 1.0, (5.0, 5.0, 5.0))
    img, _ = render(pc, s, 16, 16, samples=16)
    assert img[..., :3].max() == 0.0


def test_spot_cone_and_blend():
    light = np.array([0.0, 0.0, 2.0])
    size, blend = np.radians(60.0), 0.3
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = light  # points down -Z
    s = plane_scene()
    s.add_spot_light(m, (10.0, 10.0, 10.0), spot_size=size, spot_blend=blend)
    img, _ = render(pc, s, W, W, samples=64)
    cos_h = np.cos(size / 2)

    def rad(p):
        d = p - light
        c = -d[..., 2] / np.sqrt((d**2).sum(-1))
        t = np.clip((c - cos_h) / ((1 - cos_h) * blend), 0, 1)
        return point_radiance(p, light, 10.0) * t * t * (3 - 2 * t)

    exp = expected(rad)
    assert (exp == 0).any() and (exp > 0).any()  # the cone edge is in view
    got = img[..., 0]
    assert np.abs(got - exp).max() < 0.02 * exp.max()


def test_lights_cast_shadows_unless_told_not_to():
    # A black blocker at z = 1 under a point light at z = 2 shadows the square |x|,|y| < 1 of the
    # plane; the camera sees the ring of it that the blocker itself does not hide.
    pts = plane_points(sub=1)[:, :, 0, :]
    ax = np.abs(pts[..., :2]).max(-1)
    ring = (ax > 0.75) & (ax < 0.95)
    for cast in (True, False):
        s = plane_scene()
        blocker = s.add_material("blocker", (0.0, 0.0, 0.0))
        pos, tris = quad((-0.5, -0.5, 1.0), (1.0, 0, 0), (0, 1.0, 0))
        add_object(s, pos, tris, blocker)
        s.add_point_light((0.0, 0.0, 2.0), (10.0, 10.0, 10.0), cast_shadow=cast)
        img, _ = render(pc, s, W, W, samples=4)
        shadowed = img[..., 0][ring]
        assert ring.sum() > 20
        assert (shadowed.max() == 0.0) == cast, shadowed.max()
        assert img[..., 0][ax > 1.1].min() > 0.0  # outside the shadow: lit either way


def test_constant_environment_texture_equals_world_colour():
    def scene(env):
        s = pc.Scene()
        m = s.add_material("m", (0.8, 0.8, 0.8))
        pos, tris, nrm = uv_sphere(1.0)
        add_object(s, pos, tris, m)
        if env:
            s.set_world_texture(np.full((8, 16, 3), 0.5, np.float32), strength=2.0)
        else:
            s.set_world_color((1.0, 1.0, 1.0))
        s.set_camera(camera(pc, (0, -5, 0), (0, 0, 0)))
        return s

    a, _ = render(pc, scene(True), 32, 32, samples=16)
    b, _ = render(pc, scene(False), 32, 32, samples=16)
    assert np.abs(a - b).max() < 1e-3
    assert abs(a[16, 16, 0] - 0.8) < 0.01


def env_and_lights(strength, point=True, sun=False, tree="off"):
    """The plane (100 m wide: a large scene, whose environment has a large power estimate)
    under a uniform environment of the given strength, with a point light and/or a sun."""
    s = plane_scene()
    if point:
        s.add_point_light((0.0, 0.0, 2.0), (5.0, 5.0, 5.0), radius=0.1)
    if sun:
        s.add_sun_light((0.3, 0.2, 1.0), (2.0, 2.0, 2.0), angle=0.05)
    sky = np.full((8, 16, 3), 0.5, np.float32)
    sky[2:4, 3:5] = 20.0  # not uniform: a constant one is no light to sample
    s.set_world_texture(sky, strength=strength)
    s.light_tree = tree
    s.commit()
    return s


@pytest.mark.parametrize("sun", [False, True])
def test_local_lights_keep_half_the_choices_beside_the_environment(sun):
    """Issue 25: by power alone the environment (its estimate grows with the scene) took 80 % of
    the light samples beside the bench's point light, and rough glass showing that light was
    1.5x noisier than in Cycles, whose light tree averages a choice by upper bounds of the
    importance with one by lower bounds, where the environment has none. So the environment's
    share of the choices stays below one half however bright, where local lights exist."""
    p = np.array([[0.5, 0.0, 0.0]], np.float32)
    n = np.array([[0.0, 0.0, 1.0]], np.float32)
    u = np.zeros(1, np.float32)
    shares = []
    for strength in (1e-5, 1e-3, 0.1, 10.0):
        _, _, pmfs = env_and_lights(strength, sun=sun).light_choices(p, n, u, all_pmfs=True)
        assert abs(pmfs[0].sum() - 1.0) < 1e-5
        shares.append(pmfs[0, -1])  # the environment is the last entry
    assert 0.0 < shares[0] and shares[-1] < 0.5, shares
    assert np.all(np.diff(shares) > 0) and shares[-1] > 0.45, shares  # half its power share
    # The light tree keeps the same share for it.
    _, _, pmfs = env_and_lights(0.1, sun=sun, tree="on").light_choices(p, n, u, all_pmfs=True)
    assert abs(pmfs[0, -1] - shares[2]) < 1e-5 * shares[2]
    # Without a local light (a sun and the environment) the choice stays by power.
    if sun:
        _, _, pmfs = env_and_lights(1e4, point=False, sun=True).light_choices(p, n, u, all_pmfs=True)
        assert pmfs[0, -1] > 0.9


def test_environment_beside_a_point_light_stays_unbiased():
    """The environment's smaller share changes which light is sampled, not the image: the lit
    plane with and without the point light's share of the samples matches the sum of each
    light alone."""
    def scene(point, env):
        s = plane_scene()
        if point:
            s.add_point_light((0.0, 0.0, 2.0), (5.0, 5.0, 5.0), radius=0.1)
        if env:
            sky = np.full((8, 16, 3), 0.5, np.float32)
            sky[5:7, 3:5] = 20.0  # a bright patch above the plane
            s.set_world_texture(sky, strength=1.0)
        return s

    def rgb(point, env):
        return render(pc, scene(point, env), W, W, samples=64)[0][..., :3]

    both, sum_ = rgb(True, True), rgb(True, False) + rgb(False, True)
    assert abs(both.mean() / sum_.mean() - 1.0) < 0.01


def env_image():
    """A dim sky with one small, very bright patch: hard for BSDF sampling alone."""
    h, w = 32, 64
    img = np.full((h, w, 3), 0.05, np.float32)
    img[24:27, 10:13] = (200.0, 150.0, 100.0)
    return img


def test_environment_direction_convention():
    h, w = 16, 32
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    img = np.stack(np.broadcast_arrays(u[None, :], v[:, None], np.zeros((h, w))), -1).astype(np.float32)
    s = pc.Scene()
    s.set_world_texture(img)
    for target, (eu, ev) in {(1, 0, 0): (0.5, 0.5), (0, 1, 0): (0.25, 0.5), (-1, 0, 0): (None, 0.5),
                             (0, -1, 0): (0.75, 0.5)}.items():
        s.set_camera(camera(pc, (0, 0, 0), target, lens=200.0))
        got, _ = render(pc, s, 4, 4, samples=4)
        if eu is not None:
            assert abs(got[..., 0].mean() - eu) < 0.02, (target, got[..., 0].mean())
        assert abs(got[..., 1].mean() - ev) < 0.02
    s.set_camera(camera(pc, (0, 0, 0), (0, 0, 1), lens=200.0, up=(0, 1, 0)))
    got, _ = render(pc, s, 4, 4, samples=4)
    assert got[..., 1].mean() > 0.95  # straight up is the top row (v = 1)


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_environment_importance_sampling_is_unbiased():
    def scene():
        s = pc.Scene()
        m = s.add_material("m", (0.7, 0.7, 0.7))
        pos, tris = quad((-3, -3, 0), (6, 0, 0), (0, 6, 0))
        add_object(s, pos, tris, m)
        pos, tris, nrm = uv_sphere(0.6, center=(0, 0, 0.6))
        add_object(s, pos, tris, m, nrm)
        s.set_world_texture(env_image(), strength=1.0)
        s.set_camera(camera(pc, (0, -4, 2.5), (0, 0, 0.4)))
        return s

    nee, _ = render(pc, scene(), 24, 24, samples=256, use_nee=True)
    brdf, _ = render(pc, scene(), 24, 24, samples=4096, use_nee=False)
    assert abs(nee[..., :3].mean() / brdf[..., :3].mean() - 1) < 0.02
    ref = nee[..., :3].reshape(4, 6, 4, 6, 3).mean(axis=(1, 3))
    alt = brdf[..., :3].reshape(4, 6, 4, 6, 3).mean(axis=(1, 3))
    assert np.abs(ref - alt).max() < 0.08 * ref.max()


def sun_disc_image(h=64, w=128, radius=0.06, radiance=2000.0, sky=0.02):
    """A dim sky and a hard sun disc a few texels wide at 50 degrees elevation (as captured HDRs
    have): most of the light comes from a few texels and their bilinear footprint."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    elev = (v - 0.5) * np.pi
    sun_u, sun_elev = 0.3, np.radians(50.0)
    du = np.minimum(np.abs(u - sun_u), 1 - np.abs(u - sun_u))[None, :] * 2 * np.pi * np.cos(sun_elev)
    dist = np.hypot(du, (elev - sun_elev)[:, None])
    img = np.full((h, w, 3), sky, np.float32)
    img[dist < radius] = radiance
    return img


def sky_irradiance(img, sub=16):
    """E = integral of L cos over the upper hemisphere, L bilinear between texel centres
    (wrapping in u, clamped in v), on a grid of sub x sub points per texel."""
    h, w = img.shape[:2]
    lum = img[..., 0].astype(np.float64)
    v = (np.arange(h * sub) + 0.5) / (h * sub)
    u = (np.arange(w * sub) + 0.5) / (w * sub)
    fx, fy = u * w - 0.5, np.clip(v * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(fx).astype(int), np.minimum(np.floor(fy).astype(int), h - 2)
    tx, ty = fx - x0, fy - y0
    xa, xb = x0 % w, (x0 + 1) % w
    rows = lum[y0] * (1 - ty)[:, None] + lum[y0 + 1] * ty[:, None]
    L = rows[:, xa] * (1 - tx) + rows[:, xb] * tx
    elev = (v - 0.5) * np.pi
    # d(omega) = 2 pi^2 cos(elev) du dv; cos to the floor's normal = sin(elev).
    weight = np.maximum(np.sin(elev), 0) * 2 * np.pi**2 * np.cos(elev) / (h * sub * w * sub)
    return float((L * weight[:, None]).sum())


def test_environment_sun_disc_is_sampled_in_proportion_to_its_radiance():
    # An open floor under the sun disc, light samples only (max_bounces 0): every pixel has
    # the same expected value, so the spread across pixels at 1 spp is the per-sample variance.
    img_env = sun_disc_image()
    exp = ALBEDO / np.pi * sky_irradiance(img_env)
    s = plane_scene()
    s.set_world_texture(img_env, strength=1.0)
    img, _ = render(pc, s, W, W, samples=64, max_bounces=0)
    assert abs(img[..., 0].mean() / exp - 1) < 0.01, (img[..., 0].mean(), exp)
    one, _ = render(pc, s, 64, 64, samples=1, max_bounces=0)
    rel_var = float(one[..., 0].var() / exp**2)
    # Measured: 0.012 with the bilinear density; 1.43 with the 3x3-max per-texel distribution
    # (a third of the samples on the sun's dim, bilinear rim).
    assert rel_var < 0.05, rel_var


def sky_and_sun_image():
    """A sky brightening towards the zenith (0.2 at the horizon to 1.5) and a dim ground, with
    the sun disc: most of the map lies below its mean, which MIS compensation leaves to BSDF
    samples (where none follows, light samples use the whole map)."""
    img = sun_disc_image(sky=0.0)
    h = img.shape[0]
    elev = ((np.arange(h) + 0.5) / h - 0.5) * np.pi
    sky = np.where(elev > 0, 0.2 + 1.3 * np.sin(np.maximum(elev, 0)), 0.1).astype(np.float32)
    return np.maximum(img, sky[:, None, None])


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_compensated_environment_sampling_is_unbiased():
    img_env = sky_and_sun_image()
    exp = ALBEDO / np.pi * sky_irradiance(img_env)
    # max_bounces 0: the light sample alone (no BSDF sample follows: the whole map's
    # distribution); 1: the compensated light sample and the BSDF ray to the sky under MIS;
    # then BSDF rays alone (noisy on the sun: more samples, a wider bound).
    for bounces, nee, spp, tol in ((0, True, 256, 0.01), (1, True, 256, 0.01), (1, False, 1024, 0.02)):
        s = plane_scene()
        s.set_world_texture(img_env, strength=1.0)
        img, stats = render(pc, s, W, W, samples=spp, max_bounces=bounces, use_nee=nee)
        assert abs(img[..., 0].mean() / exp - 1) < tol, (bounces, nee, img[..., 0].mean() / exp)
        assert stats["nonfinite_samples"] == 0


def test_compensated_environment_sampling_has_low_variance():
    # Sun and sky over the floor with a BSDF sample after the light sample (max_bounces 1): the
    # per-pixel spread at 1 spp is the per-sample variance (every pixel has the same mean).
    img_env = sky_and_sun_image()
    exp = ALBEDO / np.pi * sky_irradiance(img_env)
    s = plane_scene()
    s.set_world_texture(img_env, strength=1.0)
    one, _ = render(pc, s, 64, 64, samples=1, max_bounces=1)
    rel_var = float(one[..., 0].var() / exp**2)
    # Measured: 0.0038 with MIS compensation; 0.21 with light samples in proportion to the whole
    # map's (bilinear) luminance under the same MIS, 0.072 for that light sample alone.
    assert rel_var < 0.02, rel_var


def rmse(a, b):
    return float(np.sqrt(((a[..., :3] - b[..., :3]) ** 2).mean()))


M32, M64 = (1 << 32) - 1, (1 << 64) - 1


def _mix64(x):
    x ^= x >> 33
    x = (x * 0xFF51AFD7ED558CCD) & M64
    x ^= x >> 33
    x = (x * 0xC4CEB9FE1A85EC53) & M64
    return x ^ (x >> 33)


def _rev(x):
    return int(f"{x:032b}"[::-1], 2)


def _laine_karras(x, seed):
    x = (x + seed) & M32
    for k in (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6):
        x ^= (x * k) & M32
    return x


def _nested_uniform_scramble(v, seed):
    return _rev(_laine_karras(_rev(v), seed))


def _sobol_dim1(index):
    d, r = 1 << 31, 0
    for i in range(32):
        if index >> i & 1:
            r ^= d
        d ^= d >> 1
    return r


def _sobol_joe_kuo(index, s, a, m):
    """Sobol dimension with primitive polynomial degree s, coefficients a, initial m (Joe-Kuo)."""
    v = [m[i] << (31 - i) for i in range(s)]
    for i in range(s, 32):
        x = v[i - s] ^ (v[i - s] >> s)
        for k in range(1, s):
            if a >> (s - 1 - k) & 1:
                x ^= v[i - k]
        v.append(x)
    r = 0
    for i in range(32):
        if index >> i & 1:
            r ^= v[i]
    return r


def sobol_reference(seed, pixel, sample, dims, sets4=False, points_low=False):
    """The sampler's Owen-scrambled Sobol draws, written out in Python integers from the
    definitions (Burley 2020), not from the core's shortcuts (byte tables, shuffle reversals).
    sets4: the 4-D sets of the sobol4d samplers (two draws per shuffled index, the second from
    Sobol dimensions 2 and 3; points_low: past the first set, the first from 2 and 3)."""
    base = _mix64(((seed * 0x9E3779B97F4A7C15) & M64) ^ _mix64((pixel + 0x632BE59BD9B4E019) & M64)
                  ^ _mix64(0x5EED ^ 0x8CB92BA72F3D8DD7))
    out = []
    for dim in range(dims):
        h = _mix64(base ^ (((dim // 2 if sets4 else dim) * 0x9E3779B97F4A7C15) & M64))
        index = _nested_uniform_scramble(sample, h & M32)  # the shuffled sample index
        if sets4 and (dim % 2 == 1) != (points_low and dim >= 2):
            h2 = _mix64(h ^ 0xC2B2AE3D27D4EB4F)
            x = _nested_uniform_scramble(_sobol_joe_kuo(index, 2, 1, (1, 3)), h2 >> 32)
            y = _nested_uniform_scramble(_sobol_joe_kuo(index, 3, 1, (1, 3, 1)), h2 & M32)
        else:
            x = _nested_uniform_scramble(_rev(index), h >> 32)  # dimension 0: van der Corput
            y = _nested_uniform_scramble(_sobol_dim1(index), _mix64(h) >> 32)
        out.append(((x >> 8) * 2.0**-24, (y >> 8) * 2.0**-24))
    return np.array(out, np.float32)


def test_sobol_sampler_matches_its_definition_bit_for_bit():
    rng = np.random.default_rng(11)
    cases = [(0, 0, 0), (1, 5, 1), (7, 123456, 1023), (2**32 - 1, 2**40 + 3, 2**31 + 5)]
    cases += [tuple(int(v) for v in (rng.integers(0, 2**32), rng.integers(0, 2**48), rng.integers(0, 2**32)))
              for _ in range(40)]
    for seed, pixel, sample in cases:
        # the Sobol dimensions (PCG32 after them): the default's 4-D sets in Cycles' order, and
        # the pairs (the default before issue 25)
        got = pc.sampler_values(seed, pixel, sample, 16)
        np.testing.assert_array_equal(got, sobol_reference(seed, pixel, sample, 16, True, points_low=True),
                                      err_msg=str((seed, pixel, sample)))
        got = pc.sampler_values(seed, pixel, sample, 16, "sobol_pairs")
        np.testing.assert_array_equal(got, sobol_reference(seed, pixel, sample, 16), err_msg=str((seed, pixel, sample)))


def test_sobol_variants_match_their_definitions_and_stratify_in_4d():
    # The opt-in measurement samplers (docs/design/sampling.md, "Random numbers").
    assert _sobol_joe_kuo(1 << 2, 2, 1, (1, 3)) == 0x60000000  # Burley's/Joe-Kuo's directions
    assert _sobol_joe_kuo(1 << 3, 3, 1, (1, 3, 1)) == 0x50000000
    assert _sobol_joe_kuo(1 << 5, 1, 0, (1,)) == _sobol_dim1(1 << 5)  # the generator, checked on dim 1
    for seed, pixel, sample in [(0, 0, 0), (7, 123456, 1023), (2**32 - 1, 2**40 + 3, 2**31 + 5)]:
        for name, sets4 in (("sobol4d", True), ("sobol_deep", False)):
            np.testing.assert_array_equal(pc.sampler_values(seed, pixel, sample, 16, name),
                                          sobol_reference(seed, pixel, sample, 16, sets4), err_msg=name)
    np.testing.assert_array_equal(pc.sampler_values(5, 9, 3, 16, "sobol_deep"), pc.sampler_values(5, 9, 3, 16, "sobol_pairs"))
    # 256 samples of a 4-D set (draws 2 and 3): every 1-D projection in 256 strata exactly once,
    # every 2-D projection at most 2 per cell of 16 x 16 (the padded pairs' draw 2 x draw 3: 3+)
    v = np.array([pc.sampler_values(3, 77, i, 40, "sobol4d_deep") for i in range(256)])
    p = np.concatenate([v[:, 2], v[:, 3]], axis=1)
    for a in range(4):
        assert np.histogram(p[:, a], bins=256, range=(0, 1))[0].max() == 1
        for b in range(a + 1, 4):
            assert np.histogram2d(p[:, a], p[:, b], bins=16, range=[[0, 1], [0, 1]])[0].max() <= 2, (a, b)
    # the deep variants stay Sobol past the 16th draw; the others turn to PCG32 there
    assert np.histogram(v[:, 30, 0], bins=256, range=(0, 1))[0].max() == 1
    for name in ("sobol", "sobol_pairs"):
        w = np.array([pc.sampler_values(3, 77, i, 40, name) for i in range(256)])
        assert np.histogram(w[:, 30, 0], bins=256, range=(0, 1))[0].max() > 1, name
    with pytest.raises(ValueError):
        pc.sampler_values(3, 77, 0, 4, "halton")


def roulette_reference(seed, pixel, sample, bounce):
    """sobol4d_rr's Russian roulette number (Cycles' PRNG_TERMINATE): a 1-D Owen-scrambled
    Sobol sequence per bounce, keyed apart from the layout's draws (bounce + 2^32)."""
    base = _mix64(((seed * 0x9E3779B97F4A7C15) & M64) ^ _mix64((pixel + 0x632BE59BD9B4E019) & M64)
                  ^ _mix64(0x5EED ^ 0x8CB92BA72F3D8DD7))
    h = _mix64(base ^ (((bounce + 2**32) * 0x9E3779B97F4A7C15) & M64))
    index = _nested_uniform_scramble(sample, h & M32)
    return (_nested_uniform_scramble(_rev(index), h >> 32) >> 8) * 2.0**-24


def test_roulette_on_its_own_sequence():
    # sobol4d_rr: sobol4d's draws, and the roulette's own number per bounce
    for seed, pixel, sample in [(0, 0, 0), (7, 123456, 1023), (2**32 - 1, 2**40 + 3, 2**31 + 5)]:
        np.testing.assert_array_equal(pc.sampler_values(seed, pixel, sample, 16, "sobol4d_rr"),
                                      pc.sampler_values(seed, pixel, sample, 16, "sobol4d"))
        for bounce in (0, 3, 11, 1000):
            assert pc.sampler_roulette(seed, pixel, sample, bounce, "sobol4d_rr") == \
                np.float32(roulette_reference(seed, pixel, sample, bounce)), (seed, pixel, sample, bounce)
    # the default takes the light set's number (Cycles' own roulette cost the Cornell box 1-2 %)
    for name in ("sobol", "sobol_pairs", "sobol4d"):
        assert pc.sampler_roulette(3, 77, 5, 3, name) == -1.0, name
    # sobol4d_cycles: the default's draws (Cycles' order: past the camera's set, the sets' halves
    # swapped) with sobol4d_rr's roulette
    for seed, pixel, sample in [(0, 0, 0), (7, 123456, 1023), (2**32 - 1, 2**40 + 3, 2**31 + 5)]:
        for name in ("sobol", "sobol4d_cycles"):
            np.testing.assert_array_equal(pc.sampler_values(seed, pixel, sample, 16, name),
                                          sobol_reference(seed, pixel, sample, 16, True, points_low=True))
        assert pc.sampler_roulette(seed, pixel, sample, 5, "sobol4d_cycles") == \
            pc.sampler_roulette(seed, pixel, sample, 5, "sobol4d_rr")
    # stratified over the samples: 256 samples in 256 strata once each, at every bounce; and
    # other bounces' (and pixels') sequences are others
    r = np.array([[pc.sampler_roulette(3, 77, i, b, "sobol4d_rr") for b in (3, 4)] for i in range(256)]
                 + [[pc.sampler_roulette(3, 78, i, 3, "sobol4d_rr"), 0.0] for i in range(256)])
    for col in (r[:256, 0], r[:256, 1], r[256:, 0]):
        assert np.histogram(col, bins=256, range=(0, 1))[0].max() == 1
    assert not np.array_equal(r[:256, 0], r[:256, 1]) and not np.array_equal(r[:256, 0], r[256:, 0])


@pytest.mark.converged
def test_sobol_converges_faster_than_random():
    ref, _ = render(pc, cornell(pc), 32, 32, samples=2048)
    errs = {}
    for sampler in ("sobol", "random"):
        e = []
        for seed in range(3):
            img, _ = render(pc, cornell(pc), 32, 32, samples=16, sampler=sampler, seed=seed)
            e.append(rmse(img, ref))
        errs[sampler] = np.mean(e)
    assert errs["sobol"] < 0.85 * errs["random"], errs


def test_adaptive_sampling_stops_converged_pixels_and_is_deterministic():
    def scene():
        s = pc.Scene()
        m = s.add_material("m", (0.8, 0.8, 0.8))
        pos, tris = quad((-1, 0, -2), (1, 0, 0), (0, 0, 4))  # left half: a wall lit by...
        add_object(s, pos, tris, m)
        img = np.full((32, 64, 3), 0.05, np.float32)
        img[20:23, 46:49] = 500.0  # ...a tiny bright patch behind the camera (found by chance only)
        s.set_world_texture(img)   # right half: the plain dim sky, noise-free
        s.set_camera(camera(pc, (0, -3, 0), (0, 0, 0), lens=30.0))
        return s

    st = pc.RenderSettings()
    st.width, st.height, st.samples, st.adaptive_threshold, st.use_nee = 32, 32, 512, 0.01, False
    counts = []
    for _ in range(2):
        sess = pc.Session(scene(), st)
        sess.start()
        while not sess.wait(1.0):
            pass
        counts.append(sess.sample_counts())
        film = sess.film()
    c = counts[0]
    assert np.array_equal(counts[0], counts[1])
    sky, wall = c[:, 24:], c[:, :8]
    assert sky.max() < 100 and wall.mean() > 3 * sky.mean(), (sky.max(), wall.mean())
    assert np.isfinite(film).all()


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_diffuse_bounce_limit_matches_total_limit_for_diffuse_scenes():
    # Same light paths, different estimators at the last vertex (a per-type limit still traces
    # the BSDF ray to keep MIS weights; the total limit gives the light sample all the weight).
    a, _ = render(pc, cornell(pc), 24, 24, samples=256, max_bounces=12, diffuse_bounces=1)
    b, _ = render(pc, cornell(pc), 24, 24, samples=256, max_bounces=1, diffuse_bounces=1024)
    full, _ = render(pc, cornell(pc), 24, 24, samples=256, max_bounces=12)
    assert abs(a[..., :3].mean() / b[..., :3].mean() - 1) < 0.01
    assert full[..., :3].mean() > 1.05 * a[..., :3].mean()


def test_bad_light_parameters_raise():
    s = pc.Scene()
    with pytest.raises(ValueError):
        s.add_point_light((np.nan, 0, 0), (1, 1, 1))
    with pytest.raises(ValueError):
        s.add_point_light((0, 0, 0), (1, 1, 1), radius=-1.0)
    with pytest.raises(ValueError):
        s.add_sun_light((0, 0, 0), (1, 1, 1))
    with pytest.raises(ValueError):
        s.add_spot_light(np.zeros((4, 4), np.float32), (1, 1, 1))
    with pytest.raises(ValueError):
        s.add_area_light(np.eye(4, dtype=np.float32), 1.0, 1.0, (1, 1, 1), spread=np.nan)
    with pytest.raises(ValueError):
        s.add_point_light((0, 0, 1), (1, 1, 1), radius=-0.5, soft_falloff=False)
    with pytest.raises(ValueError):
        s.set_world_texture(np.zeros((4, 4), np.float32))
    # NaN or negative colours are treated as black rather than poisoning the image.
    s.add_point_light((0, 0, 1), (np.nan, -1.0, 1.0))


# ---------------------------------------------------------------- sphere lights (Soft Falloff off)

def _frame(axis):
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    t = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    t /= np.linalg.norm(t)
    return a, t, np.cross(a, t)


def _hits_sphere(p, dirs, c, r):
    oc = np.asarray(c, np.float64) - p
    b = dirs @ oc
    if oc @ oc <= r * r:
        return np.ones(len(dirs), bool)
    return (b > 0) & (oc @ oc - b * b <= r * r)


def _spot_matrix_down(pos):
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = pos  # emits along -Z
    return m


# (point p, sphere centre, radius, spot size or None); the spot points down -Z.
SPHERE_CASES = {
    "far": ((0.3, -0.2, 0.0), (0.0, 0.0, 6.0), 0.2, None),
    "near": ((0.5, 0.0, 0.0), (0.0, 0.0, 0.8), 0.7, None),
    "inside": ((0.1, 0.2, 0.3), (0.0, 0.0, 0.5), 0.7, None),
    # the spot's 15 degree spread cone is smaller than the sphere's 30 degrees: it is sampled
    "spot spread": ((0.3, 0.0, 0.0), (0.0, 0.0, 2.0), 1.0, np.radians(30.0)),
    # the sphere's cone is sampled, and the spot's cone cuts through it
    "spot cut": ((1.2, 0.0, 0.0), (0.0, 0.0, 2.0), 0.5, np.radians(60.0)),
}


@pytest.mark.parametrize("case", list(SPHERE_CASES))
def test_sphere_light_samples_follow_their_pdf(case):
    """Chi-square of the sampled directions against the density sample_light reports, over bins
    of equal solid angle about the sampled cone, the expected count of each bin integrated over
    the directions that reach the sphere (and the spot's cone) on a fine grid."""
    p, c, r, spot = SPHERE_CASES[case]
    p, c = np.asarray(p, np.float64), np.asarray(c, np.float64)
    s = pc.Scene()
    if spot is None:
        s.add_point_light(position=tuple(c), intensity=(5.0,) * 3, radius=r, soft_falloff=False)
    else:
        s.add_spot_light(_spot_matrix_down(c), (5.0,) * 3, radius=r, spot_size=spot, spot_blend=0.2,
                         soft_falloff=False)
    pos, tris = quad((20, 20, -5), (1, 0, 0), (0, 1, 0))  # out of the way
    add_object(s, pos, tris, s.add_material("m", (0.5,) * 3))
    s.commit()
    d2 = (c - p) @ (c - p)
    inside = d2 <= r * r
    omc_sphere = 2.0 if inside else 1.0 - np.sqrt(1.0 - r * r / d2)
    omc_spot = 1.0 - np.cos(spot / 2) if spot is not None else 2.0
    spread = omc_spot <= omc_sphere
    omc = min(omc_sphere, omc_spot)
    axis = (0.0, 0.0, 1.0) if spread or inside else c - p
    a, t, b = _frame(axis)

    n = 200_000
    rng = np.random.default_rng(11)
    u = rng.random((n, 3), dtype=np.float32)
    pts = np.tile(p.astype(np.float32), (n, 1))
    ok, wi, dist, pdf, pdf_hit, t_hit = s.light_samples(pts, u)
    wi = wi.astype(np.float64)
    pdf_exp = 1.0 / (4 * np.pi) if inside else 1.0 / (2 * np.pi * omc)
    np.testing.assert_allclose(pdf[ok], pdf_exp, rtol=1e-4)
    # The sample lies on the sphere, and its ray finds the light there with the same pdf.
    on = p + wi[ok] * dist[ok, None]
    np.testing.assert_allclose(np.linalg.norm(on - c, axis=1), r, rtol=1e-3)
    np.testing.assert_allclose(t_hit[ok], dist[ok], rtol=2e-3, atol=1e-5)
    np.testing.assert_allclose(pdf_hit[ok], pdf[ok], rtol=1e-4)

    nb = 8
    def bins(d):
        x = np.clip((1.0 - d @ a) / omc, 0, 1 - 1e-9)
        phi = np.mod(np.arctan2(d @ b, d @ t), 2 * np.pi)
        return (x * nb).astype(int) * nb + np.minimum((phi / (2 * np.pi) * nb).astype(int), nb - 1)

    observed = np.bincount(bins(wi[ok]), minlength=nb * nb).astype(np.float64)
    # The fraction of each bin's solid angle that can be sampled (reaches the sphere; inside the
    # spot's cone), on a stratified 32 x 32 grid per bin.
    m = 32
    g = (np.arange(m) + 0.5) / m
    gx, gp = np.meshgrid(g, g, indexing="ij")
    frac = np.zeros(nb * nb)
    for i in range(nb):
        for j in range(nb):
            omc_d = (i + gx.ravel()) / nb * omc
            phi = (j + gp.ravel()) / nb * 2 * np.pi
            cos_d = 1.0 - omc_d
            sin_d = np.sqrt(np.maximum(0.0, omc_d * (2 - omc_d)))
            d = (a[None] * cos_d[:, None] + t[None] * (sin_d * np.cos(phi))[:, None]
                 + b[None] * (sin_d * np.sin(phi))[:, None])
            keep = _hits_sphere(p, d, c, r)
            if spot is not None and not inside:
                keep &= d[:, 2] > np.cos(spot / 2)  # -d inside the cone about -Z
            frac[i * nb + j] = keep.mean()
    expected = n * frac / (nb * nb)  # pdf x the bin's solid angle omc 2 pi / nb^2
    assert observed[expected == 0].sum() <= 1e-4 * n
    big = expected >= 20
    chi2 = ((observed[big] - expected[big]) ** 2 / expected[big]).sum()
    rest_o, rest_e = observed[~big].sum(), expected[~big].sum()
    if rest_e > 0:
        chi2 += (rest_o - rest_e) ** 2 / max(rest_e, 1.0)
    k = big.sum() + (rest_e > 0)
    # Wilson-Hilferty: z of chi2 with k degrees of freedom, about N(0, 1) under the null.
    z = ((chi2 / k) ** (1 / 3) - (1 - 2 / (9 * k))) / np.sqrt(2 / (9 * k))
    assert z < 4.0, (chi2, k)
    assert big.sum() >= 16  # the test sees the distribution's shape, not one bin


def sphere_cone_integral(p, c, r, integrand=lambda z: np.maximum(z, 0), m=48):
    """At points p (..., 3), the integral of integrand(z) (z: the direction's Z) over the cone of
    a sphere (centre c, radius r), uniform in 1 - cos, by an m x m midpoint rule. The default is
    the cosine to +Z cut by the horizon: the plane z = 0's irradiance from unit radiance."""
    pts = p.reshape(-1, 3)
    out = np.empty(len(pts))
    g = (np.arange(m) + 0.5) / m
    gx, gp = (x.ravel() for x in np.meshgrid(g, g, indexing="ij"))
    for k0 in range(0, len(pts), 256):
        q = pts[k0:k0 + 256]
        to_c = c - q
        d = np.linalg.norm(to_c, axis=1)
        omc = 1.0 - np.sqrt(1.0 - (r / d) ** 2)
        a = to_c / d[:, None]
        t = np.cross(a, [1.0, 0.0, 0.0])
        t /= np.linalg.norm(t, axis=1)[:, None]
        b = np.cross(a, t)
        omc_d = gx[None] * omc[:, None]
        cos_d, sin_d = 1 - omc_d, np.sqrt(omc_d * (2 - omc_d))
        phi = gp * 2 * np.pi
        z = (a[:, 2:3] * cos_d + t[:, 2:3] * sin_d * np.cos(phi) + b[:, 2:3] * sin_d * np.sin(phi))
        out[k0:k0 + 256] = integrand(z).mean(axis=1) * 2 * np.pi * omc
    return out.reshape(p.shape[:-1])


def sphere_irradiance(p, c, r, intensity, m=48):
    """Irradiance of the plane z = 0 (normal +Z) at points p (..., 3) from a sphere of radiance
    I / (pi r^2): its cone cut by the horizon."""
    return sphere_cone_integral(p, c, r, m=m) * intensity / (np.pi * r * r)


def grey_region_means(img, exp):
    """8 x 8 region means of a render's red channel and of the expected grey image exp (H, W)."""
    got = region_means(img[..., :3], 8)[..., 0]
    want = region_means(np.repeat(exp[..., None], 3, -1), 8)[..., 0]
    return got, want


def test_sphere_light_near_a_plane_matches_its_form_factor():
    """A sphere light of radius 0.5 with its centre 0.6 above the plane: its cone is cut by the
    horizon next to it; where it is whole, the irradiance is I cos / d^2 (a point light's)."""
    c, r, inten = np.array([0.3, -0.2, 0.6]), 0.5, 4.0
    s = plane_scene()
    s.add_point_light(tuple(c), (inten,) * 3, radius=r, soft_falloff=False)
    img, stats = render(pc, s, W, W, samples=256)
    assert stats["nonfinite_samples"] == 0
    p = plane_points(sub=2)
    exp = (ALBEDO / np.pi * sphere_irradiance(p, c, r, inten)).mean(axis=2)
    # The soft disk's irradiance I cos / (d^2 + r^2) is far off here: the test can tell them apart.
    d = c - p
    d2 = (d**2).sum(-1)
    soft = (ALBEDO / np.pi * inten * np.maximum(d[..., 2], 0) / np.sqrt(d2) / (d2 + r * r)).mean(axis=2)
    assert (soft / exp).min() < 0.7
    got, want = grey_region_means(img, exp)
    np.testing.assert_allclose(got, want, rtol=0.01)


def test_sphere_spot_light_cone_near_a_plane():
    """A sphere spot: its cone and blend along each sample's direction, uniform over the sphere's
    visible cone; checked against the same integral with the attenuation inside."""
    c, r, inten = np.array([0.0, 0.0, 0.9]), 0.4, 6.0
    size, blend = np.radians(70.0), 0.3
    s = plane_scene()
    s.add_spot_light(_spot_matrix_down(c), (inten,) * 3, radius=r, spot_size=size, spot_blend=blend,
                     soft_falloff=False)
    # 1024 spp: at 256 the worst lit region's noise is 1.3-2.5 % over seeds with either sampler
    # (it passed on the Sobol pairs' seed 0 by luck); at 1024 0.9-1.3 %
    img, _ = render(pc, s, W, W, samples=1024)
    cos_h = np.cos(size / 2)

    def cone_cosine_and_blend(z):
        x = np.clip((z - cos_h) / ((1 - cos_h) * blend), 0, 1)  # -dir's cosine to -Z is z
        return np.maximum(z, 0) * x * x * (3 - 2 * x)
    e = sphere_cone_integral(plane_points(sub=2), c, r, cone_cosine_and_blend)
    exp = (ALBEDO / np.pi * e * inten / (np.pi * r * r)).reshape(W, W, -1).mean(axis=2)
    got, want = grey_region_means(img, exp)
    lit = want > 0.05 * want.max()
    assert lit.sum() > 8 and (~lit).sum() > 0  # the cone's edge is in view
    np.testing.assert_allclose(got[lit], want[lit], rtol=0.015)
    assert np.abs(got - want).max() < 0.01 * want.max()


# ---------------------------------------------------------------- area light spread

def spread_attenuation(tan_a, spread):
    half = spread / 2
    norm = 1 / (np.tan(half) - half) if half > 0.05 else 3 / half**3
    return np.maximum((np.tan(half) - tan_a) * norm, 0.0)


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
@pytest.mark.parametrize("ellipse", [False, True], ids=["rect", "ellipse"])
def test_area_light_spread_matches_numerical_integration(ellipse):
    """Spread 40 degrees (Cycles' soft-box grid): each point of the plane is lit by the part of
    the light within 20 degrees of its normal, the emission falling off with tan of the angle;
    sampled over the light's rectangle clipped to that part."""
    center, sx, sy, radiance, spread = np.array([0.3, 0.0, 1.0]), 1.6, 1.0, 4.0, np.radians(40.0)
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = center
    s = plane_scene()
    s.add_area_light(m, sx, sy, (radiance,) * 3, ellipse=ellipse, spread=spread)
    img, stats = render(pc, s, W, W, samples=1024 if ellipse else 256)  # ellipses: by area, noisier
    assert stats["nonfinite_samples"] == 0
    n = 160
    g = (np.arange(n) + 0.5) / n - 0.5
    U, V = np.meshgrid(g * sx, g * sy, indexing="ij")
    inside = np.ones_like(U, bool) if not ellipse else (U / sx) ** 2 + (V / sy) ** 2 <= 0.25
    lp = np.stack([U[inside] + center[0], V[inside] + center[1], np.full(inside.sum(), center[2])], -1)
    dA = (sx / n) * (sy / n)

    def rad(p):
        d = lp[None, None, None] - p[..., None, :]
        r2 = (d**2).sum(-1)
        tan_a = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2) / d[..., 2]
        cos2 = d[..., 2] ** 2 / r2
        return ALBEDO / np.pi * radiance * (spread_attenuation(tan_a, spread) * cos2 / r2).sum(-1) * dA

    pts = plane_points(sub=2)
    exp = np.stack([rad(pts[i : i + 2]) for i in range(0, W, 2)]).reshape(W, W, -1).mean(-1)
    # The pool of light has an edge: without the spread, it would fill the view.
    assert exp.min() < 0.02 * exp.max()
    got, want = grey_region_means(img, exp)
    lit = want > 0.1 * want.max()
    np.testing.assert_allclose(got[lit], want[lit], rtol=0.02)
    assert np.abs(got - want).max() < 0.01 * want.max()
    assert abs(img[..., 0].mean() / exp.mean() - 1) < 0.01


def test_area_light_spread_keeps_the_power():
    """Cycles normalises the spread so that the light's power does not change: a wide plane under
    a small light gets the same total light at any spread."""
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = (0.0, 0.0, 0.5)
    means = []
    for spread in (np.pi, np.radians(90.0), np.radians(30.0)):
        s = plane_scene()
        s.add_area_light(m, 0.2, 0.2, (5.0,) * 3, spread=spread)
        img, _ = render(pc, s, W, W, samples=64)  # the camera sees x, y in +-1.44 (4 m up, 50 mm)
        means.append(img[..., 0].mean())
    assert means[2] > means[1] > means[0]  # more of it lands in view as the spread narrows
    # 30 degrees: within 0.5 tan 15 = 0.13 of the centre, all of the power is in view
    expected = ALBEDO / np.pi * 5.0 * np.pi * 0.04 / (2.88**2)  # albedo/pi * power / view area
    assert abs(means[2] / expected - 1) < 0.02


def test_light_max_bounces_skips_light_samples_past_it():
    """Cycles' light Max Bounces (light_select_reached_max_bounces): light samples at vertices
    past that many bounces skip the light. A point light at the centre of a closed diffuse
    sphere (albedo a = 0.5): vertex k's light sample brings a^k L0, so the camera sees L0 with
    Max Bounces 0, L0 (1 + a) with 1, and L0 / (1 - a) without a limit."""
    def film(max_bounces):
        s = pc.Scene()
        m = s.add_material("shell", (0.5, 0.5, 0.5))
        pos, tris, nrm = uv_sphere(1.0, nu=48, nv=24, inward=True)
        add_object(s, pos, tris, m, nrm)
        s.add_point_light((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
        if max_bounces is not None:
            s.set_light_max_bounces(0, max_bounces)
        s.set_camera(camera(pc, (0.0, -0.2, 0.0), (0.0, 1.0, 0.0), lens=20.0))
        img, stats = render(pc, s, 16, 16, samples=128, max_bounces=64)
        return np.asarray(img)[..., :3].mean(), stats
    l0, stats = film(0)
    assert stats["kernel"] == "general" and "light bounce limits" in stats["features"]
    assert l0 == pytest.approx(0.5 / np.pi, rel=0.03)  # a I / (pi R^2) on the unit sphere
    one, _ = film(1)
    assert one / l0 == pytest.approx(1.5, rel=0.02)
    unlimited, stats = film(None)
    assert unlimited / l0 == pytest.approx(2.0, rel=0.03)
    assert "light bounce limits" not in stats["features"]
    # Caustic light paths would bring a limited light's deeper bounces back: off, with the reason.
    s = pc.Scene()
    s.add_material("grey", (0.5, 0.5, 0.5))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), 0)
    s.add_point_light((0.0, 0.0, 1.0), (1.0, 1.0, 1.0))
    s.set_light_max_bounces(0, 2)
    s.set_camera(camera(pc, (0.0, -2.0, 2.0), (0.0, 0.0, 0.0)))
    _, stats = render(pc, s, 8, 8, samples=1, caustic_light_paths=1.0)
    assert stats["caustics"] == "off: not with a light's Max Bounces"
    s = pc.Scene()
    s.add_point_light((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="max_bounces"):
        s.set_light_max_bounces(0, -1)
    with pytest.raises(IndexError):
        s.set_light_max_bounces(1, 3)
