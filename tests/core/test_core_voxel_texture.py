"""The Point Density texture's grid read (op "tex_voxel", Cycles' svm_node_tex_voxel;
docs/design/volumes.md "Volume Coefficients and Point Density"): a dense grid
(VolumeGrid.from_dense) read at a vector taken to the grid's texture space: as it is (World:
the grid's transform), into the shading object's space (Object), or its generated coordinates
(Texture); 0 outside the grid's box (Cycles' clip extension); bad grids raise."""
import numpy as np
import pytest

from core_scenes import add_object, core
from test_core_hetero_volumes import cube

pc = core()
pytestmark = pytest.mark.sanitize

RES = 8


def texture_grid(values):
    """A dense grid whose object space is the texture space [0, 1]^3 (voxel i at (i + 0.5) / RES)."""
    m = np.diag([1.0 / RES, 1.0 / RES, 1.0 / RES, 1.0])
    m[:3, 3] = 0.5 / RES
    return pc.VolumeGrid.from_dense(values, m), m


def voxel_scene(grid, space, interp="LINEAR"):
    """A box [0, 2]^3 in object space, scaled 1.5 in x and moved by (-0.5, -0.25, -0.3) (over
    the world's [0, 1]^3 too), whose volume's sigma_s is the grid read at the point."""
    s = pc.Scene()
    s.add_volume_grid(grid)
    prog = [("position", 0), ("tex_voxel", 1, 0, 0, "FAC", interp, space), ("const", 2, (0.0,)),
            ("closure", "volume", None, {"sigma_s": 1, "sigma_a": 2})]
    m = s.add_shader("vol", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                     volume=prog)
    pos, tris = cube(1.0)
    matrix = np.diag([1.5, 1.0, 1.0, 1.0]).astype(np.float32)
    matrix[:3, 3] = (-0.5, -0.25, -0.3)
    add_object(s, (pos + 1.0).astype(np.float32), tris, m, matrix=matrix)
    s.commit()
    return s, m, matrix


def to_world(matrix, obj):
    return obj @ matrix[:3, :3].T + matrix[:3, 3]


def test_dense_grid_holds_the_voxels():
    rng = np.random.default_rng(2)
    v = rng.random((RES, 5, 11)).astype(np.float32)  # [z, y, x], not multiples of the brick
    g = pc.VolumeGrid.from_dense(v, np.eye(4))
    assert g.channels == 1 and tuple(g.bbox_min) == (0, 0, 0) and tuple(g.bbox_max) == (10, 4, RES - 1)
    np.testing.assert_array_equal(g.voxels((0, 0, 0), (10, 4, RES - 1)), v.transpose(2, 1, 0))
    c = rng.random((3, 4, 5, 3)).astype(np.float32)
    g3 = pc.VolumeGrid.from_dense(c, np.eye(4))
    np.testing.assert_array_equal(g3.voxels((0, 0, 0), (4, 3, 2)), c.transpose(2, 1, 0, 3))
    bad = v.copy()
    bad[1, 2, 3] = np.nan
    assert pc.VolumeGrid.from_dense(bad, np.eye(4)).nonfinite_replaced == 1
    with pytest.raises(ValueError):
        pc.VolumeGrid.from_dense(np.zeros((4, 4), np.float32), np.eye(4))
    with pytest.raises(ValueError):
        pc.VolumeGrid.from_dense(np.zeros((4, 4, 4, 2), np.float32), np.eye(4))
    with pytest.raises(RuntimeError):
        pc.VolumeGrid.from_dense(np.zeros((4, 4, 4), np.float32), np.zeros((4, 4)))  # singular


@pytest.mark.parametrize("space", ["TEXTURE", "OBJECT", "WORLD"])
def test_read_in_each_space(space):
    rng = np.random.default_rng(4)
    v = rng.random((RES, RES, RES)).astype(np.float32)
    grid, m = texture_grid(v)
    s, mat, matrix = voxel_scene(grid, space)
    obj = rng.uniform(0.02, 1.98, (400, 3)).astype(np.float32)
    world = to_world(matrix, obj)
    tex = {"TEXTURE": obj / 2.0, "OBJECT": obj, "WORLD": world}[space]  # generated: the box's [0, 1]
    inside = np.all((tex >= 0.0) & (tex <= 1.0), axis=1)
    expect = np.where(inside, grid.sample_index(tex * RES - 0.5, "linear"), 0.0)
    got = np.array([s.medium_at(0, mat, tuple(p))["sigma_s"][0] for p in world])
    assert inside.sum() >= 10
    np.testing.assert_allclose(got, expect, rtol=1e-4, atol=1e-5)


def test_outside_the_box_reads_zero_closest_reads_the_voxel():
    """All voxels 1: inside the box's outer half voxels the linear read blends with 0 beyond
    the edge (Cycles' clip reads 0 there), outside the box 0 (not the blend); Closest reads the
    voxel holding the point (floor(u RES))."""
    grid, _ = texture_grid(np.ones((RES, RES, RES), np.float32))
    s, mat, matrix = voxel_scene(grid, "OBJECT")
    for x, e in ((0.5, 1.0), (0.999, 0.508), (0.001, 0.508), (1.01, 0.0), (1.03, 0.0), (-0.01, 0.0)):
        world = to_world(matrix, np.array([[x, 0.5, 0.5]], np.float32))[0]
        assert s.medium_at(0, mat, tuple(world))["sigma_s"][0] == pytest.approx(e, abs=1e-4), x
    v = np.zeros((RES, RES, RES), np.float32)
    v[4, 4, 2] = 5.0  # voxel (x 2, y 4, z 4): u in [2 / 8, 3 / 8)
    grid, _ = texture_grid(v)
    s, mat, matrix = voxel_scene(grid, "OBJECT", "CLOSEST")
    for x, e in ((0.26, 5.0), (0.37, 5.0), (0.24, 0.0), (0.38, 0.0)):
        world = to_world(matrix, np.array([[x, 4.5 / RES, 4.5 / RES]], np.float32))[0]
        assert s.medium_at(0, mat, tuple(world))["sigma_s"][0] == pytest.approx(e), x
