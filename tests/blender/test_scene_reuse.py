"""Renders that use the mesh cache (animation frames, persistent data) keep their committed
core scene: the next render reuses it, with only the camera, lights, world, materials and
moved matrices set again, when every mesh is unchanged; its image equals a fresh render's."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, render_to_array
from test_animation import _animated_scene

pytestmark = pytest.mark.skipif(not core_available(), reason="core module not built")


def _scene_with_material():
    sc = _animated_scene()
    for obj in (sc.camera, bpy.data.objects["Mover"]):  # moved by hand here, not by keyframes
        obj.animation_data_clear()
    mat = bpy.data.materials.new("Paint")
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.8, 0.2, 0.1, 1.0)
    bpy.data.objects["Mover"].data.materials.append(mat)
    # A textured floor: a kept scene must map its shader programs to the images it holds.
    image = bpy.data.images.new("Checker", 16, 16)
    image.generated_type = 'COLOR_GRID'
    floor = bpy.data.materials.new("Floor")
    floor.use_nodes = True
    nodes, links = floor.node_tree.nodes, floor.node_tree.links
    tex, coords = nodes.new("ShaderNodeTexImage"), nodes.new("ShaderNodeTexCoord")
    tex.image = image
    links.new(coords.outputs["Generated"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], nodes["Principled BSDF"].inputs["Base Color"])
    bpy.data.objects["Floor"].data.materials.append(floor)
    return sc


def _move_camera(sc):
    sc.camera.location.z += 0.4


def _recolour_and_dim(sc):
    bsdf = bpy.data.materials["Paint"].node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.1, 0.3, 0.9, 1.0)
    bpy.data.objects["Lamp"].data.energy = 250.0


def _move_object(sc):
    bpy.data.objects["Mover"].location.x += 0.7


def _edit_mesh(sc):
    mesh = bpy.data.objects["Mover"].data
    mesh.vertices[0].co.z += 0.3
    mesh.update()


STEPS = (None, _move_camera, _recolour_and_dim, _move_object, _edit_mesh)


def _render_steps(persistent):
    from addon import render_cache
    render_cache.clear()
    sc = _scene_with_material()
    sc.render.use_persistent_data = persistent
    images, states = [], []
    kept = render_cache.SCENE_CACHE
    try:
        for step in STEPS:
            if step is not None:
                step(sc)
            images.append(render_to_array(sc))
            if persistent:
                assert len(kept.image_ids) == 1  # the floor's texture is in the core scene
            states.append((kept.reused, kept.scene, kept.scene.stats()["geometry_builds"]
                           if kept.scene is not None else None))
    finally:
        sc.render.use_persistent_data = False
        render_cache.clear()
    return images, states


def test_persistent_data_reuses_the_committed_scene():
    fresh, fresh_states = _render_steps(persistent=False)
    assert all(state == (False, None, None) for state in fresh_states)  # nothing kept
    kept, states = _render_steps(persistent=True)
    reused = [s[0] for s in states]
    # The camera, a material and a light changed: the same scene, no BVH build. A moved
    # (merged) object: the same scene, its geometry rebuilt. An edited mesh: a new scene.
    assert reused == [False, True, True, True, False]
    first = states[0][1]
    assert [s[1] is first for s in states] == [True, True, True, True, False]
    assert [s[2] for s in states] == [1, 1, 1, 2, 1]
    for step, a, b in zip(STEPS, fresh, kept):
        np.testing.assert_array_equal(a, b, err_msg=getattr(step, "__name__", "first render"))
    # Each step changed the image (so the kept scene really took the change).
    for a, b in zip(kept, kept[1:]):
        assert not np.array_equal(a, b)


def _counts(cache):
    """The last export's hits and misses, by object name."""
    return sorted(cache.previous["hit"]), sorted(cache.previous["missed"])


def _cache_counts():
    from addon import render_cache
    return _counts(render_cache.MESH_CACHE)


