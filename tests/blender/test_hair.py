"""Hair (Curves objects) against Cycles in the same bpy (issue 23): a patch of thick, gently
sagging strands above a floor under an area light, rendered by both engines with Cycles'
3D curves (shape THICK), compared by the whole-image mean and 8x8 region means."""

import functools
import math

import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()
render_pair = ms.render_pair
assert_agree = functools.partial(ms.assert_agree, floor=0.05)

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def add_hair(name, material, strands=7, keys=5, radius=0.05, length=3.0, sag=0.15,
             spacing=0.16, curve_type=None, radii=None):
    """A Curves object: `strands` strands along x (ends outside the frame), side by side in y,
    each sagging by `sag` in the middle, keys Catmull-Rom keys each."""
    curves = bpy.data.hair_curves.new(name)
    curves.add_curves([keys] * strands)
    x = np.linspace(-length / 2, length / 2, keys)
    pts = []
    for s in range(strands):
        y = (s - (strands - 1) / 2) * spacing
        z = 0.5 - sag * (1.0 - (2.0 * x / length) ** 2) + 0.03 * math.sin(s)
        pts.append(np.stack([x, np.full(keys, y), z], 1))
    pts = np.concatenate(pts).astype(np.float32)
    curves.attributes["position"].data.foreach_set("vector", pts.ravel())
    r = curves.attributes.new("radius", 'FLOAT', 'POINT')
    r.data.foreach_set("value", np.full(len(pts), radius, np.float32) if radii is None else radii)
    if curve_type is not None:
        curves.set_types(type=curve_type)
    curves.materials.append(material)
    obj = bpy.data.objects.new(name, curves)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def hair_scene(material_fn, size=48, **hair):
    def build():
        scene = ms.studio(size=size, world=(0.05, 0.05, 0.05), light_strength=8.0, light_size=2.0,
                          camera=((0.0, -2.2, 1.6), (0.0, 0.0, 0.45)), lens=50.0)
        scene.cycles_curves.shape = 'THICK'
        add_hair("Hair", material_fn(), **hair)
        return scene
    return build


def test_hair_export_arrays():
    """The exporter reads the strands with foreach_get: points, offsets, radii, curve type."""
    from addon.export.curves import collect_curves
    ms.studio(size=16)
    add_hair("Hair", ms.diffuse("H", (0.5, 0.5, 0.5)), strands=3, keys=4, curve_type='POLY',
             radii=np.linspace(0.01, 0.05, 12).astype(np.float32))
    warn = Warnings()
    data = collect_curves(bpy.context.evaluated_depsgraph_get(), warn)
    assert len(data) == 1 and not warn
    c = data[0]
    assert c.points.shape == (12, 3) and c.offsets.tolist() == [0, 4, 8, 12]
    np.testing.assert_allclose(c.radii, np.linspace(0.01, 0.05, 12), rtol=1e-6)
    assert c.curve_type == 'poly' and len(c.matrices) == 1


def test_huang_material_exports_curve_normals():
    """Only a material with Huang hair makes the exporter read Blender's curve normals (the
    ellipse's major axis): unit vectors, here across the strands' vertical planes, also for
    the first point (which bpy 4.5's foreach_get returns as garbage)."""
    from addon.export.curves import collect_curves
    ms.studio(size=16)
    add_hair("Hair", principled_hair("H", 'MELANIN', model='HUANG'), strands=3, keys=4)
    (c,) = collect_curves(bpy.context.evaluated_depsgraph_get(), Warnings())
    assert c.normals.shape == (12, 3)
    np.testing.assert_allclose(np.abs(c.normals), [[0.0, 1.0, 0.0]] * 12, atol=1e-5)
    ms.studio(size=16)
    add_hair("Hair", principled_hair("H", 'MELANIN'), strands=3, keys=4)
    (c,) = collect_curves(bpy.context.evaluated_depsgraph_get(), Warnings())
    assert c.normals is None


