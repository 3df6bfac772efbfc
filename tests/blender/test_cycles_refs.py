"""The stored Cycles references (cycles_refs.py): the fingerprint changes with anything the render
reads and with nothing else, the same scene gets the same key in another process, and the
store round-trips float32 exactly."""

import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest

import cycles_refs
from blender_util import empty_scene_with_camera, node_material

HERE = Path(__file__).resolve().parent


def small_scene():
    """A sphere with a node material (a colour, an image texture, a Principled BSDF), a subdivision modifier, a
    creased cube, a point light and a world: one of each kind of data the key must see."""
    sc = empty_scene_with_camera(32)
    sc.render.engine = 'CYCLES'
    bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=6)
    sphere = bpy.context.object
    sphere.modifiers.new("Subdivision", 'SUBSURF').levels = 1
    mat = node_material("Paint", "ShaderNodeBsdfDiffuse", Color=(0.5, 0.2, 0.1, 1.0))
    img = bpy.data.images.new("Tex", 4, 4)
    img.pixels.foreach_set(np.linspace(0, 1, 64, dtype=np.float32))
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Diffuse BSDF"].inputs["Roughness"])
    sphere.data.materials.append(mat)
    # A node with more than 16 sockets of several types (the walk reads those one by one).
    principled = mat.node_tree.nodes.new("ShaderNodeBsdfPrincipled")
    principled.inputs["Metallic"].default_value = 0.5
    mat.node_tree.links.new(principled.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Surface"])
    bpy.ops.mesh.primitive_cube_add(location=(2, 0, 0))
    cube = bpy.context.object.data
    cube.attributes.new("crease_edge", 'FLOAT', 'EDGE').data.foreach_set("value", [0.0] * len(cube.edges))
    light = bpy.data.lights.new("Lamp", 'POINT')
    light.energy = 100.0
    lamp = bpy.data.objects.new("Lamp", light)
    lamp.location = (1, -2, 3)
    sc.collection.objects.link(lamp)
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.5
    sc.world = world
    sc.cycles.samples, sc.cycles.seed = 16, 0
    return sc


def key(sc=None):
    return cycles_refs.fingerprint(sc or bpy.context.scene, "rgba")


def _pixel(sc):
    img = bpy.data.images["Tex"]
    px = np.empty(64, np.float32)
    img.pixels.foreach_get(px)
    px[5] += 0.25
    img.pixels.foreach_set(px)


def _vertex(sc):
    mesh = bpy.data.objects["Sphere"].data
    mesh.vertices[3].co.z += 1e-4


def _crease(sc):
    cube = bpy.data.objects["Cube"].data
    cube.attributes["crease_edge"].data[2].value = 1.0


CHANGES = {
    "material colour": lambda sc: bpy.data.materials["Paint"].node_tree.nodes["Diffuse BSDF"].inputs[
        "Color"].__setattr__("default_value", (0.5, 0.2, 0.11, 1.0)),
    "light power": lambda sc: setattr(bpy.data.lights["Lamp"], "energy", 100.5),
    "one vertex": _vertex,
    "image pixel": _pixel,
    "modifier setting": lambda sc: setattr(bpy.data.objects["Sphere"].modifiers[0], "render_levels", 3),
    "world strength": lambda sc: setattr(
        bpy.data.worlds["World"].node_tree.nodes["Background"].inputs["Strength"], "default_value", 0.6),
    "seed": lambda sc: setattr(sc.cycles, "seed", 1),
    "samples": lambda sc: setattr(sc.cycles, "samples", 17),
    "frame": lambda sc: sc.frame_set(2),
    "visibility flag": lambda sc: setattr(bpy.data.objects["Sphere"], "visible_glossy", False),
    "edge crease": _crease,
    "link": lambda sc: bpy.data.materials["Paint"].node_tree.links.remove(
        bpy.data.materials["Paint"].node_tree.links[0]),
    "resolution": lambda sc: setattr(sc.render, "resolution_x", 33),
    "principled input": lambda sc: setattr(
        bpy.data.materials["Paint"].node_tree.nodes["Principled BSDF"].inputs["Metallic"], "default_value", 0.25),
}


@pytest.fixture(scope="module")
def base_key():
    return key(small_scene())


@pytest.mark.parametrize("change", sorted(CHANGES))
def test_a_change_changes_the_key(base_key, change):
    sc = small_scene()
    assert key(sc) == base_key  # rebuilt the same: the same key
    CHANGES[change](sc)
    assert key(sc) != base_key, change


def test_not_what_cycles_ignores(base_key):
    """The output path, the thread count and Pathlight's own settings do not reach Cycles' image."""
    sc = small_scene()
    sc.render.filepath = "/tmp/somewhere/else.exr"
    sc.render.threads_mode, sc.render.threads = 'FIXED', 3
    if hasattr(sc, "pathlight"):
        sc.pathlight.samples = 12345
    assert key(sc) == base_key


def test_the_same_key_in_another_process(base_key):
    """Another process builds the scene (its mesh primitives come out with their faces in another
    order now and then) and gets the same key."""
    code = ("import sys, os; sys.path[:0] = [%r, %r]\n"
            "import test_cycles_refs as t\n"
            "print('KEY', t.key(t.small_scene()), flush=True)\n"
            "os._exit(0)\n") % (str(HERE), str(HERE.parents[1]))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    keys = [line.split()[1] for line in out.stdout.splitlines() if line.startswith("KEY ")]
    assert keys == [base_key], out.stdout[-2000:] + out.stderr[-2000:]


def test_faces_in_another_order_are_the_same_mesh():
    """The key sees the mesh as a set of faces: the same faces listed in another order (as
    Blender's primitives come out) give the same key; one face's corners rotated do not (that
    splits the quad along the other diagonal)."""
    def quads(order, rotate=False):
        empty_scene_with_camera(8)
        faces = [(0, 1, 2, 3), (1, 4, 5, 2)]
        if rotate:
            faces[0] = (1, 2, 3, 0)
        verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)]
        mesh = bpy.data.meshes.new("Quads")
        mesh.from_pydata(verts, [], [faces[i] for i in order])
        bpy.context.scene.collection.objects.link(bpy.data.objects.new("Quads", mesh))
        return key()
    assert quads([0, 1]) == quads([1, 0])
    assert quads([0, 1]) != quads([0, 1], rotate=True)


