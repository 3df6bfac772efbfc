"""View layer settings Cycles 4.5 honours (addon/export/view_layer.py), against Cycles in the same
bpy where the image shows them, else by a property that must hold: Material Override, World
Override, the Filter toggles (Environment, Surfaces, Curves, Volumes, Motion Blur), the
layer's Samples, and two view layers in one render, with the export caches in between.

The scene (32x32, box filter): a grey floor and a red sphere in collection "Ground" / "Props",
a small emissive panel (a mesh light), a point light, a bluish world; hair strands and a point
cloud where the filters need them. Tolerances: material_scenes.assert_agree's (mean 1 %,
8x8 regions 3 %; dark regions absolutely against 0.02) unless said."""

import functools
import math
import tempfile
from pathlib import Path

import bpy
import numpy as np
import pytest

import cycles_refs
import material_scenes as ms
from blender_util import BOX_FILTER, Warnings, core_available, load_addon, node_material, render_to_array
from material_scenes import assert_agree

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

SAMPLES = 1024
CYCLES_SAMPLES = 1024  # (stored: costs no test time)
BOUNCES = 6


def _collection(name, objs):
    col = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(col)
    for ob in objs:
        for c in list(ob.users_collection):
            c.objects.unlink(ob)
        col.objects.link(ob)
    return col


def layer_scene(hair=False, cloud=False):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = 32
    scene.render.resolution_percentage = 100
    floor = ms.add_plane("Floor", 8.0, ms.diffuse("FloorMat", (0.5, 0.5, 0.5)))
    ball = ms.add_sphere("Ball", 0.7, ms.diffuse("Red", (0.8, 0.1, 0.05)), location=(-0.4, 0.3, 0.7))
    panel = ms.add_plane("Panel", 0.8, ms.emission("Glow", (1.0, 0.8, 0.4), 6.0), location=(0.9, -0.2, 0.9),
                         rotation_euler=(0.0, math.radians(-70), 0.0))
    extra = []
    if hair:
        from test_hair import add_hair
        strands = add_hair("Strands", node_material("HairMat", "ShaderNodeBsdfDiffuse", Color=(0.1, 0.6, 0.2, 1)),
                           strands=4, keys=4, radius=0.08, length=4.0, sag=0.0, spacing=0.5)
        strands.location = (0.0, -1.0, 0.2)
        extra.append(strands)
    if cloud:
        from test_point_clouds import add_cloud
        pebbles = add_cloud("Pebbles", node_material("PebbleMat", "ShaderNodeBsdfDiffuse", Color=(0.2, 0.3, 0.8, 1)),
                            n=10, spread=2.0, radii=np.full(10, 0.2), seed=5)
        pebbles.location = (0.6, 0.8, 0.0)
        extra.append(pebbles)
    _collection("Ground", [floor])
    _collection("Props", [ball, panel] + extra)
    light = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", 'POINT'))
    light.data.energy = 300.0
    light.data.shadow_soft_size = 0.3
    light.location = (-1.5, -1.5, 3.0)
    scene.collection.objects.link(light)
    ms.add_camera((0.0, -5.5, 2.2), (0.0, 0.0, 0.6), lens=35.0)
    scene.world = constant_world("Sky", (0.2, 0.3, 0.5))
    return scene


def constant_world(name, color, strength=1.0):
    world = bpy.data.worlds.new(name)
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    return world


def clay():
    return node_material("Clay", "ShaderNodeBsdfDiffuse", Color=(0.8, 0.8, 0.8, 1))


def pair(build, what, samples=SAMPLES, **settings):
    """Pathlight's and Cycles' renders of build()'s scene, compared; returns them."""
    ours = render_to_array(build(), "PATHLIGHT", samples=samples, max_bounces=BOUNCES, **settings)
    cycles = render_to_array(build(), "CYCLES", samples=CYCLES_SAMPLES, max_bounces=BOUNCES,
                             **BOX_FILTER, **settings)
    assert_agree(ours, cycles, what)
    return ours, cycles


def cycles_of(build):
    return render_to_array(build(), "CYCLES", samples=CYCLES_SAMPLES, max_bounces=BOUNCES, **BOX_FILTER)


# ------------------------------------------------------------------ Material Override


def override_scene():
    scene = layer_scene(hair=True, cloud=True)
    scene.view_layers[0].material_override = clay()
    return scene


def test_material_override_as_cycles():
    """Every surface clay: meshes (the mesh light's emission gone with its material), hair and
    points; lamps and the world keep their own shaders."""
    ours, cycles = pair(override_scene, "material override")
    plain = cycles_of(functools.partial(layer_scene, hair=True, cloud=True))
    # (the override is visible: the red ball and the glowing panel turn grey)
    assert np.abs(plain[..., :3] - cycles[..., :3]).mean() > 0.05


