"""Motion blur of heterogeneous media (docs/design/motion-blur.md "Volumes"): a medium whose
density follows its object is looked up through the instance's transform at the ray's time, so
the transmittance through a slab that moves (or turns) across a ray averages over the shutter;
a volume with a velocity grid advects its lookups (Cycles' semi-Lagrangian step); the majorants
bound the medium over the whole motion (delta tracking's weights stay exactly 1)."""
import math

import numpy as np
import pytest

import vdb_writer as vw
from core_scenes import core
from test_core_hetero_volumes import cube

pc = core()
pytestmark = pytest.mark.sanitize

D = 1.0  # the slab's density
N = 20000


def slab_program(d=D, half=0.5, absorb=False):
    """sigma_s = d where |x_object| < half, else 0 (albedo 1; absorb: sigma_a instead)."""
    return [("object", 0), ("separate", 1, 0, 0), ("math", 2, 1, 1, "ABSOLUTE", False),
            ("const", 3, (half,)), ("math", 4, 2, 3, "LESS_THAN", False), ("const", 5, (d,)),
            ("math", 6, 4, 5, "MULTIPLY", False), ("const", 7, (0.0,)),
            ("closure", "volume", None, {"sigma_s": 7, "sigma_a": 6} if absorb else {"sigma_s": 6, "sigma_a": 7})]


def translate(x):
    m = np.eye(4, dtype=np.float32)
    m[0, 3] = x
    return m


