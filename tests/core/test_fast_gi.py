"""Cycles' Fast GI Approximation (RenderSettings.ao_bounces, ao_factor, ao_additive_factor,
ao_distance; Blender's Light Paths > Fast GI Approximation) and Film > Transparent Glass
(film_transparent_glass, film_transparent_roughness); docs/design/sampling.md "Fast GI
approximation", docs/design/passes.md "Transparent glass".

Replace, as Cycles' path_state_ao_bounce / integrate_background / integrator_intersect_terminate:
once a path's bounces (less transmission, less one if any was glossy) reach ao_bounces, its next
ray reaches at most ao_distance; a surface there ends the path (its emission still counts), the
world it reaches counts times ao_factor. Add, as integrate_surface_ao: every surface adds its
diffuse closures' weight times the factor where a cosine ray of ao_distance finds nothing.

Closed forms: inside a closed sphere of emission Le and albedo a (no world), Replace with N
bounces gives sum_{k<=N} a^k Le; a convex diffuse sphere of albedo a under a constant world W,
without light sampling, gives a f W (N = 1) or a W (N >= 2), with the world's light sample
(flat shading: both strategies' pdfs equal, each half the weight) a W (1 + f) / 2; Add gives
a W + a k."""
import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, cornell, emitting_enclosure, quad, run_session, uv_sphere

pc = core()
W = H = 24


def film(scene, samples=256, seed=3, threads=2, **kw):
    kw.setdefault("caustic_light_paths_auto", False)
    sess = run_session(pc, scene, W, H, samples, threads=threads, seed=seed, **kw)
    return np.asarray(sess.film()).astype(np.float64), sess.stats()


def furnace(albedo=0.6, world=1.0, smooth=False):
    s = pc.Scene()
    m = s.add_material("sphere", (albedo, albedo, albedo))
    pos, tris, nrm = uv_sphere(1.0, nu=64, nv=32)
    add_object(s, pos, tris, m, nrm if smooth else None)
    s.set_world_color((world, world, world))
    s.set_camera(camera(pc, (0.0, -5.0, 0.0), (0.0, 0.0, 0.0), lens=50.0))
    return s


