"""Light and shadow linking in the core: light sets per object, set masks per light.

A closed form: a diffuse sphere of albedo a inside a black shell that emits Le everywhere sees
radiance Le from every direction, so it shows a * Le (it is convex: nothing else reaches it).
Lights in the shell that are not linked to the sphere's light set must add nothing, by light
samples or by rays, and the MIS weights of the shell's light samples and of the rays that hit
it must use the sphere's set's pdfs, or the image is not a * Le."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, run_session, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize

ALBEDO, LE = 0.8, 0.5
SET0, SET1 = 0b01, 0b10
ALL = (1 << 64) - 1


def linked_furnace(light_tree="off", blocker=False, receiver="mesh"):
    """The sphere (light set 1) in the shell (lighting set 1 only), bright lights of set 0 beside
    it. blocker: a black plate (shadow set 1) between the sphere and part of the shell, which the
    shell's light passes (its shadow mask has set 0 only); "points" / "curves": a black sphere of
    a point cloud / a black thick strand there instead. receiver "points": the sphere is a point
    cloud's; "curves": a thick vertical strand of radius 0.5 through it (convex too)."""
    s = pc.Scene()
    s.light_tree = light_tree
    shell = s.add_material("shell", (0.0, 0.0, 0.0), (LE, LE, LE))
    grey = s.add_material("grey", (ALBEDO, ALBEDO, ALBEDO))
    black = s.add_material("black", (0.0, 0.0, 0.0))
    lamp = s.add_material("lamp", (0.0, 0.0, 0.0), (40.0, 40.0, 40.0))
    eye = np.eye(4, dtype=np.float32)
    pos, tris, nrm = uv_sphere(3.0, nu=32, nv=16, inward=True)
    s.add_instance(s.add_mesh(pos, tris, nrm, None, [shell]), eye, light_mask=SET1,
                   shadow_mask=SET0 if blocker else ALL)
    if receiver == "points":
        s.add_points(np.zeros((1, 3), np.float32), np.float32([0.5]), grey, light_set=1)
    elif receiver == "curves":
        s.add_curves(np.float32([[0, 0, -2.5], [0, 0, 2.5]]), np.int32([0, 2]), np.float32([0.5, 0.5]), grey,
                     curve_type="poly", light_set=1)
    else:
        pos, tris, nrm = uv_sphere(0.5, nu=48, nv=24)
        s.add_instance(s.add_mesh(pos, tris, nrm, None, [grey]), eye, light_set=1)
    # Set 0's lights, close to the sphere and far brighter than the shell: an emissive quad, an
    # area light and a point light with a radius (rays cross them: lights never occlude).
    pos, tris = quad((-0.4, 0.8, -0.4), (0.8, 0, 0), (0, 0, 0.8))
    s.add_instance(s.add_mesh(pos, tris, None, None, [lamp]), eye, light_mask=SET0)
    area = np.eye(4, dtype=np.float32)
    area[:3, 3] = (0.0, 0.0, 1.2)
    area[:3, :3] = np.diag((1.0, -1.0, -1.0))  # facing down at the sphere
    s.add_area_light(area, 1.0, 1.0, (50.0, 50.0, 50.0))
    s.set_light_links(0, light_mask=SET0)
    s.add_point_light((1.0, 0.0, 0.0), (30.0, 30.0, 30.0), radius=0.2)
    s.set_light_links(1, light_mask=SET0)
    for k in range(8):  # more set-0 lamps: the tree has several levels
        s.add_point_light((1.5 * np.cos(k), 1.5 * np.sin(k), 1.5), (5.0, 5.0, 5.0), radius=0.05)
        s.set_light_links(2 + k, light_mask=SET0)
    if blocker == "points":
        s.add_points(np.float32([[0.0, 1.4, 0.0]]), np.float32([0.8]), black, shadow_set=1)
    elif blocker == "curves":
        s.add_curves(np.float32([[-2, 1.2, 0], [2, 1.2, 0]]), np.int32([0, 2]), np.float32([0.4, 0.4]), black,
                     curve_type="poly", shadow_set=1)
    elif blocker:
        pos, tris = quad((-1.0, 1.0, -1.0), (2.0, 0, 0), (0, 0, 2.0))
        s.add_instance(s.add_mesh(pos, tris, None, None, [black]), eye, shadow_set=1)
    s.set_camera(camera(pc, (0.0, -1.6, 0.0), (0.0, 0.0, 0.0), lens=50.0))
    return s


