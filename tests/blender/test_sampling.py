"""Sampling settings through the add-on (issue 4): the settings reach the core's
RenderSettings, the animated seed, the panels; renders: NEE/MIS unbiasedness, the Sobol
sampler, per-type bounce limits against Cycles, adaptive sampling."""

import math

import bpy
import numpy as np
import pytest

from blender_util import (RecordingLayout, core_available, core_has, core_session, load_addon, render_to_array,
                          BOX_FILTER)
from light_scenes import (add_light, box, camera, diffuse_material, diffuse_set,
                          emission_material, empty_scene, load_image, plane, synthetic_hdr, world_image)
from material_scenes import region_means

load_addon()
from addon import session, ui  # noqa: E402
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


needs_lights = pytest.mark.skipif(not core_has("Scene", "add_area_light"),
                                  reason="the core has no analytic lights")
needs_adaptive = pytest.mark.skipif(not core_has("Session", "sample_counts"),
                                    reason="the core has no adaptive sampling (sample_counts)")
needs_settings = pytest.mark.skipif(not core_has("RenderSettings", "diffuse_bounces"),
                                    reason="the core has no per-type bounce limits")


# ---------------------------------------------------------------- settings (no core)

def test_defaults_are_cycles_defaults():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    props = bpy.context.scene.pathlight
    cycles = bpy.context.scene.cycles
    assert props.use_adaptive_sampling is True
    assert props.adaptive_threshold == pytest.approx(cycles.adaptive_threshold)  # 0.01
    assert props.adaptive_min_samples == cycles.adaptive_min_samples == 0
    assert (props.max_bounces, props.diffuse_bounces, props.glossy_bounces,
            props.transmission_bounces, props.transparent_bounces) == (
        cycles.max_bounces, cycles.diffuse_bounces, cycles.glossy_bounces, cycles.transmission_bounces,
        cycles.transparent_max_bounces)
    assert props.sampler == 'SOBOL' and props.use_animated_seed is False
    assert props.pixel_pattern == 'INDEPENDENT'  # (not yet Cycles' Automatic: docs/design/sampling.md)


