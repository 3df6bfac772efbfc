"""Light node trees as programs (core/scene/light_shader.h) through the module, against closed
forms on the plane of test_core_lights: Light Falloff by the sample's distance, a constant
program folded into the colour, a gobo by the spot's uv, and the light's power estimate."""
import numpy as np
import pytest

from core_scenes import core, render
from test_core_lights import W, check, expected, plane_scene, point_radiance

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
LIGHT = np.array([0.3, -0.2, 2.0])


def falloff_program(kind, strength=2.0, smooth=0.0):
    return [("const", 0, (strength,)), ("const", 1, (smooth,)), ("light_falloff", 2, 0, 1, kind),
            ("closure", "emission", None, {"color": 2})]  # (a value reads as grey)


@pytest.mark.parametrize("kind, power", [("QUADRATIC", 0), ("LINEAR", 1), ("CONSTANT", 2)])
def test_light_falloff_scales_by_the_sample_distance(kind, power):
    s = plane_scene()
    s.add_point_light(LIGHT, (10.0, 10.0, 10.0), shader=falloff_program(kind))
    img, stats = render(pc, s, W, W, samples=16)

    def radiance(p):
        r = np.sqrt(((LIGHT - p) ** 2).sum(-1))
        return point_radiance(p, LIGHT, 10.0) * 2.0 * r ** power
    check(img, expected(radiance), tol=0.005)
    assert stats["nonfinite_samples"] == 0


def test_smooth_falloff_and_a_constant_program():
    s = plane_scene()
    s.add_point_light(LIGHT, (10.0, 10.0, 10.0), shader=falloff_program("QUADRATIC", 1.0, 3.0))
    img, _ = render(pc, s, W, W, samples=16)

    def radiance(p):
        r2 = ((LIGHT - p) ** 2).sum(-1)
        return point_radiance(p, LIGHT, 10.0) * r2 / (3.0 + r2)
    check(img, expected(radiance), tol=0.005)
    # A program that reads nothing of the sample is folded into the colour: the plain light's image.
    s1, s2 = plane_scene(), plane_scene()
    s1.add_point_light(LIGHT, (10.0, 10.0, 10.0),
                       shader=[("const", 0, (0.5, 0.25, 2.0)), ("closure", "emission", None, {"color": 0})])
    s2.add_point_light(LIGHT, (5.0, 2.5, 20.0))
    a, _ = render(pc, s1, 8, 8, samples=4)
    b, _ = render(pc, s2, 8, 8, samples=4)
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)


def test_spot_gobo_by_parametric_coordinates():
    # A spot straight down (identity matrix: it points along -Z) of 90 degrees: Parametric's x
    # is 0.5 + x / (2 tan(45) z) on the plane, so a gobo of "x < 0.5 -> 0" darkens x < 0.
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = (0.0, 0.0, 2.0)
    prog = [("geometry", 0, "PARAMETRIC"), ("separate", 1, 0, 0), ("const", 2, (0.5,)),
            ("math", 3, 1, 2, "GREATER_THAN", False), ("closure", "emission", None, {"color": 3})]
    s = plane_scene()
    s.add_spot_light(m, (10.0, 10.0, 10.0), spot_size=np.pi / 2, spot_blend=0.0, shader=prog)
    img, _ = render(pc, s, W, W, samples=16)
    left, right = img[:, : W // 2 - 1, 0], img[:, W // 2 + 1:, 0]
    assert left.max() == 0.0 and right.min() > 0.0


def test_shader_power_steers_the_light_choice():
    # Two equal lights, one with a tree whose estimate is 4: it takes 4/5 of the samples, which
    # shows as the same mean image (unbiased) with the dim light's side noisier.
    def scene(power):
        s = plane_scene()
        for x, p in ((-1.5, power), (1.5, 1.0)):
            s.add_point_light((x, 0.0, 1.0), (5.0, 5.0, 5.0), shader=falloff_program("QUADRATIC", 1.0),
                              shader_power=p)
        return s
    a, _ = render(pc, scene(1.0), W, W, samples=64)
    b, _ = render(pc, scene(4.0), W, W, samples=64)
    assert abs(a[..., 0].mean() / b[..., 0].mean() - 1.0) < 0.02
    with pytest.raises(ValueError, match="shader op 'light_falloff'"):
        pc.Scene().add_point_light((0, 0, 1), (1, 1, 1), shader=[("light_falloff", 0, 0, 0, "CUBIC")])
