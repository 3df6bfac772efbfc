"""True displacement (the material's Displacement method 'DISPLACEMENT' or 'BOTH'): Cycles moves
every vertex of the evaluated mesh (here subdivided by a modifier) by the displacement shader at
that vertex, then recomputes the normals ('DISPLACEMENT') or keeps them and adds the bump
('BOTH'). Pathlight against Cycles in the same bpy, lit by a sun at a grazing angle so that the
silhouette, the shadows and the shading all differ clearly from bump; and the export: what each
method compiles to, bump-only materials unchanged, bad displacements warned."""
import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

W, H = 64, 48


def disp_material(name, method, source="wave", scale=0.08, image=None, space='OBJECT'):
    """A grey Principled BSDF displaced by a Wave (object coordinates), Noise (object
    coordinates) or image (UV) height through a Displacement node."""
    mat, nodes, links, out = ms.new_material(name)
    mat.displacement_method = method
    bsdf = ms.set_inputs(nodes.new("ShaderNodeBsdfPrincipled"), Base_Color=(0.7, 0.7, 0.7, 1.0),
                         Roughness=0.5)
    links.new(bsdf.outputs[0], out.inputs["Surface"])
    if source == "color":  # the mesh's colour attribute (per vertex, interpolated by the modifier)
        attr = nodes.new("ShaderNodeVertexColor")
        attr.layer_name = "Height"
        height = attr.outputs["Color"]
    elif source == "image":
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        uv = nodes.new("ShaderNodeUVMap")
        links.new(uv.outputs["UV"], tex.inputs["Vector"])
        height = tex.outputs["Color"]
    else:
        coord = nodes.new("ShaderNodeTexCoord")
        if source == "wave":
            tex = ms.set_inputs(nodes.new("ShaderNodeTexWave"), Scale=2.5, Distortion=2.0, Detail=1.0)
        elif source == "vector":
            tex = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=2.0, Detail=1.0)
        else:
            tex = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=3.0, Detail=1.0)
        links.new(coord.outputs["Object"], tex.inputs["Vector"])
        height = tex.outputs["Fac"]
    if source == "vector":  # Vector Displacement of the Noise's colour in tangent space
        links.new(coord.outputs["Object"], tex.inputs["Vector"])
        disp = ms.set_inputs(nodes.new("ShaderNodeVectorDisplacement"), Scale=scale, Midlevel=0.5)
        disp.space = 'TANGENT'
        links.new(tex.outputs["Color"], disp.inputs["Vector"])
        links.new(disp.outputs[0], out.inputs["Displacement"])
        return mat
    disp = ms.set_inputs(nodes.new("ShaderNodeDisplacement"), Scale=scale, Midlevel=0.5)
    disp.space = space
    links.new(height, disp.inputs["Height"])
    links.new(disp.outputs[0], out.inputs["Displacement"])
    return mat


def ring_image():
    """Concentric rings of height, non-colour data (a byte image, as a painted height map)."""
    y, x = np.mgrid[0:64, 0:64] / 63.0
    h = 0.5 + 0.5 * np.sin(np.hypot(x - 0.5, y - 0.5) * 28.0)
    px = np.stack([h, h, h, np.ones_like(h)], -1)
    return ms.pixel_image("Rings", px, colorspace="Non-Color")


def colored_grid(name, mat):
    """A 16x16 grid whose point colour attribute "Height" holds crossed sine ridges."""
    import bmesh
    def build(bm):
        bm.loops.layers.uv.new("UVMap")
        bmesh.ops.create_grid(bm, x_segments=16, y_segments=16, size=0.8, calc_uvs=True)
    obj = ms.add_mesh_object(name, build, (mat,), rotation_euler=(0.0, 0.0, 0.4))
    mesh = obj.data
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    x, y = co[0::3], co[1::3]
    h = 0.5 + 0.25 * (np.sin(x * 9.0) + np.cos(y * 7.0))
    col = mesh.color_attributes.new("Height", 'FLOAT_COLOR', 'POINT')
    col.data.foreach_set("color", np.stack([h, h, h, np.ones_like(h)], -1).astype(np.float32).ravel())
    return obj