def test_bad_strands_warn_and_render():
    """NaN points and zero radii: one warning, the other strands still render."""
    ms.studio(size=16)
    obj = add_hair("Hair", ms.diffuse("H", (0.5, 0.5, 0.5)), strands=4, keys=3)
    pos = np.empty(12 * 3, np.float32)
    obj.data.attributes["position"].data.foreach_get("vector", pos)
    pos[3 * 1] = np.nan  # strand 0
    obj.data.attributes["position"].data.foreach_set("vector", pos)
    rad = np.full(12, 0.05, np.float32)
    rad[6:9] = 0.0  # strand 2
    obj.data.attributes["radius"].data.foreach_set("value", rad)
    from addon.export.curves import collect_curves
    warn = Warnings()
    collect_curves(bpy.context.evaluated_depsgraph_get(), warn)
    assert len(warn) == 1 and "2 of 4 strands" in warn[0]
    img = render_to_array(bpy.context.scene, "PATHLIGHT", samples=2)
    assert np.isfinite(img).all()


def test_object_attributes_on_curves_export_without_warning():
    """Object attributes on a Curves object are per-object slots of the curves (as of meshes'
    instances): the export resolves them and warns about nothing (it used to warn that they
    read 0; their values against Cycles: test_object_attributes.py)."""
    from addon.export import export_scene
    ms.studio(size=16)
    mat, nodes, links, out = ms.new_material("CurvesAttr")
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_type, attr.attribute_name = 'OBJECT', "tint"
    em = nodes.new("ShaderNodeEmission")
    links.new(attr.outputs["Color"], em.inputs["Color"])
    links.new(em.outputs[0], out.inputs["Surface"])
    obj = add_hair("Hair", mat, strands=3, keys=4)
    obj["tint"] = (0.25, 0.5, 0.75)
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    assert not warn, list(warn)
    (c,) = data.curves
    assert data.uv_sets.object_attributes == [('OBJECT', "tint")]
    assert len(c.object_attributes) == 1
    np.testing.assert_allclose(c.object_attributes[0], [[0.25, 0.5, 0.75, 1.0]])


def test_diffuse_hair_matches_cycles():
    ours, cycles = render_pair(hair_scene(lambda: ms.diffuse("Hair", (0.8, 0.5, 0.3))), 256)
    assert_agree(ours, cycles)


def principled_hair(name, parametrization='COLOR', model='CHIANG', **inputs):
    mat, nodes, links, out = ms.new_material(name)
    node = nodes.new("ShaderNodeBsdfHairPrincipled")
    node.model = model  # first: the other model's and modes' inputs are hidden
    node.parametrization = parametrization
    ms.set_inputs(node, **inputs)
    links.new(node.outputs[0], out.inputs["Surface"])
    return mat


# Moderately rough hair: the glossy lobes' noise at 1024 samples stays below ~2 % per region.
@pytest.mark.parametrize("case", [
    ("COLOR", dict(Color=(0.6, 0.35, 0.2, 1.0), Roughness=0.45, Radial_Roughness=0.5, IOR=1.45,
                   Offset=0.06)),
    ("MELANIN", dict(Melanin=0.3, Melanin_Redness=0.6, Roughness=0.4, Coat=0.3)),
], ids=lambda c: c[0].lower())
def test_principled_hair_matches_cycles(case):
    mode, inputs = case
    ours, cycles = render_pair(hair_scene(lambda: principled_hair("Hair", mode, **inputs)), 1024)
    assert_agree(ours, cycles)


def hdr_world():
    """An HDR environment (light_scenes.synthetic_hdr: sky, ground, a sun) at a strength that
    leaves the area light the main light."""
    from light_scenes import load_image, synthetic_hdr, world_image
    world_image(load_image(synthetic_hdr(64, 32, sun_peak=40.0), name="hair_env"), strength=0.15)


def huang_scene(mode, inputs, size=48):
    base = hair_scene(lambda: principled_hair("Hair", mode, model='HUANG', **inputs), size=size)

    def build():
        scene = base()
        hdr_world()
        return scene
    return build


