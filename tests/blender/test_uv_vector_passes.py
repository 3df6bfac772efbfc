"""The UV, Vector and shader AOV passes against Cycles 4.5 in the same bpy, read back from
Blender's multilayer EXR: a UV-mapped, checker-textured plane sliding sideways, a turning
sphere seen partly through a transparent one, a card rising by a shape key (writing an AOV from
inside nested node groups), and a rising camera; one render per engine (64x48, 16 samples,
1-pixel box filter)."""
import math

import bpy
import numpy as np
import pytest

from blender_util import core_available, empty_scene_with_camera, load_addon, node_material, \
    render_multilayer_pair

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

SAMPLES = 16


def _linear(obj):
    for fc in obj.animation_data.action.fcurves:
        for k in fc.keyframe_points:
            k.interpolation = 'LINEAR'


def aov_material(name, value_of, color=None):
    """A diffuse material with AOV Output nodes: "val" (VALUE) gets value_of(nodes, links)'s
    socket, "col" (COLOR) a Checker Texture on the UV map when color is set."""
    mat = node_material(name, "ShaderNodeBsdfDiffuse")
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    out = nodes.new("ShaderNodeOutputAOV")
    out.aov_name = "val"
    value = value_of(nodes, links)
    if isinstance(value, float):
        out.inputs["Value"].default_value = value
    else:
        links.new(value, out.inputs["Value"])
    if color is not None:
        checker = nodes.new("ShaderNodeTexChecker")
        checker.inputs["Scale"].default_value = 3.0
        checker.inputs["Color1"].default_value = color
        coords = nodes.new("ShaderNodeTexCoord")
        links.new(coords.outputs["UV"], checker.inputs["Vector"])
        col = nodes.new("ShaderNodeOutputAOV")
        col.aov_name = "col"
        links.new(checker.outputs["Color"], col.inputs["Color"])
    return mat


def group_aov(mat):
    """Writes "col" from inside a group inside a group linked to nothing: the material's UV ->
    Outer (Vector) -> Inner (Color) -> AOV Output, so each level's Group Input reads its own
    group node's input."""
    inner = bpy.data.node_groups.new("AovInner", "ShaderNodeTree")
    inner.interface.new_socket("Color", in_out='INPUT', socket_type='NodeSocketColor')
    col = inner.nodes.new("ShaderNodeOutputAOV")
    col.aov_name = "col"
    inner.links.new(inner.nodes.new("NodeGroupInput").outputs[0], col.inputs["Color"])
    outer = bpy.data.node_groups.new("AovOuter", "ShaderNodeTree")
    outer.interface.new_socket("Vector", in_out='INPUT', socket_type='NodeSocketVector')
    nested = outer.nodes.new("ShaderNodeGroup")
    nested.node_tree = inner
    outer.links.new(outer.nodes.new("NodeGroupInput").outputs[0], nested.inputs[0])
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    group = nodes.new("ShaderNodeGroup")
    group.node_tree = outer
    links.new(nodes.new("ShaderNodeTexCoord").outputs["UV"], group.inputs[0])
    return mat


def _uv_u(nodes, links):
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(nodes.new("ShaderNodeTexCoord").outputs["UV"], sep.inputs["Vector"])
    return sep.outputs["X"]