def test_material_override_export_slots():
    """Each slot takes the override, an object without slots too; the export's materials hold
    the override alone (plus nothing of the objects' own)."""
    from addon.export import export_scene
    scene = override_scene()
    bare = ms.add_sphere("Bare", 0.2, None, location=(1.5, 1.5, 0.3))
    assert not bare.material_slots
    data = export_scene(bpy.context.evaluated_depsgraph_get(), Warnings())
    names = {n for n in data.material_names if n}
    assert names == {"Clay"}, names
    for mesh, slots in zip(data.meshes, data.material_slots):
        assert slots and all(data.material_names[i] == "Clay" for i in slots), mesh.name
    assert all(data.material_names[i] == "Clay" for i in data.curve_materials + data.point_materials)
    scene.view_layers[0].material_override = None
    data = export_scene(bpy.context.evaluated_depsgraph_get(), Warnings())
    assert {"Red", "Glow", "FloorMat"} <= set(data.material_names)


def volume_override_scene():
    from test_volume_objects import principled_volume, smoke_cube
    scene = layer_scene()
    smoke = smoke_cube("Smoke", principled_volume("Fog", density=2.0))
    smoke.scale = (0.5, 0.5, 0.5)
    smoke.location = (0.8, -0.8, 0.6)
    scene.view_layers[0].material_override = clay()
    return scene


def test_material_override_on_a_volume_object_as_cycles():
    """A volume object takes the (surface-only) override too, as Cycles: the smoke is gone."""
    pair(volume_override_scene, "material override on a volume object", samples=256)


# ------------------------------------------------------------------ World Override


def world_override_scene():
    scene = layer_scene()
    scene.view_layers[0].world_override = constant_world("Dusk", (0.6, 0.25, 0.1), 1.5)
    return scene


def test_world_override_as_cycles():
    ours, cycles = pair(world_override_scene, "world override")
    plain = cycles_of(layer_scene)
    assert np.abs(plain[..., :3] - cycles[..., :3]).mean() > 0.05
    # The sky's corner takes the override's colour (orange, not the scene world's blue).
    assert ours[0, 0, 0] > ours[0, 0, 2]


# ------------------------------------------------------------------ Filter


def filtered_scene(prop):
    scene = layer_scene(hair=True, cloud=True)
    setattr(scene.view_layers[0], prop, False)
    return scene


@pytest.mark.parametrize("prop", ["use_sky", "use_solid", "use_strand"])
def test_filter_as_cycles(prop):
    """Environment off: the world black to every ray (no light from it either). Surfaces off:
    meshes gone altogether (no shadows, no mesh light); points stay. Curves off: hair gone."""
    build = functools.partial(filtered_scene, prop)
    ours, cycles = pair(build, f"{prop} off")
    plain = cycles_of(functools.partial(layer_scene, hair=True, cloud=True))
    assert np.abs(plain[..., :3] - cycles[..., :3]).mean() > 0.01, "the filter shows in Cycles"


def test_volumes_filter_drops_volume_objects():
    """Volumes off: volume objects are not exported (Cycles syncs them without grids); a
    volume in a mesh's material stays (its geometry is a surface's)."""
    from addon.export import export_scene
    from test_volume_objects import principled_volume, smoke_cube
    layer_scene()
    smoke_cube("Smoke", principled_volume("Fog"))
    ms.add_sphere("Globe", 0.3, principled_volume("Inside"), location=(1.0, 1.0, 0.5))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    with_volumes = export_scene(depsgraph, Warnings())
    assert with_volumes.volume_grids
    bpy.context.view_layer.use_volumes = False
    depsgraph = bpy.context.evaluated_depsgraph_get()
    without = export_scene(depsgraph, Warnings())
    assert not without.volume_grids
    assert len(without.meshes) == len(with_volumes.meshes) - 1
    assert "Inside" in without.material_names


def moving_scene(layer_blur):
    scene = layer_scene()
    ball = scene.objects["Ball"]
    scene.frame_set(1)
    ball.location.x = -1.0
    ball.keyframe_insert("location", frame=1)
    ball.location.x = 1.0
    ball.keyframe_insert("location", frame=2)
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    scene.view_layers[0].use_motion_blur = layer_blur
    return scene


def test_motion_blur_filter():
    """The layer's Motion Blur off renders as the scene's off, bit for bit; on, it blurs."""
    off = render_to_array(moving_scene(False), samples=16, max_bounces=BOUNCES)
    scene = moving_scene(True)
    scene.render.use_motion_blur = False
    np.testing.assert_array_equal(off, render_to_array(scene, samples=16, max_bounces=BOUNCES))
    on = render_to_array(moving_scene(True), samples=16, max_bounces=BOUNCES)
    assert np.abs(on - off).mean() > 1e-3


# ------------------------------------------------------------------ Samples


