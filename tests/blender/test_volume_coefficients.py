"""The Volume Coefficients node (Blender 4.5): absorption, scatter and emission given as
per-channel coefficients per unit length, times the mix weight, with the node's phase
function (Cycles 4.5 svm_node_volume_coefficients). What the compiler makes of it (the same
medium as the equivalent Volume Absorption + Volume Scatter + Emission nodes), renders of it
against those nodes, and against Blender's own Cycles in the same bpy: a homogeneous cube
(Cycles' homogeneous option) and a textured one (null scattering against Cycles' ray
marching, as test_hetero_volumes.py)."""
import time

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, Warnings, core_has, load_addon, render_to_array
from material_scenes import region_means

load_addon()
from addon.export.material import convert_material  # noqa: E402
from addon.export.world import world_volume  # noqa: E402
from test_hetero_volumes import het_scene, needs_het  # noqa: E402
from test_volume_phases import fog_scene, volume_material  # noqa: E402

ABS = (0.3, 0.5, 0.8)
SCAT = (1.4, 1.1, 0.6)
EMIT = (0.12, 0.06, 0.02)


def coefficients(nodes, phase='HENYEY_GREENSTEIN', absorption=ABS, scatter=SCAT, emission=EMIT, **inputs):
    node = nodes.new("ShaderNodeVolumeCoefficients")
    node.phase = phase
    node.inputs["Absorption Coefficients"].default_value = absorption
    node.inputs["Scatter Coefficients"].default_value = scatter
    node.inputs["Emission Coefficients"].default_value = emission
    for key, value in inputs.items():
        node.inputs[key].default_value = value
    return node


def coeff_build(**inputs):
    return lambda nodes, link: coefficients(nodes, **inputs).outputs[0]


def equivalent_nodes(nodes, link, density=2.0, feed=None):
    """Volume Absorption (colour 1 - ABS / d) + Volume Scatter (colour SCAT / d) at density d, and
    an Emission of colour EMIT and strength 1 (times `feed` where given): Cycles' meanings give
    the coefficients of coefficients() (times feed)."""
    ab = nodes.new("ShaderNodeVolumeAbsorption")
    ab.inputs["Color"].default_value = tuple(1.0 - a / density for a in ABS) + (1.0,)
    sc = nodes.new("ShaderNodeVolumeScatter")
    sc.inputs["Color"].default_value = tuple(s / density for s in SCAT) + (1.0,)
    sc.inputs["Anisotropy"].default_value = 0.3
    for n in (ab, sc):
        n.inputs["Density"].default_value = density
    em = nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = EMIT + (1.0,)
    if feed is not None:
        for n in (ab, sc):
            mul = nodes.new("ShaderNodeMath")
            mul.operation = 'MULTIPLY'
            mul.inputs[1].default_value = density
            link(feed(), mul.inputs[0])
            link(mul.outputs[0], n.inputs["Density"])
        link(feed(), em.inputs["Strength"])
    add1, add2 = nodes.new("ShaderNodeAddShader"), nodes.new("ShaderNodeAddShader")
    link(ab.outputs[0], add1.inputs[0])
    link(sc.outputs[0], add1.inputs[1])
    link(add1.outputs[0], add2.inputs[0])
    link(em.outputs[0], add2.inputs[1])
    return add2.outputs[0]


def gradient(nodes, link):
    """A Gradient Texture of Generated coordinates times 2 (0 .. 2 along the cube's x)."""
    coords = nodes.new("ShaderNodeTexCoord")
    grad = nodes.new("ShaderNodeTexGradient")
    link(coords.outputs["Generated"], grad.inputs["Vector"])
    scale = nodes.new("ShaderNodeMath")
    scale.operation = 'MULTIPLY'
    scale.inputs[1].default_value = 2.0
    link(grad.outputs["Fac"], scale.inputs[0])
    return scale.outputs[0]


def textured_coefficients(nodes, link):
    """The coefficients times the gradient (a Vector Math Scale of each)."""
    node = coefficients(nodes, Anisotropy=0.3)
    g = gradient(nodes, link)
    for name, value in (("Absorption Coefficients", ABS), ("Scatter Coefficients", SCAT),
                        ("Emission Coefficients", EMIT)):
        vm = nodes.new("ShaderNodeVectorMath")
        vm.operation = 'SCALE'
        vm.inputs[0].default_value = value
        link(g, vm.inputs["Scale"])
        link(vm.outputs[0], node.inputs[name])
    return node.outputs[0]


def textured_equivalent(nodes, link):
    g = gradient(nodes, link)
    return equivalent_nodes(nodes, link, feed=lambda: g)


def compiled(build):
    w = Warnings()
    data = convert_material(volume_material("M", build), w, None, None, False)
    return data.volume, w


def test_compiler_reads_the_coefficients():
    vol, w = compiled(coeff_build(Anisotropy=0.3))
    assert len(w) == 0, w
    assert vol["sigma_a"] == pytest.approx(ABS) and vol["sigma_s"] == pytest.approx(SCAT)
    assert vol["emission"] == pytest.approx(EMIT) and vol["g"] == pytest.approx(0.3)
    # The same medium as the equivalent Absorption + Scatter + Emission nodes.
    ref, w = compiled(equivalent_nodes)
    assert len(w) == 0, w
    for k in ("sigma_a", "sigma_s", "emission", "g"):
        assert vol[k] == pytest.approx(ref[k]), k