def _fresh_render(sc):
    """A render of the scene as it is now, from nothing (no persistent data, empty caches)."""
    from addon import render_cache
    sc.render.use_persistent_data = False
    render_cache.clear()
    image = render_to_array(sc)
    sc.render.use_persistent_data = True
    return image


def test_persistent_data_trusts_the_depsgraph_updates(monkeypatch):
    """With persistent data (one view layer) the depsgraph's updates say which meshes changed:
    no fingerprints, unchanged meshes reused, changed ones (an edit, a new modifier, a modifier
    setting, an animated modifier on a new frame) exported again; every image equals a fresh
    render of the same state."""
    from addon import render_cache
    from addon.export import mesh_cache
    calls = []
    real = mesh_cache.mesh_fingerprint
    monkeypatch.setattr(mesh_cache, "mesh_fingerprint", lambda mesh: calls.append(1) or real(mesh))
    render_cache.clear()
    sc = _scene_with_material()
    sc.render.use_persistent_data = True
    floor = bpy.data.objects["Floor"]

    def add_modifier(sc):  # pushes the floor along its normals by half the strength
        floor.modifiers.new("Lift", 'DISPLACE')

    def modifier_setting(sc):
        floor.modifiers["Lift"].strength = 0.2

    def next_frame(sc):  # the strength is animated: the geometry changes with the frame
        lift, frame = floor.modifiers["Lift"], sc.frame_current
        lift.keyframe_insert("strength", frame=frame)
        lift.strength = 0.6
        lift.keyframe_insert("strength", frame=frame + 1)
        sc.frame_set(frame + 1)

    steps = [(None, [], ["Floor", "Mover"]),
             (_move_camera, ["Floor", "Mover"], []),
             (_move_object, ["Floor", "Mover"], []),  # a transform: the same arrays
             (_edit_mesh, ["Floor"], ["Mover"]),
             (add_modifier, ["Mover"], ["Floor"]),
             (modifier_setting, ["Mover"], ["Floor"]),
             (next_frame, ["Mover"], ["Floor"]),
             # Blender re-evaluates animated geometry for every render (it lists it again).
             (None, ["Mover"], ["Floor"]),
             (lambda sc: floor.modifiers.remove(floor.modifiers["Lift"]), ["Mover"], ["Floor"]),
             (None, ["Floor", "Mover"], [])]
    try:
        last = None
        for step, hit, missed in steps:
            if step is not None:
                step(sc)
            image = render_to_array(sc)
            assert _cache_counts() == (hit, missed), getattr(step, "__name__", "no change")
            # Every change shows in the image, so a stale mesh could not pass as a fresh one.
            if last is not None:
                assert (step is None) == np.array_equal(image, last), getattr(step, "__name__", step)
            last = image
            np.testing.assert_array_equal(image, _fresh_render(sc), err_msg=getattr(step, "__name__", ""))
            # _fresh_render emptied the caches: render once more with persistent data, so the
            # next step's render starts from this state's tracked export.
            render_to_array(sc)
        assert calls == []  # tracked renders compute no fingerprints
    finally:
        sc.render.use_persistent_data = False
        render_cache.clear()


def test_a_failed_render_forgets_the_depsgraph_updates(monkeypatch):
    """A render that fails before its export ends has read (and so used up) the depsgraph's
    updates: the next render must not trust them, and exports every mesh again."""
    from addon import render_cache, session
    render_cache.clear()
    sc = _scene_with_material()
    sc.render.use_persistent_data = True
    try:
        render_to_array(sc)
        _edit_mesh(sc)

        def broken():
            raise RuntimeError("no core")
        with monkeypatch.context() as m:
            m.setattr(session, "get_core", broken)
            with pytest.raises(RuntimeError, match="no core"):  # the operator raises the report
                render_to_array(sc)  # the edit's update is gone with this render
        image = render_to_array(sc)
        assert _cache_counts() == ([], ["Floor", "Mover"])
        np.testing.assert_array_equal(image, _fresh_render(sc))
    finally:
        sc.render.use_persistent_data = False
        render_cache.clear()


