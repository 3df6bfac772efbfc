"""add_mesh's index and normal inputs through the core module alone (no Blender, so the
sanitizer build runs them): int32 index arrays read in place and other integer arrays converted
give the same scene; shared normals (normals + normal_indices, kept shared by the core) render
exactly as the expanded corner_normals; bad inputs raise ValueError and add nothing."""
import numpy as np
import pytest

from core_scenes import core, render_lit_mesh

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def bumpy_grid(n=20, seed=4):
    """A smooth bumpy grid: positions, triangles and per-vertex normals."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    z = 0.2 * np.sin(3 * x) * np.cos(2 * y) + 0.02 * rng.standard_normal(x.shape)
    pos = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    i = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    tris = np.concatenate([np.stack([i, i + 1, i + n + 2], 1), np.stack([i, i + n + 2, i + n + 1], 1)])
    nrm = np.zeros_like(pos)  # area-weighted vertex normals
    face = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    for k in range(3):
        np.add.at(nrm, tris[:, k], face)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return pos, tris, nrm.astype(np.float32)


def render_mesh(pos, tris, **kw):
    return render_lit_mesh(pc, pos, tris, **kw)


@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.uint32, np.int16])
def test_index_arrays_of_any_integer_type_and_layout(dtype):
    pos, tris, nrm = bumpy_grid(6)
    ref = render_mesh(pos, tris.astype(np.int64), corner_normals=nrm[tris])
    strided = np.repeat(tris.astype(dtype), 2, axis=1)[:, ::2]  # not contiguous
    assert not strided.flags.c_contiguous
    for t in (tris.astype(dtype), strided):
        np.testing.assert_array_equal(render_mesh(pos, t, corner_normals=nrm[tris]), ref)


def test_shared_normals_render_as_the_expanded_ones():
    pos, tris, nrm = bumpy_grid()
    expanded = render_mesh(pos, tris, corner_normals=nrm[tris])
    flat = render_mesh(pos, tris)
    assert expanded[..., :3].mean() > 0.05
    assert np.abs(expanded - flat).max() > 1e-3  # the normals matter in this image
    for idx_dtype in (np.int32, np.int64):
        shared = render_mesh(pos, tris, normals=nrm, normal_indices=tris.astype(idx_dtype))
        np.testing.assert_array_equal(shared, expanded)
    # Per-face normals through an index per corner, as the add-on sends flat faces.
    face = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    face = (face / np.linalg.norm(face, axis=1, keepdims=True)).astype(np.float32)
    per_face = np.repeat(np.arange(len(tris), dtype=np.int32), 3).reshape(-1, 3)
    np.testing.assert_array_equal(render_mesh(pos, tris, normals=face, normal_indices=per_face),
                                  render_mesh(pos, tris, corner_normals=np.repeat(face[:, None], 3, 1)))


def test_per_vertex_normals_are_kept_shared():
    """Normals indexed by the triangles' own vertex indices (the add-on's smooth meshes) are kept
    per vertex: 36 bytes per triangle less than expanded corner normals, the same image; other
    indices are kept as given (3 indices, not 3 normals, per triangle)."""
    pos, tris, nrm = bumpy_grid(40)

    def geometry(**kw):
        s = pc.Scene()
        s.add_instance(s.add_mesh(pos, tris, **kw), np.eye(4, dtype=np.float32))
        s.commit()
        return s.stats()["geometry_bytes"]
    expanded = geometry(corner_normals=nrm[tris])
    shared = geometry(normals=nrm, normal_indices=tris)
    indexed = geometry(normals=nrm, normal_indices=tris[:, [1, 2, 0]][:, [2, 0, 1]].copy())  # equal, another array
    corner = geometry(normals=nrm[tris].reshape(-1, 3), normal_indices=np.arange(3 * len(tris), dtype=np.int32).reshape(-1, 3))
    n = len(tris)
    assert expanded - shared >= 32 * n and indexed == shared
    assert 0 < corner - (shared + 12 * len(tris) * 3 - 12 * len(pos)) <= 12 * n  # 3 normals + 3 indices per triangle
    # Fewer normals than vertices: the triangles' indices must still be in range for them.
    with pytest.raises(ValueError, match="normal index"):
        pc.Scene().add_mesh(pos, tris, normals=nrm[:10], normal_indices=tris)


def test_shared_normals_are_validated():
    s = pc.Scene()
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    tri = np.array([[0, 1, 2]], np.int32)
    n = np.array([[0, 0, 1]], np.float32)
    with pytest.raises(ValueError, match="normal index 1 out of range for 1 normals"):
        s.add_mesh(pos, tri, normals=n, normal_indices=np.array([[0, 0, 1]], np.int32))
    with pytest.raises(ValueError, match="normal index -1"):
        s.add_mesh(pos, tri, normals=n, normal_indices=np.array([[0, 0, -1]], np.int64))
    with pytest.raises(ValueError, match="normal_indices must have shape"):
        s.add_mesh(pos, tri, normals=n, normal_indices=np.zeros((2, 3), np.int32))
    with pytest.raises(ValueError, match="normals must have shape"):
        s.add_mesh(pos, tri, normals=np.zeros((1, 4), np.float32), normal_indices=np.zeros((1, 3), np.int32))
    with pytest.raises(ValueError, match="normals need normal_indices"):
        s.add_mesh(pos, tri, normals=n)
    with pytest.raises(ValueError, match="normal_indices need normals"):
        s.add_mesh(pos, tri, normal_indices=np.zeros((1, 3), np.int32))
    with pytest.raises(ValueError, match="not both"):
        s.add_mesh(pos, tri, corner_normals=np.zeros((1, 3, 3), np.float32), normals=n,
                   normal_indices=np.zeros((1, 3), np.int32))
    with pytest.raises(ValueError, match="triangle index 3 out of range for 3 vertices"):
        s.add_mesh(pos, np.array([[0, 1, 3]], np.int32))
    with pytest.raises(ValueError, match="triangle index -1"):
        s.add_mesh(pos, np.array([[0, 1, -1]], np.int64))
    with pytest.raises(ValueError, match="material_indices must have shape"):
        s.add_mesh(pos, tri, material_indices=np.zeros(2, np.int32))
    # None of the failed calls added a mesh: the next one gets id 0.
    assert s.add_mesh(pos, tri, normals=n, normal_indices=np.zeros((1, 3), np.int32)) == 0


# Polygon meshes (the export's fast path; compared with Blender itself in test_export_polygons.py).

def polygon_grid(n=12, seed=6, spread=0.3):
    """A bumpy grid of quads (some non-planar enough to flip), as flat polygon arrays."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    z = spread * rng.standard_normal(x.shape)
    pos = np.stack([x, y, z], -1).reshape(-1, 3).astype(np.float32)
    i = np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]
    cv = np.stack([i, i + 1, i + n + 2, i + n + 1], -1).reshape(-1).astype(np.int32)
    return pos, cv, np.arange(0, len(cv) + 1, 4, dtype=np.int32)


