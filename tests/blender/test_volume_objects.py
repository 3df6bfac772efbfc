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

from blender_util import BOX_FILTER, Warnings, core_available, load_addon, render_to_array
from light_scenes import add_light, box, camera, diffuse_material, empty_scene, plane
from material_scenes import region_means

load_addon()

needs_grids = pytest.mark.skipif(not (core_available() and hasattr(load_addon().core.get_core().Scene,
                                                                   "add_volume_grid")),
                                 reason="the core renders no volume grids")

RES = 20  # voxels per axis of the Volume Cube (coarse: a half-voxel misplacement shows)


def assert_agrees(scene, samples, what, region=0.03):
    """Both engines' renders: something lit, the means within 1 %, every 8x8 region within
    `region` (regions darker than a quarter of the mean held to that)."""
    ours, ref = render_both(scene, samples, what)
    check_agrees(ours, ref, what, region)
    return ours


def check_agrees(ours, ref, what, region=0.03):
    a, b = region_means(ours), region_means(ref)
    rel = np.abs(a - b) / np.maximum(b, 0.25 * b.mean())
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    print(what, "mean ratio", ratio, "worst region", rel.max(), "median", np.median(rel))
    assert ours.mean() > 0.01
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    assert rel.max() < region


def smoke_cube(name, material=None, res=RES):
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
        cube.inputs[f"Resolution {axis}"].default_value = res
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
    assert_agrees(scene, 512, "smoke cube")


@needs_grids
def test_default_volume_shader_agrees_with_cycles():
    """A geometry-nodes volume without a material: Cycles' default volume shader (Principled
    Volume of its defaults reading "density"). Measured: mean 1.0001, worst region 2.7 %."""
    scene = lit_scene()
    smoke_cube("Smoke")
    assert_agrees(scene, 256, "default volume")


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
    # Measured 3.2 % at 640 samples, 4.5 % at 256, at the volume's dim top edge (noise of both
    # engines there); a half-voxel shift or a missing object-space density scale gives 9-10 %.
    assert_agrees(scene, 512, "file volume", region=0.04)


# ---------------------------------------------------------------- export, bad input, cost

def export(warnings):
    from addon.export import export_scene
    return export_scene(bpy.context.evaluated_depsgraph_get(), warnings)


def vdb_file(path, grids):
    """Writes grids (vdb_writer.Grid) to `path`."""
    import vdb_writer as vw
    path.write_bytes(vw.write_vdb(grids))
    return path


def ball_leaf(channels=1):
    """One 8^3 leaf at the origin: a ball of density 2 (vector grids: (2, 1, 0) per voxel)."""
    idx = np.indices((8, 8, 8)).transpose(1, 2, 3, 0)
    inside = np.linalg.norm(idx - 3.5, axis=-1) < 3.5
    values = np.where(inside, 2.0, 0.0).astype(np.float32)
    if channels == 3:
        values = np.stack([values, values * 0.5, values * 0.0], axis=-1)
    return {(0, 0, 0): (values, inside)}


def small_scene():
    scene = empty_scene(16)
    add_light('POINT', location=(1.0, -1.0, 3.0), energy=300.0)
    camera((0.0, -5.0, 1.0), lens=40.0, look_at=(0.0, 0.0, 1.0))
    return scene


