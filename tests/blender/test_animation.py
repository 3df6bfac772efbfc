"""Animation renders: every frame of a moving object and camera, each equal to a single-frame
render of that frame, with unchanged meshes served from the export cache."""

import math
import tempfile
from pathlib import Path

import bpy
import numpy as np
import pytest

from blender_util import _setup_pathlight, core_available, empty_scene_with_camera, \
    load_addon, read_exr, render_to_array

pytestmark = pytest.mark.skipif(not core_available(), reason="core module not built")


def _animated_scene():
    load_addon()
    sc = empty_scene_with_camera(24)
    import bmesh
    for name, size, loc in (("Mover", 1.0, (-1.0, 0.0, 0.0)), ("Floor", 6.0, (0.0, 0.0, -1.0))):
        mesh = bpy.data.meshes.new(name)
        bm = bmesh.new()
        bmesh.ops.create_cube(bm, size=size)
        bm.to_mesh(mesh)
        bm.free()
        obj = bpy.data.objects.new(name, mesh)
        obj.location = loc
        if name == "Floor":
            obj.scale = (1.0, 1.0, 0.05)
        sc.collection.objects.link(obj)
    mover, cam = bpy.data.objects["Mover"], sc.camera
    for frame, x in ((1, -1.0), (3, 1.0)):
        mover.location.x = x
        mover.keyframe_insert("location", frame=frame)
    for frame, z in ((1, 0.0), (3, 0.6)):
        cam.location.z = z
        cam.keyframe_insert("location", frame=frame)
    light = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    light.location = (0.0, -3.0, 3.0)
    light.data.energy = 400.0
    sc.collection.objects.link(light)
    sc.frame_start, sc.frame_end = 1, 3
    sc.render.engine = "PATHLIGHT"
    sc.pathlight.samples = 4
    sc.render.threads_mode = "FIXED"; sc.render.threads = 1
    sc.pathlight.use_animated_seed = True
    _setup_pathlight(sc.pathlight)  # the settings render_to_array uses for single frames
    return sc


def test_animation_frames_match_single_frames_and_reuse_meshes(monkeypatch):
    from addon import render_cache
    # As in interactive Blender, where the cache is emptied when the job ends (a background
    # process keeps it: see test_render_frame_range_jobs_keep_the_cache_in_background).
    keep = render_cache.keep_between_jobs
    monkeypatch.setattr(render_cache, "keep_between_jobs",
                        lambda scene: keep(scene, background=False))
    sc = _animated_scene()
    stats = []

    def record(scene, *args):
        stats.append(dict(render_cache.MESH_CACHE.previous))
    bpy.app.handlers.render_post.append(record)
    try:
        with tempfile.TemporaryDirectory(prefix="pathlight_anim_") as tmp:
            r = sc.render
            image = r.image_settings
            image.file_format, image.color_mode, image.color_depth = 'OPEN_EXR', 'RGBA', '32'
            sc.view_settings.view_transform = 'Standard'
            r.use_compositing = r.use_sequencer = False
            r.filepath = str(Path(tmp) / "frame_####")
            r.use_file_extension = True
            bpy.ops.render.render(animation=True, scene=sc.name)
            frames = [read_exr(Path(tmp) / f"frame_{f:04d}.exr") for f in (1, 2, 3)]
    finally:
        bpy.app.handlers.render_post.remove(record)

    # Frame 1 exports both meshes; frames 2 and 3 only move the mover: both come from the cache.
    assert [(s["hits"], s["misses"]) for s in stats] == [(0, 2), (2, 0), (2, 0)]
    # The job is over and the scene has no persistent data: the cache was emptied.
    assert not render_cache.MESH_CACHE._entries

    assert not np.allclose(frames[0], frames[1]) and not np.allclose(frames[1], frames[2])
    for f in (1, 2, 3):
        sc.frame_set(f)
        np.testing.assert_array_equal(frames[f - 1], render_to_array(sc))


def test_mesh_cache_sees_geometry_changes():
    """An edited mesh (same datablock) is exported again; an unchanged one is not."""
    from addon.export import export_scene
    from addon.export.mesh_cache import MeshCache
    sc = _animated_scene()
    cache = MeshCache()
    dg = bpy.context.evaluated_depsgraph_get()
    export_scene(dg, lambda m: None, cache)
    assert (cache.previous["hits"], cache.previous["misses"]) == (0, 2)
    mesh = bpy.data.objects["Mover"].data
    mesh.vertices[0].co.z += 0.25
    mesh.update()
    dg = bpy.context.evaluated_depsgraph_get()
    data = export_scene(dg, lambda m: None, cache)
    assert cache.previous["missed"] == ["Mover"] and cache.previous["hit"] == ["Floor"]
    mover = next(m for m in data.meshes if m.name == "Mover")
    assert np.isclose(mover.positions[0, 2], -0.25)  # the edit is in the export
    # Adding a modifier changes the evaluated geometry too.
    bpy.data.objects["Floor"].modifiers.new("Bevel", 'BEVEL')
    dg = bpy.context.evaluated_depsgraph_get()
    export_scene(dg, lambda m: None, cache)
    assert cache.previous["missed"] == ["Floor"]


def _one_frame_jobs(sc, frames, tmp):
    """What `blender -b file -f 1..3` does: one RE_RenderAnim(frame, frame) job per frame
    (creator_args.cc, arg_handle_frame_render). Returns each job's export-cache counts."""
    from addon import render_cache
    stats = []

    def record(scene, *args):
        stats.append((render_cache.MESH_CACHE.previous["hits"],
                      render_cache.MESH_CACHE.previous["misses"]))
    bpy.app.handlers.render_post.append(record)
    try:
        r = sc.render
        r.image_settings.file_format = 'PNG'
        r.use_compositing = r.use_sequencer = False
        r.filepath = str(Path(tmp) / "f_####")
        for f in frames:
            sc.frame_start = sc.frame_end = f
            bpy.ops.render.render(animation=True, scene=sc.name)
    finally:
        bpy.app.handlers.render_post.remove(record)
    return stats


