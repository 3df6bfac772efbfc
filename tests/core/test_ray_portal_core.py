"""The Ray Portal closure through the module, in closed form: a grey diffuse ground of albedo
0.5 under a wide portal card, a constant white world (light-sampled by the sky samples) and a
camera between the two looking down. Shadow rays stop at the portal (Cycles' veto), and what a
BSDF ray finds past it gets the full weight (MIS skip), so the ground shows exactly
albedo x what the card passes: without the veto the sky samples would add light, without the
skip half the BSDF rays' would be lost (the power heuristic's share)."""

import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, quad, render

pc = core()
pytestmark = pytest.mark.sanitize


def ground_under(program):
    s = pc.Scene()
    add_object(s, *quad((-1000, -1000, 0), (2000, 0, 0), (0, 2000, 0)), s.add_material("ground", (0.5, 0.5, 0.5)))
    add_object(s, *quad((-1000, -1000, 1), (2000, 0, 0), (0, 2000, 0)), s.add_shader("card", program))
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0.0, 0.0, 0.5), (0.0, 0.01, 0.0), lens=50.0))
    return s


MIXED = [("const", 0, (0.5, 0.5, 0.5)), ("const", 1, (1.0, 1.0, 1.0)),
         ("closure", "ray_portal", 0, {"color": 1}), ("closure", "transparent", 0, {"color": 1})]


@pytest.mark.parametrize("program, passed", [
    (closure("ray_portal", color=(0.6, 0.6, 0.6)), 0.6),  # unlinked Position, Direction: straight on
    (closure("ray_portal", color=(1.0, 1.0, 1.0), position=(0.0, 0.0, 1.0), direction=(0.0, 0.0, 1.0)), 1.0),
    (MIXED, 1.0),  # half portal, half Transparent: shadows still stop, MIS still skipped
])
def test_ground_under_a_portal_is_albedo_times_what_it_passes(program, passed):
    film, _ = render(pc, ground_under(program), 16, 16, 16)
    # Every sample alike (cosine-sampled diffuse under a uniform sky), but for the rare one that
    # leaves past the card's edge (1e-6 of the cosine-weighted sky): per pixel within one such.
    rgb = film[..., :3]
    assert abs(rgb.mean() / (0.5 * passed) - 1.0) < 2e-3, rgb.mean()
    assert np.abs(rgb - 0.5 * passed).max() < 0.02, (rgb.min(), rgb.max())
