"""Program worlds (Environment's program kind, core/scene/environment.cpp): the world's node tree
as a shader program evaluated per escaped ray with its Light Path state, and the map baked from
it that steers the light samples. Through the module, against closed forms."""
import numpy as np
import pytest

from core_scenes import core, furnace_scene, render

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def const_program(rgb):
    return [("const", 0, tuple(rgb)), ("closure", "emission", None, {"color": 0})]


def z_program(a=1.0, b=0.5):
    """L(dir) = a + b * dir.z, grey: the world's P is the direction."""
    return [("position", 0), ("separate", 1, 0, 2), ("const", 2, (b,)), ("math", 3, 1, 2, "MULTIPLY", False),
            ("const", 4, (a,)), ("math", 5, 3, 4, "ADD", False), ("closure", "emission", None, {"color": 5})]


def camera_ray_program(camera_rgb, other_rgb):
    """Light Path's Is Camera Ray as a Mix's factor: camera_rgb to the camera, other_rgb to
    every other ray and to the light samples."""
    return [("const", 0, tuple(other_rgb)), ("const", 1, tuple(camera_rgb)), ("light_path", 2, "IS_CAMERA_RAY"),
            ("mix", 3, 2, 0, 1, "MIX", False), ("closure", "emission", None, {"color": 3})]


def test_a_constant_program_is_the_constant_world():
    a, b = furnace_scene(pc, 0.8), furnace_scene(pc, 0.8)
    assert a.set_world_program(const_program((0.3, 0.5, 0.7))) is False
    b.set_world_color((0.3, 0.5, 0.7))
    ia, _ = render(pc, a, 24, 24, samples=8)
    ib, _ = render(pc, b, 24, 24, samples=8)
    assert np.array_equal(ia, ib)


def test_furnace_under_a_varying_program_world():
    # |P| = 1 in every direction: a varying program worth 1, so the white furnace holds.
    s = furnace_scene(pc, 0.8)
    prog = [("position", 0), ("vector_math", 1, 0, 0, 0, 0, "LENGTH"), ("closure", "emission", None, {"color": 1})]
    assert s.set_world_program(prog, 64) is True
    img, stats = render(pc, s, 64, 64, samples=32)
    assert abs(img[24:40, 24:40, :3].mean() - 0.8) < 0.008
    assert np.abs(img[:4, :4, :3] - 1.0).max() < 1e-5  # the world seen directly
    assert stats["nonfinite_samples"] == 0


def test_program_world_matches_the_same_world_as_an_image():
    # L = 1 + 0.5 z as a program and as an equirectangular image: the same sphere (light samples
    # by the baked map, MIS with BSDF rays that evaluate the program).
    h, w = 256, 512
    elevation = np.pi * ((np.arange(h) + 0.5) / h - 0.5)
    px = np.repeat((1.0 + 0.5 * np.sin(elevation))[:, None], w, 1)
    px = np.repeat(px[..., None], 3, 2).astype(np.float32)
    a, b = furnace_scene(pc, 0.8), furnace_scene(pc, 0.8)
    assert a.set_world_program(z_program(), 256) is True
    b.set_world_texture(px, 1.0)
    ia, sa = render(pc, a, 48, 48, samples=128)
    ib, _ = render(pc, b, 48, 48, samples=128)
    sphere = np.s_[14:34, 14:34, :3]
    assert abs(ia[sphere].mean() / ib[sphere].mean() - 1.0) < 0.01
    top, bottom = ia[14:24, 14:34, :3].mean(), ia[24:34, 14:34, :3].mean()  # (row 0: bottom)
    assert bottom > top * 1.1 or top > bottom * 1.1  # the light is not uniform: z shows
    assert sa["nonfinite_samples"] == 0


def test_camera_ray_program_shows_one_colour_and_lights_with_the_other():
    s = furnace_scene(pc, 0.8)
    assert s.set_world_program(camera_ray_program((0.0, 0.0, 1.0), (1.0, 1.0, 1.0)), 32) is True
    img, _ = render(pc, s, 48, 48, samples=32)
    np.testing.assert_allclose(img[:3, :3, :3], np.broadcast_to((0.0, 0.0, 1.0), (3, 3, 3)), atol=1e-6)
    center = img[18:30, 18:30, :3].mean(axis=(0, 1))
    np.testing.assert_allclose(center, 0.8, atol=0.01)  # lit white, not blue
    s.commit()
    dirs = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], np.float32)
    np.testing.assert_allclose(s.world_radiance(dirs, camera_ray=True), [[0, 0, 1]] * 2)
    np.testing.assert_allclose(s.world_radiance(dirs, camera_ray=False), [[1, 1, 1]] * 2)


def test_world_samples_pdf_is_consistent():
    # A bright lobe about +z over a dim floor: sample() gives pdf(dir), the pdf integrates to 1
    # over the sphere, and radiance / pdf estimates the world's power.
    prog = [("position", 0), ("separate", 1, 0, 2), ("const", 2, (0.0,)), ("math", 3, 1, 2, "MAXIMUM", False),
            ("const", 4, (16.0,)), ("math", 5, 3, 4, "POWER", False), ("const", 6, (0.05,)),
            ("math", 7, 5, 6, "ADD", False), ("closure", "emission", None, {"color": 7})]
    s = pc.Scene()
    assert s.set_world_program(prog, 128) is True
    s.commit()
    rng = np.random.default_rng(1)
    u = rng.random((20000, 2)).astype(np.float32)
    dirs, rad, pdf, pdf_of = s.world_sample(u)
    ok = pdf > 0
    assert ok.mean() > 0.999
    # (the density's cos(elevation) factor is per cell row: a direction on a row's edge may round
    # into the next row, a step of ~1 %, as for image worlds)
    rel = np.abs(pdf_of[ok] / pdf[ok] - 1.0)
    assert (rel < 2e-3).mean() > 0.999 and rel.max() < 0.05
    # Uniform directions: E[pdf] * 4 pi = 1, E[L] * 4 pi = the power.
    v = rng.normal(size=(200000, 3)).astype(np.float32)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    assert abs(s.world_pdf(v).mean() * 4 * np.pi - 1.0) < 0.02
    z = np.maximum(v[:, 2], 0.0)
    power = (z ** 16 + 0.05).mean() * 4 * np.pi  # = 2 pi / 17 + 0.2 pi
    est = (rad[ok, 0] / pdf[ok]).sum() / len(pdf)
    assert abs(est / power - 1.0) < 0.02
    np.testing.assert_allclose(s.world_radiance(dirs[:8])[:, 0], rad[:8, 0], rtol=1e-5)


