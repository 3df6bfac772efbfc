"""Volume bench scenes (issue 23), built procedurally in bpy like realistic_scenes.py:

- fog_box: a Cornell-style room (white, red and green walls, two boxes) filled with homogeneous
  scattering fog (a Principled Volume cube), lit by one spot light from the ceiling.
- smoke_grid: a Volume object backed by a .vdb file written here (a smoke puff of analytic
  density, no downloads), a Principled Volume material, on a floor under an area light; only
  where the core renders volume objects (see SCENES)."""
import math
import sys
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


def scenes():
    """The scenes this build can render (the smoke grid needs volume objects in the core)."""
    out = {"Fog-filled Cornell box with a spot light": fog_box}
    return out
