"""The UV and Vector passes of the compiled core, against closed forms: a plane's UV map
read back through its Position pass, and motion vectors of a translated plane and a moved
camera in raster pixels (Cycles' layout: (previous - here).xy, (here - next).xy)."""
import numpy as np
import pytest

from core_scenes import camera, core, look_at_matrix, quad, run_session

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif("UV" not in pc.render_passes(), reason="core without the UV pass")]

EYE = (0.0, -5.0, 0.0)
W, H = 24, 16
PPU = W / (2 * 5.0 * 18.0 / 50.0)  # raster pixels per unit on the plane y = 0 (50 mm, 36 mm sensor)


def translation(x=0.0, y=0.0, z=0.0):
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = (x, y, z)
    return m


def plane(scene, half, uvs=True, **instance):
    """A square of side 2*half in y = 0 facing the camera; uv (0, 0) at (-half, -half), U along
    +z and V along +x."""
    pos, tris = quad((-half, 0.0, -half), (0, 0, 2 * half), (2 * half, 0, 0))
    corner_uv = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], np.float32)
    mat = scene.add_material("grey", (0.5, 0.5, 0.5))
    extra = {"uvs": {0: np.ascontiguousarray(corner_uv[tris])}} if uvs else {}
    mesh = scene.add_mesh(pos, tris, None, None, [mat], **extra)
    scene.add_instance(mesh, np.eye(4, dtype=np.float32), **instance)


def session(scene, passes, samples=2, **kw):
    return run_session(pc, scene, W, H, samples, passes=passes, threads=2, **kw)


def test_uv_pass_is_the_interpolated_uv_map_with_alpha_one():
    s = pc.Scene()
    plane(s, 10.0)
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    sess = session(s, ["UV", "Position"], uv_pass_set=0)
    uv, pos = sess.film_pass("UV"), sess.film_pass("Position")
    assert uv.shape == (H, W, 3)
    # Linear in the hit point: the mean uv is the uv of the mean position.
    np.testing.assert_allclose(uv[..., 0], (pos[..., 2] + 10.0) / 20.0, atol=2e-5)
    np.testing.assert_allclose(uv[..., 1], (pos[..., 0] + 10.0) / 20.0, atol=2e-5)
    np.testing.assert_array_equal(uv[..., 2], 1.0)
    # Without the set (or another set than the mesh has): 0, alpha too, as Cycles.
    for k in (-1, 3):
        assert not session(s, ["UV"], samples=1, uv_pass_set=k).film_pass("UV").any()


