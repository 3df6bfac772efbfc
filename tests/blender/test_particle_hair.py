"""Particle hair (hair particle systems rendered as paths, issue 23) against Cycles in the same
bpy: a patch of hair on a plane, its parents' or children's strands exported with co_hair, the
radius from the hair shape, the emitter hidden or shown, the emitter's UV at the roots, and
bad input."""

import functools

import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon, render_to_array
import material_scenes as ms
from test_hair import assert_channels_agree, curves_info_material, principled_hair, unlit

load_addon()
render_pair = ms.render_pair
assert_agree = functools.partial(ms.assert_agree, floor=0.05)

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def add_hair_patch(material, patch_size=1.0, count=200, length=0.35, children=0, child_type='INTERPOLATED',
                   step=3, root=1.0, tip=0.3, scale=0.02, shape=0.0, close_tip=False,
                   location=(0.0, 0.0, 0.0), name="Patch", emitter_material=None):
    """A plane with a hair particle system of `count` parents (and `children` render children
    per parent; the display count the same, so the viewport depsgraph matches), grown along
    the normal with a little randomness; the hair's material in slot 2."""
    emitter = ms.add_plane(name, patch_size, emitter_material or ms.diffuse("Skin", (0.4, 0.3, 0.25)),
                           location=location)
    emitter.data.materials.append(material)  # slot 2: the hair's
    mod = emitter.modifiers.new("Hair", 'PARTICLE_SYSTEM')
    s = mod.particle_system.settings
    s.type = 'HAIR'
    s.count = count
    s.use_advanced_hair = True
    s.normal_factor = 1.0
    s.tangent_factor = 0.0
    s.factor_random = 0.01  # a little disorder
    s.hair_length = length  # last: it scales the velocity factors
    s.child_type = child_type if children else 'NONE'
    s.child_percent = s.rendered_child_count = max(children, 1)
    s.display_step = s.render_step = step
    s.material = 2
    s.root_radius, s.tip_radius, s.radius_scale, s.shape = root, tip, scale, shape
    s.use_close_tip = close_tip
    return emitter


def patch_scene(material_fn, size=48, **patch):
    """build() for render_pair: the studio (floor, area light above) and a hair patch 2 cm
    above the floor (coplanar with it, Cycles' shadow rays from the floor hit the emitter)."""
    def build():
        scene = ms.studio(size=size, world=(0.05, 0.05, 0.05), light_strength=8.0, light_size=2.0,
                          camera=((0.0, -1.6, 1.1), (0.0, 0.0, 0.12)), lens=50.0)
        scene.cycles_curves.shape = 'THICK'
        add_hair_patch(material_fn(), location=(0.0, 0.0, 0.02), **patch)
        return scene
    return build


def collect(warn=None):
    from addon.export.curves import collect_curves
    warn = Warnings() if warn is None else warn
    return collect_curves(bpy.context.evaluated_depsgraph_get(), warn), warn


def test_particle_hair_export_arrays():
    """Children only when there are any (else the parents), 2^step + 1 keys per strand in object
    space, the hair's material slot, the emitter's matrix."""
    ms.studio(size=16)
    hair_mat = ms.diffuse("HairMat", (0.5, 0.5, 0.5))
    emitter = add_hair_patch(hair_mat, count=40, step=2, location=(0.3, -0.2, 0.1))
    data, warn = collect()
    assert not warn, list(warn)
    (c,) = data
    assert c.name == "Patch" and c.material.name == "HairMat" and c.curve_type == 'catmull_rom'
    assert c.offsets.tolist() == list(range(0, 40 * 5 + 1, 5))
    np.testing.assert_allclose(c.matrices[0][:3, 3], (0.3, -0.2, 0.1), atol=1e-6)
    roots = c.points[c.offsets[:-1]]
    assert np.abs(roots[:, 2]).max() < 1e-5 and np.abs(roots[:, :2]).max() <= 0.5 + 1e-5  # on the plane
    tips = c.points[c.offsets[1:] - 1]
    assert np.all(tips[:, 2] > 0.2)  # grown up along the normal
    emitter.particle_systems[0].settings.child_type = 'SIMPLE'
    emitter.particle_systems[0].settings.child_percent = 3
    (c,), _ = collect()
    assert len(c.offsets) - 1 == 40 * 3  # children only, as Cycles