def test_enum_items_keep_their_numbers():
    """A saved .blend stores an EnumProperty as its item's number: the items that existed keep
    theirs (the old Sobol pairs came last as Sobol Pairs when 4-D sets became the default)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    rna = bpy.context.scene.pathlight.bl_rna.properties
    numbers = {p: {i.identifier: i.value for i in rna[p].enum_items} for p in ("sampler", "pixel_pattern")}
    assert numbers["sampler"] == {'SOBOL': 0, 'RANDOM': 1, 'SOBOL_DEEP': 2, 'SOBOL4D': 3, 'SOBOL4D_DEEP': 4,
                                  'SOBOL4D_RR': 5, 'SOBOL4D_CYCLES': 6, 'SOBOL_PAIRS': 7}
    assert numbers["pixel_pattern"] == {'AUTOMATIC': 0, 'BLUE_NOISE': 1, 'BLUE_NOISE_ROUND': 2,
                                        'BLUE_NOISE_FIRST': 3, 'INDEPENDENT': 4}


@needs_settings
def test_settings_reach_the_core():
    from addon.core import get_core
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    props = scene.pathlight
    props.sampler = 'RANDOM'
    props.adaptive_threshold = 0.05
    props.adaptive_min_samples = 24
    props.diffuse_bounces, props.glossy_bounces, props.transmission_bounces = 3, 5, 7
    props.transparent_bounces = 11
    st = session.render_settings(get_core(), scene)
    assert st.transparent_bounces == 11
    assert st.sampler == "random"
    assert st.adaptive_threshold == pytest.approx(0.05) and st.adaptive_min_samples == 24
    assert (st.diffuse_bounces, st.glossy_bounces, st.transmission_bounces) == (3, 5, 7)
    # the old pairs and the opt-in measurement patterns
    for variant in ('SOBOL_PAIRS', 'SOBOL_DEEP', 'SOBOL4D', 'SOBOL4D_DEEP', 'SOBOL4D_RR', 'SOBOL4D_CYCLES'):
        props.sampler = variant
        assert session.render_settings(get_core(), scene).sampler == variant.lower()
    props.use_adaptive_sampling = False
    props.sampler = 'SOBOL'
    st = session.render_settings(get_core(), scene)
    assert st.adaptive_threshold == 0.0 and st.sampler == "sobol"
    assert not st.guiding  # off by default, as Cycles' Path Guiding
    assert st.guiding_photons == 0.0 and not st.guiding_caustics
    assert not (st.guiding_learn_probability or st.guiding_cosine or st.guiding_filter)
    props.use_guiding = True
    st = session.render_settings(get_core(), scene)
    assert st.guiding
    # The guided path trains with caustic photons (docs/design/sampling.md)
    assert st.guiding_photons > 0.0 and st.guiding_caustics and st.guiding_photon_share == pytest.approx(0.15)
    # ... with a learnt probability per cell (from 0.5 down), the cosine product, the directional filter
    assert st.guiding_learn_probability and st.guiding_cosine and st.guiding_filter
    assert st.guiding_probability == pytest.approx(0.5)
    # Caustic light paths: automatic by default (the core decides where they pay), else the
    # paths per sample asked for, or off (docs/design/sampling.md)
    assert st.caustic_light_paths == 0.0 and st.caustic_light_paths_auto
    assert ui.caustics_in_effect(props).startswith("Automatic")
    props.use_caustic_light_paths, props.caustic_light_paths = True, 0.5
    st = session.render_settings(get_core(), scene)
    assert st.caustic_light_paths == pytest.approx(0.5) and not st.caustic_light_paths_auto
    assert ui.caustics_in_effect(props) == "On: 0.5 light paths per sample"
    props.use_caustic_light_paths, props.caustic_light_paths_auto = False, False
    st = session.render_settings(get_core(), scene)
    assert st.caustic_light_paths == 0.0 and not st.caustic_light_paths_auto
    assert ui.caustics_in_effect(props) == "Off"
    props.caustic_light_paths_auto = True


def test_caustics_warn_only_when_asked_for():
    """The core's "off: ..." (asked for, not possible) warns; the automatic mode's "off
    (automatic): ..." and "on (automatic): ..." do not."""
    class Sess:
        def __init__(self, state):
            self.state = state

        def stats(self):
            return {"caustics": self.state}

    for state, warns in (("off: not with a panoramic camera's depth of field", 1),
                         ("off (automatic): the environment's peak holds 20 % of its power (under 40 %)", 0),
                         ("off (automatic): no smooth surface to cast caustics", 0),
                         ("on (automatic): the environment's peak holds 60 % of its power", 0), ("on", 0), ("", 0)):
        got = []
        session._report_caustics(Sess(state), got.append)
        assert len(got) == warns, state


@needs_core
def test_automatic_caustics_follow_the_environments_sun():
    """The add-on's default (Automatic) in a Blender scene: a chrome ball on a floor under an HDRI
    whose sun holds most of its light gets caustic light paths; under a dimmer sun it does not,
    and says why in the stats (docs/design/sampling.md "Automatic caustic light paths")."""
    from addon.core import get_core
    import material_scenes as ms
    pc = get_core()
    states = {}
    for peak in (200.0, 50.0):
        scene = empty_scene(32)
        scene.render.engine = "PATHLIGHT"
        ms.add_plane("Floor", 6.0, ms.diffuse("Floor", (0.6, 0.6, 0.6)))
        ms.add_sphere("Chrome", 0.4, ms.glossy("Chrome", roughness=0.05), location=(0.8, 0.3, 0.4))
        world_image(load_image(synthetic_hdr(64, 32, sun_peak=peak), name=f"Sun{peak:g}"))
        ms.add_camera((0.0, -4.0, 2.0), (0.0, 0.0, 0.4))
        core_scene = to_core(pc, export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None))
        core_scene.commit()
        states[peak] = pc.Session(core_scene, session.render_settings(pc, scene)).stats()["caustics"]
        if peak == 200.0:
            # Path Guiding keeps them ("Guiding with caustic light paths"), in its guided kernel.
            scene.pathlight.use_guiding = True
            st = pc.Session(core_scene, session.render_settings(pc, scene)).stats()
            states["guided"] = st["caustics"]
            assert "guiding+caustics" in st["kernel"], st["kernel"]
    assert states[200.0].startswith("on (automatic)") and states["guided"] == states[200.0], states
    assert states[50.0].startswith("off (automatic): the environment's peak"), states


