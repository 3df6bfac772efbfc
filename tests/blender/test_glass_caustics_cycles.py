"""Caustic light paths through smooth glass against Cycles (issue 25): a smooth glass sphere
(Glass BSDF, roughness 0, IOR 1.45) on a grey floor under a low sun lamp of 10 degrees beside it, the
camera on the floor's caustic beside the ball. Cycles' image comes from tests/cycles_refs/ (docs/building.md)."""
import math

import bpy
import pytest
from mathutils import Vector

from blender_util import BOX_FILTER, core_available, load_addon, render_to_array
from light_scenes import add_light
from material_scenes import add_camera, add_plane, add_sphere, assert_agree, bsdf_material, diffuse, set_world

load_addon()

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
LIGHT_PATHS = dict(use_caustic_light_paths=True, caustic_light_paths=0.5)


def glass_ball_in_the_sun():
    """tests/core/test_caustic_glass.py's sphere and sun: the sphere focuses the sun onto the
    floor inside its own shadow, which the camera sees from the sun's side."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 64, 48
    scene.render.resolution_percentage = 100
    add_plane("Floor", 8.0, diffuse("Floor", (0.5, 0.5, 0.5)))
    glass, _ = bsdf_material("Glass", "ShaderNodeBsdfGlass", Roughness=0.0, IOR=1.45)
    add_sphere("Ball", 0.4, glass, location=(0.0, 0.3, 0.45))
    to_sun = Vector((0.8, 0.2, 0.55)).normalized()
    add_light("SUN", name="Sun", rotation=to_sun.to_track_quat("Z", "Y").to_euler(), energy=3.0,
              angle=math.radians(10.0))
    set_world((0.03, 0.03, 0.04))
    add_camera((-0.9, -1.6, 2.0), (-0.9, 0.2, 0.0), lens=45.0)
    return scene


@needs_core
@pytest.mark.converged
def test_glass_ball_caustic_agrees_with_cycles():
    ours = render_to_array(glass_ball_in_the_sun(), "PATHLIGHT", samples=1024, max_bounces=8, **LIGHT_PATHS)
    cycles = render_to_array(glass_ball_in_the_sun(), "CYCLES", samples=32768, max_bounces=8, **BOX_FILTER)
    assert_agree(ours, cycles, "smooth glass ball under a sun of 10 degrees, light paths 0.5")