def test_program_errors_are_python_exceptions():
    s = pc.Scene()
    with pytest.raises(ValueError):
        s.set_world_program([("light_path", 0, "NOT_A_RAY")])
    with pytest.raises(ValueError):
        s.set_world_program(const_program((1, 1, 1)), 7)
    with pytest.raises(ValueError):
        s.world_radiance(np.zeros((1, 3), np.float32))  # not committed


def test_light_the_map_does_not_see_is_found_by_rays():
    # Dark with no ray kind (the map, light samples) but white to diffuse rays: the environment
    # is no light to sample, BSDF rays find it with weight 1, and the furnace sphere shows 0.8.
    s = furnace_scene(pc, 0.8)
    prog = [("light_path", 0, "IS_DIFFUSE_RAY"), ("closure", "emission", None, {"color": 0})]
    assert s.set_world_program(prog, 32) is True
    img, stats = render(pc, s, 48, 48, samples=64)
    assert img[:3, :3, :3].max() == 0.0  # the camera sees the dark world
    assert abs(img[18:30, 18:30, :3].mean() - 0.8) < 0.01
    s.commit()
    _, _, pdf, _ = s.world_sample(np.full((4, 2), 0.5, np.float32))
    assert not pdf.any()
    assert stats["nonfinite_samples"] == 0


def test_caustic_light_paths_stay_off_for_a_program_world():
    s = furnace_scene(pc, 0.8)
    assert s.set_world_program(z_program(), 32) is True
    _, stats = render(pc, s, 16, 16, samples=4, caustic_light_paths=1.0)
    assert stats["caustics"].startswith("off") and "program" in stats["caustics"], stats["caustics"]


@pytest.mark.parametrize("kind", ["image", "program"])
def test_world_not_sampled_is_found_by_rays_alone(kind):
    # World ▸ Settings ▸ Sampling Method None (Scene.world_sampled False): no light sample picks
    # the world, and rays that escape find it with weight 1, so the furnace under a varying
    # world (L = 1 + 0.5 z) still gives the image world's mean.
    h, w = 128, 256
    elevation = np.pi * ((np.arange(h) + 0.5) / h - 0.5)
    px = np.repeat((1.0 + 0.5 * np.sin(elevation))[:, None], w, 1)
    px = np.repeat(px[..., None], 3, 2).astype(np.float32)

    def scene(sampled):
        s = furnace_scene(pc, 0.8)
        if kind == "image":
            s.set_world_texture(px, 1.0)
        else:
            assert s.set_world_program(z_program(), 256) is True
        assert s.world_sampled is True  # the default
        s.world_sampled = sampled
        return s

    off, on = scene(False), scene(True)
    for s in (off, on):
        s.commit()
    pts = np.tile(np.array([[0.0, 0.0, 1.01]], np.float32), (64, 1))
    u = np.random.default_rng(1).random((64, 3), dtype=np.float32)
    assert not off.light_samples(pts, u)[0].any()  # no light to sample
    assert on.light_samples(pts, u)[0].all()
    ioff, soff = render(pc, off, 48, 48, samples=128)
    ion, _ = render(pc, on, 48, 48, samples=128)
    a, b = ioff[16:32, 16:32, :3].mean(), ion[16:32, 16:32, :3].mean()
    assert abs(a / b - 1.0) < 0.01, (a, b)
    assert soff["nonfinite_samples"] == 0


def depth_program(output):
    """L = Light Path `output` (a count) + 0.25, grey: what the world reads."""
    return [("light_path", 0, output), ("const", 1, (0.25,)), ("math", 2, 0, 1, "ADD", False),
            ("closure", "emission", None, {"color": 2})]


def test_world_reads_ray_depth_one_further_as_cycles():
    # Cycles evaluates a background with PATH_RAY_EMISSION: Ray Depth reads one more than the
    # ray's bounces (a camera ray 1, a diffuse bounce's 2), the other counts as they are.
    s = pc.Scene()
    s.add_material("m", (0.5, 0.5, 0.5))
    assert s.set_world_program(depth_program("RAY_DEPTH"), 64) is True
    s.commit()
    up = np.array([[0.0, 0.0, 1.0]], np.float32)
    assert s.world_radiance(up, camera_ray=True)[0, 0] == pytest.approx(1.25)
    assert s.world_radiance(up, camera_ray=False)[0, 0] == pytest.approx(2.25)
    dirs, rad, pdf, _ = s.world_sample(np.array([[0.3, 0.6]], np.float32))
    assert rad[0, 0] == pytest.approx(1.25)  # no path: no counts, Ray Depth 1 (Cycles' map)
    t = pc.Scene()
    t.add_material("m", (0.5, 0.5, 0.5))
    assert t.set_world_program(depth_program("DIFFUSE_DEPTH"), 64) is True
    t.commit()
    assert t.world_radiance(up, camera_ray=False)[0, 0] == pytest.approx(0.25)  # its 0, no +1