def test_store_round_trips_exactly(tmp_path, monkeypatch):
    monkeypatch.setattr(cycles_refs, "REFS_DIR", tmp_path)
    rng = np.random.default_rng(1)
    opaque = rng.random((5, 7, 4), dtype=np.float32)
    opaque[..., 3] = 1.0
    clear = rng.random((5, 7, 4), dtype=np.float32)
    clear[0, 0] = [np.nan, np.inf, -0.0, 1e-38]
    arrays = {"a": opaque, "b": clear, "c": rng.random((3, 2), dtype=np.float32)}
    cycles_refs.store("k" * 32, arrays)
    back = cycles_refs.load("k" * 32)
    assert sorted(back) == sorted(arrays)
    for name, arr in arrays.items():
        assert back[name].dtype == np.float32 and back[name].tobytes() == arr.tobytes(), name
    assert cycles_refs.load("z" * 32) is None


def test_modes(tmp_path, monkeypatch):
    """use: render once, then read; render: never read; check: render and compare, fail when the
    stored image differs; refresh: overwrite."""
    monkeypatch.setattr(cycles_refs, "REFS_DIR", tmp_path)
    monkeypatch.setattr(cycles_refs, "USED_DIR", tmp_path / "used")
    sc = small_scene()
    calls = []

    def render(value=1.0):
        calls.append(value)
        return {"rgba": np.full((2, 2, 4), value, np.float32)}

    for mode in ("use", "use", "render", "check"):
        monkeypatch.setenv("PATHLIGHT_CYCLES_REFS", mode)
        assert cycles_refs.cached(sc, "rgba", render)["rgba"][0, 0, 0] == 1.0
    assert len(calls) == 3  # the second `use` read the file
    monkeypatch.setenv("PATHLIGHT_CYCLES_REFS", "use")
    with pytest.raises(cycles_refs.ReferenceMismatch):
        cycles_refs.cached(sc, "rgba", lambda: render(1.001), refs="check")
    cycles_refs.cached(sc, "rgba", lambda: render(1.0 + 1e-7), refs="check")  # float noise passes
    monkeypatch.setenv("PATHLIGHT_CYCLES_REFS", "refresh")
    cycles_refs.cached(sc, "rgba", lambda: render(2.0))
    monkeypatch.setenv("PATHLIGHT_CYCLES_REFS", "use")
    assert cycles_refs.cached(sc, "rgba", render)["rgba"][0, 0, 0] == 2.0
    used = "".join(p.read_text() for p in (tmp_path / "used").iterdir()).split()
    assert {"stored", "hit", "checked"} <= set(used)
    monkeypatch.setenv("PATHLIGHT_CYCLES_REFS", "bogus")
    with pytest.raises(ValueError):
        cycles_refs.cached(sc, "rgba", render)



