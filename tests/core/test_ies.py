"""IES light profiles in the core (pc.IesProfile; lights' `ies` argument): the LM-63 reader with
Cycles 4.5's conventions (candela x 4 pi / 177.83, symmetric profiles mirrored, its Catmull-Rom
lookup and edge rules), hostile files that must fail cleanly, and lights whose light samples and
ray hits carry the same profile (MIS stays exact). The comparison with Cycles itself is in
tests/blender/test_ies_lights.py."""
import math

import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, run_session
from test_light_hits import plane_scene, renders

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

CD_TO_CYCLES = 4 * math.pi / 177.83  # Cycles' candela to lamp-strength factor


def ies_text(v, h, cd, ptype=1, mult=1.0, header="IESNA:LM-63-2002\n[TEST] synthetic\n", tilt="TILT=NONE\n"):
    """An LM-63 file: cd[i][j] is the candela at horizontal angle h[i], vertical angle v[j]."""
    lines = [header + tilt + f"1 1000 {mult} {len(v)} {len(h)} {ptype} 2 0.0 0.0 0.0", "1.0 1.0 100",
             " ".join(map(str, v)), " ".join(map(str, h))]
    lines += [" ".join(map(str, row)) for row in cd]
    return ("\n".join(lines) + "\nEND\n").encode()


def direction(h_deg, v_deg):
    """The light-local direction of Cycles' angles: v from straight down (-Z), h = atan2(x, y) + pi."""
    h, v = math.radians(h_deg) - math.pi, math.radians(v_deg)
    return (math.sin(v) * math.sin(h), math.sin(v) * math.cos(h), -math.cos(v))


def cubic(a, b, c, d, x):
    return 0.5 * (((d + 3 * (b - c) - a) * x + (2 * a - 5 * b + 4 * c - d)) * x + (c - a)) * x + b


def test_table_values_are_candela_in_cycles_units():
    v, h = [0, 30, 60, 90], [0, 90, 180, 270, 360]
    cd = [[100 + 10 * i + j for j in range(4)] for i in range(5)]
    p = pc.IesProfile(ies_text(v, h, cd, mult=2.0))
    np.testing.assert_allclose(p.h_angles, np.radians(h), rtol=1e-6)
    np.testing.assert_allclose(p.v_angles, np.radians(v), rtol=1e-6)
    # At interior table points the interpolation gives the entry (times the multiplier).
    for i in (1, 2):
        for j in (1, 2):
            assert p.lookup(math.radians(h[i]), math.radians(v[j])) == pytest.approx(
                2.0 * cd[i][j] * CD_TO_CYCLES, rel=1e-5)
    # Straight down is vertical angle 0; straight up is beyond the table (90 degrees): 0.
    assert p.eval((0, 0, -1)) > 0 and p.eval((0, 0, 1)) == 0.0
    assert p.eval((0, 0, 0)) == 0.0


def test_cycles_edges_do_not_wrap_at_360_degrees():
    # A constant profile over the full circle: inside, constant; in the first and last
    # horizontal intervals Cycles' float test (2 pi - 1e-7 rounds to 2 pi) leaves the
    # neighbour beyond the end 0, so the Catmull-Rom curve bulges there, as Cycles renders it.
    p = pc.IesProfile(ies_text([0, 45, 90], [0, 90, 180, 270, 360], [[1000] * 3] * 5))
    k = 1000 * CD_TO_CYCLES
    assert p.lookup(math.radians(135), math.radians(30)) == pytest.approx(k, rel=1e-5)
    assert p.lookup(math.radians(45), math.radians(30)) == pytest.approx(k * cubic(0, 1, 1, 1, 0.5), rel=1e-5)
    assert p.lookup(math.radians(315), math.radians(30)) == pytest.approx(k * cubic(1, 1, 1, 0, 0.5), rel=1e-5)


