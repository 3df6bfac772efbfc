"""Caustic light paths through smooth glass and mirrors (issue 25; integrator_caustics.cpp and
trace_path.inl, docs/design/sampling.md "Caustic light paths through glass and mirrors"): delta
vertices in the light path's smooth chain, with MIS weights that still sum to 1 against the path
tracer's BSDF rays through the same chain. The image agrees with the plain path tracer's within
its noise, with far less of it; few or many light paths give the same image (the densities agree);
deterministic; a delta lamp next to glass stays the path tracer's alone."""
import re

import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, quad, render, uv_sphere
# (the environment with a one-texel sun and the seeds' renders at 48 x 36 of the caustic tests)
from test_caustic_light_paths import assert_same_within_noise, renders, sun_env

pc = core()


def glass_scene(light="env", delta=False, angle=4.0, radius=0.1, world=None, glossy=False):
    """A diffuse floor, a smooth glass sphere (Glass BSDF, roughness 0, IOR 1.45) and a tilted
    perfect mirror panel (Glossy, roughness 0) beside it, under sun_env ("env"), a sun lamp of
    `angle` degrees ("sun") or a point lamp of `radius` ("point") behind them, so that the
    sphere's focused caustic and the mirror's reflected patch fall on the floor in view.
    delta: the lamp without extent (angle or radius 0). world: an environment map beside the
    lamp (else a dim colour). glossy: the sphere and the panel smooth Glossy (roughness 0.1)
    instead of glass and a mirror."""
    s = pc.Scene()
    floor = s.add_material("floor", (0.7, 0.7, 0.7))
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), floor)
    if glossy:
        glass = s.add_shader("glass", closure("glossy", color=(0.9, 0.9, 0.9), roughness=0.1))
        mirror = s.add_shader("mirror", closure("glossy", color=(0.95, 0.95, 0.95), roughness=0.1))
    else:
        glass = s.add_shader("glass", closure("glass", color=(0.98, 0.98, 0.98), roughness=0.0, ior=1.45))
        mirror = s.add_shader("mirror", closure("glossy", color=(0.95, 0.95, 0.95), roughness=0.0))
    pos, tris, nrm = uv_sphere(0.4, center=(0.0, 0.3, 0.45))
    add_object(s, pos, tris, glass, nrm)
    add_object(s, *quad((0.5, -0.6, 0.0), (0.6, 0.0, 0.0), (0.0, -0.15, 0.6)), mirror)
    if light == "env":
        s.set_world_texture(sun_env())
    elif world is not None:
        s.set_world_texture(world)
    else:
        s.set_world_color((0.03, 0.03, 0.04))
    if light == "sun":
        s.add_sun_light((0.25, 0.55, 0.8), (3.0, 3.0, 3.0), angle=0.0 if delta else np.radians(angle))
    if light == "point":
        s.add_point_light((0.3, 1.3, 2.0), (20.0, 20.0, 20.0), radius=0.0 if delta else radius)
    s.set_camera(camera(pc, (0.0, -2.2, 2.4), (0.0, 0.1, 0.0), lens=35.0))
    s.commit()
    return s


def sheet_scene(angle=10.0):
    """A single refracting sheet (Refraction BSDF, IOR 1.33, roughness 0: one interface, so the
    light path's refraction is not undone by a second one) standing between a sun lamp of `angle`
    degrees and the floor in view: the floor behind it is lit through it alone."""
    s = pc.Scene()
    floor = s.add_material("floor", (0.7, 0.7, 0.7))
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), floor)
    water = s.add_shader("water", closure("refraction", color=(1.0, 1.0, 1.0), roughness=0.0, ior=1.33))
    add_object(s, *quad((-0.9, -1.2, 0.0), (0.0, 2.4, 0.0), (0.0, 0.0, 1.2)), water)
    s.set_world_color((0.03, 0.03, 0.04))
    s.add_sun_light((-0.8, 0.0, 0.6), (3.0, 3.0, 3.0), angle=np.radians(angle))
    s.set_camera(camera(pc, (0.0, -2.2, 2.4), (0.0, 0.1, 0.0), lens=35.0))
    s.commit()
    return s


# The floor in view (rows, columns of the 48 x 36 film): the sphere's caustic, the mirror's patch,
# and the sheet's lit floor.
CAUSTIC = (slice(10, 19), slice(16, 28))
PATCH = (slice(12, 22), slice(28, 38))
SHEET = (slice(2, 26), slice(14, 22))


