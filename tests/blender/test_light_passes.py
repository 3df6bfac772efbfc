"""Cycles' light-component passes, Mist and AO through headless Blender, against Cycles' own
passes of the same scene (64x48: a diffuse floor and wall, a glossy, a glass and a fog sphere
under a sun and an area light).

Tolerances from measured noise: at 256 spp, Cycles against itself (two seeds) differs by up to
0.8 % in the mean of a component (as light, i.e. times its colour) and 6 % of Combined's mean in
an 8x8 region (glints of the lights in the smooth glass, where the Glossy Color is 0.03: the
divided passes are far noisier there, so the light is compared before the division and the
colours on their own). At 512 spp the region noise is about 4.5 %: regions within 5 % of
Combined's mean and means within 2 %."""
import math

import bpy
import numpy as np
import pytest

from blender_util import (core_available, core_has, empty_scene_with_camera, load_addon, node_material,
                          render_multilayer_file)
from light_scenes import world_color

addon = load_addon()

pytestmark = [pytest.mark.skipif(not core_available(), reason="pathlight_core is not built"),
              pytest.mark.skipif(not core_has("RenderSettings", "mist_start"), reason="core without light passes")]

LIGHT = ["DiffDir", "DiffInd", "DiffCol", "GlossDir", "GlossInd", "GlossCol",
         "TransDir", "TransInd", "TransCol", "VolumeDir", "VolumeInd"]
COLOURS = {"DiffCol", "GlossCol", "TransCol"}


def sphere(name, location, radius, material):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24, radius=radius, location=location)
    obj = bpy.context.active_object
    obj.name = name
    bpy.ops.object.shade_smooth()
    obj.data.materials.append(material)
    return obj


def plane(name, size, location, rotation, material):
    bpy.ops.mesh.primitive_plane_add(size=size, location=location, rotation=rotation)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.materials.append(material)
    return obj


def mixed_scene():
    sc = empty_scene_with_camera(64)
    sc.render.resolution_y = 48
    sc.camera.location = (0.0, -6.0, 1.2)
    sc.camera.rotation_euler = (math.radians(82), 0.0, 0.0)
    plane("Floor", 12, (0, 0, -1), (0, 0, 0), node_material("Floor", "ShaderNodeBsdfDiffuse", Color=(0.6, 0.6, 0.6, 1)))
    plane("Wall", 12, (0, 3, 2), (math.pi / 2, 0, 0),
          node_material("Wall", "ShaderNodeBsdfDiffuse", Color=(0.7, 0.4, 0.3, 1)))
    sphere("Glossy", (-1.6, 0.5, 0.0), 0.9,
           node_material("Glossy", "ShaderNodeBsdfGlossy", Color=(0.9, 0.8, 0.5, 1), Roughness=0.3))
    sphere("Glass", (0.2, -0.8, -0.3), 0.7, node_material("Glass", "ShaderNodeBsdfGlass", Color=(1, 1, 1, 1),
                                                           Roughness=0.0, IOR=1.45))
    fog = node_material("Fog", "ShaderNodeVolumePrincipled", socket="Volume", Density=1.5)
    sphere("Fog", (1.8, 0.6, 0.1), 0.9, fog)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.data.energy = 2.5
    sun.data.angle = math.radians(12)  # a soft sun: its glints in the smooth glass are not fireflies
    sun.rotation_euler = (math.radians(35), math.radians(20), 0)
    sc.collection.objects.link(sun)
    area = bpy.data.objects.new("Area", bpy.data.lights.new("Area", 'AREA'))
    area.data.energy = 300.0
    area.data.size = 3.0  # large and dim: its reflection in the glass is no firefly either
    area.location = (2.5, -2.5, 3.0)
    area.rotation_euler = (math.radians(45), 0, math.radians(45))
    sc.collection.objects.link(area)
    for i, name in enumerate(("Floor", "Wall", "Glossy", "Glass", "Fog")):
        obj = bpy.data.objects[name]
        obj.pass_index = 10 + i
        obj.active_material.pass_index = 20 + 2 * i
    world_color((0.05, 0.07, 0.1))
    world = sc.world
    world.mist_settings.start, world.mist_settings.depth, world.mist_settings.falloff = 2.0, 8.0, 'LINEAR'
    world.light_settings.distance = 1.5
    return sc