def test_particle_hair_radius_shape():
    """The radius along a strand: radius_scale x 0.5 x root at the root, x tip at the tip, the
    shape exponent on the length fraction between (Cycles' shaperadius), Close Tip zeroing the
    last key."""
    ms.studio(size=16)
    emitter = add_hair_patch(ms.diffuse("H", (0.5, 0.5, 0.5)), count=10, step=3, root=2.0, tip=0.5,
                             scale=0.04, shape=-0.5)
    (c,), _ = collect()
    r = c.radii.reshape(10, 9)
    np.testing.assert_allclose(r[:, 0], 0.04, rtol=1e-6)
    np.testing.assert_allclose(r[:, -1], 0.01, rtol=1e-6)
    pts = c.points.reshape(10, 9, 3).astype(np.float64)
    seg = np.linalg.norm(np.diff(pts, axis=1), axis=2)
    t = np.concatenate([np.zeros((10, 1)), np.cumsum(seg, 1)], 1)
    t /= t[:, -1:]
    np.testing.assert_allclose(r, (1.0 - t) ** 0.5 * 0.03 + 0.01, rtol=1e-4, atol=1e-7)  # 1 + shape
    s = emitter.particle_systems[0].settings
    s.shape, s.use_close_tip = 0.5, True
    (c,), _ = collect()
    r = c.radii.reshape(10, 9)
    np.testing.assert_allclose(r[:, 4], (1.0 - t[:, 4]) ** 2.0 * 0.03 + 0.01, rtol=1e-4)  # 1 / (1 - shape)
    assert np.all(r[:, -1] == 0.0)


def info_scene(hide_emitter, **patch):
    """Thick, strongly tapered particle hair (240 parents x 3 interpolated children on a 2 m
    emitter, its edges out of the frame) seen directly in Curves Info colours (Intercept,
    Random, Thickness x 10), nothing lit: radius, intercept and strand numbering against Cycles."""
    patch_build = patch_scene(lambda: curves_info_material("Info"), size=48, count=240, children=3,
                              scale=0.012, shape=0.4, step=3, patch_size=2.0, **patch)

    def build():
        scene = patch_build()
        bpy.data.objects["Patch"].show_instancer_for_render = not hide_emitter
        return scene
    return unlit(build)


def test_particle_hair_curves_info_matches_cycles():
    """The hair shape (root 2, tip 0.25, shape 0.4, Close Tip) seen in Thickness, with
    Intercept and Random, on interpolated children: each channel within the issue's bar."""
    ours, cycles = render_pair(info_scene(False, root=2.0, tip=0.25, close_tip=True), 256)
    assert_channels_agree(ours, cycles)


def test_particle_hair_with_the_emitter_hidden_matches_cycles():
    """Show Emitter off: the strands render without the plane, their roots in view, with open
    tips of non-zero radius (root 4, tip 1, no Close Tip): both ends cut off flat, as Cycles'
    thick curves end (half-sphere caps were 6-9 % off at the roots)."""
    ours, cycles = render_pair(info_scene(True, root=4.0, tip=1.0, close_tip=False), 256)
    assert_channels_agree(ours, cycles)


def test_emitter_hidden_exports_hair_without_the_mesh():
    from addon.export import export_scene
    ms.studio(size=16)
    emitter = add_hair_patch(ms.diffuse("H", (0.5, 0.5, 0.5)), count=10)
    emitter.show_instancer_for_viewport = emitter.show_instancer_for_render = False
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    assert not warn, list(warn)
    assert "Patch" not in [m.name for m in data.meshes]
    assert [c.name for c in data.curves] == ["Patch"] and len(data.curves[0].offsets) == 11
    emitter.show_instancer_for_viewport = True
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    assert "Patch" in [m.name for m in data.meshes] and len(data.curves) == 1


