"""Fast GI Approximation and Film > Transparent Glass through the add-on, under Cycles' names
(scene.pathlight.use_fast_gi, fast_gi_method, ao_bounces, ao_bounces_render; the world's
light_settings.ao_factor and distance; film_transparent_glass, film_transparent_roughness): the
settings reach the core as Cycles' BlenderSync gives them to its Integrator (render and viewport
bounces), the panels lay them out as Cycles', and renders agree with Cycles'
(docs/design/sampling.md "Fast GI approximation", docs/design/passes.md "Transparent glass").
Cycles' images come from tests/cycles_refs/ (docs/building.md)."""
import math

import bpy
import numpy as np
import pytest

from blender_util import RecordingLayout, core_available, load_addon
from material_scenes import (add_camera, add_plane, add_sphere, assert_agree, bsdf_material, diffuse, emission,
                             render_pair, set_world)

load_addon()
from addon import session, ui, viewport_update  # noqa: E402

needs_core = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")
NAMES = ("use_fast_gi", "fast_gi_method", "ao_bounces", "ao_bounces_render", "film_transparent_glass",
         "film_transparent_roughness")


def test_settings_have_cycles_names_and_reach_the_core():
    from addon.core import get_core
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    props = scene.pathlight
    for name in NAMES:
        assert hasattr(scene.cycles, name) and hasattr(props, name)
        assert getattr(props, name) == pytest.approx(getattr(scene.cycles, name)), name  # Cycles' defaults
    pc = get_core()
    st = session.render_settings(pc, scene)
    assert (st.ao_bounces, st.ao_factor, st.ao_additive_factor) == (0, 0.0, 0.0)  # off by default
    scene.world = bpy.data.worlds.new("World")
    light = scene.world.light_settings
    light.ao_factor, light.distance = 0.7, 3.5
    props.use_fast_gi, props.ao_bounces, props.ao_bounces_render = True, 3, 2
    st = session.render_settings(pc, scene)
    assert (st.ao_bounces, st.ao_factor, st.ao_additive_factor) == (2, pytest.approx(0.7), 0.0)
    assert st.ao_distance == pytest.approx(3.5)
    st = session.render_settings(pc, scene, viewport=True)  # the viewport's bounces
    assert st.ao_bounces == 3
    props.fast_gi_method = 'ADD'
    st = session.render_settings(pc, scene)
    assert (st.ao_factor, st.ao_additive_factor) == (0.0, pytest.approx(0.7))
    scene.world = None  # (Cycles: no world, no Fast GI)
    st = session.render_settings(pc, scene)
    assert (st.ao_factor, st.ao_additive_factor) == (0.0, 0.0)
    # Transparent Glass: the threshold as set; the core squares it twice.
    props.film_transparent_glass, props.film_transparent_roughness = True, 0.3
    st = session.render_settings(pc, scene)
    assert st.film_transparent_glass and st.film_transparent_roughness == pytest.approx(0.3)
    # Every one restarts the viewport, the world's factor and distance too.
    scene.world = bpy.data.worlds.new("World2")
    for name, value in (("use_fast_gi", False), ("fast_gi_method", 'REPLACE'), ("ao_bounces", 5),
                        ("film_transparent_glass", False), ("film_transparent_roughness", 0.2)):
        before = viewport_update.settings_signature(scene)
        setattr(props, name, value)
        assert viewport_update.settings_signature(scene) != before, name
    for name, value in (("ao_factor", 0.3), ("distance", 1.5)):
        before = viewport_update.settings_signature(scene)
        setattr(scene.world.light_settings, name, value)
        assert viewport_update.settings_signature(scene) != before, name


