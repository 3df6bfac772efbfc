"""Cycles' Filter Glossy and Reflective / Refractive Caustics (RenderSettings.filter_glossy,
caustics_reflective, caustics_refractive; Blender's Light Paths > Caustics; docs/design/
sampling.md "Filter Glossy and caustics toggles").

Caustics toggles, as Cycles' svm closure set-up: at a point a diffuse bounce reached (the last
scattering, transparent crossings aside), glossy reflection closures are dropped with Reflective
off, refraction closures with Refractive off, glass loses each lobe (and goes when both are off).
Filter Glossy, as Cycles' surface_shader_prepare_closures: with the path's smallest BSDF pdf so
far (min_ray_pdf) times 1 / blur_glossy below 1, every microfacet closure's alpha is raised to at
least sqrt(1 - that) / 2 (bsdf_blur). Both change no random number before the vertex they act
at, so several checks below are exact."""
import math

import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, quad, region_means, run_session, uv_sphere

pc = core()
W = H = 32
SUN = (0.0, 0.8, 1.0)  # towards the sun: behind the casters, so their caustics fall towards the camera


def caustic_scene(casters="real"):
    """A diffuse floor under a sun of 0.3 rad with a smooth glass sphere (its refraction focuses
    near the floor) and a tilted mirror panel (its reflection lights a patch of the floor).
    casters: "real", "black" (both casters black diffuse: their shadows only) or "emit" (the
    casters emissive and the rest black, no sun: a mask of the pixels that see them)."""
    s = pc.Scene()
    emit = casters == "emit"
    floor = s.add_material("floor", (0.0, 0.0, 0.0) if emit else (0.8, 0.8, 0.8))
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), floor)
    if casters == "real":
        glass = s.add_shader("glass", closure("glass", color=(1.0, 1.0, 1.0), roughness=0.0, ior=1.5))
        mirror = s.add_shader("mirror", closure("glossy", color=(0.9, 0.9, 0.9), roughness=0.0))
    elif casters == "black":
        glass = mirror = s.add_material("black", (0.0, 0.0, 0.0))
    else:
        glass = mirror = s.add_material("emit", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    pos, tris, nrm = uv_sphere(0.3, nu=32, nv=16, center=(-0.55, 0.2, 0.5))
    add_object(s, pos, tris, glass, nrm)
    # A mirror panel standing at x = 0.9, turned to send the sun down onto the floor at x < 0.9.
    add_object(s, *quad((0.9, -0.5, 0.2), (0.0, 1.0, 0.0), (0.35, 0.0, 0.8)), mirror)
    if not emit:
        s.add_sun_light(SUN, (3.0, 3.0, 3.0), angle=0.3)
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, -2.6, 2.4), (0.0, 0.3, 0.1), lens=30.0))
    s.commit()
    return s


def film(scene, samples=64, seed=1, **kw):
    kw.setdefault("caustic_light_paths_auto", False)  # the path tracer alone, in every render
    sess = run_session(pc, scene, W, H, samples, threads=2, seed=seed, **kw)
    return np.asarray(sess.film())[..., :3].astype(np.float64), sess.stats()


@pytest.fixture(scope="module")
def caustics():
    """Renders of the caustic scene: each toggle setting and the casters' shadows alone, the
    mask of the pixels that do not see a caster (nor border one) and of those that see only one."""
    real, black = caustic_scene(), caustic_scene("black")
    mask = film(caustic_scene("emit"), samples=4)[0]
    seen = mask.max(-1) > 0.0
    near = seen.copy()
    near[1:] |= seen[:-1]
    near[:-1] |= seen[1:]
    near[:, 1:] |= near[:, :-1].copy()
    near[:, :-1] |= near[:, 1:].copy()
    out = {"floor": ~near, "seen": mask.min(-1) > 0.999}
    for name, kw in (("on", {}), ("no_refl", {"caustics_reflective": False}),
                     ("no_refr", {"caustics_refractive": False}),
                     ("off", {"caustics_reflective": False, "caustics_refractive": False})):
        out[name] = film(real, samples=1024, **kw)
    out["black"] = film(black, samples=1024)
    return out