def moving_scene():
    """Frame 1 of: a 2x2 UV-mapped plane, tilted, sliding +x by 0.4 a frame; a UV sphere turning
    about z by 10 degrees a frame; the camera rising by 0.2 a frame after frame 1 (so only the
    next frame's vectors see it)."""
    sc = empty_scene_with_camera(64)
    sc.render.resolution_y = 48
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(-0.8, 0.0, 0.0), rotation=(math.radians(80), 0.3, 0.0))
    plane = bpy.context.active_object
    plane.data.materials.append(aov_material("Plane", _uv_u, color=(0.9, 0.3, 0.1, 1.0)))
    for f, x in ((0, -1.2), (2, -0.4)):
        plane.location.x = x
        plane.keyframe_insert("location", frame=f)
    _linear(plane)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(1.0, 0.5, 0.2), segments=24, ring_count=12)
    sphere = bpy.context.active_object
    sphere.data.materials.append(aov_material("Sphere", lambda nodes, links: 0.25))
    # A mostly transparent sphere in front of its edge: AOVs add up through it (Cycles writes
    # them at each surface until the data passes' one, at least half opaque).
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(0.6, -1.5, 0.3), segments=16, ring_count=8)
    glass = bpy.context.active_object
    veil = aov_material("Veil", lambda nodes, links: 0.5)
    nodes, links = veil.node_tree.nodes, veil.node_tree.links
    mix = nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.8
    links.new(nodes["Diffuse BSDF"].outputs[0], mix.inputs[1])
    links.new(nodes.new("ShaderNodeBsdfTransparent").outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], nodes["Material Output"].inputs["Surface"])
    glass.data.materials.append(veil)
    # A card that rises by 0.3 a frame through an animated shape key (deformation).
    bpy.ops.mesh.primitive_plane_add(size=0.6, location=(1.4, -0.5, -1.1), rotation=(math.pi / 2, 0.0, 0.0))
    card = bpy.context.active_object
    card.data.materials.append(group_aov(aov_material("Card", lambda nodes, links: 0.0)))
    card.shape_key_add(name="Basis")
    up = card.shape_key_add(name="Up")
    for v in up.data:
        v.co.y += 0.6  # (local y is world z)
    for f, value in ((0, 0.0), (2, 1.0)):
        up.value = value
        up.keyframe_insert("value", frame=f)
    for fc in card.data.shape_keys.animation_data.action.fcurves:
        for k in fc.keyframe_points:
            k.interpolation = 'LINEAR'
    for f, a in ((0, -10.0), (2, 10.0)):
        sphere.rotation_euler.z = math.radians(a)
        sphere.keyframe_insert("rotation_euler", frame=f)
    _linear(sphere)
    cam = sc.camera
    for f, z in ((1, 0.0), (2, 0.2)):
        cam.location.z = z
        cam.keyframe_insert("location", frame=f)
    _linear(cam)
    sc.frame_set(1)
    vl = sc.view_layers[0]
    vl.use_pass_uv = vl.use_pass_vector = True
    for name, kind in (("col", 'COLOR'), ("val", 'VALUE')):
        aov = vl.aovs.add()
        aov.name, aov.type = name, kind
    sc.render.use_motion_blur = False
    return sc


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    # (refs="check": the stored Cycles file is checked against a fresh render)
    return render_multilayer_pair(moving_scene(), tmp_path_factory.mktemp("uv_vector"), SAMPLES, 8, refs="check")


def _stack(ch, name, channels):
    return np.stack([ch[f"{name}.{c}"] for c in channels], axis=-1)


def test_both_engines_write_the_same_layers(renders):
    cycles, pathlight = renders
    for name in ("UV.U", "UV.V", "UV.A", "Vector.X", "Vector.Y", "Vector.Z", "Vector.W", "col.R", "col.G",
                 "col.B", "col.A", "val.X"):
        assert name in cycles and name in pathlight


def test_uv_pass_matches_cycles_per_pixel(renders):
    cycles, pathlight = renders
    uc, up = _stack(cycles, "UV", "UVA"), _stack(pathlight, "UV", "UVA")
    # Alpha is the share of samples that hit a UV-mapped surface: the same coverage.
    assert abs(uc[..., 2].mean() - up[..., 2].mean()) < 0.01
    full = (uc[..., 2] == 1.0) & (up[..., 2] == 1.0)
    assert full.sum() > 600
    d = np.abs(uc[..., :2] - up[..., :2])[full]
    # Within a pixel the UVs vary by ~0.04 (plane) and more on the sphere: 16 jittered samples
    # of different sequences differ by their noise.
    assert np.median(d) < 0.004, np.median(d)
    assert np.quantile(d, 0.99) < 0.02, np.quantile(d, 0.99)