def centre(img):
    """The mean of the central 8 x 8 pixels (all on the sphere) and their pixels' spread."""
    c = img[W // 2 - 4:W // 2 + 4, H // 2 - 4:H // 2 + 4, :3]
    return c.mean(), c.mean(-1).std() / np.sqrt(c.shape[0] * c.shape[1])


def close(value, expected, err, k=5.0, floor=2e-3):
    assert abs(value - expected) < k * err + floor, (value, expected, err)


# --- Replace ---------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 2, 3])
def test_replace_in_a_closed_emitting_room_stops_after_n_bounces(n):
    # Le = a = 0.5: without Fast GI the radiance is Le / (1 - a) = 1 everywhere; with it the
    # AO ray after n bounces finds the shell within the distance (the sphere's diameter is 2):
    # its emission, then nothing. Light samples on: the shell's own MIS keeps the sum exact.
    img, st = film(emitting_enclosure(pc), samples=128, ao_bounces=n, ao_factor=1.0, ao_distance=10.0)
    expected = sum(0.5 ** (k + 1) for k in range(n + 1))  # 0.75, 0.875, 0.9375
    m = img[..., :3].mean()
    sem = img[..., :3].mean(-1).std() / np.sqrt(W * H)
    close(m, expected, sem)
    assert st["kernel"] == "general" and "fast gi" in st["features"]


def test_replace_reads_the_objects_own_ao_distance():
    """Cycles' intersect_closest: an object's own AO Distance (add_instance's ao_distance), where
    set, is the reach of the AO rays that leave its surfaces instead of the world's. The shell of
    emission 0.5, albedo 0.5 under a grey world 0.8, factor 0.5, no light samples: a reach past
    the shell brings its emission (0.5 + 0.25), a reach far shorter the world (0.5 + 0.5 f W)."""
    def room(ao_distance):
        s = pc.Scene()
        m = s.add_material("shell", (0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
        pos, tris, nrm = uv_sphere(1.0, nu=32, nv=16, inward=True)
        s.add_instance(s.add_mesh(pos, tris, nrm, None, [m]), np.eye(4, dtype=np.float32),
                       ao_distance=ao_distance)
        s.set_world_color((0.8, 0.8, 0.8))
        s.set_camera(camera(pc, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), lens=20.0))
        return s

    def check(ao_distance, world_distance, expected):
        img, _ = film(room(ao_distance), samples=128, ao_bounces=1, ao_factor=0.5,
                      ao_distance=world_distance, use_nee=False)
        close(img[..., :3].mean(), expected, img[..., :3].mean(-1).std() / np.sqrt(W * H))
    check(10.0, 1e-3, 0.75)  # the object's reach, not the world's
    check(1e-3, 10.0, 0.5 + 0.5 * 0.5 * 0.8)
    # 0 (Cycles' default), and what Cycles' RNA never gives, are the world's distance.
    for bad in (0.0, -1.0, float("nan")):
        check(bad, 1e-3, 0.5 + 0.5 * 0.5 * 0.8)


def test_replace_short_distance_brings_the_world_times_the_factor():
    # An AO distance far shorter than the room: every AO ray reaches no surface, so it brings the
    # world times the factor (without light samples: the BSDF ray alone). Le + a f W.
    s = emitting_enclosure(pc)
    s.set_world_color((0.8, 0.8, 0.8))
    img, _ = film(s, samples=128, ao_bounces=1, ao_factor=0.5, ao_distance=1e-3, use_nee=False)
    sem = img[..., :3].mean(-1).std() / np.sqrt(W * H)
    close(img[..., :3].mean(), 0.5 + 0.5 * 0.5 * 0.8, sem)
    # ... and with a black world the room goes dark: the shell's own emission only.
    s.set_world_color((0.0, 0.0, 0.0))
    dark, _ = film(s, samples=16, ao_bounces=1, ao_factor=0.5, ao_distance=1e-3, use_nee=False)
    assert np.allclose(dark[..., :3], 0.5, atol=1e-5)


@pytest.mark.parametrize("n,f", [(1, 0.5), (1, 2.0), (2, 0.5)])
def test_white_furnace_without_light_samples(n, f):
    a = 0.6
    img, _ = film(furnace(a), samples=128, ao_bounces=n, ao_factor=f, use_nee=False)
    m, err = centre(img)
    close(m, a * f if n == 1 else a, err)


def test_white_furnace_light_sample_keeps_its_weight():
    # Cycles scales only what the AO ray brings (integrate_background): the world's light sample
    # at the vertex before it keeps its full value; flat shading gives each strategy half.
    a, f = 0.6, 0.25
    s = furnace(a)
    s.world_light_samples = True  # (the constant world as a light: opt-in in the core)
    img, _ = film(s, samples=256, ao_bounces=1, ao_factor=f)
    m, err = centre(img)
    close(m, a * (1.0 + f) / 2.0, err)


def test_replace_in_the_cornell_box_removes_later_bounces():
    # Cornell box, Replace after 1 bounce and an unbounded distance: the walls the AO ray meets
    # add nothing, so only the lamp's direct light (its light sample and the rays that find it)
    # remains; a black world changes nothing (no ray escapes the closed box), and factor 0 is
    # Fast GI off (Cycles: ao_bounces 0 without a factor), bit for bit the plain render.
    plain, st_plain = film(cornell(pc), samples=32)
    one, _ = film(cornell(pc), samples=32, ao_bounces=1, ao_factor=1.0, ao_distance=float("inf"))
    two, _ = film(cornell(pc), samples=32, ao_bounces=2, ao_factor=1.0, ao_distance=float("inf"))
    assert one[..., :3].mean() < 0.95 * two[..., :3].mean() < 0.95 * plain[..., :3].mean()
    off, st_off = film(cornell(pc), samples=32, ao_bounces=1, ao_factor=0.0)
    assert np.array_equal(off, plain) and st_off["kernel"] == st_plain["kernel"] == "diffuse"


def test_replace_counts_no_transmission_bounce():
    # A smooth glass slab (two faces) between the camera and the furnace sphere: its two
    # refractions are transmission bounces, which Cycles' count leaves out (bounce -
    # transmission_bounce), so the sphere behind it still gets its AO ray after its own diffuse
    # bounce: a f W times the slab's transmittance (an AO distance of 1 keeps the sphere's AO rays
    # off the slab). Counted, the AO ray would leave the first face and end at the second (glass:
    # no emission, no transparency): black.
    def scene(slab):
        s = furnace(0.6)
        if slab:
            glass = s.add_shader("glass", closure("glass", color=(1.0, 1.0, 1.0), roughness=0.0, ior=1.5))
            add_object(s, *quad((-2, -3.5, -2), (4, 0, 0), (0, 0, 4)), glass)
            add_object(s, *quad((-2, -3.4, -2), (0, 0, 4), (4, 0, 0)), glass)
        return s
    fields = dict(samples=128, ao_bounces=1, ao_factor=0.5, ao_distance=1.0, use_nee=False)
    ref, _ = film(scene(False), **fields)
    through, _ = film(scene(True), **fields)
    m, err = centre(ref)
    close(m, 0.6 * 0.5, err)
    # (plus the slab's reflection of the world, about 0.08: what a black sphere would show)
    assert 0.85 * m < centre(through)[0] < m + 0.12


def test_a_shortened_ray_that_reaches_nothing_still_finds_the_sun():
    # A ground plane under a sun with an angle (found by BSDF rays too: light hits) and a black
    # world: an AO ray that reaches nothing within its distance is an escaped ray, so the sun
    # counts (Cycles' integrate_distant_lights, unscaled) exactly as for an unbounded AO ray.
    # (Principled: a diffuse-only vertex finds such lights by its light samples alone.)
    def scene():
        s = pc.Scene()
        m = s.add_shader("ground", closure("principled", base_color=(0.7, 0.7, 0.7), roughness=0.5))
        add_object(s, *quad((-5, -5, 0), (10, 0, 0), (0, 10, 0)), m)
        s.add_sun_light((0.3, -0.2, 1.0), (3.0, 3.0, 3.0), angle=0.4)
        s.set_world_color((0.0, 0.0, 0.0))
        s.set_camera(camera(pc, (0.0, -3.0, 2.0), (0.0, 0.0, 0.0), lens=35.0))
        return s
    short, st = film(scene(), samples=16, ao_bounces=1, ao_factor=0.5, ao_distance=1e-3)
    unbounded, _ = film(scene(), samples=16, ao_bounces=1, ao_factor=0.5, ao_distance=float("inf"))
    assert "light hits" in st["features"] and short[..., :3].mean() > 0.1
    assert np.array_equal(short, unbounded)


# --- Add -------------------------------------------------------------------------------------

@pytest.mark.parametrize("k", [0.5, 1.0])
def test_add_on_the_furnace_adds_the_diffuse_weight_times_the_factor(k):
    a = 0.6
    plain, _ = film(furnace(a), samples=128)
    add, st = film(furnace(a), samples=128, ao_additive_factor=k)
    m, err = centre(add)
    close(m, a + a * k, err)
    close(centre(plain)[0], a, err)
    assert st["kernel"] == "general"


def flat_enclosure():
    """emitting_enclosure with flat shading: every cosine ray about the normal stays inside
    (with smooth normals a ray below the triangle leaves through it, in Cycles too)."""
    s = pc.Scene()
    m = s.add_material("shell", (0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
    pos, tris, _ = uv_sphere(1.0, nu=32, nv=16, inward=True)
    add_object(s, pos, tris, m)
    s.set_camera(camera(pc, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), lens=20.0))
    return s


def test_add_in_a_closed_room_adds_nothing():
    # Inside the closed sphere every AO ray of distance 10 meets the shell: nothing is added,
    # and its own random numbers leave the path's as they were (bit for bit the plain render).
    plain, _ = film(flat_enclosure(), samples=16)
    add, _ = film(flat_enclosure(), samples=16, ao_additive_factor=1.0, ao_distance=10.0)
    assert np.array_equal(plain, add)
    # A short distance: the rays get out, and light is added.
    short, _ = film(flat_enclosure(), samples=16, ao_additive_factor=1.0, ao_distance=1e-3)
    assert short[..., :3].mean() > plain[..., :3].mean() + 0.3


# --- Both ------------------------------------------------------------------------------------

@pytest.mark.parametrize("fields", [{"ao_bounces": 1, "ao_factor": 0.7, "ao_distance": 0.5},
                                    {"ao_additive_factor": 0.6, "ao_distance": 0.5}])
def test_deterministic_across_thread_counts(fields):
    a, _ = film(cornell(pc), samples=16, threads=1, **fields)
    b, _ = film(cornell(pc), samples=16, threads=3, **fields)
    assert np.array_equal(a, b)


def test_guiding_and_caustic_light_paths_are_off_with_a_reason():
    _, st = film(cornell(pc), samples=2, ao_bounces=1, ao_factor=1.0, guiding=True,
                 caustic_light_paths=1.0)
    assert st["guiding"] == "off: not with Fast GI Approximation"
    assert st["caustics"] == "off: not with Fast GI Approximation"
    assert "guiding" not in st["features"]
    _, st = film(cornell(pc), samples=2, ao_bounces=1, ao_factor=1.0, guiding=True)
    _, plain = film(cornell(pc), samples=2, guiding=True)
    assert plain["guiding"] == "" and "guiding" in plain["features"]


def test_bad_settings_are_zero_with_a_warning():
    st = pc.RenderSettings()
    with pytest.warns(UserWarning, match="ao_bounces"):
        st.ao_bounces = -2
    assert st.ao_bounces == 0
    for name in ("ao_factor", "ao_additive_factor", "film_transparent_roughness"):
        with pytest.warns(UserWarning, match=name):
            setattr(st, name, float("nan"))
        assert getattr(st, name) == 0.0
        with pytest.warns(UserWarning, match=name):
            setattr(st, name, -1.0)
        assert getattr(st, name) == 0.0


# --- Transparent glass -----------------------------------------------------------------------

def glass_scene(roughness=0.0):
    """A glass sphere filling the view's centre under a constant grey world."""
    s = pc.Scene()
    g = s.add_shader("glass", closure("glass", color=(1.0, 1.0, 1.0), roughness=roughness, ior=1.45))
    pos, tris, nrm = uv_sphere(1.0, nu=64, nv=32)
    add_object(s, pos, tris, g, nrm)
    s.set_world_color((0.5, 0.5, 0.5))
    s.set_camera(camera(pc, (0.0, -5.0, 0.0), (0.0, 0.0, 0.0), lens=50.0))
    return s


def test_transparent_glass_moves_the_world_seen_through_glass_to_alpha():
    # The same paths either way (the flag changes only where the world goes): per pixel, what
    # Transparent Glass takes out of the colour is the world times 1 - alpha.
    s = glass_scene()
    off, _ = film(s, samples=64, film_transparent=True)
    on, _ = film(s, samples=64, film_transparent=True, film_transparent_glass=True)
    assert np.all(off[..., 3] >= 0.0)
    c_off, c_on = centre(off)[0], centre(on)[0]
    alpha_on = on[W // 2 - 4:W // 2 + 4, H // 2 - 4:H // 2 + 4, 3].mean()
    assert np.allclose(off[W // 2 - 4:W // 2 + 4, H // 2 - 4:H // 2 + 4, 3], 1.0)  # opaque glass without it
    assert 0.02 < alpha_on < 0.3  # (the Fresnel reflections, and internal ones, stay opaque)
    assert np.allclose(on[..., :3], off[..., :3] - 0.5 * (off[..., 3:4] - on[..., 3:4]), atol=1e-5)
    assert c_on < 0.5 * c_off
    # The background itself is transparent either way; Transparent Glass without transparent
    # film does nothing.
    assert np.allclose(on[0, 0, 3], 0.0) and np.allclose(off[0, 0, 3], 0.0)
    opaque, _ = film(s, samples=64, film_transparent_glass=True)
    plain, _ = film(s, samples=64)
    assert np.array_equal(opaque, plain)


@pytest.mark.parametrize("roughness,threshold,transparent", [(0.2, 0.1, False), (0.2, 0.25, True),
                                                             (0.09, 0.1, True)])
def test_transparent_glass_roughness_threshold(roughness, threshold, transparent):
    # Cycles compares alpha_x alpha_y (roughness^4 for Blender's roughness) with the threshold^4.
    s = glass_scene(roughness)
    on, _ = film(s, samples=16, film_transparent=True, film_transparent_glass=True,
                 film_transparent_roughness=threshold)
    off, _ = film(s, samples=16, film_transparent=True)
    alpha = on[W // 2 - 4:W // 2 + 4, H // 2 - 4:H // 2 + 4, 3].mean()
    if transparent:
        assert alpha < 0.5
    else:
        assert np.array_equal(on, off)