def test_render_frame_range_jobs_keep_the_cache_in_background(monkeypatch):
    """`--render-frame A..B` (a Flamenco chunk) renders each frame as its own job: in a
    background process the cache survives from job to job, so unchanged meshes are exported
    once per chunk; interactive Blender empties it after every job."""
    from addon import render_cache
    assert bpy.app.background  # the bpy module runs as background Blender
    sc = _animated_scene()
    render_cache.MESH_CACHE.clear()
    with tempfile.TemporaryDirectory(prefix="pathlight_chunk_") as tmp:
        assert _one_frame_jobs(sc, (1, 2, 3), tmp) == [(0, 2), (2, 0), (2, 0)]
        assert render_cache.MESH_CACHE._entries  # kept after the last job too
        # Loading a file empties it.
        blend = str(Path(tmp) / "chunk.blend")
        bpy.ops.wm.save_as_mainfile(filepath=blend)
        bpy.ops.wm.open_mainfile(filepath=blend)
        assert not render_cache.MESH_CACHE._entries
        sc = bpy.context.scene
        # Interactive Blender: every job starts from an empty cache, unless the scene uses
        # persistent data.
        assert not render_cache.keep_between_jobs(sc, background=False)
        assert render_cache.keep_between_jobs(sc)
        keep = render_cache.keep_between_jobs
        monkeypatch.setattr(render_cache, "keep_between_jobs",
                            lambda scene: keep(scene, background=False))
        assert _one_frame_jobs(sc, (1, 2), tmp) == [(0, 2), (0, 2)]
        assert not render_cache.MESH_CACHE._entries
        sc.render.use_persistent_data = True
        assert keep(sc, background=False)


def test_single_frame_renders_skip_the_cache(monkeypatch):
    """A single-frame render (F12, render(write_still=True)) of a scene without persistent data
    computes no fingerprints (nothing could reuse its meshes; they cost about half of a big
    mesh's export) and leaves no entries; with persistent data it fills the cache, and the
    depsgraph's updates, not fingerprints, say what the next render can reuse."""
    from addon import render_cache
    from addon.export import mesh_cache
    calls = []
    real = mesh_cache.mesh_fingerprint
    monkeypatch.setattr(mesh_cache, "mesh_fingerprint", lambda mesh: calls.append(1) or real(mesh))
    sc = _animated_scene()
    render_cache.MESH_CACHE.clear()
    image = render_to_array(sc)
    assert image[..., :3].mean() > 0.0  # rendered the scene
    assert calls == [] and not render_cache.MESH_CACHE._entries
    sc.render.use_persistent_data = True
    try:
        render_to_array(sc)
        assert calls == [] and len(render_cache.MESH_CACHE._entries) == 2
        render_to_array(sc)
        assert render_cache.MESH_CACHE.previous["hits"] == 2 and calls == []
    finally:
        sc.render.use_persistent_data = False
        render_cache.MESH_CACHE.clear()


def _raw_mesh(co, corner_verts, loop_starts):
    me = bpy.data.meshes.new("Raw")
    me.vertices.add(len(co))
    me.vertices.foreach_set("co", np.asarray(co, np.float32).ravel())
    me.loops.add(len(corner_verts))
    me.loops.foreach_set("vertex_index", np.asarray(corner_verts, np.int32))
    me.polygons.add(len(loop_starts))
    me.polygons.foreach_set("loop_start", np.asarray(loop_starts, np.int32))
    me.update(calc_edges=True)
    return me


def test_mesh_fingerprint_sees_what_the_export_reads():
    """The fingerprint (raw arrays only) changes with positions, the split of the corners into
    faces, face and corner attributes (sharp faces, materials, UVs), and not with selection."""
    from addon.export.mesh_cache import mesh_fingerprint
    load_addon()
    co = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0), (3, 0.5, 0)]
    cv = [0, 1, 2, 3, 1, 4, 5, 2, 4, 6, 5]
    base = mesh_fingerprint(_raw_mesh(co, cv, [0, 4, 8]))
    assert mesh_fingerprint(_raw_mesh(co, cv, [0, 4, 8])) == base  # deterministic
    moved = [list(p) for p in co]
    moved[6][2] = 0.5
    assert mesh_fingerprint(_raw_mesh(moved, cv, [0, 4, 8])) != base
    assert mesh_fingerprint(_raw_mesh(co, cv, [0, 4, 7])) != base  # same corners, other faces
    # Each edit against the same mesh with the attribute present but unchanged.
    for edit in ("sharp", "material", "uv", "select"):
        prints = []
        for change in (False, True):
            me = _raw_mesh(co, cv, [0, 4, 8])
            if edit == "sharp":
                me.shade_smooth()
                me.polygons[0].use_smooth = not change
            elif edit == "material":
                me.polygons[0].material_index = 1
                me.polygons[2].material_index = 1 if change else 0
            elif edit == "uv":
                me.uv_layers.new(name="UVMap").uv[3].vector = (0.5, 0.25 if change else 0.0)
            else:
                me.vertices[0].select = me.polygons[1].select = True
                me.polygons[0].select = me.vertices[2].select = change
            prints.append(mesh_fingerprint(me))
        assert (prints[0] != prints[1]) == (edit != "select"), edit