# Variance bounds per sample: measured 0.18x (environment), 0.07x (sun of 4 degrees), 0.02x
# (point of radius 0.1) at 128 spp x 3 seeds.
GLASS_SETS = {"env": (dict(light="env"), 0.35), "sun": (dict(light="sun"), 0.2), "point": (dict(light="point"), 0.1)}


@pytest.fixture(scope="module", params=list(GLASS_SETS))
def glass_renders(request):
    s = glass_scene(**GLASS_SETS[request.param][0])
    plain, _ = renders(s, 128, (1, 2, 3))
    lt, st = renders(s, 128, (1, 2, 3), caustic_light_paths=0.5)
    return request.param, plain, lt, st


def test_glass_and_mirrors_converge_to_the_path_tracers_image(glass_renders):
    # The whole image within 1 %, each 4 x 4 region within 3 sd of the two estimates' seed spread
    # or 3 % (finer regions meet the plain image's rare caustic fireflies, whose 3-seed spread
    # says little; the few-or-many test below is the exact check).
    _, plain, lt, st = glass_renders
    assert st["caustics"] == "on"
    assert_same_within_noise(plain, lt, regions=4)


def test_glass_and_mirrors_light_paths_lower_the_variance(glass_renders):
    kind, plain, lt, _ = glass_renders
    assert lt.var(0, ddof=1).mean() < GLASS_SETS[kind][1] * plain.var(0, ddof=1).mean()


# Few or many light paths: with few (0.03 per sample) the weights split between the path tracer's
# BSDF rays through the glass and the light paths, with many (3) the light paths take nearly all;
# the image is the same only if both sides use the same densities through the delta vertices. The
# lamps with the extent that lets the BSDF rays find them often (a sun of 10 degrees, a point of
# radius 0.3); the sheet: a single refraction, whose etap^2 a closed object's second one undoes.
FEW_MANY = {
    "env": (lambda: glass_scene("env"), (CAUSTIC, PATCH)),
    "sun": (lambda: glass_scene("sun", angle=10.0), (CAUSTIC, PATCH)),
    "point": (lambda: glass_scene("point", radius=0.3), (CAUSTIC,)),
    "sheet": (lambda: sheet_scene(), (SHEET,)),
}


@pytest.mark.parametrize("kind", list(FEW_MANY))
def test_glass_few_or_many_light_paths_give_the_same_image(kind):
    make, windows = FEW_MANY[kind]
    s = make()
    few, st = renders(s, 96, (1, 2, 3, 4), caustic_light_paths=0.03)
    many, _ = renders(s, 24, (1, 2, 3, 4), caustic_light_paths=3.0)
    assert st["caustics"] == "on"
    for r, c in windows:
        f, m = few[:, r, c].mean(), many[:, r, c].mean()
        assert abs(f / m - 1.0) < 0.05, (kind, f / m)
    if kind == "sheet":
        # The light path's value through one refraction against the plain path tracer's (a
        # closed object's second refraction would undo an etap^2 lost in it): a coarse bound, the
        # plain image's fireflies there having a seed spread of a few percent.
        plain, _ = renders(s, 96, (1, 2, 3, 4))
        r, c = SHEET
        assert abs(many[:, r, c].mean() / plain[:, r, c].mean() - 1.0) < 0.1


@pytest.mark.sanitize  # quick: the delta vertices on the sanitizer build too
def test_glass_deterministic_whatever_the_threads():
    for s in (glass_scene("point"), glass_scene("env")):
        kw = dict(samples=4, seed=9, caustic_light_paths=1.0)
        a, st = render(pc, s, 40, 24, threads=1, tile_size=8, **kw)
        b, _ = render(pc, s, 40, 24, threads=2, tile_size=16, **kw)
        assert st["caustics"] == "on" and np.array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.sanitize  # quick: a delta lamp's light paths stopping at glass on the sanitizer build too
@pytest.mark.parametrize("light", ["sun", "point"])
def test_a_delta_lamp_next_to_glass_adds_no_light(light):
    # A sun of angle 0 or a point of radius 0: no BSDF ray finds it and no light sample passes the
    # glass or the mirror next to it, so the path tracer cannot make these caustics (nor can
    # Cycles): the light paths that meet glass or a mirror first add nothing either.
    s = glass_scene(light, delta=True)
    a, _ = render(pc, s, 32, 24, samples=16, seed=4)
    b, st = render(pc, s, 32, 24, samples=16, seed=4, caustic_light_paths=1.0)
    assert st["caustics"] == "on"
    a, b = np.asarray(a)[..., :3], np.asarray(b)[..., :3]
    assert abs(b.mean() / a.mean() - 1.0) < 1e-4 and np.abs(b - a).max() < 0.01 * a.max()