def test_bsdf_toggles_drop_and_trim_as_cycles():
    on = pc.caustics_keep
    assert on("conductor", {"alpha": 0.1}, False, True) is None  # Glossy, Metallic, Principled's
    assert on("conductor", {"alpha": 0.1}, True, False) is True
    glass = {"alpha": 0.0}
    assert on("dielectric", glass, False, True) == (False, True)  # Cycles' zero reflection_tint
    assert on("dielectric", glass, True, False) == (True, False)
    assert on("dielectric", glass, False, False) is None
    refraction = {"alpha": 0.0, "reflection": False, "fresnel_on_transmission": False}
    assert on("dielectric", refraction, False, True) == (False, True)  # (Refraction: refractive only)
    assert on("dielectric", refraction, True, False) is None
    assert on("toon", {"glossy": True}, False, True) is None
    for kind in ("diffuse", "translucent", "transparent", "hair_chiang", "hair_huang", "sheen", "velvet"):
        assert on(kind, {}, False, False) is True, kind
    assert on("toon", {}, False, False) is True  # (the diffuse Toon)


def test_both_toggles_off_leave_the_casters_shadows_alone_exactly(caustics):
    # Off, a diffuse bounce that meets the glass or the mirror ends there, as one that meets a
    # black caster: every floor pixel the same paths, the same numbers.
    off, black, on = caustics["off"][0], caustics["black"][0], caustics["on"][0]
    floor = caustics["floor"]
    assert floor.sum() > 0.6 * floor.size
    assert np.array_equal(off[floor], black[floor])
    # (there were caustics to remove: the floor's brightest regions gain 0.2 and more with them)
    assert (regions(np.where(floor[..., None], on - black, 0.0))).max() > 0.15
    assert caustics["off"][1]["kernel"] == "general" and caustics["on"][1]["kernel"] != "general"


def test_the_camera_still_sees_the_glass_refract(caustics):
    # A camera ray is no diffuse bounce: the glass and the mirror seen directly keep their lobes
    # (the floor through them, lit by the sun), where black casters show nothing.
    seen = caustics["seen"]
    off, on, black = caustics["off"][0][seen], caustics["on"][0][seen], caustics["black"][0][seen]
    assert off.mean() > 0.5 * on.mean() > 0.0
    assert black.mean() < 0.1 * off.mean()  # (black but for the floor at the pixels' edges)


def regions(img):
    return region_means(img, 8).mean(-1)


def test_each_toggle_keeps_the_other_kind_of_caustic(caustics):
    floor = caustics["floor"]
    cut = lambda name: np.where(floor[..., None], caustics[name][0], 0.0)  # noqa: E731
    on, black = regions(cut("on")), regions(cut("black"))
    no_refl, no_refr = regions(cut("no_refl")), regions(cut("no_refr"))
    # The glass's focus: the region whose light the refractive toggle removes most; the mirror's
    # patch: the one the reflective toggle removes most. Distinct, and both well above the shadows.
    glass_r = np.unravel_index(np.argmax(on - no_refr), on.shape)
    mirror_r = np.unravel_index(np.argmax(on - no_refl), on.shape)
    assert glass_r != mirror_r
    assert on[glass_r] > black[glass_r] + 0.15 and on[mirror_r] > black[mirror_r] + 0.15
    # Reflective off: the mirror's caustic gone (its patch within a fifth of the shadows' light),
    # the glass's kept (within 15 %, the path tracer's caustic noise at 1024 spp); Refractive off:
    # the reverse.
    gain = lambda img, r: img[r] - black[r]  # noqa: E731
    assert gain(no_refl, mirror_r) < 0.2 * gain(on, mirror_r)
    assert abs(gain(no_refl, glass_r) / gain(on, glass_r) - 1.0) < 0.15
    assert gain(no_refr, glass_r) < 0.2 * gain(on, glass_r)
    assert abs(gain(no_refr, mirror_r) / gain(on, mirror_r) - 1.0) < 0.15


def test_toggles_turn_the_caustic_light_paths_off():
    s = caustic_scene()
    _, st = film(s, samples=1, caustic_light_paths=0.5)
    assert st["caustics"] == "on"
    for kw in ({"caustics_reflective": False}, {"caustics_refractive": False}, {"filter_glossy": 1.0}):
        _, st = film(s, samples=1, caustic_light_paths=0.5, **kw)
        assert st["caustics"].startswith("off: not with Filter Glossy"), kw
        assert "light path tricks" in st["features"]