def test_panels_lay_out_cycles_settings():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.world = bpy.data.worlds.new("World")
    panel = ui.PATHLIGHT_RENDER_PT_light_paths_fast_gi
    assert panel in ui.classes and panel.bl_parent_id == "PATHLIGHT_RENDER_PT_light_paths"
    ctx = type("Ctx", (), {"scene": scene})
    layout = RecordingLayout()
    panel.draw_header(type("Panel", (), {"layout": layout})(), ctx)
    assert layout.props == ["use_fast_gi"]
    layout = RecordingLayout()
    panel.draw(type("Panel", (), {"layout": layout})(), ctx)
    assert layout.props == ["fast_gi_method", "ao_factor", "distance", "ao_bounces", "ao_bounces_render"]
    scene.pathlight.fast_gi_method = 'ADD'  # (Cycles shows the bounces for Replace only)
    layout = RecordingLayout()
    panel.draw(type("Panel", (), {"layout": layout})(), ctx)
    assert layout.props == ["fast_gi_method", "ao_factor", "distance"]
    panel = ui.PATHLIGHT_RENDER_PT_film_transparency
    assert panel in ui.classes and panel.bl_parent_id == "PATHLIGHT_RENDER_PT_film"
    layout = RecordingLayout()
    panel.draw_header(type("Panel", (), {"layout": layout})(), ctx)
    panel.draw(type("Panel", (), {"layout": layout})(), ctx)
    assert layout.props == ["film_transparent", "film_transparent_glass", "film_transparent_roughness"]


def room():
    """A small room open towards the camera: coloured diffuse walls, an emissive panel under the
    ceiling and a grey world outside. Cycles' world is not light-sampled here (its sampling
    method None), as Pathlight's constant world beside a lamp: the AO factor then scales the
    same world light in both (docs/design/sampling.md "Fast GI approximation")."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = 48
    scene.render.resolution_percentage = 100
    wall = diffuse("Wall", (0.7, 0.7, 0.7))
    add_plane("Floor", 4.0, diffuse("Floor", (0.6, 0.55, 0.5)))
    add_plane("Back", 4.0, wall, location=(0.0, 2.0, 2.0), rotation_euler=(math.pi / 2, 0.0, 0.0))
    add_plane("Left", 4.0, diffuse("Red", (0.7, 0.15, 0.1)), location=(-2.0, 0.0, 2.0),
              rotation_euler=(0.0, math.pi / 2, 0.0))
    add_plane("Right", 4.0, diffuse("Green", (0.15, 0.6, 0.2)), location=(2.0, 0.0, 2.0),
              rotation_euler=(0.0, -math.pi / 2, 0.0))
    add_plane("Ceiling", 4.0, wall, location=(0.0, 0.0, 4.0), rotation_euler=(math.pi, 0.0, 0.0))
    add_plane("Lamp", 0.8, emission("Lamp", (1.0, 0.95, 0.9), 20.0), uv=False, location=(0.3, 0.8, 3.9),
              rotation_euler=(math.pi, 0.0, 0.0))
    add_sphere("Ball", 0.6, diffuse("Ball", (0.8, 0.8, 0.8)), location=(-0.5, 0.6, 0.6))
    set_world((0.4, 0.45, 0.5))
    scene.world.cycles.sampling_method = 'NONE'
    light = scene.world.light_settings
    light.ao_factor, light.distance = 0.6, 2.5
    add_camera((0.0, -5.5, 2.0), (0.0, 0.5, 1.8), lens=30.0)
    return scene


CASES = {
    "replace 1": dict(use_fast_gi=True, fast_gi_method='REPLACE', ao_bounces_render=1),
    "replace 2": dict(use_fast_gi=True, fast_gi_method='REPLACE', ao_bounces_render=2),
    "add": dict(use_fast_gi=True, fast_gi_method='ADD'),
}


@needs_core
@pytest.mark.parametrize("case", CASES)
def test_fast_gi_agrees_with_cycles(case):
    ours, cycles = render_pair(room, 512, bounces=8, cycles_samples=4096, **CASES[case])
    assert_agree(ours, cycles, f"room, Fast GI {case}")
    # (it changed the image: without it the room is brighter, or darker with Add)
    plain = render_pair(room, 64, bounces=8, cycles_samples=4096)[1]
    assert abs(cycles[..., :3].mean() / plain[..., :3].mean() - 1.0) > 0.05


def room_with_object_distances():
    """The room with objects' own AO Distances (Object ▸ Visibility ▸ Fast GI Approximation):
    short on the back wall and the floor, long on the ball."""
    scene = room()
    for name, d in (("Back", 0.4), ("Floor", 0.8), ("Ball", 6.0)):
        bpy.data.objects[name].cycles.ao_distance = d
    return scene


@needs_core
def test_objects_own_ao_distance_agrees_with_cycles():
    """Cycles' intersect_closest: an AO ray leaving an object with its own AO Distance reaches
    that far instead of the world's distance."""
    settings = CASES["replace 1"]
    ours, cycles = render_pair(room_with_object_distances, 512, bounces=8, cycles_samples=4096, **settings)
    assert_agree(ours, cycles, "room, Fast GI replace 1, objects' own AO distances")
    # (they changed Cycles' image: the world's distance alone gives another)
    plain = render_pair(room, 16, bounces=8, cycles_samples=4096, **settings)[1]
    assert abs(cycles[..., :3].mean() / plain[..., :3].mean() - 1.0) > 0.02


