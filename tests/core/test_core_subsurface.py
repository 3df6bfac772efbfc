"""Random-walk subsurface scattering through the core module: energy in a white furnace, the
albedo inversion (a thick slab's multiple-scattering albedo is the colour), determinism, the
walk inside instanced meshes, and bad input (open meshes, zero, huge and NaN radii)."""
import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, quad, render, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

RW, SKIN = 1.0, 2.0  # the add-on's numbers for Random Walk and Random Walk (Skin)


def box(lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    pos = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], np.float32)
    tris = []
    for a, b, c, d in ((0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)):
        tris += [(a, b, c), (a, c, d)]
    return pos, np.array(tris, np.uint32)


def furnace(program, samples=32, size=16, matrices=None, seed=0, kernel="general"):
    s = pc.Scene()
    m = s.add_shader("m", program)
    pos, tris, nrm = uv_sphere(1.0, nu=48, nv=24)
    if matrices is None:
        add_object(s, pos, tris, m, nrm)
    else:  # one mesh, several instances: the walk runs in its object-space BLAS
        mesh = s.add_mesh(pos, tris, nrm, None, [m])
        for mat in matrices:
            s.add_instance(mesh, np.asarray(mat, np.float32))
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0, -4, 0), (0, 0, 0), lens=60.0))
    img, stats = render(pc, s, size, size, samples=samples, max_bounces=1024, seed=seed)
    assert stats["nonfinite_samples"] == 0
    assert stats["kernel"] == kernel
    return img[..., :3]


@pytest.mark.parametrize("prog", [
    closure("subsurface", color=(1.0, 1.0, 1.0), radius=(1.0, 0.7, 0.5), scale=2.0, method=RW),
    closure("principled", base_color=(1.0, 1.0, 1.0), roughness=0.5, specular_level=0.0, subsurface_weight=1.0,
            subsurface_radius=(1.0, 0.7, 0.5), subsurface_scale=2.0),
], ids=["random walk", "principled"])
def test_white_subsurface_sphere_vanishes_in_a_white_furnace(prog):
    # Albedo 1 and mean free paths near the sphere's size: walks leave within Cycles' 256 steps,
    # so nothing is lost; the exit's diffuse closure sees the white world. (Not Skin: it shrinks
    # the radius of albedo 1 by sqrt(3 (1 - 0.999999)), and then, in Cycles too, walks longer
    # than the cut lose about 8 %.)
    img = furnace(prog, samples=128)
    centre = img[4:12, 4:12].mean()
    assert abs(centre - 1.0) < 0.01, centre


def test_darker_colour_loses_energy():
    img = furnace(closure("subsurface", color=(0.5, 0.5, 0.5), radius=(1.0, 0.7, 0.5), scale=2.0))
    assert img[5:11, 5:11].mean() < 0.8


@pytest.mark.parametrize("c", [0.3, 0.7])
def test_thick_slab_returns_its_colour(c):
    # The albedo inversion's purpose: a half space (mean free path 1e-3 of its size) lit by a
    # white world sends back the colour, not the single-scattering albedo (0.3 maps to 0.88,
    # 0.7 to 0.985, whose walks without the inversion would return far more). Skin enters half
    # diffusely, as the fit assumes; the 256-step cut loses about a percent.
    s = pc.Scene()
    m = s.add_shader("m", closure("subsurface", color=(c, c, c), radius=(1.0, 1.0, 1.0), scale=0.02, method=SKIN))
    pos, tris = box((-3, -3, -2), (3, 3, 0))
    add_object(s, pos, tris, m)
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0, -0.5, 3), (0, 0, 0), lens=50.0))
    img, stats = render(pc, s, 12, 12, samples=48, max_bounces=1024)
    ms = img[..., :3].mean()
    assert abs(ms - c) < 0.06 * c + 0.01, ms


def test_walks_are_deterministic_per_seed():
    prog = closure("subsurface", color=(0.8, 0.5, 0.3), radius=(1.0, 0.5, 0.2), scale=0.3)
    a, b = furnace(prog, samples=4, seed=3), furnace(prog, samples=4, seed=3)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, furnace(prog, samples=4, seed=4))


def test_instanced_mesh_walks_in_its_own_blas():
    prog = closure("subsurface", color=(0.8, 0.5, 0.3), radius=(1.0, 0.5, 0.2), scale=0.3)
    merged = furnace(prog, samples=32)
    far = np.eye(4, dtype=np.float32)
    far[0, 3] = 50.0  # a second instance, out of view: the mesh is instanced, not merged
    inst = furnace(prog, samples=32, matrices=[np.eye(4), far])
    # The same object seen (other random numbers): the same brightness and tint.
    assert np.allclose(inst[5:11, 5:11].mean(axis=(0, 1)), merged[5:11, 5:11].mean(axis=(0, 1)), atol=0.03)
    assert inst[5:11, 5:11, 0].mean() > inst[5:11, 5:11, 2].mean() + 0.1


@pytest.mark.parametrize("radius", [(0.0, 0.0, 0.0), (float("nan"), 1.0, -1.0), (1e30, 1e30, 1e30), (1e-30, 1, 1)])
def test_bad_radii_render_finite_images(radius):
    img = furnace(closure("subsurface", color=(0.8, 0.8, 0.8), radius=radius, scale=1.0), samples=8)
    assert np.isfinite(img).all() and img.max() > 0.0