def test_symmetric_profiles_are_mirrored_to_the_full_circle():
    v = [0, 30, 60, 90]
    quadrant = [[100, 200, 300, 400], [150, 250, 350, 450], [300, 400, 500, 600]]
    p = pc.IesProfile(ies_text(v, [0, 45, 90], quadrant))
    np.testing.assert_allclose(np.degrees(p.h_angles), [0, 45, 90, 135, 180, 225, 270, 315, 360], atol=1e-4)
    half = pc.IesProfile(ies_text(v, [0, 90, 180], quadrant))
    np.testing.assert_allclose(np.degrees(half.h_angles), [0, 90, 180, 270, 360], atol=1e-4)
    # Mirror images of a direction about the planes at 90 and 180 degrees get the same value
    # (away from the first and last intervals, where Cycles' missing wrap breaks the symmetry).
    for hv in (55.0, 80.0):
        ref = p.eval(direction(hv, 40))
        assert ref > 0
        for mirrored in (180 - hv, 180 + hv, 360 - hv):
            assert p.eval(direction(mirrored, 40)) == pytest.approx(ref, rel=1e-4), mirrored
    # One horizontal angle: rotationally symmetric.
    sym = pc.IesProfile(ies_text(v, [0], [[100, 300, 500, 700]]))
    vals = [sym.lookup(math.radians(a), math.radians(45)) for a in (10, 100, 190, 280)]
    assert max(vals) > 0 and np.ptp(vals) < 0.2 * max(vals)  # (the no-wrap bulge only)
    # A file that leaves out the 360 entry but is evenly spaced gets it back.
    skip = pc.IesProfile(ies_text(v, [0, 90, 180, 270], [[100] * 4] * 4))
    assert np.degrees(skip.h_angles[-1]) == pytest.approx(360, abs=1e-4)


def test_types_a_and_b_map_onto_type_c_angles():
    v = [0, 45, 90]
    cd = [[100, 200, 300], [400, 500, 600], [700, 800, 900]]
    b = pc.IesProfile(ies_text(v, [0, 45, 90], cd, ptype=2))
    assert np.degrees(b.h_angles[-1]) == pytest.approx(360, abs=1e-4) and b.mean > 0
    a = pc.IesProfile(ies_text(v, [0, 45, 90], cd, ptype=3))
    assert np.degrees(a.v_angles[0]) == pytest.approx(90, abs=1e-4)  # 0..90 -> 90..180: upwards
    assert a.eval((0, 0, -1)) == 0.0


def test_tilt_include_and_commas():
    v, h, cd = [0, 45, 90], [0], [[100, 200, 300]]
    plain = pc.IesProfile(ies_text(v, h, cd))
    tilted = pc.IesProfile(ies_text(v, h, cd, tilt="TILT=INCLUDE\n1\n3\n0 45 90\n1.0 0.9 0.8\n"))
    commas = pc.IesProfile(ies_text(v, h, cd).replace(b"0 45 90", b"0,45,90"))
    for q in (tilted, commas):
        assert q.eval(direction(0, 30)) == pytest.approx(plain.eval(direction(0, 30)), rel=1e-6)


GOOD = ies_text([0, 22.5, 45, 67.5, 90], [0, 90, 180], [[900, 800, 600, 300, 50]] * 3)


@pytest.mark.parametrize("data", [
    b"", b"garbage", b"\nTILT=NONE", b"\nTILT=NONE\n", b"IESNA\nTILT=NONE\n1 1 1 3 1 9 2 0 0 0\n",
    b"IESNA\nTILT=NONE\n1 1000 1 999999999 999999999 1 2 0 0 0\n1 1 1\n0 90\n",
    b"IESNA\nTILT=NONE\n1 1000 1 -5 2 1 2 0 0 0\n1 1 1\n",
    b"IESNA\nTILT=NONE\n1 1000 1 99999999999999999999999 1 1 2 0 0 0\n1 1 1\n",
    b"IESNA\nTILT=INCLUDE\n1\n999999999999\n",
    GOOD.replace(b"900", b"nan"), GOOD.replace(b"22.5", b"inf"), GOOD.replace(b"1 1000 1.0", b"1 1000 1e999"),
    GOOD.replace(b"22.5 45", b"45 22.5"),  # not ascending
    GOOD.replace(b"\n0 90 180\n", b"\n10 90 180\n"),  # type C must start at 0 or 90
], ids=lambda d: repr(d[:24]))
def test_hostile_files_raise_value_error(data):
    with pytest.raises(ValueError):
        pc.IesProfile(data)


def test_every_truncation_and_random_bytes_fail_cleanly():
    # Each prefix either parses (the numbers happen to be complete) or raises ValueError; a
    # profile that parses gives finite, non-negative values everywhere.
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(64, 3))
    samples = [GOOD[:n] for n in range(len(GOOD))]
    samples += [bytes(rng.integers(0, 256, 200, dtype=np.uint8)) for _ in range(50)]
    samples += [GOOD[:n] + bytes(rng.integers(0, 256, 40, dtype=np.uint8)) for n in range(60, len(GOOD), 7)]
    parsed = 0
    for data in samples:
        try:
            p = pc.IesProfile(data)
        except ValueError:
            continue
        parsed += 1
        vals = [p.eval(tuple(d)) for d in dirs]
        assert np.isfinite(vals).all() and min(vals) >= 0.0 and np.isfinite(p.mean)
    assert parsed >= 1  # (the whole file, at least, up to its END line)


