"""Render passes, transparent film, exposure and the BVH debug view of the compiled core
(issue 5), checked against values known in closed form."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, render, run_session, uv_sphere

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif(not hasattr(pc.RenderSettings(), "passes"), reason="core without render passes")]

EYE = (0.0, -5.0, 0.0)  # cameras look along +y from here at the plane y = 0
ALL = ["Depth", "Normal", "Position", "Emit", "Env", "Denoising Normal", "Denoising Albedo", "Sample Count"]


def const(reg, rgb):
    return ("const", reg, (rgb[0], rgb[1], rgb[2], 1.0))


def shader(scene, kind, color, roughness=0.0, ior=1.5, mix_transparent=None):
    """A material of one closure (weight 1) with a constant colour; mix_transparent=w adds a
    white Transparent BSDF of weight w and scales the closure by 1 - w (a Mix Shader)."""
    w = 1.0 if mix_transparent is None else 1.0 - mix_transparent
    prog = [const(0, color), const(1, (w, w, w)), ("const", 2, (roughness, 0, 0, 0)), ("const", 3, (ior, 0, 0, 0))]
    params = {"color": 0}
    if kind in ("glossy", "glass", "refraction"):
        params["roughness"] = 2
    if kind in ("glass", "refraction"):
        params["ior"] = 3
    prog.append(("closure", kind, 1, params))
    if mix_transparent is not None:
        t = mix_transparent
        prog += [const(4, (t, t, t)), const(5, (1, 1, 1)), ("closure", "transparent", 4, {"color": 5})]
    return scene.add_shader(kind, prog)


def wall(scene, mat, y=0.0, half=3.0, facing=-1.0):
    """A square in the plane y = const, centred on the view axis, normal (0, facing, 0)."""
    pos, tris = quad((-half, y, -half), (0, 0, 2 * half), (2 * half, 0, 0))  # normal -y
    if facing > 0:
        tris = tris[:, ::-1].copy()
    add_object(scene, pos, tris, mat)


def session(scene, width=24, height=16, samples=4, **kw):
    return run_session(pc, scene, width, height, samples, **{"threads": 2, **kw})


def test_pass_table_names_and_channels():
    table = pc.render_passes()
    # Blender's / Cycles' names, so that compositor sockets and EXR layers line up.
    for name, ch in [("Depth", 1), ("Normal", 3), ("Position", 3), ("Emit", 3), ("Env", 3),
                     ("Denoising Normal", 3), ("Denoising Albedo", 3), ("Sample Count", 1),
                     ("BVH Nodes", 1), ("BVH Triangles", 1)]:
        assert table[name] == ch
    st = pc.RenderSettings()
    st.passes = ["Normal", "Depth"]
    assert set(st.passes) == {"Normal", "Depth"}
    with pytest.raises(ValueError, match="unknown render pass"):
        st.passes = ["Z"]


def test_depth_normal_position_of_a_plane_exactly():
    s = pc.Scene()
    wall(s, s.add_material("grey", (0.5, 0.5, 0.5)), half=10.0)
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    sess = session(s, samples=3, passes=ALL)
    depth = sess.film_pass("Depth")
    assert depth.shape == (16, 24, 1) and depth.dtype == np.float32
    # Cycles' Z: distance along the view axis, the same for every pixel of a facing plane.
    np.testing.assert_allclose(depth, 5.0, rtol=1e-5)
    np.testing.assert_allclose(sess.film_pass("Normal"), np.broadcast_to([0, -1, 0], (16, 24, 3)), atol=1e-6)
    pos = sess.film_pass("Position")
    np.testing.assert_allclose(pos[..., 1], 0.0, atol=1e-5)
    # Rows bottom-up, columns left to right: x grows to the right, z upwards.
    assert np.all(np.diff(pos[..., 0], axis=1) > 0) and np.all(np.diff(pos[..., 2], axis=0) > 0)
    assert np.all(sess.film_pass("Sample Count") == 3)


def test_depth_is_the_view_axis_distance_off_axis_and_1e10_on_misses():
    s = pc.Scene()
    # A plane tilted about z: its view depth varies across the image as y of the hit point.
    pos, tris = quad((-1.0, -0.5, -1.0), (0, 0, 2.0), (2.0, 1.0, 0))
    add_object(s, pos, tris, s.add_material("grey", (0.5, 0.5, 0.5)))
    s.set_camera(camera(pc, EYE, (0, 0, 0), lens=25.0))
    sess = session(s, samples=1, passes=["Depth", "Position"])
    depth, p = sess.film_pass("Depth")[..., 0], sess.film_pass("Position")
    hit = depth < 1e9
    assert hit.any() and (~hit).any()
    np.testing.assert_array_equal(depth[~hit], 1e10)
    np.testing.assert_allclose(depth[hit], p[..., 1][hit] - EYE[1], rtol=1e-5)


def test_normal_faces_the_camera_on_back_faces():
    s = pc.Scene()
    wall(s, s.add_material("grey", (0.5, 0.5, 0.5)), half=10.0, facing=+1.0)  # seen from behind
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    sess = session(s, samples=1, passes=["Normal", "Denoising Normal"])
    np.testing.assert_allclose(sess.film_pass("Normal"), np.broadcast_to([0, -1, 0], (16, 24, 3)), atol=1e-6)
    # Camera space as Cycles: facing the camera is -Z.
    np.testing.assert_allclose(sess.film_pass("Denoising Normal"), np.broadcast_to([0, 0, -1], (16, 24, 3)),
                               atol=1e-6)


@pytest.mark.parametrize("front", ["none", "mirror", "refraction", "transparent", "rough_glossy"])
def test_denoising_albedo_follows_specular_surfaces(front):
    """The albedo of a diffuse wall of colour c, seen directly or through a perfectly specular
    surface of colour g (Cycles: the rough surface's albedo times the specular albedo)."""
    c, g = (0.2, 0.5, 0.8), (0.9, 0.6, 0.3)
    s = pc.Scene()
    diffuse = s.add_material("wall", c)
    if front == "mirror":
        # A mirror facing the camera, tilted 45 degrees about x: it shows the floor z = -4.
        pos, tris = quad((-20, -2, 2), (40, 0, 0), (0, 4, -4))
        add_object(s, pos, tris, shader(s, "glossy", g))
        pos, tris = quad((-20, -20, -4), (40, 0, 0), (0, 40, 0))
        add_object(s, pos, tris, diffuse)
    else:
        wall(s, diffuse, half=20.0)
        if front == "refraction":
            wall(s, shader(s, "refraction", g, ior=1.5), y=-1.0, half=20.0)
        elif front == "transparent":
            wall(s, shader(s, "transparent", g), y=-1.0, half=20.0)
        elif front == "rough_glossy":
            wall(s, shader(s, "glossy", g, roughness=0.5), y=-1.0, half=20.0)
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    albedo = session(s, samples=2, passes=["Denoising Albedo"]).film_pass("Denoising Albedo")
    expected = {"none": c, "mirror": np.multiply(c, g), "refraction": np.multiply(c, g),
                "transparent": np.multiply(c, g), "rough_glossy": g}[front]
    np.testing.assert_allclose(albedo, np.broadcast_to(expected, albedo.shape), rtol=1e-5, atol=1e-6)


def test_data_passes_skip_mostly_transparent_surfaces():
    s = pc.Scene()
    wall(s, s.add_material("grey", (0.5, 0.5, 0.5)), half=10.0)
    wall(s, shader(s, "transparent", (0.8, 0.8, 0.8)), y=-2.0, half=10.0)  # 80 % transparent
    wall(s, shader(s, "diffuse", (1, 1, 1), mix_transparent=0.3), y=-3.0, half=1.0)   # 30 %: opaque enough
    s.set_camera(camera(pc, EYE, (0, 0, 0), lens=25.0))
    depth = session(s, samples=1, passes=["Depth"]).film_pass("Depth")[..., 0]
    assert set(np.unique(np.round(depth, 4))) == {2.0, 5.0}
    assert depth[8, 12] == pytest.approx(2.0) and depth[1, 1] == pytest.approx(5.0)


def test_emit_env_and_exposure():
    e, w = (3.0, 2.0, 1.0), (0.25, 0.5, 0.75)
    s = pc.Scene()
    wall(s, s.add_material("lamp", (0, 0, 0), e), half=0.5)
    s.set_world_color(w)
    s.set_camera(camera(pc, EYE, (0, 0, 0), lens=25.0))
    sess = session(s, samples=1, passes=["Emit", "Env", "Depth"], use_nee=False)
    hit = sess.film_pass("Depth")[..., 0] < 1e9
    assert hit.any() and (~hit).any()
    emit, env = sess.film_pass("Emit"), sess.film_pass("Env")
    np.testing.assert_allclose(emit[hit], np.broadcast_to(e, emit[hit].shape), rtol=1e-6)
    np.testing.assert_array_equal(emit[~hit], 0.0)
    np.testing.assert_allclose(env[~hit], np.broadcast_to(w, env[~hit].shape), rtol=1e-6)
    np.testing.assert_array_equal(env[hit], 0.0)
    film = sess.film()
    np.testing.assert_allclose(film[..., :3], emit + env, rtol=1e-6)

    # Exposure: a linear multiplier of Combined and the light passes, not of data passes.
    sess2 = session(s, samples=1, passes=["Emit", "Env", "Depth"], use_nee=False, exposure=2.5)
    np.testing.assert_allclose(sess2.film()[..., :3], 2.5 * film[..., :3], rtol=1e-6)
    np.testing.assert_allclose(sess2.film()[..., 3], film[..., 3])
    np.testing.assert_allclose(sess2.film_pass("Emit"), 2.5 * emit, rtol=1e-6)
    np.testing.assert_array_equal(sess2.film_pass("Depth"), sess.film_pass("Depth"))
    with pytest.raises(ValueError, match="exposure"):
        session(s, exposure=float("nan"))


def test_passes_do_not_change_the_image():
    s = pc.Scene()
    wall(s, s.add_material("grey", (0.5, 0.5, 0.5)), half=2.0)
    pos, tris, nrm = uv_sphere(0.7, center=(0.0, -1.0, 0.0))
    add_object(s, pos, tris, shader(s, "glass", (1, 1, 1), roughness=0.1), nrm)
    s.set_world_color((0.8, 0.9, 1.0))
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    plain = session(s, samples=4).film()
    with_passes = session(s, samples=4, passes=ALL).film()
    np.testing.assert_array_equal(plain, with_passes)


def test_unrequested_pass_is_a_clear_error():
    s = pc.Scene()
    wall(s, s.add_material("grey", (0.5, 0.5, 0.5)))
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    sess = session(s, samples=1, passes=["Depth"])
    with pytest.raises(ValueError, match="not requested"):
        sess.film_pass("Normal")
    with pytest.raises(ValueError, match="unknown render pass"):
        sess.film_pass("Nope")
    assert np.all(sess.film_pass("Sample Count") == 1)  # always available: the film counts samples


def test_sample_count_with_adaptive_sampling():
    s = pc.Scene()
    wall(s, s.add_material("grey", (0.5, 0.5, 0.5)), half=10.0)
    pos, tris, nrm = uv_sphere(0.6, center=(0.0, -1.0, 0.0))
    add_object(s, pos, tris, s.add_material("lamp", (0.5, 0.5, 0.5), (4.0, 4.0, 4.0)), nrm)
    s.set_world_color((0.3, 0.3, 0.3))
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    sess = session(s, width=32, height=32, samples=128, passes=["Sample Count"], adaptive_threshold=0.05,
                   adaptive_min_samples=16)
    counts = sess.film_pass("Sample Count")[..., 0]
    np.testing.assert_array_equal(counts, sess.sample_counts())
    assert counts.min() >= 16 and counts.max() <= 128 and counts.min() < counts.max()


def test_transparent_film_alpha():
    s = pc.Scene()
    # Left: an opaque diffuse square; right: one that is 40 % Transparent BSDF; around: the world.
    pos, tris = quad((-2.0, 0.0, -1.0), (0, 0, 2.0), (1.8, 0, 0))
    add_object(s, pos, tris, s.add_material("grey", (0.5, 0.5, 0.5)))
    pos, tris = quad((0.2, 0.0, -1.0), (0, 0, 2.0), (1.8, 0, 0))
    add_object(s, pos, tris, shader(s, "diffuse", (0.5, 0.5, 0.5), mix_transparent=0.4))
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, EYE, (0, 0, 0), lens=35.0))
    sess = session(s, width=48, height=24, samples=64, passes=["Depth", "Env"], film_transparent=True)
    film, depth = sess.film(), sess.film_pass("Depth")[..., 0]
    world = depth >= 1e9
    assert world.any()
    np.testing.assert_array_equal(film[world], 0.0)       # neither colour nor alpha
    assert np.all(sess.film_pass("Env")[world] == 1.0)    # the Env pass still shows the world
    left = film[6:18, 6:18]
    np.testing.assert_array_equal(left[..., 3], 1.0)
    assert left[..., :3].mean() > 0.1                     # the world still lights the scene
    right = film[6:18, 30:42, 3]
    assert right.mean() == pytest.approx(0.6, abs=0.03)   # alpha = 1 - transparent weight
    assert right.min() < 1.0

    opaque = session(s, width=48, height=24, samples=4).film()
    np.testing.assert_array_equal(opaque[..., 3], 1.0)    # without transparent film: alpha 1
    assert np.all(opaque[world][:, :3] == 1.0)