def rotate_z(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    m = np.eye(4, dtype=np.float32)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def moving_scene(steps):
    s = pc.Scene()
    m = s.add_shader("vol", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                     volume=slab_program())
    pos, tris = cube()
    mesh = s.add_mesh(pos, tris, None, None, [m])
    s.add_instance(mesh, steps[len(steps) // 2], motion=np.array(steps, np.float32))
    s.commit()
    return s, m


# (steps over the shutter, the ray's (x, y), the object-space x at shutter time t)
CASES = {
    "translation": ([translate(-1.0), translate(0.0), translate(1.0)], (0.2, 0.1),
                    lambda x, y, t: x - (-1.0 + 2.0 * t)),
    "rotation": ([rotate_z(-45.0), rotate_z(0.0), rotate_z(45.0)], (0.55, 0.3),
                 lambda x, y, t: math.cos(math.radians(-45 + 90 * t)) * x
                 + math.sin(math.radians(-45 + 90 * t)) * y),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_moving_slab_averages_its_transmittance_over_the_shutter(case):
    steps, (x, y), obj_x = CASES[case]
    s, m = moving_scene(steps)
    # Along z through the cube: the slab covers the ray (optical depth 2 D) while |x_obj| < 0.5.
    ts = (np.arange(200000) + 0.5) / 200000
    inside = np.abs([obj_x(x, y, t) for t in ts[::100]]) < 0.5
    expect = float(np.mean(np.where(inside, math.exp(-2.0 * D), 1.0)))
    _, w = s.medium_track(0, m, (x, y, -1.0), (0.0, 0.0, 1.0), 2.0, N, "ratio", 3, None)
    est = w[:, 0]
    se = est.std() / math.sqrt(N)
    assert abs(est.mean() - expect) < 4.0 * se + 2e-3, (est.mean(), expect)
    # The frame alone (time 0.5) is another value: the lookup follows the motion.
    frame = math.exp(-2.0 * D) if abs(obj_x(x, y, 0.5)) < 0.5 else 1.0
    assert abs(frame - expect) > 0.2
    _, wf = s.medium_track(0, m, (x, y, -1.0), (0.0, 0.0, 1.0), 2.0, 2000, "ratio", 4, 0.5)
    assert wf[:, 0].mean() == pytest.approx(frame, abs=0.03)
    # Majorants over the swept space bound the density at every time: delta tracking's weights
    # (albedo 1, grey) stay exactly 1, and its escapes are the transmittance.
    dist, wd = s.medium_track(0, m, (x, y, -1.0), (0.0, 0.0, 1.0), 2.0, N, "delta", 5, None)
    assert np.allclose(wd, 1.0, atol=1e-5)
    passed = np.isinf(dist).mean()
    assert abs(passed - expect) < 4.0 * math.sqrt(expect * (1 - expect) / N) + 2e-3


def test_swept_majorants_cover_the_motion_and_stay_tight():
    s, m = moving_scene(CASES["translation"][0])
    grid, lo, hi = s.medium_majorants(0, m)
    assert lo[0] < -1.99 and hi[0] > 1.99  # the cube's sweep from x -2 to 2
    # Every cell whose x range the slab (object |x| < 0.5, moved by -1..1) reaches bounds D.
    xs = np.linspace(lo[0], hi[0], 17)
    reach = (xs[1:] > -1.5) & (xs[:-1] < 1.5)
    assert np.all(grid[:, :, reach] >= D * (1 - 1e-5))
    # Outside the sweep of the cube the majorants are 0 (no collisions where nothing is).
    assert grid.min() >= 0.0


VOXEL = 0.125
SCALE = 3.0


def velocity_grids(vx=2.0):
    """A slab of density 1 (voxels x 6..9 of 16^3) and a constant velocity (vx, 0, 0)."""
    dens = vw.Grid(name="density", codec="blosc", transform=("UniformScaleMap", VOXEL))
    vel = vw.Grid(name="velocity", value_type="vec3s", background=(vx, 0.0, 0.0), codec="blosc",
                  transform=("UniformScaleMap", VOXEL))
    for o in [(x, y, z) for x in (0, 8) for y in (0, 8) for z in (0, 8)]:
        v = np.zeros((8, 8, 8), np.float32)
        for i in range(8):
            if 6 <= o[0] + i <= 9:
                v[i] = 1.0
        dens.leaves[o] = (v, np.ones((8, 8, 8), bool))
        vel.leaves[o] = (np.tile(np.float32([vx, 0.0, 0.0]), (8, 8, 8, 1)), np.ones((8, 8, 8), bool))
    infos = {i["name"]: i["grid"] for i in pc.read_vdb_bytes(vw.write_vdb([dens, vel]))}
    return infos["density"], infos["velocity"]


def velocity_scene(scale, offset=-0.5, velocity_id=1, vx=2.0):
    dens, vel = velocity_grids(vx)
    s = pc.Scene()
    assert s.add_volume_grid(dens) == 0 and s.add_volume_grid(vel) == 1
    prog = [("volume_grid", 0, 0, "FAC", "LINEAR"), ("const", 1, (SCALE,)),
            ("math", 2, 0, 1, "MULTIPLY", False), ("const", 3, (0.0,)),
            ("closure", "volume", None, {"sigma_s": 2, "sigma_a": 3})]
    m = s.add_shader("vol", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                     volume=prog)
    pos, tris = cube(1.0)
    pos = pos * 1.1 + 1.0  # object [-0.1, 2.1]^3 around the grid's [0, 2]^3
    mesh = s.add_mesh(pos.astype(np.float32), tris, None, None, [m])
    s.set_mesh_velocity(mesh, velocity_id, scale, offset)
    s.add_instance(mesh, np.eye(4, dtype=np.float32))
    s.commit()
    return s, m, dens


def optical_depth(dens, x, shift):
    """The slab's optical depth along z at object x - shift (the grid read as the core does)."""
    z = (np.arange(4000) + 0.5) / 4000 * 2.0
    pts = np.stack([np.full_like(z, x - shift), np.full_like(z, 1.0), z], axis=1).astype(np.float32)
    return SCALE * float(dens.sample_index(pts / VOXEL - 0.5, "linear").mean()) * 2.0


def test_velocity_grid_advects_the_lookup_over_the_shutter():
    k = 0.5  # scale: a displacement of velocity x 0.5 x (t - 0.5), 2 x 0.5 = 1 object unit over the shutter
    s, m, dens = velocity_scene(k)
    x = 1.0  # the slab's centre (voxels 6..9 at index + 0.5: x in [0.8125, 1.3125])
    ts = (np.arange(400) + 0.5) / 400
    expect = float(np.mean([math.exp(-optical_depth(dens, x, 2.0 * k * (t - 0.5))) for t in ts]))
    _, w = s.medium_track(0, m, (x, 1.0, -0.05), (0.0, 0.0, 1.0), 2.1, N, "ratio", 7, None)
    est = w[:, 0]
    se = est.std() / math.sqrt(N)
    assert abs(est.mean() - expect) < 4.0 * se + 2e-3, (est.mean(), expect)
    still = math.exp(-optical_depth(dens, x, 0.0))
    assert abs(still - expect) > 0.2
    # At one time: the slab moved by velocity x scale x (t - 0.5), looked up exactly there.
    for t in (0.0, 0.3, 1.0):
        shift = 2.0 * k * (t - 0.5)
        for px in (0.7, 1.1, 1.6):
            want = SCALE * float(dens.sample_index(np.float32([[px - shift, 1.0, 1.0]]) / VOXEL - 0.5)[0])
            got = s.medium_at(0, m, (px, 1.0, 1.0), time=t)["sigma_s"][0]
            assert got == pytest.approx(want, rel=1e-4, abs=1e-5)
    # The majorants cover the displaced slab: delta tracking's weights stay 1.
    _, wd = s.medium_track(0, m, (x + 0.4, 1.0, -0.05), (0.0, 0.0, 1.0), 2.1, 5000, "delta", 8, None)
    assert np.allclose(wd, 1.0, atol=1e-5)


def test_shutter_start_offsets_the_time():
    s, m, dens = velocity_scene(0.5, offset=0.0)
    shift = 2.0 * 0.5 * 0.25  # at time 0.25 with the shutter starting at the frame
    want = SCALE * float(dens.sample_index(np.float32([[1.2 - shift, 1.0, 1.0]]) / VOXEL - 0.5)[0])
    assert s.medium_at(0, m, (1.2, 1.0, 1.0), time=0.25)["sigma_s"][0] == pytest.approx(want, rel=1e-4, abs=1e-5)


def test_velocity_bad_input():
    s, m, dens = velocity_scene(0.5, velocity_id=9)  # no such grid: no velocity blur
    a = s.medium_at(0, m, (1.0, 1.0, 1.0), time=0.0)["sigma_s"][0]
    b = s.medium_at(0, m, (1.0, 1.0, 1.0), time=0.5)["sigma_s"][0]
    assert a == b
    with pytest.raises(ValueError):
        s2 = pc.Scene()
        mesh = s2.add_mesh(*[np.asarray(v) for v in cube()], None, None, [])
        s2.set_mesh_velocity(mesh, 0, float("nan"), -0.5)
    with pytest.raises(ValueError):
        pc.Scene().set_mesh_velocity(0, 0, 1.0, -0.5)  # unknown mesh


def test_three_float_velocity_grids_act_as_one_vector_grid():
    dens, vel = velocity_grids()
    comps = []
    for name, value in (("vx", 2.0), ("vy", 0.0), ("vz", 0.0)):
        g = vw.Grid(name=name, background=value, codec="blosc", transform=("UniformScaleMap", VOXEL))
        g.leaves[(0, 0, 0)] = (np.full((8, 8, 8), value, np.float32), np.ones((8, 8, 8), bool))
        comps.append(pc.read_vdb_bytes(vw.write_vdb([g]))[0]["grid"])
    s = pc.Scene()
    for g in [dens, vel] + comps:
        s.add_volume_grid(g)
    prog = [("volume_grid", 0, 0, "FAC", "LINEAR"), ("const", 1, (0.0,)),
            ("closure", "volume", None, {"sigma_s": 0, "sigma_a": 1})]
    m = s.add_shader("vol", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                     volume=prog)
    pos, tris = cube(1.0)
    mesh = s.add_mesh((pos * 1.1 + 1.0).astype(np.float32), tris, None, None, [m])
    s.set_mesh_velocity(mesh, 2, 0.5, -0.5, grid_y=3, grid_z=4)
    s.add_instance(mesh, np.eye(4, dtype=np.float32))
    s.commit()
    # At time 1: moved back by (2, 0, 0) x 0.5 x (1 - 0.5), from the slab's edge to its centre.
    want = float(dens.sample_index(np.float32([[1.5 - 0.5, 1.0, 1.0]]) / VOXEL - 0.5)[0])
    assert want > 0.9
    assert s.medium_at(0, m, (1.5, 1.0, 1.0), time=1.0)["sigma_s"][0] == pytest.approx(want, rel=1e-4)
    assert s.medium_at(0, m, (1.5, 1.0, 1.0), time=0.5)["sigma_s"][0] < 0.5


@pytest.mark.parametrize("kind", ["homogeneous", "slab program"])
def test_rendered_moving_medium_averages_over_the_shutter(kind):
    """Through the integrator: a camera ray at x = 0.2 through a cube translating from x -1 to 1
    over the shutter (white world behind). A homogeneous absorbing medium blurs by its moving
    boundaries (covered 90 % of the time: 0.9 exp(-2) + 0.1); the slab program (|x_object| <
    0.5, density 1) by its lookups at the ray's time (covered half the time: 0.5 exp(-2) + 0.5)."""
    from core_scenes import camera, render
    s = pc.Scene()
    transparent = [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})]
    volume = {"sigma_a": (1.0, 1.0, 1.0)} if kind == "homogeneous" else slab_program(absorb=True)
    m = s.add_shader("vol", transparent, volume=volume)
    pos, tris = cube()
    steps = [translate(-1.0), translate(0.0), translate(1.0)]
    s.add_instance(s.add_mesh(pos, tris, None, None, [m]), steps[1], motion=np.array(steps, np.float32))
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0.2, -20.0, 0.1), (0.2, 0.0, 0.1), lens=3000.0))
    img, _ = render(pc, s, 8, 8, samples=512)
    f = 0.9 if kind == "homogeneous" else 0.5
    expect = f * math.exp(-2.0) + (1.0 - f)
    assert img[..., :3].mean() == pytest.approx(expect, rel=0.02)
