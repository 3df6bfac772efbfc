"""Voxel grids in volume programs (volume objects, issue 23; docs/design/volumes.md "Volume
objects"): the "volume_grid" op reads a scene grid at the point in the instance's object space
with voxel i's value at index i + 0.5 (Cycles' lookups), a missing grid reads 0, and the
majorant grid built from the voxel grid's own majorants bounds the extinction everywhere, also
at a single bright voxel between the lattice points that the sampled majorants would miss."""
import numpy as np
import pytest

import vdb_writer as vw
from core_scenes import add_object, camera, core, render
from test_core_hetero_volumes import cube

pc = core()
pytestmark = pytest.mark.sanitize

VOXEL = 0.125
SCALE = 3.0  # the program's density multiplier


def random_grid(seed=1, spike=True):
    """16^3 voxels (2x2x2 leaves) of values in [0, 1], one voxel 40; voxel size VOXEL."""
    rng = np.random.default_rng(seed)
    g = vw.Grid(name="density", codec="blosc", transform=("UniformScaleMap", VOXEL))
    for o in [(x, y, z) for x in (0, 8) for y in (0, 8) for z in (0, 8)]:
        vals = rng.random((8, 8, 8)).astype(np.float32)
        if spike and o == (8, 0, 8):
            vals[3, 5, 2] = 40.0
        g.leaves[o] = (vals, np.ones((8, 8, 8), bool))
    (info,) = pc.read_vdb_bytes(vw.write_vdb([g]))
    return info["grid"]


def grid_program(grid_id, scale=SCALE):
    return [("volume_grid", 0, grid_id, "FAC", "LINEAR"), ("const", 1, (scale,)),
            ("math", 2, 0, 1, "MULTIPLY", False), ("const", 3, (0.0,)),
            ("closure", "volume", None, {"sigma_s": 2, "sigma_a": 3})]


def grid_scene(grid, program_grid=0, box=1.1):
    s = pc.Scene()
    gid = s.add_volume_grid(grid)
    assert gid == 0 and s.volume_grid_count == 1
    m = s.add_shader("vol", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                     volume=grid_program(program_grid))
    pos, tris = cube(1.0)
    matrix = np.eye(4, dtype=np.float32)
    matrix[:3, 3] = (0.5, -0.25, 2.0)  # object [0, 2]^3 (the grid) from a box around it
    pos = pos * box + 1.0
    add_object(s, pos.astype(np.float32), tris, m, matrix=matrix)
    s.commit()
    return s, m, matrix


def test_grid_read_at_cycles_voxel_placement():
    grid = random_grid(spike=False)
    s, m, matrix = grid_scene(grid)
    rng = np.random.default_rng(5)
    obj = rng.uniform(0.05, 1.95, (200, 3)).astype(np.float32)
    # Cycles: voxel i's value at index i + 0.5, i.e. OpenVDB's trilinear sample half a voxel down.
    expect = grid.sample_index(obj / VOXEL - 0.5, "linear") * SCALE
    for p, e in zip(obj, expect):
        d = s.medium_at(0, m, tuple(p + matrix[:3, 3]))
        assert d["sigma_s"][0] == pytest.approx(e, rel=1e-4, abs=1e-5)
    # Outside the grid: the background (0).
    d = s.medium_at(0, m, tuple(np.array([2.15, 1.0, 1.0]) + matrix[:3, 3]))
    assert d["sigma_s"][0] == 0.0


def test_missing_grid_reads_zero():
    s, m, matrix = grid_scene(random_grid(spike=False), program_grid=7)
    d = s.medium_at(0, m, tuple(np.array([1.0, 1.0, 1.0]) + matrix[:3, 3]))
    assert d["sigma_s"] == (0.0, 0.0, 0.0)


