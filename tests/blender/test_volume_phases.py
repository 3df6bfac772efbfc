"""The Volume Scatter node's phase functions other than Henyey-Greenstein (Fournier-Forand,
Draine, Rayleigh, Mie) and several phase functions in one material (an Add / Mix Shader of
Volume Scatter nodes): what the compiler makes of them, and renders against Blender's own
Cycles in the same bpy (a homogeneous scattering cube on a floor under a point light, as
test_volumes.py)."""
import time

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, Warnings, core_available, load_addon, render_to_array
from light_scenes import add_light, box, camera, diffuse_material, empty_scene, plane
from material_scenes import region_means

load_addon()
from addon.export.material import convert_material  # noqa: E402

needs_phases = pytest.mark.skipif(not (core_available() and hasattr(load_addon().core.get_core(), "sample_phase")),
                                  reason="the core has no phase functions other than Henyey-Greenstein")
SAMPLES = 2048


def volume_material(name, build):
    """A material with only a Volume: build(nodes, link) returns the volume shader's output."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    links.new(build(nodes, links.new), nodes["Material Output"].inputs["Volume"])
    if hasattr(mat.cycles, "homogeneous_volume"):
        mat.cycles.homogeneous_volume = True  # Cycles' analytic homogeneous path
    return mat


def scatter(nodes, phase, color=(0.9, 0.7, 0.5, 1.0), density=1.5, **inputs):
    """A Volume Scatter node of `phase`; its phase's inputs exist only once the phase is set."""
    node = nodes.new("ShaderNodeVolumeScatter")
    node.phase = phase
    node.inputs["Color"].default_value = color
    node.inputs["Density"].default_value = density
    for key, value in inputs.items():
        node.inputs[key].default_value = value
    return node


def one(phase, **inputs):
    return lambda nodes, link: scatter(nodes, phase, **inputs).outputs[0]


def mixture(nodes, link):
    """Mix Shader (Fac 0.4) of HG g 0.7 (density 2) and Rayleigh (density 1.5), grey colours of
    different levels: Cycles 4.5 weights its closures by channel means, which for grey
    scattering is the per-channel mixture we render (docs/design/volumes.md)."""
    a = scatter(nodes, 'HENYEY_GREENSTEIN', (0.9, 0.9, 0.9, 1.0), 2.0, Anisotropy=0.7)
    b = scatter(nodes, 'RAYLEIGH', (0.6, 0.6, 0.6, 1.0), 1.5)
    mix = nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.4
    link(a.outputs[0], mix.inputs[1])
    link(b.outputs[0], mix.inputs[2])
    return mix.outputs[0]


def compiled(build):
    w = Warnings()
    data = convert_material(volume_material("M", build), w, None, None, False)
    return data.volume, w


def test_compiler_passes_each_phase_with_its_parameters():
    vol, w = compiled(one('HENYEY_GREENSTEIN', Anisotropy=0.3))
    assert len(w) == 0 and vol["g"] == pytest.approx(0.3) and "phases" not in vol  # as before
    cases = {
        'FOURNIER_FORAND': (dict(Backscatter=0.2, IOR=1.2), "ff", (0.2, 1.2)),
        'DRAINE': (dict(Anisotropy=0.4, Alpha=0.8), "draine", (0.4, 0.8)),
        'RAYLEIGH': ({}, "rayleigh", ()),
        'MIE': (dict(Diameter=7.0), "mie", (7.0,)),
    }
    for phase, (inputs, kind, params) in cases.items():
        vol, w = compiled(one(phase, **inputs))
        assert len(w) == 0, (phase, w)
        (k, ss, p), = vol["phases"]
        assert k == kind and p == pytest.approx(params), (phase, vol)
        assert ss == pytest.approx((0.9 * 1.5, 0.7 * 1.5, 0.5 * 1.5)) and vol["sigma_s"] == pytest.approx(ss)


