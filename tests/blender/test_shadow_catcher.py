"""Shadow catcher and holdout objects through headless Blender, against Cycles 4.5 in the same
bpy: a diffuse sphere on a catcher plane under a sun, an area light and an HDR-ish world (48x48,
box filter). Cycles' composite of Combined (the matte, and the approximate shadow catcher with
and without transparent film) and its Shadow Catcher pass, per 8x8 region.

Tolerances from measured noise (docs/design/passes.md): at 256 spp Cycles against itself (seeds 1
and 2) differs by up to 6.9 % of the mean in an 8x8 region of the matte's colour (mostly
transparent black: a small mean), 1.8 % in the Shadow Catcher pass and 2 % in alpha; Pathlight
against Cycles by 3.8 %, 1.7 % and 1.9 %. Means agree within 0.03 %. The same scene in world
fog (32x32, 128 spp): Cycles against itself up to 5.7 % in a region of the matte's colour, 3.1 %
in the pass, 4.9 % in the opaque composite; Pathlight 5.1 %, 1.2 % and 4.5 %."""
import math

import bpy
import numpy as np
import pytest

from blender_util import core_available, core_has, empty_scene_with_camera, load_addon, node_material, \
    render_multilayer_file
from light_scenes import load_image, synthetic_hdr, world_image

addon = load_addon()

pytestmark = [pytest.mark.skipif(not core_available(), reason="pathlight_core is not built"),
              pytest.mark.skipif(not core_has("RenderSettings", "mist_start"), reason="core without passes")]

SAMPLES = 256
# Cycles renders at 4x Pathlight's samples: its images are stored (tests/cycles_refs), so that
# costs no test time, and at equal samples its own noise took half of the regions' tolerances
# (docs/design/sampling.md, "The default").
CYCLES_FACTOR = 4


def catcher_scene(casters=True):
    sc = empty_scene_with_camera(48)
    sc.camera.location = (0.0, -5.0, 2.5)
    sc.camera.rotation_euler = (math.radians(65), 0.0, 0.0)
    bpy.ops.mesh.primitive_plane_add(size=8, location=(0, 0, -1))
    floor = bpy.context.active_object
    floor.name = "Catcher"
    floor.data.materials.append(node_material("Floor", "ShaderNodeBsdfDiffuse", Color=(0.7, 0.7, 0.7, 1)))
    floor.is_shadow_catcher = True
    if casters:
        bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=0.8, location=(0.3, 0.4, -0.2))
        ball = bpy.context.active_object
        ball.name = "Ball"
        bpy.ops.object.shade_smooth()
        ball.data.materials.append(node_material("Ball", "ShaderNodeBsdfDiffuse", Color=(0.8, 0.3, 0.2, 1)))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.data.energy = 2.0
    sun.data.angle = math.radians(8)
    sun.rotation_euler = (math.radians(30), math.radians(-25), 0)
    sc.collection.objects.link(sun)
    area = bpy.data.objects.new("Area", bpy.data.lights.new("Area", 'AREA'))
    area.data.energy = 150.0
    area.data.size = 2.0
    area.location = (2.5, -1.5, 3.0)
    area.rotation_euler = (math.radians(40), 0, math.radians(60))
    sc.collection.objects.link(area)
    world = world_image(load_image(synthetic_hdr(64, 32, sun_peak=20.0), name="sc_env"), strength=0.5)
    # (Cycles' default 1024-wide importance map took 5 s a render here; 64 is the image's own width)
    world.cycles.sampling_method = 'MANUAL'
    world.cycles.sample_map_resolution = 64
    return sc