def test_filter_glossy_roughness_is_cycles():
    f = pc.filter_glossy_roughness
    assert f(0.0, 0.01) == 0.0  # off
    assert f(1.0, math.inf) == 0.0  # the camera's first vertex: no bounce yet
    assert f(1.0, 1.0) == 0.0 and f(2.0, 0.5) == 0.0  # pdf times filter_glossy 1: nothing
    assert f(1.0, 0.25) == pytest.approx(math.sqrt(0.75) * 0.5, rel=1e-6)
    assert f(0.5, 1.5) == pytest.approx(0.25, rel=1e-6)  # blur_glossy 2: 0.75 -> sqrt(0.25) / 2
    assert f(0.1, 1.0 / math.pi) == pytest.approx(math.sqrt(1.0 - 0.1 / math.pi) * 0.5, rel=1e-6)


@pytest.mark.parametrize("kind, sharp, rough", [
    ("conductor", {"alpha": 0.01}, {"alpha": 0.3}),
    ("conductor", {"alpha": 0.01, "distribution": "beckmann"}, {"alpha": 0.3, "distribution": "beckmann"}),
    ("conductor", {"alpha": 0.01, "distribution": "ashikhmin_shirley"},
     {"alpha": 0.3, "distribution": "ashikhmin_shirley"}),
    ("conductor", {"alpha": 0.01, "alpha_y": 0.6}, {"alpha": 0.3, "alpha_y": 0.6}),  # each axis
    ("conductor", {"alpha": 0.0, "specular_eta": 1.5, "f0": (0.04, 0.04, 0.04)},
     {"alpha": 0.3, "specular_eta": 1.5, "f0": (0.04, 0.04, 0.04)}),
    ("dielectric", {"alpha": 0.0}, {"alpha": 0.3}),  # smooth glass becomes rough
    ("dielectric", {"alpha": 0.01, "reflection": False, "fresnel_on_transmission": False},
     {"alpha": 0.3, "reflection": False, "fresnel_on_transmission": False}),
    ("hair_huang", {"roughness": 0.1}, {"roughness": 0.3}),
])
def test_blur_is_the_rougher_closure_exactly(kind, sharp, rough):
    rng = np.random.default_rng(3)
    wi = rng.normal(size=(256, 3)).astype(np.float32)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = (0.3, -0.2, 0.9) if kind != "hair_huang" else (0.2, 0.3, 0.9)
    fb, pb = pc.bsdf_eval(kind, dict(sharp, blur=0.3), wo, wi)
    fr, pr = pc.bsdf_eval(kind, rough, wo, wi)
    assert np.array_equal(fb, fr) and np.array_equal(pb, pr)
    assert fr.max() > 0.0
    # A closure already rougher keeps its own roughness.
    fk, _ = pc.bsdf_eval(kind, dict(rough, blur=0.1), wo, wi)
    assert np.array_equal(fk, fr)


def test_blur_raises_chiang_hair_as_cycles_compares_it():
    # Cycles compares its mapped variances and scale with the roughness: a rough strand keeps
    # what it has, a smooth one takes the roughness itself as its variance.
    rng = np.random.default_rng(4)
    wi = rng.normal(size=(64, 3)).astype(np.float32)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = (0.3, 0.2, 0.9)
    smooth = {"roughness": 0.05, "radial_roughness": 0.05}
    f0, _ = pc.bsdf_eval("hair_chiang", smooth, wo, wi)
    fb, _ = pc.bsdf_eval("hair_chiang", dict(smooth, blur=0.3), wo, wi)
    assert not np.allclose(f0, fb)
    # (a roughness of 1 maps to a variance and scale above 0.3: unchanged)
    fr, _ = pc.bsdf_eval("hair_chiang", {"roughness": 1.0, "radial_roughness": 1.0}, wo, wi)
    frb, _ = pc.bsdf_eval("hair_chiang", {"roughness": 1.0, "radial_roughness": 1.0, "blur": 0.3}, wo, wi)
    assert np.array_equal(fr, frb)


