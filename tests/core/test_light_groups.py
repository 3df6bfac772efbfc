"""Light groups (Cycles' View Layer ▸ Light Groups, its Combined_<name> passes): each emitter (an
analytic light, an emissive object, the world, an emitting volume) names a group, and the light
of every contribution to Combined from it (seen, found by a ray, light-sampled, through a
volume, a caustic light path's splat or connection) goes to its group's pass too, clamped as it
was. So where every emitter is in a group the groups sum to Combined to float rounding, which
the tests assert tightly; a contribution site that forgot its group, or an unclamped one, breaks
that sum. Groups change no random number: Combined, and each group's pass, are bit for bit the
same whatever the other emitters' groups."""
import numpy as np
import pytest

from core_scenes import camera, core, look_at_matrix, quad, region_means, run_session, uv_sphere
from core_scenes import closure as program
from test_caustic_connections import CONN, shaded_scene
from test_caustic_light_paths import mirror_scene
from test_core_hetero_volumes import cube, linear_program
from test_light_linking import ALL, mirror_room
from test_light_tree import lamp_room

pc = core()
pytestmark = pytest.mark.skipif(not hasattr(pc.RenderSettings(), "light_groups"), reason="core without light groups")


def add(s, pos, tris, material, normals=None, group=-1):
    mesh = s.add_mesh(pos, tris, normals, None, [material])
    s.add_instance(mesh, np.eye(4, dtype=np.float32), light_group=group)


def studio(light_a=0, light_b=1, emitter=2, world=3, quad_emission=(3.0, 2.0, 1.0), only_a=False):
    """An open studio: a floor, a back wall, a glossy and a glass sphere; a point lamp A (with
    extent: rays find it), an area lamp B, an emissive quad and a sky colour, in groups light_a,
    light_b, emitter and world (-1: none). only_a: lamp A alone lights it (B left out, the quad
    black, the world black), the same geometry."""
    s = pc.Scene()
    white = s.add_material("white", (0.7, 0.7, 0.7))
    add(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), white)
    add(s, *quad((-3, 2, 0), (6, 0, 0), (0, 0, 3)), white)
    glossy = s.add_shader("glossy", program("glossy", color=(0.9, 0.8, 0.6), roughness=0.25))
    pos, tris, nrm = uv_sphere(0.5, nu=32, nv=16, center=(-0.7, 0.5, 0.5))
    add(s, pos, tris, glossy, nrm)
    glass = s.add_shader("glass", program("glass", color=(1.0, 1.0, 1.0), roughness=0.0, ior=1.45))
    pos, tris, nrm = uv_sphere(0.4, nu=32, nv=16, center=(0.7, 0.2, 0.4))
    add(s, pos, tris, glass, nrm)
    lamp = s.add_material("panel", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0) if only_a else quad_emission)
    add(s, *quad((-1.5, 1.9, 1.2), (0.8, 0, 0), (0, 0, 0.6)), lamp, group=emitter)
    s.add_point_light((1.2, -0.8, 2.0), (30.0, 28.0, 24.0), radius=0.15)
    s.set_light_group(0, light_a)
    if not only_a:
        s.add_area_light(look_at_matrix((-1.0, -1.5, 2.5), (0.0, 0.5, 0.3)), 0.6, 0.4, (8.0, 9.0, 12.0))
        s.set_light_group(1, light_b)
    s.set_world_color((0.0, 0.0, 0.0) if only_a else (0.15, 0.2, 0.3))
    s.set_world_light_group(world)
    s.set_camera(camera(pc, (0.0, -4.0, 1.6), (0.0, 0.5, 0.6), lens=30.0))
    s.commit()
    return s


def render(scene, w=32, h=24, spp=8, groups=4, **kw):
    sess = run_session(pc, scene, w, h, spp, threads=2, seed=3, light_groups=groups, **kw)
    comb = np.asarray(sess.film())[..., :3].astype(np.float64)
    return comb, [np.asarray(sess.film_light_group(i)).astype(np.float64) for i in range(groups)], sess


def assert_sum(comb, groups):
    """The groups sum to Combined to float rounding (each plane is a running mean of its own)."""
    total = np.sum(groups, axis=0)
    np.testing.assert_allclose(total, comb, rtol=2e-5, atol=2e-6 * max(1.0, float(comb.max())))