@needs_grids
def test_bad_volume_input_warns_and_renders(tmp_path):
    """A missing file, a hostile (truncated) file, an empty grid: each object is left out with
    a warning; a vector grid read as a density renders with its mean, with a warning; the
    render goes on (no exception, no crash)."""
    import vdb_writer as vw
    small_scene()
    mat = principled_volume("PV")
    vector = vw.Grid(name="density", value_type="vec3s", background=(0.0, 0.0, 0.0),
                     transform=("UniformScaleMap", 0.25))
    good = vdb_file(tmp_path / "vector.vdb", [grid_with(vector, ball_leaf(3))])
    data = good.read_bytes()
    (tmp_path / "hostile.vdb").write_bytes(data[: len(data) // 2] + bytes(64))
    vdb_file(tmp_path / "empty.vdb", [vw.Grid(name="density")])
    file_volume("Missing", tmp_path / "nowhere.vdb", mat)
    file_volume("Hostile", tmp_path / "hostile.vdb", mat)
    file_volume("Empty", tmp_path / "empty.vdb", mat)
    file_volume("Vector", good, mat, location=(0.0, 0.0, 0.5))
    warnings = Warnings()
    data = export(warnings)
    text = "\n".join(warnings)
    print(text)
    names = [m.name for m in data.meshes]
    assert names == ["Vector"]
    assert "Volume 'Missing'" in text and "Volume 'Hostile'" in text and "Volume 'Empty'" in text
    assert "vector grid 'density' is read as a float" in text
    img = render_to_array(samples=4)
    assert np.isfinite(img).all()
    assert img[..., :3].max() > 0.0  # the vector grid's ball is lit


def grid_with(grid, leaves):
    grid.leaves = leaves
    return grid


@needs_grids
def test_volume_info_and_default_volume_read_grids(tmp_path):
    """Volume Info's Density reads the grid (as the Attribute node); a volume object without a
    material gets Cycles' default volume (Principled Volume: colour 0.5, the "density" grid);
    a grid name the volume lacks reads 0 (the material is then empty: nothing rendered)."""
    import vdb_writer as vw
    small_scene()
    path = vdb_file(tmp_path / "ball.vdb", [grid_with(vw.Grid(name="density"), ball_leaf())])
    file_volume("Info", path, attribute_volume("Info", node="ShaderNodeVolumeInfo"))
    vol = bpy.data.volumes.new("NoMaterial")
    vol.filepath = str(path)
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("NoMaterial", vol))
    file_volume("Missing grid", path, attribute_volume("Missing", attribute="smoke"))
    warnings = Warnings()
    data = export(warnings)
    assert not warnings, warnings
    by_name = {m.name: slots for m, slots in zip(data.meshes, data.material_slots)}
    assert set(by_name) == {"Info", "NoMaterial"}  # the missing grid's medium is empty
    info = data.materials[by_name["Info"][0]].volume
    assert any(op[0] == "volume_grid" for op in info)
    default = data.materials[by_name["NoMaterial"][0]].volume
    assert [op for op in default if op[0] == "volume_grid"] == [("volume_grid", 2, 0, "FAC", "LINEAR")]
    # Object-space box: active voxels 1..6, their trilinear footprint with values at i + 0.5
    # is [0.5, 7.5], padded half a voxel: index [0, 8], times the voxel size 0.5.
    box = data.meshes[0].positions
    np.testing.assert_allclose(box.min(axis=0), 0.0, atol=1e-6)
    np.testing.assert_allclose(box.max(axis=0), 4.0, atol=1e-6)


@needs_grids
def test_no_volume_objects_cost_nothing():
    """Without volume objects the export has no grids and no program reads one; a textured mesh
    volume's program is unchanged (no grid ops), and the core scene holds no grid."""
    scene = small_scene()
    from light_scenes import box
    box("Fog", 1.0, principled_volume("Fog"))
    warnings = Warnings()
    data = export(warnings)
    assert data.volume_grids == []
    for m in data.materials:
        for prog in (m.program, m.volume if isinstance(m.volume, list) else []):
            assert not any(op[0] == "volume_grid" for op in prog or [])
    # The mesh volume keeps its homogeneous medium (the density attribute applies to volume
    # objects only, as Cycles finds no "density" on a mesh).
    assert isinstance(data.materials[data.material_slots[0][0]].volume, dict)
    from addon import scene_writer
    core_scene = scene_writer.to_core(load_addon().core.get_core(), data)
    assert core_scene.volume_grid_count == 0


@needs_grids
def test_box_respects_clipping(tmp_path):
    """A faint leaf (0.0005 per voxel) far from the ball: below the volume's Clipping (0.001 by
    default) it is left out of the box, as Cycles leaves it out of its mesh; Clipping 0 keeps it."""
    import vdb_writer as vw
    small_scene()
    grid = grid_with(vw.Grid(name="density"), ball_leaf())
    grid.leaves[(64, 0, 0)] = (np.full((8, 8, 8), 0.0005, np.float32), np.ones((8, 8, 8), bool))
    path = vdb_file(tmp_path / "faint.vdb", [grid])
    ob = file_volume("Faint", path, principled_volume("PV"))
    assert ob.data.render.clipping == pytest.approx(0.001)
    box = export(Warnings()).meshes[0].positions
    # The ball's bricks and their neighbours (majorant cells bound a brick's neighbours too):
    # index x up to 15 (+ 2 for the footprint), not the faint leaf's 71.
    assert box.max(axis=0)[0] == pytest.approx((15 + 2) * 0.5)
    ob.data.render.clipping = 0.0
    box = export(Warnings()).meshes[0].positions
    assert box.max(axis=0)[0] == pytest.approx((71 + 2) * 0.5)


def ball_grid(name, fn, voxel=0.125):
    """A 16^3-voxel grid (2x2x2 leaves, all active) of fn(r), r the distance from the centre in
    object units; voxel size `voxel` (the grid spans [0, 2] at 0.125)."""
    import vdb_writer as vw
    g = vw.Grid(name=name, codec="blosc", transform=("UniformScaleMap", voxel))
    for o in [(x, y, z) for x in (0, 8) for y in (0, 8) for z in (0, 8)]:
        idx = np.indices((8, 8, 8)).transpose(1, 2, 3, 0) + np.array(o)
        r = np.linalg.norm((idx + 0.5) * voxel - 8 * voxel, axis=-1)
        g.leaves[o] = (fn(r).astype(np.float32), np.ones((8, 8, 8), bool))
    return g


@needs_grids
def test_temperature_grid_blackbody_agrees_with_cycles(tmp_path):
    """Principled Volume's Temperature times its "temperature" grid drives Blackbody emission
    (a flame: 2400 K at the rim to 3400 K at the centre), density from the "density" grid, no
    lights: the emission alone against Cycles. 512 samples: worst region 2.4 % (at 256, 2.6 %
    before the grid-bound majorants, 3.4 % after: the same estimator, other random numbers)."""
    scene = empty_scene(40)
    scene.cycles.volume_step_rate = 0.25
    scene.cycles.volume_max_steps = 4096
    camera((0.0, -4.0, 1.0), lens=40.0, look_at=(0.0, 0.0, 1.0))
    path = vdb_file(tmp_path / "flame.vdb", [
        ball_grid("density", lambda r: np.clip(1.0 - r / 0.95, 0.0, 1.0) * 1.5),
        ball_grid("temperature", lambda r: np.where(r < 0.95, 1.0 - 0.3 * r / 0.95, 0.0))])
    mat = principled_volume("Flame", density=1.0, color=(0.3, 0.3, 0.3, 1.0))
    vol = next(n for n in mat.node_tree.nodes if n.type == 'PRINCIPLED_VOLUME')
    vol.inputs["Blackbody Intensity"].default_value = 1.0
    vol.inputs["Temperature"].default_value = 3400.0
    file_volume("Flame", path, mat, location=(-1.0, -1.0, 0.0))
    assert_agrees(scene, 512, "flame")


@needs_grids
def test_instances_share_one_box(tmp_path):
    """A volume in a collection instanced twice (and shown itself): one box with three matrices;
    an instance scaled by 2 gets its own material (Cycles' object-space density: 1 / 2)."""
    small_scene()
    path = vdb_file(tmp_path / "ball.vdb", [ball_grid("density", lambda r: np.clip(1.0 - r, 0.0, 1.0))])
    coll = bpy.data.collections.new("Smoke")
    bpy.context.scene.collection.children.link(coll)
    ob = file_volume("Ball", path, principled_volume("PV"))
    bpy.context.scene.collection.objects.unlink(ob)
    coll.objects.link(ob)
    for k, scale in enumerate((1.0, 1.0, 2.0)):
        inst = bpy.data.objects.new(f"Inst{k}", None)
        inst.instance_type = 'COLLECTION'
        inst.instance_collection = coll
        inst.location = (3.0 * k, 0.0, 0.0)
        inst.scale = (scale,) * 3
        bpy.context.scene.collection.objects.link(inst)
    warnings = Warnings()
    data = export(warnings)
    assert not warnings, warnings
    counts = sorted(len(m.matrices) for m in data.meshes)
    assert counts == [1, 3]  # scale 1: the object and two instances; scale 2: one
    assert len(data.volume_grids) == 1
    (big,) = [s for m, s in zip(data.meshes, data.material_slots) if len(m.matrices) == 1]
    (small,) = [s for m, s in zip(data.meshes, data.material_slots) if len(m.matrices) == 3]

    def has_half(slots):
        return any(op[0] == "const" and op[2][0] == pytest.approx(0.5) for op in data.materials[slots[0]].volume)
    assert has_half(big) and not has_half(small)
    # Live edits replace materials by name: the volume compiles have none, and a viewport
    # edit of "PV" re-exports (volume_material_names).
    assert data.material_names[big[0]] == "" and data.volume_material_names == {"PV"}


SMOKE_COLOUR, CUBE_COLOUR = (0.8, 0.7, 0.5, 1.0), (0.8, 0.85, 0.9, 1.0)


def overlap_scene(smoke_colour, cube_colour, anisotropy):
    """The smoke cube (Principled Volume, anisotropy 0) and a homogeneous Volume Scatter cube
    of the given anisotropy, almost wholly inside the smoke's box, where both count."""
    from test_volumes import volume_cube

    scene = lit_scene()
    smoke_cube("Smoke", principled_volume("Smoke", density=1.5, color=smoke_colour))
    scatter = volume_cube("ShaderNodeVolumeScatter", Color=cube_colour, Density=1.0, Anisotropy=anisotropy)
    box("Cube", 1.2, scatter, location=(0.55, -0.35, 0.1), rotation_euler=(0.0, 0.0, 0.4))
    return scene


@needs_grids
def test_volume_object_overlapping_a_volume_cube_agrees_with_cycles():
    """Cycles' volume stack sums every volume a point is in, also a grid's: a homogeneous
    Volume Scatter cube overlapping the smoke cube. Before, the innermost layer alone counted
    there. Both anisotropies 0 (different ones: the test below). 1024 samples: worst region
    2.2 % (at 512, 2.2 % before the grid-bound majorants, 2.9-3.9 % over three seeds after, in
    the same region; against the former renderer at 2048 samples that region is within 1.4 %,
    seed to seed 0.8 %)."""
    scene = overlap_scene(SMOKE_COLOUR, CUBE_COLOUR, 0.0)
    assert_agrees(scene, 1024, "smoke overlapping a cube")


@needs_grids
def test_overlap_with_different_anisotropies_agrees_with_cycles_per_channel():
    """The cube at anisotropy 0.5 over the smoke's 0: where both scatter, the phase function of
    a channel is the mixture of the two weighted by that channel's scattering coefficients.
    Cycles 4.5 weights its phase closures by their channel-averaged weights (the todo in its
    volume_shader_phase_pick), so its coloured render is not the per-channel answer: up to 4 %
    brighter in blue in a band of the overlap. Channels are independent, so the coloured
    scene's blue channel is the grey scene with the blue coefficients everywhere (smoke colour
    0.5, cube 0.9), where channel averages are exact: that scene against Cycles, and our
    coloured render's blue channel against Cycles' render of it. Measured at 512 samples: mean
    ratios 0.9990 and 0.9993, worst regions 2.7 % and 2.8 % (a dim region reached 3.4 % at 768
    samples, so 3.5 % is held); against Cycles' coloured render the blue band is 4.3 % off,
    and 2.3 % with our mixture weighted by channel averages as Cycles'."""
    blue = 2
    grey = tuple(c[blue] for c in (SMOKE_COLOUR, CUBE_COLOUR))
    scene = overlap_scene(SMOKE_COLOUR, CUBE_COLOUR, 0.5)
    coloured = render_to_array(scene, samples=512, max_bounces=8)[..., :3]
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = overlap_scene((grey[0],) * 3 + (1.0,), (grey[1],) * 3 + (1.0,), 0.5)
    ours, ref = render_both(scene, 512, "grey overlap of anisotropies 0 and 0.5")
    check_agrees(ours, ref, "grey overlap of anisotropies 0 and 0.5", region=0.035)
    check_agrees(np.repeat(coloured[..., blue:blue + 1], 3, axis=-1), ref,
                 "coloured overlap's blue channel against the grey one", region=0.035)


@needs_grids
def test_cubic_interpolation_agrees_with_cycles():
    """Volume Interpolation Cubic (Cycles' tricubic B-spline) on a coarse 6^3 smoke cube, where
    it visibly differs from the linear read (regions up to 40 %). At 1024 samples: mean ratio
    0.9986-0.9990, worst region 2.1 % (the dim top edge), median 0.15 %; at 512 the top edge
    reached 3.1 % before the grid-bound majorants and 3.8 % after, so 1024 and 3.5 %."""
    scene = lit_scene()
    scene.cycles.volume_step_rate = 0.5  # (Cycles' tricubic ray marching is slow; the field is smooth)
    mat = principled_volume("Cubic", density=1.5)
    mat.cycles.volume_interpolation = 'CUBIC'
    smoke_cube("Coarse", mat, res=6)
    w = Warnings()
    export(w)
    assert not [m for m in w if "Cubic" in m], w
    cubic = assert_agrees(scene, 1024, "cubic interpolation", region=0.035)
    mat.cycles.volume_interpolation = 'LINEAR'
    linear = render_to_array(scene, samples=128, max_bounces=8)[..., :3]
    a, b = region_means(cubic), region_means(linear)
    diff = np.abs(a - b) / np.maximum(a, 0.25 * a.mean())
    print("cubic vs linear: largest region difference", diff.max())
    assert diff.max() > 0.1