def test_majorants_bound_the_grid_including_a_single_voxel():
    grid = random_grid()
    # A box far larger than the grid: majorant cells of 2.75 (22 voxels), lattice points 7.3
    # voxels apart, so the spike's 2-voxel footprint falls between them.
    s, m, matrix = grid_scene(grid, box=22.0)
    maj, lo, hi = s.medium_majorants(0, m)
    lo, hi = np.asarray(lo), np.asarray(hi)
    n = maj.shape[0]
    # Dense points (every 1/4 voxel) and the spike's neighbourhood: each point's extinction
    # is within its majorant cell's value.
    axis = np.arange(0.0, 2.0, VOXEL / 4) + VOXEL / 8
    obj = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    sigma = grid.sample_index(obj / VOXEL - 0.5, "linear") * SCALE
    world = obj + matrix[:3, 3]
    cell = np.clip(((world - lo) / (hi - lo) * n).astype(int), 0, n - 1)
    bound = maj[cell[:, 2], cell[:, 1], cell[:, 0]]
    assert sigma.max() > 20.0 * SCALE  # the spike is among the points
    assert np.all(sigma <= bound * (1.0 + 1e-5))
    # The lattice alone (4 points per cell and axis, 16 voxels per cell) would miss the spike:
    # its cell's bound must come from the grid's majorants, above the spike's own value.
    k = np.argmax(sigma)
    assert bound[k] >= 40.0 * SCALE * (1.0 - 1e-5)


def bspline_weights(t):
    """Uniform cubic B-spline weights of the voxels floor - 1 .. floor + 2 (columns)."""
    s = 1.0 - t
    return np.stack([s ** 3, 3 * t ** 3 - 6 * t ** 2 + 4, -3 * t ** 3 + 3 * t ** 2 + 3 * t + 1, t ** 3], -1) / 6.0


def test_cubic_read_is_the_tricubic_b_spline_and_majorants_bound_it():
    """Volume Interpolation Cubic (Cycles' tricubic B-spline at the same voxel placement): the
    op against the B-spline of the voxels computed here; it differs from the linear read; the
    majorant cells (built for the linear footprint) still bound it, the spike included."""
    grid = random_grid()
    s = pc.Scene()
    s.add_volume_grid(grid)
    prog = grid_program(0)
    prog[0] = ("volume_grid", 0, 0, "FAC", "CUBIC")
    m = s.add_shader("vol", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                     volume=prog)
    pos, tris = cube(1.0)
    add_object(s, (pos * 1.1 + 1.0).astype(np.float32), tris, m)
    s.commit()
    vox = np.pad(grid.voxels((0, 0, 0), (15, 15, 15)), 2)  # background 0 around, index + 2
    rng = np.random.default_rng(9)
    obj = rng.uniform(-0.05, 2.05, (300, 3))
    ijk = obj / VOXEL - 0.5
    base = np.floor(ijk).astype(int)
    w = [bspline_weights(ijk[:, a] - base[:, a]) for a in range(3)]
    want = np.zeros(len(obj))
    for i in range(4):
        for j in range(4):
            for k in range(4):
                v = vox[base[:, 0] + i + 1, base[:, 1] + j + 1, base[:, 2] + k + 1]
                want += w[0][:, i] * w[1][:, j] * w[2][:, k] * v
    got = np.array([s.medium_at(0, m, tuple(p))["sigma_s"][0] for p in obj])
    np.testing.assert_allclose(got, want * SCALE, rtol=1e-4, atol=1e-4)
    assert np.allclose(grid.sample_index(ijk.astype(np.float32), "cubic"), want, rtol=1e-4, atol=1e-4)
    linear = grid.sample_index(ijk.astype(np.float32), "linear")
    assert np.abs(linear - want).max() > 0.5  # the spike's neighbourhood at least
    maj, lo, hi = s.medium_majorants(0, m)
    lo, hi = np.asarray(lo), np.asarray(hi)
    axis = np.arange(-0.05, 2.05, VOXEL / 4)
    dense = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    sigma = grid.sample_index((dense / VOXEL - 0.5).astype(np.float32), "cubic") * SCALE
    cell = np.clip(((dense - lo) / (hi - lo) * maj.shape[0]).astype(int), 0, maj.shape[0] - 1)
    assert sigma.max() > 5.0 * SCALE
    assert np.all(sigma <= maj[cell[:, 2], cell[:, 1], cell[:, 0]] * (1.0 + 1e-5))