@pytest.mark.sanitize  # quick: the probes' delta closures on the sanitizer build too
def test_glass_alone_casts_caustics():
    # Nothing smooth but glass and a mirror: the probes count them as casters (before: "no smooth
    # surface"), and the automatic mode turns the light paths on under the environment's sun.
    s = glass_scene("env")
    _, st = render(pc, s, 16, 12, samples=1, caustic_light_paths=1.0)
    assert st["caustics"] == "on"
    _, st = render(pc, s, 16, 12, samples=1, caustic_light_paths_auto=True)
    assert st["caustics"].startswith("on (automatic)")


def lamp_share(state):
    """The lamps' share of the light paths' power (percent) that an automatic decision names."""
    m = re.search(r"lamps with extent send (\d+) %", state)
    return int(m.group(1)) if m else None


def sky_map(mean):
    """An environment map without a peak: a gradient from 0.5 to 1.5 x `mean` down its rows (a
    constant one is a colour, not a map)."""
    rows = np.linspace(1.5, 0.5, 32, dtype=np.float32) * mean
    return np.repeat(rows[:, None, None], 64, 1).repeat(3, 2).astype(np.float32)


@pytest.mark.sanitize  # quick: tiny renders
def test_automatic_for_lamps_with_extent_over_glass_and_mirrors():
    """The automatic mode's lamp rule (session.cpp, kAutoLamp*; docs/design/sampling.md "Glass and
    mirrors under a sun lamp: the automatic rule"): where the environment's rule does not turn them
    on, 0.25 light paths per sample where lamps with extent send at least half of the light paths'
    power and the probes find smooth glass or a mirror; else off, silently, the plain image."""
    kw = dict(samples=3, seed=4)
    # On: a sun lamp of 4 degrees or a point of radius 0.1 over glass and a mirror (no map); a
    # map without a peak (its rule says off) beside the sun, which sends most of the power.
    dim = sky_map(0.1)  # 4 pi 0.1 against the sun's 3: ~30 % of the power
    for scene, share in ((glass_scene("sun"), 100), (glass_scene("point"), 100), (glass_scene("sun", world=dim), 60)):
        a, st = render(pc, scene, 24, 16, caustic_light_paths_auto=True, **kw)
        assert st["caustics"].startswith("on (automatic): lamps with extent send"), st["caustics"]
        assert "+caustics" in st["kernel"] and lamp_share(st["caustics"]) >= share, st["caustics"]
        b, _ = render(pc, scene, 24, 16, caustic_light_paths=0.25, **kw)  # the lamps' rule is 0.25 per sample
        assert np.array_equal(np.asarray(a), np.asarray(b))
    # The environment's rule decides first: a map whose sun holds most of its power beside the
    # sun lamp is on at its 0.1, by its own reason.
    sunny = glass_scene("sun", world=sun_env(peak=2000.0))
    a, st = render(pc, sunny, 24, 16, caustic_light_paths_auto=True, **kw)
    assert st["caustics"].startswith("on (automatic): the environment's peak"), st["caustics"]
    b, _ = render(pc, sunny, 24, 16, caustic_light_paths=0.1, **kw)
    assert np.array_equal(np.asarray(a), np.asarray(b))
    # Off: a delta sun or point (its caustics through glass no strategy of the path tracer makes);
    # glossy casters without glass or a mirror; a bright map without a peak that holds most of
    # the light paths' power (its rule says off, and the sun lamp's share is under half).
    bright = sky_map(0.5)  # 4 pi 0.5 against the sun's 3: ~68 %
    cases = ((glass_scene("sun", delta=True), "no lamp with extent"),
             (glass_scene("point", delta=True), "no lamp with extent"),
             (glass_scene("sun", glossy=True), "no smooth glass or mirror"),
             (glass_scene("sun", world=bright), "(under 50 %)"))
    for scene, why in cases:
        p, _ = render(pc, scene, 24, 16, **kw)
        q, st_q = render(pc, scene, 24, 16, caustic_light_paths_auto=True, **kw)
        assert st_q["caustics"].startswith("off (automatic): ") and why in st_q["caustics"], st_q["caustics"]
        assert np.array_equal(np.asarray(p), np.asarray(q))
    # Explicit light paths still run where the rule says off (the glossy casters).
    _, st = render(pc, glass_scene("sun", glossy=True), 24, 16, caustic_light_paths=0.25, **kw)
    assert st["caustics"] == "on"
