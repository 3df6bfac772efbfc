"""Volume bench scenes (issue 23), built procedurally in bpy like realistic_scenes.py:

- fog_box: a Cornell-style room (white, red and green walls, two boxes) filled with homogeneous
  scattering fog (a Principled Volume cube), lit by one spot light from the ceiling.
- smoke_grid: a Volume object backed by a .vdb file written here (a smoke puff of analytic
  density written by Blender's own VolumeGrids.save, no downloads), a Principled Volume
  material, on a floor under an area light."""
import math
import sys
import tempfile
from pathlib import Path

import bpy

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
import material_scenes as ms  # noqa: E402
import realistic_scenes as rs  # noqa: E402

WIDTH, HEIGHT = 80, 80


def open_box(name, size, mats):
    """A Cornell-style box of side `size` from z = 0, open towards -y: floor, ceiling and back
    wall mats[0], the -x wall mats[1], the +x wall mats[2]; normals inwards."""
    s, h = size / 2, size

    def build(bm):
        rs._quad(bm, [(-s, -s, 0), (-s, s, 0), (s, s, 0), (s, -s, 0)])   # floor (up)
        rs._quad(bm, [(-s, -s, h), (s, -s, h), (s, s, h), (-s, s, h)])   # ceiling (down)
        rs._quad(bm, [(-s, s, 0), (-s, s, h), (s, s, h), (s, s, 0)])     # back wall (-y)
        rs._quad(bm, [(-s, -s, 0), (-s, -s, h), (-s, s, h), (-s, s, 0)])  # -x wall (+x)
        rs._quad(bm, [(s, -s, 0), (s, s, 0), (s, s, h), (s, -s, h)])     # +x wall (-x)
        for i, f in enumerate(bm.faces):
            f.material_index = (0, 0, 0, 1, 2)[i]
    return ms.add_mesh_object(name, build, mats)


def fog_box(width=WIDTH, height=HEIGHT, density=0.35):
    scene = rs._empty(width, height)
    white = ms.diffuse("FogWhite", (0.75, 0.75, 0.75))
    open_box("FogRoom", 2.0, (white, ms.diffuse("FogRed", (0.65, 0.06, 0.05)),
                              ms.diffuse("FogGreen", (0.12, 0.45, 0.1))))
    rs.box("FogTall", (0.55, 0.55, 1.1), white, (-0.35, 0.3, 0.55), rotation=0.3)
    rs.box("FogShort", (0.55, 0.55, 0.55), white, (0.4, -0.3, 0.275), rotation=-0.3)
    fog, nodes, links, out = ms.new_material("Fog")
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Density"].default_value = density
    vol.inputs["Color"].default_value = (0.9, 0.9, 0.9, 1.0)
    vol.inputs["Anisotropy"].default_value = 0.2
    links.new(vol.outputs[0], out.inputs["Volume"])
    if hasattr(fog.cycles, "homogeneous_volume"):
        fog.cycles.homogeneous_volume = True
    rs.box("FogVolume", (1.98, 1.98, 1.98), fog, (0.0, 0.0, 1.0))  # inside the walls, open side too
    bpy.ops.object.light_add(type='SPOT', location=(0.0, 0.0, 1.9))
    spot = bpy.context.active_object.data
    spot.energy, spot.spot_size, spot.spot_blend, spot.shadow_soft_size = 150.0, math.radians(70.0), 0.2, 0.05
    ms.add_camera((0.0, -3.6, 1.0), (0.0, 0.0, 1.0), lens=32.0)
    return scene


def smoke_puff_file(path, resolution=64):
    """Writes a smoke puff to the .vdb `path` (Blender's own writer, VolumeGrids.save): a
    geometry-nodes Volume Cube over [-1, 1]^3 whose density is a noise texture shaped by a
    falloff from the centre, then removes the helper object."""
    vol = bpy.data.volumes.new("PuffSource")
    ob = bpy.data.objects.new("PuffSource", vol)
    bpy.context.scene.collection.objects.link(ob)
    ng = bpy.data.node_groups.new("Puff", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    n, link = ng.nodes, ng.links.new
    out, cube = n.new("NodeGroupOutput"), n.new("GeometryNodeVolumeCube")
    pos, length = n.new("GeometryNodeInputPosition"), n.new("ShaderNodeVectorMath")
    length.operation = 'LENGTH'
    noise = n.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 2.5
    noise.inputs["Detail"].default_value = 4.0
    falloff = n.new("ShaderNodeMapRange")
    falloff.inputs["From Min"].default_value, falloff.inputs["From Max"].default_value = 0.2, 0.95
    falloff.inputs["To Min"].default_value, falloff.inputs["To Max"].default_value = 1.0, 0.0
    shape = n.new("ShaderNodeMath")
    shape.operation = 'MULTIPLY'
    dens = n.new("ShaderNodeMapRange")  # the noise (about 0.3-0.7) as 0-6
    dens.inputs["From Min"].default_value, dens.inputs["From Max"].default_value = 0.4, 0.7
    dens.inputs["To Min"].default_value, dens.inputs["To Max"].default_value = 0.0, 6.0
    link(pos.outputs[0], length.inputs[0])
    link(length.outputs["Value"], falloff.inputs["Value"])
    link(pos.outputs[0], noise.inputs["Vector"])
    link(noise.outputs["Fac"], dens.inputs["Value"])
    link(dens.outputs["Result"], shape.inputs[0])
    link(falloff.outputs["Result"], shape.inputs[1])
    link(shape.outputs[0], cube.inputs["Density"])
    cube.inputs["Min"].default_value = (-1.0, -1.0, -1.0)
    cube.inputs["Max"].default_value = (1.0, 1.0, 1.0)
    for axis in "XYZ":
        cube.inputs[f"Resolution {axis}"].default_value = resolution
    link(cube.outputs[0], out.inputs[0])
    ob.modifiers.new("GN", "NODES").node_group = ng
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    if not (ev.data.grids.load() and ev.data.grids.save(str(path))):
        raise RuntimeError("Blender could not write the smoke puff's grids")
    bpy.data.objects.remove(ob)
    bpy.data.volumes.remove(vol)
    return path


_PUFF = Path(tempfile.gettempdir()) / "pathlight_bench_puff.vdb"


def smoke_grid(width=WIDTH, height=HEIGHT):
    scene = rs._empty(width, height)
    smoke_puff_file(_PUFF)
    vol = bpy.data.volumes.new("Smoke")
    vol.filepath = str(_PUFF)
    ob = bpy.data.objects.new("Smoke", vol)
    scene.collection.objects.link(ob)
    ob.location = (0.0, 0.0, 1.05)
    mat, nodes, links, out = ms.new_material("Smoke")
    pv = nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Color"].default_value = (0.85, 0.85, 0.85, 1.0)
    links.new(pv.outputs[0], out.inputs["Volume"])
    ob.data.materials.append(mat)
    ms.add_plane("SmokeFloor", 8.0, ms.diffuse("SmokeFloor", (0.5, 0.5, 0.5)))
    bpy.ops.object.light_add(type='AREA', location=(1.5, -1.0, 3.2))
    area = bpy.context.active_object
    area.data.energy, area.data.size = 600.0, 1.0
    ms.look_at(area, (0.0, 0.0, 1.0))
    ms.set_world((0.05, 0.06, 0.08))
    ms.add_camera((0.0, -4.6, 1.6), (0.0, 0.0, 1.0), lens=40.0)
    return scene


def scenes():
    return {
        "Fog-filled Cornell box with a spot light": fog_box,
        "Smoke grid from a .vdb under an area light": smoke_grid,
    }
