"""Adaptive subdivision in the core (pc.subdivide_mesh, geometry/subdivide.h) without Blender:
limit positions against the closed-form B-spline values of a regular grid, creases and boundary
rules, watertight dicing (every diced edge shared by exactly two triangles, opposite ways) on
closed cages of quads, n-gons and triangles, and a dicing density that follows the camera."""
import numpy as np
import pytest

from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

EYE = np.eye(4, dtype=np.float32)


def polymesh(faces):
    corner_verts = np.array([v for f in faces for v in f], np.int32)
    offsets = np.cumsum([0] + [len(f) for f in faces]).astype(np.int32)
    return corner_verts, offsets


CUBE_P = np.array([(x, y, z) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], np.float32)
CUBE_F = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]


def prism(n=5):
    """A closed n-gon prism (two n-gons, n quads) plus nothing else."""
    a = 2 * np.pi * np.arange(n) / n
    p = np.concatenate([np.stack([np.cos(a), np.sin(a), -np.ones(n)], 1),
                        np.stack([np.cos(a), np.sin(a), np.ones(n)], 1)]).astype(np.float32)
    faces = [tuple(range(n - 1, -1, -1)), tuple(range(n, 2 * n))]
    faces += [(k, (k + 1) % n, n + (k + 1) % n, n + k) for k in range(n)]
    return p, faces


TETRA_P = np.array([(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)], np.float32)
TETRA_F = [(0, 1, 2), (0, 3, 1), (0, 2, 3), (1, 3, 2)]


def dice(p, faces, matrix=EYE, **kw):
    cv, off = polymesh(faces)
    args = dict(camera_position=(0.0, 0.0, 0.0), pixel_size=1.0, ortho=True, dicing_rate=1.0)
    args.update(kw)
    return pc.subdivide_mesh(p, cv, off, matrix, **args)


def assert_watertight(tris):
    """Closed and consistently wound: every directed edge once, its reverse once."""
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    assert (e[:, 0] != e[:, 1]).all()
    directed = {tuple(x) for x in e.tolist()}
    assert len(directed) == len(e), "a directed edge is used twice"
    missing = [x for x in directed if (x[1], x[0]) not in directed]
    assert not missing, f"{len(missing)} edges open (cracks), e.g. {missing[:3]}"


@pytest.mark.parametrize("name", ["cube", "prism", "tetra"])
def test_dicing_is_watertight_with_uneven_edge_factors(name):
    p, faces = {"cube": (CUBE_P, CUBE_F), "prism": prism(), "tetra": (TETRA_P, TETRA_F)}[name]
    # A perspective camera near one side: edge factors differ from patch to patch.
    out = dice(p, faces, camera_position=(2.5, 0.4, 0.3), pixel_size=0.02, ortho=False, dicing_rate=2.0)
    tris = out["triangles"]
    assert out["max_edge_factor"] > 4
    assert_watertight(tris)
    # Every triangle keeps the cage's outward winding (the limit surface is convex here).
    P = out["positions"]
    t = P[tris]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    centre = t.mean(1) - P.mean(0)
    assert ((n * centre).sum(1) > 0).mean() > 0.999