def glossy_room(alpha, camera_on="wall"):
    """A diffuse back wall over a glossy floor (GGX alpha) under a small, bright emitter that
    faces down: the camera sees the wall (every path to the floor passed a diffuse bounce), or
    ("floor") the floor alone under the emitter, whose reflection is all there is to see."""
    s = pc.Scene()
    wall = s.add_material("wall", (0.8, 0.8, 0.8))
    lamp = s.add_material("lamp", (0.0, 0.0, 0.0), (40.0, 40.0, 40.0))
    floor = s.add_shader("floor", closure("glossy", color=(0.9, 0.9, 0.9), roughness=math.sqrt(alpha)))
    add_object(s, *quad((-2, -2, 0), (4, 0, 0), (0, 4, 0)), floor)
    if camera_on == "wall":
        add_object(s, *quad((-2, 1.5, 0), (4, 0, 0), (0, 0, 3)), wall)  # facing -y
    add_object(s, *quad((-0.2, 0.2, 2.0), (0, 0.4, 0), (0.4, 0, 0)), lamp)  # facing down
    s.set_world_color((0.0, 0.0, 0.0))
    if camera_on == "wall":
        s.set_camera(camera(pc, (0.0, -1.0, 1.2), (0.0, 1.5, 1.2), lens=50.0))  # (the wall alone)
    else:
        s.set_camera(camera(pc, (0.0, -1.0, 1.5), (0.0, 0.4, 0.0), lens=30.0))
    s.commit()
    return s


def test_filter_glossy_leaves_what_the_camera_sees_directly():
    # The camera's first vertex is blurred by nothing (no bounce yet): the mirror floor seen
    # directly, whose next vertex is the lamp or the black world, renders bit for bit.
    s = glossy_room(0.0, camera_on="floor")
    plain, st0 = film(s, samples=16)
    blurred, st1 = film(s, samples=16, filter_glossy=1.0)
    assert plain.max() > 1.0  # (the lamp's reflection)
    assert st1["kernel"] == "general" and st0["kernel"] != "general"
    assert np.array_equal(plain, blurred)


def test_filter_glossy_after_a_diffuse_bounce_is_the_rougher_floor():
    # After the wall's diffuse bounce the pdf is cos / pi <= 1 / pi: with blur_glossy 10
    # (filter_glossy 0.1) the floor's alpha becomes sqrt(1 - 0.1 pdf) / 2, in [0.4919, 0.5]: the
    # wall then is lit as by a floor of alpha 0.5 (which the blur leaves as it is), within noise.
    sharp, rough = glossy_room(0.0), glossy_room(0.5)
    seeds = (1, 2, 3, 4)
    blurred = np.array([film(sharp, samples=64, seed=k, filter_glossy=10.0)[0] for k in seeds])
    ref = np.array([film(rough, samples=64, seed=k)[0] for k in seeds])
    plain = np.array([film(sharp, samples=64, seed=k)[0] for k in seeds])
    a, b, p = (np.array([regions(i) for i in x]) for x in (blurred, ref, plain))
    sd = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
    assert abs(blurred.mean() / ref.mean() - 1.0) < 0.03
    assert np.all(np.abs(a.mean(0) - b.mean(0)) <= np.maximum(4.0 * sd, 0.03 * b.mean(0)))
    # Unblurred, the sharp floor throws the lamp's image onto the wall: another picture, and
    # fireflies (light found by BSDF rays alone) that the blur removes.
    assert np.max(np.abs(p.mean(0) - b.mean(0)) / np.maximum(b.mean(0), 1e-3)) > 0.3
    assert blurred.var(0).mean() < 0.5 * plain.var(0).mean()
    # An explicit alpha of 0.5 is above every blur here: bit for bit with or without it.
    assert np.array_equal(film(rough, samples=16, filter_glossy=10.0)[0], film(rough, samples=16)[0])


def test_defaults_render_bit_for_bit_through_the_tricks_code():
    # filter_glossy 0, both toggles on, no clamp: the specialised kernel (no tricks code) and the
    # general one (tricks compiled in, off) give the same image.
    s = caustic_scene()
    spec, st0 = film(s, samples=8, filter_glossy=0.0, caustics_reflective=True, caustics_refractive=True)
    gen, st1 = film(s, samples=8, force_general_kernel=True)
    assert st0["kernel"] != "general" and st1["kernel"] == "general"
    assert "light path tricks" not in st0["features"]
    assert np.array_equal(spec, gen)


def test_bad_filter_glossy_is_off_with_a_warning():
    st = pc.RenderSettings()
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.warns(UserWarning, match="filter_glossy"):
            st.filter_glossy = bad
        assert st.filter_glossy == 0.0
    st.filter_glossy = 0.5
    assert st.filter_glossy == 0.5
