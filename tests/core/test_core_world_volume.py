"""The world's Volume as a program (docs/design/volumes.md "World volumes"): a heterogeneous
medium with majorants over the scene's bounds (geometry, lights, camera), empty beyond them;
its coefficients at points, a white furnace inside an emitting enclosure, absorption along a
chord against exp(-tau), the open-scene probe, and bad values."""
import math

import numpy as np
import pytest

from core_scenes import add_object, camera, core, emitting_enclosure, quad, render
from test_core_hetero_volumes import A, B, cube, linear_program, tau

pc = core()
pytestmark = pytest.mark.sanitize


def closed_box(s, material, half=1.0):
    pos, tris = cube(half)
    add_object(s, pos, tris, material)


def emitter(s, e):
    return s.add_shader("wall", [("const", 0, (e, e, e)), ("closure", "emission", None, {"color": 0})])


def test_world_program_coefficients_and_majorants():
    """A program is accepted as the world's Volume: its coefficients at points, majorants over
    the scene's bounds (which hold the camera) bounding the density, the feature, and the probe
    of a closed scene (no ray leaves it)."""
    s = pc.Scene()
    closed_box(s, emitter(s, 1.0))
    s.set_world_volume(linear_program(absorb=0.5))
    s.set_camera(camera(pc, (-0.5, 0.0, 0.0), (1.0, 0.0, 0.0)))
    s.commit()
    for x in (-0.9, 0.0, 0.7):
        d = s.medium_at(-1, 0, (x, 0.2, 0.1))
        assert d["sigma_s"] == pytest.approx((A + B * (x + 1),) * 3, rel=1e-5)
        assert d["sigma_a"] == pytest.approx((0.5 * (A + B * (x + 1)),) * 3, rel=1e-5)
    grid, lo, hi = s.medium_majorants(-1, 0)
    assert np.all(np.asarray(lo) < -1.0) and np.all(np.asarray(hi) > 1.0)  # the box, padded
    assert np.all(np.asarray(hi) - np.asarray(lo) < 2.2)
    xs = np.linspace(lo[0], hi[0], 17)[1:]
    assert np.all(grid >= 1.5 * (A + B * (xs + 1.0))[None, None, :] * (1.0 - 1e-5))
    stats = s.stats()
    assert "heterogeneous volumes" in stats["features"] and stats["world_volume_open"] == 0.0
    # A homogeneous world has no heterogeneous medium.
    s.set_world_volume({"sigma_s": (0.1, 0.1, 0.1)})
    s.commit()
    with pytest.raises(ValueError):
        s.medium_majorants(-1, 0)
    assert "world_volume_open" not in s.stats()


def test_white_furnace_of_a_world_program():
    """Inside a closed shell of emission 0.5 and albedo 0.5 the radiance is 1 everywhere; a
    purely scattering world medium whose density varies (linear in x) leaves it 1."""
    s = emitting_enclosure(pc)
    s.set_world_volume(linear_program(a=0.3, b=0.8))
    img, stats = render(pc, s, 8, 8, samples=256, max_bounces=512)
    assert "heterogeneous volumes" in stats["features"] and stats["nonfinite_samples"] == 0
    assert img[..., :3].mean() == pytest.approx(1.0, rel=0.01)
    assert np.allclose(img[..., :3].mean(axis=(0, 1)), 1.0, rtol=0.02)


def test_world_program_absorption_along_a_chord():
    """Absorbing world fog, sigma_a = A + B (x + 1), seen from x = -0.9 towards an emitting
    wall at x = 1 (inside a closed box): E exp(-tau(1.9))."""
    s = pc.Scene()
    closed_box(s, emitter(s, 2.0))
    s.set_world_volume(linear_program(albedo=0.0, absorb=1.0))
    cam = camera(pc, (-0.9, 0.0, 0.0), (1.0, 0.0, 0.0), lens=400.0)
    cam.clip_start = 1e-4
    s.set_camera(cam)
    img, stats = render(pc, s, 5, 5, samples=1024)
    want = 2.0 * math.exp(-(A * 1.9 + 0.5 * B * (1.9 ** 2 + 2 * 0.1 * 1.9)))
    # (tau from x = -0.9: the integral of A + B (x + 1) over [-0.9, 1])
    assert want == pytest.approx(2.0 * math.exp(-(tau(2.0) - tau(0.1))), rel=1e-6)
    # The image spans 2.6 degrees: every pixel's chord is within 0.1 % of the axis's; ratio
    # tracking's estimates are noisy (about 6 % per pixel at 1024 samples), their mean is not.
    assert img[..., :3].mean(axis=(0, 1)) == pytest.approx((want,) * 3, rel=0.02)


def test_world_program_is_empty_beyond_the_scene_bounds():
    """An open scene: rays that leave the scene's bounds see the background through the fog
    inside the bounds only (exp(-sigma d), d to the bounds' face), and the probe says the scene
    is open."""
    s = pc.Scene()
    wall = s.add_material("grey", (0.5, 0.5, 0.5))
    pos, tris = quad((-1.0, 2.0, -1.0), (2.0, 0.0, 0.0), (0.0, 0.0, 2.0))
    add_object(s, pos, tris, wall)
    sigma = 0.7
    s.set_world_volume([("position", 0), ("separate", 1, 0, 0), ("const", 2, (0.0,)),
                        ("math", 3, 1, 2, "MULTIPLY", False), ("const", 4, (sigma,)),
                        ("math", 5, 3, 4, "ADD", False), ("closure", "volume", None, {"sigma_a": 5})])
    s.set_world_color((1.0, 1.0, 1.0))
    cam = camera(pc, (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), lens=400.0)  # away from the wall
    cam.clip_start = 1e-4
    s.set_camera(cam)
    img, stats = render(pc, s, 5, 5, samples=64)
    assert 0.0 < s.stats()["world_volume_open"] < 1.0
    _, lo, _ = s.medium_majorants(-1, 0)
    assert lo[1] < 0.0  # the camera is inside the bounds
    want = math.exp(-sigma * (0.0 - lo[1]))
    assert img[2, 2, :3] == pytest.approx((want,) * 3, rel=0.02)


def test_bad_world_program_values_render_finite():
    """NaN, negative and infinite coefficients from a world program read 0 (no NaN pixels)."""
    s = emitting_enclosure(pc)
    nan, inf = float("nan"), float("inf")
    s.set_world_volume([("position", 0), ("separate", 1, 0, 0), ("const", 2, (nan,)),
                        ("math", 3, 1, 2, "MULTIPLY", False), ("const", 4, (-2.0, inf, nan)),
                        ("closure", "volume", None, {"sigma_s": 3, "sigma_a": 4, "emission": 4})])
    img, stats = render(pc, s, 8, 8, samples=16, max_bounces=64)
    assert stats["nonfinite_samples"] == 0 and np.all(np.isfinite(img))
    assert img[..., :3].mean() == pytest.approx(1.0, rel=0.02)  # the fog reads 0: the enclosure alone