def render(sc, engine, path, transparent, pass_on, seed=1, samples=SAMPLES):
    """Combined (RGBA) and, with pass_on, the Shadow Catcher pass (RGB), image order; Cycles
    at CYCLES_FACTOR x samples."""
    sc.render.engine = engine
    sc.render.film_transparent = transparent
    vl = sc.view_layers[0]
    vl.cycles.use_pass_shadow_catcher = vl.pathlight.use_pass_shadow_catcher = pass_on
    if engine == 'CYCLES':
        c = sc.cycles
        c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = 'CPU', CYCLES_FACTOR * samples, False, False
        c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
        c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = 8
        c.pixel_filter_type, c.filter_width = 'BOX', 1.0
        c.seed = seed
    else:
        p = sc.pathlight
        p.seed, p.samples, p.use_adaptive_sampling, p.max_bounces = seed, samples, False, 8
        p.diffuse_bounces = p.glossy_bounces = p.transmission_bounces = 8
        p.filter_type, p.filter_width = 'BOX', 1.0
    ch = render_multilayer_file(sc, path)
    combined = np.stack([ch[f"Combined.{c}"] for c in "RGBA"], -1)
    catcher = np.stack([ch[f"Shadow Catcher.{c}"] for c in "RGB"], -1) if pass_on else None
    return combined, catcher