def bvh_scene():
    s = pc.Scene()
    grey = s.add_material("grey", (0.5, 0.5, 0.5))
    # A dense cluster of small spheres on the left, one big quad on the right, nothing at the top.
    for i in range(4):
        for j in range(4):
            pos, tris, nrm = uv_sphere(0.15, nu=16, nv=8, center=(-1.5 + 0.3 * i, 0.3 * j, -1.0 + 0.3 * j))
            add_object(s, pos, tris, grey, nrm)
    pos, tris = quad((0.5, 0.0, -1.5), (0, 0, 1.5), (1.5, 0, 0))
    add_object(s, pos, tris, grey)
    s.set_camera(camera(pc, EYE, (0, 0, 0), lens=30.0))
    return s


def test_bvh_view_counts_match_traversal_of_the_same_rays():
    s = bvh_scene()
    w, h = 40, 30
    sess = session(s, width=w, height=h, samples=16, debug_view="bvh")
    assert sess.progress()["samples_total"] == 1  # one ray per pixel centre
    nodes, tris = sess.film_pass("BVH Nodes")[..., 0], sess.film_pass("BVH Triangles")[..., 0]
    ys, xs = np.mgrid[0:h, 0:w]
    xy = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1).astype(np.float32)
    o, d, tmax = s.camera_rays(w, h, xy)
    n_ref, t_ref = s.traversal_counts(o, d, tmax)
    np.testing.assert_array_equal(nodes.ravel(), n_ref)
    np.testing.assert_array_equal(tris.ravel(), t_ref)

    t, prim, _, _ = s.intersect(o, d)
    hit = (prim >= 0).reshape(h, w)
    assert hit.any() and (~hit).any()
    assert np.all(nodes[hit] > 0) and np.all(tris[hit] > 0)
    assert np.all(tris[h - 3:, :] == 0)  # the top rows look past the whole scene
    # Rays into the sphere cluster do more work than rays onto the lone quad.
    cluster = hit & (xs < w // 2)
    lone = hit & (xs > 3 * w // 4)
    assert cluster.any() and lone.any()
    assert nodes[cluster].mean() > 1.5 * nodes[lone].mean()
    assert tris[cluster].mean() > tris[lone].mean()