def test_object_ao_distance_export_and_panel():
    """The object's own AO Distance, else its instancer's (BlenderSync), reaches add_instance;
    the panel draws Cycles' property."""
    from addon.export import mesh as mesh_export
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    own = add_sphere("Own", 0.5, diffuse("A", (0.5, 0.5, 0.5)))
    own.cycles.ao_distance = 2.5
    inner = add_sphere("Inner", 0.5, diffuse("B", (0.5, 0.5, 0.5)), location=(3.0, 0.0, 0.0))
    coll = bpy.data.collections.new("Instanced")
    coll.objects.link(inner)
    empty = bpy.data.objects.new("Instancer", None)
    empty.instance_type, empty.instance_collection = 'COLLECTION', coll
    empty.cycles.ao_distance = 1.5
    scene.collection.objects.link(empty)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    found = {}
    for inst in depsgraph.object_instances:
        if inst.object.type == 'MESH':
            found[(inst.object.name, inst.is_instance)] = mesh_export.object_info(inst)[8]
    assert found[("Own", False)] == pytest.approx(2.5)
    assert found[("Inner", True)] == pytest.approx(1.5)  # the instancer's
    assert found[("Inner", False)] == 0.0
    panel = ui.PATHLIGHT_OBJECT_PT_fast_gi
    assert panel in ui.classes and panel.bl_parent_id == "OBJECT_PT_visibility"
    layout = RecordingLayout()
    panel.draw(type("Panel", (), {"layout": layout})(), type("Ctx", (), {"scene": scene, "object": own}))
    assert layout.props == ["ao_distance"]


def glass_ball():
    """A smooth glass ball over a grey floor lit by the world alone (a sun's glint in the glass
    is fireflies at these counts in both engines), the world seen around and through the ball,
    on transparent film."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = 48
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    add_plane("Floor", 3.0, diffuse("Floor", (0.5, 0.5, 0.5)))
    glass, _ = bsdf_material("Glass", "ShaderNodeBsdfGlass", Roughness=0.0, IOR=1.45)
    add_sphere("Ball", 0.5, glass, location=(0.0, 0.0, 0.7))
    set_world((0.6, 0.65, 0.7))
    add_camera((0.0, -3.2, 1.4), (0.0, 0.0, 0.6), lens=40.0)
    return scene


@needs_core
@pytest.mark.parametrize("glass", [False, True])
def test_transparent_glass_agrees_with_cycles(glass):
    ours, cycles = render_pair(glass_ball, 512, bounces=8, cycles_samples=4096, film_transparent_glass=glass,
                               film_transparent_roughness=0.1)
    assert_agree(ours, cycles, f"glass ball on transparent film, Transparent Glass {glass}")
    # Alpha: the same test on the alpha channel (as grey).
    a_ours, a_cycles = np.repeat(ours[..., 3:4], 3, -1), np.repeat(cycles[..., 3:4], 3, -1)
    assert_agree(a_ours, a_cycles, f"alpha, Transparent Glass {glass}")
    centre = cycles[20:28, 20:28, 3].mean()
    assert (centre < 0.5) if glass else (centre > 0.99)  # (it is what the setting changes)