def test_pass_shapes_and_settings():
    comb, g, sess = render(studio(), 8, 6, 1, groups=2)
    assert comb.shape == (6, 8, 3) and all(x.shape == (6, 8, 3) for x in g)
    with pytest.raises(ValueError):
        sess.film_light_group(2)
    st = pc.RenderSettings()
    st.light_groups = 65
    with pytest.raises(ValueError):
        pc.Session(studio(), st)
    s = pc.Scene()
    with pytest.raises(ValueError):
        s.set_world_light_group(64)
    with pytest.raises(IndexError):
        s.set_light_group(0, 1)  # (no light 0)


@pytest.mark.parametrize("general", [False, True])
def test_groups_sum_to_combined(general):
    comb, g, sess = render(studio(), spp=16, force_general_kernel=general)
    assert sess.stats()["nonfinite_samples"] == 0
    assert_sum(comb, g)
    means = [x.mean() for x in g]
    assert min(means) > 0.01 * comb.mean(), means  # every emitter lights something
    # The lamps light the floor, the world the sky above the wall: different images.
    assert np.abs(g[0] / g[0].mean() - g[3] / g[3].mean()).mean() > 0.3


def test_groups_change_neither_combined_nor_each_other():
    plain = run_session(pc, studio(), 32, 24, 8, threads=2, seed=3).film()
    comb, g, _ = render(studio())
    np.testing.assert_array_equal(np.asarray(plain)[..., :3], comb.astype(np.float32))
    # B in no group: A's, the quad's and the world's passes are unchanged, bit for bit; the
    # groups then sum to Combined less what B sent (its pass of the render above).
    comb2, g2, _ = render(studio(light_b=-1))
    np.testing.assert_array_equal(comb2, comb)
    for k in (0, 2, 3):
        np.testing.assert_array_equal(g2[k], g[k])
    assert np.all(g2[1] == 0.0)
    np.testing.assert_allclose(np.sum(g2, axis=0), comb - g[1], rtol=2e-5, atol=1e-5)
    assert g[1].mean() > 0.02 * comb.mean()
    # Two emitters in one group: that group holds both.
    comb3, g3, _ = render(studio(light_b=0))
    np.testing.assert_allclose(g3[0], g[0] + g[1], rtol=2e-5, atol=1e-5)
    # A group the render does not keep (index past light_groups): the light reaches no pass.
    comb4, g4, _ = render(studio(world=3), groups=3)
    np.testing.assert_allclose(np.sum(g4, axis=0), comb4 - g[3], rtol=2e-5, atol=1e-5)


def test_a_groups_pass_is_its_lamp_alone_within_noise():
    """Lamp A's group against a render lit by A alone: the same light, by other light choices
    (B and the quad and the world change its probability), so within noise, not exactly."""
    a, alone = [], []
    for seed in (1, 2, 3):
        sess = run_session(pc, studio(), 24, 18, 64, threads=2, seed=seed, light_groups=4)
        a.append(np.asarray(sess.film_light_group(0), np.float64))
        alone.append(np.asarray(run_session(pc, studio(only_a=True), 24, 18, 64, threads=2,
                                            seed=seed + 10).film(), np.float64)[..., :3])
    a, alone = np.array(a), np.array(alone)
    assert abs(a.mean() / alone.mean() - 1.0) < 0.03
    ra = np.array([region_means(i, 4) for i in a])
    rb = np.array([region_means(i, 4) for i in alone])
    sd = np.sqrt(ra.var(0, ddof=1) / 3 + rb.var(0, ddof=1) / 3)
    assert np.all(np.abs(ra.mean(0) - rb.mean(0)) <= np.maximum(4.0 * sd, 0.05 * rb.mean(0)))


def test_exposure_scales_the_groups_as_combined():
    comb, g, _ = render(studio())
    comb2, g2, _ = render(studio(), exposure=2.0)
    np.testing.assert_allclose(comb2, 2.0 * comb, rtol=1e-6)
    for k in range(4):
        np.testing.assert_allclose(g2[k], 2.0 * g[k], rtol=1e-6)


def test_clamping_goes_to_the_groups_as_to_combined():
    free, gf, _ = render(studio(), spp=8)
    comb, g, _ = render(studio(), spp=8, clamp_direct=0.6, clamp_indirect=0.1)
    assert comb.mean() < 0.9 * free.mean()  # (the limits cut a lot)
    assert_sum(comb, g)
    for k in range(4):
        assert g[k].mean() <= gf[k].mean() + 1e-6