def enable(view_layer, names):
    vl = view_layer
    for kind, short in (("diffuse", "Diff"), ("glossy", "Gloss"), ("transmission", "Trans")):
        for part, suffix in (("direct", "Dir"), ("indirect", "Ind"), ("color", "Col")):
            setattr(vl, f"use_pass_{kind}_{part}", short + suffix in names)
    vl.pathlight.use_pass_volume_direct = vl.cycles.use_pass_volume_direct = "VolumeDir" in names
    vl.pathlight.use_pass_volume_indirect = vl.cycles.use_pass_volume_indirect = "VolumeInd" in names
    vl.use_pass_mist = "Mist" in names
    vl.use_pass_ambient_occlusion = "AO" in names
    vl.use_pass_object_index = "IndexOB" in names
    vl.use_pass_material_index = "IndexMA" in names
    vl.use_pass_emit = vl.use_pass_environment = True


def render_passes(sc, engine, path, samples, seed=1):
    """Every channel of the multilayer EXR that Blender writes: {"<pass>.<channel>": (H, W)}."""
    sc.render.engine = engine
    if engine == 'CYCLES':
        c = sc.cycles
        c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = 'CPU', samples, False, False
        c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
        c.blur_glossy = 0.0
        c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = 12
        c.volume_bounces = c.transparent_max_bounces = 12
        c.pixel_filter_type, c.filter_width = 'BOX', 1.0
        c.seed = seed
    else:
        p = sc.pathlight
        p.seed = seed
        p.samples, p.use_adaptive_sampling, p.max_bounces = samples, False, 12
        p.diffuse_bounces = p.glossy_bounces = p.transmission_bounces = p.volume_bounces = 12
        p.transparent_bounces = 12
        p.filter_type, p.filter_width = 'BOX', 1.0
    return render_multilayer_file(sc, path)


def rgb(ch, name):
    return np.stack([ch[f"{name}.{c}"] for c in "RGB"], -1)


SAMPLES = 512


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    sc = mixed_scene()
    enable(sc.view_layers[0], LIGHT + ["Mist", "AO", "IndexOB", "IndexMA"])
    tmp = tmp_path_factory.mktemp("light_passes")
    return (render_passes(sc, 'PATHLIGHT', tmp / "pathlight.exr", SAMPLES),
            render_passes(sc, 'CYCLES', tmp / "cycles.exr", SAMPLES))


def light(ch, name):
    """A component as light (times its colour): what adds up to Combined."""
    colour = {"Diff": "DiffCol", "Gloss": "GlossCol", "Trans": "TransCol"}.get(name[:-3])
    return rgb(ch, name) * (rgb(ch, colour) if colour else 1.0)


