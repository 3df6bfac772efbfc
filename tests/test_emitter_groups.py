"""Emitter groups: a small mesh light (a quad's two triangles, a fan of up to four) chosen as one
light and sampled over its whole solid angle, each triangle picked in proportion to the solid
angle it subtends. Checked through the core module: the density of the light samples against the
pdf the renderer's MIS uses for the same directions, its integral, closed-form irradiance, the
image against per-triangle sampling, and the variance it removes."""
import numpy as np
import pytest

from core_scenes import add_object, core, cornell, quad, region_means, render
from test_core_lights import W, check, expected, plane_scene, solid_angle_ref

pc = core()


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
    """Lambert's polygon formula over the quad's four edges (as test_core_lights' triangle)."""
    from test_core_lights import ALBEDO
    poly = NEAR_QUAD[0]
    a = poly[None, None, None] - p[..., None, :]
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = np.roll(a, -1, axis=-2)
    c = np.cross(a, b)
    theta = np.arccos(np.clip((a * b).sum(-1), -1.0, 1.0))
    return ALBEDO / np.pi * NEAR_L * 0.5 * np.abs((theta * c[..., 2] / np.linalg.norm(c, axis=-1)).sum(-1))


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


def test_grouped_lights_render_the_per_triangle_image():
    # The Cornell box (its light one quad) at high sample counts: the same image either way, to
    # within the noise of the regions; the whole-image means within 0.5 %.
    imgs = {}
    for groups in (True, False):
        s = cornell(pc)
        s.emitter_groups = groups
        imgs[groups] = render(pc, s, 48, 48, samples=512, max_bounces=6, seed=5)[0][..., :3]
    a, b = region_means(imgs[True], 6), region_means(imgs[False], 6)
    assert abs(imgs[True].mean() / imgs[False].mean() - 1) < 0.005
    np.testing.assert_allclose(a, b, rtol=0.03)
