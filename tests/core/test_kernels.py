"""Scene-specialised integrator kernels (issue 6): the features the core detects in a scene and
a render, the kernel it picks from them, and that every specialised kernel renders exactly the
image of the general one (same sample streams, so bit for bit)."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, cornell, quad, run_session, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

ALL = set(pc.Scene().stats().get("features", [])) | {
    "diffuse", "glossy", "glass", "transparent", "varying shaders", "textures", "normal maps", "media",
    "volumes", "heterogeneous volumes", "mesh lights", "point lights", "spot lights", "sun lights", "area lights",
    "environment", "world light", "dof", "pixel filter", "passes", "transparent film", "adaptive sampling", "light tree",
    "light hits", "subsurface", "motion blur", "guiding", "shadow terminator", "light linking", "shadow catcher",
    "holdout objects", "indirect only objects", "light path tricks", "fast gi", "light bounce limits"}


def shader(s, name, kind, sigma=None, **params):
    """A constant-input closure material (test_core_materials' closure())."""
    regs, prog = {}, []
    for i, (k, v) in enumerate(params.items()):
        prog.append(("const", i, v if isinstance(v, tuple) else (v,)))
        regs[k] = i
    prog.append(("closure", kind, None, regs))
    return s.add_shader(name, prog, **({} if sigma is None else {"volume_absorption": sigma}))


def with_sphere(material_fn):
    """The Cornell box with its sphere's material replaced by material_fn(scene)."""
    def build():
        s = cornell(pc)
        pos, tris, nrm = uv_sphere(0.3, center=(-0.4, 0.4, 0.3))
        add_object(s, pos, tris, material_fn(s), nrm)
        return s
    return build


def textured(s):
    tex = np.zeros((4, 4, 4), np.float32)
    tex[..., :3] = 0.2
    tex[::2, ::2, :3] = 0.8
    tex[..., 3] = 1.0
    img = s.add_image(tex)
    return s.add_shader("tex", [("uv", 0, 0), ("image", 1, 0, img, "LINEAR", "REPEAT"),
                               ("closure", "diffuse", None, {"color": 1})])


def textured_scene():
    s = pc.Scene()
    m = textured(s)
    pos, tris = quad((-2, -2, 0), (4, 0, 0), (0, 4, 0))
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    s.add_instance(s.add_mesh(pos, tris, None, None, [m], uvs={0: uv}), np.eye(4, dtype=np.float32))
    s.add_sun_light((0.3, 0.2, 1.0), (3.0, 3.0, 3.0), angle=0.1)
    s.set_camera(camera(pc, (0, -3, 3), (0, 0, 0)))
    return s


def normal_map_scene():
    s = pc.Scene()
    prog = [("const", 0, (0.6, 0.5, 0.9)), ("normal_map", 1, 0, None, 0),
            ("closure", "diffuse", None, {"normal": 1})]
    m = s.add_shader("nm", prog)
    pos, tris = quad((-2, -2, 0), (4, 0, 0), (0, 4, 0))
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    s.add_instance(s.add_mesh(pos, tris, None, None, [m], uvs={0: uv}), np.eye(4, dtype=np.float32))
    s.add_point_light((0.5, 0.0, 1.5), (20.0, 20.0, 20.0), radius=0.1)
    s.set_camera(camera(pc, (0, -3, 3), (0, 0, 0)))
    return s


def environment_scene():
    s = pc.Scene()
    m = s.add_material("grey", (0.6, 0.6, 0.6))
    pos, tris, nrm = uv_sphere(0.8)
    add_object(s, pos, tris, m, nrm)
    pos, tris = quad((-3, -3, -0.8), (6, 0, 0), (0, 6, 0))
    add_object(s, pos, tris, m)
    h, w = 16, 32
    sky = np.full((h, w, 3), 0.2, np.float32)
    sky[12:14, 5:8] = 200.0  # a small bright sun
    s.set_world_texture(sky, 1.0)
    s.set_camera(camera(pc, (0, -4, 1.5), (0, 0, 0)))
    return s


def lights_scene():
    s = pc.Scene()
    m = s.add_material("grey", (0.7, 0.7, 0.7))
    pos, tris = quad((-3, -3, 0), (6, 0, 0), (0, 6, 0))
    add_object(s, pos, tris, m)
    pos, tris, nrm = uv_sphere(0.5, center=(0, 0, 0.5))
    add_object(s, pos, tris, m, nrm)
    s.add_point_light((1.0, -1.0, 2.0), (30.0, 30.0, 30.0), radius=0.1)
    spot = np.eye(4, dtype=np.float32)
    spot[:3, 3] = (-1.0, -1.0, 3.0)
    s.add_spot_light(spot, (50.0, 40.0, 30.0), radius=0.05)
    s.add_sun_light((0.2, -0.3, 1.0), (1.0, 1.0, 1.0), angle=0.05)
    area = np.eye(4, dtype=np.float32)
    area[:3, 3] = (0.0, 1.0, 2.5)
    s.add_area_light(area, 0.5, 0.3, (8.0, 8.0, 8.0))
    s.set_world_color((0.05, 0.05, 0.08))
    s.set_camera(camera(pc, (0, -4, 2.5), (0, 0, 0.3)))
    return s


def transparent_scene():
    s = with_sphere(lambda s: s.add_shader("card", [
        ("const", 0, (0.5,)), ("const", 1, (0.5,)), ("const", 2, (0.8, 0.3, 0.2)),
        ("closure", "transparent", 0, {}), ("closure", "diffuse", 1, {"color": 2})]))()
    return s


def dof_scene():
    s = cornell(pc)
    cam = camera(pc, (0.0, -0.95, 1.0), (0.0, 1.0, 1.0), lens=16.0)
    cam.aperture_size = 0.05
    cam.focus_distance = 1.2
    s.set_camera(cam)
    return s


def many_lights_scene(glossy=False):
    s = with_sphere(lambda s: shader(s, "metal", "glossy", roughness=0.2))() if glossy else cornell(pc)
    rng = np.random.default_rng(4)
    for _ in range(12):  # more than Scene's kLightTreeMinLights: the light tree
        s.add_point_light(tuple(rng.uniform((-0.9, -0.9, 0.2), (0.9, 0.9, 1.9))), (0.3, 0.3, 0.3), radius=0.02)
    return s


# name: (scene builder, RenderSettings fields, features expected, kernel expected)
CASES = {
    "diffuse": (lambda: cornell(pc), {}, {"diffuse", "mesh lights"}, "diffuse"),
    "glass": (with_sphere(lambda s: shader(s, "glass", "glass", roughness=0.0, ior=1.5)), {},
              {"diffuse", "glass", "mesh lights"}, "surfaces"),
    "glossy": (with_sphere(lambda s: shader(s, "metal", "glossy", roughness=0.2)), {},
               {"diffuse", "glossy", "mesh lights"}, "surfaces"),
    "media": (with_sphere(lambda s: shader(s, "absorber", "glass", sigma=((0.5, 0.8, 1.0), 2.0),
                                           roughness=0.0, ior=1.3)), {},
              {"diffuse", "glass", "media", "mesh lights"}, "surfaces+media"),
    "volumes": (with_sphere(lambda s: s.add_shader("fog", [("const", 0, (1.0, 1.0, 1.0)),
                                                            ("closure", "transparent", None, {"color": 0})],
                                                    volume={"sigma_s": (2.0, 2.0, 2.0), "g": 0.3})), {},
                {"diffuse", "transparent", "media", "volumes", "mesh lights"}, "surfaces+media"),
    "transparent": (transparent_scene, {}, {"diffuse", "transparent", "mesh lights"}, "surfaces"),
    "textures": (textured_scene, {}, {"diffuse", "varying shaders", "textures", "sun lights", "light hits"}, "diffuse"),
    "normal maps": (normal_map_scene, {}, {"diffuse", "varying shaders", "normal maps", "point lights",
                                                    "light hits"},
                    "diffuse"),
    "environment": (environment_scene, {}, {"diffuse", "environment"}, "diffuse+env"),
    "lights": (lights_scene, {}, {"diffuse", "point lights", "spot lights", "sun lights", "area lights",
                                  "world light", "light hits"}, "diffuse"),
    "dof": (dof_scene, {}, {"diffuse", "mesh lights", "dof"}, "diffuse"),
    "filter": (lambda: cornell(pc), {"filter_type": "blackman_harris", "filter_width": 1.5},
               {"diffuse", "mesh lights", "pixel filter"}, "diffuse"),
    "passes": (lambda: cornell(pc), {"passes": ["Depth", "Normal", "Denoising Albedo", "Emit"]},
               {"diffuse", "mesh lights", "passes"}, "general"),
    "transparent film": (environment_scene, {"film_transparent": True},
                         {"diffuse", "environment", "transparent film"}, "general"),
    "light tree": (many_lights_scene, {}, {"diffuse", "mesh lights", "point lights", "light tree", "light hits"},
                   "diffuse+tree"),
    "light tree glossy": (lambda: many_lights_scene(True), {},
                          {"diffuse", "glossy", "mesh lights", "point lights", "light tree", "light hits"},
                          "surfaces+tree"),
    "random sampler": (lambda: cornell(pc), {"sampler": "random"}, {"diffuse", "mesh lights"}, "diffuse"),
    # Random walks live in the general kernel only (a scene without them keeps its kernel).
    "subsurface": (with_sphere(lambda s: shader(s, "skin", "subsurface", color=(0.8, 0.5, 0.4), radius=(1.0, 0.5, 0.2),
                                                scale=0.1)), {},
                   {"diffuse", "subsurface", "varying shaders", "mesh lights"}, "general"),
    "adaptive": (lambda: cornell(pc), {"adaptive_threshold": 0.05, "adaptive_min_samples": 4},
                 {"diffuse", "mesh lights", "adaptive sampling"}, "diffuse"),
}


def linked_scene():
    """The lights scene with one light linked to set 1 only and shadow-linked (light linking
    lives in the general kernel only)."""
    s = lights_scene()
    s.set_light_links(0, light_mask=0b10, shadow_mask=0b10)
    return s


CASES["light linking"] = (linked_scene, {}, {"diffuse", "point lights", "spot lights", "sun lights", "area lights",
                                             "world light", "light hits", "light linking"}, "general")


def bounce_limited_scene():
    """The lights scene with a light's Max Bounces (one of Cycles' tricks: kKernelTricks, the
    general kernels only)."""
    s = lights_scene()
    s.set_light_max_bounces(0, 1)
    return s


CASES["light bounce limits"] = (bounce_limited_scene, {}, {"diffuse", "point lights", "spot lights", "sun lights",
                                                           "area lights", "world light", "light hits",
                                                           "light bounce limits"}, "general")


def moving_cornell():
    """The Cornell box with a sphere that moves over the shutter (motion blur)."""
    s = cornell(pc)
    white = s.add_material("white2", (0.73, 0.73, 0.73))
    pos, tris, nrm = uv_sphere(0.25, nu=16, nv=8)
    steps = np.stack([np.eye(4, dtype=np.float32)] * 3)
    steps[:, :3, 3] = [(-0.5, 0.0, 0.4), (-0.3, 0.1, 0.5), (-0.1, 0.2, 0.6)]
    s.add_instance(s.add_mesh(pos, tris, nrm, None, [white]), steps[1], motion=steps)
    return s


CASES["motion blur"] = (moving_cornell, {}, {"diffuse", "mesh lights", "motion blur"}, "diffuse")
def flagged_cornell(**flags):
    """The Cornell box with a second sphere that is a shadow catcher or a holdout object (only
    the general kernel splits paths at catchers; holdouts need the film's alpha)."""
    s = cornell(pc)
    white = s.add_material("white2", (0.73, 0.73, 0.73))
    pos, tris, nrm = uv_sphere(0.25, nu=16, nv=8, center=(-0.4, 0.3, 0.25))
    s.add_instance(s.add_mesh(pos, tris, nrm, None, [white]), np.eye(4, dtype=np.float32), **flags)
    return s


CASES["shadow catcher"] = (lambda: flagged_cornell(shadow_catcher=True), {},
                           {"diffuse", "mesh lights", "shadow catcher", "passes"}, "general+catcher")
CASES["holdout object"] = (lambda: flagged_cornell(holdout=True), {},
                           {"diffuse", "mesh lights", "holdout objects"}, "general")
# Objects camera rays pass (Indirect Only): the catcher kernel alone steps past them.
CASES["indirect only object"] = (lambda: flagged_cornell(camera_invisible=True), {},
                                 {"diffuse", "mesh lights", "indirect only objects"}, "general+catcher")
# Guided renders run the guided kernels (integrator_guided.cpp), which cover every surface.
CASES["guiding"] = (lambda: cornell(pc), {"guiding": True}, {"diffuse", "mesh lights", "guiding"},
                    "diffuse+env+guiding")


# Clamping, Filter Glossy and the caustics toggles (kKernelTricks) run in the general kernels
# only: the others are compiled without them (docs/design/sampling.md "Clamping").
for _name, _fields in (("clamping", {"clamp_indirect": 1.0}), ("clamp direct", {"clamp_direct": 2.0}),
                       ("filter glossy", {"filter_glossy": 1.0}),
                       ("no reflective caustics", {"caustics_reflective": False}),
                       ("no refractive caustics", {"caustics_refractive": False})):
    CASES[_name] = (lambda: cornell(pc), _fields, {"diffuse", "mesh lights", "light path tricks"}, "general")
CASES["guided clamping"] = (lambda: cornell(pc), {"guiding": True, "clamp_indirect": 1.0},
                            {"diffuse", "mesh lights", "guiding", "light path tricks"}, "general")

# Fast GI (kKernelFastGI) runs in the general kernels only, as the tricks.
for _name, _fields in (("fast gi replace", {"ao_bounces": 1, "ao_factor": 0.5}),
                       ("fast gi add", {"ao_additive_factor": 0.5, "ao_distance": 0.3})):
    CASES[_name] = (lambda: cornell(pc), _fields, {"diffuse", "mesh lights", "fast gi"}, "general")


def session(build, fields, general, size=24, samples=8):
    return run_session(pc, build(), size, size, samples, threads=2, force_general_kernel=general, **fields)


@pytest.mark.parametrize("name", CASES)
def test_features_detected_and_kernel_chosen(name):
    build, fields, expected, kernel = CASES[name]
    st = session(build, fields, general=False, samples=1).stats()
    assert set(st["features"]) == expected
    assert set(st["unused_features"]) == ALL - expected  # and nothing else is claimed
    assert st["kernel"] == kernel
    # (shadow catchers: the general kernel of their own, which alone splits paths)
    general = "general+catcher" if expected & {"shadow catcher", "indirect only objects"} else "general"
    assert session(build, fields, general=True, samples=1).stats()["kernel"] == general


def test_a_clamped_render_runs_a_kernel_that_clamps():
    # The tricks run only where compiled in (kKernelTricks): a clamped render must pick such a
    # kernel, and clamp there (a kernel without the bit would ignore the limit silently).
    plain = session(lambda: cornell(pc), {}, general=False)
    clamped = session(lambda: cornell(pc), {"clamp_indirect": 0.01}, general=False)
    assert plain.stats()["kernel"] == "diffuse" and clamped.stats()["kernel"] == "general"
    assert clamped.film()[..., :3].mean() < 0.9 * plain.film()[..., :3].mean()


@pytest.mark.parametrize("name,instance", [("diffuse", 0), ("glass", 0), ("environment", 1), ("media", 0)])
def test_a_bake_runs_the_general_kernel(name, instance):
    # Only the general kernels take a bake's given first hit (PathCounters::first_hit): the
    # specialised ones are compiled without that per-ray check, so a bake session forces them.
    build, fields, _, kernel = CASES[name]
    st = pc.RenderSettings()
    st.width, st.height, st.samples, st.threads = 4, 4, 2, 2
    for k, v in fields.items():
        setattr(st, k, v)
    # (16 texels on the first triangle of a quad)
    spec = {"instance": instance, "triangle": np.zeros(16, np.int32), "bary": np.full((16, 2), 0.25, np.float32),
            "mode": "surface"}
    s = build()
    s.commit()
    sess = pc.Session(s, st, bake=spec)
    sess.start()
    while not sess.wait(1.0):
        pass
    assert sess.stats()["kernel"] == "general"
    assert np.asarray(sess.film())[..., :3].max() > 0.0  # (the texels were lit)
    # (a render of the same scene keeps its own kernel)
    assert session(build, fields, general=False, samples=1).stats()["kernel"] == kernel


@pytest.mark.parametrize("fields", [{"ao_bounces": 1, "ao_factor": 0.5},
                                    {"ao_additive_factor": 0.5, "ao_distance": 0.3}])
def test_a_fast_gi_render_runs_a_kernel_that_has_it(fields):
    # Fast GI runs only where compiled in (kKernelFastGI): its render must pick such a kernel
    # and change the image there (Replace darkens the closed box, Add with rays shorter than the
    # box brightens it).
    plain = session(lambda: cornell(pc), {}, general=False).film()[..., :3].mean()
    fast = session(lambda: cornell(pc), fields, general=False)
    assert fast.stats()["kernel"] == "general"
    ratio = fast.film()[..., :3].mean() / plain
    assert ratio < 0.9 if "ao_bounces" in fields else ratio > 1.1


@pytest.mark.parametrize("name", CASES)
def test_specialised_kernel_renders_the_general_kernels_image(name):
    build, fields, _, _ = CASES[name]
    spec, gen = session(build, fields, general=False), session(build, fields, general=True)
    a, b = spec.film(), gen.film()
    assert a[..., :3].max() > 0.0  # something was rendered
    assert np.array_equal(a, b)
    for p in fields.get("passes", []):
        assert np.array_equal(spec.film_pass(p), gen.film_pass(p)), p
    assert spec.stats()["rays"] == gen.stats()["rays"]


def test_scene_features_are_detected_again_at_each_commit():
    s = cornell(pc)
    s.commit()
    assert "glass" not in s.stats()["features"]
    glass = shader(s, "glass", "glass", roughness=0.0, ior=1.5)
    pos, tris, nrm = uv_sphere(0.3, center=(-0.4, 0.4, 0.3))
    add_object(s, pos, tris, glass, nrm)
    s.commit()
    assert set(s.stats()["features"]) == {"glass", "diffuse", "mesh lights"}
    s.set_world_color((0.1, 0.1, 0.1))  # a light-only change: no geometry rebuild
    s.commit()
    assert set(s.stats()["features"]) == {"glass", "diffuse", "mesh lights", "world light"}


def test_unused_materials_add_no_features():
    s = cornell(pc)
    shader(s, "glass", "glass", roughness=0.0, ior=1.5)  # on no triangle
    s.set_world_color((0.0, 0.0, 0.0))
    s.commit()
    assert set(s.stats()["features"]) == {"diffuse", "mesh lights"}


@pytest.mark.parametrize("instanced", [False, True])
def test_a_material_on_one_kept_triangle_adds_its_features(instanced):
    """Meshes of one material are checked by one scan of their material ids, others triangle by
    triangle: glass on one triangle of a sphere counts, glass only on a dropped (degenerate)
    triangle does not, and a mesh all of glass does."""
    def features(material_indices, positions_edit=None):
        s = cornell(pc)
        s.set_world_color((0.0, 0.0, 0.0))
        glass = shader(s, "glass", "glass", roughness=0.0, ior=1.5)
        diffuse = shader(s, "grey", "diffuse")
        pos, tris, nrm = uv_sphere(0.3, center=(-0.4, 0.4, 0.3))
        if positions_edit is not None:
            pos, tris = positions_edit(pos.copy(), tris)
        mesh = s.add_mesh(pos, tris, None, np.asarray(material_indices(len(tris)), np.int32), [diffuse, glass])
        for k in range(2 if instanced else 1):
            m = np.eye(4, dtype=np.float32)
            m[0, 3] = 0.1 * k
            s.add_instance(mesh, m)
        s.commit()
        return set(s.stats()["features"])
    assert "glass" not in features(lambda n: np.zeros(n))
    assert "glass" in features(lambda n: np.ones(n))
    one = lambda n: np.eye(1, n, n // 2)[0]  # noqa: E731  glass on triangle n // 2 only
    assert "glass" in features(one)

    def degenerate_middle(pos, tris):  # triangle n // 2 collapsed to a point: dropped
        t = tris[len(tris) // 2]
        pos = np.concatenate([pos, pos[t[:1]]])
        tris = tris.copy()
        tris[len(tris) // 2] = len(pos) - 1
        return pos.astype(np.float32), tris
    assert "glass" not in features(one, degenerate_middle)