class Props:
    def __init__(self, samples, offset=0, frame_samples=0, mode='USE'):
        self.samples, self.sample_offset, self.frame_samples, self.use_layer_samples = \
            samples, offset, frame_samples, mode


class Layer:
    def __init__(self, samples):
        self.samples = samples


def test_layer_samples_rule():
    from addon.session import layer_samples
    assert layer_samples(Props(128), Layer(0)) is None  # 0: the scene's
    assert layer_samples(Props(128), Layer(16)) == (16, 0)
    assert layer_samples(Props(128), Layer(500)) == (500, 0)
    assert layer_samples(Props(128, mode='BOUNDED'), Layer(500)) is None
    assert layer_samples(Props(128, mode='BOUNDED'), Layer(16)) == (16, 0)
    assert layer_samples(Props(128, mode='IGNORE'), Layer(16)) is None
    # Farm pieces of a 128-sample frame, the layer 100: [64, 128) is cut to [64, 100), the
    # blue noise laid out for 100; a piece past 100 renders nothing.
    assert layer_samples(Props(64, 64, 128), Layer(100)) == (36, 100)
    assert layer_samples(Props(64, 0, 128), Layer(100)) == (64, 100)
    assert layer_samples(Props(28, 100, 128), Layer(100)) == (0, 100)
    assert layer_samples(Props(64, 64, 128, 'BOUNDED'), Layer(200)) is None


def test_layer_samples_render_as_the_scenes():
    """A layer's 4 samples over the scene's 64 render exactly as the scene's 4 samples."""
    scene = layer_scene()
    scene.view_layers[0].samples = 4
    layered = render_to_array(scene, samples=64, max_bounces=BOUNCES)
    scene.view_layers[0].samples = 0
    np.testing.assert_array_equal(layered, render_to_array(scene, samples=4, max_bounces=BOUNCES))
    assert np.abs(layered - render_to_array(scene, samples=64, max_bounces=BOUNCES)).mean() > 1e-4


# ------------------------------------------------------------------ Indirect Only


def indirect_scene(case):
    """Props Indirect Only (the ball and panel unseen, their shadow, light and bounce kept);
    with Holdout as well (holdout wins: Cycles clears Indirect Only on held-out objects); or the
    floor a shadow catcher in an Indirect Only collection (the camera sees past it)."""
    scene = layer_scene(hair=True, cloud=True)
    layers = scene.view_layers[0].layer_collection.children
    if case == "catcher":
        scene.objects["Floor"].is_shadow_catcher = True
        layers["Ground"].indirect_only = True
    else:
        layers["Props"].indirect_only = True
        layers["Props"].holdout = case == "holdout"
    return scene


@pytest.mark.parametrize("case", ["indirect", "holdout", "catcher"])
def test_indirect_only_as_cycles(case):
    build = functools.partial(indirect_scene, case)
    ours, cycles = pair(build, f"indirect only ({case})")
    np.testing.assert_allclose(ours[..., 3].mean(), cycles[..., 3].mean(), atol=0.01)
    plain = cycles_of(functools.partial(layer_scene, hair=True, cloud=True))
    assert np.abs(plain - cycles).mean() > 0.01, "the collection's setting shows in Cycles"


def test_indirect_only_export():
    from addon.export import export_scene
    indirect_scene("indirect")
    data = export_scene(bpy.context.evaluated_depsgraph_get(), Warnings())
    flags = {owner[0]: info[9] for m in data.meshes for owner, info in zip(m.owners, m.infos)}
    assert flags == {"Floor": False, "Ball": True, "Panel": True}
    assert all(info[9] for c in data.curves + data.points for info in c.infos)
    bpy.context.view_layer.layer_collection.children["Props"].holdout = True
    data = export_scene(bpy.context.evaluated_depsgraph_get(), Warnings())
    assert not any(info[9] for m in data.meshes for info in m.infos)  # holdout wins


# ------------------------------------------------------------------ Two view layers


def two_layer_scene():
    """Layer "Clay": clay override, Props Indirect Only. Layer "Cutout": Ground excluded, the
    sphere's collection held out."""
    scene = layer_scene()
    first = scene.view_layers[0]
    first.name = "Clay"
    first.material_override = clay()
    first.layer_collection.children["Props"].indirect_only = True
    second = scene.view_layers.new("Cutout")
    second.layer_collection.children["Ground"].exclude = True
    second.layer_collection.children["Props"].holdout = True
    scene.render.film_transparent = False
    return scene


def three_layer_scene():
    """Three layers of the same objects: "Plain", "Ghost" (Props Indirect Only), "Clay" (the
    override): the same meshes each time, so the caches would hand them on if anything let them."""
    scene = layer_scene()
    scene.view_layers[0].name = "Plain"
    scene.view_layers.new("Ghost").layer_collection.children["Props"].indirect_only = True
    scene.view_layers.new("Clay").material_override = clay()
    return scene