def test_transparent_film_world_group_as_cycles():
    """On a transparent film the world seen directly is not in Combined; Cycles still writes it
    to the world's group where the Env pass is on (it evaluates the world for that pass)."""
    opaque, g0, _ = render(studio())
    _, g, _ = render(studio(), film_transparent=True)
    _, ge, _ = render(studio(), film_transparent=True, passes=["Env"])
    np.testing.assert_array_equal(ge[3], g0[3])
    sky = np.all(g0[3] == np.float32([0.15, 0.2, 0.3]), axis=-1)  # (the world seen directly)
    assert sky.sum() >= 8
    assert np.all(g[3][sky] == 0.0) and np.all(g[3] <= g0[3] + 1e-7)
    assert np.sum(g0[3] != g[3]) <= 3 * 2 * sky.sum()  # (the sky's pixels and its edge's)
    for k in range(3):
        np.testing.assert_array_equal(g[k], g0[k])


def test_caustic_light_paths_splat_to_their_emitters_groups():
    # The environment's sun (group 0) and a sun lamp (group 1) send light paths; the floor's
    # caustics reach Combined by the splats, which must go to their sources' groups too.
    s = mirror_scene(sun_light=True)
    s.set_world_light_group(0)
    s.set_light_group(0, 1)
    comb, g, sess = render(s, 32, 24, 8, groups=2, caustic_light_paths=1.0)
    assert sess.stats()["caustics"] == "on"
    assert_sum(comb, g)
    assert g[0].mean() > 0.01 and g[1].mean() > 0.01


def test_light_vertex_connections_go_to_the_lamps_group():
    s = shaded_scene()  # a sun (light 0) alone, its caustics seen after a rough bounce
    s.set_light_group(0, 1)
    comb, g, sess = render(s, 32, 24, 8, groups=2, **CONN)
    assert sess.stats()["caustics"] == "on" and sess.stats()["caustic_connections"] == 2
    assert comb.mean() > 0.0
    assert np.all(g[0] == 0.0)
    np.testing.assert_allclose(g[1], comb, rtol=2e-5, atol=2e-6)


def test_light_tree_groups_sum_to_combined():
    # 50 points, 3 spots and an area light (the light tree) in three groups; the emissive
    # quads and the sphere (mesh lights, ungrouped here) are left out of this room.
    s = lamp_room("on", quads=0, sphere=False)
    lights = 54
    for i in range(lights):
        s.set_light_group(i, i % 3)
    s.commit()
    comb, g, sess = render(s, 32, 24, 8, groups=3)
    assert s.light_tree_active
    assert_sum(comb, g)
    assert min(x.mean() for x in g) > 0.1 * comb.mean()


def test_volumes_send_their_light_to_their_groups():
    """A fog sphere that scatters lamp A's light (light samples at volume points, equiangular
    and free-flight, and the lamp found by phase rays), an emitting homogeneous sphere (group 1)
    and an emitting heterogeneous cube (group 2), beside each other and overlapping."""
    s = pc.Scene()
    white = s.add_material("white", (0.7, 0.7, 0.7))
    add(s, *quad((-4, -4, -1), (8, 0, 0), (0, 8, 0)), white)
    clear = [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})]
    fog = s.add_shader("fog", clear, volume={"sigma_s": (1.5, 1.5, 1.5), "sigma_a": (0.2, 0.2, 0.2)})
    pos, tris, nrm = uv_sphere(1.0, nu=32, nv=16, center=(-0.8, 0.0, 0.0))
    add(s, pos, tris, fog, nrm, group=3)  # (scatters only: its group gets nothing)
    glow = s.add_shader("glow", clear, volume={"sigma_s": (0.5, 0.5, 0.5), "sigma_a": (0.5, 0.5, 0.5),
                                               "emission": (0.6, 0.3, 0.1)})
    pos, tris, nrm = uv_sphere(0.6, nu=32, nv=16, center=(0.2, -0.3, 0.2))
    add(s, pos, tris, glow, nrm, group=1)
    smoke = s.add_shader("smoke", clear, volume=linear_program(a=0.5, b=0.5, albedo=0.7, absorb=0.3,
                                                                emission=(0.1, 0.3, 0.5)))
    pos, tris = cube(0.6)
    mesh = s.add_mesh(pos + np.float32([1.0, 0.0, 0.0]), tris, None, None, [smoke])
    s.add_instance(mesh, np.eye(4, dtype=np.float32), light_group=2)
    s.add_point_light((0.0, -1.5, 2.0), (20.0, 20.0, 20.0), radius=0.1)
    s.set_light_group(0, 0)
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, -5.0, 1.0), (0.0, 0.0, 0.0), lens=35.0))
    s.commit()
    comb, g, sess = render(s, 32, 24, 16, groups=4)
    assert "volumes" in sess.stats()["features"]
    assert_sum(comb, g)
    assert g[0].mean() > 0.01 and g[1].mean() > 0.01 and g[2].mean() > 0.005
    assert np.all(g[3] == 0.0)


