"""Compressed (quantised) wide BVH nodes (issue 6, "compact nodes"; Scene.compact_bvh): child
boxes as bytes from a per-node origin in power-of-two steps. They must be conservative (every
dequantised box, computed as the traversal computes it, contains the child's true box), so the
traversal reports exactly the float tree's hits: the same t, triangle and barycentrics on
awkward rays, on hostile inputs (flat scenes whose boxes have zero extent on an axis, scenes far
from the origin, tiny and huge scales), through the top level of instanced scenes, and the same
images bit for bit; and the nodes take less memory."""
import numpy as np
import pytest

from core_scenes import core, cornell, render, uv_sphere
from test_bvh import awkward_rays, awkward_soup, brute_force_closest, hostile_soup, noisy_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
HAS_AVX2 = pc.build_info()["bvh"] == "bvh8"
WIDE = ("bvh4", "bvh8")


def make_scene(meshes, layout, compact, matrices=None, **kw):
    s = pc.Scene(**kw)
    s.compact_bvh = compact
    for k, (pos, tris) in enumerate(meshes):
        mesh = s.add_mesh(pos, tris)
        for m in (matrices or [np.eye(4, dtype=np.float32)]):
            s.add_instance(mesh, m)
    s.commit(bvh=layout)
    return s


def same_hits(a, b, o, d, tmax=np.inf):
    ha, hb = a.intersect(o, d, tmax), b.intersect(o, d, tmax)
    for x, y in zip(ha, hb):
        assert np.array_equal(x, y)
    assert np.array_equal(a.occluded(o, d, tmax), b.occluded(o, d, tmax))
    return ha


@pytest.fixture(scope="module")
def awkward():
    rng = np.random.default_rng(7)
    meshes = [noisy_sphere(120, rng), awkward_soup(rng)]
    return meshes, {(lay, c): make_scene(meshes, lay, c) for lay in WIDE for c in ("off", "on")}


def test_the_setting_is_validated_and_rebuilds_the_geometry():
    s = make_scene([noisy_sphere(8, np.random.default_rng(0))], "auto", "off")
    assert s.compact_bvh == "off" and not s.stats()["bvh_compact"]
    builds = s.stats()["geometry_builds"]
    s.compact_bvh = "on"
    s.commit()
    assert s.compact_bvh == "on" and s.stats()["bvh_compact"]
    assert s.stats()["geometry_builds"] == builds + 1
    s.commit()  # unchanged: no rebuild
    assert s.stats()["geometry_builds"] == builds + 1
    with pytest.raises(ValueError):
        s.compact_bvh = "yes"
    # "auto" (the default) compresses only huge BLASes (over 8M triangles, too big for a test).
    auto = make_scene([noisy_sphere(40, np.random.default_rng(0))], "auto", "auto")
    assert pc.Scene().compact_bvh == "auto" and not auto.stats()["bvh_compact"]


@pytest.mark.parametrize("layout", WIDE)
def test_nodes_are_smaller_and_the_tree_is_the_same(awkward, layout):
    _, sc = awkward
    off, on = sc[(layout, "off")], sc[(layout, "on")]
    so, sn = off.stats(), on.stats()
    assert so["bvh_layout"] == sn["bvh_layout"] == ("bvh8" if layout == "bvh8" and HAS_AVX2 else "bvh4")
    assert not so["bvh_compact"] and sn["bvh_compact"]
    assert so["bvh_wide_nodes"] == sn["bvh_wide_nodes"] > 0
    # 8-wide nodes 256 -> 128 bytes, 4-wide 128 -> 80; nothing else changes.
    saved = 128 if sn["bvh_layout"] == "bvh8" else 48
    assert so["bvh_bytes"] - sn["bvh_bytes"] == saved * sn["bvh_wide_nodes"]
    no, nn = off.wide_bvh_nodes(), on.wide_bvh_nodes()
    assert not no["compact"] and nn["compact"]
    for k in ("child", "count", "valid", "triangles", "prims"):
        assert np.array_equal(no[k], nn[k], equal_nan=k == "triangles"), k