def subdivide(obj, levels, simple):
    mod = obj.modifiers.new("Subdivision", 'SUBSURF')
    mod.subdivision_type = 'SIMPLE' if simple else 'CATMULL_CLARK'
    mod.levels = mod.render_levels = levels
    return obj


def scene(method, shape="plane", source="wave", scale=0.08):
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        sc = bpy.context.scene
        sc.render.resolution_x, sc.render.resolution_y = W, H
        ms.set_world((0.05, 0.05, 0.05))
        image = ring_image() if source == "image" else None
        mat = disp_material(f"{source}-{method}", method, source, scale, image)
        if source == "color":
            subdivide(colored_grid("Grid", mat), 2, False)
            ms.add_camera((0.0, -1.7, 1.2), (0.0, 0.0, 0.0))
        elif shape == "plane":
            subdivide(ms.add_plane("Plane", 1.6, mat, rotation_euler=(0.0, 0.0, 0.4)), 6, True)
            ms.add_camera((0.0, -1.7, 1.2), (0.0, 0.0, 0.0))
        else:
            ball = ms.add_sphere("Ball", 0.5, mat, segments=32, rings=16)
            if shape == "flat-sphere":  # flat shading: the displaced faces' own normals
                for poly in ball.data.polygons:
                    poly.use_smooth = False
            subdivide(ball, 2, False)
            ms.add_camera((0.0, -2.2, 0.3), (0.0, 0.0, 0.0))
        ms.add_sun(4.0, 72.0)  # 18 degrees above the horizon
        return sc
    return build


CASES = {  # method, shape, height, scale, samples (the fewest that converge to the bar)
    "plane-wave-displacement": ("DISPLACEMENT", "plane", "wave", 0.08, 512),
    "plane-wave-both": ("BOTH", "plane", "wave", 0.08, 1536),
    "plane-image-displacement": ("DISPLACEMENT", "plane", "image", 0.06, 256),
    "plane-vector-tangent-displacement": ("DISPLACEMENT", "plane", "vector", 0.1, 256),
    "plane-color-attribute-displacement": ("DISPLACEMENT", "plane", "color", 0.1, 256),
    "sphere-noise-displacement": ("DISPLACEMENT", "sphere", "noise", 0.1, 128),
    "flat-sphere-noise-displacement": ("DISPLACEMENT", "flat-sphere", "noise", 0.1, 128),
    "sphere-noise-both": ("BOTH", "sphere", "noise", 0.1, 128),
}


@pytest.mark.converged
@pytest.mark.parametrize("case", list(CASES))
def test_true_displacement_matches_cycles(case):
    method, shape, source, scale, samples = CASES[case]
    ours, cycles = ms.render_pair(scene(method, shape, source, scale), samples)
    ms.assert_agree(ours, cycles, case)
    # It is not bump: the same material as bump differs from Cycles' true displacement by far
    # more than the engines differ.
    bump = render_to_array(scene("BUMP", shape, source, scale)(), "PATHLIGHT", samples=16)
    effect = np.abs(bump - cycles)[..., :3].mean()
    assert effect > 5 * np.abs(ours - cycles)[..., :3].mean(), effect


def export(method, source="wave"):
    from addon.export import export_scene
    scene(method, "plane", source)()
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    (mat,) = [m for m in data.materials if m.name == f"{source}-{method}"]
    return data, mat, warn


