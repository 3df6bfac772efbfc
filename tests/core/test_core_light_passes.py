"""Cycles' light-component passes (Diffuse / Glossy / Transmission Direct, Indirect, Color;
Volume Direct, Indirect), Mist and AO of the compiled core: Cycles' identity (the components
times their colours, plus Emit and Env, are Combined) and closed forms."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, cornell, quad, run_session, uv_sphere

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif("DiffDir" not in pc.render_passes(), reason="core without light passes")]

COMPONENTS = ["DiffDir", "DiffInd", "DiffCol", "GlossDir", "GlossInd", "GlossCol",
              "TransDir", "TransInd", "TransCol", "VolumeDir", "VolumeInd"]


def closure(scene, kind, color, roughness=0.0, ior=1.5, transparent=0.0):
    prog = [("const", 0, (*color, 1.0)), ("const", 1, (1 - transparent,) * 3 + (1.0,)),
            ("const", 2, (roughness, 0, 0, 0)), ("const", 3, (ior, 0, 0, 0))]
    params = {"color": 0}
    if kind in ("glossy", "glass"):
        params["roughness"] = 2
    if kind == "glass":
        params["ior"] = 3
    prog.append(("closure", kind, 1, params))
    if transparent:
        prog += [("const", 4, (transparent,) * 3 + (1.0,)), ("const", 5, (1, 1, 1, 1)),
                 ("closure", "transparent", 4, {"color": 5})]
    return scene.add_shader(kind, prog)


def mixed_box():
    """The Cornell box with a rough glossy sphere, a glass sphere and a scattering sphere."""
    s = cornell(pc)
    for kind, color, rough, centre, r in [("glossy", (0.8, 0.6, 0.3), 0.3, (-0.4, 0.3, 0.3), 0.3),
                                          ("glass", (1.0, 1.0, 1.0), 0.0, (0.0, -0.1, 0.9), 0.25)]:
        pos, tris, nrm = uv_sphere(r, center=centre)
        add_object(s, pos, tris, closure(s, kind, color, rough), nrm)
    vol = s.add_shader("fog", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                       volume={"sigma_s": (3.0, 3.0, 3.0), "sigma_a": (0.5, 0.5, 0.5)})
    pos, tris, nrm = uv_sphere(0.25, center=(0.45, -0.2, 1.4))
    add_object(s, pos, tris, vol, nrm)
    return s


def test_pass_table_has_cycles_names():
    table = pc.render_passes()
    for name in COMPONENTS + ["AO"]:
        assert table[name] == 3
    assert table["Mist"] == 1


@pytest.mark.parametrize("general", [False, True])
def test_components_times_colours_plus_emit_and_env_are_combined(general):
    s = mixed_box()
    sess = run_session(pc, s, 32, 32, 16, passes=COMPONENTS + ["Emit", "Env"], threads=2,
                       force_general_kernel=general)
    p = {n: sess.film_pass(n) for n in COMPONENTS + ["Emit", "Env"]}
    total = p["Emit"] + p["Env"] + p["VolumeDir"] + p["VolumeInd"]
    for k in ("Diff", "Gloss", "Trans"):
        total = total + (p[k + "Dir"] + p[k + "Ind"]) * p[k + "Col"]
    combined = sess.film()[..., :3]
    np.testing.assert_allclose(total, combined, atol=2e-5 * max(1.0, combined.max()))
    # Every kind of light is there, so the identity is not met by empty passes.
    for n in ("DiffDir", "DiffInd", "GlossDir", "GlossInd", "TransInd", "VolumeDir", "VolumeInd", "Emit"):
        assert p[n].mean() > 1e-3, n
    # Colours are the closures' albedos: the white walls' diffuse colour is 0.73.
    white = np.all(np.abs(p["DiffCol"] - 0.73) < 1e-4, axis=-1)
    assert white.mean() > 0.3


def test_component_passes_do_not_change_combined():
    s = mixed_box()
    plain = run_session(pc, s, 24, 24, 8, threads=2, passes=["Emit"]).film()
    with_lp = run_session(pc, s, 24, 24, 8, threads=2, passes=["Emit", "DiffDir", "VolumeInd"]).film()
    np.testing.assert_array_equal(plain, with_lp)


def test_direct_diffuse_of_a_sunlit_plane_is_the_irradiance_over_pi():
    # A white-ish diffuse plane under a sun at normal incidence, black world: DiffDir (after the
    # division by the colour) is E / pi, DiffInd is 0, and DiffCol is the albedo.
    s = pc.Scene()
    m = closure(s, "diffuse", (0.5, 0.25, 0.8))
    pos, tris = quad((-10, -10, 0), (20, 0, 0), (0, 20, 0))
    add_object(s, pos, tris, m)
    s.add_sun_light((0.0, 0.0, 1.0), (3.0, 3.0, 3.0))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, -3.0, 4.0), (0.0, 0.0, 0.0)))
    sess = run_session(pc, s, 16, 16, 4, passes=["DiffDir", "DiffInd", "DiffCol"], threads=2)
    np.testing.assert_allclose(sess.film_pass("DiffDir"), 3.0 / np.pi, rtol=1e-4)
    assert np.all(sess.film_pass("DiffInd") == 0.0)
    np.testing.assert_allclose(sess.film_pass("DiffCol"), np.broadcast_to([0.5, 0.25, 0.8], (16, 16, 3)), rtol=1e-5)


def test_mist_follows_the_camera_distance_and_falloff():
    s = pc.Scene()
    pos, tris = quad((-1, 0, -1), (0, 0, 2), (2, 0, 0))  # y = 0, facing the camera
    add_object(s, pos, tris, s.add_material("grey", (0.5, 0.5, 0.5)))
    eye = np.array([0.0, -5.0, 0.0])
    s.set_camera(camera(pc, tuple(eye), (0, 0, 0)))
    for falloff, f in [(1.0, lambda m: m), (2.0, lambda m: m * m), (0.5, np.sqrt)]:
        sess = run_session(pc, s, 24, 16, 1, passes=["Mist", "Position", "Depth"], threads=2,
                           mist_start=2.0, mist_depth=10.0, mist_falloff=falloff, filter_width=1e-4)
        mist = sess.film_pass("Mist")[..., 0]
        hit = sess.film_pass("Depth")[..., 0] < 1e9
        dist = np.linalg.norm(sess.film_pass("Position") - eye, axis=-1)
        assert hit.any() and (~hit).any()
        np.testing.assert_allclose(mist[hit], f(np.clip((dist[hit] - 2.0) / 10.0, 0, 1)), atol=1e-4)
        assert np.all(mist[~hit] == 1.0)  # nothing seen: full mist, as Cycles


def test_ao_is_one_in_the_open_and_zero_in_a_closed_box():
    s = cornell(pc)
    closed = run_session(pc, s, 16, 16, 4, passes=["AO"], threads=2, ao_distance=100.0).film_pass("AO")
    assert np.all(closed == 0.0)
    near = run_session(pc, s, 16, 16, 16, passes=["AO"], threads=2, ao_distance=0.05).film_pass("AO")
    assert 0.8 < near.mean() < 1.0  # only corners and the sphere's contact occlude short rays
    plane = pc.Scene()
    pos, tris = quad((-10, -10, 0), (20, 0, 0), (0, 20, 0))
    add_object(plane, pos, tris, plane.add_material("grey", (0.5, 0.5, 0.5)))
    plane.set_camera(camera(pc, (0.0, -3.0, 2.0), (0.0, 0.0, 0.0)))
    ao = run_session(pc, plane, 16, 16, 4, passes=["AO"], threads=2, ao_distance=100.0).film_pass("AO")
    hit = ao[..., 0] > 0
    assert hit.mean() > 0.3 and np.all(ao[hit] == 1.0)


def test_object_and_material_index_of_the_first_sample():
    # Two quads side by side (pass indices 3 and 7, materials 2 and 5) on a black world: each
    # pixel keeps the indices of its first sample, not a mean over its samples (Cycles' ids).
    s = pc.Scene()
    ids = []
    for x0, obj_index, mat_index in [(-1.0, 3, 2), (0.0, 7, 5)]:
        m = s.add_material(f"m{mat_index}", (0.5, 0.5, 0.5))
        s.set_material_pass_index(m, mat_index)
        pos, tris = quad((x0, 0, -1), (0, 0, 2), (1, 0, 0))
        mesh = s.add_mesh(pos, tris, None, None, [m])
        s.add_instance(mesh, np.eye(4, dtype=np.float32), pass_index=obj_index)
        ids.append((obj_index, mat_index))
    s.set_camera(camera(pc, (0.0, -5.0, 0.0), (0, 0, 0)))
    sess = run_session(pc, s, 32, 16, 8, passes=["IndexOB", "IndexMA"], threads=2)
    ob, ma = sess.film_pass("IndexOB")[..., 0], sess.film_pass("IndexMA")[..., 0]
    x = np.broadcast_to((np.arange(32) + 0.5 - 16) * (5.0 * 36.0 / 50.0 / 32), (16, 32))  # pixel centres
    assert set(np.unique(ob)) == {0.0, 3.0, 7.0}  # no averages at the shared edge
    left, right = ob == 3.0, ob == 7.0
    assert left.sum() > 50 and right.sum() > 50
    assert np.all(ma[left] == 2.0) and np.all(ma[right] == 5.0) and np.all(ma[ob == 0.0] == 0.0)
    inner = (np.abs(x) > 0.15) & (np.abs(x) < 0.85)  # away from edges, where the first sample may miss
    assert np.all(ob[inner & (x < 0)] == 3.0) and np.all(ob[inner & (x > 0)] == 7.0)


def test_bad_mist_and_ao_settings_raise_and_infinite_ao_is_unbounded():
    for name, value in [("mist_depth", -1.0), ("mist_falloff", 0.0), ("mist_start", float("nan")),
                        ("ao_distance", float("nan")), ("ao_distance", -2.0)]:
        bad = pc.RenderSettings()
        bad.width = bad.height = 8
        setattr(bad, name, value)
        with pytest.raises(ValueError):
            pc.Session(committed_cornell(), bad)
    ao = run_session(pc, cornell(pc), 8, 8, 2, passes=["AO"], threads=2, ao_distance=float("inf")).film_pass("AO")
    assert np.all(ao == 0.0)  # the closed box occludes every ray


def committed_cornell():
    s = cornell(pc)
    s.commit()
    return s