def test_compiler_weights_and_phases():
    # Mix Shader: each coefficient times the mix weight (Fac 0.25 towards the node).
    def mixed(nodes, link):
        mix = nodes.new("ShaderNodeMixShader")
        mix.inputs["Fac"].default_value = 0.25
        link(coefficients(nodes, Anisotropy=0.3).outputs[0], mix.inputs[2])
        return mix.outputs[0]
    vol, w = compiled(mixed)
    assert len(w) == 0, w
    assert vol["sigma_a"] == pytest.approx(np.multiply(ABS, 0.25))
    assert vol["sigma_s"] == pytest.approx(np.multiply(SCAT, 0.25))
    assert vol["emission"] == pytest.approx(np.multiply(EMIT, 0.25))
    # The node's other phases: a lobe of that type with its parameters, as Volume Scatter's.
    cases = {'FOURNIER_FORAND': (dict(Backscatter=0.2, IOR=1.2), "ff", (0.2, 1.2)),
             'DRAINE': (dict(Anisotropy=0.4, Alpha=0.8), "draine", (0.4, 0.8)),
             'RAYLEIGH': ({}, "rayleigh", ()), 'MIE': (dict(Diameter=7.0), "mie", (7.0,))}
    for phase, (inputs, kind, params) in cases.items():
        vol, w = compiled(coeff_build(phase=phase, **inputs))
        assert len(w) == 0, (phase, w)
        (k, ss, p), = vol["phases"]
        assert k == kind and p == pytest.approx(params) and ss == pytest.approx(SCAT), (phase, vol)
    # Negative coefficients mean nothing: 0, with a warning.
    vol, w = compiled(coeff_build(absorption=(-1.0, 0.5, 0.5)))
    assert len(w) == 1 and vol["sigma_a"] == pytest.approx((0.0, 0.5, 0.5))


def test_textured_coefficients_compile_to_a_program_and_world():
    prog, w = compiled(textured_coefficients)
    assert len(w) == 0, w
    assert isinstance(prog, list) and prog[-1][:2] == ("closure", "volume")
    assert set(prog[-1][3]) == {"sigma_a", "sigma_s", "emission", "g"}
    # The world's Volume: homogeneous and textured.
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    out = nodes["World Output"]
    links.new(coefficients(nodes, Anisotropy=0.3).outputs[0], out.inputs["Volume"])
    w = Warnings()
    vol = world_volume(world, w)
    assert len(w) == 0 and vol["sigma_s"] == pytest.approx(SCAT) and vol["sigma_a"] == pytest.approx(ABS), (w, vol)
    links.new(textured_coefficients(nodes, links.new), out.inputs["Volume"])
    prog = world_volume(world, w)
    assert len(w) == 0 and isinstance(prog, list), w


def _compare(ours, ref, what, tol):
    a, b = region_means(ours), region_means(ref)
    rel = np.abs(a - b) / np.maximum(b, 0.25 * b.mean())
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    print(what, "mean ratio", ratio, "worst region", rel.max())
    assert ours.mean() > 0.01
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    assert rel.max() < tol, (np.unravel_index(np.argmax(rel), rel.shape), rel.max())


@needs_het
def test_textured_coefficients_render_as_the_equivalent_nodes():
    """Pathlight against itself: the textured node against Absorption + Scatter + Emission of the
    same gradient (the same medium; the programs differ, so the paths differ by rounding)."""
    a = render_to_array(het_scene(textured_coefficients), samples=256, max_bounces=8)[..., :3]
    b = render_to_array(het_scene(textured_equivalent), samples=256, max_bounces=8)[..., :3]
    _compare(a, b, "coefficients vs nodes", 0.002)  # (measured: 2.4e-7)


@pytest.mark.skipif(not core_has("Scene", "medium_majorants"), reason="no volumes in the core")
def test_homogeneous_coefficients_agree_with_cycles():
    scene = fog_scene(coeff_build(Anisotropy=0.3))
    t0 = time.time()
    ours = render_to_array(scene, samples=2048, max_bounces=8)[..., :3]
    t1 = time.time()
    ref = render_to_array(scene, "CYCLES", samples=2048, max_bounces=8, **BOX_FILTER)[..., :3]
    print(f"pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    _compare(ours, ref, "homogeneous", 0.03)


@needs_het
def test_textured_coefficients_agree_with_cycles():
    scene = het_scene(textured_coefficients)
    t0 = time.time()
    # 2048 against Cycles' 4096 (stored), as test_hetero_volumes.py's gradient: at 1024 each the
    # worst region (the emitting, scattering end of the gradient) was 4.7 % off.
    ours = render_to_array(scene, samples=2048, max_bounces=8)[..., :3]
    t1 = time.time()
    ref = render_to_array(scene, "CYCLES", samples=4096, max_bounces=8, **BOX_FILTER)[..., :3]
    print(f"pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    _compare(ours, ref, "textured", 0.03)