def sphere_mean(scene, samples=64, size=32):
    film = run_session(pc, scene, size, size, samples, max_bounces=4, threads=2).film()
    c = film[size // 4: 3 * size // 4, size // 4: 3 * size // 4, :3]  # on the sphere
    return c


@pytest.mark.parametrize("tree", ["off", "on"])
def test_unlinked_lights_add_nothing_and_mis_uses_the_sets_pdfs(tree):
    s = linked_furnace(tree)
    s.commit()
    assert "light linking" in s.stats()["features"]
    img = sphere_mean(s)
    expected = ALBEDO * LE  # a / pi times the irradiance pi Le
    assert abs(img.mean() / expected - 1.0) < 0.01, img.mean()
    # Noise-free: every light sample and every ray from the sphere finds the shell alone.
    assert img.std() / img.mean() < 0.05


def test_shadow_linked_blockers_let_the_light_pass():
    img = sphere_mean(linked_furnace(blocker=True))
    assert abs(img.mean() / (ALBEDO * LE) - 1.0) < 0.01, img.mean()


@pytest.mark.parametrize("receiver, blocker", [("points", "curves"), ("curves", "points")])
def test_curves_and_points_take_their_light_and_shadow_sets(receiver, blocker):
    """A point cloud's sphere and a thick strand as the receiver of set 1 (lights of set 0 would
    make them far brighter), each with the other kind as the blocker that the shell's light
    passes (blocked, it would be darker)."""
    s = linked_furnace(receiver=receiver)
    s.commit()
    assert "light linking" in s.stats()["features"]
    img = sphere_mean(s)
    assert abs(img.mean() / (ALBEDO * LE) - 1.0) < 0.01, img.mean()
    assert img.std() / img.mean() < 0.05  # the shell alone: noise-free
    # The blocker covers about a tenth of the shell as the receiver sees it.
    img = sphere_mean(linked_furnace(receiver=receiver, blocker=blocker))
    assert abs(img.mean() / (ALBEDO * LE) - 1.0) < 0.01, img.mean()


def test_curve_and_point_sets_alone_turn_linking_on():
    """Sets on curves and points alone (no object or light masks) still count as linking, and
    the default sets do not."""
    for kind in ("points", "curves"):
        for sets, linked in (({}, False), ({"shadow_set": 2}, True), ({"light_set": 3}, True)):
            s = pc.Scene()
            m = s.add_material("grey", (0.5, 0.5, 0.5))
            if kind == "points":
                s.add_points(np.zeros((1, 3), np.float32), np.float32([0.5]), m, **sets)
            else:
                s.add_curves(np.float32([[0, 0, 0], [0, 0, 1]]), np.int32([0, 2]), None, m, **sets)
            s.add_point_light((0.0, -2.0, 1.0), (1.0, 1.0, 1.0))
            s.commit()
            assert ("light linking" in s.stats()["features"]) == linked, (kind, sets)
    s = pc.Scene()
    m = s.add_material("grey", (0.5, 0.5, 0.5))
    with pytest.raises(ValueError):
        s.add_curves(np.float32([[0, 0, 0], [0, 0, 1]]), np.int32([0, 2]), None, m, light_set=64)
    with pytest.raises(ValueError):
        s.add_points(np.zeros((1, 3), np.float32), None, m, shadow_set=-1)


def test_light_choice_per_set():
    """Set 1 picks only the shell's triangles, with pmfs that sum to 1; set 0 never the shell."""
    s = linked_furnace("on")
    s.commit()
    rng = np.random.default_rng(3)
    p = rng.uniform(-0.4, 0.4, (64, 3)).astype(np.float32)
    n = np.zeros_like(p)
    u = rng.uniform(0, 1, 64).astype(np.float32)
    k1, pmf1, all1 = s.light_choices(p, n, u, all_pmfs=True, light_set=1)
    k0, _, all0 = s.light_choices(p, n, u, all_pmfs=True, light_set=0)
    # Entries: the 10 analytic lights, the shell's triangles (one group each), the lamp quad.
    lights, kk = 10, all1.shape[1]
    assert ((k1 >= lights) & (k1 < kk - 1)).all()
    np.testing.assert_allclose(all1.sum(axis=1), 1.0, rtol=1e-4)
    np.testing.assert_allclose(all1[np.arange(64), k1], pmf1, rtol=1e-6)
    assert ((k0 < lights) | (k0 == kk - 1)).all()
    assert (all0[:, lights:kk - 1] == 0).all() and (all1[:, :lights] == 0).all()
    np.testing.assert_allclose(all0.sum(axis=1), 1.0, rtol=1e-4)


def test_trivial_linking_renders_the_unlinked_image_bit_for_bit():
    """Linking that changes nothing (every object in set 1, every light lighting every set)
    runs the linking code (general kernel) and renders the unlinked general kernel's image."""
    from core_scenes import cornell

    def build(linked):
        s = cornell(pc)
        if linked:  # a sphere in set 1; the masks stay all-sets
            pos, tris, nrm = uv_sphere(0.2, center=(-0.4, -0.2, 0.2))
            s.add_instance(s.add_mesh(pos, tris, nrm, None, [0]), np.eye(4, dtype=np.float32), light_set=1,
                           shadow_set=1)
        else:
            pos, tris, nrm = uv_sphere(0.2, center=(-0.4, -0.2, 0.2))
            s.add_instance(s.add_mesh(pos, tris, nrm, None, [0]), np.eye(4, dtype=np.float32))
        s.add_point_light((0.5, -0.5, 1.5), (2.0, 2.0, 2.0), radius=0.1)
        return s

    a = run_session(pc, build(False), 24, 24, 8, threads=2, force_general_kernel=True)
    b = run_session(pc, build(True), 24, 24, 8, threads=2)
    assert b.stats()["kernel"] == "general"
    assert "light linking" in b.stats()["features"]
    assert a.film()[..., :3].max() > 0.0
    assert np.array_equal(a.film(), b.film())


def test_unlinked_scene_keeps_its_kernel_and_image():
    """Passing the default sets and masks explicitly changes nothing: same features, same
    specialised kernel, the same image bit for bit."""
    from core_scenes import cornell

    def build(explicit):
        s = cornell(pc)
        pos, tris, nrm = uv_sphere(0.2, center=(-0.4, -0.2, 0.2))
        kw = dict(light_set=0, shadow_set=0, light_mask=(1 << 64) - 1, shadow_mask=(1 << 64) - 1) if explicit else {}
        s.add_instance(s.add_mesh(pos, tris, nrm, None, [0]), np.eye(4, dtype=np.float32), **kw)
        s.add_point_light((0.5, -0.5, 1.5), (2.0, 2.0, 2.0), radius=0.1)
        if explicit:
            s.set_light_links(0)
        return s

    a = run_session(pc, build(False), 24, 24, 8, threads=2)
    b = run_session(pc, build(True), 24, 24, 8, threads=2)
    assert "light linking" not in b.stats()["features"]
    assert a.stats()["kernel"] == b.stats()["kernel"] != "general"
    assert np.array_equal(a.film(), b.film())


def test_bad_sets_raise():
    s = pc.Scene()
    m = s.add_material("grey", (0.5, 0.5, 0.5))
    pos, tris = quad((0, 0, 0), (1, 0, 0), (0, 1, 0))
    mesh = s.add_mesh(pos, tris, None, None, [m])
    with pytest.raises(ValueError):
        s.add_instance(mesh, np.eye(4, dtype=np.float32), light_set=64)
    with pytest.raises(ValueError):
        s.add_instance(mesh, np.eye(4, dtype=np.float32), shadow_set=-1)
    with pytest.raises(IndexError):
        s.set_light_links(3, light_mask=1)


def glossy(s, name, roughness):
    return s.add_shader(name, [("const", 0, (0.9, 0.9, 0.9)), ("const", 1, (roughness,)),
                               ("closure", "glossy", None, {"color": 0, "roughness": 1})])


def mirror_room(shadow_mask):
    """An area light and a sun seen in a mirror sphere and a glossy floor (roughness 0.1),
    with the given shadow mask on both (the sphere and floor are in shadow set 0)."""
    s = pc.Scene()
    floor = glossy(s, "floor", 0.1)
    mirror = glossy(s, "mirror", 0.0)
    pos, tris = quad((-3, -3, 0), (6, 0, 0), (0, 6, 0))
    add_object(s, pos, tris, floor)
    pos, tris, nrm = uv_sphere(0.6, center=(0.0, 0.5, 0.6))
    add_object(s, pos, tris, mirror, nrm)
    area = np.eye(4, dtype=np.float32)
    area[:3, 3] = (0.8, -0.2, 2.0)
    area[:3, :3] = np.diag((1.0, -1.0, -1.0))
    s.add_area_light(area, 0.6, 0.4, (20.0, 20.0, 20.0))
    s.add_sun_light((-0.3, 0.6, 0.4), (2.0, 2.0, 2.0), angle=0.2)
    for k in range(2):
        s.set_light_links(k, shadow_mask=shadow_mask)
    s.set_camera(camera(pc, (0.0, -3.0, 1.2), (0.0, 0.5, 0.4), lens=35.0))
    return s


def test_shadow_linked_lights_are_seen_by_mirrors_and_weighted_by_mis():
    """Shadow linking that excludes no blocker in the scene (set 5 is empty) changes the
    estimator (dedicated rays for the lights, MIS against their light samples) but not the
    image: the mirror shows the lights, the glossy floor their highlights."""
    unlinked = run_session(pc, mirror_room(ALL), 32, 32, 256, max_bounces=3, threads=2).film()[..., :3]
    linked_s = run_session(pc, mirror_room(ALL & ~(1 << 5)), 32, 32, 256, max_bounces=3, threads=2)
    assert "light linking" in linked_s.stats()["features"]
    linked = linked_s.film()[..., :3]
    assert abs(linked.mean() / unlinked.mean() - 1.0) < 0.01
    reg = lambda im: im.reshape(4, 8, 4, 8, 3).mean(axis=(1, 3))  # noqa: E731
    a, b = reg(linked), reg(unlinked)
    assert (np.abs(a - b) <= 0.03 * np.maximum(b, 0.1 * b.mean())).all(), np.round(np.abs(a - b) / b, 3)


def fog_box(linked):
    """A scattering fog cube seen against black, lit by lamp A; linked: the cube in light set 1,
    A lighting set 1 only and a brighter lamp B set 0 only (which must add nothing)."""
    s = pc.Scene()
    fog = s.add_shader("fog", [("const", 0, (1.0, 1.0, 1.0)), ("closure", "transparent", None, {"color": 0})],
                       volume={"sigma_s": (1.5, 1.5, 1.5), "g": 0.3})
    pos, tris, nrm = uv_sphere(0.8, nu=24, nv=12)
    s.add_instance(s.add_mesh(pos, tris, nrm, None, [fog]), np.eye(4, dtype=np.float32), light_set=1 if linked else 0)
    s.add_point_light((1.2, -0.5, 1.0), (6.0, 6.0, 6.0), radius=0.1)
    if linked:
        s.set_light_links(0, light_mask=SET1)
        s.add_point_light((-1.2, -0.5, 0.5), (30.0, 30.0, 30.0), radius=0.1)
        s.set_light_links(1, light_mask=SET0)
    s.set_camera(camera(pc, (0.0, -3.0, 0.0), (0.0, 0.0, 0.0), lens=40.0))
    return s


def test_volume_objects_take_their_light_set():
    """Scattering in a volume object uses that object's light set (Cycles' volume shading
    object): the linked fog renders the fog lit by A alone."""
    ref = run_session(pc, fog_box(False), 24, 24, 256, max_bounces=4, threads=2).film()[..., :3]
    img = run_session(pc, fog_box(True), 24, 24, 256, max_bounces=4, threads=2).film()[..., :3]
    assert ref.mean() > 0.01
    assert abs(img.mean() / ref.mean() - 1.0) < 0.02, (img.mean(), ref.mean())
    reg = lambda im: im.reshape(3, 8, 3, 8, 3).mean(axis=(1, 3))  # noqa: E731
    a, b = reg(img), reg(ref)
    assert (np.abs(a - b) <= 0.05 * np.maximum(b, 0.2 * b.mean())).all(), np.round(np.abs(a - b) / b, 3)