@needs_settings
def test_noise_pattern_reaches_the_core():
    """Noise Pattern and Frame Samples (the blue-noise pattern, docs/design/sampling.md): Automatic
    is Blue-Noise for renders and Blue-Noise (First) in the viewport, as Cycles'; a Frame Samples
    below the piece's own end warns and falls back."""
    from addon.core import get_core
    if not core_has("RenderSettings", "pixel_pattern"):
        pytest.skip("core without pixel_pattern")
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    props = scene.pathlight
    for value, core_name in (('AUTOMATIC', "blue_noise"), ('BLUE_NOISE', "blue_noise"),
                             ('BLUE_NOISE_ROUND', "blue_noise_round"),
                             ('BLUE_NOISE_FIRST', "blue_noise_first"), ('INDEPENDENT', "independent")):
        props.pixel_pattern = value
        assert session.render_settings(get_core(), scene).pixel_pattern == core_name
    props.pixel_pattern = 'AUTOMATIC'
    assert session.pixel_pattern_settings(props, None, viewport=True)["pixel_pattern"] == "blue_noise_first"
    props.samples, props.sample_offset, props.frame_samples = 100, 200, 1000
    assert session.render_settings(get_core(), scene).pattern_samples == 1000
    warnings = []
    props.frame_samples = 250  # below 200 + 100
    st = session.render_settings(get_core(), scene, warnings.append)
    assert st.pattern_samples == 0 and len(warnings) == 1 and "Frame Samples" in warnings[0]
    # a farm piece (Sample Offset) without Frame Samples under the default blue noise: warned;
    # independent pixels need none
    props.frame_samples = 0
    st = session.render_settings(get_core(), scene, warnings.append)
    assert st.pattern_samples == 0 and len(warnings) == 2 and "Sample Offset without Frame Samples" in warnings[1]
    props.pixel_pattern = 'INDEPENDENT'
    session.render_settings(get_core(), scene, warnings.append)
    assert len(warnings) == 2


def test_animated_seed_adds_the_frame():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.pathlight.seed = 5
    scene.frame_set(12)
    assert session.render_seed(scene) == 5
    scene.pathlight.use_animated_seed = True
    assert session.render_seed(scene) == 17
    scene.frame_set(-20)  # negative frames still give a valid (non-negative) seed
    assert 0 <= session.render_seed(scene) < 2 ** 31


def test_panels_draw_existing_properties():
    """Draw each Pathlight panel into a recording layout: every property it shows exists."""

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    obj = bpy.data.objects.new("O", bpy.data.meshes.new("O"))
    world = bpy.data.worlds.new("W")  # (the light group panels draw the world's field)
    shown = set()
    for light_type in ('POINT', 'SPOT', 'SUN', 'AREA'):
        for shape in ('SQUARE', 'RECTANGLE'):
            light = bpy.data.lights.new("L", light_type)
            if light_type == 'AREA':
                light.shape = shape
            context = type("Ctx", (), {"scene": scene, "light": light, "object": obj, "engine": "PATHLIGHT",
                                       "view_layer": scene.view_layers[0], "world": world})
            for cls in ui.classes:
                if getattr(cls, "bl_space_type", "PROPERTIES") == 'VIEW_3D':
                    continue  # (the shading popover's panel reads a 3D view: test_viewport_passes.py)
                layout = RecordingLayout()
                if hasattr(cls, "draw_header"):  # (a header's switch: Fast GI, Film > Transparent)
                    cls.draw_header(type("Panel", (), {"layout": layout})(), context)
                cls.draw(type("Panel", (), {"layout": layout})(), context)
                shown.update(layout.props)
    # (Spot size and blend are in Blender's DATA_PT_spot, which Pathlight is added to.)
    for name in ("samples", "adaptive_threshold", "adaptive_min_samples", "sampler", "pixel_pattern",
                 "frame_samples", "seed",
                 "use_animated_seed", "max_bounces", "diffuse_bounces", "glossy_bounces",
                 "transmission_bounces", "energy", "exposure", "color", "shadow_soft_size",
                 "angle", "shape", "size", "size_y", "use_shadow", "film_exposure",
                 "film_transparent", "debug_view", "use_pass_z", "use_pass_denoising_data",
                 "use_pass_sample_count", "is_shadow_catcher", "lightgroup", "use_fast_gi", "fast_gi_method",
                 "ao_bounces_render", "film_transparent_glass", "film_transparent_roughness"):
        assert name in shown, name