def test_majorants_are_tight_over_grid_cells():
    """A program that grows with the grid (here 3 x the density) gets, per 16^3 cell, the program
    at the largest voxel of the cell's trilinear stencils (x 1.001): no 1.5x safety factor over
    sampled values, no floor of 0.5 / cell diagonal, no bound over whole 8^3 bricks and their
    neighbours (that rule made the bench smoke's majorants 12x its mean density, 2.8x after)."""
    grid = random_grid(spike=False)
    s, m, matrix = grid_scene(grid)
    maj, lo, hi = s.medium_majorants(0, m)
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    n = maj.shape[0]
    vox = grid.voxels((-8, -8, -8), (24, 24, 24))  # (x, y, z), voxel i at index -8 + i
    size = (hi - lo) / n
    stencil = np.zeros_like(maj)
    for z in range(n):
        for y in range(n):
            for x in range(n):
                c = np.array([x, y, z])
                # The cell in index space (Cycles' placement: index = object / VOXEL - 0.5),
                # grown by 0.01 voxels for rounding; its trilinear stencils.
                a = (lo + size * c - matrix[:3, 3]) / VOXEL - 0.5 - 0.01
                b = (lo + size * (c + 1) - matrix[:3, 3]) / VOXEL - 0.5 + 0.01
                i0, i1 = np.floor(a).astype(int) + 8, np.floor(b).astype(int) + 9
                stencil[z, y, x] = vox[i0[0]:i1[0] + 1, i0[1]:i1[1] + 1, i0[2]:i1[2] + 1].max()
    floor = 0.05 / np.linalg.norm(size)
    want = np.maximum(stencil * SCALE * 1.001, floor)
    assert np.all(maj <= want * (1.0 + 1e-4))
    assert maj.sum() > 0.9 * want.sum()  # (the stencils grown by rounding only add a little)
    # ... and they still bound a dense sampling of the program.
    axis = np.arange(0.0, 2.0, VOXEL / 4) + VOXEL / 8
    obj = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    sigma = grid.sample_index(obj / VOXEL - 0.5, "linear") * SCALE
    cell = np.clip(((obj + matrix[:3, 3] - lo) / (hi - lo) * n).astype(int), 0, n - 1)
    assert np.all(sigma <= maj[cell[:, 2], cell[:, 1], cell[:, 0]] * (1.0 + 1e-5))


def lit_grid_scene(scale):
    """The random grid (density scale x [0, 1], albedo 1) in its box under a point light, seen by
    a camera from -y."""
    s = pc.Scene()
    s.add_volume_grid(random_grid(spike=False))
    m = s.add_shader("vol", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                     volume=grid_program(0, scale))
    pos, tris = cube(1.0)
    matrix = np.eye(4, dtype=np.float32)
    matrix[:3, 3] = (0.5, -0.25, 2.0)
    add_object(s, (pos * 1.1 + 1.0).astype(np.float32), tris, m, matrix=matrix)
    centre = np.array([1.5, 0.75, 3.0])
    s.add_point_light(tuple(centre + (2.0, -1.5, 2.5)), (60.0, 60.0, 60.0), 0.1)
    s.set_camera(camera(pc, tuple(centre + (0.0, -4.5, 0.0)), tuple(centre), lens=50.0))
    s.commit()
    return s


@pytest.mark.parametrize("scale", [0.5, 3.0])
def test_light_sample_per_segment_agrees_and_lowers_variance(scale):
    """The light sample in every segment crossed (RenderSettings.volume_segment_nee) against the
    one at delta tracking's scattering only: the same image (both unbiased) and, in a thin medium
    (optical depth about 0.5 across, most camera rays pass without scattering), far less noise."""
    s = lit_grid_scene(scale)
    imgs = {}
    for on in (True, False):
        imgs[on] = np.stack([render(pc, s, 16, 16, samples=64, seed=11 + k, max_bounces=4,
                                    volume_segment_nee=on)[0][..., :3] for k in range(4)])
    mean_on, mean_off = imgs[True].mean(), imgs[False].mean()
    assert mean_on > 0.01
    assert mean_on == pytest.approx(mean_off, rel=0.02)
    var_on, var_off = (float(imgs[k].var(axis=0, ddof=1).mean()) for k in (True, False))
    if scale < 1.0:
        assert var_on < 0.5 * var_off, (var_on, var_off)
    else:
        assert var_on < 1.1 * var_off, (var_on, var_off)  # (dense: most paths scatter anyway)