def test_compiler_keeps_each_closure_of_a_mixture():
    vol, w = compiled(mixture)
    assert len(w) == 0, w
    assert sorted(vol["phases"]) == [("hg", pytest.approx((1.08,) * 3), pytest.approx((0.7,))),
                                     ("rayleigh", pytest.approx((0.36,) * 3), ())]
    # Two HG closures of different anisotropies: two lobes (no longer one mean g); equal ones merge.
    def two_hg(g2):
        def build(nodes, link):
            add = nodes.new("ShaderNodeAddShader")
            link(scatter(nodes, 'HENYEY_GREENSTEIN', Anisotropy=0.5).outputs[0], add.inputs[0])
            link(scatter(nodes, 'HENYEY_GREENSTEIN', Anisotropy=g2).outputs[0], add.inputs[1])
            return add.outputs[0]
        return build
    vol, w = compiled(two_hg(-0.3))
    assert len(w) == 0 and [p[2] for p in vol["phases"]] == [pytest.approx((0.5,)), pytest.approx((-0.3,))]
    vol, w = compiled(two_hg(0.5))
    assert len(w) == 0 and vol["g"] == pytest.approx(0.5) and "phases" not in vol

    # A program that folds to constants (a constant Blackbody) keeps its lobes in the dict.
    def hot_and_ff(nodes, link):
        pv = nodes.new("ShaderNodeVolumePrincipled")
        pv.inputs["Blackbody Intensity"].default_value = 1.0
        pv.inputs["Anisotropy"].default_value = 0.2
        add = nodes.new("ShaderNodeAddShader")
        link(pv.outputs[0], add.inputs[0])
        link(scatter(nodes, 'FOURNIER_FORAND', density=2.0).outputs[0], add.inputs[1])
        return add.outputs[0]
    vol, w = compiled(hot_and_ff)
    assert len(w) == 0 and isinstance(vol, dict), (w, vol)
    assert sorted((k, p) for k, _, p in vol["phases"]) == [("ff", pytest.approx((0.1, 1.33))),
                                                           ("hg", pytest.approx((0.2,)))]
    assert vol["sigma_s"] == pytest.approx(np.add((0.5,) * 3, (1.8, 1.4, 1.0)))


@needs_phases
def test_varying_volume_compiles_lobes_the_core_renders():
    """A Noise-driven Fournier-Forand density plus a constant Mie: a program whose volume closure
    has a lobe of each (scattering and parameter registers); the core renders it finitely."""
    def build(nodes, link):
        a = scatter(nodes, 'FOURNIER_FORAND', density=2.0, Backscatter=0.3)
        noise = nodes.new("ShaderNodeTexNoise")
        link(noise.outputs["Fac"], a.inputs["Density"])
        add = nodes.new("ShaderNodeAddShader")
        link(a.outputs[0], add.inputs[0])
        link(scatter(nodes, 'MIE', density=1.0, Diameter=3.0).outputs[0], add.inputs[1])
        return add.outputs[0]
    prog, w = compiled(build)
    assert len(w) == 0, w
    assert isinstance(prog, list) and set(prog[-1][3]) == {"ss0", "ff0", "ss1", "mie1"}
    scene = empty_scene(16)
    plane("Floor", 8.0, diffuse_material("Floor", 0.6))
    box("Fog", 1.6, volume_material("V", build), location=(0.0, 0.0, 0.85))
    add_light('POINT', location=(1.6, -1.4, 2.6), energy=400.0)
    camera((0.0, -4.5, 2.2), lens=40.0, look_at=(0.0, 0.0, 0.7))
    img = render_to_array(scene, samples=16, max_bounces=8)[..., :3]
    assert np.all(np.isfinite(img)) and img.mean() > 0.01


def fog_scene(build, size=40):
    scene = empty_scene(size)
    plane("Floor", 8.0, diffuse_material("Floor", 0.6))
    box("Fog", 1.6, volume_material("Fog", build), location=(0.0, 0.0, 0.85), rotation_euler=(0.0, 0.0, 0.5))
    add_light('POINT', location=(1.6, -1.4, 2.6), energy=400.0, shadow_soft_size=0.3)
    camera((0.0, -4.5, 2.2), lens=40.0, look_at=(0.0, 0.0, 0.7))
    return scene


# Parameters whose lobes converge at this budget: Fournier-Forand's forward peak has infinite
# variance under light sampling for B below about 0.2 at IOR 1.33 (its exponent v above -0.5),
# in both engines; Mie at 0.3 um (Cycles' 0.1-1.5 um branch) is less peaked than at 20.
CASES = {
    "fournier_forand": one('FOURNIER_FORAND', Backscatter=0.3, IOR=1.33),
    "draine": one('DRAINE', Anisotropy=0.3, Alpha=1.0),
    "rayleigh": one('RAYLEIGH'),
    "mie": one('MIE', Diameter=0.3),
    "mixture": mixture,
}
# Mie's HG lobe (g 0.65) leaves the dim top edge noisier: 3.0 % worst region at 2048 samples.
# Draine and the mixture: 3.4 % and 3.2 % at 2048 with the shared shadow ray's random numbers
# (one region, seed 0; Draine at seeds 5 and 9: 1.2 % and 1.7 %; means within 0.03 %).
CASE_SAMPLES = {"mie": 3072, "draine": 3072, "mixture": 3072}
# Cycles at 4x (stored: no test time) where its own noise was most of the error: the mixture at
# 3072 against Cycles' 3072 read 1.6-3.2 % over seeds 0-3 (seed 0 failed) and four seeds' mean
# 2.2 %; against 12288 1.1-1.7 %, the mean 0.9 % (docs/design/sampling.md, "The default").
# Mie likewise: four seeds' mean was 2.3 % off Cycles' 3072 in one region ("Blue noise as the
# default").
CYCLES_FACTOR = {"mixture": 4, "mie": 4}


