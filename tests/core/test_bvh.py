"""The wide BVHs (4-wide SSE, 8-wide AVX2) against the binary one they are collapsed from: the
same closest hits (t, triangle, barycentrics) on many rays, including the awkward ones (axis-
parallel directions with zero and negative-zero components, origins inside boxes and on box
planes, slivers, coincident centroids); occluded() agrees with intersect(); commit can be
cancelled from another thread."""
import functools
import threading
import time

import numpy as np
import pytest

from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
LAYOUTS = ("binary", "bvh4", "bvh8")
HAS_AVX2 = pc.build_info()["bvh"] == "bvh8"


def noisy_sphere(n, rng, radius=1.0, center=(0, 0, 0)):
    th = np.linspace(0.0, np.pi, n + 1)
    ph = np.linspace(0.0, 2.0 * np.pi, 2 * n + 1)
    t, p = np.meshgrid(th, ph, indexing="ij")
    r = radius * (1 + 0.05 * np.sin(7 * t) * np.cos(5 * p) + 0.01 * rng.standard_normal(t.shape))
    pos = np.stack([r * np.sin(t) * np.cos(p), r * np.sin(t) * np.sin(p), r * np.cos(t)], -1).reshape(-1, 3)
    w = 2 * n + 1
    i, j = np.meshgrid(np.arange(n), np.arange(2 * n), indexing="ij")
    a = (i * w + j).ravel()
    tris = np.concatenate([np.stack([a, a + w, a + 1], 1), np.stack([a + 1, a + w, a + w + 1], 1)])
    return (pos + center).astype(np.float32), tris.astype(np.int32)


def awkward_soup(rng):
    """Random triangles of all sizes, slivers, axis-aligned cubes sharing planes with box bounds,
    and a fan of triangles with one centroid (no plane splits them: count splits)."""
    parts = []
    c = rng.uniform(-3, 3, (3000, 1, 3))
    parts.append(c + rng.normal(size=(3000, 3, 3)) * rng.choice([1e-3, 0.05, 0.5], (3000, 1, 1)))
    a = rng.uniform(-3, 3, (500, 1, 3))
    e = rng.normal(size=(500, 1, 3))
    parts.append(np.concatenate([a, a + e, a + e * (1 + 1e-4) + rng.normal(size=(500, 1, 3)) * 1e-5], 1))  # slivers
    for k in range(40):  # unit cubes on an integer grid: faces on exact, shared planes
        o = rng.integers(-3, 3, 3).astype(float)
        q = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]) + o
        f = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (2, 3, 7), (2, 7, 6), (1, 2, 6),
             (1, 6, 5), (0, 4, 7), (0, 7, 3)]
        parts.append(q[np.array(f)])
    ang = rng.uniform(0, 2 * np.pi, 200)
    fan = np.stack([np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1),
                    np.stack([np.cos(ang + 2.1), np.sin(ang + 2.1), 0.1 + 0 * ang], 1),
                    np.stack([np.cos(ang + 4.2), np.sin(ang + 4.2), -0.1 + 0 * ang], 1)], 1)
    parts.append(fan * 0.5 + 1.5)
    v = np.concatenate(parts).astype(np.float32)
    return v.reshape(-1, 3), np.arange(len(v) * 3, dtype=np.int32).reshape(-1, 3)


def make_scene(meshes, layout):
    s = pc.Scene()
    for pos, tris in meshes:
        s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    s.commit(bvh=layout)
    return s


