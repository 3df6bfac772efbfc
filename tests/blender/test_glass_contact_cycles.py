"""A glass cylinder standing on a floor, against Cycles 4.5 (docs/materials.md, "Known
differences", the glass resting on a floor): a smooth-shaded Principled glass cylinder (roughness
0, IOR 1.5, 32-gon caps) whose bottom cap lies in the floor's plane, under a uniform world, seen
from above through its top, 32 x 32. Pathlight spawns a ray that crosses the bottom cap past the
coplanar floor (offset_ray_origin) and misses it; Cycles skips only the crossed triangle and finds
the floor. Lifted 2 cm off the floor the two agree (the control). Cycles' images come from
tests/cycles_refs/ (docs/building.md)."""
import bmesh
import pytest

from blender_util import canonical_order, core_available, load_addon
import light_scenes as ls
import material_scenes as ms

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def glass_on_floor(lift=0.0):
    scene = ls.empty_scene(32, 32)
    ls.world_color((1.0, 1.0, 1.0))
    mat, nodes, links, out = ms.new_material("Glass")
    p = ms.set_inputs(nodes.new("ShaderNodeBsdfPrincipled"), Base_Color=(1.0, 1.0, 1.0, 1.0),
                      Roughness=0.0, IOR=1.5, Transmission_Weight=1.0)
    links.new(p.outputs[0], out.inputs["Surface"])

    def cylinder(bm):
        bmesh.ops.create_cone(bm, cap_ends=True, segments=32, radius1=0.35, radius2=0.35, depth=1.2)
        canonical_order(bm)
    ms.add_mesh_object("Bottle", cylinder, (mat,), smooth=True, location=(0.0, 0.0, 0.6 + lift))
    ms.add_plane("Floor", 8.0, ms.diffuse("FloorMat", (0.5, 0.5, 0.5)))
    ms.add_camera((0.0, -3.4, 1.6), (0.0, 0.0, 0.9), lens=70.0)
    return scene


def _render(lift):
    return ms.render_pair(lambda: glass_on_floor(lift), 512, bounces=64, cycles_samples=1024)


def test_glass_lifted_off_floor_matches_cycles():
    ours, ref = _render(0.02)
    ms.assert_agree(ours, ref, "glass lifted off the floor")


@pytest.mark.xfail(strict=True, reason="a ray leaving glass through a face coplanar with the floor "
                   "is spawned past the floor (offset_ray_origin) and misses it; Cycles finds it "
                   "(docs/materials.md, Known differences)")
def test_glass_resting_on_floor_matches_cycles():
    ours, ref = _render(0.0)
    ms.assert_agree(ours, ref, "glass resting on the floor")