def test_uv_pass_of_a_mesh_without_uv_map_and_of_misses_is_zero():
    s = pc.Scene()
    plane(s, 0.5, uvs=False)
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    assert not session(s, ["UV"], uv_pass_set=0).film_pass("UV").any()
    s = pc.Scene()
    plane(s, 0.5)
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    uv = session(s, ["UV"], samples=4, uv_pass_set=0).film_pass("UV")
    assert uv[0, 0].tolist() == [0.0, 0.0, 0.0]  # the corner sees the world
    assert uv[H // 2, W // 2, 2] == 1.0


def test_vector_pass_of_a_moving_plane_and_a_moving_camera_in_pixels():
    s = pc.Scene()
    # Was 0.5 to the left at the previous frame, will be 0.5 to the right at the next one.
    plane(s, 10.0, pass_motion=np.stack([translation(x=-0.5), translation(x=0.5)]))
    cam = camera(pc, EYE, (0, 0, 0))
    still = look_at_matrix(EYE, (0, 0, 0))
    moved = np.array(still, np.float32)
    moved[2, 3] += 0.3  # the camera rises by 0.3 at the next frame
    cam.pass_motion = np.stack([still, moved]).astype(np.float32)
    s.set_camera(cam)
    sess = session(s, ["Vector"])
    v = sess.film_pass("Vector")
    assert v.shape == (H, W, 4)
    expected = np.array([-0.5 * PPU, 0.0, -0.5 * PPU, 0.3 * PPU], np.float32)
    np.testing.assert_allclose(v.reshape(-1, 4), np.broadcast_to(expected, (H * W, 4)), atol=2e-3)


def test_vector_pass_averages_over_hits_only_and_still_scenes_read_zero():
    s = pc.Scene()
    plane(s, 1.0, pass_motion=np.stack([translation(z=0.2), translation(z=0.2)]))
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    v = session(s, ["Vector"], samples=8).film_pass("Vector")
    inside = v[H // 2, W // 2]
    np.testing.assert_allclose(inside, [0.0, 0.2 * PPU, 0.0, -0.2 * PPU], atol=2e-3)
    assert not v[0, 0].any()  # the world: no motion (weight 0)
    # A pixel on the plane's edge: some samples miss, the hits' vector stays whole.
    edge = v[H // 2, int(W / 2 + 1.0 * PPU)]
    assert abs(edge[1] - 0.2 * PPU) < 2e-3 or not edge.any()
    s = pc.Scene()
    plane(s, 1.0)
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    assert not session(s, ["Vector"], samples=1).film_pass("Vector").any()


def test_vector_pass_follows_a_deforming_mesh():
    s = pc.Scene()
    pos, tris = quad((-10.0, 0.0, -10.0), (0, 0, 20.0), (20.0, 0, 0))
    mesh = s.add_mesh(pos, tris, None, None, [s.add_material("grey", (0.5, 0.5, 0.5))])
    # Every vertex 0.25 lower at the previous frame and 0.25 higher at the next: the pixels
    # move up by 0.25 units per frame.
    assert s.set_mesh_pass_motion(mesh, np.stack([pos - [0, 0, 0.25], pos + [0, 0, 0.25]]).astype(np.float32))
    assert not s.set_mesh_pass_motion(mesh, np.zeros((2, 3, 3), np.float32))  # wrong length: refused
    assert s.set_mesh_pass_motion(mesh, np.stack([pos - [0, 0, 0.25], pos + [0, 0, 0.25]]).astype(np.float32))
    s.add_instance(mesh, np.eye(4, dtype=np.float32))
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    v = session(s, ["Vector"]).film_pass("Vector")
    np.testing.assert_allclose(v[..., 1], -0.25 * PPU, atol=2e-3)
    np.testing.assert_allclose(v[..., 3], -0.25 * PPU, atol=2e-3)
    np.testing.assert_allclose(v[..., [0, 2]], 0.0, atol=2e-3)


def test_vector_pass_follows_deforming_strands_and_points():
    """Strands and points whose keys move between frames (pass_points): a strand's hit moves
    as the point between its segment's two keys at the hit's parameter (Cycles' motion keys),
    a point's as its centre. Orthographic, so the vectors do not depend on depth."""
    scale = 8.0
    ppu = W / scale  # pixels per unit across
    s = pc.Scene()
    mat = s.add_material("grey", (0.5, 0.5, 0.5))
    # One straight poly strand along x at z = 0.2 from x = -4 to 4 (a single segment), radius 0.5:
    # at the previous frame its root was 0.1 lower and its tip 0.9 lower, at the next as much higher.
    keys = np.array([(-4.0, 0.0, 0.2), (4.0, 0.0, 0.2)], np.float32)
    lift = np.array([(0, 0, 0.1), (0, 0, 0.9)], np.float32)
    s.add_curves(keys, np.array([0, 2]), np.full(2, 0.5, np.float32), mat, curve_type="poly",
                 pass_points=np.stack([keys - lift, keys + lift]))
    # A sphere of radius 1 at z = -2.5 that was 0.4 to its left and will be 0.4 to its right.
    centre = np.array([(0.0, 0.0, -2.5)], np.float32)
    s.add_points(centre, np.ones(1, np.float32), mat,
                 pass_points=np.stack([centre - [0.4, 0, 0], centre + [0.4, 0, 0]]).astype(np.float32))
    with pytest.raises(ValueError, match="pass_points"):
        s.add_points(centre, np.ones(1, np.float32), mat, pass_points=np.zeros((2, 2, 3), np.float32))
    cam = camera(pc, EYE, (0, 0, 0))
    cam.type = "ORTHO"
    cam.ortho_scale = scale
    s.set_camera(cam)
    v = session(s, ["Vector"], samples=4).film_pass("Vector")
    # Film rows count from the bottom: z = 0.2 is row H / 2 + 0.2 ppu, the sphere's centre row 0.5.
    strand_row = int(H / 2 + 0.2 * ppu)
    cols = np.arange(2, W - 2)
    x = (cols + 0.5 - W / 2) / ppu
    expected = -(0.1 + 0.8 * (x + 4.0) / 8.0) * ppu  # the lift at the hit's parameter, in pixels
    np.testing.assert_allclose(v[strand_row, cols, 1], expected, rtol=0.02, atol=2e-3)
    np.testing.assert_allclose(v[strand_row, cols, 3], expected, rtol=0.02, atol=2e-3)
    np.testing.assert_allclose(v[strand_row, cols][:, [0, 2]], 0.0, atol=2e-3)
    sphere_row = int(H / 2 - 2.5 * ppu)
    np.testing.assert_allclose(v[sphere_row, W // 2 - 1:W // 2 + 1], [[-0.4 * ppu, 0.0, -0.4 * ppu, 0.0]] * 2,
                               atol=2e-3)
    # Without pass_points (or with them unchanged) the same strand is still.
    s = pc.Scene()
    mat = s.add_material("grey", (0.5, 0.5, 0.5))
    s.add_curves(keys, np.array([0, 2]), np.full(2, 0.5, np.float32), mat, curve_type="poly",
                 pass_points=np.stack([keys, keys]))
    s.set_camera(cam)
    assert not session(s, ["Vector"], samples=1).film_pass("Vector").any()


def test_bad_pass_motion_is_refused_or_ignored():
    s = pc.Scene()
    with pytest.raises(ValueError, match="pass_motion"):
        plane(s, 1.0, pass_motion=np.stack([np.eye(4)] * 3).astype(np.float32))
    cam = camera(pc, EYE, (0, 0, 0))
    cam.pass_motion = np.full((2, 4, 4), np.nan, np.float32)
    assert cam.pass_motion is None  # not finite: still


def aov_material(scene, name, writes, closure="diffuse"):
    """A material of one closure (white diffuse, or a clear Transparent BSDF) that writes
    `writes`: [(slot, "COLOR" or "VALUE", value (r, g, b) or v)] through aov_output ops."""
    prog = [("const", 0, (1.0, 1.0, 1.0, 1.0)), ("const", 1, (0.5, 0.5, 0.5, 1.0))]
    reg = 2
    for slot, kind, value in writes:
        v = tuple(value) + (1.0,) if kind == "COLOR" else (value, 0.0, 0.0, 0.0)
        prog += [("const", reg, v), ("aov_output", reg + 1, reg, slot, kind)]
        reg += 2
    prog.append(("closure", closure, 0, {"color": 0 if closure == "transparent" else 1}))
    return scene.add_shader(name, prog)


def test_shader_aovs_add_up_through_transparent_surfaces_to_the_first_opaque_one():
    s = pc.Scene()
    back = aov_material(s, "back", [(0, "COLOR", (0.2, 0.4, 0.6)), (1, "VALUE", 0.25)])
    veil = aov_material(s, "veil", [(1, "VALUE", 0.5)], closure="transparent")
    behind = aov_material(s, "behind", [(1, "VALUE", 100.0)])
    for y, half, mat in ((1.0, 20.0, behind), (0.0, 20.0, back), (-1.0, 0.5, veil)):
        pos, tris = quad((-half, y, -half), (0, 0, 2 * half), (2 * half, 0, 0))
        s.add_instance(s.add_mesh(pos, tris, None, None, [mat]), np.eye(4, dtype=np.float32))
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    sess = session(s, [], samples=2, shader_aovs=[4, 1])
    col, val = sess.film_aov(0), sess.film_aov(1)
    assert col.shape == (H, W, 4) and val.shape == (H, W, 1)
    # Everywhere the backdrop: its colour with alpha 1; nothing from the surface behind it.
    np.testing.assert_allclose(col.reshape(-1, 4), np.broadcast_to([0.2, 0.4, 0.6, 1.0], (H * W, 4)), atol=1e-6)
    # The veil (a clear Transparent BSDF) adds its 0.5 to the backdrop's 0.25 where it covers
    # the pixel; the corners see the backdrop alone.
    assert np.isclose(val[0, 0, 0], 0.25) and np.isclose(val[H // 2, W // 2, 0], 0.75)
    assert set(np.round(np.unique(val), 4)) >= {0.25, 0.75}
    assert val.max() <= 0.75 + 1e-6


def test_shader_aovs_read_zero_without_writers_and_bad_settings_are_refused():
    s = pc.Scene()
    plane(s, 10.0)
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    sess = session(s, [], samples=1, shader_aovs=[1])
    assert not sess.film_aov(0).any()
    with pytest.raises(ValueError, match="no shader AOV"):
        sess.film_aov(1)
    for bad in ([2], [4] * 17):
        with pytest.raises(ValueError, match="shader AOV"):
            session(s, [], samples=1, shader_aovs=bad)
    with pytest.raises(ValueError, match="aov slot"):
        pc.Scene().add_shader("bad", [("const", 0, (1, 1, 1, 1)), ("aov_output", 1, 0, 16, "VALUE")])