# Huang's model against Cycles under the area light and an HDR-ish sky: round fibres with
# Direct Coloring, and elliptical ones (Aspect Ratio 0.85, major axis along Blender's curve
# normals) with Melanin and uneven lobe weights. The worst region is noise: round fibres 3.0 %
# at 1024 samples, 2.2 % at 3072 (mean 1.0023 both), hence 1536; the ellipse 2.1 % at 1024.
@pytest.mark.parametrize("case", [
    ("COLOR", 1536, dict(Color=(0.6, 0.35, 0.2, 1.0), Roughness=0.4, IOR=1.55, Offset=0.05, Aspect_Ratio=1.0)),
    ("MELANIN", 1024, dict(Melanin=0.3, Melanin_Redness=0.6, Roughness=0.35, Aspect_Ratio=0.85,
                           Transmission=0.7, Secondary_Reflection=1.3)),
], ids=["color-round", "melanin-ellipse"])
def test_huang_hair_matches_cycles(case):
    mode, samples, inputs = case
    ours, cycles = render_pair(huang_scene(mode, inputs), samples)
    assert_agree(ours, cycles, what=f"Huang {mode}")


def test_huang_ellipse_needs_the_curve_normals():
    """The ellipse's major axis follows Blender's curve normals (here across the strands'
    vertical planes): without them (the tangent's arbitrary basis, Cycles' fallback) the
    silhouettes of an opaque elliptical fibre differ; with them the renders agree."""
    from addon.export import curves as curves_export
    inputs = dict(Absorption_Coefficient=(30.0, 30.0, 30.0), Roughness=0.4, Offset=0.0, Aspect_Ratio=0.6)
    build = huang_scene("ABSORPTION", inputs, size=32)
    # Cycles at 4x (stored: no test time): against its 1024 the mean of 44 seeds' renders was
    # itself 3.0 % off in one region (Cycles' noise), so seeds failed 5 % there by chance
    # (docs/design/sampling.md "Blue noise as the default").
    ours, cycles = render_pair(build, 1024, cycles_samples=4096)
    assert_agree(ours, cycles, what="opaque ellipse", region=0.05, whole=0.02)
    saved = curves_export.curve_normals
    curves_export.curve_normals = lambda curves: None
    try:
        without = render_to_array(build(), "PATHLIGHT", samples=256, max_bounces=16)
    finally:
        curves_export.curve_normals = saved
    ratio, worst, _ = ms.compare(without, cycles, floor=0.05)
    print(f"without the normals: mean ratio {ratio:.4f}, worst region {worst:.4f}")
    assert worst > 0.1, worst


def curves_info_material(name):
    """Emission coloured by Curves Info: Intercept, Random and Thickness (x 10) as R, G, B."""
    mat, nodes, links, out = ms.new_material(name)
    info = nodes.new("ShaderNodeHairInfo")
    comb = nodes.new("ShaderNodeCombineXYZ")
    scale = nodes.new("ShaderNodeMath")
    scale.operation = 'MULTIPLY'
    scale.inputs[1].default_value = 10.0
    links.new(info.outputs["Thickness"], scale.inputs[0])
    links.new(info.outputs["Intercept"], comb.inputs["X"])
    links.new(info.outputs["Random"], comb.inputs["Y"])
    links.new(scale.outputs[0], comb.inputs["Z"])
    em = nodes.new("ShaderNodeEmission")
    links.new(comb.outputs[0], em.inputs["Color"])
    links.new(em.outputs[0], out.inputs["Surface"])
    return mat


def unlit(build):
    """build's studio with its light and floor hidden and a black world: an emission material's
    colour seen directly (also the particle hair tests' scenes)."""
    def dark():
        scene = build()
        for name in ("Light", "Floor"):
            bpy.data.objects[name].hide_render = True
        ms.set_world((0.0, 0.0, 0.0))
        return scene
    return dark


def assert_channels_agree(ours, cycles, channels=3):
    """Each colour channel (one material output each) alone, as grey, within the issue's bar."""
    for c in range(channels):
        assert_agree(ours[..., [c, c, c, 3]], cycles[..., [c, c, c, 3]], region=0.03, floor=0.1)


