"""Subsurface scattering against Cycles 4.5 in the same bpy (issue 24): a Principled sphere with
Subsurface Weight 1 and a skin-like radius under an HDR-like environment and under a point light,
a thin slab lit from behind (light must come through it), the Random Walk (Skin) method, the
Subsurface Scattering node and Christensen-Burley's disk sampling. Cycles' default subsurface
settings, equal bounce limits. Tolerances: the whole-image mean within 1 %, every 8x8 region
within 3 % (regions darker than 0.02 compare absolutely). Measured agreement numbers are
printed (pytest -s)."""

import math

import bpy
import pytest

from blender_util import core_available, load_addon, render_to_array
import light_scenes as ls
import material_scenes as ms
from material_scenes import assert_agree, render_pair

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def skin(name="Skin", method='RANDOM_WALK', **inputs):
    """Principled, Subsurface Weight 1, Blender's default radius (1, 0.2, 0.1) at a scale that
    makes the red light travel a good part of the object."""
    values = dict(Base_Color=(0.8, 0.55, 0.45, 1), Subsurface_Weight=1.0, Subsurface_Scale=0.1, Roughness=0.5)
    values.update(inputs)
    mat, node = ms.bsdf_material(name, "ShaderNodeBsdfPrincipled", **values)
    node.subsurface_method = method
    return mat


def sphere_scene(light, material):
    def build():
        scene = ls.empty_scene(48)
        ms.add_sphere("Ball", 0.5, material(), location=(0.0, 0.0, 0.0))
        if light == "environment":
            env = ls.synthetic_hdr(64, 32, sun_sigma=0.35, sun_peak=4.0)
            ls.world_image(ls.load_image(env, "sky"))
        else:
            ls.world_color((0.02, 0.02, 0.02))
            ls.add_light('POINT', location=(1.5, -1.5, 2.0), energy=300.0, shadow_soft_size=0.1)
        ms.add_camera((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), lens=60.0)
        return scene
    return build


@pytest.mark.parametrize("light", ["environment", "point"])
def test_principled_subsurface_sphere(light):
    ours, cycles = render_pair(sphere_scene(light, skin), 256)
    assert_agree(ours, cycles, f"subsurface sphere {light}")


def test_thin_slab_lit_from_behind():
    # A 0.1 m slab between the camera and a sun behind it: its front is lit only by light that
    # walked through it (and a dim world). Mean free paths of about half the thickness.
    def build():
        scene = ls.empty_scene(48)
        wax = skin("Wax", Base_Color=(0.9, 0.7, 0.5, 1), Subsurface_Radius=(1.0, 0.8, 0.6), Subsurface_Scale=0.6)
        ls.box("Slab", 1.0, wax, scale=(1.0, 0.1, 1.0))
        ls.world_color((0.01, 0.01, 0.01))
        ls.add_light('SUN', rotation=(math.radians(-80.0), 0.0, math.radians(10.0)), energy=3.0, angle=0.05)
        ms.add_camera((0.1, -2.0, 0.1), (0.0, 0.0, 0.0), lens=80.0)  # the slab fills the view
        return scene
    ours, cycles = render_pair(build, 1024)
    assert_agree(ours, cycles, "backlit slab")


def test_skin_method_and_subsurface_node_spheres():
    # Random Walk (Skin) (its albedo-adjusted radius, half-diffuse entry at Subsurface IOR) and
    # the Subsurface Scattering node (Random Walk, its own roughness and anisotropy).
    def build():
        scene = ls.empty_scene(48)
        mat = skin("Skin method", method='RANDOM_WALK_SKIN', Subsurface_Scale=0.2)
        mat.node_tree.nodes["Principled BSDF"].inputs["Subsurface IOR"].default_value = 1.35
        ms.add_sphere("Skin", 0.45, mat, location=(-0.5, 0.0, 0.0))
        node_mat, node = ms.bsdf_material("Node", "ShaderNodeSubsurfaceScattering", Color=(0.3, 0.6, 0.9, 1),
                                          Scale=0.2, Roughness=0.6, Anisotropy=0.5, IOR=1.5)
        ms.add_sphere("Node", 0.45, node_mat, location=(0.5, 0.0, 0.0))
        env = ls.synthetic_hdr(64, 32, sun_sigma=0.35, sun_peak=4.0)
        ls.world_image(ls.load_image(env, "sky"))
        ms.add_camera((0.0, -3.5, 0.0), (0.0, 0.0, 0.0), lens=60.0)
        return scene
    ours, cycles = render_pair(build, 256)
    assert_agree(ours, cycles, "skin and node spheres")


@pytest.mark.parametrize("light", ["environment", "point"])
def test_christensen_burley_sphere(light):
    # Cycles' disk-sampling BSSRDF: probe rays across a disk about one of three axes.
    ours, cycles = render_pair(sphere_scene(light, lambda: skin("Burley", method='BURLEY')), 256)
    assert_agree(ours, cycles, f"burley sphere {light}")


def test_half_subsurface_under_a_coat_with_anisotropy():
    # Subsurface Weight 0.5 beside the diffuse, under the specular and a coat, HG anisotropy 0.6.
    mat = lambda: skin("Half", Subsurface_Weight=0.5, Coat_Weight=0.5, Roughness=0.3,  # noqa: E731
                       Subsurface_Anisotropy=0.6)
    ours, cycles = render_pair(sphere_scene("environment", mat), 256)
    assert_agree(ours, cycles, "half subsurface, coat, anisotropy")


def test_subsurface_with_its_own_normal():
    # A Bump (Noise heights) on the Principled: Cycles lights the walks' exits from the BSSRDF's
    # normal there (SD_HAS_BSSRDF_BUMP), bump-shadowed. With the smooth normal there instead:
    # mean ratio 1.043, worst region 36 %.
    def material():
        mat = skin("Bumped skin", Roughness=0.4)
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        noise = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=3.0)
        bump = ms.set_inputs(nodes.new("ShaderNodeBump"), Distance=0.3)
        links.new(noise.outputs["Fac"], bump.inputs["Height"])
        links.new(bump.outputs["Normal"], nodes["Principled BSDF"].inputs["Normal"])
        return mat
    ours, cycles = render_pair(sphere_scene("point", material), 512)
    assert_agree(ours, cycles, "subsurface with its own normal")
