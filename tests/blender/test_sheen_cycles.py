"""Sheen and rough diffuse against Cycles 4.5 (issue 24): four spheres, each compared on its own
quadrant of the image: Principled Sheen (weight 1, roughness 0.5, a tint) over a dark base, a
Sheen BSDF (microfibre, roughness 0.6), Principled Diffuse Roughness and a rough Diffuse BSDF (Cycles'
energy-preserving Oren-Nayar), lit by an HDR-like environment and by a point light. Per sphere:
its quadrant's mean within 1 %, every cell of an 8x8 grid over the quadrant within 3 % (cells
darker than 0.02 compare absolutely). Measured agreement numbers are printed (pytest -s)."""

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, core_available, load_addon, render_to_array
import light_scenes as ls
import material_scenes as ms

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

SIZE = 96  # four 48 x 48 quadrants


def spheres(light, segments=128):
    def build():
        scene = ls.empty_scene(SIZE)
        materials = (
            ("Sheen", "ShaderNodeBsdfPrincipled",
             dict(Base_Color=(0.05, 0.04, 0.06, 1), Roughness=0.6, Sheen_Weight=1.0, Sheen_Roughness=0.5,
                  Sheen_Tint=(1.0, 0.55, 0.75, 1))),
            ("Sheen BSDF", "ShaderNodeBsdfSheen", dict(Color=(0.8, 0.9, 1.0, 1), Roughness=0.6)),
            ("Diffuse roughness", "ShaderNodeBsdfPrincipled",
             dict(Base_Color=(0.8, 0.45, 0.2, 1), Roughness=0.5, Diffuse_Roughness=1.0)),
            ("Rough diffuse", "ShaderNodeBsdfDiffuse", dict(Color=(0.3, 0.6, 0.35, 1), Roughness=0.7)),
        )
        # Quadrants in image order: top-left, top-right, bottom-left, bottom-right.
        for (name, node_type, inputs), (x, z) in zip(materials, ((-0.6, 0.6), (0.6, 0.6), (-0.6, -0.6), (0.6, -0.6))):
            mat, node = ms.bsdf_material(name, node_type, **inputs)
            if node_type == "ShaderNodeBsdfSheen":
                assert node.distribution == 'MICROFIBER'
            # Where a coarse sphere's interpolated normal turns from the view at the rim, the lobes
            # stay on the side the geometry shows the viewer, as Cycles' (sheen peaks there).
            ms.add_sphere(name, 0.5, mat, segments=segments, rings=segments // 2, location=(x, 0.0, z))
        ms.add_camera((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), lens=60.0)
        # The background out of the film (alpha 0, colour 0): a quadrant's mean is its sphere's.
        scene.render.film_transparent = True
        if light == "environment":
            ls.world_image(ls.load_image(ls.synthetic_hdr(64, 32, sun_sigma=0.35, sun_peak=4.0), "sky"),
                           strength=3.0)
        else:
            # Up and to the side: each sphere shows its lit side, its terminator and a lit rim.
            ls.add_light('POINT', location=(3.0, -2.0, 3.0), energy=3000.0, shadow_soft_size=0.0)
        return scene
    return build


def quadrants(img):
    h = img.shape[0] // 2
    return [img[:h, :h], img[:h, h:], img[h:, :h], img[h:, h:]]


@pytest.mark.parametrize("light,segments", [("environment", 128), ("point", 128), ("point", 24)])
def test_sheen_and_rough_diffuse_spheres(light, segments):
    build = spheres(light, segments)
    samples = 1024  # dark rims and terminators: at 512 a cell is noisy to ~4 %
    ours = render_to_array(build(), "PATHLIGHT", samples=samples, max_bounces=8)
    cycles = render_to_array(build(), "CYCLES", samples=samples, max_bounces=8, **BOX_FILTER)
    assert np.isfinite(ours).all()
    names = ("principled sheen", "sheen bsdf", "diffuse roughness", "rough diffuse")
    failures = []
    for name, a, b in zip(names, quadrants(ours), quadrants(cycles)):
        ratio, worst, rel = ms.compare(a, b)
        print(f"\n{light} {segments} {name}: mean ratio {ratio:.4f}, worst region {worst:.4f} "
              f"(means {a[..., :3].mean():.4f} / {b[..., :3].mean():.4f})")
        if abs(ratio - 1.0) >= 0.01 or worst >= 0.03:
            failures.append(f"{name}: mean ratio {ratio:.4f}, worst region {worst:.3f}\n{np.round(rel, 3)}")
    assert not failures, "\n".join(failures)


def test_ashikhmin_velvet_sphere():
    # The Sheen BSDF's other distribution, under the environment and the point light at once;
    # uniformly sampled (as in Cycles), so it needs more samples: at 2048 the mean agreed to
    # 0.15 % and the worst cell to 1.4 %.
    def build():
        scene = ls.empty_scene(48)
        mat, node = ms.bsdf_material("Velvet", "ShaderNodeBsdfSheen", Color=(0.9, 0.5, 0.6, 1), Roughness=0.5)
        node.distribution = 'ASHIKHMIN'
        ms.add_sphere("Velvet", 0.8, mat, segments=128, rings=64)
        ms.add_camera((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), lens=60.0)
        scene.render.film_transparent = True
        ls.world_image(ls.load_image(ls.synthetic_hdr(64, 32, sun_sigma=0.35, sun_peak=4.0), "sky"),
                       strength=3.0)
        ls.add_light('POINT', location=(3.0, -2.0, 3.0), energy=3000.0, shadow_soft_size=0.0)
        return scene
    ours = render_to_array(build(), "PATHLIGHT", samples=2048, max_bounces=8)
    cycles = render_to_array(build(), "CYCLES", samples=2048, max_bounces=8, **BOX_FILTER)
    ratio, worst, rel = ms.compare(ours, cycles)
    print(f"\nvelvet: mean ratio {ratio:.4f}, worst region {worst:.4f}")
    assert abs(ratio - 1.0) < 0.01, ratio
    assert worst < 0.03, np.round(rel, 3)


def test_toon_spheres():
    # Toon BSDF, Diffuse and Glossy (Size 0.6, Smooth 0.2), each on its half of the image, under
    # a uniform world and the point light (its highlight a hard-edged disc on the glossy one).
    def build():
        scene = ls.empty_scene(64, 32)
        for name, component, color, x in (("Toon diffuse", 'DIFFUSE', (0.8, 0.4, 0.2, 1), -0.9),
                                          ("Toon glossy", 'GLOSSY', (0.7, 0.8, 0.9, 1), 0.9)):
            mat, node = ms.bsdf_material(name, "ShaderNodeBsdfToon", Color=color, Size=0.6, Smooth=0.2)
            node.component = component
            ms.add_sphere(name, 0.8, mat, segments=128, rings=64, location=(x, 0.0, 0.0))
        ms.add_camera((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), lens=60.0)
        scene.render.film_transparent = True
        ls.world_color((0.4, 0.5, 0.6))
        ls.add_light('POINT', location=(3.0, -2.0, 3.0), energy=3000.0, shadow_soft_size=0.0)
        return scene
    ours = render_to_array(build(), "PATHLIGHT", samples=2048, max_bounces=8)
    cycles = render_to_array(build(), "CYCLES", samples=2048, max_bounces=8, **BOX_FILTER)
    failures = []
    for name, a, b in (("diffuse", ours[:, :32], cycles[:, :32]), ("glossy", ours[:, 32:], cycles[:, 32:])):
        ratio, worst, rel = ms.compare(a, b)
        print(f"\ntoon {name}: mean ratio {ratio:.4f}, worst region {worst:.4f}")
        if abs(ratio - 1.0) >= 0.01 or worst >= 0.03:
            failures.append(f"{name}: mean ratio {ratio:.4f}, worst region {worst:.3f}\n{np.round(rel, 3)}")
    assert not failures, "\n".join(failures)