def test_curves_info_matches_cycles():
    """Intercept (root to tip), per-strand Random (Cycles' hash) and Thickness, seen directly,
    on tapering strands."""
    radii = np.tile(np.linspace(0.06, 0.03, 5), 7).astype(np.float32)
    ours, cycles = render_pair(unlit(hair_scene(lambda: curves_info_material("Info"), radii=radii)), 64)
    assert_channels_agree(ours, cycles)


def test_particle_hair_is_exported_without_a_warning():
    """Particle hair used to be only warned about (convert it); now it becomes curves (its
    tests: test_particle_hair.py)."""
    from addon.export.curves import collect_curves
    ms.studio(size=16)
    emitter = bpy.data.objects["Floor"]
    mod = emitter.modifiers.new("Hair", 'PARTICLE_SYSTEM')
    mod.particle_system.settings.type = 'HAIR'
    mod.particle_system.settings.count = 10
    warn = Warnings()
    (c,) = collect_curves(bpy.context.evaluated_depsgraph_get(), warn)
    assert not warn, list(warn)
    assert c.name == "Floor" and len(c.offsets) == 11


def test_object_info_on_curves_matches_cycles():
    """Object Info on a Curves object: its Random, Color and Location, as on meshes."""
    def material():
        mat, nodes, links, out = ms.new_material("ObjInfo")
        info = nodes.new("ShaderNodeObjectInfo")
        sep = nodes.new("ShaderNodeSeparateXYZ")
        comb = nodes.new("ShaderNodeCombineXYZ")
        links.new(info.outputs["Location"], sep.inputs[0])
        links.new(info.outputs["Random"], comb.inputs["X"])
        links.new(info.outputs["Alpha"], comb.inputs["Y"])
        links.new(sep.outputs["Z"], comb.inputs["Z"])
        em = nodes.new("ShaderNodeEmission")
        links.new(comb.outputs[0], em.inputs["Color"])
        links.new(em.outputs[0], out.inputs["Surface"])
        return mat

    def build():
        scene = hair_scene(material)()
        obj = bpy.data.objects["Hair"]
        obj.location = (0.0, 0.0, 0.3)
        obj.color = (0.2, 0.4, 0.6, 0.7)
        return scene
    ours, cycles = render_pair(unlit(build), 16)
    assert_channels_agree(ours, cycles)


def test_principled_hair_on_a_mesh_renders():
    """On a mesh (no fibre) an arbitrary tangent of the normal stands in: finite and lit."""
    ms.studio(size=16)
    ms.add_sphere("Ball", 0.5, principled_hair("H", 'COLOR', Color=(0.6, 0.35, 0.2, 1.0)),
                  location=(0.0, 0.0, 0.5))
    img = render_to_array(bpy.context.scene, "PATHLIGHT", samples=8)
    assert np.isfinite(img).all()
    assert img[4:12, 4:12, :3].mean() > 0.0


