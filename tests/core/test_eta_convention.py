"""Refraction carries no 1/eta^2, as Cycles' (docs/materials.md "Refraction: no 1/eta^2, as
Cycles"): a path's throughput through a smooth interface is the lobe's colour alone, so a camera
inside a closed water or glass mesh sees a white world at exactly 1 (pbrt's radiance convention,
which Pathlight used before, gave 1.33^2 = 1.769), and the caustic light paths, which transport
importance (the adjoint, with the factor the other way), give the same image as the path tracer
where the factor matters: a camera inside water lit through its surface, and a lamp inside a
glass ball."""
import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, quad, render, uv_sphere
from test_caustic_light_paths import assert_same_within_noise, renders

pc = core()


def water_ball_around_the_camera(kind, ior=1.33):
    """The camera at the centre of a closed smooth ball (radius 1) of `kind` under a white world."""
    s = pc.Scene()
    if kind == "principled":
        prog = closure("principled", base_color=(1.0, 1.0, 1.0), roughness=0.0, ior=ior, transmission=1.0)
    else:
        prog = closure(kind, color=(1.0, 1.0, 1.0), roughness=0.0, ior=ior)
    m = s.add_shader("water", prog)
    pos, tris, nrm = uv_sphere(1.0, nu=48, nv=24)
    add_object(s, pos, tris, m, nrm)
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0.0, 0.0, 0.0), (0.0, 1.0, 0.2), lens=30.0))
    s.commit()
    return s


@pytest.mark.sanitize  # quick: 16 x 12 pixels
@pytest.mark.parametrize("kind", ["glass", "refraction", "principled"])
def test_camera_inside_water_sees_a_white_world_at_one(kind):
    """Every sample's weight is 1 through each crossing (Fresnel choice by probability, no
    1/eta^2) and every path leaves the ball: each pixel is 1 (Cycles' value; before: 1.769)."""
    img, _ = render(pc, water_ball_around_the_camera(kind), 16, 12, samples=16, seed=3, max_bounces=64)
    rgb = np.asarray(img)[..., :3]
    assert abs(rgb.mean() - 1.0) < 2e-3, rgb.mean()
    assert np.abs(rgb - 1.0).max() < 0.02, np.abs(rgb - 1.0).max()


def water_tank(angle=10.0):
    """An underwater shot: the camera inside a closed box of water (Glass BSDF, IOR 1.33, roughness
    0) over a grey floor that lies inside the water, lit by a sun lamp of `angle` degrees outside
    through the water's top (only the BSDF rays through the surface or the light paths find it)
    and a dim world."""
    s = pc.Scene()
    floor = s.add_material("floor", (0.7, 0.7, 0.7))
    add_object(s, *quad((-2.5, -2.5, 0.05), (5, 0, 0), (0, 5, 0)), floor)
    water = s.add_shader("water", closure("glass", color=(1.0, 1.0, 1.0), roughness=0.0, ior=1.33))
    lo, hi = np.array([-3.0, -3.0, 0.0]), np.array([3.0, 3.0, 2.0])
    for axis in range(3):  # the six faces, normals outwards
        for side in (0, 1):
            u, v = np.zeros(3), np.zeros(3)
            a, b = (axis + 1) % 3, (axis + 2) % 3
            u[a], v[b] = hi[a] - lo[a], hi[b] - lo[b]
            corner = lo.copy()
            corner[axis] = hi[axis] if side else lo[axis]
            if not side:
                u, v = v, u
            add_object(s, *quad(tuple(corner), tuple(u), tuple(v)), water)
    s.set_world_color((0.03, 0.03, 0.04))
    s.add_sun_light((-0.5, 0.3, 0.8), (3.0, 3.0, 3.0), angle=np.radians(angle))
    s.set_camera(camera(pc, (0.0, -2.0, 1.4), (0.0, 0.3, 0.0), lens=30.0))
    s.commit()
    return s


def lamp_in_glass():
    """A point lamp of radius 0.3 at the centre of a smooth glass ball (Glass BSDF, IOR 1.5,
    radius 0.5) over a grey floor: everything on the floor is lit through the glass."""
    s = pc.Scene()
    floor = s.add_material("floor", (0.7, 0.7, 0.7))
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), floor)
    glass = s.add_shader("glass", closure("glass", color=(1.0, 1.0, 1.0), roughness=0.0, ior=1.5))
    pos, tris, nrm = uv_sphere(0.5, center=(0.0, 0.3, 0.7))
    add_object(s, pos, tris, glass, nrm)
    s.add_point_light((0.0, 0.3, 0.7), (8.0, 8.0, 8.0), radius=0.3)
    s.set_world_color((0.03, 0.03, 0.04))
    s.set_camera(camera(pc, (0.0, -2.2, 2.4), (0.0, 0.1, 0.0), lens=35.0))
    s.commit()
    return s


@pytest.mark.parametrize("make", [water_tank, lamp_in_glass], ids=["camera-in-water", "lamp-in-glass"])
def test_light_paths_agree_with_the_path_tracer_across_one_interface(make):
    """The light path crosses one interface between the lamp and the camera (into the water, out
    of the glass), so its throughput must carry the adjoint's factor, etap^2 of the path tracer's
    side (integrator_caustics.cpp): the converged images agree within noise, and so do few or
    many light paths (the MIS densities). With the light path's etap^2 dropped (its throughput as
    before the change) the light-path image was 1.67x the plain one (camera in water) and 0.855x
    (lamp in glass): the whole-image check fails."""
    s = make()
    seeds = (1, 2, 3, 4)
    plain, _ = renders(s, 256, seeds)  # (the plain image's BSDF rays find the light through glass)
    lt, st = renders(s, 96, seeds, caustic_light_paths=1.0)
    assert st["caustics"] == "on"
    assert_same_within_noise(plain, lt, regions=4)
    many, _ = renders(s, 32, seeds, caustic_light_paths=3.0)
    assert abs(many.mean() / plain.mean() - 1.0) < 0.02, many.mean() / plain.mean()