def true_boxes(nodes):
    """The true box (lo x, hi x, lo y, ...) of every used lane from the triangles below it, bottom
    up (a child node's index is above its parent's)."""
    box, child, count, valid, tris = nodes["box"], nodes["child"], nodes["count"], nodes["valid"], nodes["triangles"]
    m, w = child.shape
    node_box = np.zeros((m, 6))
    lane_box = np.full((m, w, 6), np.nan)
    for n in range(m - 1, -1, -1):
        for i in np.flatnonzero(valid[n]):
            if count[n, i]:
                first = child[n, i]
                t = tris[first: first + (count[n, i] + 3) // 4].reshape(-1, 3, 3)[: count[n, i]]  # (k, vertex, axis)
                lane_box[n, i, 0::2] = t.min(axis=(0, 1))
                lane_box[n, i, 1::2] = t.max(axis=(0, 1))
            else:
                assert child[n, i] > n
                lane_box[n, i] = node_box[child[n, i]]
        used = lane_box[n, valid[n]]
        node_box[n, 0::2] = used[:, 0::2].min(0)
        node_box[n, 1::2] = used[:, 1::2].max(0)
    return lane_box


def check_conservative(s):
    nodes = s.wide_bvh_nodes()
    assert nodes["compact"]
    truth = true_boxes(nodes)
    v = nodes["valid"]
    q = nodes["box"].astype(np.float64)
    assert (q[..., 0::2][v] <= truth[..., 0::2][v]).all()  # dequantised lo at or below the true lo
    assert (q[..., 1::2][v] >= truth[..., 1::2][v]).all()
    # And tight: per axis at most about two steps (a step < 2 x the node's extent / 255) beyond,
    # plus rounding far from the origin.
    ext = np.maximum(truth[..., 1::2].max(1, where=v[..., None], initial=-np.inf)
                     - truth[..., 0::2].min(1, where=v[..., None], initial=np.inf), 0.0)  # (m, 3)
    mag = np.abs(truth).max(axis=(1, 2), where=v[..., None], initial=0.0)
    slack = 4.0 * ext / 255.0 + 4.0 * np.spacing(mag.astype(np.float32))[:, None] + 1e-37
    assert (truth[..., 0::2] - q[..., 0::2] <= slack[:, None, :])[v].all()
    assert (q[..., 1::2] - truth[..., 1::2] <= slack[:, None, :])[v].all()
    return nodes


@pytest.mark.parametrize("layout", WIDE)
def test_every_dequantised_box_contains_the_true_box(awkward, layout):
    _, sc = awkward
    check_conservative(sc[(layout, "on")])
    # The float tree's boxes are the true ones (no spatial splits): the same lanes.
    f, q = sc[(layout, "off")].wide_bvh_nodes(), sc[(layout, "on")].wide_bvh_nodes()
    v = f["valid"]
    assert (q["box"][..., 0::2][v] <= f["box"][..., 0::2][v]).all()
    assert (q["box"][..., 1::2][v] >= f["box"][..., 1::2][v]).all()
    assert np.allclose(true_boxes(f)[v], f["box"][v])


@pytest.mark.parametrize("layout", WIDE)
@pytest.mark.parametrize("tmax", [np.inf, 2.0])
def test_hits_are_the_float_trees(awkward, layout, tmax):
    _, sc = awkward
    o, d = awkward_rays(np.random.default_rng(11))
    t, prim, _, _ = same_hits(sc[(layout, "off")], sc[(layout, "on")], o, d, tmax)
    assert 0.2 < (prim >= 0).mean() < 0.95
    # The looser boxes cost a few more visits, not many.
    n_off, t_off = sc[(layout, "off")].traversal_counts(o, d)
    n_on, t_on = sc[(layout, "on")].traversal_counts(o, d)
    assert n_off.mean() <= n_on.mean() < 1.15 * n_off.mean()
    assert t_off.mean() <= t_on.mean() < 1.15 * t_off.mean()


def shifted_scaled(meshes, scale, shift):
    return [((pos.astype(np.float64) * scale + shift).astype(np.float32), tris) for pos, tris in meshes]


def grid(n, rng, axis):
    """An n x n grid of triangles (slightly jittered, not overlapping) in the plane coordinate
    `axis` = 0.5 exactly, over [-2, 2]^2: every box has zero extent along that axis."""
    u = np.linspace(-2.0, 2.0, n + 1)
    a, b = np.meshgrid(u, u, indexing="ij")
    j = rng.uniform(-0.3, 0.3, (2,) + a.shape) * (4.0 / n)
    j[:, [0, -1], :] = 0.0
    j[:, :, [0, -1]] = 0.0
    uv = np.stack([a + j[0], b + j[1]], -1).reshape(-1, 2)
    pos = np.insert(uv, axis, 0.5, axis=1).astype(np.float32)
    i, k = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    q = (i * (n + 1) + k).ravel()
    return pos, np.concatenate([np.stack([q, q + n + 1, q + 1], 1), np.stack([q + 1, q + n + 1, q + n + 2], 1)]).astype(np.int32)


HOSTILE = {
    # A flat floor (z = 0.5 exactly: every box has zero extent in z, the step clamps to 2^-126)
    # crossed by a flat wall (x = 0.5 exactly).
    "flat": lambda rng: [grid(40, rng, 2), grid(20, rng, 0)],
    "far": lambda rng: shifted_scaled([noisy_sphere(40, rng)], 1.0, (3e4, -2e4, 1e4)),
    "very_far": lambda rng: shifted_scaled([noisy_sphere(40, rng)], 1.0, (1e7, 0.0, -3e6)),
    "tiny": lambda rng: shifted_scaled([noisy_sphere(40, rng)], 1e-9, 0.0),
    "tiny_far": lambda rng: shifted_scaled([noisy_sphere(40, rng)], 1e-6, (1.0, 2.0, -3.0)),
    "huge": lambda rng: shifted_scaled([noisy_sphere(40, rng)], 1e8, 0.0),
}


@pytest.mark.parametrize("layout", WIDE)
@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_scales_and_zero_extents(layout, case):
    rng = np.random.default_rng(3)
    meshes = HOSTILE[case](rng)
    off, on = make_scene(meshes, layout, "off"), make_scene(meshes, layout, "on")
    assert on.stats()["bvh_compact"] and on.stats()["triangles"] > 1000
    check_conservative(on)
    # Rays from around the scene's box at its targets' triangles, and random ones through it.
    tv = np.concatenate([pos[tris] for pos, tris in meshes]).astype(np.float64)
    lo, hi = tv.reshape(-1, 3).min(0), tv.reshape(-1, 3).max(0)
    c, r = (lo + hi) / 2, max((hi - lo).max(), 1e-30)
    n = 4000
    aim = tv[rng.integers(0, len(tv), n)].mean(1)
    o = c + rng.normal(size=(n, 3)) * r
    d = aim - o
    d[n // 2:] = rng.normal(size=(n // 2, 3))  # random directions from around the scene
    d /= np.linalg.norm(d, axis=1, keepdims=True)  # unit directions: t in scene units
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    t, prim, _, _ = same_hits(off, on, o32, d32)
    assert (prim >= 0).mean() > 0.3
    # A few against brute force in double precision.
    ks = np.arange(0, n, 97)
    for k, best in zip(ks, brute_force_closest(tv, o32[ks], d32[ks])):
        if np.isfinite(best) and prim[k] >= 0:
            assert abs(t[k] - best) <= 1e-4 * best, (k, t[k], best)


@pytest.mark.parametrize("layout", WIDE)
def test_hostile_soup_matches_brute_force(layout):
    # NaN, inf and beyond-1e30 triangles (dropped by the scene), zero-area ones, duplicates, 600
    # equal centroids: the compressed tree finds the float tree's hits, and those are brute force's.
    rng = np.random.default_rng(5)
    tri, usable = hostile_soup(rng, n=20_000)
    mesh = [(tri.reshape(-1, 3), np.arange(3 * len(tri), dtype=np.int32).reshape(-1, 3))]
    off, on = make_scene(mesh, layout, "off"), make_scene(mesh, layout, "on")
    assert on.stats()["bvh_compact"] and on.stats()["dropped_triangles"] == (~usable).sum()
    check_conservative(on)
    target = np.flatnonzero(usable)[rng.integers(0, usable.sum(), 200)]
    aim = tri[target].astype(np.float64).mean(1)
    o = rng.normal(size=(200, 3)) * 30
    o32, d32 = o.astype(np.float32), (aim - o).astype(np.float32)
    t, prim, _, _ = same_hits(off, on, o32, d32)
    tri64 = np.where(usable[:, None, None], tri, np.nan).astype(np.float64)
    for k, best in enumerate(brute_force_closest(tri64, o32, d32)):
        assert prim[k] >= 0 and abs(t[k] - best) <= 1e-5 * best, k


@pytest.mark.parametrize("mode", ["shared", "dynamic"])
def test_instanced_scenes_through_the_top_level(mode):
    rng = np.random.default_rng(9)
    sphere = noisy_sphere(30, rng)
    mats = []
    for i in range(6):
        a = rng.normal(size=(3, 3)) * 0.3 + np.eye(3)
        m = np.eye(4)
        m[:3, :3] = a
        m[:3, 3] = (3.0 * (i % 3) - 3.0, 3.0 * (i // 3) - 1.5, 0.2 * i)
        mats.append(m.astype(np.float32))
    kw = {"dynamic": True} if mode == "dynamic" else {}
    off = make_scene([sphere], "auto", "off", mats, **kw)
    on = make_scene([sphere], "auto", "on", mats, **kw)
    assert on.stats()["tlas_instances"] == 6 and on.stats()["bvh_compact"]
    assert off.stats()["bvh_bytes"] > on.stats()["bvh_bytes"]
    n = 20_000
    o = (rng.normal(size=(n, 3)) * [6, 5, 3]).astype(np.float32)
    d = (rng.normal(size=(n, 3)) * [1, 1, 0.3] - o * 0.2).astype(np.float32)
    hits = on.intersect(o, d, instances=True)
    for x, y in zip(off.intersect(o, d, instances=True), hits):
        assert np.array_equal(x, y)
    prim, inst = hits[1], hits[4]
    assert (prim >= 0).mean() > 0.2 and len(np.unique(inst[prim >= 0])) == 6
    assert np.array_equal(off.occluded(o, d, 3.0), on.occluded(o, d, 3.0))


@pytest.mark.parametrize("layout", WIDE)
def test_images_are_bit_for_bit_the_float_trees(layout):
    films = []
    for c in ("off", "on"):
        s = cornell(pc)
        s.compact_bvh = c
        s.commit(bvh=layout)
        assert s.stats()["bvh_compact"] == (c == "on")
        film, st = render(pc, s, 48, 48, 8, seed=3, threads=2)
        films.append(film)
    assert films[0].mean() > 0.01
    assert np.array_equal(films[0], films[1])


@pytest.mark.parametrize("layout", WIDE)
def test_compact_nodes_over_the_clustered_build(awkward, layout):
    # The two build options meet in collapse(): a clustered ("fast") tree compressed must still
    # be conservative and hit exactly as the same tree in float nodes.
    meshes, _ = awkward
    sc = {}
    for c in ("off", "on"):
        s = pc.Scene()
        s.compact_bvh, s.build_quality = c, "fast"
        for pos, tris in meshes:
            s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
        s.commit(bvh=layout)
        assert s.stats()["bvh_clusters"] > 0 and s.stats()["bvh_compact"] == (c == "on")
        sc[c] = s
    check_conservative(sc["on"])
    o, d = awkward_rays(np.random.default_rng(12))
    same_hits(sc["off"], sc["on"], o, d)