def test_timed_and_unset_never_touch_the_store(tmp_path, monkeypatch):
    """A render with a time limit (the bench's equal-time renders) depends on the machine's speed:
    it is never read from or written to the store, whatever the mode; and with the variable unset
    (a bench script, not pytest) the store is off."""
    monkeypatch.setattr(cycles_refs, "REFS_DIR", tmp_path)
    monkeypatch.setattr(cycles_refs, "USED_DIR", tmp_path / "used")
    sc = small_scene()
    calls = []

    def render():
        calls.append(1)
        return {"rgba": np.ones((2, 2, 4), np.float32)}

    monkeypatch.setenv("PATHLIGHT_CYCLES_REFS", "use")
    sc.cycles.time_limit = 0.5
    cycles_refs.cached(sc, "rgba", render)
    cycles_refs.cached(sc, "rgba", render)
    assert len(calls) == 2 and not any(tmp_path.glob("*.plref"))
    sc.cycles.time_limit = 0.0
    monkeypatch.delenv("PATHLIGHT_CYCLES_REFS")
    assert cycles_refs.mode() == "render"
    cycles_refs.cached(sc, "rgba", render)
    assert len(calls) == 3 and not any(tmp_path.glob("*.plref"))
    monkeypatch.setenv("PATHLIGHT_CYCLES_REFS", "use")
    cycles_refs.cached(sc, "rgba", render)
    cycles_refs.cached(sc, "rgba", render)
    assert len(calls) == 4 and len(list(tmp_path.glob("*.plref"))) == 1


def test_a_vdb_written_again_is_the_same_file(tmp_path):
    """OpenVDB writes a random UUID into each file's header: the key reads past it, and past
    nothing else (a changed grid byte still changes it)."""
    head = b" BDV\0\0\0\0" + (224).to_bytes(4, "little") + (12).to_bytes(4, "little") + bytes(4) + b"\1"
    files = []
    for name, uuid, body in (("a", b"F47D43DB-3366-16C7-6BA7-BC4C63449593", b"grid"),
                             ("b", b"20C98150-AECC-8BAF-3F9F-6E5683B7F035", b"grid"),
                             ("c", b"20C98150-AECC-8BAF-3F9F-6E5683B7F035", b"grix")):
        files.append(tmp_path / f"{name}.vdb")
        files[-1].write_bytes(head + uuid + body)
    a, b, c = (cycles_refs._stable_bytes(f) for f in files)
    assert a == b and b != c
    files[0].write_bytes(b"not a vdb" * 10)
    assert cycles_refs._stable_bytes(files[0]) == b"not a vdb" * 10


def test_prune_keeps_what_a_run_used(tmp_path):
    """`build.py test --refs prune` deletes the references no record of the run names."""
    sys.path.insert(0, str(HERE.parents[1]))
    from tools.buildsys.testing import prune_unused
    refs, used = tmp_path / "refs", tmp_path / "used"
    refs.mkdir()
    used.mkdir()
    for name in ("a" * 32 + ".plref", "b" * 32 + ".exr", "c" * 32 + ".plref", ".cccc.plref.tmp1"):
        (refs / name).write_bytes(b"x")
    (used / "gw0-1.txt").write_text(f"{'a' * 32} hit 0.01 0.01 t::x\n")
    (used / "gw1-2.txt").write_text(f"{'b' * 32} stored 1.0 2.0 t::y [p q]\n")
    keys, removed = prune_unused(refs, used)
    assert keys == {"a" * 32, "b" * 32}
    assert sorted(p.name for p in refs.iterdir()) == ["a" * 32 + ".plref", "b" * 32 + ".exr"]
    assert len(removed) == 2
