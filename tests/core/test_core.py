"""Tests of the compiled core through its Python module (Mitsuba style): analytic scenes,
unbiasedness, determinism, cancellation, robustness of the ray queries and input validation."""
import time

import numpy as np
import pytest

from core_scenes import (add_object, camera, core, cornell, emitting_enclosure, furnace_scene, quad,
                         region_means, render, uv_sphere)

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


@pytest.mark.parametrize("smooth", [False, True])
def test_white_furnace_albedo_08(smooth):
    img, stats = render(pc, furnace_scene(pc, 0.8, smooth), 64, 64, samples=16)
    center = img[24:40, 24:40, :3]
    assert abs(center.mean() - 0.8) < 0.008
    assert abs(img[:4, :4, :3].mean() - 1.0) < 1e-6  # the world seen directly
    assert stats["nonfinite_samples"] == 0


def test_white_furnace_albedo_1_disappears():
    img, _ = render(pc, furnace_scene(pc, 1.0, smooth=False), 48, 48, samples=16)
    assert np.abs(img[..., :3] - 1.0).max() < 1e-3
    # Smooth shading normals lose a little energy where a cosine sample around the shading
    # normal falls below the geometric surface; Cycles' diffuse BSDF rejects those samples too.
    img, _ = render(pc, furnace_scene(pc, 1.0, smooth=True), 48, 48, samples=64)
    assert abs(img[..., :3].mean() - 1.0) < 0.01


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_emitting_enclosure_reaches_le_over_one_minus_albedo():
    # Inside a closed sphere with emission Le and albedo a, radiance is Le / (1 - a) everywhere
    # (pbrt-v4's analytic integrator test): exercises emission, NEE/MIS, bounces and roulette.
    for use_nee in (True, False):
        img, stats = render(pc, emitting_enclosure(pc), 32, 32, samples=256, max_bounces=64, use_nee=use_nee)
        assert abs(img[..., :3].mean() - 1.0) < 0.01, (use_nee, img[..., :3].mean())
        assert stats["nonfinite_samples"] == 0


@pytest.mark.converged
def test_nee_and_brdf_sampling_converge_to_the_same_image():
    # A larger light keeps pure BSDF sampling's noise low enough to compare region means.
    with_nee, _ = render(pc, cornell(pc, 3.0, 1.0), 48, 48, samples=256, use_nee=True)
    without, _ = render(pc, cornell(pc, 3.0, 1.0), 48, 48, samples=2048, use_nee=False)
    a, b = region_means(with_nee, 4), region_means(without, 4)
    assert abs(with_nee[..., :3].mean() / without[..., :3].mean() - 1.0) < 0.01
    assert np.all(np.abs(a - b) <= 0.04 * np.maximum(b, 0.05)), np.abs(a - b) / np.maximum(b, 0.05)


def test_max_bounces_zero_is_direct_light_only():
    direct, _ = render(pc, cornell(pc), 32, 32, samples=128, max_bounces=0)
    full, _ = render(pc, cornell(pc), 32, 32, samples=128, max_bounces=32)
    # Indirect light makes the box clearly brighter, never darker.
    assert full[..., :3].mean() > 1.15 * direct[..., :3].mean()


def test_deterministic_for_a_seed_and_independent_of_threads():
    a, _ = render(pc, cornell(pc), 40, 24, samples=8, seed=7, threads=1, tile_size=8)
    b, _ = render(pc, cornell(pc), 40, 24, samples=8, seed=7, threads=2, tile_size=16)
    c, _ = render(pc, cornell(pc), 40, 24, samples=8, seed=8, threads=2)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_a_pass_splits_few_tiles_into_bands_with_the_same_image():
    # One 32-pixel tile: 2 threads get bands of its rows (session.cpp run), not one item.
    a, sa = render(pc, cornell(pc), 32, 32, samples=6, seed=3, threads=1)
    b, sb = render(pc, cornell(pc), 32, 32, samples=6, seed=3, threads=2)
    assert sa["work_items"] == 1 and sb["work_items"] == 8
    assert np.array_equal(a, b)
    # Adaptive sampling judges whole tiles: no bands.
    _, sc = render(pc, cornell(pc), 32, 32, samples=6, seed=3, threads=2, adaptive_threshold=0.01)
    assert sc["work_items"] == 1