@needs_phases
@pytest.mark.parametrize("case", CASES)
def test_phase_agrees_with_cycles(case):
    scene = fog_scene(CASES[case])
    samples = CASE_SAMPLES.get(case, SAMPLES)
    t0 = time.time()
    ours = render_to_array(scene, samples=samples, max_bounces=8)[..., :3]
    t1 = time.time()
    ref = render_to_array(scene, "CYCLES", samples=samples * CYCLES_FACTOR.get(case, 1), max_bounces=8,
                          **BOX_FILTER)[..., :3]
    print(f"pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    a, b = region_means(ours), region_means(ref)
    floor = 0.25 * b.mean()  # as test_volumes.py: dim silhouette regions held to a quarter of the mean
    rel = np.abs(a - b) / np.maximum(b, floor)
    worst = np.unravel_index(np.argmax(rel), rel.shape)
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    print(case, "mean ratio", ratio, "worst region", rel.max())
    assert ours[14:26, 14:26].mean() > 0.05  # lit fog
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    assert rel.max() < 0.03, (worst, a[worst], b[worst])


def varying_mixture(nodes, link):
    """A Gradient Texture on Generated coordinates times 3 as the density of Draine (grey 0.9,
    g 0.5, alpha 1) and Fournier-Forand (grey 0.6, B 0.3) closures added: a volume program of
    two lobes."""
    coords = nodes.new("ShaderNodeTexCoord")
    grad = nodes.new("ShaderNodeTexGradient")
    link(coords.outputs["Generated"], grad.inputs["Vector"])
    scale = nodes.new("ShaderNodeMath")
    scale.operation = 'MULTIPLY'
    scale.inputs[1].default_value = 3.0
    link(grad.outputs["Fac"], scale.inputs[0])
    feed = scale.outputs[0]
    a = scatter(nodes, 'DRAINE', (0.9, 0.9, 0.9, 1.0), 1.0, Anisotropy=0.5, Alpha=1.0)
    b = scatter(nodes, 'FOURNIER_FORAND', (0.6, 0.6, 0.6, 1.0), 1.0, Backscatter=0.3)
    link(feed, a.inputs["Density"])
    link(feed, b.inputs["Density"])
    add = nodes.new("ShaderNodeAddShader")
    link(a.outputs[0], add.inputs[0])
    link(b.outputs[0], add.inputs[1])
    return add.outputs[0]


@needs_phases
def test_varying_mixture_of_phases_agrees_with_cycles():
    """The program path (delta tracking, lobes per point) against Cycles' ray marching (as
    test_hetero_volumes.py: Volume Step Rate 0.3)."""
    from test_hetero_volumes import het_scene
    scene = het_scene(varying_mixture)
    prog, w = compiled(varying_mixture)
    assert isinstance(prog, list) and len(w) == 0
    t0 = time.time()
    # Pathlight at 2048 spp, Cycles at 4096 (stored: no test time). Both at 1024: 2.0-4.0 % over
    # seeds 0-5 with the 4-D sets, the mean of the six 1.8 % off Cycles' own noise; 2048 against
    # 4096 (two seeds' mean): 1.6-2.2 % (docs/design/sampling.md, "The default").
    ours = render_to_array(scene, samples=2048, max_bounces=8)[..., :3]
    t1 = time.time()
    ref = render_to_array(scene, "CYCLES", samples=4096, max_bounces=8, **BOX_FILTER)[..., :3]
    print(f"pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    a, b = region_means(ours), region_means(ref)
    rel = np.abs(a - b) / np.maximum(b, 0.25 * b.mean())
    worst = np.unravel_index(np.argmax(rel), rel.shape)
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    print("varying mixture: mean ratio", ratio, "worst region", rel.max())
    assert ours.mean() > 0.01
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    assert rel.max() < 0.03, (worst, a[worst], b[worst])