def layer_images(scene, path, layers):
    """{layer: RGBA (H, W, 4)} of a multilayer EXR render of every view layer."""
    import OpenEXR
    scene.render.use_compositing = scene.render.use_sequencer = False
    image = scene.render.image_settings
    image.file_format, image.color_depth, image.exr_codec = 'OPEN_EXR_MULTILAYER', '32', 'ZIP'
    scene.render.filepath = str(path)
    scene.render.use_file_extension = False

    def read(p):
        with OpenEXR.File(str(p), separate_channels=True) as exr:
            ch = exr.channels()
            return {name: np.stack([np.array(ch[f"{name}.Combined.{c}"].pixels, np.float32) for c in "RGBA"], -1)
                    for name in layers}

    def run():
        bpy.ops.render.render(write_still=True, scene=scene.name)

    if scene.render.engine == "CYCLES":
        cycles_refs.cached_file(scene, "multilayer", path, run, read, None)
    return read(path) if scene.render.engine == "CYCLES" else (run(), read(path))[1]


def render_layers(scene, engine, path, samples):
    from blender_util import _setup_cycles, _setup_pathlight
    scene.render.engine = engine
    if engine == "CYCLES":
        _setup_cycles(scene.cycles, BOUNCES)
        scene.cycles.samples = samples
        scene.cycles.pixel_filter_type, scene.cycles.filter_width = 'BOX', 1.0
    else:
        _setup_pathlight(scene.pathlight)
        scene.pathlight.samples, scene.pathlight.max_bounces = samples, BOUNCES
    return layer_images(scene, path, [vl.name for vl in scene.view_layers if vl.use])


def test_two_view_layers_as_cycles(tmp_path):
    scene = two_layer_scene()
    cycles = render_layers(scene, "CYCLES", tmp_path / "cycles.exr", CYCLES_SAMPLES)
    ours = render_layers(two_layer_scene(), "PATHLIGHT", tmp_path / "ours.exr", SAMPLES)
    for name in ("Clay", "Cutout"):
        assert_agree(ours[name][..., :3], cycles[name][..., :3], name)
        np.testing.assert_allclose(ours[name][..., 3].mean(), cycles[name][..., 3].mean(), atol=0.01)
    # Cutout: no floor, and the held-out sphere and panel leave the film transparent.
    assert cycles["Cutout"][..., 3].min() < 0.01 and ours["Cutout"][..., 3].min() < 0.01


@pytest.mark.parametrize("build", [two_layer_scene, three_layer_scene])
def test_layers_leave_nothing_to_the_next(tmp_path, build):
    """With persistent data (the kept core scene and mesh cache) two renders of every layer
    give the same images, and each layer's image is the one it gets rendered alone: an
    override, an Indirect Only or an excluded collection does not leak to the other layers or
    the next render."""
    from addon import render_cache
    render_cache.clear()
    scene = build()
    scene.render.use_persistent_data = True
    try:
        first = render_layers(scene, "PATHLIGHT", tmp_path / "a.exr", 8)
        second = render_layers(scene, "PATHLIGHT", tmp_path / "b.exr", 8)
        for name in first:
            np.testing.assert_array_equal(first[name], second[name], err_msg=name)
        for name in list(first):
            render_cache.clear()
            alone = build()
            for vl in alone.view_layers:
                vl.use = vl.name == name
            alone.render.use_persistent_data = True
            image = render_layers(alone, "PATHLIGHT", tmp_path / f"{name}.exr", 8)[name]
            np.testing.assert_array_equal(first[name], image, err_msg=name)
    finally:
        bpy.context.scene.render.use_persistent_data = False
        render_cache.clear()


def test_one_layer_with_persistent_data_follows_its_settings():
    """One layer with persistent data (the tracked mode, which trusts the depsgraph's updates):
    setting and clearing the override, or Indirect Only, between renders renders each state as
    a fresh render does."""
    from addon import render_cache
    render_cache.clear()
    scene = layer_scene()
    scene.render.use_persistent_data = True
    layer = scene.view_layers[0]
    props = layer.layer_collection.children["Props"]
    try:
        def shot():
            return render_to_array(scene, samples=8, max_bounces=BOUNCES)

        def fresh():
            render_cache.clear()
            return shot()
        plain = shot()
        layer.material_override = clay()
        np.testing.assert_array_equal(shot(), fresh())
        layer.material_override = None
        props.indirect_only = True
        ghost = shot()
        np.testing.assert_array_equal(ghost, fresh())
        props.indirect_only = False
        np.testing.assert_array_equal(shot(), plain)
        assert not np.array_equal(ghost, plain)
    finally:
        scene.render.use_persistent_data = False
        render_cache.clear()
