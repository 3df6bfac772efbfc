"""Path guiding (core/render/guiding.h): the learnt field's sampling against its pdf, what it
learns, and guided renders: unbiased (analytic scenes keep their closed-form values, the image
agrees with the unguided one), deterministic for a seed whatever the threads and tiles, and off
unless asked for."""
import math

import numpy as np
import pytest

from core_scenes import (add_object, closure, core, cornell, emitting_enclosure, furnace_scene, region_means,
                         render, run_session, uv_sphere)

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

CONE = np.array([0.6, 0.0, 0.8])  # the bright directions of the synthetic field: cos > 0.9


def uniform_dirs(rng, n):
    z = rng.uniform(-1.0, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * math.pi, n)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def trained_field(iterations=3, records=20000, seed=1, order=None):
    """A one-cell field trained on uniformly sampled directions whose radiance is 1 in CONE and
    0.01 elsewhere (records of L / pdf, pdf = 1 / 4 pi)."""
    g = pc.GuidingField()
    g.reset((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1e12)
    rng = np.random.default_rng(seed)
    for _ in range(iterations):
        dirs = uniform_dirs(rng, records)
        values = np.where(dirs @ CONE > 0.9, 1.0, 0.01) * 4.0 * math.pi
        idx = np.arange(records) if order is None else order(records)
        for i in idx:
            g.record((0.5, 0.5, 0.5), tuple(dirs[i]), float(values[i]))
        g.end_iteration(1)
    return g


def square_grid(n):
    """Directions at the centres of an n x n grid over the sphere's equal-area square."""
    x, y = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n, indexing="ij")
    z = 2.0 * x.ravel() - 1.0
    r = np.sqrt(1.0 - z * z)
    phi = 2.0 * math.pi * y.ravel()
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def test_untrained_field_is_uniform():
    g = pc.GuidingField()
    g.reset((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1000.0)
    assert not g.ready
    w, pdf = g.sample((0.5, 0.5, 0.5), 0.3, 0.7)
    assert pdf == pytest.approx(1.0 / (4.0 * math.pi))
    assert np.linalg.norm(w) == pytest.approx(1.0, abs=1e-5)


def test_learnt_field_integrates_to_one_and_samples_its_pdf():
    g = trained_field()
    assert g.ready and g.iterations == 3
    # The quadtree's leaves after three iterations are no finer than 1/256 of the square's
    # side here, so the grid's midpoint sum is exact.
    grid = square_grid(256)
    pdfs = np.array([g.pdf((0.5, 0.5, 0.5), tuple(w)) for w in grid])
    assert pdfs.mean() * 4.0 * math.pi == pytest.approx(1.0, abs=1e-5)
    rng = np.random.default_rng(2)
    hits = 0
    for u1, u2 in rng.uniform(0.0, 1.0, (4000, 2)):
        w, pdf = g.sample((0.5, 0.5, 0.5), float(u1), float(u2))
        assert np.linalg.norm(w) == pytest.approx(1.0, abs=1e-5)
        assert g.pdf((0.5, 0.5, 0.5), w) == pytest.approx(pdf, rel=1e-4)  # the density it sampled
        hits += np.dot(w, CONE) > 0.9
    # Sampled directions fall in the cone as often as the pdf says (binomial noise: 4000 draws).
    cone_mass = pdfs[grid @ CONE > 0.9].sum() / pdfs.sum()
    assert hits / 4000 == pytest.approx(cone_mass, abs=0.03)
    # ... and the field has learnt the light: 84 % of the radiance is in 5 % of the sphere.
    assert cone_mass > 0.65


def test_learning_is_independent_of_the_record_order():
    a = trained_field(iterations=2, records=5000)
    b = trained_field(iterations=2, records=5000,
                      order=lambda n: np.random.default_rng(9).permutation(n))
    for w in square_grid(24):
        assert a.pdf((0.5, 0.5, 0.5), tuple(w)) == b.pdf((0.5, 0.5, 0.5), tuple(w))


def test_crowded_cells_split_and_keep_their_own_light():
    # Records from two corners of the bounds, each with light from its own side: the field
    # splits and each half learns its own direction.
    g = pc.GuidingField()
    g.reset((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 500.0)
    rng = np.random.default_rng(3)
    for it in range(4):
        for corner, light in (((0.1, 0.5, 0.5), (-1.0, 0.0, 0.0)), ((0.9, 0.5, 0.5), (1.0, 0.0, 0.0))):
            dirs = uniform_dirs(rng, 4000)
            for w in dirs:
                g.record(corner, tuple(w), (1.0 if w @ light > 0.8 else 0.0) * 4.0 * math.pi)
        g.end_iteration(2 ** it)
    assert g.cells > 1
    assert g.pdf((0.1, 0.5, 0.5), (-1.0, 0.0, 0.0)) > 10.0 * g.pdf((0.1, 0.5, 0.5), (1.0, 0.0, 0.0))
    assert g.pdf((0.9, 0.5, 0.5), (1.0, 0.0, 0.0)) > 10.0 * g.pdf((0.9, 0.5, 0.5), (-1.0, 0.0, 0.0))


def test_each_surface_orientation_learns_apart():
    # The same point, records on a floor (normal +z) lit from above and on a ceiling (-z) lit
    # from below: each orientation keeps its own light.
    g = pc.GuidingField()
    g.reset((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1e12)
    rng = np.random.default_rng(4)
    for it in range(3):
        for n in ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0)):
            for w in uniform_dirs(rng, 4000):
                g.record((0.5, 0.5, 0.5), tuple(w), (1.0 if w @ np.array(n) > 0.8 else 0.0) * 4.0 * math.pi, n=n)
        g.end_iteration(1)
    up, down = (0.0, 0.0, 1.0), (0.0, 0.0, -1.0)
    assert g.pdf((0.5, 0.5, 0.5), up, n=up) > 10.0 * g.pdf((0.5, 0.5, 0.5), down, n=up)
    assert g.pdf((0.5, 0.5, 0.5), down, n=down) > 10.0 * g.pdf((0.5, 0.5, 0.5), up, n=down)


def test_bad_records_are_ignored():
    g = pc.GuidingField()
    g.reset((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1000.0)
    for v in (float("nan"), float("inf"), -1.0, 0.0):
        g.record((0.5, 0.5, 0.5), (0.0, 0.0, 1.0), v)
    g.record((0.5, 0.5, 0.5), (0.0, 0.0, 1.0), 1e30)  # clamped, not overflowing
    g.record((5.0, -3.0, 0.5), (1.0, 0.0, 0.0), 1.0)  # outside the bounds: the nearest cell
    g.end_iteration(1)
    for w in square_grid(16):
        p = g.pdf((0.5, 0.5, 0.5), tuple(w))
        assert math.isfinite(p) and p >= 0.0
    with pytest.raises(ValueError):
        g.sample((0.5, 0.5, 0.5), 1.0, 0.5)


def test_guided_white_furnace_keeps_its_closed_form_values():
    img, stats = render(pc, furnace_scene(pc, 1.0, smooth=False), 48, 48, samples=64, guiding=True)
    assert "guiding" in stats["kernel"] and stats["guiding_iterations"] == 5  # 1 + 2 + 4 + 8 + 16 samples
    assert abs(img[..., :3].mean() - 1.0) < 0.01
    img, _ = render(pc, furnace_scene(pc, 0.8, smooth=False), 48, 48, samples=64, guiding=True)
    assert abs(img[18:30, 18:30, :3].mean() - 0.8) < 0.01


@pytest.mark.converged  # (slow under the sanitizer; the cheaper tests run the same code)
def test_guided_emitting_enclosure_reaches_le_over_one_minus_albedo():
    for use_nee in (True, False):
        img, stats = render(pc, emitting_enclosure(pc), 32, 32, samples=256, max_bounces=64, use_nee=use_nee,
                            guiding=True)
        assert abs(img[..., :3].mean() - 1.0) < 0.01, (use_nee, img[..., :3].mean())
        assert stats["nonfinite_samples"] == 0


@pytest.mark.converged  # (slow under the sanitizer; the cheaper tests run the same code)
def test_guided_render_agrees_with_the_unguided_one():
    guided, _ = render(pc, cornell(pc, 3.0, 1.0), 48, 48, samples=256, guiding=True)
    plain, _ = render(pc, cornell(pc, 3.0, 1.0), 48, 48, samples=256)
    assert abs(guided[..., :3].mean() / plain[..., :3].mean() - 1.0) < 0.01
    a, b = region_means(guided, 4), region_means(plain, 4)
    assert np.all(np.abs(a - b) <= 0.04 * np.maximum(b, 0.05)), np.abs(a - b) / np.maximum(b, 0.05)


def test_guided_renders_are_deterministic_whatever_the_threads_and_tiles():
    a, _ = render(pc, cornell(pc), 40, 24, samples=16, seed=7, threads=1, tile_size=8, guiding=True)
    b, _ = render(pc, cornell(pc), 40, 24, samples=16, seed=7, threads=2, tile_size=16, guiding=True)
    c, _ = render(pc, cornell(pc), 40, 24, samples=16, seed=7, threads=2, tile_size=8, guiding=True)
    assert np.array_equal(a, b) and np.array_equal(a, c)
    plain, _ = render(pc, cornell(pc), 40, 24, samples=16, seed=7)
    assert not np.array_equal(a, plain)  # (it did guide)


@pytest.mark.converged  # (slow under the sanitizer; the cheaper tests run the same code)
def test_the_field_learns_where_the_light_is():
    # Without light samples, every path finds the Cornell box's small light by its own
    # bounces; the field on the floor learns to look up at it.
    s = cornell(pc, light_strength=40.0, light_size=0.3)
    sess = run_session(pc, s, 64, 64, 512, guiding=True, use_nee=False)
    floor, up = np.array([0.0, -0.3, 0.001]), (0.0, 0.0, 1.0)
    # The mean pdf over directions to a 5 x 5 grid on the light (0.3 wide): the pdf towards one
    # point of it fell below 4x uniform on 1-2 of 6 seeds with any sampler (a quadtree leaf
    # beside the light's; docs/design/sampling.md, "The default").
    g = np.linspace(-0.12, 0.12, 5)
    to_light = np.array([(x, y, 1.98) for x in g for y in g]) - floor
    to_light /= np.linalg.norm(to_light, axis=1, keepdims=True)
    uniform = 1.0 / (4.0 * math.pi)
    assert np.mean([sess.guiding_pdf(tuple(floor), tuple(d), up) for d in to_light]) > 4.0 * uniform
    assert sess.guiding_pdf(tuple(floor), (0.0, 0.0, -1.0), up) < uniform  # nothing comes from below


def test_guiding_is_off_by_default():
    _, stats = render(pc, cornell(pc), 16, 16, samples=4)
    assert "guiding" not in stats["kernel"] and stats["guiding_iterations"] == 0
    assert "guiding" in stats["unused_features"]


def test_photon_records_make_a_cells_distribution_by_their_share():
    # Camera records spread evenly, photon records all from CONE: photons alone (a cell without
    # camera records, or share 1) aim at the cone, share 0 leaves the camera's distribution, and
    # the two scales never meet (each is normalised per cell).
    def field(share, camera=True, photons=True):
        g = pc.GuidingField()
        g.reset((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1e12)
        g.photon_share = share
        rng = np.random.default_rng(5)
        for _ in range(2):
            for w in uniform_dirs(rng, 3000):
                if camera:
                    g.record((0.5, 0.5, 0.5), tuple(w), 1e6)  # far larger than the photons' values
                if photons and w @ CONE > 0.9:
                    g.record_photon((0.5, 0.5, 0.5), tuple(w), 0.5)
            g.end_iteration(1)
        return g

    p, cone = (0.5, 0.5, 0.5), tuple(CONE)
    uniform = 1.0 / (4.0 * math.pi)
    assert field(0.5, camera=False).photon_records > 0
    assert field(0.5, camera=False).pdf(p, cone) > 8.0 * uniform
    assert field(1.0).pdf(p, cone) > 8.0 * uniform
    assert field(0.0).pdf(p, cone) < 2.0 * uniform
    half = field(0.5).pdf(p, cone)
    assert 3.0 * uniform < half < field(1.0).pdf(p, cone)
    assert field(0.5, photons=False).photon_records == 0


def lamp_box(pc):
    """The Cornell box lit by a small point light under its ceiling (photons start at lights)."""
    s = cornell(pc, light_strength=0.0)
    s.add_point_light((0.0, 0.0, 1.8), (2.0, 1.8, 1.5), radius=0.05)
    return s


def test_photon_trained_guiding_is_deterministic_whatever_the_threads_and_tiles():
    kw = dict(samples=16, seed=7, guiding=True, guiding_photons=2.0)
    a, _ = render(pc, lamp_box(pc), 40, 24, threads=1, tile_size=8, **kw)
    b, _ = render(pc, lamp_box(pc), 40, 24, threads=2, tile_size=16, **kw)
    c, _ = render(pc, lamp_box(pc), 40, 24, threads=2, tile_size=8, **kw)
    assert np.array_equal(a, b) and np.array_equal(a, c)
    camera_only, _ = render(pc, lamp_box(pc), 40, 24, samples=16, seed=7, guiding=True)
    assert not np.array_equal(a, camera_only)  # (the photons changed the guide)


def test_photon_trained_guided_white_furnace_keeps_its_closed_form_value():
    img, stats = render(pc, furnace_scene(pc, 1.0, smooth=False), 48, 48, samples=64, guiding=True,
                        guiding_photons=1.0)
    assert abs(img[..., :3].mean() - 1.0) < 0.01
    assert stats["nonfinite_samples"] == 0


@pytest.mark.converged  # (slow under the sanitizer; the cheaper tests run the same code)
def test_photon_trained_guided_render_agrees_with_the_unguided_one():
    guided, stats = render(pc, lamp_box(pc), 48, 48, samples=256, guiding=True, guiding_photons=2.0,
                           guiding_photon_share=1.0)
    plain, _ = render(pc, lamp_box(pc), 48, 48, samples=256)
    assert stats["nonfinite_samples"] == 0
    assert abs(guided[..., :3].mean() / plain[..., :3].mean() - 1.0) < 0.01
    a, b = region_means(guided, 4), region_means(plain, 4)
    assert np.all(np.abs(a - b) <= 0.04 * np.maximum(b, 0.05)), np.abs(a - b) / np.maximum(b, 0.05)


def test_bad_photon_settings_fall_back():
    # Non-finite or negative photon settings: no photons (or the defaults), never a crash.
    plain, _ = render(pc, lamp_box(pc), 16, 16, samples=8, seed=3, guiding=True)
    for photons, share, split in ((float("nan"), 0.5, 1.0), (-3.0, 0.5, 1.0)):
        img, stats = render(pc, lamp_box(pc), 16, 16, samples=8, seed=3, guiding=True, guiding_photons=photons,
                            guiding_photon_share=share, guiding_photon_split=split)
        assert np.array_equal(img, plain)
    img, stats = render(pc, lamp_box(pc), 16, 16, samples=8, seed=3, guiding=True, guiding_photons=1.0,
                        guiding_photon_share=float("nan"), guiding_photon_split=float("inf"))
    assert np.all(np.isfinite(img)) and stats["nonfinite_samples"] == 0


MIRROR = (-0.4, -0.1, 1.2)  # the smooth metal ball's centre in mirror_box


def mirror_box(pc, roughness=0.1):
    """lamp_box with a smooth metal ball near the lamp: its caustics light the walls and floor."""
    s = lamp_box(pc)
    m = s.add_shader("mirror", closure("glossy", color=(0.9, 0.9, 0.9), roughness=roughness))
    pos, tris, nrm = uv_sphere(0.25, center=MIRROR)
    add_object(s, pos, tris, m, nrm)
    return s


CAUSTICS = dict(guiding=True, guiding_photons=2.0, guiding_caustics=True)


def test_caustic_photon_guiding_is_deterministic_whatever_the_threads_and_tiles():
    kw = dict(samples=16, seed=7, **CAUSTICS)
    a, _ = render(pc, mirror_box(pc), 40, 24, threads=1, tile_size=8, **kw)
    b, _ = render(pc, mirror_box(pc), 40, 24, threads=2, tile_size=16, **kw)
    c, _ = render(pc, mirror_box(pc), 40, 24, threads=2, tile_size=8, **kw)
    assert np.array_equal(a, b) and np.array_equal(a, c)
    camera_only, _ = render(pc, mirror_box(pc), 40, 24, samples=16, seed=7, guiding=True)
    assert not np.array_equal(a, camera_only)  # (the caustic photons changed the guide)


def test_caustic_photons_aim_the_walls_at_the_mirror():
    # The ceiling and the left wall see the lamp's caustic in the ball: the photon-trained guide
    # points at the ball more than the camera-trained one (the box's few cells blur both).
    rng = np.random.default_rng(1)
    points = (((-0.4, -0.1, 1.999), (0.0, 0.0, -1.0)), ((-0.7, -0.2, 1.999), (0.0, 0.0, -1.0)),
              ((-0.999, -0.1, 1.5), (1.0, 0.0, 0.0)))

    def towards_ball(sess):  # the mean pdf over directions at the ball's surface, over uniform
        total = 0.0
        for p, n in points:
            v = rng.normal(size=(200, 3))
            d = np.array(MIRROR) + 0.25 * v / np.linalg.norm(v, axis=1)[:, None] - np.array(p)
            d /= np.linalg.norm(d, axis=1)[:, None]
            total += np.mean([sess.guiding_pdf(p, tuple(w), n) for w in d]) * 4.0 * math.pi
        return total / len(points)

    sess = run_session(pc, mirror_box(pc), 32, 32, 32, **CAUSTICS)
    assert sess.stats()["guiding_iterations"] > 0
    caustic, camera = towards_ball(sess), towards_ball(run_session(pc, mirror_box(pc), 32, 32, 32, guiding=True))
    assert caustic > 2.0 and caustic > 1.3 * camera, (caustic, camera)


def mirror_furnace(pc):
    """The white furnace's diffuse sphere (albedo 1) beside a white mirror ball: 1 everywhere."""
    s = furnace_scene(pc, 1.0, smooth=False)
    m = s.add_shader("mirror", closure("glossy", color=(1.0, 1.0, 1.0), roughness=0.0))
    pos, tris, nrm = uv_sphere(0.6, center=(1.2, 0.6, 0.6))
    add_object(s, pos, tris, m, nrm)
    return s


def test_caustic_photon_guided_white_furnace_keeps_its_closed_form_value():
    img, stats = render(pc, mirror_furnace(pc), 48, 48, samples=64, **CAUSTICS)
    assert "guiding" in stats["kernel"] and stats["guiding_iterations"] > 0
    assert abs(img[..., :3].mean() - 1.0) < 0.01, img[..., :3].mean()
    assert stats["nonfinite_samples"] == 0


@pytest.mark.converged  # (slow under the sanitizer; the cheaper tests run the same code)
def test_caustic_photon_guided_render_agrees_with_the_unguided_one():
    # The ball's caustics keep plain renders noisy (256 samples: regions 9-10 % from a 2048-
    # sample render), so the reference has 1024 samples and the regions 8 %.
    guided, stats = render(pc, mirror_box(pc), 48, 48, samples=512, **CAUSTICS)
    plain, _ = render(pc, mirror_box(pc), 48, 48, samples=1024)
    assert stats["nonfinite_samples"] == 0
    assert abs(guided[..., :3].mean() / plain[..., :3].mean() - 1.0) < 0.01
    a, b = region_means(guided, 4), region_means(plain, 4)
    assert np.all(np.abs(a - b) <= 0.08 * np.maximum(b, 0.05)), np.abs(a - b) / np.maximum(b, 0.05)


# Caustic lobes (GuidingField::set_caustic_lobes): directions at a rough vertex towards where
# the kept caustic photons near it came from, in one-sample MIS with the BSDF and the SD-tree.
LOBES = dict(CAUSTICS, guiding_caustic_lobes=0.3)


def test_caustic_lobe_guiding_is_deterministic_whatever_the_threads_and_tiles():
    kw = dict(samples=16, seed=7, **LOBES)
    a, stats = render(pc, mirror_box(pc), 40, 24, threads=1, tile_size=8, **kw)
    b, _ = render(pc, mirror_box(pc), 40, 24, threads=2, tile_size=16, **kw)
    assert np.array_equal(a, b)
    assert stats["guiding_caustic_cells"] > 0  # the ball's caustics found cubes to aim from
    without, stats = render(pc, mirror_box(pc), 40, 24, samples=16, seed=7, **CAUSTICS)
    assert stats["guiding_caustic_cells"] == 0 and not np.array_equal(a, without)


def test_caustic_lobe_guided_white_furnace_keeps_its_closed_form_value():
    img, stats = render(pc, mirror_furnace(pc), 48, 48, samples=64, **LOBES)
    assert stats["guiding_caustic_cells"] > 0
    assert abs(img[..., :3].mean() - 1.0) < 0.01, img[..., :3].mean()
    assert stats["nonfinite_samples"] == 0


@pytest.mark.converged  # (slow under the sanitizer; the furnace above runs the same code)
def test_caustic_lobe_guided_render_agrees_with_the_unguided_one():
    # The ball's caustics make one render's image mean vary by about 0.7 % (256 samples, seed
    # to seed): the means of a few seeds, within 1.5 % (about 2 standard errors).
    guided = [render(pc, mirror_box(pc), 32, 32, samples=128, seed=s, **LOBES) for s in (1, 2, 3)]
    plain = [render(pc, mirror_box(pc), 32, 32, samples=256, seed=s)[0] for s in (1, 2)]
    assert all(st["nonfinite_samples"] == 0 and st["guiding_caustic_cells"] > 0 for _, st in guided)
    g = np.mean([img[..., :3].mean() for img, _ in guided])
    assert abs(g / np.mean([img[..., :3].mean() for img in plain]) - 1.0) < 0.015


def test_bad_caustic_lobe_settings_fall_back():
    for lobes, cube, cone in ((float("nan"), 0.01, 0.1), (0.3, float("inf"), 0.1), (0.3, 0.01, -1.0),
                              (5.0, -2.0, float("nan"))):
        img, stats = render(pc, mirror_box(pc), 16, 16, samples=8, seed=3, guiding_caustic_lobes=lobes,
                            guiding_caustic_cube=cube, guiding_caustic_cone=cone, **CAUSTICS)
        assert np.all(np.isfinite(img)) and stats["nonfinite_samples"] == 0


def test_path_classes_split_the_image():
    # The measurement mask (RenderSettings.guiding_class_mask): with the guide's probability 0
    # the paths are the plain ones, so the six classes' images add up to the whole image, and
    # the ball's caustics on the walls (L S D E) are a class of their own.
    kw = dict(samples=16, seed=4, guiding=True, guiding_probability=0.0)
    whole, _ = render(pc, mirror_box(pc), 24, 24, **kw)
    parts = [render(pc, mirror_box(pc), 24, 24, guiding_class_mask=1 << k, **kw)[0] for k in range(6)]
    assert np.allclose(np.sum(parts, axis=0)[..., :3], whole[..., :3], rtol=1e-4, atol=1e-6)
    assert all(p[..., :3].mean() > 0.0 for p in parts[:3]), [p[..., :3].mean() for p in parts]


def test_caustic_lobes_change_nothing_without_smooth_surfaces():
    # No smooth lobe, no caustic record, no lobes: the same paths as caustic photons alone.
    kw = dict(samples=16, seed=7, **CAUSTICS)
    a, _ = render(pc, lamp_box(pc), 24, 24, **kw)
    b, stats = render(pc, lamp_box(pc), 24, 24, guiding_caustic_lobes=0.3, **kw)
    assert stats["guiding_caustic_cells"] == 0 and np.array_equal(a, b)


# The learnt guide probability (GuidingField.set_learn_probability): per cell, the candidate
# probability (0, 0.1, ..., 0.9) of least estimated second moment; the cosine product
# (guiding_cosine) and Müller's directional filter (guiding_filter).
def moment_field(product, seed=6, samples=2000, initial=1.0):
    """A one-cell field fed the records of a 64-direction toy vertex drawn from the mixture of
    two pdfs, pb (the BSDF's) and pg (the guide's), half and half, whose integrand is
    product(pb, pg): returns the probability it learns (at most `initial`)."""
    rng = np.random.default_rng(seed)
    pb = rng.uniform(0.1, 1.0, 64)
    pb /= pb.sum()
    pg = rng.uniform(0.0, 1.0, 64) ** 4
    pg /= pg.sum()
    q = 0.5 * pb + 0.5 * pg
    f = product(pb, pg)
    g = pc.GuidingField()
    g.reset((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1e12)
    g.set_learn_probability(True, initial)
    for i in rng.choice(64, size=samples, p=q):
        g.record_moment((0.5, 0.5, 0.5), float(f[i] / q[i]), float(q[i]), float(pb[i]), float(pg[i]))
    g.end_iteration(1)
    return g.probability((0.5, 0.5, 0.5))


def test_learnt_probability_follows_the_better_strategy():
    # An integrand shaped as the guide's pdf earns the largest candidate, one shaped as the
    # BSDF's none, their even mixture one half (its second moment is least there, exactly).
    assert moment_field(lambda pb, pg: pg) == pytest.approx(0.9)
    assert moment_field(lambda pb, pg: pb) == 0.0
    assert moment_field(lambda pb, pg: 0.5 * pb + 0.5 * pg) == pytest.approx(0.5)
    # Never above the initial probability; too few records: the cell keeps it.
    assert moment_field(lambda pb, pg: pg, initial=0.3) == pytest.approx(0.3)
    assert moment_field(lambda pb, pg: pb, initial=0.3) == 0.0
    assert moment_field(lambda pb, pg: pg, samples=100, initial=0.5) == pytest.approx(0.5)


def test_directional_filter_spreads_a_record_over_its_leaf():
    # Records from one direction only: unfiltered, the quadtree's leaf about it holds them all;
    # filtered, the leaves beside it share them, the pdf still integrates to one, and sampling
    # draws the density it reports.
    def field(box):
        g = pc.GuidingField()
        g.reset((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1e12)
        g.set_directional_filter(box)
        rng = np.random.default_rng(7)
        for _ in range(3):
            for w in uniform_dirs(rng, 2000):
                g.record((0.5, 0.5, 0.5), tuple(w), 0.01)
            for _ in range(2000):
                g.record((0.5, 0.5, 0.5), tuple(CONE), 1.0)
            g.end_iteration(1)
        return g

    p = (0.5, 0.5, 0.5)
    plain, box = field(False), field(True)
    grid = square_grid(256)
    pdfs = np.array([box.pdf(p, tuple(w)) for w in grid])
    assert pdfs.mean() * 4.0 * math.pi == pytest.approx(1.0, abs=1e-4)
    assert box.pdf(p, tuple(CONE)) < plain.pdf(p, tuple(CONE))
    near = grid[(grid @ CONE > 0.9) & (grid @ CONE < 0.98)]
    assert np.mean([box.pdf(p, tuple(w)) for w in near]) > np.mean([plain.pdf(p, tuple(w)) for w in near])
    rng = np.random.default_rng(8)
    for u1, u2 in rng.uniform(0.0, 1.0, (500, 2)):
        w, pdf = box.sample(p, float(u1), float(u2))
        assert box.pdf(p, w) == pytest.approx(pdf, rel=1e-4)


LEARNT = dict(guiding=True, guiding_learn_probability=True, guiding_cosine=True, guiding_filter=True)


def test_learnt_probability_cosine_and_filter_are_deterministic_whatever_the_threads_and_tiles():
    kw = dict(samples=16, seed=7, **LEARNT)
    a, _ = render(pc, cornell(pc), 40, 24, threads=1, tile_size=8, **kw)
    b, _ = render(pc, cornell(pc), 40, 24, threads=2, tile_size=16, **kw)
    assert np.array_equal(a, b)
    fixed, _ = render(pc, cornell(pc), 40, 24, samples=16, seed=7, guiding=True)
    assert not np.array_equal(a, fixed)  # (they changed the guide)


def test_learnt_probability_guided_white_furnace_keeps_its_closed_form_value():
    img, stats = render(pc, furnace_scene(pc, 1.0, smooth=False), 48, 48, samples=64, **LEARNT)
    assert abs(img[..., :3].mean() - 1.0) < 0.01
    assert stats["nonfinite_samples"] == 0


@pytest.mark.converged  # (slow under the sanitizer; the cheaper tests run the same code)
def test_learnt_probability_guided_render_agrees_with_the_unguided_one():
    guided, _ = render(pc, cornell(pc, 3.0, 1.0), 48, 48, samples=256, **LEARNT)
    plain, _ = render(pc, cornell(pc, 3.0, 1.0), 48, 48, samples=256)
    assert abs(guided[..., :3].mean() / plain[..., :3].mean() - 1.0) < 0.01
    a, b = region_means(guided, 4), region_means(plain, 4)
    assert np.all(np.abs(a - b) <= 0.04 * np.maximum(b, 0.05)), np.abs(a - b) / np.maximum(b, 0.05)