def test_polygon_triangulation_follows_the_quad_flip_rule():
    """Triangles stay, quads split along 0-2 unless (0 1 2) and (0 2 3) face away from each
    other (then 1-3), n-gons get a fan and are counted; vertex triangles match the corners."""
    pos, cv, off = polygon_grid()
    # Append a triangle and a pentagon.
    cv = np.concatenate([cv, [0, 1, 2], [3, 4, 5, 6, 7]]).astype(np.int32)
    off = np.concatenate([off, [off[-1] + 3, off[-1] + 8]]).astype(np.int32)
    corners, verts, ngons = pc.triangulate_polygons(pos, cv, off)
    assert ngons == 1 and corners.shape == (len(cv) - 2 * (len(off) - 1), 3)
    np.testing.assert_array_equal(verts, cv[corners])
    p = pos[cv].astype(np.float32)
    flips = 0
    for f in range(len(off) - 1):
        b, size = off[f], off[f + 1] - off[f]
        t0 = b - 2 * f
        got = corners[t0:t0 + size - 2]
        if size == 4:
            v1, v2, v3, v4 = p[b:b + 4]
            flip = np.dot(np.cross(v2 - v1, v3 - v1), np.cross(v4 - v1, v3 - v1)) > 0
            flips += flip
            want = [[b, b + 1, b + 3], [b + 1, b + 2, b + 3]] if flip else [[b, b + 1, b + 2], [b, b + 2, b + 3]]
        else:
            want = [[b, b + k + 1, b + k + 2] for k in range(size - 2)]
        np.testing.assert_array_equal(got, want)
    assert 5 < flips < len(off) - 10  # both splits occur