def test_regular_grid_limit_is_the_bicubic_b_spline():
    n = 6
    rng = np.random.default_rng(3)
    x, y = np.meshgrid(np.arange(n + 1, dtype=np.float32), np.arange(n + 1, dtype=np.float32))
    z = rng.uniform(-0.05, 0.05, x.shape).astype(np.float32)
    p = np.stack([x, y, z], -1).reshape(-1, 3)
    faces = [(j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
             for j in range(n) for i in range(n)]
    # Orthographic, 0.55 units per pixel: unit edges get 2 segments.
    out = dice(p, faces, pixel_size=0.55)
    assert out["max_edge_factor"] == 2
    P = out["positions"]
    w1 = np.array([1, 4, 1]) / 6.0
    w2 = np.array([1, 23, 23, 1]) / 48.0  # cubic B-spline at a knot midpoint
    for (i, j) in [(2, 2), (3, 2), (3, 4)]:  # limit of a regular vertex: tensor (1 4 1) / 6
        ref = w1 @ z[j - 1:j + 2, i - 1:i + 2] @ w1
        assert np.isclose(P[j * (n + 1) + i, 2], ref, atol=2e-5)
        assert np.allclose(P[j * (n + 1) + i, :2], (i, j), atol=1e-5)
    for (i, j) in [(2, 2), (2, 3)]:  # middle of the edge (i, j)-(i + 1, j)
        ref = w1 @ z[j - 1:j + 2, i - 1:i + 3] @ w2
        k = np.flatnonzero(np.all(np.abs(P[:, :2] - (i + 0.5, j)) < 1e-5, axis=1))
        assert len(k) == 1
        assert np.isclose(P[k[0], 2], ref, atol=2e-5)


def test_boundary_corners_and_creases():
    quad = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], np.float32)
    smooth = dice(quad, [(0, 1, 2, 3)])["positions"]
    kept = dice(quad, [(0, 1, 2, 3)], smooth_corners=False)["positions"]
    # Blender's default 'ALL': a one-face corner follows the boundary curve's limit (1/6 in).
    assert np.allclose(smooth[0], (1 / 6, 1 / 6, 0), atol=1e-6)
    assert np.allclose(kept[0], (0, 0, 0), atol=1e-6)  # 'PRESERVE_CORNERS'
    # A cube whose 12 edges are infinitely sharp stays a cube; a smooth one is rounded.
    edges = np.array(sorted({tuple(sorted((f[k], f[(k + 1) % 4]))) for f in CUBE_F for k in range(4)}), np.int32)
    sharp = dice(CUBE_P, CUBE_F, pixel_size=0.2, crease_edges=edges,
                 crease_sharpness=np.full(len(edges), 10.0, np.float32))["positions"]
    assert np.allclose(np.abs(sharp).max(1), 1.0, atol=1e-5)
    assert np.allclose(np.abs(sharp[:8]), 1.0)
    round_ = dice(CUBE_P, CUBE_F, pixel_size=0.2)["positions"]
    assert np.abs(round_).max() < 0.95
    # The cube's corner limit: valence 3, (9 v + 4 * 3 edge nbrs + 3 diagonal) / 24 after
    # refinement; it lies on the diagonal, well inside.
    d = round_[7]
    assert np.allclose(d, d[0]) and 0.4 < d[0] < 0.7
    simple = dice(CUBE_P, CUBE_F, pixel_size=0.2, catmull_clark=False)["positions"]
    assert np.allclose(np.abs(simple).max(1), 1.0, atol=1e-5)


def test_dicing_follows_the_camera_distance():
    p = np.array([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], np.float32)
    counts = []
    for dist in (4.0, 8.0, 16.0):
        out = dice(p, [(0, 1, 2, 3)], camera_position=(0.0, 0.0, dist), pixel_size=1.0 / 100, ortho=False,
                   dicing_rate=1.0)
        t = out["positions"][out["triangles"]]
        # Diced edges are about dicing_rate pixels long (at most twice it, Cycles' estimate).
        lengths = np.linalg.norm(t - np.roll(t, 1, axis=1), axis=2)
        assert lengths.max() / (dist / 100) < 2.5
        counts.append(len(out["triangles"]))
    # Each doubling of the distance quarters the triangles (about).
    assert 3.0 < counts[0] / counts[1] < 5.5 and 3.0 < counts[1] / counts[2] < 5.5
    # max_subdivisions caps the edge factors; the cap still dices watertight.
    capped = dice(p, [(0, 1, 2, 3)], camera_position=(0.0, 0.0, 4.0), pixel_size=1.0 / 100, ortho=False,
                  max_level=3)
    assert capped["max_edge_factor"] <= 8


# Cycles' offscreen_dicing_scale (Camera::world_to_raster_size): a camera at the origin looking
# down -z whose view spans x in +-0.5, y in +-0.375 at unit depth (or in units, orthographic).
AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0))  # right, up, forward
FRAME = (-0.5, 0.5, -0.375, 0.375)  # left, right, bottom, top
OFFSCREEN = dict(offscreen_scale=4.0, camera_axes=AXES, frame=FRAME)