IES_LIGHTS = {  # (name in test_light_hits.LIGHTS, profile): the profile brighter downward / asymmetric
    "point": ies_text([0, 30, 60, 90, 120, 150, 180], [0, 90, 180, 270, 360],
                      [[900, 700, 400, 200, 100, 50, 20], [900, 800, 700, 500, 300, 100, 20],
                       [900, 600, 300, 100, 50, 20, 10], [900, 800, 900, 900, 600, 300, 20],
                       [900, 700, 400, 200, 100, 50, 20]]),
    "rect": ies_text([0, 45, 90], [0, 90, 180, 270, 360],
                     [[500, 500, 500], [500, 1000, 1000], [500, 1500, 1500], [500, 2000, 2000], [500, 500, 500]]),
}


@pytest.mark.parametrize("name", ["point", "spot", "sphere", "rect", "ellipse"])
def test_ies_light_samples_ray_hits_and_mis_render_alike(name):
    """The profile scales light samples and ray hits alike: light samples alone, rays alone and
    MIS give the same image on a rough glossy floor (as test_light_hits' lights without IES)."""
    profile = pc.IesProfile(IES_LIGHTS["rect" if name in ("rect", "ellipse") else "point"])
    imgs = {}
    s = plane_scene(name, ies=profile)
    s.light_hits = False
    imgs["nee"] = renders(s)
    s = plane_scene(name, ies=profile)
    imgs["bsdf"] = renders(s, spp=256, use_nee=False)
    imgs["mis"] = renders(s)
    flat = plane_scene(name)
    flat.light_hits = False
    assert np.abs(renders(flat, seeds=1).mean() - imgs["nee"].mean()) > 0.05 * imgs["nee"].mean()  # it matters
    reg = lambda im: im.reshape(im.shape[0], 4, 4, 4, 4, 3).mean(axis=(2, 4, 5))
    r = {k: reg(v) for k, v in imgs.items()}
    ref = r["nee"].mean(0)
    lit = ref > 0.05 * ref.max()
    se = np.sqrt((r["mis"].var(0, ddof=1) + r["nee"].var(0, ddof=1)) / r["mis"].shape[0]) + 1e-4 * ref.max()
    assert (np.abs(r["mis"].mean(0) - ref) / se)[lit].max() < 5.0
    assert abs(imgs["mis"].mean() / imgs["nee"].mean() - 1) < 0.01
    assert abs(imgs["bsdf"].mean() / imgs["nee"].mean() - 1) < 0.03, (imgs["bsdf"].mean(), imgs["nee"].mean())


def test_ies_frame_follows_the_light():
    # A profile lit only upwards (type C from 90 to 180 degrees, which Cycles keeps so) leaves
    # the floor below a point light dark, and lights it once the light's matrix turns it over.
    profile = pc.IesProfile(ies_text([90, 120, 150, 180], [0], [[400, 600, 800, 1000]]))
    assert profile.eval((0, 0, -1)) == 0.0 and profile.eval((0, 0, 1)) == 0.0  # (180: the end)
    assert profile.eval((0.3, 0, 1)) > 0.0
    flipped = np.eye(4, dtype=np.float32)
    flipped[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
    means = []
    for m in (None, flipped):
        s = pc.Scene()
        pos, tris = quad((-3, -3, 0), (6, 0, 0), (0, 6, 0))
        add_object(s, pos, tris, s.add_material("floor", (0.6,) * 3))
        s.add_point_light(position=(0, 0, 1), intensity=(1, 1, 1), ies=profile, ies_matrix=m)
        s.set_camera(camera(pc, (0.0, -3.5, 2.5), (0.0, 0.0, 0.3)))
        means.append(np.asarray(run_session(pc, s, 16, 16, 4, max_bounces=1).film())[..., :3].mean())
    assert means[0] == 0.0 and means[1] > 0.0
    with pytest.raises(Exception):
        pc.Scene().add_point_light(position=(0, 0, 0), intensity=(1, 1, 1), ies="not a profile")
