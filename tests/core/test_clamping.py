"""Clamping (RenderSettings.clamp_direct, clamp_indirect; Cycles' Light Paths > Clamping, its
film_clamp_light): each contribution to the film whose |r| + |g| + |b| exceeds 3 x the limit
is scaled down to it (Cycles' Integrator multiplies the settings by 3: grey light is clamped
to the setting per channel). Direct: light that arrives at the camera's first scattering vertex (its
light samples, what its BSDF ray finds) or that the camera sees; indirect: after more
scatterings (volume scatterings count, transparent crossings do not; caustic light paths and
light-vertex connections always). Off (0) by default; limits no contribution reaches leave the
render bit for bit as it was. Clamping changes no random number, so a clamped render takes the
same paths as the unclamped one: the tests compare the two exactly."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, cornell, quad, run_session
from test_caustic_connections import shaded_scene
from test_caustic_light_paths import mirror_scene
from test_core_hetero_volumes import linear_program, medium_scene
from test_core_light_passes import COMPONENTS, mixed_box
from test_core_volumes import volume_sphere
from test_light_linking import ALL, mirror_room

pc = core()
TINY = 1e-6
# A path's contributions: at most a few per vertex (light sample, emission, lights crossed,
# a connection), 13 vertices at the default 12 bounces; each clamped one is at most 3 TINY per
# channel. The images below are means of such sums.
BOUND = 100 * 3 * TINY


def render(scene, w=24, h=24, samples=8, **kw):
    return run_session(pc, scene, w, h, samples, threads=2, seed=5, **kw)


def rgb(sess):
    return np.asarray(sess.film())[..., :3].astype(np.float64)


def emitter_wall(radiance):
    """An emitter of the given radiance (black otherwise) filling the view, under a black world."""
    s = pc.Scene()
    lamp = s.add_material("lamp", (0.0, 0.0, 0.0), radiance)
    add_object(s, *quad((-5, 2, -5), (10, 0, 0), (0, 0, 10)), lamp)  # y = 2, facing the camera
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, -3.0, 0.0), (0.0, 0.0, 0.0)))
    s.commit()
    return s


@pytest.mark.sanitize
def test_an_emitter_seen_directly_is_clamped_by_the_direct_limit_exactly():
    s = emitter_wall((5.0, 5.0, 5.0))
    assert np.all(rgb(render(s, 8, 8, 2)) == 5.0)
    # |r| + |g| + |b| = 15 scaled down to 3 x 1: (1, 1, 1); to 3 x 3: (3, 3, 3)
    assert np.all(rgb(render(s, 8, 8, 2, clamp_direct=1.0)) == 1.0)
    assert np.all(rgb(render(s, 8, 8, 2, clamp_direct=3.0)) == 3.0)
    # The camera's own light is direct: the indirect limit leaves it.
    assert np.all(rgb(render(s, 8, 8, 2, clamp_indirect=1.0)) == 5.0)
    assert np.all(rgb(render(s, 8, 8, 2, clamp_direct=5.0)) == 5.0)  # (at the limit: kept)
    # The sum of the channels, not the largest: (6, 3, 3) at 3 x 2 is halved.
    img = rgb(render(emitter_wall((6.0, 3.0, 3.0)), 8, 8, 2, clamp_direct=2.0))
    assert np.all(img == np.array([3.0, 1.5, 1.5]))


def test_a_tiny_indirect_limit_leaves_what_the_first_vertex_finds():
    # Without light samples the camera's first vertex gets its direct light by its BSDF ray
    # alone, with the same numbers whatever the bounces after it: max_bounces 0 (Pathlight's
    # and Cycles' "direct light only") is the render whose indirect contributions are all 0.
    s = cornell(pc)
    kw = dict(samples=8, use_nee=False)
    direct = rgb(render(s, max_bounces=0, **kw))
    full = rgb(render(s, **kw))
    clamped = rgb(render(s, clamp_indirect=TINY, **kw))
    assert (full - direct).mean() > 0.05  # (the box's indirect light is there to clamp)
    assert np.all(np.abs(clamped - direct) <= 13 * 3 * TINY + 1e-6 * direct)
    assert np.all(clamped >= direct - 1e-6 * direct)


def direct_part(sess):
    """Cycles' direct light of a render with the light passes: what the camera sees (Emit, Env)
    and the Direct components times their colours."""
    p = {n: np.asarray(sess.film_pass(n), np.float64) for n in COMPONENTS + ["Emit", "Env"]}
    total = p["Emit"] + p["Env"] + p["VolumeDir"]
    for k in ("Diff", "Gloss", "Trans"):
        total = total + p[k + "Dir"] * p[k + "Col"]
    return total, p


@pytest.mark.parametrize("general", [False, True])
def test_a_tiny_indirect_limit_leaves_the_direct_passes(general):
    # With light samples (MIS between them and the BSDF rays), through glossy, glass and a
    # scattering volume: the clamped render is the unclamped one's direct light (its passes,
    # which split direct from indirect as the clamp does), its indirect passes ~0.
    s = mixed_box()
    kw = dict(samples=8, passes=COMPONENTS + ["Emit", "Env"], force_general_kernel=general)
    full = render(s, **kw)
    clamped = render(s, clamp_indirect=TINY, **kw)
    direct, p = direct_part(full)
    combined = rgb(clamped)
    tol = 2e-5 * max(1.0, combined.max())  # (the passes' sum, as test_core_light_passes)
    assert (rgb(full) - direct).mean() > 0.02  # indirect light to clamp
    np.testing.assert_allclose(combined, direct, atol=tol + BOUND)
    _, q = direct_part(clamped)
    for k in ("Diff", "Gloss", "Trans"):
        assert np.all(q[k + "Ind"] * q[k + "Col"] <= BOUND), k
        np.testing.assert_array_equal(q[k + "Dir"], p[k + "Dir"])
    assert np.all(q["VolumeInd"] <= BOUND)
    np.testing.assert_array_equal(q["VolumeDir"], p["VolumeDir"])
    assert p["VolumeInd"].max() > 1e-3 and p["TransInd"].max() > 1e-3


def test_a_tiny_indirect_limit_converges_to_direct_light_only():
    # With light samples the two estimate the same direct light differently (the last vertex
    # of max_bounces 0 gives its light samples the whole weight): equal within noise.
    s = cornell(pc)
    clamped = rgb(render(s, 32, 32, 64, clamp_indirect=TINY))
    direct = rgb(render(s, 32, 32, 64, max_bounces=0))
    # Measured: means 1.0003, worst 4 x 4 region 0.05 % apart (the box's lamp is a mesh light,
    # the two estimators' noise nearly the same).
    assert abs(clamped.mean() / direct.mean() - 1.0) < 0.005
    reg = lambda im: im.reshape(4, 8, 4, 8, 3).mean(axis=(1, 3))  # noqa: E731
    a, b = reg(clamped), reg(direct)
    assert np.all(np.abs(a - b) <= 0.02 * np.maximum(b, 0.1 * b.mean()))


# Scenes of every kind of contribution: surfaces (the Cornell box), glossy, glass and a
# homogeneous volume (mixed box), an emitting heterogeneous medium (delta tracking's emission,
# its segment light samples and light hits), an emitting homogeneous one, shadow-linked lamps
# (dedicated rays), a shadow catcher, caustic light paths (splats) and light-vertex connections.
SCENES = {
    "cornell": (lambda: cornell(pc), {}),
    "mixed box": (mixed_box, {}),
    "heterogeneous": (lambda: medium_scene(linear_program(emission=(0.5, 0.4, 0.3)))[0], {}),
    "homogeneous": (lambda: volume_sphere({"sigma_s": (1.0, 1.0, 1.0), "sigma_a": (0.2, 0.2, 0.2),
                                           "emission": (0.3, 0.3, 0.3)}), {}),
    "shadow linked": (lambda: mirror_room(ALL & ~(1 << 5)), dict(max_bounces=3)),
    "caustic paths": (mirror_scene, dict(caustic_light_paths=1.0)),
    "connections": (shaded_scene, dict(caustic_light_paths=0.5, caustic_connections=2)),
}


@pytest.mark.parametrize("name", list(SCENES))
def test_tiny_limits_leave_almost_nothing(name):
    make, kw = SCENES[name]
    s = make()
    full = render(s, **kw)
    clamped = render(s, clamp_direct=TINY, clamp_indirect=TINY, **kw)
    assert rgb(full).mean() > 1e-3
    assert rgb(clamped).max() <= BOUND, rgb(clamped).max()


@pytest.mark.parametrize("name", list(SCENES))
def test_limits_no_contribution_reaches_change_nothing(name):
    make, kw = SCENES[name]
    s = make()
    a = render(s, **kw)
    b = render(s, clamp_direct=1e30, clamp_indirect=1e30, **kw)
    np.testing.assert_array_equal(np.asarray(a.film()), np.asarray(b.film()))


def test_shadow_catcher_pass_is_clamped_too():
    from test_core_shadow_catcher import scene as catcher_scene
    s = catcher_scene()
    full = render(s, passes=["Shadow Catcher"])
    clamped = render(s, clamp_direct=TINY, clamp_indirect=TINY, passes=["Shadow Catcher"])
    assert np.asarray(full.film_pass("Shadow Catcher"))[..., :3].max() > 0.1
    assert rgb(clamped).max() <= BOUND


def test_light_passes_still_sum_to_combined():
    s = mixed_box()
    kw = dict(samples=8, passes=COMPONENTS + ["Emit", "Env"])
    full = render(s, **kw)
    clamped = render(s, clamp_direct=2.0, clamp_indirect=0.2, **kw)
    total, p = direct_part(clamped)
    for k in ("Diff", "Gloss", "Trans"):
        total = total + p[k + "Ind"] * p[k + "Col"]
    total = total + p["VolumeInd"]
    combined = rgb(clamped)
    np.testing.assert_allclose(total, combined, atol=2e-5 * max(1.0, combined.max()))
    # The lamp seen directly (12, 10.2, 7.2) is clamped to a sum of 3 x 2 in Combined and Emit alike.
    emit = p["Emit"].sum(axis=-1)
    assert emit.max() <= 6.0 * (1 + 1e-6) and rgb(full).max() > 10.0
    assert combined.mean() < 0.9 * rgb(full).mean()


@pytest.mark.parametrize("name", ["caustic paths", "connections"])
def test_light_paths_are_clamped_as_indirect_light(name):
    # The direct light (unclamped) is the same with light paths and without; their splats and
    # connections carry light that arrived after a scattering past the camera's first vertex,
    # so a tiny indirect limit leaves both images at it (unclamped, the caustics differ by
    # their noise).
    make, kw = SCENES[name]
    s = make()
    plain = rgb(render(s, clamp_indirect=TINY))
    lt = rgb(render(s, clamp_indirect=TINY, **kw))
    assert np.all(np.abs(lt - plain) <= BOUND + 1e-5 * plain), np.abs(lt - plain).max()
    assert np.abs(rgb(render(s, **kw)) - rgb(render(s))).max() > 0.01


def test_bad_limits_are_off_with_a_warning():
    st = pc.RenderSettings()
    assert st.clamp_direct == 0.0 and st.clamp_indirect == 0.0  # off by default
    for bad in (-1.0, float("nan"), float("inf"), float("-inf")):
        with pytest.warns(UserWarning, match="clamp_indirect"):
            st.clamp_indirect = bad
        assert st.clamp_indirect == 0.0
        with pytest.warns(UserWarning, match="clamp_direct"):
            st.clamp_direct = bad
        assert st.clamp_direct == 0.0
    st.clamp_direct, st.clamp_indirect = 2.5, 0.0
    assert (st.clamp_direct, st.clamp_indirect) == (2.5, 0.0)
