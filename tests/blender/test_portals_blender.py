"""Light portals (an area light with Cycles' Portal on) against Cycles 4.5: a small room lit
through a window by an HDR sky with a soft sun, the portal in the window. Export (a portal is no
emitter; the core gets it), the image against Cycles' with the same portal (mean within 1 %, 8x8
regions within Cycles' own seed-to-seed noise), and the portal's point: lower per-sample variance than without it."""
import math

import bpy
import numpy as np
import pytest

from blender_util import core_has, load_addon, render_to_array
from light_scenes import add_light, camera, diffuse_material, empty_scene, load_image, plane, synthetic_hdr, world_image
from material_scenes import assert_agree, render_pair

load_addon()
from addon.export.light import collect_lights  # noqa: E402

needs_portals = pytest.mark.skipif(not core_has("Scene", "add_portal_light"), reason="the core has no portals")


# The window: x in [-W, W], z in [Z0, Z1] of the wall y = 2.
W, Z0, Z1 = 0.9, 0.7, 1.8


def window_room(portal=True, size=48):
    """A closed 4 x 4 x 2.5 m room (diffuse walls) with a window in its +y wall, an HDR sky whose
    soft sun shines in through it onto the floor; the camera inside."""
    scene = empty_scene(size)
    white, floor = diffuse_material("White", 0.7), diffuse_material("FloorMat", (0.6, 0.5, 0.4))
    up = (math.pi / 2, 0.0, 0.0)  # a plane's local y along z
    plane("Floor", 1.0, floor, scale=(4, 4, 1))
    plane("Ceiling", 1.0, white, location=(0, 0, 2.5), scale=(4, 4, 1))
    plane("WallS", 1.0, white, location=(0, -2, 1.25), rotation_euler=up, scale=(4, 2.5, 1))
    for name, x in (("WallW", -2), ("WallE", 2)):
        plane(name, 1.0, white, location=(x, 0, 1.25), rotation_euler=(math.pi / 2, 0, math.pi / 2), scale=(4, 2.5, 1))
    side = (2 - W) / 2
    for name, loc, sc in [("WinL", (-2 + side, 2, 1.25), (2 - W, 2.5)), ("WinR", (2 - side, 2, 1.25), (2 - W, 2.5)),
                          ("WinB", (0, 2, Z0 / 2), (2 * W, Z0)), ("WinT", (0, 2, (Z1 + 2.5) / 2), (2 * W, 2.5 - Z1))]:
        plane(name, 1.0, white, location=loc, rotation_euler=up, scale=(*sc, 1))
    world_image(load_image(synthetic_hdr(64, 32, sun_sigma=0.2, sun_peak=10.0)))
    if portal:
        # local -Z (where a portal lets the world in) along -y, into the room; local y along z
        add_light('AREA', name="Portal", location=(0, 2, (Z0 + Z1) / 2), rotation=(-math.pi / 2, 0, 0),
                  shape='RECTANGLE', size=2 * W, size_y=Z1 - Z0).data.cycles.is_portal = True
    camera((0.3, -1.7, 1.2), look_at=(0.0, 2.0, 0.7), lens=20.0)
    return scene


def test_portal_is_exported_as_a_portal():
    window_room()
    warnings = []
    lights = collect_lights(bpy.context.evaluated_depsgraph_get(), warnings.append, lambda i: True)
    assert warnings == [] and [light.kind for light in lights] == ["portal"]
    args = lights[0].args
    assert (args["size_x"], args["size_y"], args["ellipse"]) == (pytest.approx(2 * W), pytest.approx(Z1 - Z0), False)
    z = args["matrix"][:3, 2]  # local +Z: -Z, where the world comes in, points into the room (-y)
    assert z @ (0, 1, 0) == pytest.approx(1.0, abs=1e-6)


def test_non_area_portals_warn():
    empty_scene(8)
    add_light('POINT', name="Odd", energy=5.0).data.cycles.is_portal = True
    warnings = []
    assert collect_lights(bpy.context.evaluated_depsgraph_get(), warnings.append, lambda i: True) == []
    assert len(warnings) == 1 and "'Odd'" in warnings[0]


@needs_portals
@pytest.mark.converged
def test_window_room_with_a_portal_agrees_with_cycles():
    """512 spp (CI time): Cycles against itself with another seed differs by 4.9 % in the worst
    8x8 region here, so the regions' bar is 4.5 %. At 1024 spp: ours within 1.8 % (Cycles seed to
    seed 2.6 %), docs/design/lights.md."""
    ours, ref = render_pair(window_room, 512, bounces=3)
    assert_agree(ours, ref, "window room with a portal", region=0.045)


@needs_portals
def test_portal_lowers_the_variance_in_the_room():
    """Per-sample variance (pixels over seeds, relative to the image's mean square), 8 seeds x
    4 spp, with and without the portal."""
    def variance(portal):
        window_room(portal, size=32)
        imgs = np.stack([render_to_array(samples=4, seed=s, max_bounces=3)[..., :3] for s in range(8)])
        return float(imgs.var(axis=0, ddof=1).mean() * 4 / (imgs.mean() ** 2))
    without, with_portal = variance(False), variance(True)
    print(f"\nper-sample variance: without the portal {without:.4f}, with it {with_portal:.4f}")
    assert with_portal < 0.5 * without, (without, with_portal)