def _reference_vertex_normals(pos, cv, off):
    """Angle-weighted Newell face normals per vertex, in float64."""
    p = pos.astype(np.float64)
    out = np.zeros_like(p)
    for f in range(len(off) - 1):
        vs = cv[off[f]:off[f + 1]]
        q = p[vs]
        fn = np.cross(q, np.roll(q, -1, axis=0)).sum(0)
        fn /= np.linalg.norm(fn)
        for k, v in enumerate(vs):
            a, b = q[k - 1] - q[k], q[(k + 1) % len(vs)] - q[k]
            ang = np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))
            out[v] += fn * ang
    return out / np.linalg.norm(out, axis=1, keepdims=True)


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_polygon_vertex_and_corner_normals(threads):
    """Vertex normals are the angle-weighted face normals (arccos approximated within 5e-5);
    corner normals without sharp edges are the vertex normals, with every face sharp the face
    normals, and a sharp edge splits only the corners along it."""
    pos, cv, off = polygon_grid(8, spread=0.1)
    vn = pc.polygon_vertex_normals(pos, cv, off, threads)
    np.testing.assert_allclose(vn, _reference_vertex_normals(pos, cv, off), atol=2e-4)
    # Edges: one id per undirected vertex pair.
    nxt = cv.reshape(-1, 4)[:, [1, 2, 3, 0]].ravel()
    pairs = np.sort(np.stack([cv, nxt], 1), axis=1)
    keys, ce = np.unique(pairs[:, 0] * len(pos) + pairs[:, 1], return_inverse=True)
    ce = ce.astype(np.int32)
    smooth = pc.polygon_corner_normals(pos, cv, off, ce, len(keys), None, None, threads)
    np.testing.assert_allclose(smooth, vn[cv], atol=1e-6)
    flat = pc.polygon_corner_normals(pos, cv, off, ce, len(keys), None, np.ones(len(off) - 1, bool), threads)
    p = pos[cv].reshape(-1, 4, 3).astype(np.float64)
    fn = np.cross(p, np.roll(p, -1, axis=1)).sum(1)
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    np.testing.assert_allclose(flat, np.repeat(fn, 4, axis=0), atol=1e-6)
    sharp = np.zeros(len(keys), bool)
    sharp[ce[5]] = True  # the edge from corner 5 to corner 6
    one = pc.polygon_corner_normals(pos, cv, off, ce, len(keys), sharp, None, threads)
    changed = np.flatnonzero(np.abs(one - smooth).max(1) > 1e-6)
    assert set(cv[changed]) <= {cv[5], cv[6]} and len(changed) >= 2
    with pytest.raises(ValueError, match="corner edge"):
        pc.polygon_corner_normals(pos, cv, off, ce + len(keys), len(keys))
    with pytest.raises(ValueError, match="sharp_faces"):
        pc.polygon_corner_normals(pos, cv, off, ce, len(keys), None, np.ones(3, bool))


def shuffled(pos, cv, seed=1):
    """The same mesh with its vertices renumbered at random (faces then use vertices from all
    over the array) and the permutation: vertex v of the result is vertex perm[v]."""
    perm = np.random.default_rng(seed).permutation(len(pos))
    return pos[perm], np.argsort(perm)[cv].astype(np.int32), perm