def test_vector_pass_matches_cycles_per_pixel(renders):
    cycles, pathlight = renders
    vc, vp = _stack(cycles, "Vector", "XYZW"), _stack(pathlight, "Vector", "XYZW")
    full = (cycles["UV.A"] == 1.0) & (pathlight["UV.A"] == 1.0)
    assert np.abs(vc[full]).max() > 2.0  # it moves by pixels, in every component
    for c in range(4):
        assert np.abs(vc[full][:, c]).max() > 0.5, c
    # The card's deformation: it rose by 0.3 units (about 3.6 pixels) since the last frame.
    rising = full & (vc[..., 1] < -2.0)
    assert rising.sum() > 10 and (vp[..., 1][rising] < -2.0).all()
    d = np.abs(vc - vp)[full]
    assert np.median(d) < 0.01, np.median(d)
    assert np.quantile(d, 0.99) < 0.05, np.quantile(d, 0.99)
    # The world: no motion in either.
    miss = (cycles["UV.A"] == 0.0) & (pathlight["UV.A"] == 0.0)
    assert miss.sum() > 300
    assert not vc[miss].any() and not vp[miss].any()


def test_shader_aovs_match_cycles_per_pixel(renders):
    cycles, pathlight = renders
    cc, cp = _stack(cycles, "col", "RGBA"), _stack(pathlight, "col", "RGBA")
    vc, vp = cycles["val.X"], pathlight["val.X"]
    # What each object writes: the plane its UV's U and the checker, the sphere 0.25, the
    # veil 0.5 at its front, and at its back and beyond where the path went on through it
    # (80 %): about 0.5 + 0.8 (0.5 + 0.8 x 0.25) = 1.06 over the sphere.
    assert cc[..., 3].max() == 1.0
    assert (np.isclose(vc, 0.25, atol=1e-3) & np.isclose(vp, 0.25, atol=1e-3)).sum() > 100
    assert ((vc > 1.0) & (vp > 1.0)).sum() > 5
    # The card writes "col" from inside nested node groups: its UVs as (u, v, 0, 1), the only
    # colour without blue (the plane's checker has some in both squares).
    card = (cc[..., 3] == 1.0) & (cc[..., 2] < 1e-4) & (cc[..., :2].max(axis=-1) > 0.05)
    assert card.sum() > 20
    assert np.abs(cp[card] - cc[card]).max(axis=-1).mean() < 0.02
    for a, b in ((cc, cp), (vc[..., None], vp[..., None])):
        d = np.abs(a - b).max(axis=-1)
        # Pixels on edges (of objects and checker squares) mix different values by their
        # 16 samples: they differ by the samples' noise; the rest agree to float precision.
        assert np.median(d) < 1e-3, np.median(d)
        assert np.quantile(d, 0.95) < 0.2, np.quantile(d, 0.95)
        assert abs(a.mean() - b.mean()) < 0.01 * max(a.mean(), 1e-3) + 2e-3, (a.mean(), b.mean())


def test_compositor_sockets_for_uv_vector_and_aovs():
    sc = moving_scene()
    sc.render.engine = 'PATHLIGHT'
    sc.use_nodes = True
    rl = sc.node_tree.nodes.new("CompositorNodeRLayers")
    rl.update()
    names = {s.name for s in rl.outputs if s.enabled}
    assert {"UV", "Vector", "col", "val"} <= names
    sc.view_layers[0].use_pass_uv = False
    sc.view_layers[0].aovs.remove(sc.view_layers[0].aovs[0])
    rl.update()
    names = {s.name for s in rl.outputs if s.enabled}
    assert "UV" not in names and "col" not in names and "val" in names