def test_shadow_catcher_paths_write_no_group_after_the_split():
    """As Cycles (PATH_RAY_SHADOW_CATCHER_HIT): what a path gathers past a shadow catcher goes
    to no light group, so where the floor is a catcher the groups hold only what the camera
    sees before it (the lamps and spheres' own light)."""
    s = studio()
    comb, g, _ = render(s, groups=4)
    s2 = pc.Scene()
    # The same studio with the floor a catcher.
    white = s2.add_material("white", (0.7, 0.7, 0.7))
    mesh = s2.add_mesh(*quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), None, None, [white])
    s2.add_instance(mesh, np.eye(4, dtype=np.float32), shadow_catcher=True, light_group=-1)
    add(s2, *quad((-3, 2, 0), (6, 0, 0), (0, 0, 3)), white)
    s2.add_point_light((1.2, -0.8, 2.0), (30.0, 28.0, 24.0), radius=0.15)
    s2.set_light_group(0, 0)
    s2.set_world_color((0.15, 0.2, 0.3))
    s2.set_world_light_group(3)
    s2.set_camera(camera(pc, (0.0, -4.0, 1.6), (0.0, 0.5, 0.6), lens=30.0))
    s2.commit()
    comb2, g2, _ = render(s2, groups=4)
    floor = comb2.mean(axis=-1) > -1  # every pixel
    total = np.sum(g2, axis=0)
    # The floor fills the lower half of the view: there the groups hold nothing.
    assert np.all(total[:6] == 0.0) and comb2[:6].mean() > 0.0
    assert floor.all() and total[-4:].mean() > 0.0  # (the wall above it, lit and seen directly)


def test_curves_and_points_emit_into_their_objects_groups():
    """Curves and point clouds are emitters found by rays alone (no light samples): their
    emission goes to their set's group."""
    s = pc.Scene()
    white = s.add_material("white", (0.7, 0.7, 0.7))
    add(s, *quad((-3, -3, -1), (6, 0, 0), (0, 6, 0)), white)
    glow = s.add_material("glow", (0.0, 0.0, 0.0), (2.0, 1.5, 1.0))
    pts = np.array([[x, 0.0, 0.2 * (x % 2)] for x in np.linspace(-1.0, 1.0, 9)], np.float32)
    s.add_points(pts, np.full(len(pts), 0.12, np.float32), glow, light_group=0)
    strands = np.array([[x, 0.5, z] for x in (-0.6, 0.0, 0.6) for z in np.linspace(-0.8, 0.8, 4)], np.float32)
    s.add_curves(strands, np.array([0, 4, 8, 12], np.int32), np.full(len(strands), 0.05, np.float32), glow,
                 light_group=1)
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, -4.0, 0.5), (0.0, 0.0, 0.0), lens=35.0))
    s.commit()
    comb, g, _ = render(s, 32, 24, 8, groups=2)
    assert_sum(comb, g)
    assert g[0].mean() > 0.01 and g[1].mean() > 0.005


def test_shadow_linked_lamps_found_by_dedicated_rays_go_to_their_groups():
    """Shadow-linked lamps with extent are found by dedicated rays (dedicated_light_hits), each
    handing its light to its own group; the world is black, so the two lamps are all (the
    area lamp faces away from what the camera sees: the sun's glint in the mirror and the
    floor, found by dedicated rays only, are most of the image)."""
    s = mirror_room(ALL & ~(1 << 5))
    s.set_light_group(0, 0)  # the area lamp
    s.set_light_group(1, 1)  # the sun
    s.set_world_color((0.0, 0.0, 0.0))
    s.commit()
    comb, g, sess = render(s, 32, 24, 8, groups=2, max_bounces=3)
    assert "light linking" in sess.stats()["features"]
    assert_sum(comb, g)
    assert g[1].mean() > 0.1