def regions(img):
    h, w = img.shape[:2]
    return img.reshape(h // 8, 8, w // 8, 8, -1).mean(axis=(1, 3))


# (film transparent, Shadow Catcher pass): the matte with the pass; the approximate composite
# on a transparent and an opaque film without it.
CASES = [(True, True), (True, False), (False, False)]


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    sc = catcher_scene()
    tmp = tmp_path_factory.mktemp("shadow_catcher")
    out = {}
    for transparent, pass_on in CASES:
        for engine in ('PATHLIGHT', 'CYCLES'):
            out[engine, transparent, pass_on] = render(sc, engine, tmp / f"{engine}{transparent}{pass_on}.exr",
                                                       transparent, pass_on)
    return out


def assert_close(a, b, mean_tol, region_tol, what):
    scale = max(float(np.abs(b).mean()), 1e-3)
    assert abs(a.mean() - b.mean()) / scale < mean_tol, (what, a.mean(), b.mean())
    worst = float(np.abs(regions(a) - regions(b)).max()) / scale
    assert worst < region_tol, (what, worst)


@pytest.mark.parametrize("transparent,pass_on", CASES)
def test_combined_as_cycles(renders, transparent, pass_on):
    ours, _ = renders['PATHLIGHT', transparent, pass_on]
    cycles, _ = renders['CYCLES', transparent, pass_on]
    assert_close(ours[..., :3], cycles[..., :3], 0.01, 0.06, "rgb")
    assert_close(ours[..., 3:], cycles[..., 3:], 0.01, 0.03, "alpha")


def test_shadow_catcher_pass_as_cycles(renders):
    _, ours = renders['PATHLIGHT', True, True]
    _, cycles = renders['CYCLES', True, True]
    assert cycles.min() < 0.6  # a shadow there is
    assert_close(ours, cycles, 0.005, 0.03, "shadow catcher")


def test_matte_hides_the_catcher(renders):
    # With the pass asked for, Combined is the matte: the ball alone, the catcher transparent.
    combined, catcher = renders['PATHLIGHT', True, True]
    alpha = combined[..., 3]
    assert (alpha < 0.01).mean() > 0.5 and (alpha > 0.99).mean() > 0.05
    # Where the catcher is, its approximate composite darkens the alpha by the shadow.
    approx, _ = renders['PATHLIGHT', True, False]
    shadowed = (alpha < 0.01) & (catcher.mean(-1) < 0.7)
    assert shadowed.sum() > 10
    np.testing.assert_allclose(approx[..., 3][shadowed], 1.0 - catcher.mean(-1)[shadowed], atol=0.02)


def test_no_casters_is_identity(tmp_path):
    # Nothing casts anything on the catcher: the pass is exactly 1 (the two halves of the split
    # see the same scene with the same random numbers) and the transparent film's alpha 0.
    sc = catcher_scene(casters=False)
    sc.render.resolution_x = sc.render.resolution_y = 24
    combined, catcher = render(sc, 'PATHLIGHT', tmp_path / "none.exr", True, True, samples=4)
    np.testing.assert_allclose(catcher, 1.0, atol=1e-5)
    approx, _ = render(sc, 'PATHLIGHT', tmp_path / "none2.exr", True, False, samples=4)
    np.testing.assert_allclose(approx, 0.0, atol=1e-5)


def test_holdout_object_as_cycles(tmp_path):
    # Object ▸ Visibility ▸ Holdout: alpha 0 and no colour where seen, a plain object to other rays.
    sc = catcher_scene()
    sc.objects["Catcher"].is_shadow_catcher = False
    sc.objects["Ball"].is_holdout = True
    sc.render.resolution_x = sc.render.resolution_y = 24
    ours, _ = render(sc, 'PATHLIGHT', tmp_path / "p.exr", False, False, samples=64)
    cycles, _ = render(sc, 'CYCLES', tmp_path / "c.exr", False, False, samples=64 // CYCLES_FACTOR)
    hole = cycles[..., 3] < 0.01
    assert hole.mean() > 0.05
    # (pixels on its silhouette: the two engines' samples fall differently)
    assert (ours[..., 3][hole] < 0.01).mean() > 0.95
    inside = hole & (ours[..., 3] < 0.01)
    assert np.abs(ours[..., :3][inside]).max() < 1e-6
    assert abs(ours[..., 3].mean() - cycles[..., 3].mean()) < 0.01
    # (Cycles seed to seed at 64 spp: 0.2 % in the mean, 1.2 % in a region)
    assert_close(ours[..., :3], cycles[..., :3], 0.01, 0.03, "holdout rgb")
    # A holdout collection of the view layer holds it out as well (Cycles' holdout_get).
    ball = sc.objects["Ball"]
    ball.is_holdout = False
    coll = bpy.data.collections.new("Held out")
    sc.collection.children.link(coll)
    for c in ball.users_collection:
        c.objects.unlink(ball)
    coll.objects.link(ball)
    sc.view_layers[0].layer_collection.children["Held out"].holdout = True
    held, _ = render(sc, 'PATHLIGHT', tmp_path / "h.exr", False, False, samples=4)
    assert (held[..., 3][inside] == 0.0).all()


def fog_catcher_scene():
    """catcher_scene() in world fog (Volume Scatter, density 0.04: about a quarter of the light
    from the catcher is lost on its way to the camera)."""
    sc = catcher_scene()
    nodes, links = sc.world.node_tree.nodes, sc.world.node_tree.links
    fog = nodes.new("ShaderNodeVolumeScatter")
    fog.inputs["Density"].default_value = 0.04
    out = next(n for n in nodes if n.bl_idname == "ShaderNodeOutputWorld")
    links.new(fog.outputs[0], out.inputs["Volume"])
    return sc


# (film transparent, Shadow Catcher pass) of the fog renders: the pass (and the matte), and the
# approximate composite on an opaque film.
FOG_CASES = [(True, True), (False, False)]
FOG_SAMPLES = 512  # Pathlight's (Cycles' 128 x CYCLES_FACTOR): at 128 its regions' colour was 5-11 % off


@pytest.fixture(scope="module")
def fog_renders(tmp_path_factory):
    sc = fog_catcher_scene()
    sc.render.resolution_x = sc.render.resolution_y = 32
    tmp = tmp_path_factory.mktemp("shadow_catcher_fog")
    return {(engine, transparent, pass_on): render(sc, engine, tmp / f"{engine}{transparent}{pass_on}.exr",
                                                   transparent, pass_on,
                                                   samples=FOG_SAMPLES if engine == 'PATHLIGHT' else 128)
            for transparent, pass_on in FOG_CASES for engine in ('PATHLIGHT', 'CYCLES')}


def test_catcher_path_leaves_the_world_fog_as_cycles(fog_renders):
    """The split comes after the fog on the way to the catcher (the matte keeps that fog's
    light and takes its transparency), and the catcher's copy of the path is then in no volume
    but the catchers' own (Cycles re-initialises its volume stack without the other objects
    and the world): the sun and the world, which the infinite fog swallows on the other
    paths, light the copy's catcher, so the pass is dark even out of the ball's shadow."""
    _, ours = fog_renders['PATHLIGHT', True, True]
    _, cycles = fog_renders['CYCLES', True, True]
    assert cycles.min() < 0.3 and np.median(cycles) < 0.9
    assert_close(ours, cycles, 0.01, 0.04, "shadow catcher in fog")
    for transparent, pass_on in FOG_CASES:
        ours, _ = fog_renders['PATHLIGHT', transparent, pass_on]
        cycles, _ = fog_renders['CYCLES', transparent, pass_on]
        assert_close(ours[..., :3], cycles[..., :3], 0.01, 0.06, f"fog rgb {transparent, pass_on}")
        assert_close(ours[..., 3:], cycles[..., 3:], 0.01, 0.03, f"fog alpha {transparent, pass_on}")


def test_curves_and_points_as_holdout_and_catcher_as_cycles(tmp_path):
    """Curves and point clouds take the Holdout and Shadow Catcher of their objects, as Cycles:
    strands held out on the floor (alpha 0 where seen), and a cloud of large points on the
    floor as shadow catchers of the ball (the matte, and the Shadow Catcher pass)."""
    from test_hair import add_hair
    from test_point_clouds import add_cloud
    sc = catcher_scene()
    sc.objects["Catcher"].is_shadow_catcher = False
    sc.render.resolution_x = sc.render.resolution_y = 32
    hair = add_hair("Strands", node_material("Hair", "ShaderNodeBsdfDiffuse", Color=(0.2, 0.5, 0.8, 1)),
                    strands=3, keys=4, radius=0.12, length=4.0, sag=0.0, spacing=0.6)
    hair.location = (0.0, -1.2, -1.4)
    hair.is_holdout = True
    cloud = add_cloud("Pebbles", node_material("Pebble", "ShaderNodeBsdfDiffuse", Color=(0.6, 0.6, 0.5, 1)),
                      n=12, spread=2.4, radii=np.full(12, 0.3), seed=3)
    cloud.location = (0.4, 0.9, -1.3)
    cloud.is_shadow_catcher = True
    out = {}
    for engine in ('PATHLIGHT', 'CYCLES'):  # (Cycles at CYCLES_FACTOR x 128)
        out[engine] = render(sc, engine, tmp_path / f"{engine}.exr", True, True,
                             samples=256 if engine == 'PATHLIGHT' else 128)
    (ours, ours_pass), (cycles, cycles_pass) = out['PATHLIGHT'], out['CYCLES']
    # The floor (the lower half, opaque but for them): the strands, and the catchers
    # (transparent in the matte), take out a fifth of it or more.
    assert (cycles[16:, :, 3] < 0.5).mean() > 0.2
    assert cycles_pass.min() < 0.5  # the ball shadows some catchers
    # (Cycles seed to seed here: regions 2.5 % in colour, 0.5 % in alpha, 4.7 % in the pass;
    # Pathlight against Cycles 2.0 %, 0.2 % and 3.8 %.)
    assert_close(ours[..., :3], cycles[..., :3], 0.01, 0.05, "rgb")
    assert_close(ours[..., 3:], cycles[..., 3:], 0.01, 0.03, "alpha")
    # The pass is a per-pixel ratio (Combined less the matte over the catcher path's light): at
    # the points' silhouettes, where few samples reach a catcher, single pixels read 4-24 in
    # either engine at any sample count, and a region's mean followed them (over 16 seeds 13 and
    # 16 of 16 failed 8 %, sets and pairs). Clipped at 2 (a shadow's ratio is at most about 1)
    # in both: 0.8-4.1 % over 16 seeds; a ball 15 % larger 11 %, the cloud not a catcher 13 %,
    # the ball hidden 17 % (docs/design/sampling.md, "The default").
    assert_close(np.minimum(ours_pass, 2.0), np.minimum(cycles_pass, 2.0), 0.01, 0.08, "shadow catcher")