def awkward_rays(rng, n=60_000):
    o = rng.uniform(-3.5, 3.5, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    # Axis-parallel directions, with +0 and -0 in the other components.
    k = n // 4
    axis = rng.integers(0, 3, k)
    dd = np.zeros((k, 3), np.float32)
    dd[np.arange(k), axis] = rng.choice([-1.0, 1.0], k)
    dd[rng.uniform(size=(k, 3)) < 0.5] *= -1.0  # negative zeros
    d[:k] = dd
    # Origins on the cubes' integer planes (box planes of the leaves), some inside the sphere.
    o[k: 2 * k] = np.round(o[k: 2 * k])
    o[2 * k: 3 * k] *= 0.1
    # Directions with one zero component.
    d[3 * k:, 0] = 0.0
    return o, d


@pytest.fixture(scope="module")
def scenes():
    rng = np.random.default_rng(7)
    meshes = [noisy_sphere(120, rng), awkward_soup(rng)]
    return {lay: make_scene(meshes, lay) for lay in LAYOUTS}


def test_layouts_are_built_as_asked(scenes):
    assert scenes["binary"].stats()["bvh_layout"] == "binary"
    assert scenes["bvh4"].stats()["bvh_layout"] == "bvh4"
    assert scenes["bvh8"].stats()["bvh_layout"] == ("bvh8" if HAS_AVX2 else "bvh4")
    for lay in ("bvh4", "bvh8"):
        st = scenes[lay].stats()
        assert st["bvh_wide_nodes"] > 0
        assert st["bvh_wide_nodes"] < st["bvh_nodes"] / 2  # 4 and 8 children per node, not 2
        assert st["bvh_bytes"] > 36 * st["triangles"]      # triangles are in there
    auto = make_scene([noisy_sphere(8, np.random.default_rng(0))], "auto")
    assert auto.stats()["bvh_layout"] == pc.build_info()["bvh"]
    with pytest.raises(ValueError):
        auto.commit(bvh="bvh16")


@pytest.mark.parametrize("layout", ["bvh4", "bvh8"])
@pytest.mark.parametrize("tmax", [np.inf, 2.0])
def test_wide_bvh_hits_are_identical_to_the_binary_bvh(scenes, layout, tmax):
    rng = np.random.default_rng(11)
    o, d = awkward_rays(rng)
    t0, p0, u0, v0 = scenes["binary"].intersect(o, d, tmax)
    t1, p1, u1, v1 = scenes[layout].intersect(o, d, tmax)
    hit = p0 >= 0
    assert 0.2 < hit.mean() < 0.95  # the rays do test something
    assert np.array_equal(p0 >= 0, p1 >= 0)
    same = p0 == p1
    # Same triangle: bit-identical t and barycentrics.
    assert np.array_equal(t0[same], t1[same])
    assert np.array_equal(u0[same], u1[same]) and np.array_equal(v0[same], v1[same])
    # A different triangle only for ties: the soup has coplanar overlapping cube faces, hit at
    # the same t up to rounding (which of two such hits wins depends on the visiting order, in
    # the scalar test too: a hit 1 ulp closer can fail T < tmax * det).
    diff = ~same
    assert diff.sum() <= 0.02 * len(p0), diff.sum()  # shared cube faces: many exact ties
    assert (np.abs(t0[diff] - t1[diff]) <= 2 * np.spacing(t0[diff])).all()


@pytest.mark.parametrize("layout", ["bvh4", "bvh8"])
def test_wide_bvh_hits_are_bit_identical_without_ties(layout):
    # A closed bumpy sphere (no overlapping faces, so no ties: random rays almost never hit an edge exactly) seen from inside and outside.
    rng = np.random.default_rng(21)
    mesh = [noisy_sphere(150, rng)]
    ref, wide = make_scene(mesh, "binary"), make_scene(mesh, layout)
    o, d = awkward_rays(rng, 100_000)
    a, b = ref.intersect(o, d), wide.intersect(o, d)
    assert 0.2 < (a[1] >= 0).mean() < 0.95
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    assert np.array_equal(ref.occluded(o, d, 1.0), wide.occluded(o, d, 1.0))


def test_generic_and_avx2_kernels_agree(scenes):
    if not HAS_AVX2:
        pytest.skip("this CPU has no AVX2: the 8-wide kernel is never used")
    rng = np.random.default_rng(12)
    o, d = awkward_rays(rng)
    a, b = scenes["bvh4"].intersect(o, d), scenes["bvh8"].intersect(o, d)
    assert np.array_equal(a[0], b[0])
    assert (a[1] != b[1]).sum() <= 1e-4 * len(o)
    assert np.array_equal(scenes["bvh4"].occluded(o, d, 1.5), scenes["bvh8"].occluded(o, d, 1.5))


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("tmax", [np.inf, 0.5, 3.0])
def test_occluded_agrees_with_intersect(scenes, layout, tmax):
    rng = np.random.default_rng(13)
    o, d = awkward_rays(rng)
    t, prim, _, _ = scenes[layout].intersect(o, d, tmax)
    occ = scenes[layout].occluded(o, d, tmax)
    assert 0.05 < occ.mean() < 0.95
    hit = prim >= 0
    assert not (occ & ~hit).any()  # an occluder is always a real hit before tmax
    assert (t[occ] < tmax).all()
    # Shadow rays count only hits certainly before tmax (t plus its error bound), so a hit
    # within rounding of tmax may not occlude; every other hit does.
    missed = hit & ~occ
    assert missed.sum() <= 1e-3 * len(o), missed.sum()
    assert (t[missed] > tmax * (1 - 1e-4)).all(), t[missed].min()


@pytest.mark.parametrize("layout", LAYOUTS)
def test_tiny_scenes(layout):
    # One triangle: the root is a leaf, and a wide root with one used lane.
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    s = make_scene([(pos, np.array([[0, 1, 2]], np.int32))], layout)
    o = np.array([[0.2, 0.2, 1], [2, 2, 1], [0.2, 0.2, -1]], np.float32)
    d = np.array([[0, 0, -1], [0, 0, -1], [0, 0, -1]], np.float32)
    t, prim, b1, b2 = s.intersect(o, d)
    assert prim.tolist() == [0, -1, -1] and t[0] == 1.0
    assert s.occluded(o, d).tolist() == [True, False, False]
    e = pc.Scene()
    e.commit(bvh=layout)
    assert e.intersect(o, d)[1].tolist() == [-1, -1, -1]
    assert not e.occluded(o, d).any()


@pytest.mark.parametrize("layout", LAYOUTS)
def test_short_directions_hit_as_unit_ones(layout):
    # The triangle test's rounding-error bound on t must scale with the direction: a bound that
    # grew as 1 / |d|^2 (pbrt-v4's, which assumes unit directions) rejected true hits of short
    # ones, as the batch API allows and as object space gives the rays of instances scaled up.
    rng = np.random.default_rng(3)
    s = make_scene([noisy_sphere(60, rng)], layout)
    o = rng.uniform(-3, 3, (20_000, 3)).astype(np.float32)
    d = rng.normal(size=(20_000, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t1, p1, _, _ = s.intersect(o, d)
    assert 0.03 < (p1 >= 0).mean() < 0.5
    for scale in (1e-2, 1e-4, 1e-6):
        ds = (d * np.float32(scale)).astype(np.float32)
        t, p, _, _ = s.intersect(o, ds)
        assert np.array_equal(p, p1), (scale, (p != p1).sum())
        assert np.allclose(t[p1 >= 0] * scale, t1[p1 >= 0], rtol=1e-5)
        assert np.array_equal(s.occluded(o, ds, 2.0 / scale), s.occluded(o, d, 2.0))


def test_instances_scaled_up_hit_as_merged_ones():
    # A mesh instanced at scale 1e4 traces its rays in object space with directions of length
    # 1e-4: it must hit what the same mesh merged in world space hits.
    rng = np.random.default_rng(4)
    pos, tris = noisy_sphere(60, rng)
    m = np.diag([1e4, 1e4, 1e4, 1]).astype(np.float32)
    hits = {}
    o = (rng.uniform(-3, 3, (20_000, 3)) * 1e4).astype(np.float32)
    d = rng.normal(size=(20_000, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for dynamic in (False, True):
        s = pc.Scene(dynamic=dynamic)
        s.add_instance(s.add_mesh(pos, tris), m)
        s.commit()
        assert s.stats()["real_instances"] == int(dynamic)
        hits[dynamic] = s.intersect(o, d)[1]
    assert (hits[False] >= 0).sum() > 500
    assert (hits[True] != hits[False]).sum() <= 2  # near-ties between the two roundings


def big_grid(n):
    """A noisy height field of 2 n^2 triangles (one mesh, so the BVH build dominates commit)."""
    rng = np.random.default_rng(3)
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    z = 0.01 * rng.standard_normal(x.shape)
    pos = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    tris = np.concatenate([np.stack([a, a + n + 1, a + 1], 1), np.stack([a + 1, a + n + 1, a + n + 2], 1)])
    return pos, tris.astype(np.int32)


def commit_cancelled_from_another_thread(s):
    """Commits `s` on a thread while this one keeps asking it to stop; the RuntimeErrors raised."""
    errors = []

    def run():
        try:
            s.commit()
        except RuntimeError as e:
            errors.append(e)

    th = threading.Thread(target=run)
    th.start()
    while th.is_alive():  # commit() clears the request when it starts, so keep asking
        s.cancel_commit()
        time.sleep(0.002)
    th.join()
    return errors


@pytest.mark.parametrize("quality", ["sah", "fast"])
def test_commit_can_be_cancelled_from_another_thread_and_run_again(quality):
    """Also the clustered build: its Morton sort and runs, the SAH over the runs and the second
    pass over their triangles each stop on the request."""
    pos, tris = big_grid(700)  # ~1M triangles: a commit takes a second or more
    s = pc.Scene()
    s.build_quality = quality
    s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    s.cancel_commit()  # no commit running: no effect on the next one
    errors = commit_cancelled_from_another_thread(s)
    assert len(errors) == 1 and "cancelled" in str(errors[0])
    o = np.array([[0.5, 0.5, 1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0]], np.float32)
    with pytest.raises(ValueError, match="commit"):
        s.intersect(o, d)  # uncommitted, not half-built
    s.commit()  # usable: commit again works
    t, prim, _, _ = s.intersect(o, d)
    assert prim[0] >= 0 and abs(t[0] - 1.0) < 0.1
    assert s.stats()["triangles"] == len(tris)
    assert (s.stats()["bvh_clusters"] > 0) == (quality == "fast")


@pytest.mark.parametrize("quality,compact", [("sah", "off"), ("fast", "off"), ("sah", "on")])
def test_build_is_the_same_on_any_number_of_threads(quality, compact):
    """Parallel binning near the root and parallel subtrees give the same tree as one thread:
    same statistics (SAH cost to the bit) and the same hits. 270k triangles, so that the root is
    binned in several chunks (65536 triangles or more each). The clustered build too (Morton
    keys and run boxes in parallel chunks, its second pass over the runs' leaves on several
    threads). The wide tree too, float and compressed: on one thread the collapse is one
    serial pass, on several its subtrees are collapsed apart and copied into place, and every
    node, lane and triangle block must come out the same, in the same order."""
    rng = np.random.default_rng(11)
    meshes = [noisy_sphere(260, rng), awkward_soup(rng)]
    o = rng.uniform(-2, 2, (20_000, 3)).astype(np.float32)
    d = rng.normal(size=(20_000, 3)).astype(np.float32)
    results = []
    for threads in (1, 2, 3, 7):
        s = pc.Scene()
        s.build_quality = quality
        s.compact_bvh = compact
        for pos, tris in meshes:
            s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
        s.commit(threads=threads)
        st = s.stats()
        results.append(({k: st[k] for k in ("triangles", "bvh_nodes", "bvh_leaves", "bvh_max_depth", "bvh_wide_nodes",
                                            "bvh_sah_cost", "bvh_bytes", "bvh_clusters", "bvh_compact")},
                        s.intersect(o, d), s.wide_bvh_nodes(), binary_layout_nodes(s, threads, compact)))
    assert (results[0][0]["bvh_clusters"] > 0) == (quality == "fast")
    assert results[0][0]["bvh_compact"] == (compact == "on")
    assert results[0][0]["triangles"] > 2 * 65536 and results[0][0]["bvh_nodes"] > 50_000
    assert results[0][0]["bvh_wide_nodes"] > 5_000
    if compact == "off":
        assert len(results[0][3]["count"]) > 50_000
    for stats, hits, wide, binary in results[1:]:
        assert stats == results[0][0]
        for a, b in zip(hits, results[0][1]):
            np.testing.assert_array_equal(a, b)
        assert wide.keys() == results[0][2].keys()
        for k in wide:
            np.testing.assert_array_equal(wide[k], results[0][2][k], err_msg=k)
        # The binary layout's nodes too: the same tree, numbered the same (no gaps, depth first).
        assert binary.keys() == results[0][3].keys()
        for k in binary:
            np.testing.assert_array_equal(binary[k], results[0][3][k], err_msg=k)


def binary_layout_nodes(scene, threads, compact):
    """The binary layout's nodes of the scene's meshes (built again with bvh="binary"); {} for
    compressed nodes (the binary layout has none)."""
    if compact == "on":
        return {}
    scene.commit(threads=threads, bvh="binary")
    return scene.binary_bvh_nodes()


def check_binary_nodes(b, stats):
    """The binary layout's node array is one tree without gaps: node count = the stats' nodes,
    every interior node's children in range and numbered after it (so no cycles), every node the
    child of exactly one node (the root of none), children's boxes inside their parent's, and the
    leaves' triangle ranges tiling the leaf order."""
    lo, hi, first, count, prims = b["lo"], b["hi"], b["left_or_first"], b["count"], b["prims"]
    m = len(count)
    assert m == stats["bvh_nodes"] and m % 2 == 1
    inner = np.flatnonzero(count == 0)
    leaf = np.flatnonzero(count > 0)
    assert len(leaf) == stats["bvh_leaves"] == (m + 1) // 2
    left = first[inner].astype(np.int64)
    assert (left > inner).all() and (left + 1 < m).all()
    parents = np.bincount(np.concatenate([[0], left, left + 1]), minlength=m)
    assert (parents == 1).all()  # the root (counted once above) and every child reached exactly once
    for c in (left, left + 1):
        assert (lo[c] >= lo[inner]).all() and (hi[c] <= hi[inner]).all()
    order = leaf[np.argsort(first[leaf], kind="stable")]
    starts = first[order].astype(np.int64)
    ends = starts + count[order]
    assert starts[0] == 0 and (starts[1:] == ends[:-1]).all() and ends[-1] == len(prims)
    assert len(prims) == stats["bvh_references"]
    assert np.array_equal(np.unique(prims), np.arange(stats["triangles"]))  # every triangle in a leaf


@pytest.mark.parametrize("kind", ["sah", "fast", "spatial"])
def test_binary_layout_is_one_tree_without_gaps_and_hits_as_the_wide_one(kind):
    """The builder numbers nodes in pools (each subtree built on another thread gets 2c - 2 slots
    for its c references, the clustered build's second phase one pool per group of leaves), which
    leaves unused slots between them: the binary layout's array is renumbered without them, and
    its hits are the wide layout's. Big enough (70k triangles) that subtrees are built on two
    threads (16384 references or more)."""
    from core_scenes import sliver_room
    rng = np.random.default_rng(17)
    meshes = [noisy_sphere(130, rng)]
    if kind == "spatial":
        meshes.append(sliver_room(seed=3, spheres=40, beams=60, sphere_res=(16, 8)))
    o, d = awkward_rays(rng, 40_000)
    scenes = {}
    for layout in ("binary", "auto"):
        s = pc.Scene()
        s.build_quality = "fast" if kind == "fast" else "sah"
        s.spatial_splits = kind == "spatial"
        for pos, tris in meshes:
            s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
        s.commit(threads=2, bvh=layout)
        scenes[layout] = s
    st = scenes["binary"].stats()
    assert st["triangles"] > 4 * 16384
    assert (st["bvh_clusters"] > 0) == (kind == "fast")
    assert (st["bvh_spatial_splits"] > 0) == (kind == "spatial")
    check_binary_nodes(scenes["binary"].binary_bvh_nodes(), st)
    wide = scenes["auto"].stats()  # another tree (leaves of 4-triangle blocks): its node count from the builder
    assert wide["bvh_nodes"] == 2 * wide["bvh_leaves"] - 1 and wide["bvh_leaves"] > 5000
    t0, p0, u0, v0 = scenes["binary"].intersect(o, d)
    t1, p1, u1, v1 = scenes["auto"].intersect(o, d)
    assert 0.2 < (p0 >= 0).mean()
    assert np.array_equal(p0 >= 0, p1 >= 0)
    same = p0 == p1
    assert np.array_equal(t0[same], t1[same])
    assert np.array_equal(u0[same], u1[same]) and np.array_equal(v0[same], v1[same])
    diff = ~same  # ties only (the room's overlapping faces)
    assert diff.sum() <= 0.01 * len(p0), diff.sum()
    assert (np.abs(t0[diff] - t1[diff]) <= 2 * np.spacing(t0[diff])).all()


def test_memory_per_triangle_is_bounded():
    """Bytes per triangle as allocated, a regression bound: the BVH (wide nodes and 4-triangle
    blocks, about 58 now) and the scene's geometry with smooth normals (the mesh as added with its
    per-vertex normals, shared rather than expanded per corner, and the merged BLAS's world-space
    triangle copy and maps, about 68 now; with expanded corner normals it was ~102, and the
    flattened layout before the two-level BVH also kept per-triangle shading normals, ~142). At
    these rates 10M triangles take under 2 GiB in the core (tests/bench/bench_scaling.py renders
    such a scene)."""
    rng = np.random.default_rng(2)
    pos, tris = noisy_sphere(150, rng)
    normals = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    s = pc.Scene()
    s.add_instance(s.add_mesh(pos, tris, normals=normals, normal_indices=tris), np.eye(4, dtype=np.float32))
    s.commit()
    st = s.stats()
    n = st["triangles"]
    assert n > 80_000
    assert 40 * n < st["bvh_bytes"] < 64 * n   # 36 bytes of coordinates per triangle at least
    # World triangles and the mesh's vertex indices at least; no 36 bytes of corner normals.
    assert (36 + 12) * n < st["geometry_bytes"] < 80 * n


def books(sizes, spacing=4.0):
    """Per size n, a "book" of n triangular pages sharing one spine edge (along x, at y = z = 0
    around its corner), page k turned 0.05 + 0.1 k rad about it: every subset of pages has
    nearly the whole book's box, so the SAH keeps each book one leaf (n <= 8). Returns the
    triangles, and per page rays from the gaps above and below it straight onto its centroid
    (unique closest hits; the upward ones pass through later pages, farther away), plus per book a ray straight down onto the spine, which every page
    shares (edge functions exactly zero: the scalar fallback, a tie broken by triangle order)."""
    pos, tris, org, dirs, spine = [], [], [], [], []
    for c, n in enumerate(sizes):
        cx, cy = spacing * (c % 6), spacing * (c // 6)
        a = 0.05 + 0.1 * np.arange(n)
        base = sum(len(p) for p in pos)
        tip = np.stack([cx + 0.5 + 0 * a, cy + np.cos(a), np.sin(a)], 1)
        pos.append(np.concatenate([[[cx, cy, 0.0], [cx + 1.0, cy, 0.0]], tip]))
        tris.append(np.stack([np.zeros(n), np.ones(n), 2 + np.arange(n)], 1) + base)
        normal = np.stack([0 * a, -np.sin(a), np.cos(a)], 1)
        centroid = (pos[-1][0] + pos[-1][1] + tip) / 3.0
        org += [centroid + 0.01 * normal, centroid - 0.01 * normal]
        dirs += [-normal, normal]
        spine.append([cx + 0.5, cy, 1.0])
    return (np.concatenate(pos).astype(np.float32), np.concatenate(tris).astype(np.int32),
            np.concatenate(org).astype(np.float32), np.concatenate(dirs).astype(np.float32),
            np.asarray(spine, np.float32))


def test_leaves_of_every_size_hit_as_the_block_test_in_order():
    # Leaves of 3 to 8 triangles: one or two four-lane blocks (under AVX2 both in one eight-lane
    # test, lanes 4-7 from the second block). Rays onto every page (each lane) must hit as in the
    # binary tree (a different build, but unique hits), rays onto the spines (a tie among all
    # pages, by the scalar fallback, in either block's lanes) as in the four-wide tree, which
    # has the same leaves and tests their blocks one at a time; shadow rays stop just short of
    # the hits or reach past them.
    sizes = [3, 4, 5, 6, 7, 8, 8, 7, 6, 5, 4, 3]
    pos, tris, o, d, spine = books(sizes)
    s = {lay: make_scene([(pos, tris)], lay) for lay in LAYOUTS}
    assert s["bvh8"].stats()["bvh_leaves"] == len(sizes)  # one leaf per book: sizes 3 to 8
    hits = {lay: s[lay].intersect(o, d) for lay in LAYOUTS}
    pages = np.concatenate([np.tile(np.arange(f, f + n), 2) for f, n in zip(np.cumsum([0] + sizes[:-1]), sizes)])
    assert (hits["binary"][1] == pages).all()  # each page ray hits its page
    assert hits["binary"][0].max() < 0.0101
    for lay in ("bvh4", "bvh8"):
        for x, y in zip(hits["binary"], hits[lay]):
            assert np.array_equal(x, y)
    for tilt in ((0.0, 0.0), (0.3, 0.0)):
        sd = np.tile(np.array([[tilt[0], tilt[1], -1.0]], np.float32), (len(spine), 1))
        a, b = s["bvh4"].intersect(spine, sd), s["bvh8"].intersect(spine, sd)
        assert (a[1] >= 0).all()
        first = np.cumsum([0] + sizes[:-1])  # a book's first page wins the tie... or another one
        assert np.isin(a[1], np.concatenate([np.arange(f, f + n) for f, n in zip(first, sizes)])).all()
        for x, y in zip(a, b):
            assert np.array_equal(x, y)
    for lay in LAYOUTS:
        assert not s[lay].occluded(o, d, 0.0099).any()
        assert s[lay].occluded(o, d, 0.0101).all()
        assert s[lay].occluded(spine, np.tile([[0, 0, -1.0]], (len(spine), 1)).astype(np.float32), 1.01).all()


def hostile_soup(rng, n=70_000):
    """Triangles for the build's hostile cases, shuffled: random ones of many sizes, exact
    duplicates, 600 with one shared centroid (no plane separates them, beyond any leaf and any
    partition buffer), zero-area ones (a repeated vertex), and unusable ones (NaN, inf, beyond
    1e30) that the scene drops. Returns (triangles (T, 3, 3) float32, usable mask)."""
    c = rng.uniform(-10, 10, (n, 1, 3))
    tri = c + rng.normal(size=(n, 3, 3)) * rng.choice([1e-3, 0.02, 0.2, 1.0], (n, 1, 1))
    dup = tri[rng.integers(0, n, 3000)]
    # 600 boxes centred exactly on (0, 0, 3) (v0 = c + a, v1 = c - a, v2 = c + b with |b| <= |a|,
    # all on a 1/1024 grid: exact in float), so 600 equal centroids.
    ang = rng.uniform(0, 2 * np.pi, 600)
    a = np.round(np.stack([np.cos(ang), np.sin(ang), 0.5 + 0 * ang], 1) * 1024) / 1024
    b = a * [0.5, -0.5, 0.25]
    fan = np.stack([a, -a, b], 1) + [0, 0, 3]
    zero = tri[:1000].copy()
    zero[:, 1] = zero[:, 0]  # zero area
    nan = tri[1000:1500].copy()
    nan[np.arange(500), rng.integers(0, 3, 500), rng.integers(0, 3, 500)] = np.nan
    inf = tri[1500:2000].copy()
    inf[np.arange(500), rng.integers(0, 3, 500), rng.integers(0, 3, 500)] = np.inf * rng.choice([-1, 1], 500)
    huge = tri[2000:2200] * 1e31
    parts = [tri, dup, fan, zero, nan, inf, huge]
    usable = np.concatenate([np.ones(len(tri) + len(dup) + len(fan), bool), np.zeros(2200, bool)])
    allt = np.concatenate(parts)
    order = rng.permutation(len(allt))
    return allt[order].astype(np.float32), usable[order]


def brute_force_t(tri, o, d):
    """Möller-Trumbore in float64 against every triangle: the hit distance per triangle (inf where missed)."""
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    with np.errstate(all="ignore"):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        s = o - v0
        u = np.einsum("ij,ij->i", s, p) / det
        q = np.cross(s, e1)
        v = np.einsum("ij,j->i", q, d) / det  # not BLAS: its spinning threads cost more than the product
        t = np.einsum("ij,ij->i", e2, q) / det
        ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & np.isfinite(t)
    return np.where(ok, t, np.inf)


def brute_force_closest(tri, o, d):
    """brute_force_t's closest t for each ray of float32 rays (o, d) (inf where all miss)."""
    return np.array([brute_force_t(tri, a.astype(np.float64), b.astype(np.float64)).min() for a, b in zip(o, d)])


@functools.lru_cache(maxsize=None)
def hostile_case():
    """The hostile soup, rays at it and brute force's closest t per ray: the same for every build
    path below, so computed once (brute force was most of each test's time, 5x more under ASan).
    Returns read-only (triangles, usable mask, float64 triangles with NaN for unusable ones,
    origins, directions, closest t (inf where nothing is hit))."""
    rng = np.random.default_rng(5)
    tri, usable = hostile_soup(rng)
    # Rays at random usable triangles' centroids (from outside the soup), at the fan, and away.
    target = np.flatnonzero(usable)[rng.integers(0, usable.sum(), 300)]
    aim = tri[target].astype(np.float64).mean(1)
    o = rng.normal(size=(300, 3)) * 30
    o[:20] = [0, 0, 20]
    aim[:20] = [0, 0, 3] + rng.normal(size=(20, 3)) * [0.2, 0.2, 0]
    d = aim - o
    d[-20:] = -o[-20:]  # through the soup's middle, most hit something
    d[-5:] = o[-5:]     # away from everything: misses
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    tri64 = np.where(usable[:, None, None], tri, np.nan).astype(np.float64)
    best = brute_force_closest(tri64, o32, d32)
    case = (tri, usable, tri64, o32, d32, best)
    for a in case:
        a.setflags(write=False)
    return case


@pytest.mark.parametrize("quality", ["sah", "fast"])
@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("layout", LAYOUTS)
def test_build_matches_brute_force_on_hostile_soups(layout, threads, quality):
    """Every build path (parallel world copy and triangle filtering, binning into alternating bin
    sets, buffered and in-place partitions, count splits of coincident centroids, blocks filled
    on several threads; the clustered build's Morton runs, with 600 equal codes cut by count)
    against a brute-force test of every triangle: the same closest t and a triangle that is hit
    there, the unusable triangles dropped (and the others' rows kept)."""
    tri, usable, tri64, o32, d32, best = hostile_case()
    s = pc.Scene()
    s.build_quality = quality
    s.add_instance(s.add_mesh(tri.reshape(-1, 3), np.arange(3 * len(tri), dtype=np.int32).reshape(-1, 3)),
                   np.eye(4, dtype=np.float32))
    s.commit(threads=threads, bvh=layout)
    assert s.stats()["dropped_triangles"] == (~usable).sum()
    assert s.stats()["triangles"] == usable.sum()
    t, prim, _, _, inst, row = s.intersect(o32, d32, instances=True)
    for k in range(len(o32)):
        if not np.isfinite(best[k]):
            assert prim[k] == -1 and row[k] == -1, k
            continue
        assert prim[k] >= 0 and inst[k] == 0, k
        assert usable[row[k]], k
        assert abs(t[k] - best[k]) <= 1e-5 * best[k], (k, t[k], best[k])
        bt = brute_force_t(tri64[row[k]:row[k] + 1], o32[k].astype(np.float64), d32[k].astype(np.float64))[0]
        assert abs(bt - best[k]) <= 1e-5 * best[k], (k, bt, best[k])  # that triangle is hit there
    assert (prim[-5:] == -1).all() and (prim[:-20] >= 0).all()
    assert (s.stats()["bvh_clusters"] > 0) == (quality == "fast")


def test_clustered_build_is_used_as_asked_and_hits_as_the_full_sah():
    """build_quality: 'auto' (default) clusters only the big BVHs of dynamic (viewport) scenes;
    'fast' and 'sah' force one or the other. The clustered tree finds the same closest hits (t to
    the bit: the same watertight test on the same triangles) and its SAH cost and traversal work
    stay near the full SAH's (measured on this rough height field and sphere: SAH cost +6.0 %,
    nodes +4.8 % and triangles +5.0 % per ray)."""
    pos, tris = big_grid(240)  # 115k triangles: above the 'auto' threshold (100k)
    rng = np.random.default_rng(2)
    sph_pos, sph_tris = noisy_sphere(150, rng, 0.3, (0.5, 0.5, 0.2))
    o = np.concatenate([rng.uniform(0, 1, (20_000, 3)) + [0, 0, 0.5],
                        rng.uniform(-1, 2, (20_000, 3))]).astype(np.float32)
    d = np.concatenate([np.tile([[0, 0, -1.0]], (20_000, 1)) + rng.normal(size=(20_000, 3)) * 0.3,
                        rng.normal(size=(20_000, 3))]).astype(np.float32)
    built = {}
    for quality, dynamic in (("auto", False), ("auto", True), ("sah", True), ("fast", False)):
        s = pc.Scene(dynamic=dynamic) if dynamic else pc.Scene()
        assert s.build_quality == "auto"
        s.build_quality = quality
        s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
        s.add_instance(s.add_mesh(sph_pos, sph_tris), np.eye(4, dtype=np.float32))
        s.commit()
        built[quality, dynamic] = s
    clusters = {k: s.stats()["bvh_clusters"] for k, s in built.items()}
    assert clusters[("auto", False)] == 0 and clusters[("sah", True)] == 0
    n = built[("auto", False)].stats()["bvh_triangles"]
    assert n / 8 <= clusters[("fast", False)] <= n / 2  # runs of up to 8 triangles, mostly full
    assert clusters[("auto", True)] > 0
    ref = built[("auto", False)]
    t0, p0, _, _ = ref.intersect(o, d)
    assert (p0 >= 0).mean() > 0.3
    for key in (("fast", False), ("auto", True)):
        t1, p1, _, _ = built[key].intersect(o, d)
        np.testing.assert_array_equal(p1 >= 0, p0 >= 0)
        np.testing.assert_array_equal(t1, t0)
    fast = built[("fast", False)]
    # Regression bounds: a bad curve (e.g. cells as long as each axis, so a flat scene's noise
    # ordered it) made the height field's tree 2x worse.
    assert fast.stats()["bvh_sah_cost"] <= 1.10 * ref.stats()["bvh_sah_cost"]
    nodes0, tris0 = ref.traversal_counts(o, d)
    nodes1, tris1 = fast.traversal_counts(o, d)
    assert nodes1.mean() <= 1.10 * nodes0.mean() and tris1.mean() <= 1.10 * tris0.mean()
    with pytest.raises(ValueError, match="build_quality"):
        ref.build_quality = "best"


def test_collapse_leaves_few_two_lane_nodes():
    """The collapse opens a child whose two children are both leaves before larger children:
    left unopened it would become a wide node of two lanes (a node fetch and a traversal step
    for two boxes). Opening the largest child first (alone) left ~40 % of the 8-wide nodes of a
    tessellated sphere with two lanes; hits stay the binary tree's."""
    rng = np.random.default_rng(3)
    pos, tris = noisy_sphere(120, rng)
    s = pc.Scene()
    s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    s.commit(bvh="bvh8")
    w = s.wide_bvh_nodes()
    lanes = w["valid"].sum(axis=1)
    assert len(lanes) > 1000
    assert np.mean(lanes == 2) < 0.2, np.bincount(lanes)
    o = rng.uniform(-2, 2, (5000, 3)).astype(np.float32)
    d = rng.normal(size=(5000, 3)).astype(np.float32)
    b = pc.Scene()
    b.add_instance(b.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    b.commit(bvh="binary")
    for x, y in zip(s.intersect(o, d), b.intersect(o, d)):
        assert np.array_equal(x, y)
