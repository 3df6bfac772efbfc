"""A seed gives one image whatever the process and the thread count, through Blender too
(docs/design/sampling.md; farm split frames rely on it). Renders of the bench scenes built by
the same script used to differ between processes by ~1e-6: Blender's UV sphere comes out with
its faces in a different order in every process, the export's triangles and smooth normals
follow that order, and so did the image. The scene builders' UV spheres now sort their faces
(blender_util.canonical_order); docs/design/robustness.md, "Determinism"."""

import json
import random
import subprocess
import sys

import bmesh
import bpy
import numpy as np
import pytest

from blender_util import REPO, canonical_order, core_available

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def _mesh_arrays(bm):
    me = bpy.data.meshes.new("Canonical")
    bm.to_mesh(me)
    corner_vert = np.empty(len(me.loops), np.int32)
    me.attributes[".corner_vert"].data.foreach_get("value", corner_vert)
    starts = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("loop_start", starts)
    edges = np.empty(2 * len(me.edges), np.int32)
    me.attributes[".edge_verts"].data.foreach_get("value", edges)
    normals = np.empty(3 * len(me.vertices), np.float32)
    me.vertex_normals.foreach_get("vector", normals)  # summed in face order, bit for bit
    bpy.data.meshes.remove(me)
    return corner_vert, starts, edges, normals


def test_canonical_order_undoes_any_face_and_edge_order():
    """The same sphere with its faces and edges shuffled gives the same arrays once sorted,
    Blender's own vertex normals included."""
    arrays = []
    for shuffle in (False, True):
        bm = bmesh.new()
        bmesh.ops.create_uvsphere(bm, u_segments=16, v_segments=8, radius=1.0)
        if shuffle:
            rng = random.Random(5)
            for seq in (bm.faces, bm.edges):
                keys = {e: rng.random() for e in seq}
                seq.sort(key=keys.__getitem__)
            assert not np.array_equal(_mesh_arrays(bm)[0], arrays[0][0])  # the shuffle took
        canonical_order(bm)
        arrays.append(_mesh_arrays(bm))
        bm.free()
    for a, b in zip(*arrays):
        np.testing.assert_array_equal(a, b)


# A child process: builds a small scene of the bench's features (a subdivided smooth model with
# a noise-ramp Principled and brick bump, UV spheres with coat and subsurface, an image-textured
# floor, geometry-nodes instances, an HDR world, a point light), then prints a digest of the
# exported SceneData and the image hash of a render per thread count in argv (in this process,
# one after another: the second reuses the kept scene).
_CHILD = r"""
import dataclasses, hashlib, json, math, sys
sys.path[:0] = [sys.argv[1] + "/tests/" + d for d in ("blender", "core", "bench")]
import bpy, bmesh, numpy as np
import blender_util as bu, light_scenes as ls, material_scenes as ms, realistic_scenes as rs
bu.load_addon()
from addon.export import export_scene

def digest(v, h):
    if isinstance(v, np.ndarray):
        a = np.ascontiguousarray(v)
        h.update(f"{a.dtype.str}{a.shape}".encode()); h.update(a.tobytes())
    elif dataclasses.is_dataclass(v) and not isinstance(v, type):
        for f in dataclasses.fields(v):
            h.update(f.name.encode()); digest(getattr(v, f.name), h)
    elif isinstance(v, dict):
        for k in v:
            h.update(repr(k).encode()); digest(v[k], h)
    elif isinstance(v, (list, tuple)):
        h.update(b"["); [digest(x, h) for x in v]; h.update(b"]")
    elif isinstance(v, float):
        h.update(v.hex().encode())
    elif isinstance(v, (int, str, bool, bytes, type(None), frozenset)):
        h.update(repr(sorted(v) if isinstance(v, frozenset) else v).encode())
    else:
        h.update(type(v).__name__.encode())

scene = rs._empty(40, 30)
bpy.ops.mesh.primitive_monkey_add(size=1.2, location=(-0.6, 0.0, 0.7))
monkey = bpy.context.active_object
monkey.modifiers.new("Subsurf", 'SUBSURF').levels = 1
monkey.data.shade_smooth()
monkey.data.materials.append(rs._textured_principled("Gilded"))
ms.add_sphere("Paint", 0.35, rs.principled("Paint", (0.6, 0.02, 0.02), 0.4, Coat_Weight=1.0),
              location=(0.8, 0.2, 0.35))
ms.add_sphere("Wax", 0.25, rs.principled("Wax", (0.9, 0.75, 0.55), 0.4, Subsurface_Weight=1.0,
              Subsurface_Scale=0.1), location=(0.5, -0.6, 0.25), segments=24, rings=12)
ms.add_plane("Floor", 6.0, ms.textured_material("Tiles", rs._checker_image("TileImage", n=64, tiles=8)))
pebble = ms.add_mesh_object("Pebble", lambda bm: bmesh.ops.create_icosphere(bm, subdivisions=2, radius=0.08),
                            (rs.principled("Stone", (0.4, 0.4, 0.35)),), smooth=True)
pebble.hide_render = True
host = ms.add_plane("Host", 0.01, None, location=(0.0, -1.2, 0.05))
ms.scatter_on_grid(host, pebble, 1.2, 3, scale=(0.7, 1.3), name="Pebbles")
ls.world_image(ls.load_image(ls.synthetic_hdr(64, 32, sun_peak=50.0), name="HDR"))
bpy.ops.object.light_add(type='POINT', location=(2.0, -2.5, 3.5))
bpy.context.active_object.data.energy = 200.0
ms.add_camera((0.0, -4.2, 2.2), (0.0, 0.0, 0.5), lens=40.0)

h = hashlib.sha1()
digest(export_scene(bpy.context.evaluated_depsgraph_get(), lambda msg: None), h)
images = []
for threads in map(int, sys.argv[2].split(",")):
    img = bu.render_to_array(scene, samples=2, seed=3, threads_mode='FIXED', threads=threads)
    assert img[..., :3].mean() > 0.01
    images.append(hashlib.sha1(np.ascontiguousarray(img).tobytes()).hexdigest())
print("DIGEST " + json.dumps({"export": h.hexdigest(), "images": images}))
"""


@needs_core
def test_a_scene_script_renders_the_same_image_in_every_process_and_thread_count():
    """Two fresh processes build the same scene: identical exported arrays and bit-identical
    renders on 2 threads (twice in one process) and on 1."""
    procs = [subprocess.Popen([sys.executable, "-c", _CHILD, str(REPO), threads], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for threads in ("2,2", "1")]
    results = []
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-3000:]
        results.append(json.loads(out.split("DIGEST ", 1)[1].splitlines()[0]))
    a, b = results
    assert a["export"] == b["export"], "the exported scene differs between processes"
    assert len(set(a["images"] + b["images"])) == 1, results