def test_cancel_stops_quickly():
    st = pc.RenderSettings()
    st.width, st.height, st.samples = 256, 256, 1_000_000
    sess = pc.Session(cornell(pc), st)
    sess.start()
    sess.wait(0.3)
    t = time.perf_counter()
    sess.cancel()
    while not sess.wait(0.05):
        assert time.perf_counter() - t < 1.0
    assert time.perf_counter() - t < 0.5
    assert sess.progress()["cancelled"]
    film = sess.film()
    assert np.isfinite(film).all()


def test_time_limit_is_honoured():
    st = pc.RenderSettings()
    st.width, st.height, st.samples, st.time_limit = 64, 64, 1_000_000, 0.5
    sess = pc.Session(cornell(pc), st)
    t = time.perf_counter()
    sess.start()
    while not sess.wait(1.0):
        pass
    elapsed = time.perf_counter() - t
    assert 0.4 < elapsed < 2.0
    assert 0 < sess.progress()["samples_done"] < 1_000_000


def test_film_rect_matches_film_and_rows_start_at_the_bottom():
    s = pc.Scene()
    bright = s.add_material("bright", (0, 0, 0), (1.0, 1.0, 1.0))
    pos, tris = quad((-10, 0, -10), (20, 0, 0), (0, 0, 10))  # lower half of the view
    add_object(s, pos, tris, bright)
    s.set_camera(camera(pc, (0.0, -5.0, 0.0), (0.0, 0.0, 0.0)))
    st = pc.RenderSettings()
    st.width, st.height, st.samples = 32, 16, 4
    sess = pc.Session(s, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    film = sess.film()
    assert film.shape == (16, 32, 4) and film.dtype == np.float32
    assert film[:6, :, 0].min() == 1.0 and film[10:, :, 0].max() == 0.0  # row 0 is the bottom
    assert np.array_equal(sess.film_rect(3, 2, 10, 7), film[2:9, 3:13])
    with pytest.raises(ValueError):
        sess.film_rect(30, 0, 10, 1)


def closed_icosphere(subdiv=3):
    t = (1.0 + 5 ** 0.5) / 2.0
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    verts = [np.array(x, float) / np.linalg.norm(x) for x in v]
    for _ in range(subdiv):
        cache, nf = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = nf
    return np.array(verts, np.float32), np.array(f, np.int32)


def test_watertight_rays_through_vertices_and_edges_never_escape():
    pos, tris = closed_icosphere(3)
    s = pc.Scene()
    m = s.add_material("m")
    add_object(s, pos, tris, m)
    s.commit()
    # Aim from inside at every vertex and every edge midpoint (exactly shared features), from
    # several origins, plus many random directions.
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    targets = np.concatenate([pos, 0.5 * (pos[edges[:, 0]] + pos[edges[:, 1]])])
    rng = np.random.default_rng(1)
    origins = np.concatenate([np.zeros((1, 3)), rng.uniform(-0.3, 0.3, (15, 3))]).astype(np.float32)
    o = np.repeat(origins, len(targets), 0)
    d = np.tile(targets, (len(origins), 1)) - o
    rd = rng.normal(size=(200_000, 3)).astype(np.float32)
    o = np.concatenate([o, np.zeros_like(rd)]).astype(np.float32)
    d = np.concatenate([d, rd]).astype(np.float32)
    t, prim, _, _ = s.intersect(o, d)
    assert (prim >= 0).all(), f"{(prim < 0).sum()} of {len(prim)} rays escaped"
    assert np.isfinite(t).all()


def test_spawned_rays_do_not_rehit_their_surface_at_any_scale():
    # Tiny, huge and sliver triangles far from and near the origin: points computed from
    # barycentrics as the core does, offset by the core's rule, must never see their triangle.
    rng = np.random.default_rng(2)
    cases = [(1e-4, 0.0), (1.0, 0.0), (1e4, 0.0), (1.0, 1e3), (1e-2, 1e2), ("sliver", 0.0)]
    for scale, shift in cases:
        if scale == "sliver":
            v = np.array([[0, 0, 0], [10, 0, 0], [10, 1e-4, 1e-5]], np.float32)
        else:
            v = (rng.normal(size=(3, 3)) * scale + shift).astype(np.float32)
        s = pc.Scene()
        add_object(s, v, np.array([[0, 1, 2]], np.int32), s.add_material("m"))
        s.commit()
        n = 50_000
        b = rng.uniform(size=(n, 2)).astype(np.float32)
        flip = b.sum(1) > 1
        b[flip] = 1 - b[flip]
        b0 = (np.float32(1) - b[:, 0] - b[:, 1])[:, None]
        p = v[0] * b0 + v[1] * b[:, :1] + v[2] * b[:, 1:]
        # The bound of p's rounding error, as the core computes it for its hit points.
        err = (np.abs(v[0] * b0) + np.abs(v[1] * b[:, :1]) + np.abs(v[2] * b[:, 1:])) * pc.barycentric_error_bound()
        ng = np.cross(v[1] - v[0], v[2] - v[0]).astype(np.float64)
        ng = (ng / np.linalg.norm(ng)).astype(np.float32)
        for side in (1.0, -1.0):
            nn = np.tile(ng * np.float32(side), (n, 1))
            d = rng.normal(size=(n, 3)).astype(np.float32)
            d *= np.sign(d @ nn[0])[:, None]  # leave to the offset side, many at grazing angles
            d[: n // 2] += -nn[: n // 2] * (d[: n // 2] @ nn[0])[:, None] * np.float32(0.999)
            o = pc.offset_ray_origin(p, nn, err.astype(np.float32))
            assert not s.occluded(o, d).any(), (scale, shift, side)


def test_bad_input_raises_clear_errors():
    s = pc.Scene()
    pos, tris = quad((0, 0, 0), (1, 0, 0), (0, 1, 0))
    with pytest.raises(ValueError, match="positions"):
        s.add_mesh(pos[:, :2], tris)
    with pytest.raises(ValueError, match="out of range"):
        s.add_mesh(pos, tris + 10)
    with pytest.raises(ValueError, match="corner_normals"):
        s.add_mesh(pos, tris, np.zeros((5, 3, 3), np.float32))
    with pytest.raises(ValueError):
        s.add_instance(0, np.eye(4))  # no such mesh
    mesh = s.add_mesh(pos, tris)
    with pytest.raises(ValueError, match="NaN"):
        s.add_instance(mesh, np.full((4, 4), np.nan))
    st = pc.RenderSettings()
    st.width, st.height = 64, 64
    with pytest.raises(ValueError, match="camera"):
        pc.Session(s, st)
    s.set_camera(camera(pc, (0, -3, 0), (0, 0, 0)))
    st.width, st.height = 100_000, 100_000
    with pytest.raises(ValueError, match="too large"):
        pc.Session(s, st)
    st.width, st.height, st.samples = 8, 8, 0
    with pytest.raises(ValueError, match="samples"):
        pc.Session(s, st)


def test_nan_and_degenerate_triangles_are_dropped_and_counted():
    s = pc.Scene()
    m = s.add_material("m")
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0], [2, 0, 0]], np.float32)
    tris = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4], [0, 0, 2]], np.int32)
    add_object(s, pos, tris, m)
    s.set_camera(camera(pc, (0.3, 0.3, 3), (0.3, 0.3, 0), up=(0, 1, 0)))
    s.commit()
    st = s.stats()
    assert st["triangles"] == 1 and st["dropped_triangles"] == 3
    img, stats = render(pc, s, 16, 16, samples=2)
    assert np.isfinite(img).all() and stats["nonfinite_samples"] == 0


