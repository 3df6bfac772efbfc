"""The Point Density texture (ShaderNodeTexPointDensity): Blender voxelises a particle system or
an object's vertices (node.calc_point_density), the core reads the voxels as a scene grid
(op tex_voxel: Cycles' svm_node_tex_voxel), in Object space (the shading object's generated
coordinates) or World space (the source object's transform and bounds), in volumes only as
Cycles. Against Blender's own Cycles in the same bpy: a vertex cloud as the density of a
volume cube in either space, and an emitting surface (black in both). (Particle sources are
not compared: in this bpy, headless, calc_point_density_minmax finds no particles, so both
engines read 0.)"""
import time

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, Warnings, core_has, load_addon, render_to_array
from light_scenes import camera, empty_scene, mesh_object, plane
from material_scenes import region_means

load_addon()
from addon.export.material import convert_material  # noqa: E402
from test_hetero_volumes import het_scene, needs_het  # noqa: E402

needs_voxel = pytest.mark.skipif(not core_has("VolumeGrid", "from_dense"), reason="the core has no dense grids")


def vertex_cloud(n=40, seed=3, half=0.6, location=(0.0, 0.0, 0.0)):
    """A mesh of n loose vertices in a cube of half-size `half` (not rendered: no faces)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-half, half, (n, 3))
    me = bpy.data.meshes.new("Cloud")
    me.from_pydata([tuple(p) for p in pts], [], [])
    ob = bpy.data.objects.new("Cloud", me)
    group = ob.vertex_groups.new(name="W")  # the Color output's source (loose vertices have no
    for i, wt in enumerate(rng.uniform(0.2, 1.0, n)):  # corner colours for Vertex Color)
        group.add([i], float(wt), 'REPLACE')
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    return ob


def density_node(nodes, source, space='OBJECT', radius=0.3, resolution=40, interpolation='Linear'):
    pd = nodes.new("ShaderNodeTexPointDensity")
    pd.object = source
    pd.point_source = 'OBJECT'
    pd.vertex_color_source = 'VERTEX_WEIGHT'
    pd.vertex_attribute_name = "W"
    pd.space = space
    pd.radius = radius
    pd.resolution = resolution
    pd.interpolation = interpolation
    return pd


def density_volume(source, space='OBJECT', scale=6.0, color=False):
    """Principled Volume of Density = Point Density * scale (a volume program), its Color the
    Point Density's Color (the vertices' colour attribute) where `color`."""
    def build(nodes, link):
        vol = nodes.new("ShaderNodeVolumePrincipled")
        vol.inputs["Color"].default_value = (0.85, 0.8, 0.7, 1.0)
        pd = density_node(nodes, source, space)
        if color:
            link(pd.outputs["Color"], vol.inputs["Color"])
        mul = nodes.new("ShaderNodeMath")
        mul.operation = 'MULTIPLY'
        mul.inputs[1].default_value = scale
        link(pd.outputs["Density"], mul.inputs[0])
        link(mul.outputs[0], vol.inputs["Density"])
        return vol.outputs[0]
    return build


def emitting_plane_material(source, space, output="Density"):
    """Emission of the Point Density's Color, or of white at strength Density."""
    mat = bpy.data.materials.new(f"PD {space} {output}")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    em = nodes.new("ShaderNodeEmission")
    pd = density_node(nodes, source, space, radius=0.35)
    if output == "Density":
        links.new(pd.outputs["Density"], em.inputs["Strength"])
    else:
        links.new(pd.outputs["Color"], em.inputs["Color"])
    links.new(em.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def test_compiler_emits_a_grid_read():
    """A scene export: the grid is made (its voxels Blender's) and read by a tex_voxel op; a
    material compiled outside an export and a node without an object read 0."""
    empty_scene(8)
    cloud = vertex_cloud()
    from addon.export.material import MaterialTable
    table = MaterialTable(Warnings(), depsgraph=bpy.context.evaluated_depsgraph_get())
    mat = bpy.data.materials.new("V")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    links.new(density_volume(cloud)(nodes, links.new), nodes["Material Output"].inputs["Volume"])
    data = table.materials[table.index(mat)]
    assert len(table.grids) == 1 and table.grids[0].channels == 1
    op = next(o for o in data.volume if o[0] == "tex_voxel")
    assert op[3:] == (0, "FAC", "LINEAR", "TEXTURE"), op  # the material has a volume: generated coords
    pd = next(n for n in nodes if n.type == 'TEX_POINTDENSITY')
    pd.cache_point_density(depsgraph=bpy.context.evaluated_depsgraph_get())  # (calc frees it)
    px = np.asarray(pd.calc_point_density(depsgraph=bpy.context.evaluated_depsgraph_get())).reshape(40, 40, 40, 4)
    g = table.grids[0]
    vox = g.voxels((0, 0, 0), (39, 39, 39))  # [i, j, k] = [x, y, z]
    np.testing.assert_array_equal(vox, px[..., 3].transpose(2, 1, 0))
    # Texture space: voxel i's centre at (i + 0.5) / 40.
    np.testing.assert_allclose(g.transform[:3, 3], (0.5 / 40,) * 3)
    # No export (a material preview): Density 0 with a warning; no object: 0, as Cycles.
    w = Warnings()
    vol = convert_material(mat, w, None, None, False).volume
    assert vol is None and len(w) == 1 and "Point Density" in w[0], (vol, w)
    pd.object = None
    w = Warnings()
    assert convert_material(mat, w, None, None, False).volume is None and len(w) == 0, w
    # Density and Color of one node: one calc_point_density (Blender frees its cache after
    # each), two grids; a resolution above the limit: 0, warned; an object without points: 0.
    pd.object = cloud
    vol = next(n for n in nodes if n.type == 'PRINCIPLED_VOLUME')
    links.new(pd.outputs["Color"], vol.inputs["Color"])
    table = MaterialTable(Warnings(), depsgraph=bpy.context.evaluated_depsgraph_get())
    table.index(mat)
    assert [g.channels for g in table.grids] == [3, 1] or [g.channels for g in table.grids] == [1, 3]
    for res, source, warned in ((201, cloud, True), (40, bpy.data.objects.new("E", bpy.data.meshes.new("E")), False)):
        if source.name not in bpy.context.scene.collection.objects:
            bpy.context.scene.collection.objects.link(source)
        pd.object, pd.resolution = source, res
        w = Warnings()
        table = MaterialTable(w, depsgraph=bpy.context.evaluated_depsgraph_get())
        table.index(mat)
        assert len(w) == int(warned) and all(g.max_value == 0.0 for g in table.grids), (res, w)
        assert not warned or table.grids == []


def _compare(ours, ref, what, tol, floor=0.25):
    a, b = region_means(ours), region_means(ref)
    rel = np.abs(a - b) / np.maximum(b, floor * b.mean())
    ratio = ours.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    print(what, "mean ratio", ratio, "worst region", rel.max())
    assert ours.mean() > 0.01
    np.testing.assert_allclose(ratio, 1.0, atol=0.01)
    assert rel.max() < tol, (np.unravel_index(np.argmax(rel), rel.shape), rel.max())


@needs_het
@needs_voxel
@pytest.mark.parametrize("space", ["OBJECT", "WORLD"])
def test_vertex_cloud_volume_agrees_with_cycles(space):
    """A vertex cloud's density in a volume cube under a point light, against Cycles' ray
    marching (as test_hetero_volumes.py): Object space (the cube's generated coordinates), and
    World space (the cloud moved, turned and scaled; the Color output, its vertex weights, as
    the volume's colour)."""
    def build(nodes, link):
        cloud = vertex_cloud()
        if space == 'WORLD':
            cloud.location = (0.1, 0.05, 0.85)
            cloud.rotation_euler = (0.0, 0.3, 0.4)
            cloud.scale = (1.2, 0.9, 1.0)
        return density_volume(cloud, space, color=space == 'WORLD')(nodes, link)
    scene = het_scene(build)
    t0 = time.time()
    ours = render_to_array(scene, samples=1024, max_bounces=8)[..., :3]
    t1 = time.time()
    ref = render_to_array(scene, "CYCLES", samples=1024, max_bounces=8, **BOX_FILTER)[..., :3]
    print(f"pathlight {t1 - t0:.1f} s, cycles {time.time() - t1:.1f} s")
    _compare(ours, ref, f"vertex cloud volume, {space}", 0.03)


@needs_voxel
def test_surfaces_read_zero_as_cycles():
    """Cycles 4.5 evaluates svm_node_tex_voxel in volume shaders only: an emitting plane through
    the cloud whose strength is the Point Density renders black there (stored reference); ours
    too, with a warning naming the node."""
    scene = empty_scene(32)
    cloud = vertex_cloud()
    mat = emitting_plane_material(cloud, 'WORLD', "Density")
    plane("Plane", 2.4, mat, location=(0.0, 0.0, 0.05))
    cam = camera((0.0, 0.0, 4.0))
    cam.data.type = 'ORTHO'
    cam.data.ortho_scale = 2.6
    w = Warnings()
    convert_material(mat, w, None, None, False)
    assert len(w) == 1 and "volumes only" in w[0], w
    ours = render_to_array(scene, samples=4, max_bounces=1)[..., :3]
    ref = render_to_array(scene, "CYCLES", samples=4, max_bounces=1, **BOX_FILTER)[..., :3]
    assert ref.max() == 0.0 and ours.max() == 0.0, (ref.max(), ours.max())