@functools.lru_cache(maxsize=1)
def principled_patch_pair():
    """A patch of 150 parents x 4 interpolated children (600 strands) on a plane under an area
    light, Principled Hair (Chiang, melanin), 1024 samples: (Pathlight, Cycles), rendered once
    for the two tests below."""
    mat = lambda: principled_hair("Hair", 'MELANIN', Melanin=0.35, Melanin_Redness=0.5, Roughness=0.4)
    return render_pair(patch_scene(mat, count=150, children=4, scale=0.012, root=1.0, tip=0.4), 1024)


def test_principled_hair_particle_patch_mean_matches_cycles():
    """The image mean within the issue's 1 %, and 8x8 regions within 8 % (measured: mean
    +0.08 %; before rays starting inside interpenetrating strands met their inside, +0.6 %
    with regions up to +6.4 % inside the dense hair)."""
    ours, cycles = principled_patch_pair()
    assert_agree(ours, cycles, region=0.08)


def test_principled_hair_particle_patch_regions_match_cycles():
    """The issue's bar: every 8x8 region within 3 % (measured: worst 2.6 %, of either sign,
    noise at 1024 samples; it was +6.4 % while rays starting inside a strand passed through it)."""
    ours, cycles = principled_patch_pair()
    assert_agree(ours, cycles)


def uv_root_material(name):
    """Emission of the UV Map node's (u, v, 0): on particle hair, the emitter's UV at the root."""
    mat, nodes, links, out = ms.new_material(name)
    uv = nodes.new("ShaderNodeUVMap")
    em = nodes.new("ShaderNodeEmission")
    links.new(uv.outputs["UV"], em.inputs["Color"])
    links.new(em.outputs[0], out.inputs["Surface"])
    return mat


def test_particle_hair_emitter_uv_matches_cycles():
    """The UV Map node on particle hair reads the emitter's UV at each strand's root (Cycles'
    per-curve UV), for interpolated children."""
    build = patch_scene(lambda: uv_root_material("UV"), size=48, count=80, children=3, scale=0.02, step=2)
    ours, cycles = render_pair(unlit(build), 256)
    assert_channels_agree(ours, cycles, channels=2)  # (u, v, 0)


def colour_root_material(name, node="ShaderNodeAttribute"):
    """Emission of the emitter's byte colour attribute "Col" at the strand's root (an Attribute
    node by name, or a Color Attribute node)."""
    mat, nodes, links, out = ms.new_material(name)
    col = nodes.new(node)
    if node == "ShaderNodeAttribute":
        col.attribute_name = "Col"
    else:
        col.layer_name = "Col"
    em = nodes.new("ShaderNodeEmission")
    links.new(col.outputs["Color"], em.inputs["Color"])
    links.new(em.outputs[0], out.inputs["Surface"])
    return mat


@pytest.mark.parametrize("node", ["ShaderNodeAttribute", "ShaderNodeVertexColor"])
def test_particle_hair_emitter_colour_matches_cycles(node):
    """The emitter's byte colour attribute on face corners, read by name (Attribute or Color
    Attribute node) on particle hair: Cycles' per-curve vertex colour at each root (sRGB
    decoded), for interpolated children; four corner colours across the patch."""
    build = patch_scene(lambda: colour_root_material("Colour", node), size=48, count=80, children=3,
                        scale=0.02, step=2)

    def dark():
        scene = build()
        for obj_name in ("Light", "Floor"):
            bpy.data.objects[obj_name].hide_render = True
        ms.set_world((0.0, 0.0, 0.0))
        mesh = bpy.data.objects["Patch"].data
        attr = mesh.color_attributes.new("Col", 'BYTE_COLOR', 'CORNER')
        for loop in mesh.loops:
            co = mesh.vertices[loop.vertex_index].co
            attr.data[loop.index].color = (0.9 if co.x > 0 else 0.1, 0.8 if co.y > 0 else 0.05, 0.3, 1.0)
        return scene
    ours, cycles = render_pair(dark, 256)
    assert ours[..., :3].max() > 0.2  # the colours are there
    for c in range(3):
        assert_agree(ours[..., [c, c, c, 3]], cycles[..., [c, c, c, 3]], region=0.03, floor=0.1)