@pytest.mark.parametrize("method", ["DISPLACEMENT", "BOTH"])
def test_true_displacement_compiles_a_vertex_program_without_warnings(method):
    _, mat, warn = export(method)
    assert not warn, list(warn)
    assert mat.displacement_method == method
    assert mat.displacement[-1][:2] == ("closure", "displacement")
    assert "tex_wave" in [op[0] for op in mat.displacement]
    # 'BOTH' also bumps the shading normal; 'DISPLACEMENT' does not.
    assert ("set_normal" in [op[0] for op in mat.program]) == (method == "BOTH")


def test_bump_only_materials_are_not_displaced():
    from addon import scene_writer
    from addon.core import get_core
    data, mat, warn = export("BUMP")
    assert mat.displacement is None and mat.displacement_method == 'BUMP'
    assert "set_normal" in [op[0] for op in mat.program]
    pc = get_core()
    calls = []
    real = pc.Scene.displace_mesh

    class Spy:  # counts displace_mesh calls of the scene writer
        def __init__(self):
            self.scene = pc.Scene()

        def __getattr__(self, name):
            if name == "displace_mesh":
                return lambda *a, **k: calls.append(real(self.scene, *a, **k))
            return getattr(self.scene, name)

    spy_pc = type("PC", (), {"Scene": Spy, "object_random_id": pc.object_random_id, "Camera": pc.Camera})
    scene_writer.to_core(spy_pc, data, warn)
    assert not calls
    # The same mesh with 'DISPLACEMENT' goes through it and moves.
    data, mat, _ = export("DISPLACEMENT")
    scene_writer.to_core(spy_pc, data, warn)
    (out,) = calls
    (mesh,) = data.meshes
    assert out["displaced"] == len(mesh.positions)
    assert np.abs(out["positions"] - mesh.positions).max() > 0.01


def test_huge_displacement_is_shortened_with_a_warning_and_renders():
    from addon import scene_writer
    from addon.core import get_core
    from addon.export import export_scene
    scene("DISPLACEMENT", "plane", "wave", 1e30)()
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    scene_writer.to_core(get_core(), data, warn)
    assert any("huge displacement" in w for w in warn), list(warn)
    img = render_to_array(bpy.context.scene, "PATHLIGHT", samples=2)
    assert np.isfinite(img).all()


def test_a_kept_scene_is_not_reused_for_displaced_meshes():
    """Displaced vertices depend on the materials and the object's transform: persistent data
    builds the scene anew for them (bump-only scenes are still reused)."""
    from addon import render_cache
    for method, reused in (("DISPLACEMENT", False), ("BUMP", True)):
        data, _, _ = export(method)
        assert render_cache._same_geometry(data, data) == reused, method


def test_deformation_steps_move_with_the_displaced_vertices():
    """Deformation blur: the scene writer hands the core the motion steps moved by the same
    offsets as the frame's vertices (Cycles adds the offset to every motion step)."""
    from addon import scene_writer
    from addon.core import get_core
    data, _, warn = export("DISPLACEMENT")
    (mesh,) = data.meshes
    steps = np.stack([mesh.positions, mesh.positions + np.float32([0.0, 0.05, 0.0])])
    mesh.motion_positions = steps
    pc = get_core()
    seen = {}

    class Spy:
        def __init__(self):
            self.scene = pc.Scene()

        def __getattr__(self, name):
            real = getattr(self.scene, name)
            if name in ("add_mesh", "set_mesh_motion"):
                def record(*a, **k):
                    seen[name] = (a, k)
                    return real(*a, **k)
                return record
            return real

    spy_pc = type("PC", (), {"Scene": Spy, "object_random_id": pc.object_random_id, "Camera": pc.Camera})
    scene_writer.to_core(spy_pc, data, warn)
    positions = seen["add_mesh"][0][0]
    offsets = positions - mesh.positions
    assert np.abs(offsets).max() > 0.01
    np.testing.assert_allclose(seen["add_mesh"][1]["undisplaced"], mesh.positions)
    np.testing.assert_allclose(seen["set_mesh_motion"][0][1], steps + offsets[None], atol=1e-6)