def test_offscreen_pixel_grows_with_the_distance_to_the_view():
    px = 1e-3

    def size(p, scale=4.0, ortho=False):
        return pc.dicing_pixel_size(p, (0.0, 0.0, 0.0), px, ortho, scale, AXES, FRAME)

    approx = pytest.approx
    # In view: the distance times a pixel's angle, as without the scale.
    assert size((0.2, 0.1, -2.0)) == approx(px * np.sqrt(4.05), rel=1e-5)
    # Right of the view 2 ahead: + a pixel's angle x (scale - 1) x the distance to the right
    # side plane (x = 0.5 z, normal (1, 0, -0.5) / |.|); above it likewise with the top one.
    assert size((3.0, 0.0, -2.0)) == approx(px * (np.sqrt(13) + 3 * 2 / np.sqrt(1.25)), rel=1e-5)
    assert size((0.0, 2.0, -2.0)) == approx(px * (np.sqrt(8) + 3 * 1.25 / np.sqrt(1 + 0.375 ** 2)), rel=1e-5)
    # Behind the camera: the distance to the camera stands for the one to the view.
    assert size((0.0, 0.0, 5.0)) == approx(px * (5 + 3 * 5), rel=1e-5)
    assert size((3.0, 0.0, -2.0), scale=1.0) == approx(px * np.sqrt(13), rel=1e-5)
    # Orthographic: the distance to the view's box (here 2.5 in x) over its half diagonal's
    # RMS side, scaling the pixel itself.
    f = 2.5 / np.sqrt((0.5 ** 2 + 0.375 ** 2) / 2)
    assert size((3.0, 0.0, -2.0), ortho=True) == approx(px * (1 + 3 * f), rel=1e-5)
    assert size((0.3, 0.3, -2.0), ortho=True) == approx(px, rel=1e-6)


def predicted_factor(a, b, px, rate=1.0, scale=4.0):
    """Cycles' edge factor of a quad's straight edge: each half (Cycles splits quads in both
    directions first) measured by DiagSplit::T, two segments in pixels of their middles."""
    def T(a, b):
        pts = [a, (a + b) / 2, b]
        lens = [np.linalg.norm(q - p) / pc.dicing_pixel_size(tuple((p + q) / 2), (0.0, 0.0, 0.0), px, False,
                                                              scale, AXES, FRAME) for p, q in zip(pts, pts[1:])]
        return max(1, int(max(np.ceil(sum(lens) / rate), np.ceil(2 * max(lens) / rate))))
    a, b = np.float64(a), np.float64(b)
    return T(a, (a + b) / 2) + T((a + b) / 2, b)


def test_offscreen_patches_dice_coarser_as_cycles_predicts():
    """A strip of eight unit quads at depth 4 (Simple subdivision: flat): the view spans x in
    +-2 there, so four lie in it and four to its right. With the scale the in-view patches
    keep their triangles and the off-screen ones get the edge factors Cycles' rule predicts."""
    xs = np.arange(-2.0, 7.0)
    p = np.array([(x, y, -4.0) for y in (-0.5, 0.5) for x in xs], np.float32)
    n = len(xs)
    faces = [(i, i + 1, n + i + 1, n + i) for i in range(n - 1)]
    px = 1.0 / 100
    kw = dict(camera_position=(0.0, 0.0, 0.0), pixel_size=px, ortho=False, catmull_clark=False)
    plain = dice(p, faces, **kw)
    off = dice(p, faces, **kw, **OFFSCREEN)
    per_face = [np.bincount(d["triangle_faces"], minlength=len(faces)) for d in (plain, off)]
    assert (per_face[0][:3] == per_face[1][:3]).all()  # faces 0-2: no edge off screen
    assert (per_face[1][4:] < per_face[0][4:]).all()
    # The last patch alone (no in-view neighbour): its largest edge factor is Cycles'.
    last = dice(p, [faces[-1]], **kw, **OFFSCREEN)
    i = faces[-1]
    edges = [(p[i[k]], p[i[(k + 1) % 4]]) for k in range(4)]
    assert last["max_edge_factor"] == max(predicted_factor(a, b, px) for a, b in edges)
    assert dice(p, [faces[-1]], **kw)["max_edge_factor"] >= 2 * last["max_edge_factor"]


def test_bad_input_is_refused():
    cv, off = polymesh([(0, 1, 2, 3)])
    q = np.zeros((4, 3), np.float32)
    with pytest.raises(ValueError):
        pc.subdivide_mesh(q, cv, off, EYE, (0, 0, 0), 0.0)
    with pytest.raises(ValueError):
        pc.subdivide_mesh(q, cv, off, EYE, (0, 0, 0), 1.0, crease_edges=np.int32([[0, 9]]),
                          crease_sharpness=np.float32([1.0]))
    with pytest.raises(ValueError):
        pc.subdivide_mesh(q, np.int32([0, 1, 7, 3]), off, EYE, (0, 0, 0), 1.0)
    # A degenerate cage (all points equal) dices without crashing.
    out = pc.subdivide_mesh(q, cv, off, EYE, (0, 0, 1), 0.01)
    assert np.isfinite(out["positions"]).all()