def awkward_mesh(n=160):
    """A large grid (over 3 x 32768 corners, so up to three threads share the normals) with
    triangles, n-gons, degenerate faces (a zero-area quad, a face using one vertex twice) and
    loose vertices, as flat polygon arrays."""
    pos, cv, off = polygon_grid(n, seed=9, spread=0.05)
    faces = [list(cv[off[f]:off[f + 1]]) for f in range(len(off) - 1)]
    for k in range(0, len(faces), 37):  # a triangle and a pentagon in place of two quads
        if k + 1 < len(faces):
            a, b = faces[k], faces[k + 1]
            faces[k], faces[k + 1] = a[:3], [a[0], a[1], b[1], b[2], a[3]]
    faces[5] = [faces[5][0], faces[5][1], faces[5][1], faces[5][2]]  # a vertex twice
    pos = np.concatenate([pos, np.zeros((2, 3), np.float32), [[7.0, 7.0, 7.0]]]).astype(np.float32)
    v = len(pos) - 3
    faces.append([v, v + 1, v, v + 1])  # zero area: Newell gives +z
    sizes = [len(f) for f in faces]
    return pos, np.concatenate(faces).astype(np.int32), np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)


def test_vertex_normals_are_the_same_on_any_thread_count():
    """Each vertex sums its faces in face order however the work is split (threads owning
    vertex ranges of a well-numbered mesh; face normals on all threads and the sum on one
    for scattered vertex numbers): bit for bit the same normals."""
    pos, cv, off = awkward_mesh()
    assert len(cv) > 3 * 32768 and (np.diff(off) > 4).any() and (np.diff(off) == 3).any()
    one = pc.polygon_vertex_normals(pos, cv, off, 1)
    assert np.isfinite(one).all() and np.abs(one).max() > 0.5
    for threads in (2, 3, 0):
        np.testing.assert_array_equal(pc.polygon_vertex_normals(pos, cv, off, threads), one)
    spos, scv, perm = shuffled(pos, cv)
    for threads in (1, 2):
        np.testing.assert_array_equal(pc.polygon_vertex_normals(spos, scv, off, threads), one[perm])
    # The corner normals without sharp edges (a separate implementation) agree with them bit for
    # bit wherever a vertex's corners form one fan (all but a few around the odd faces).
    nxt = np.concatenate([np.roll(cv[off[f]:off[f + 1]], -1) for f in range(len(off) - 1)])
    keys, ce = np.unique(np.sort(np.stack([cv, nxt], 1), axis=1) @ [len(pos), 1], return_inverse=True)
    corner = pc.polygon_corner_normals(pos, cv, off, ce.astype(np.int32), len(keys), None, None, 2)
    interior = np.flatnonzero(np.abs(corner - one[cv]).max(1) == 0)
    assert len(interior) > 0.9 * len(cv)


def _edges(pos, cv, off):
    """One edge id per undirected vertex pair, as Blender numbers them (an edge per pair)."""
    nxt = np.concatenate([np.roll(cv[off[f]:off[f + 1]], -1) for f in range(len(off) - 1)])
    keys, ce = np.unique(np.sort(np.stack([cv, nxt], 1), axis=1) @ [len(pos), 1], return_inverse=True)
    return ce.astype(np.int32).ravel(), len(keys)


def hostile_corner_mesh():
    """awkward_mesh (triangles, n-gons, a face using a vertex twice, a zero-area face, loose
    vertices) plus a fin (three faces on one edge), a face wound against its neighbours, a face
    of one vertex three times and one folded back on itself, with random sharp edges and faces."""
    pos, cv, off = awkward_mesh()
    faces = [list(cv[off[f]:off[f + 1]]) for f in range(len(off) - 1)]
    faces[100] = faces[100][::-1]
    a, b = faces[200][0], faces[200][1]
    x = len(pos)
    pos = np.concatenate([pos, [[0.3, 0.2, 1.0], [5.0, 5.0, 5.0]]]).astype(np.float32)  # the last one loose
    faces += [[a, b, x], [b, a, x], [3, 3, 3], [0, 1, 2, 1]]
    cv = np.concatenate(faces).astype(np.int32)
    off = np.concatenate([[0], np.cumsum([len(f) for f in faces])]).astype(np.int32)
    ce, edges = _edges(pos, cv, off)
    rng = np.random.default_rng(4)
    return pos, cv, off, ce, edges, rng.random(edges) < 0.1, rng.random(len(off) - 1) < 0.05