def test_bad_particle_hair_warns_and_renders():
    """No particles, zero radius, zero length and an emitter scaled to zero (no object space):
    a warning each, no crash."""
    ms.studio(size=16)
    add_hair_patch(ms.diffuse("A", (0.5, 0.5, 0.5)), count=0, name="Empty")
    add_hair_patch(ms.diffuse("B", (0.5, 0.5, 0.5)), count=5, root=0.0, tip=0.0, name="Thin",
                          location=(2.0, 0.0, 0.0))
    flat = add_hair_patch(ms.diffuse("C", (0.5, 0.5, 0.5)), count=5, name="Flat", location=(-2.0, 0.0, 0.0))
    flat.particle_systems[0].settings.normal_factor = 0.0  # no velocity: every key at the root
    flat.particle_systems[0].settings.factor_random = 0.0
    squashed = add_hair_patch(ms.diffuse("D", (0.5, 0.5, 0.5)), count=5, name="Squashed",
                              location=(0.0, 2.0, 0.0))
    squashed.scale = (0.0, 0.0, 0.0)
    data, warn = collect()
    text = "\n".join(warn)
    assert "'Squashed'" in text
    assert "'Empty'" in text and "no strands" in text
    assert "Particle hair on 'Thin': 5 of 5 strands" in text
    assert "Particle hair on 'Flat': 5 of 5 strands" in text
    img = render_to_array(bpy.context.scene, "PATHLIGHT", samples=2)
    assert np.isfinite(img).all()


def test_emitter_colour_attributes_on_particle_hair_warn():
    """A float colour attribute on the emitter's points is not read on particle hair (Cycles
    gives particle hair only byte colours on face corners): one clear warning (the UV map the
    same material reads is exported, one uv per strand)."""
    from addon.export import export_scene
    ms.studio(size=16)
    mat, nodes, links, out = ms.new_material("HairAttr")
    col, uv = nodes.new("ShaderNodeVertexColor"), nodes.new("ShaderNodeUVMap")
    col.layer_name = "Col"
    mix = nodes.new("ShaderNodeMixRGB")
    links.new(col.outputs["Color"], mix.inputs[1])
    links.new(uv.outputs["UV"], mix.inputs[2])
    em = nodes.new("ShaderNodeEmission")
    links.new(mix.outputs[0], em.inputs["Color"])
    links.new(em.outputs[0], out.inputs["Surface"])
    emitter = add_hair_patch(mat, count=12)
    emitter.data.color_attributes.new("Col", 'FLOAT_COLOR', 'POINT')  # the mesh has it
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    assert len(warn) == 1 and "Particle hair on 'Patch'" in warn[0] and "'Col'" in warn[0], list(warn)
    (c,) = data.curves
    (uvs,) = c.uvs.values()
    assert uvs.shape == (12, 2) and np.all((uvs >= 0.0) & (uvs <= 1.0)) and np.ptp(uvs[:, 0]) > 0.1


def test_particle_hair_export_cost_is_measured():
    """The co_hair loop's cost (documented in docs/design/curves.md): 10k strands x 9 keys."""
    import time
    ms.studio(size=16)
    add_hair_patch(ms.diffuse("H", (0.5, 0.5, 0.5)), count=2000, children=5, step=3)
    dg = bpy.context.evaluated_depsgraph_get()
    from addon.export.curves import collect_curves
    t = time.perf_counter()
    (c,) = collect_curves(dg, Warnings())
    dt = time.perf_counter() - t
    print(f"\n10k strands x 9 keys: {dt:.3f} s")
    assert len(c.offsets) - 1 == 10000 and c.points.shape == (90000, 3)
    assert dt < 10.0  # ~0.3 s on the shared 2-core machine; seconds would need the warning's limit lowered