def test_empty_scene_renders_the_world():
    s = pc.Scene()
    s.set_world_color((0.25, 0.5, 1.0))
    s.set_camera(camera(pc, (0, -3, 0), (0, 0, 0)))
    img, _ = render(pc, s, 8, 8, samples=2)
    assert np.allclose(img[..., :3], [0.25, 0.5, 1.0])


def test_scene_is_locked_while_a_session_renders_it():
    s = cornell(pc)
    st = pc.RenderSettings()
    st.width, st.height, st.samples = 16, 16, 1
    sess = pc.Session(s, st)
    with pytest.raises(RuntimeError, match="in use"):
        s.set_world_color((1, 1, 1))
    del sess


def test_roulette_start_bounce_keeps_the_enclosure_exact():
    # RenderSettings.rr_start_bounce (a measurement setting; docs/design/sampling.md): rolling
    # from the first vertex on or never (a start past every bounce) both converge to the closed
    # form Le / (1 - a) (24 bounces leave out 0.5^25); rolling early traces fewer rays per path.
    out = {}
    for start in (0, 3, 1000):
        img, stats = render(pc, emitting_enclosure(pc), 8, 8, samples=32, max_bounces=24, rr_start_bounce=start)
        assert abs(img[..., :3].mean() - 1.0) < 0.02, (start, img[..., :3].mean())
        out[start] = stats["rays"] / stats["paths"]
    assert out[0] < out[3] < out[1000], out
