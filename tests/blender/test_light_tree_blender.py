"""The light tree against Cycles (whose light tree is on by default): a set lit by 50 small
point lights, compared at convergence (mean within 1 %, 8x8 regions within 3 %)."""
import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, core_has, load_addon, render_to_array
from light_scenes import add_light, diffuse_set

load_addon()
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402

needs_tree = pytest.mark.skipif(not core_has("Scene", "light_tree"), reason="the core has no light tree")


def fifty_lamps():
    scene = diffuse_set(32)
    rng = np.random.default_rng(7)
    for i in range(50):  # small lamps over the set, of different colours and powers
        loc = (rng.uniform(-3.0, 3.0), rng.uniform(-2.0, 2.3), rng.uniform(0.4, 3.0))
        add_light('POINT', name=f"Lamp{i}", location=tuple(loc), energy=float(rng.uniform(5.0, 40.0)),
                  color=tuple(rng.uniform(0.4, 1.0, 3)), shadow_soft_size=0.05)
    return scene


@needs_tree
def test_fifty_point_lights_agree_with_cycles():
    scene = fifty_lamps()
    pc = load_addon().core.get_core()
    core_scene = to_core(pc, export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None))
    core_scene.commit()
    assert core_scene.light_tree_active  # 50 lights: the tree, not the power sampler
    ours = render_to_array(scene, samples=1024, max_bounces=3)[..., :3]
    ref = render_to_array(scene, "CYCLES", samples=1024, max_bounces=3, **BOX_FILTER)[..., :3]
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    reg = lambda im: im.reshape(8, 4, 8, 4, 3).mean(axis=(1, 3))
    a, b = reg(ours), reg(ref)
    rel = np.abs(a - b) / np.maximum(b, 0.1 * b.mean())
    worst = np.unravel_index(np.argmax(rel), rel.shape)
    assert rel.max() < 0.03, (worst, a[worst], b[worst])


@needs_tree
def test_bench_lamp_room_agrees_with_cycles():
    """The equal-time bench's many-light room (50 coloured lamps, 3 spots, Principled furniture;
    tests/bench/realistic_scenes.py) at 64x48, 1024 spp, 4 bounces: mean within 1 %, every 8x8
    region within 3 % (measured at 12 bounces: mean ratio 1.0003, worst region 1.8 %)."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    import realistic_scenes
    from material_scenes import assert_agree, render_pair
    ours, ref = render_pair(lambda: realistic_scenes.lamp_room(64, 48), 1024, bounces=4)
    assert_agree(ours, ref, "bench lamp room")
