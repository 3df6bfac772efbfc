"""A smooth UV sphere with a tangent-space normal map of bumps, Pathlight against Cycles in the
same bpy (issue 21): both read Blender's MikkTSpace tangents, interpolated across each
triangle (per-triangle tangents showed the sphere's facets through the bumps)."""
import math

import bpy
import bmesh  # (after bpy, which provides it)
import numpy as np
import pytest

from blender_util import core_available, load_addon
import light_scenes as ls
import material_scenes as ms
from material_scenes import assert_agree, render_pair

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


# Low-poly, so that a tangent per triangle (the core's without MikkTSpace tangents) shows.
SEGMENTS, RINGS = 12, 8


def bump_normals(w=128, h=64, freq=(6, 4), slope=1.1):
    """float (h, w, 4) tangent-space normal map (colour = n / 2 + 1/2) of the height field
    sin(2 pi fu u) sin(2 pi fv v): round bumps, slopes up to about `slope`."""
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    uu, vv = np.meshgrid(u, v)
    fu, fv = freq
    a = slope / (2 * math.pi * max(fu, fv))
    dhdu = a * 2 * math.pi * fu * np.cos(2 * math.pi * fu * uu) * np.sin(2 * math.pi * fv * vv)
    dhdv = a * 2 * math.pi * fv * np.sin(2 * math.pi * fu * uu) * np.cos(2 * math.pi * fv * vv)
    n = np.stack([-dhdu, -dhdv, np.ones_like(uu)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    px = np.ones((h, w, 4), np.float32)
    px[..., :3] = n * 0.5 + 0.5
    return px


def bumpy_sphere_scene(tangent_node=False, scale=(1.0, 1.0, 1.0)):
    """A diffuse smooth UV sphere (SEGMENTS x RINGS, 0..1 UVs, its pole turned towards the
    camera) whose Normal Map reads the bumps, lit by a sun from above the camera and a dim
    world. tangent_node: half of it an anisotropic glossy whose tangent is the Tangent node's
    (UV Map direction)."""
    def build():
        scene = ls.empty_scene(64)
        ms.set_world((0.08, 0.08, 0.08))
        mat, nodes, links, out = ms.new_material("Bumps")
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = ms.pixel_image("BumpNormals", bump_normals(), "Non-Color", float_buffer=True)
        tex.interpolation = 'Linear'
        nm = nodes.new("ShaderNodeNormalMap")
        d = ms.set_inputs(nodes.new("ShaderNodeBsdfDiffuse"), Color=(0.8, 0.8, 0.8, 1.0))
        links.new(tex.outputs["Color"], nm.inputs["Color"])
        links.new(nm.outputs["Normal"], d.inputs["Normal"])
        surface = d.outputs[0]
        if tangent_node:
            g = nodes.new("ShaderNodeBsdfAnisotropic")
            g.distribution = 'GGX'
            ms.set_inputs(g, Roughness=0.3, Anisotropy=0.8)
            tan = nodes.new("ShaderNodeTangent")
            tan.direction_type = 'UV_MAP'
            links.new(tan.outputs["Tangent"], g.inputs["Tangent"])
            mix = nodes.new("ShaderNodeMixShader")
            mix.inputs["Fac"].default_value = 0.5
            links.new(surface, mix.inputs[1])
            links.new(g.outputs[0], mix.inputs[2])
            surface = mix.outputs[0]
        links.new(surface, out.inputs["Surface"])

        def sphere(bm):
            bm.loops.layers.uv.new("UVMap")
            bmesh.ops.create_uvsphere(bm, u_segments=SEGMENTS, v_segments=RINGS, radius=1.0, calc_uvs=True)
        ms.add_mesh_object("Sphere", sphere, (mat,), smooth=True, rotation_euler=(0.9, 0.0, 0.4),
                           scale=scale)
        # The sun from behind the camera: the terminator stays near the silhouette (Cycles'
        # shadow terminator offset is a difference of its own).
        sun = ms.add_sun(3.0)
        sun.rotation_euler = (math.radians(55.0), 0.0, math.radians(-25.0))
        ms.add_camera((0.0, -3.6, 0.8), (0.0, 0.0, 0.0))
        return scene
    return build


@pytest.mark.parametrize("scale", [(1.0, 1.0, 1.0), (1.4, 1.0, 0.7)])
def test_normal_mapped_smooth_sphere_matches_cycles(scale):
    # Worst region 0.2 % with MikkTSpace tangents (0.8 % scaled unevenly); 3.3 % with a
    # tangent per triangle (the pole's fan shows it most): the bar sits between, under the
    # issue's 3 %.
    ours, cycles = render_pair(bumpy_sphere_scene(scale=scale), 256)
    assert_agree(ours, cycles, "normal-mapped sphere", region=0.015, whole=0.01)


def test_tangent_node_on_a_smooth_sphere_matches_cycles():
    # Worst region 0.3 %; the anisotropic highlight along per-triangle tangents was 75 % off.
    ours, cycles = render_pair(bumpy_sphere_scene(tangent_node=True), 256)
    assert_agree(ours, cycles, "tangent node sphere", region=0.03, whole=0.01)


def exported_mesh(fill_type, space="TANGENT", in_group=False):
    """The MeshData of a UV-mapped 8-vertex circle (an n-gon or a triangle fan) whose material
    has a Normal Map of the given space (optionally inside a node group)."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.mesh.primitive_circle_add(vertices=8, fill_type=fill_type, calc_uvs=True)
    obj = bpy.context.object
    mat, nodes, links, out = ms.new_material("NM")
    tree = nodes
    if in_group:
        group = bpy.data.node_groups.new("Bent", "ShaderNodeTree")
        group.interface.new_socket("Normal", in_out='OUTPUT', socket_type='NodeSocketVector')
        tree = group.nodes
        node = nodes.new("ShaderNodeGroup")
        node.node_tree = group
    nm = tree.new("ShaderNodeNormalMap")
    nm.space = space
    if not in_group:
        d = nodes.new("ShaderNodeBsdfDiffuse")
        links.new(nm.outputs["Normal"], d.inputs["Normal"])
        links.new(d.outputs[0], out.inputs["Surface"])
    obj.data.materials.append(mat)
    from addon.export.mesh import collect_meshes
    names = lambda materials: {0: ""}  # noqa: E731  (the active UV map, as set 0)
    (mesh,) = collect_meshes(bpy.context.evaluated_depsgraph_get(), names)
    return mesh


def test_tangents_exported_for_tangent_space_normal_maps_only():
    mesh = exported_mesh('TRIFAN')
    assert mesh.tangent_problem is None and set(mesh.tangents) == {0}
    t = mesh.tangents[0]
    assert t.shape == (len(mesh.triangles), 3, 4) and t.dtype == np.float32
    assert np.allclose(np.linalg.norm(t[..., :3], axis=-1), 1.0, atol=1e-4)
    assert set(np.unique(t[..., 3])) <= {-1.0, 1.0}
    assert set(exported_mesh('TRIFAN', in_group=True).tangents) == {0}  # found inside groups
    assert exported_mesh('TRIFAN', space="OBJECT").tangents == {}


def test_ngons_get_their_triangles_tangents():
    # calc_tangents refuses n-gons: the triangles' own, as the fan's, and no problem.
    ngon, fan = exported_mesh('NGON'), exported_mesh('TRIFAN')
    assert ngon.tangent_problem is None and set(ngon.tangents) == {0}
    t = ngon.tangents[0]
    assert t.shape == (len(ngon.triangles), 3, 4)
    assert np.allclose(np.linalg.norm(t[..., :3], axis=-1), 1.0, atol=1e-4)
    # A flat disc with planar uvs: one tangent everywhere, the fan's.
    assert np.allclose(t, fan.tangents[0][0, 0], atol=1e-4), (t[0], fan.tangents[0][0])