# ---------------------------------------------------------------- renders (need the core)

def emissive_mesh_scene(size=48):
    """The diffuse set lit only by an emissive panel (NEE can sample it, BSDF rays hit it)."""
    scene = diffuse_set(size)
    # Large enough for BSDF sampling alone to converge in a test's time.
    plane("Lamp", 1.0, emission_material("Lamp", (1.0, 0.9, 0.7), 3.0),
          location=(0.3, -0.8, 2.6), rotation_euler=(math.pi, 0.0, 0.0), scale=(3.0, 2.0, 1.0))
    return scene


@needs_core
def test_nee_on_and_off_converge_to_the_same_image():
    # MIS must be unbiased: next-event estimation changes the noise, not the mean.
    scene = emissive_mesh_scene()
    with_nee = render_to_array(scene, samples=256, max_bounces=3, use_nee=True)
    without = render_to_array(scene, samples=3072, max_bounces=3, use_nee=False)
    a, b = region_means(with_nee), region_means(without)
    rel = np.abs(a - b) / np.maximum(b, 0.1 * b.mean())
    assert rel.max() < 0.08, np.unravel_index(np.argmax(rel), rel.shape)
    ratio = with_nee[..., :3].mean(axis=(0, 1)) / without[..., :3].mean(axis=(0, 1))
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)


@needs_core
def test_emissive_mesh_scene_agrees_with_cycles():
    scene = emissive_mesh_scene()
    ours = render_to_array(scene, samples=256, max_bounces=3)
    ref = render_to_array(scene, "CYCLES", samples=256, max_bounces=3, **BOX_FILTER)
    a, b = region_means(ours), region_means(ref)
    rel = np.abs(a - b) / np.maximum(b, 0.1 * b.mean())
    assert rel.max() < 0.06, np.unravel_index(np.argmax(rel), rel.shape)
    ratio = ours[..., :3].mean(axis=(0, 1)) / ref[..., :3].mean(axis=(0, 1))
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)


def soft_shadow_scene(size=32):
    """Left half: a floor with a soft shadow from an area light (noisy); right half: the
    black world (flat, nothing to sample)."""
    scene = empty_scene(size)
    white = diffuse_material("White", 0.7)
    plane("Floor", 4.0, white, location=(-2.0, 0.0, 0.0))  # x < 0: the left half of the view
    box("Blocker", 0.4, white, location=(-1.0, 0.0, 0.6))
    add_light('AREA', location=(-1.0, 0.0, 2.0), energy=200.0, size=1.5)
    camera((0.0, 0.0, 5.0), lens=20.0)
    return scene


def core_render(scene, **props):
    """Render through the add-on's export and settings, but with a core Session held here,
    for what a Blender render result cannot show (sample counts, timing)."""
    # The 1-pixel box, as render_to_array's default (these tests predate the pixel filters).
    props = {"filter_type": 'BOX', "filter_width": 1.0, **props}
    for name, value in props.items():
        setattr(scene.pathlight, name, value)
    return core_session(scene)