def hair_bsdf_material(name, transmission_fac=0.5, tangent=False, **inputs):
    """Cycles' Hair BSDF as artists use it: its Reflection and Transmission components mixed."""
    mat, nodes, links, out = ms.new_material(name)
    refl, trans = nodes.new("ShaderNodeBsdfHair"), nodes.new("ShaderNodeBsdfHair")
    trans.component = 'Transmission'
    for node in (refl, trans):
        ms.set_inputs(node, **inputs)
    if tangent:  # the Tangent input linked: a fixed direction across the strands
        tan = nodes.new("ShaderNodeCombineXYZ")
        tan.inputs["X"].default_value, tan.inputs["Y"].default_value = 0.3, 1.0
        links.new(tan.outputs[0], refl.inputs["Tangent"])
        links.new(tan.outputs[0], trans.inputs["Tangent"])
    mix = nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = transmission_fac
    links.new(refl.outputs[0], mix.inputs[1])
    links.new(trans.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


@pytest.mark.parametrize("case", [
    ("defaults", dict(Color=(0.7, 0.45, 0.25, 1.0))),
    ("rough-offset", dict(Color=(0.5, 0.6, 0.8, 1.0), RoughnessU=0.35, RoughnessV=0.4, Offset=0.12)),
    ("tangent", dict(Color=(0.8, 0.8, 0.7, 1.0), RoughnessU=0.25, RoughnessV=0.6, tangent=True)),
], ids=lambda c: c[0])
def test_hair_bsdf_matches_cycles(case):
    """The Hair BSDF node (issue 23): Cycles' sample-versus-evaluation pairing included (its
    reflection samples beyond 90 degrees of azimuth and behind N carry their sample's value)."""
    _, inputs = case
    ours, cycles = render_pair(hair_scene(lambda: hair_bsdf_material("Hair", **inputs)), 1024)
    assert_agree(ours, cycles)


def test_hair_bsdf_exports_without_a_warning():
    from addon.export import export_scene
    ms.studio(size=16)
    add_hair("Hair", hair_bsdf_material("HairNode"), strands=3, keys=4)
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    assert not warn, list(warn)
    (mat,) = [m for m in data.materials if m.name == "HairNode"]
    kinds = sorted(op[1] for op in mat.program if op[0] == "closure")
    assert kinds == ["hair_reflection", "hair_transmission"]


def test_hair_bsdf_on_meshes_matches_cycles():
    """On meshes Cycles' fibre is the triangle's dPdv (corner 2 - corner 0 of Blender's
    triangulation, which the core reproduces) with the Offset dropped, and N faces the view on
    back faces (the tilted plane is seen from behind; the sphere's inside from its refractions)."""
    def build():
        scene = ms.studio(size=48)
        ms.add_sphere("Ball", 0.5, hair_bsdf_material("H", Color=(0.7, 0.45, 0.25, 1.0), RoughnessU=0.3,
                                                      RoughnessV=0.6, Offset=0.2), location=(0.0, 0.0, 0.5))
        ms.add_plane("Slab", 0.8, hair_bsdf_material("H2", Color=(0.4, 0.6, 0.8, 1.0), RoughnessU=0.3,
                                                     RoughnessV=0.6), location=(0.9, 0.2, 0.3),
                     rotation_euler=(0.5, 0.2, 0.3))
        return scene
    ours, cycles = render_pair(build, 1024)
    assert_agree(ours, cycles)



def two_material_hair(shape='THICK', indices=(0, 1, 1, 0, 1, 0, 1)):
    """build() for render_pair: the patch with two material slots (diffuse orange, a blue
    Principled BSDF) and a 'material_index' attribute on the curves naming one per strand."""
    def build():
        scene = hair_scene(lambda: ms.diffuse("HairA", (0.8, 0.5, 0.3)))()
        scene.cycles_curves.shape = shape
        obj = bpy.data.objects["Hair"]
        obj.data.materials.append(ms.bsdf_material("HairB", "ShaderNodeBsdfPrincipled",
                                                   Base_Color=(0.2, 0.3, 0.8, 1.0), Roughness=0.35)[0])
        attr = obj.data.attributes.new("material_index", 'INT', 'CURVE')
        attr.data.foreach_set("value", np.asarray(indices, np.int32))
        return scene
    return build


def test_per_curve_material_indices_warn():
    """Several slots and non-zero material indices on the strands: one warning that they are not
    used (Cycles 4.5 ignores them too); all zero, or one slot: no warning."""
    from addon.export.curves import collect_curves
    two_material_hair()()
    warn = Warnings()
    (c,) = collect_curves(bpy.context.evaluated_depsgraph_get(), warn)
    assert len(warn) == 1 and "material indices" in warn[0] and c.material.name == "HairA"
    two_material_hair(indices=(0,) * 7)()
    warn = Warnings()
    collect_curves(bpy.context.evaluated_depsgraph_get(), warn)
    assert not warn


@pytest.mark.parametrize("shape", ['THICK', 'RIBBONS'])
def test_per_curve_material_indices_match_cycles(shape):
    """Strands whose material_index names the second slot: Cycles 4.5 renders every strand of a
    Curves object with the first slot (measured: identical to slot 1 alone), and so does
    Pathlight; rendering them with their own slots was 4.6 % off in the mean."""
    ours, cycles = render_pair(two_material_hair(shape, indices=(1,) * 7), 256)
    assert_agree(ours, cycles, what=f"per-curve material indices ({shape})")