def test_several_view_layers_compare_fingerprints():
    """With two view layers Blender switches one depsgraph between them, and its updates list
    the switch, not the edits: such renders compare fingerprints."""
    from addon import render_cache
    render_cache.clear()
    sc = _scene_with_material()
    sc.view_layers.new("Second")
    sc.render.use_persistent_data = True
    cache = render_cache.MESH_CACHE

    def render_counts():  # hits and misses over both layers' exports
        hits, misses = cache.hits, cache.misses
        image = render_to_array(sc)
        return image, (cache.hits - hits, cache.misses - misses)
    try:
        render_to_array(sc)
        assert render_counts()[1] == (4, 0)
        _edit_mesh(sc)
        # The first layer exports the edited mesh; the second finds it by its fingerprint.
        image, counts = render_counts()
        assert counts == (3, 1)
        layers = sc.view_layers
        layers.remove(layers["Second"])
        np.testing.assert_array_equal(image, _fresh_render(sc))
    finally:
        sc.render.use_persistent_data = False
        render_cache.clear()


def _instancing_plane():
    """A plane whose geometry nodes put a generated cube on each of its corners (and keep
    the plane): generated geometry, whose `original` is the plane."""
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0.0, 0.0, 0.0))
    plane = bpy.context.active_object
    tree = bpy.data.node_groups.new("Corners", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = tree.nodes, tree.links
    group_in, group_out = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    on_points, cube = nodes.new("GeometryNodeInstanceOnPoints"), nodes.new("GeometryNodeMeshCube")
    join = nodes.new("GeometryNodeJoinGeometry")
    cube.inputs["Size"].default_value = (0.5, 0.5, 0.5)
    links.new(group_in.outputs[0], on_points.inputs["Points"])
    links.new(cube.outputs[0], on_points.inputs["Instance"])
    links.new(on_points.outputs[0], join.inputs[0])
    links.new(group_in.outputs[0], join.inputs[0])
    links.new(join.outputs[0], group_out.inputs[0])
    plane.modifiers.new("Corners", "NODES").node_group = tree
    return plane, cube


@pytest.mark.parametrize("persistent", [True, False])
def test_generated_instances_are_cached_apart_from_their_instancer(persistent):
    """Geometry-nodes instances have their instancer as `original`: under the instancer's key
    they and the plane's own mesh would replace each other (fingerprints: never a hit; trusted
    updates: the wrong arrays). Each has a key of its own and is reused while the instancer is
    unchanged. The plane's empty slot gives it the generated cube's slots, so only the ordinal
    tells their keys apart. Tracked (persistent data) and fingerprinted exports."""
    from addon import render_cache
    from addon.export import export_scene
    from addon.export.mesh_cache import MeshCache
    render_cache.clear()
    sc = _scene_with_material()
    for name in ("Mover", "Floor"):
        bpy.data.objects.remove(bpy.data.objects[name])
    plane, cube = _instancing_plane()
    plane.data.materials.append(None)
    if not persistent:  # the animation path: fingerprints
        cache = MeshCache()
        for _ in range(2):
            data = export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None, cache)
        assert _counts(cache) == (["Plane", "Plane"], [])
        sizes = sorted(len(m.triangles) for m in data.meshes)
        assert sizes == [2, 12]  # the plane's quad and the cube, not one of them twice
        return
    sc.render.use_persistent_data = True
    try:
        render_to_array(sc)
        image = render_to_array(sc)
        assert _cache_counts() == (["Plane", "Plane"], [])
        np.testing.assert_array_equal(image, _fresh_render(sc))
        render_to_array(sc)
        cube.inputs["Size"].default_value = (0.8, 0.8, 0.8)
        bigger = render_to_array(sc)
        assert _cache_counts() == ([], ["Plane", "Plane"])  # the instancer's geometry changed
        assert not np.array_equal(bigger, image)  # the cubes are in view
        np.testing.assert_array_equal(bigger, _fresh_render(sc))
    finally:
        sc.render.use_persistent_data = False
        render_cache.clear()

