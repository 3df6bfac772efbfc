"""Emitter groups: a small mesh light (a quad's two triangles, a fan of up to four) chosen as one
light and sampled over its whole solid angle, each triangle picked in proportion to the solid
angle it subtends. Checked through the core module: the density of the light samples against the
pdf the renderer's MIS uses for the same directions, its integral, closed-form irradiance, the
image against per-triangle sampling, and the variance it removes."""
import functools

import numpy as np
import pytest

from core_scenes import add_object, core, cornell, quad, random_rotation, region_means, render
from test_core_lights import W, check, expected, plane_scene, solid_angle_ref

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def light_scene(pos, tris, groups=True, matrix=None, emission=2.0, extra=None):
    """An emissive mesh alone (plus `extra` (pos, tris) lights of their own), committed."""
    s = pc.Scene()
    m = s.add_material("light", (0.0, 0.0, 0.0), (emission,) * 3)
    add_object(s, pos, tris, m, matrix=matrix)
    for p, t in extra or []:
        add_object(s, p, t, m)
    s.emitter_groups = groups
    s.commit()
    return s


QUAD = quad((-0.5, -0.3, 0.0), (1.0, 0.0, 0.0), (0.2, 0.6, 0.0))  # a parallelogram in z = 0
# A fan of four triangles around a centre: a non-planar (tent-shaped) group with shared corners.
FAN_POS = np.array([[0, 0, 0.2], [0.5, 0, 0], [0, 0.5, 0], [-0.5, 0, 0], [0, -0.5, 0]], np.float32)
FAN_TRIS = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]], np.int32)


def probe_points():
    """Points around the lights: random ones at all scales, both sides, and near-degenerate ones
    (just off the plane over the middle and beside an edge, on the diagonal, at a corner, far)."""
    rng = np.random.default_rng(3)
    pts = [rng.normal(size=3) * 10.0 ** rng.uniform(-1.5, 1.5) for _ in range(40)]
    pts += [np.array(p, float) for p in (
        (0.1, 0.0, 1e-3), (0.1, 0.0, -1e-3), (0.0, 0.0, 2e-2), (0.7, 0.3, 1e-3), (-0.5, -0.3, 1e-2),
        (0.2, 0.0, 0.05), (0.0, 0.0, 300.0), (40.0, -20.0, 10.0), (0.05, 0.05, 0.3), (0.0, 0.0, -0.01))]
    return np.array(pts, np.float32)


def total_solid_angle(p, pos, tris):
    return sum(solid_angle_ref(p, pos[t]) for t in tris)