def test_corner_normals_are_the_same_on_any_thread_count():
    """Sharp edges and faces, non-manifold and inconsistently wound edges, degenerate faces,
    loose vertices: each fan sums its corners in corner order however the work is split (threads
    owning vertex and edge ranges; one thread where the numbers are scattered), so the corner
    normals are bit for bit the same on any number of threads and under any vertex or edge
    numbering."""
    pos, cv, off, ce, edges, sharp_edges, sharp_faces = hostile_corner_mesh()
    assert len(cv) > 3 * 32768
    one = pc.polygon_corner_normals(pos, cv, off, ce, edges, sharp_edges, sharp_faces, 1)
    assert np.isfinite(one).all()
    for threads in (2, 3, 0):
        np.testing.assert_array_equal(pc.polygon_corner_normals(pos, cv, off, ce, edges, sharp_edges, sharp_faces,
                                                                threads), one)
    # Vertices and edges renumbered at random (each thread's range would reach every face).
    spos, scv, _ = shuffled(pos, cv)
    eperm = np.random.default_rng(2).permutation(edges)
    sce = np.argsort(eperm)[ce].astype(np.int32)
    for threads in (1, 2):
        got = pc.polygon_corner_normals(spos, scv, off, sce, edges, sharp_edges[eperm], sharp_faces, threads)
        np.testing.assert_array_equal(got, one)
    # A sharp face's corners are its face normal; a smooth mesh's corners (no marks) differ from
    # the marked one's only at vertices of marked edges or faces.
    flat = pc.polygon_corner_normals(pos, cv, off, ce, edges, None, np.ones(len(off) - 1, bool), 2)
    corner_face = np.repeat(np.arange(len(off) - 1), np.diff(off))
    np.testing.assert_array_equal(one[sharp_faces[corner_face]], flat[sharp_faces[corner_face]])
    smooth = pc.polygon_corner_normals(pos, cv, off, ce, edges, None, None, 2)
    marked = np.zeros(len(pos), bool)
    marked[cv[sharp_faces[corner_face]]] = True
    nxt = np.concatenate([np.roll(cv[off[f]:off[f + 1]], -1) for f in range(len(off) - 1)])
    marked[cv[sharp_edges[ce]]] = marked[nxt[sharp_edges[ce]]] = True
    differ = np.abs(one - smooth).max(1) > 0
    assert differ.any() and not differ[~marked[cv]].any()


@pytest.mark.parametrize("threads", [1, 2])
def test_triangulation_without_corner_indices(threads):
    """corners=False gives the same vertex triangles and n-gon count, and no corner indices."""
    pos, cv, off = awkward_mesh(40)
    corners, verts, ngons = pc.triangulate_polygons(pos, cv, off, threads)
    none, verts2, ngons2 = pc.triangulate_polygons(pos, cv, off, threads, corners=False)
    assert none is None and ngons2 == ngons > 0
    np.testing.assert_array_equal(verts2, verts)
    np.testing.assert_array_equal(verts, cv[corners])


def test_face_offsets_from_triangle_faces():
    """polygon_face_offsets: the faces' first corners from the face of each triangle (a face
    of k corners has k - 2); None for triangles out of face order, a face without a triangle
    or corners that do not add up (the add-on's numpy fallback: test_export_polygons.py)."""
    pos, cv, off = awkward_mesh(30)
    sizes = np.diff(off)
    tri_faces = np.repeat(np.arange(len(sizes), dtype=np.int32), sizes - 2)
    got = pc.polygon_face_offsets(tri_faces, len(sizes), len(cv))
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, off)
    np.testing.assert_array_equal(pc.polygon_face_offsets(np.zeros(0, np.int32), 0, 0), [0])
    swapped = tri_faces.copy()
    swapped[[0, -1]] = swapped[[-1, 0]]
    assert pc.polygon_face_offsets(swapped, len(sizes), len(cv)) is None
    assert pc.polygon_face_offsets(tri_faces[tri_faces != 3], len(sizes), len(cv)) is None  # face 3: none
    assert pc.polygon_face_offsets(tri_faces, len(sizes), len(cv) + 1) is None
    assert pc.polygon_face_offsets(tri_faces, len(sizes) - 1, len(cv)) is None  # a face too many
    assert pc.polygon_face_offsets(tri_faces, len(sizes), len(cv) - 1) is None
    with pytest.raises(ValueError):
        pc.polygon_face_offsets(tri_faces, -1, len(cv))
