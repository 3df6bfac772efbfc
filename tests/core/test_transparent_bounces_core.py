"""RenderSettings.transparent_bounces (Blender's Transparent Max Bounces) through the module, in
closed form, with stacks of white Transparent cards. Cycles' kernel limit is the setting + 1. A
camera ray: the crossing past the setting lets the ray find one more surface for its emission
only (Cycles' terminate on next surface), so a white world behind n cards shows iff
n <= setting + 1. A shadow ray from a vertex whose path crossed k cards passes at most
setting - k of them (Cycles' integrate_shadow_max_transparent_hits); one more blocks."""

import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, quad, render

pc = core()
pytestmark = pytest.mark.sanitize
WHITE_CARD = closure("transparent", color=(1.0, 1.0, 1.0))


def cards(s, n, z0):
    shader = s.add_shader("card", WHITE_CARD)
    for i in range(n):
        add_object(s, *quad((-1000, -1000, z0 + i), (2000, 0, 0), (0, 2000, 0)), shader)


@pytest.mark.parametrize("n, limit", [(3, 2), (4, 2), (1, 0), (2, 0), (9, 8), (10, 8)])
def test_the_world_behind_n_cards_shows_up_to_the_limit(n, limit):
    s = pc.Scene()
    cards(s, n, 1.0)
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0.0, 0.0, 0.0), (0.0, 0.01, 1.0), lens=50.0))
    film, _ = render(pc, s, 8, 8, 2, transparent_bounces=limit)
    expected = 1.0 if n <= limit + 1 else 0.0
    assert np.allclose(film[..., :3], expected, atol=1e-5), (film[..., :3].min(), film[..., :3].max())


@pytest.mark.parametrize("n, limit, lit", [(0, 8, True), (8, 8, True), (9, 8, False), (2, 2, True), (3, 2, False),
                                            (1, 0, False), (0, 0, True)])
def test_a_shadow_ray_passes_the_limit_in_cards(n, limit, lit):
    s = pc.Scene()
    add_object(s, *quad((-1000, -1000, 0), (2000, 0, 0), (0, 2000, 0)), s.add_material("ground", (0.5, 0.5, 0.5)))
    cards(s, n, 1.0)
    s.add_sun_light((0.0, 0.0, 1.0), (3.0, 3.0, 3.0))
    s.set_camera(camera(pc, (0.0, 0.0, 0.5), (0.0, 0.01, 0.0), lens=50.0))
    film, _ = render(pc, s, 8, 8, 2, transparent_bounces=limit, max_bounces=1)
    expected = 0.5 * 3.0 / np.pi if lit else 0.0  # albedo x irradiance / pi, the sun overhead
    assert np.allclose(film[..., :3], expected, rtol=1e-3, atol=1e-6), (film[..., :3].min(), film[..., :3].max())