@needs_lights
@needs_settings
def test_sobol_converges_faster_than_random():
    # Same scene, same sample count: the scrambled Sobol sequence's error on a soft shadow is
    # well below independent random numbers', and both converge to the same image.
    scene = soft_shadow_scene()
    ref = core_render(scene, samples=2048, use_adaptive_sampling=False, sampler='SOBOL',
                      seed=99).film()[..., :3]
    errors = {}
    for sampler in ('SOBOL', 'RANDOM'):
        img = core_render(scene, samples=16, use_adaptive_sampling=False, sampler=sampler,
                          seed=1).film()[..., :3]
        errors[sampler] = ((img - ref) ** 2).mean()
        assert abs(img.mean() / ref.mean() - 1) < 0.01
    assert errors['SOBOL'] < 0.7 * errors['RANDOM'], errors


@needs_lights
@needs_settings
@pytest.mark.parametrize("diffuse_bounces", [1, 2])
def test_diffuse_bounce_limit_agrees_with_cycles(diffuse_bounces):
    scene = diffuse_set(48)
    add_light('AREA', location=(0.5, -1.5, 3.0), rotation=(0.4, 0.0, 0.0), energy=400.0,
              size=1.0)
    ours = render_to_array(scene, samples=128, max_bounces=8, diffuse_bounces=diffuse_bounces)
    ref = render_to_array(scene, "CYCLES", samples=128, max_bounces=8,
                          diffuse_bounces=diffuse_bounces, **BOX_FILTER)
    unlimited = render_to_array(scene, samples=128, max_bounces=8)
    mean = lambda img: img[..., :3].mean()  # noqa: E731
    assert mean(unlimited) > mean(ours) * 1.003  # the limit really cuts light (0.7 % at 2)
    assert abs(mean(ours) / mean(ref) - 1) < 0.01
    a, b = region_means(ours), region_means(ref)
    assert (np.abs(a - b) / np.maximum(b, 0.1 * b.mean())).max() < 0.06


@needs_lights
@needs_adaptive
def test_adaptive_sampling_stops_flat_pixels_and_lowers_the_error_per_work():
    # Work is counted in samples, not seconds: wall time on a shared machine is noise (the
    # time it saves is a benchmark figure, not a test).
    scene = soft_shadow_scene(48)
    ref = core_render(scene, samples=2048, use_adaptive_sampling=False, seed=7).film()[..., :3]
    runs = {}
    for adaptive in (False, True):
        sess = core_render(scene, samples=512, use_adaptive_sampling=adaptive,
                           adaptive_threshold=0.01, adaptive_min_samples=0, seed=1)
        img = sess.film()[..., :3]
        runs[adaptive] = dict(counts=sess.sample_counts(), mse=((img - ref) ** 2).mean())
    plain, adapt = runs[False], runs[True]
    assert (plain["counts"] == 512).all()
    counts = adapt["counts"]  # (H, W), row 0 = bottom; the floor fills the left half
    auto_min = max(16, int(4 / math.sqrt(0.01)))  # Cycles' automatic minimum: 40 here
    assert (counts[:, 27:] == auto_min).all()  # the flat black half stops at the minimum
    assert counts[:, :21].mean() > 2 * auto_min  # the noisy half keeps sampling
    assert counts.max() == 512
    # Same error where it matters, far fewer samples: lower error per unit of work.
    assert adapt["mse"] < 1.1 * plain["mse"]
    assert counts.sum() < 0.6 * plain["counts"].sum()
    efficiency = {k: 1.0 / (r["mse"] * r["counts"].sum()) for k, r in runs.items()}
    assert efficiency[True] > 1.5 * efficiency[False], runs


@needs_lights
@needs_adaptive
def test_adaptive_min_samples_setting():
    scene = soft_shadow_scene(16)
    counts = core_render(scene, samples=128, use_adaptive_sampling=True,
                         adaptive_threshold=0.01, adaptive_min_samples=24).sample_counts()
    assert (counts[:, 10:] == 24).all() and counts.max() > 24


@needs_core
def test_animated_seed_changes_the_noise_per_frame():
    scene = soft_shadow_scene(16)
    scene.render.threads_mode = 'FIXED'
    scene.render.threads = 1
    scene.pathlight.use_animated_seed = True
    frames = []
    for frame in (1, 1, 2):
        scene.frame_set(frame)
        frames.append(render_to_array(scene, samples=2))
    np.testing.assert_array_equal(frames[0], frames[1])
    assert not np.array_equal(frames[0], frames[2])
