"""Volume objects (OpenVDB grids, issue 23) through the add-on against Blender's own Cycles in the
same bpy: a geometry-nodes Volume Cube with an analytic density (a ball falling off to 0) under
a point light with a Principled Volume reading its "density" grid; the same grid saved to a .vdb
file and loaded as a file-backed volume with a rotated, scaled object transform (placement);
Volume Info and Attribute reads; bad input (a missing file, a hostile file, a vector grid as
density, an empty grid): warnings and no crash (docs/design/volumes.md "Volume objects")."""
import time

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, core_available, load_addon, render_to_array
from light_scenes import add_light, camera, diffuse_material, empty_scene, plane

load_addon()

needs_grids = pytest.mark.skipif(not (core_available() and hasattr(load_addon().core.get_core().Scene,
                                                                   "add_volume_grid")),
                                 reason="the core renders no volume grids")

RES = 20  # voxels per axis of the Volume Cube (coarse: a half-voxel misplacement shows)


@pytest.fixture(autouse=True, scope="module")
def factory_scene_afterwards():
    yield
    bpy.ops.wm.read_factory_settings(use_empty=True)


def region_means(img, grid=8):
    h, w = img.shape[:2]
    return img[: h // grid * grid, : w // grid * grid].reshape(grid, h // grid, grid, w // grid, -1).mean(axis=(1, 3))


def compare(ours, ref, what):
    a, b = region_means(ours), region_means(ref)
    rel = np.abs(a - b) / np.maximum(b, 0.25 * b.mean())
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    print(what, "mean ratio", ratio, "worst region", rel.max(), "median", np.median(rel))
    return ratio, rel


def smoke_cube(name, material=None):
    """A volume object whose geometry nodes make a Volume Cube over [-1, 1]^3 with density
    3 * clamp(1 - |p| / 0.9), its material set by a Set Material node (a geometry-nodes volume
    has no material otherwise: Cycles' default volume shader)."""
    vol = bpy.data.volumes.new(name)
    ob = bpy.data.objects.new(name, vol)
    bpy.context.scene.collection.objects.link(ob)
    ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    n = ng.nodes
    out = n.new("NodeGroupOutput")
    cube, pos, length = n.new("GeometryNodeVolumeCube"), n.new("GeometryNodeInputPosition"), n.new("ShaderNodeVectorMath")
    length.operation = 'LENGTH'
    ramp = n.new("ShaderNodeMapRange")
    ramp.inputs["From Min"].default_value = 0.0
    ramp.inputs["From Max"].default_value = 0.9
    ramp.inputs["To Min"].default_value = 3.0
    ramp.inputs["To Max"].default_value = 0.0
    ng.links.new(pos.outputs[0], length.inputs[0])
    ng.links.new(length.outputs["Value"], ramp.inputs["Value"])
    ng.links.new(ramp.outputs["Result"], cube.inputs["Density"])
    cube.inputs["Min"].default_value = (-1.0, -1.0, -1.0)
    cube.inputs["Max"].default_value = (1.0, 1.0, 1.0)
    for axis in "XYZ":
        cube.inputs[f"Resolution {axis}"].default_value = RES
    if material is not None:
        setm = n.new("GeometryNodeSetMaterial")
        setm.inputs["Material"].default_value = material
        ng.links.new(cube.outputs[0], setm.inputs["Geometry"])
        ng.links.new(setm.outputs[0], out.inputs[0])
    else:
        ng.links.new(cube.outputs[0], out.inputs[0])
    ob.modifiers.new("GN", "NODES").node_group = ng
    return ob


def principled_volume(name, density=1.0, color=(0.8, 0.7, 0.5, 1.0)):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Density"].default_value = density
    vol.inputs["Color"].default_value = color
    mat.node_tree.links.new(vol.outputs[0], nodes["Material Output"].inputs["Volume"])
    return mat


def attribute_volume(name, attribute="density", node="ShaderNodeAttribute"):
    """Volume Scatter whose Density is a grid read by an Attribute (or Volume Info) node, x 2."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    sc = nodes.new("ShaderNodeVolumeScatter")
    sc.inputs["Color"].default_value = (0.9, 0.8, 0.7, 1.0)
    read = nodes.new(node)
    mul = nodes.new("ShaderNodeMath")
    mul.operation = 'MULTIPLY'
    mul.inputs[1].default_value = 2.0
    if node == "ShaderNodeAttribute":
        read.attribute_name = attribute
        links.new(read.outputs["Fac"], mul.inputs[0])
    else:
        links.new(read.outputs["Density"], mul.inputs[0])
    links.new(mul.outputs[0], sc.inputs["Density"])
    links.new(sc.outputs[0], nodes["Material Output"].inputs["Volume"])
    return mat


def lit_scene(size=48):
    scene = empty_scene(size)
    scene.cycles.volume_step_rate = 0.25
    scene.cycles.volume_max_steps = 4096
    plane("Floor", 8.0, diffuse_material("Floor", 0.6), location=(0.0, 0.0, -1.1))
    add_light('POINT', location=(1.6, -1.4, 2.2), energy=500.0, shadow_soft_size=0.3)
    camera((0.0, -4.2, 1.4), lens=40.0, look_at=(0.0, 0.0, 0.0))
    return scene


def saved_file(ob, path):
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    assert ev.data.grids.load()
    assert ev.data.grids.save(str(path))
    return path


def file_volume(name, path, material, **transform):
    vol = bpy.data.volumes.new(name)
    vol.filepath = str(path)
    ob = bpy.data.objects.new(name, vol)
    bpy.context.scene.collection.objects.link(ob)
    ob.data.materials.append(material)
    for k, v in transform.items():
        setattr(ob, k, v)
    return ob


def render_both(scene, samples, what):
    t0 = time.time()
    ours = render_to_array(scene, samples=samples, max_bounces=8)[..., :3]
    t1 = time.time()
    ref = render_to_array(scene, "CYCLES", samples=samples, max_bounces=8, **BOX_FILTER)[..., :3]
    print(f"{what}: pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    return ours, ref


@needs_grids
def test_smoke_cube_principled_volume_agrees_with_cycles():
    scene = lit_scene()
    smoke_cube("Smoke", principled_volume("Smoke", density=1.5))
    ours, ref = render_both(scene, 512, "smoke cube")
    ratio, rel = compare(ours, ref, "smoke cube")
    assert ours.mean() > 0.01
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    assert rel.max() < 0.03


@needs_grids
def test_file_backed_volume_rotated_and_scaled_agrees_with_cycles(tmp_path):
    """The grid of the smoke cube saved to a .vdb and loaded as a file-backed volume whose object
    is rotated and scaled unevenly; an Attribute node reads the grid (placement: object and grid
    transforms both apply, as Cycles)."""
    scene = lit_scene()
    src = smoke_cube("Source")
    path = saved_file(src, tmp_path / "smoke.vdb")
    bpy.data.objects.remove(src)
    file_volume("FromFile", path, attribute_volume("ByAttribute"), location=(0.1, 0.2, 0.0),
                rotation_euler=(0.3, 0.0, 0.7), scale=(1.1, 0.7, 0.9))
    ours, ref = render_both(scene, 512, "file volume")
    ratio, rel = compare(ours, ref, "file volume")
    assert ours.mean() > 0.01
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    # Measured 3.2 % at 640 samples, 4.5 % at 256, at the volume's dim top edge (noise of both
    # engines there); a half-voxel shift or a missing object-space density scale gives 9-10 %.
    assert rel.max() < 0.04