def regions(img):
    h, w = img.shape[:2]
    return img.reshape(h // 8, 8, w // 8, 8, -1).mean(axis=(1, 3))


def test_exr_channels_are_cycles(both):
    ours, cycles = both
    assert set(ours) == set(cycles)  # DiffDir.R ... Mist.Z, AO.R ...
    assert {"DiffDir.R", "VolumeInd.B", "Mist.Z", "AO.G", "TransCol.B", "IndexOB.X", "IndexMA.X"} <= set(ours)


@pytest.mark.parametrize("name", ["DiffDir", "DiffInd", "GlossDir", "GlossInd", "TransInd", "VolumeDir", "VolumeInd"])
def test_component_agrees_with_cycles(both, name):
    ours, cycles = both
    a, b = light(ours, name), light(cycles, name)
    combined = rgb(cycles, "Combined").mean()
    assert b.mean() > 0.02 * combined  # a component that is there
    assert abs(a.mean() / b.mean() - 1.0) < 0.02, (a.mean(), b.mean())
    worst = np.abs(regions(a) - regions(b)).max() / combined
    assert worst < 0.05, worst


def test_smooth_glass_has_no_direct_transmission(both):
    # Light samples cannot pass smooth glass, and what refracts first reaches a lamp only after
    # leaving the sphere again: a bounce later (Cycles' TransDir is 0 here too).
    ours, cycles = both
    assert light(ours, "TransDir").max() == 0.0 and light(cycles, "TransDir").max() == 0.0


@pytest.mark.parametrize("name", ["DiffCol", "GlossCol", "TransCol", "AO"])
def test_colours_and_ao_agree_with_cycles(both, name):
    ours, cycles = both
    a, b = rgb(ours, name), rgb(cycles, name)
    assert abs(a.mean() / b.mean() - 1.0) < 0.01
    assert np.abs(regions(a) - regions(b)).max() / b.mean() < 0.03


def test_mist_per_pixel(both):
    ours, cycles = both
    a, b = ours["Mist.Z"], cycles["Mist.Z"]
    assert 0.2 < b.mean() < 0.95  # the scene spans the mist's start and depth
    diff = np.abs(a - b)
    # Pixels on silhouettes mix what their samples saw, in different places in the two engines.
    assert np.median(diff) < 1e-3 and np.mean(diff > 0.01) < 0.03, (np.median(diff), np.mean(diff > 0.01))


def test_combined_matches_components_in_blender(both):
    ours, _ = both
    total = rgb(ours, "Emit") + rgb(ours, "Env")
    for name in ("DiffDir", "DiffInd", "GlossDir", "GlossInd", "TransDir", "TransInd", "VolumeDir", "VolumeInd"):
        total = total + light(ours, name)
    np.testing.assert_allclose(total, rgb(ours, "Combined"), rtol=1e-3, atol=1e-4)


@pytest.mark.parametrize("name", ["IndexOB.X", "IndexMA.X"])
def test_indices_per_pixel(both, name):
    ours, cycles = both
    a, b = ours[name], cycles[name]
    # The fog sphere has no surface: both see what lies behind it.
    assert set(np.unique(b)) >= ({10.0, 11.0, 12.0, 13.0} if name == "IndexOB.X" else {20.0, 22.0, 24.0, 26.0})
    assert set(np.unique(a)) <= set(np.unique(b)) | {0.0}  # ids, never averages
    # Each engine keeps its first sample's, at its own place in the pixel: pixels on silhouettes
    # may differ (4.4 % here), but only to an id that Cycles has in a neighbouring pixel. Behind
    # the fog a first sample that scatters sees no surface (0) in both: those are left out.
    assert np.mean(a != b) < 0.08, np.mean(a != b)
    padded = np.pad(b, 1, mode="edge")
    near = np.stack([padded[1 + dy:1 + dy + b.shape[0], 1 + dx:1 + dx + b.shape[1]]
                     for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    solid = ~(near == 0.0).any(axis=0)
    assert solid.mean() > 0.8
    assert np.all((near == a).any(axis=0)[solid])


# Principled BSDF spheres for the colour passes (Cycles' bsdf_albedo: the microfacet lobes'
# albedo estimated from the view, docs/design/passes.md): (name, inputs).
PRINCIPLED = [
    ("Spec", {"Base Color": (0.8, 0.3, 0.2, 1), "Roughness": 0.5, "IOR": 1.5}),
    ("SpecTint", {"Base Color": (0.2, 0.4, 0.8, 1), "Roughness": 0.2, "IOR": 1.8,
                  "Specular Tint": (0.9, 0.5, 0.3, 1)}),
    ("Metal", {"Base Color": (0.9, 0.6, 0.3, 1), "Metallic": 1.0, "Roughness": 0.4}),
    ("MetalTint", {"Base Color": (0.7, 0.7, 0.8, 1), "Metallic": 0.6, "Roughness": 0.3,
                   "Specular Tint": (0.6, 0.9, 0.5, 1)}),
    ("Coat", {"Base Color": (0.3, 0.6, 0.3, 1), "Roughness": 0.6, "Coat Weight": 1.0,
              "Coat Roughness": 0.1, "Coat IOR": 1.6}),
    ("Glass", {"Base Color": (0.9, 0.8, 0.6, 1), "Transmission Weight": 1.0, "Roughness": 0.3,
               "IOR": 1.45}),
    ("Sheen", {"Base Color": (0.5, 0.2, 0.6, 1), "Roughness": 0.7, "Sheen Weight": 1.0,
               "Sheen Roughness": 0.4, "Sheen Tint": (0.9, 0.9, 0.6, 1)}),
]


def principled_scene():
    """A row of Principled spheres, one per PRINCIPLED entry, seen from the front, no floor."""
    sc = empty_scene_with_camera(96)
    sc.render.resolution_y = 32
    sc.camera.location = (0.0, -9.0, 0.0)
    sc.camera.rotation_euler = (math.radians(90), 0.0, 0.0)
    for i, (name, inputs) in enumerate(PRINCIPLED):
        mat = bpy.data.materials.new(name)
        mat.use_nodes = True
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        for key, value in inputs.items():
            bsdf.inputs[key].default_value = value
        sphere(name, (-3.0 + i, 0.0, 0.0), 0.45, mat)
    world_color((0.5, 0.5, 0.5))
    return sc


@pytest.fixture(scope="module")
def principled_pair(tmp_path_factory):
    sc = principled_scene()
    enable(sc.view_layers[0], ["DiffCol", "GlossCol", "TransCol"])
    sc.render.film_transparent = True
    tmp = tmp_path_factory.mktemp("principled_colours")
    return (render_passes(sc, 'PATHLIGHT', tmp / "pathlight.exr", 16),
            render_passes(sc, 'CYCLES', tmp / "cycles.exr", 16))


@pytest.mark.parametrize("name", ["DiffCol", "GlossCol", "TransCol"])
def test_principled_colours_match_cycles(principled_pair, name):
    """Each sphere's colour pass per pixel (pixels inside its silhouette; the box filter's 16
    jittered samples differ between the engines, so a pixel is its samples' mean colour: the
    Diffuse Color, the same in both, differs by a median of 2e-5 per sphere). Measured medians
    of |diff| per sphere: Glossy Color 6e-6 (Metal) to 5.5e-5 (Coat), Transmission Color 2.4e-5
    (Glass); before Cycles' albedo estimates (the Fresnel at the view, the 1 / E of the
    compensation kept): Spec 2.5e-3 (0.0459 against 0.0430), Coat 5.9e-3, Sheen's specular
    1.2e-2, SpecTint 2.3e-4, Metal 3.0e-4, MetalTint 3.9e-4, Glass 7.6e-4 and 1.45e-3."""
    ours, cycles = principled_pair
    inside = (ours["Combined.A"] >= 1.0) & (cycles["Combined.A"] >= 1.0)
    inside[1:-1, 1:-1] &= inside[:-2, 1:-1] & inside[2:, 1:-1] & inside[1:-1, :-2] & inside[1:-1, 2:]
    a, b = rgb(ours, name), rgb(cycles, name)
    cols = np.arange(a.shape[1])
    report, worst = [], {}
    for i, (sphere_name, _) in enumerate(PRINCIPLED):
        centre = (i + 0.5) * a.shape[1] / len(PRINCIPLED)
        sel = inside & (np.abs(cols - centre) < a.shape[1] / len(PRINCIPLED) / 2)[None, :]
        if not sel.any():
            continue
        d = np.abs(a[sel] - b[sel])
        scale = max(float(b[sel].mean()), 1e-3)
        worst[sphere_name] = (float(np.median(d)), float(d.max()), scale)
        report.append(f"{sphere_name}: median {np.median(d):.2e}, max {d.max():.2e}, mean {b[sel].mean():.4f}"
                      f" / ours {a[sel].mean():.4f}")
    print(f"\n{name}: " + "; ".join(report))
    assert len(worst) == len(PRINCIPLED)
    for sphere_name, (median, _, scale) in worst.items():
        assert median < 1e-4 + 2.5e-4 * scale, (sphere_name, median, scale)
