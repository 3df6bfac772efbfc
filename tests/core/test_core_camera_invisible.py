"""Objects camera rays pass (add_instance's camera_invisible: Blender's Indirect Only
collections, Cycles' visibility without PATH_RAY_CAMERA), through the module: the camera sees
past such a slab to the floor, which still gets the slab's shadow; a camera-invisible emitter
still lights the floor. Cycles comparisons: tests/blender/test_view_layers.py."""
import numpy as np
import pytest

from core_scenes import camera, core, quad, run_session

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif("camera_invisible" not in pc.Scene.add_instance.__doc__,
                                 reason="core without camera_invisible")]


def scene(invisible, emitter=False):
    s = pc.Scene()
    grey = s.add_material("grey", (0.5, 0.5, 0.5))
    red = s.add_material("red", (0.8, 0.1, 0.1), emission=(4.0, 0.0, 0.0) if emitter else (0.0, 0.0, 0.0))
    pos, tris = quad((-4, -4, 0), (8, 0, 0), (0, 8, 0))  # the floor z = 0
    s.add_instance(s.add_mesh(pos, tris, None, None, [grey]), np.eye(4, dtype=np.float32))
    pos, tris = quad((-1.0, -1.0, 1.0), (2, 0, 0), (0, 2, 0))  # a slab over the middle
    s.add_instance(s.add_mesh(pos, tris, None, None, [red]), np.eye(4, dtype=np.float32),
                   camera_invisible=invisible)
    s.add_sun_light((0.0, 0.0, 1.0), (3.0, 3.0, 3.0), 0.0)
    s.set_world_color((0.2, 0.2, 0.2))
    s.set_camera(camera(pc, (0.0, 0.0, 6.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
    s.commit()
    return s


def render(s):
    return run_session(pc, s, 16, 16, 16, threads=2).film()[..., :3]


def test_camera_sees_the_shadowed_floor_through_it():
    seen, passed = render(scene(False)), render(scene(True))
    # The middle: the red slab, or the floor in its shadow (grey, lit by the world alone).
    assert seen[8, 8, 0] > 2 * seen[8, 8, 1]
    # (the shadow is reddish: the slab's underside lights it back)
    assert passed[8, 8, 0] < 0.5 * seen[8, 8, 0] and passed[8, 8].mean() < 0.5 * passed[0, 0].mean()
    # The edge: the sunlit floor in both, its red bounce from the slab's underside alike.
    np.testing.assert_allclose(passed[0, 0], seen[0, 0], rtol=0.05)


def test_an_invisible_emitter_still_lights():
    lit = render(scene(True, emitter=True))
    dark = render(scene(True))
    # Its red light reaches the floor beside it; the camera never sees the 4.0 emission itself.
    assert lit[..., 0].mean() > dark[..., 0].mean() + 0.01 and lit[..., 0].max() < 4.0
