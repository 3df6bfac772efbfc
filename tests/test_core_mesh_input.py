"""add_mesh's index and normal inputs through the core module alone (no Blender, so the
sanitizer build runs them): int32 index arrays read in place and other integer arrays converted
give the same scene; shared normals (normals + normal_indices, expanded by the core) render
exactly as the expanded corner_normals; bad inputs raise ValueError and add nothing."""
import numpy as np
import pytest

from core_scenes import core, render_lit_mesh

pc = core()


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