@pytest.mark.parametrize("mesh", ["quad", "fan", "quad_moved"])
def test_group_samples_have_the_mis_pdf_and_integrate_to_one(mesh):
    pos, tris = (FAN_POS, FAN_TRIS) if mesh == "fan" else QUAD
    matrix = None
    if mesh == "quad_moved":  # an instanced (transformed) copy: corners through the matrix
        matrix = np.array([[0, -2, 0, 0.3], [1, 0, 0, -0.2], [0, 0, 1, 0.1], [0, 0, 0, 1]], np.float32)
    # Two instances make the mesh instanced (object-space BLAS); one instance merges it.
    s = pc.Scene()
    m = s.add_material("light", (0.0, 0.0, 0.0), (2.0, 2.0, 2.0))
    mesh_id = s.add_mesh(pos, tris, None, None, [m])
    s.add_instance(mesh_id, np.eye(4, dtype=np.float32) if matrix is None else matrix)
    if matrix is not None:
        far = matrix.copy()
        far[:3, 3] += (0.0, 0.0, 1e4)
        s.add_instance(mesh_id, far)
    s.commit()
    world = pos if matrix is None else (pos @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
    n = 4096
    rng = np.random.default_rng(11)
    checked = 0
    for p in probe_points():
        u = rng.random((n, 3), dtype=np.float32)
        ok, wi, dist, pdf, pdf_hit, t_hit = s.light_samples(np.repeat(p[None], n, 0), u)
        omega = total_solid_angle(p, world, tris)
        if omega < 1e-9:
            continue
        # Every sample's pdf is the one MIS computes for the emitter its direction hits (where
        # that is the sampled point: a fan's triangle may hide part of another).
        hit = ok & (pdf_hit > 0) & (np.abs(t_hit - dist) <= 2e-5 * dist)
        assert hit.sum() > 0.3 * ok.sum(), (p, ok.sum(), hit.sum())
        # (Hits on the neighbour of the sampled triangle along their shared edge aside: a
        # handful of the samples where the two are picked with different densities.)
        same = np.isclose(pdf_hit[hit], pdf[hit], rtol=2e-3)
        assert same.mean() > 0.995, (p, same.mean(), pdf[hit][~same][:4], pdf_hit[hit][~same][:4])
        if matrix is None:
            # E[1/pdf] over the samples is the solid angle they cover: the density integrates to 1
            # over the light (checked where the samples are well conditioned).
            est = np.where(ok, 1.0 / np.where(ok, pdf, 1.0), 0.0)
            err = est.std() / np.sqrt(n)
            assert abs(est.mean() - omega) < 5 * err + 2e-3 * omega, (p, est.mean(), omega, err)
        checked += 1
    assert checked >= 40


def test_group_pdf_is_uniform_in_solid_angle_over_the_whole_quad():
    # Near the quad (solid angle sampling of both triangles), every direction has density
    # 1 / (total solid angle): the two triangles' samples are one uniform distribution.
    s = light_scene(*QUAD)
    for p in np.array([(0.1, 0.0, 0.02), (0.6, 0.2, 0.3), (-0.2, 0.1, -0.05), (1.0, 1.0, 0.5)], np.float32):
        u = np.random.default_rng(1).random((2048, 3), dtype=np.float32)
        ok, _, _, pdf, _, _ = s.light_samples(np.repeat(p[None], 2048, 0), u)
        omega = total_solid_angle(p, *QUAD)
        assert ok.mean() > 0.99
        np.testing.assert_allclose(pdf[ok], 1.0 / omega, rtol=1e-5)
    # Per-triangle sampling (the groups off): each triangle's density is its own, twice as high
    # on the smaller one seen from a point beside the quad.
    s = light_scene(*QUAD, groups=False)
    p = np.array([(0.7, 0.35, 0.1)], np.float32)
    ok, _, _, pdf, _, _ = s.light_samples(np.repeat(p, 512, 0), np.random.default_rng(2).random((512, 3), dtype=np.float32))
    assert len(np.unique(np.round(pdf[ok], 4))) == 2


def test_groups_only_for_small_single_material_meshes():
    # A mesh with more emissive triangles than a group holds keeps one light per triangle; so does
    # a quad with a material per triangle.
    s = pc.Scene()
    a = s.add_material("a", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    b = s.add_material("b", (0.0, 0.0, 0.0), (4.0, 4.0, 4.0))
    pos, tris = QUAD
    s.add_instance(s.add_mesh(pos, tris, None, np.array([0, 1], np.int32), [a, b]),
                   np.eye(4, dtype=np.float32))
    s.commit()
    p = np.array([(0.1, 0.0, 0.5)], np.float32)
    ok, _, _, pdf, pdf_hit, _ = s.light_samples(np.repeat(p, 256, 0), np.random.default_rng(0).random((256, 3), dtype=np.float32))
    assert len(np.unique(np.round(pdf[ok], 4))) == 2  # chosen by power, each by its own angle
    np.testing.assert_allclose(pdf_hit[ok], pdf[ok], rtol=2e-3)


# A vertical quad standing on the plane (base 2 cm above it, as the triangle of
# test_core_lights): the plane's points next to its base see it at close range.
NEAR_QUAD = quad((0.0, -1.2, 0.02), (0.0, 2.4, 0.0), (0.0, 0.6, 1.3))
NEAR_L = 3.0
NEAR_COLS = np.abs(np.arange(W) - (W - 1) / 2) > 1.0


def near_quad_scene(groups=True):
    s = plane_scene()
    m = s.add_material("light", (0.0, 0.0, 0.0), (NEAR_L,) * 3)
    add_object(s, *NEAR_QUAD, m)
    s.emitter_groups = groups
    return s


def quad_radiance(p):
    """Lambert's polygon formula over the quad's four edges."""
    from test_core_lights import polygon_radiance
    return polygon_radiance(p, NEAR_QUAD[0], NEAR_L)


def test_grouped_quad_near_a_plane_matches_its_form_factor():
    exp = expected(quad_radiance)[:, NEAR_COLS]
    for bounces in (0, 1):  # the light sample alone, then with BSDF hits under MIS
        img, stats = render(pc, near_quad_scene(), W, W, samples=256, max_bounces=bounces)
        got = img[:, NEAR_COLS, 0]
        rel = np.abs(got - exp) / exp
        assert rel.max() < 0.03, (bounces, rel.max())
        assert abs(got.mean() / exp.mean() - 1) < 0.005, (bounces, got.mean() / exp.mean())
        assert stats["nonfinite_samples"] == 0


def test_grouped_quad_lowers_variance_near_it():
    exp = expected(quad_radiance)[:, NEAR_COLS]
    rel_var = {}
    for groups in (True, False):
        imgs = np.stack([render(pc, near_quad_scene(groups), W, W, samples=4, seed=seed,
                                max_bounces=0)[0][:, NEAR_COLS, 0] for seed in range(16)])
        rel_var[groups] = (imgs.var(axis=0, ddof=1) / exp**2).mean()
    # Measured: 0.50x.
    assert rel_var[True] < 0.7 * rel_var[False], rel_var


@functools.lru_cache(maxsize=None)
def cornell_image(emitter_groups=True, rect_groups=True):
    """The Cornell box (its light one quad, a rectangle) at high sample counts (48 x 48, 512
    samples, seed 5) and its rectangle emitter count. Both comparisons below need it with both
    kinds of groups on (the defaults), the same render: made once per process (pass both
    arguments, positionally: lru_cache keys on the call as written)."""
    s = cornell(pc)
    s.emitter_groups, s.rect_groups = emitter_groups, rect_groups
    s.commit()
    img = render(pc, s, 48, 48, samples=512, max_bounces=6, seed=5)[0][..., :3]
    img.setflags(write=False)
    return img, s.stats()["rect_emitters"]


@pytest.mark.converged
def test_grouped_lights_render_the_per_triangle_image():
    # The Cornell box (its light one quad) at high sample counts: the same image either way, to
    # within the noise of the regions; the whole-image means within 0.5 %.
    imgs = {groups: cornell_image(groups, True)[0] for groups in (True, False)}
    a, b = region_means(imgs[True], 6), region_means(imgs[False], 6)
    assert abs(imgs[True].mean() / imgs[False].mean() - 1) < 0.005
    np.testing.assert_allclose(a, b, rtol=0.03)


# Rectangle groups: a quad light whose two triangles form a rectangle in world space is sampled as
# one spherical rectangle (Urena et al. 2013): the same uniform distribution over its solid angle
# as the two spherical triangles, with less work.

RECT = quad((-0.5, -0.3, 0.0), (1.0, 0.0, 0.0), (0.0, 0.6, 0.0))


def rect_solid_angle_ref(p, c, ex, ey):
    c, ex, ey = (np.asarray(v, np.float64) for v in (c, ex, ey))
    return solid_angle_ref(p, np.stack([c, c + ex, c + ex + ey])) + solid_angle_ref(p, np.stack([c, c + ex + ey, c + ey]))


def rect_sample(p, c, ex, ey, u):
    return pc.spherical_rect_sample(*(tuple(map(float, v)) for v in (p, c, ex, ey)), np.asarray(u, np.float32))


def test_spherical_rect_solid_angle_matches_double_reference():
    # Random rectangles (edges along permuted axes: exactly orthogonal in float) and points at all
    # scales. The closed form sums four corner atans, so its absolute error is ~1e-16 and the
    # relative one grows as 1 / omega: measured 3e-12 at 1e-4..1e-3 sr (the rectangle is sampled by
    # solid angle only above 2e-4), 2e-11 at 1e-5, 3e-10 at 1e-6.
    rng = np.random.default_rng(1)
    worst = {"used": 0.0, "small": 0.0}
    for _ in range(3000):
        perm = rng.permutation(3)
        ex = np.array([10 ** rng.uniform(-2, 1), 0.0, 0.0])[perm]
        ey = np.array([0.0, 10 ** rng.uniform(-2, 1), 0.0])[perm]
        c = rng.uniform(-1, 1, 3) * 10 ** rng.uniform(-2, 1)
        p = rng.uniform(-1, 1, 3) * 10 ** rng.uniform(-2, 2)
        p, c, ex, ey = (np.float32(v) for v in (p, c, ex, ey))
        omega, _, _ = rect_sample(p, c, ex, ey, np.zeros((0, 2)))
        ref = rect_solid_angle_ref(p, c, ex, ey)
        if ref > 1e-5:
            key = "used" if ref > 2e-4 else "small"
            worst[key] = max(worst[key], abs(omega - ref) / ref)
    assert worst["used"] < 1e-11, worst
    assert worst["small"] < 1e-9, worst
    # In its plane (or on it) a rectangle subtends nothing, and gives no samples.
    omega, _, ok = rect_sample((0.2, 0.1, 0.0), (0, 0, 0), (1, 0, 0), (0, 1, 0), [[0.5, 0.5]])
    assert omega == 0.0 and not ok.any()
    # Uniforms outside [0, 1] or NaN (never drawn by the renderer) give no sample.
    _, _, ok = rect_sample((0.2, 0.1, 0.5), (0, 0, 0), (1, 0, 0), (0, 1, 0), [[np.nan, 0.5], [-1.0, 0.5], [0.5, 0.5]])
    assert ok.tolist() == [False, False, True]


RECT_CASES = {
    "near": ([0.4, 0.3, 0.3], 1.0, 0.6),
    "far": ([0.3, 0.3, 40.0], 1.0, 0.6),             # 3.7e-4 sr: just above the area-sampling switch
    "needle": ([0.5, 0.0, 0.5], 1.0, 1e-3),
    "edge_on": ([2.0, 0.5, 1e-2], 1.0, 0.6),         # beside it, just above its plane
    "edge_on_low": ([0.5, -0.3, 1e-4], 1.0, 0.6),    # 3.2e-4 sr
    "over_corner": ([0.0, 0.0, 1e-3], 1.0, 0.6),     # a quarter hemisphere
    "hemisphere": ([20.4, 20.3, 0.3], 50.0, 50.0),   # 6.18 sr
    "hemisphere_1e-3": ([20.4, 20.3, 1e-3], 50.0, 50.0),  # 6.2828 sr
    "hemisphere_1e-5": ([20.4, 20.3, 1e-5], 50.0, 50.0),
}


@pytest.mark.parametrize("case", list(RECT_CASES))
def test_spherical_rect_samples_are_uniform_in_solid_angle(case):
    p, sx, sy = RECT_CASES[case]
    p, c = np.float32(p), np.zeros(3, np.float32)
    ex, ey = np.float32([sx, 0, 0]), np.float32([0, sy, 0])
    n, k = 256, 8
    rng = np.random.default_rng(3)
    g = (np.stack(np.meshgrid(np.arange(n), np.arange(n)), -1).reshape(-1, 2) + rng.random((n * n, 2))) / n
    omega, pts, ok = rect_sample(p, c, ex, ey, g)
    ref = rect_solid_angle_ref(p, c, ex, ey)
    assert abs(omega / ref - 1) < 1e-10
    assert ok.all()
    # The points lie on the rectangle...
    s, t = pts[:, 0] / sx, pts[:, 1] / sy
    assert np.abs(pts[:, 2]).max() < 1e-12
    assert min(s.min(), t.min()) >= 0.0 and max(s.max(), t.max()) <= 1.0
    # ...and each of k x k cells gets samples in proportion to the solid angle it subtends (5
    # sigma of a binomial count, plus one sample for cells that expect almost none; the
    # stratified grid does better).
    cell = np.minimum((s * k).astype(int), k - 1) * k + np.minimum((t * k).astype(int), k - 1)
    counts = np.bincount(cell, minlength=k * k)
    for a in range(k):
        for b in range(k):
            f = rect_solid_angle_ref(p, np.float64([a * sx / k, b * sy / k, 0]), ex / k, ey / k) / ref
            exp = f * len(g)
            assert abs(counts[a * k + b] - exp) <= 5 * np.sqrt(exp * (1 - f)) + 1, (a, b, counts[a * k + b], exp)


def rect_group_scene(pos, tris, matrix=None, rect=True, two=False, far_z=1e4):
    s = pc.Scene()
    m = s.add_material("light", (0.0, 0.0, 0.0), (2.0, 2.0, 2.0))
    mesh_id = s.add_mesh(pos, tris, None, None, [m])
    s.add_instance(mesh_id, np.eye(4, dtype=np.float32) if matrix is None else matrix)
    if two:  # a far copy: the mesh becomes instanced (an object-space BLAS)
        far = (np.eye(4) if matrix is None else matrix).astype(np.float32)
        far[:3, 3] += (0.0, 0.0, far_z)
        s.add_instance(mesh_id, far)
    s.rect_groups = rect
    s.commit()
    return s


def turned(seed, scale=(1.0, 1.0, 1.0), shift=(0.3, -0.2, 0.1)):
    m = np.eye(4)
    m[:3, :3] = random_rotation(seed) @ np.diag(scale)
    m[:3, 3] = shift
    return m.astype(np.float32)


def test_rect_groups_only_for_rectangles():
    pos, tris = RECT
    lifted = pos.copy()
    lifted[2, 2] += 0.01  # one corner out of the plane
    trapezoid = pos.copy()
    trapezoid[2, 0] += 0.05
    shear = np.eye(4, dtype=np.float32)
    shear[0, 1] = 0.3
    other_diagonal = np.array([[0, 1, 3], [1, 2, 3]], np.int32)
    flipped = np.array([[0, 1, 2], [0, 3, 2]], np.int32)  # one triangle wound the other way
    cases = [
        ((pos, tris), None, False, 1),
        ((pos, other_diagonal), None, False, 1),
        ((pos, flipped), None, False, 1),
        ((pos, tris), turned(4, (2.0, 0.5, 3.0)), False, 1),  # turned, scaled along its edges, merged
        ((pos, tris), turned(5), 10.0, 2),                    # instanced twice
        # 1e4 away its float corners are no rectangle to 1e-5 (rounding of 1e-3): two triangles.
        ((pos, tris), turned(5), 1e4, 1),
        ((pos * np.float32(1e-3), tris), None, False, 1),     # 1 mm
        (QUAD, None, False, 0),                               # a parallelogram
        ((pos, tris), shear, False, 0),                       # sheared into one
        ((pos, tris), turned(6, (1.0, 1.0, 1.0)) @ shear, False, 0),
        ((lifted, tris), None, False, 0),
        ((trapezoid, tris), None, False, 0),
        ((FAN_POS, FAN_TRIS), None, False, 0),
        ((np.concatenate([pos, pos + np.float32([2, 0, 0])]), np.array([[0, 1, 2], [4, 6, 7]], np.int32)), None, False, 0),
    ]
    for k, ((p, t), matrix, far_z, want) in enumerate(cases):
        s = rect_group_scene(p, t, matrix, two=bool(far_z), far_z=far_z or 0.0)
        assert s.stats()["rect_emitters"] == want, k
    assert rect_group_scene(pos, tris, rect=False).stats()["rect_emitters"] == 0
    # Live transform edits (the viewport's dynamic scene) re-detect it.
    s = pc.Scene(dynamic=True)
    m = s.add_material("light", (0.0, 0.0, 0.0), (2.0, 2.0, 2.0))
    add_object(s, pos, tris, m, matrix=turned(7))
    s.commit()
    assert s.stats()["rect_emitters"] == 1
    s.set_instance_transform(0, turned(7) @ shear)
    s.commit()
    assert s.stats()["rect_emitters"] == 0
    s.set_instance_transform(0, turned(8, (0.5, 2.0, 1.0)))
    s.commit()
    assert s.stats()["rect_emitters"] == 1
    # A quad of two materials is two lights, not a group.
    s = pc.Scene()
    a = s.add_material("a", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    b = s.add_material("b", (0.0, 0.0, 0.0), (4.0, 4.0, 4.0))
    s.add_instance(s.add_mesh(pos, tris, None, np.array([0, 1], np.int32), [a, b]), np.eye(4, dtype=np.float32))
    s.commit()
    assert s.stats()["rect_emitters"] == 0


@pytest.mark.parametrize("mesh", ["rect", "turned", "instanced", "other_diagonal"])
def test_rect_group_samples_have_the_mis_pdf_and_the_two_triangle_distribution(mesh):
    pos, tris = RECT
    matrix = {"turned": turned(4, (2.0, 0.5, 3.0)), "instanced": turned(5)}.get(mesh)
    if mesh == "other_diagonal":
        tris = np.array([[0, 1, 3], [1, 2, 3]], np.int32)
    s = rect_group_scene(pos, tris, matrix, two=mesh == "instanced")
    old = rect_group_scene(pos, tris, matrix, rect=False, two=mesh == "instanced")
    assert s.stats()["rect_emitters"] == 1  # (the instanced one's far copy is not: see above)
    world = pos if matrix is None else (pos @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
    if matrix is not None:  # the probe points around the light, carried with it
        pts = (probe_points() @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
    else:
        pts = probe_points()
    n = 4096
    rng = np.random.default_rng(11)
    kinds = {"spherical": 0, "area": 0}
    # Instanced: the light choice picks the near copy, the first of two of (about: their areas
    # are computed in float, one 1e4 away) equal power.
    pick, rtol = (0.5, 1e-3) if mesh == "instanced" else (1.0, 1e-5)
    for p in pts:
        u = rng.random((n, 3), dtype=np.float32)
        u[:, 0] *= 0.8 * pick
        ok, wi, dist, pdf, pdf_hit, t_hit = s.light_samples(np.repeat(p[None], n, 0), u)
        omega = total_solid_angle(p, world, tris)
        if omega < 1e-9:
            continue
        # The light is all there is near p: a ray along a sample hits it (bar grazing ones past
        # an edge), though not always at the sampled distance to 2e-5 (float rounding).
        hit = ok & (pdf_hit > 0)
        assert hit.sum() > 0.97 * ok.sum(), (p, ok.sum(), hit.sum())
        pdf = pdf / pick
        pdf_hit = pdf_hit / pick
        if omega > 2.01e-4:
            # Uniform over the whole rectangle: one density, 1 / omega (the light is the only
            # one), the one MIS gives every direction that hits it.
            kinds["spherical"] += 1
            assert ok.mean() > 0.99, (p, ok.mean())
            np.testing.assert_allclose(pdf[ok], 1.0 / omega, rtol=rtol)
            np.testing.assert_allclose(pdf_hit[hit], pdf[hit], rtol=1e-6)
            # The two spherical triangles' distribution has the same density (where they sample
            # by solid angle: each triangle above 2e-4 sr).
            ok2, _, _, pdf2, _, _ = old.light_samples(np.repeat(p[None], n, 0), u)
            tri_omegas = [solid_angle_ref(p, world[t]) for t in tris]
            if min(tri_omegas) > 2.01e-4 and max(tri_omegas) < 6.19:
                np.testing.assert_allclose(pdf2[ok2] / pick, pdf[ok].mean(), rtol=1e-6)
        else:
            # A speck: by area, as the triangles (the same pdf as MIS, to rounding).
            kinds["area"] += 1
            assert np.isclose(pdf_hit[hit], pdf[hit], rtol=2e-3).mean() > 0.995
        if matrix is None:
            # E[1/pdf] over the samples is the solid angle they cover: the density integrates to 1.
            est = np.where(ok, 1.0 / np.where(ok, pdf, 1.0), 0.0)
            err = est.std() / np.sqrt(n)
            assert abs(est.mean() - omega) < 5 * err + 2e-3 * omega, (p, est.mean(), omega, err)
    assert kinds["spherical"] >= 30 and kinds["area"] >= 3, kinds


@pytest.mark.converged
def test_rect_group_renders_the_two_triangle_image():
    # The Cornell box (its light a rectangle) at high sample counts: the same image as with two
    # spherical triangles, within the noise of the regions; the whole-image means within 0.5 %.
    imgs = {}
    for rect in (True, False):
        imgs[rect], rect_emitters = cornell_image(True, rect)
        assert rect_emitters == int(rect)
    a, b = region_means(imgs[True], 6), region_means(imgs[False], 6)
    assert abs(imgs[True].mean() / imgs[False].mean() - 1) < 0.005
    np.testing.assert_allclose(a, b, rtol=0.03)


def test_rect_group_with_varying_emission_renders_the_two_triangle_image():
    # Emission from the uv map (a different colour in each channel, across both triangles): the
    # rectangle's sample must land on the right triangle at the right barycentrics. A plane lit by
    # the quad 0.3 above it, rendered with the light sample alone and with MIS.
    from test_core_lights import plane_scene
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    pos, tris = quad((-0.8, -0.5, 0.3), (1.6, 0.0, 0.0), (0.0, 1.0, 0.0))
    prog = [("uv", 0, 0), ("separate", 1, 0, 0), ("separate", 2, 0, 1), ("const", 4, (0.2, 0.0, 0.0, 0.0)),
            ("combine", 3, 1, 2, 4, True), ("closure", "emission", None, {"color": 3})]
    imgs = {}
    for rect in (True, False):
        s = plane_scene()
        m = s.add_shader("uv light", prog)
        s.add_instance(s.add_mesh(pos, tris, None, None, [m], uvs={0: uv}), np.eye(4, dtype=np.float32))
        s.rect_groups = rect
        s.commit()
        assert s.stats()["rect_emitters"] == int(rect)
        imgs[rect] = render(pc, s, 32, 32, samples=256, max_bounces=1, seed=3)[0][..., :3]
    a, b = region_means(imgs[True], 4), region_means(imgs[False], 4)
    assert min(a[..., 0].min(), a[..., 1].min()) > 0
    np.testing.assert_allclose(a, b, rtol=0.03)
    # The image tells u from v: red (u) grows along +x, green (v) along +y under the light, so a
    # swapped or mirrored mapping would differ (measured: 2.4x and 3.0x).
    assert (a[1:3, 2, 0] > 1.5 * a[1:3, 1, 0]).all() and (a[2, 1:3, 1] > 1.5 * a[1, 1:3, 1]).all()