def test_zero_radius_is_diffuse():
    # Cycles: a radius below BSSRDF_MIN_RADIUS makes the closure a diffuse one.
    sss = furnace(closure("subsurface", color=(0.5, 0.5, 0.5), radius=(0.0, 0.0, 0.0)), samples=16)
    diff = furnace(closure("diffuse", color=(0.5, 0.5, 0.5)), samples=16, kernel="diffuse")
    assert abs(sss.mean() - diff.mean()) < 0.01 * diff.mean()


def test_open_mesh_walk_ends():
    # A lone quad: walks below it either come back up through it or die out within the
    # bounded step count (as Cycles lets them); never a hang or a non-finite pixel.
    s = pc.Scene()
    m = s.add_shader("m", closure("subsurface", color=(0.9, 0.9, 0.9), radius=(1.0, 1.0, 1.0), scale=1.0))
    pos, tris = quad((-1, -1, 0), (2, 0, 0), (0, 2, 0))
    add_object(s, pos, tris, m)
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0, -2, 2), (0, 0, 0)))
    img, stats = render(pc, s, 12, 12, samples=8, max_bounces=64)
    assert stats["nonfinite_samples"] == 0 and np.isfinite(img).all()


@pytest.mark.parametrize("max_bounces", [0, 1])
def test_bounce_limit_with_a_bssrdf_among_the_lobes(max_bounces):
    # At the last vertex the path picks a closure only so that a walk can reach its exit; the
    # other lobes' light samples there had all the weight, so a Principled with a negligible
    # Subsurface Weight renders as one without (nothing counted twice).
    def mean(ssw):
        s = pc.Scene()
        m = s.add_shader("m", closure("principled", base_color=(0.8, 0.8, 0.8), roughness=0.4, subsurface_weight=ssw,
                                      subsurface_radius=(1.0, 1.0, 1.0), subsurface_scale=0.1))
        pos, tris, nrm = uv_sphere(1.0, nu=48, nv=24)
        add_object(s, pos, tris, m, nrm)
        s.add_point_light((2.0, -3.0, 2.0), (30.0, 30.0, 30.0), radius=0.1)
        s.set_world_color((0.2, 0.2, 0.2))
        s.set_camera(camera(pc, (0, -4, 0), (0, 0, 0), lens=60.0))
        return render(pc, s, 16, 16, samples=32, max_bounces=max_bounces)[0][..., :3].mean()
    a, b = mean(1e-4), mean(0.0)
    assert abs(a - b) < 0.003 * b, (a, b)


def test_burley_disk_keeps_the_colour_and_survives_bad_radii():
    # Cycles' normalised Burley profile: a white half space under a white world returns about
    # what a diffuse one would (the profile integrates to 1; truncation and the disk's
    # projection lose a little); an open quad and odd radii stay finite.
    BURLEY = 0.0
    s = pc.Scene()
    m = s.add_shader("m", closure("subsurface", color=(0.7, 0.7, 0.7), radius=(1.0, 0.5, 0.2), scale=0.05, method=BURLEY))
    pos, tris = box((-3, -3, -2), (3, 3, 0))
    add_object(s, pos, tris, m)
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0, -0.5, 3), (0, 0, 0), lens=50.0))
    img, stats = render(pc, s, 12, 12, samples=32, max_bounces=1024)
    assert abs(img[..., :3].mean() - 0.7) < 0.05, img[..., :3].mean()
    for radius in ((float("nan"), 1e30, 0.0), (1e-30, 1e-30, 1e-30)):
        img = furnace(closure("subsurface", color=(0.8, 0.8, 0.8), radius=radius, method=BURLEY), samples=4)
        assert np.isfinite(img).all()


def test_material_edit_that_adds_subsurface_keeps_the_bvh_and_walks():
    # A live edit (set_shader, no geometry rebuild) turning a merged object's material into a
    # BSSRDF: the next commit gives it its local BVH, so walks find their exits.
    prog = closure("subsurface", color=(0.8, 0.5, 0.3), radius=(1.0, 0.5, 0.2), scale=0.3)

    def scene(program):
        s = pc.Scene()
        pc_id = s.add_shader("m", program)
        pos, tris, nrm = uv_sphere(1.0, nu=48, nv=24)
        add_object(s, pos, tris, pc_id, nrm)
        s.set_world_color((1.0, 1.0, 1.0))
        s.set_camera(camera(pc, (0, -4, 0), (0, 0, 0), lens=60.0))
        return s, pc_id

    s, mid = scene(closure("diffuse", color=(0.5, 0.5, 0.5)))
    render(pc, s, 16, 16, samples=2)
    s.set_shader(mid, "m", prog)
    edited, stats = render(pc, s, 16, 16, samples=32, max_bounces=1024)
    fresh = furnace(prog, samples=32)
    assert stats["kernel"] == "general"
    assert np.allclose(edited[4:12, 4:12, :3].mean(axis=(0, 1)), fresh[4:12, 4:12].mean(axis=(0, 1)), atol=0.03)
