"""Baking through the core (pc.Session's bake, docs/design/bake.md): texels set up on given
triangles and barycentrics, checked against closed forms."""
import numpy as np
import pytest

from core_scenes import add_object, core, quad

pc = core()
pytestmark = [pytest.mark.sanitize]

W, H = 8, 8


def bake(scene, instance, tri, bary, samples=1, mode="surface", passes=(), diff=None, width=W, height=H, **kw):
    """A finished baking Session: texel i of the width x height image on triangle tri[i] at
    barycentrics bary[i] (b1, b2) of the instance's mesh."""
    st = pc.RenderSettings()
    st.width, st.height, st.samples = width, height, samples
    st.threads = kw.pop("threads", 2)
    st.passes = list(passes)
    for k, v in kw.items():
        setattr(st, k, v)
    spec = {"instance": instance, "triangle": np.asarray(tri, np.int32),
            "bary": np.asarray(bary, np.float32).reshape(-1, 2), "mode": mode}
    if diff is not None:
        spec["differentials"] = np.asarray(diff, np.float32).reshape(-1, 4)
    sess = pc.Session(scene, st, bake=spec)
    sess.start()
    while not sess.wait(1.0):
        pass
    return sess


def glossy_program(color, roughness):
    """A Glossy BSDF of weight 1, a constant colour and Blender's roughness."""
    return [("const", 0, (*color, 1.0)), ("const", 1, (1.0, 1.0, 1.0, 1.0)), ("const", 2, (roughness, 0, 0, 0)),
            ("closure", "glossy", 1, {"color": 0, "roughness": 2})]


def random_texels(rng, n, tris):
    """n texels on random triangles of [0, tris) at random barycentrics inside them."""
    a = rng.random((n, 2)).astype(np.float32)
    flip = a.sum(axis=1) > 1.0
    a[flip] = 1.0 - a[flip]
    return rng.integers(0, tris, n).astype(np.int32), a


def transform(rot_deg, axis, scale, translate):
    """A 4x4 float32 matrix: translate @ rotate(axis, deg) @ diag(scale)."""
    ax = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    t = np.radians(rot_deg)
    k = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
    r = np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k
    m = np.eye(4)
    m[:3, :3] = r @ np.diag(scale)
    m[:3, 3] = translate
    return m.astype(np.float32)


def bumpy_mesh():
    """A small non-planar mesh (4 triangles of a pyramid's sides) with smooth corner normals
    that differ per corner."""
    pos = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], np.float32)
    tris = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]], np.int32)
    vn = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    vn[0] = (0, 0, 1)
    return pos, tris, vn[tris].astype(np.float32)  # corner normals (T, 3, 3)


@pytest.mark.parametrize("shared", [False, True])
def test_texel_position_and_normal_are_the_triangles(shared):
    """Position and Normal of each texel: the instance's triangle at the barycentrics (b1 weighs
    corner 1, b2 corner 2) and its interpolated normal through the instance's transform, to float
    rounding. shared: the mesh has two instances (an object-space BLAS), else one (merged into
    the world-space BLAS)."""
    rng = np.random.default_rng(3)
    pos, tris, cn = bumpy_mesh()
    s = pc.Scene()
    mat = s.add_material("grey", (0.5, 0.5, 0.5))
    other = s.add_mesh(*quad((-5, -5, -3), (10, 0, 0), (0, 10, 0)), material_slots=[mat])
    s.add_instance(other, np.eye(4, dtype=np.float32))  # instance 0: another object
    mesh = s.add_mesh(pos, tris, cn, material_slots=[mat])
    m = transform(37.0, (1, 2, 3), (1.5, 0.7, 1.2), (0.3, -2.0, 4.0))
    s.add_instance(mesh, m)  # instance 1: the one baked
    if shared:
        s.add_instance(mesh, transform(-20.0, (0, 0, 1), (1, 1, 1), (5, 5, 5)))
    tri, bary = random_texels(rng, W * H, len(tris))
    tri[5] = -1  # a texel of no triangle
    sess = bake(s, 1, tri, bary, passes=["Position", "Normal"])
    p = sess.film_pass("Position").reshape(-1, 3)
    n = sess.film_pass("Normal").reshape(-1, 3)
    b1, b2 = bary[:, 0:1], bary[:, 1:2]
    corners = pos[tris[tri]]  # (N, 3, 3)
    local = corners[:, 0] * (1 - b1 - b2) + corners[:, 1] * b1 + corners[:, 2] * b2
    world = local @ m[:3, :3].T + m[:3, 3]
    ok = tri >= 0
    np.testing.assert_allclose(p[ok], world[ok], atol=2e-5)
    assert np.all(p[~ok] == 0.0)
    cnn = cn[tri]
    nl = cnn[:, 0] * (1 - b1 - b2) + cnn[:, 1] * b1 + cnn[:, 2] * b2
    # Normals transform by the inverse transpose (each corner's, then interpolated).
    inv_t = np.linalg.inv(m[:3, :3].astype(np.float64)).T
    cw = cnn @ inv_t.T
    cw /= np.linalg.norm(cw, axis=2, keepdims=True)
    nw = cw[:, 0] * (1 - b1 - b2) + cw[:, 1] * b1 + cw[:, 2] * b2
    nw /= np.linalg.norm(nw, axis=1, keepdims=True)
    np.testing.assert_allclose(n[ok], nw[ok], atol=2e-5)
    film = sess.film().reshape(-1, 4)
    assert np.all(film[ok, 3] == 1.0) and np.all(film[~ok] == 0.0)  # alpha: texels only
    del nl


def test_emit_of_an_emissive_plane_is_its_emission():
    s = pc.Scene()
    mat = s.add_material("lamp", (0.5, 0.5, 0.5), emission=(2.0, 3.0, 4.0))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), mat)
    tri, bary = random_texels(np.random.default_rng(1), W * H, 2)
    sess = bake(s, 0, tri, bary, samples=2, passes=["Emit"])
    np.testing.assert_allclose(sess.film_pass("Emit").reshape(-1, 3), np.tile([2.0, 3.0, 4.0], (W * H, 1)),
                               rtol=1e-6)


def test_diffuse_color_is_the_closure_colour():
    s = pc.Scene()
    mat = s.add_material("red", (0.7, 0.2, 0.1))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), mat)
    s.set_world_color((1.0, 1.0, 1.0))
    tri, bary = random_texels(np.random.default_rng(2), W * H, 2)
    sess = bake(s, 0, tri, bary, samples=2, passes=["DiffCol", "GlossCol"])
    np.testing.assert_allclose(sess.film_pass("DiffCol").reshape(-1, 3), np.tile([0.7, 0.2, 0.1], (W * H, 1)),
                               rtol=1e-6)
    assert np.all(sess.film_pass("GlossCol") == 0.0)


def test_combined_of_a_diffuse_plane_in_the_white_furnace_is_its_albedo():
    """An open diffuse plane under a constant white world, seen from above: exactly its albedo
    (the camera side's hemisphere is all world), alpha 1."""
    s = pc.Scene()
    mat = s.add_material("grey", (0.6, 0.6, 0.6))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), mat)
    s.set_world_color((1.0, 1.0, 1.0))
    tri, bary = random_texels(np.random.default_rng(4), W * H, 2)
    sess = bake(s, 0, tri, bary, samples=16)
    film = sess.film().reshape(-1, 4)
    np.testing.assert_allclose(film[:, :3], 0.6, rtol=2e-3)
    assert np.all(film[:, 3] == 1.0)


def test_ao_of_an_open_plane_is_one_and_under_a_roof_closed_form():
    """AO with distance D of a point under an infinite roof at height h: a cosine-distributed ray
    at angle t escapes iff h / cos t > D, so AO = P(cos t < h / D) = (h / D)^2."""
    s = pc.Scene()
    mat = s.add_material("grey", (0.5, 0.5, 0.5))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), mat)
    tri, bary = random_texels(np.random.default_rng(5), W * H, 2)
    open_ = bake(s, 0, tri, bary, samples=8, passes=["AO"], ao_distance=1.0).film_pass("AO")
    np.testing.assert_allclose(open_, 1.0)
    roofed = pc.Scene()
    mat = roofed.add_material("grey", (0.5, 0.5, 0.5))
    add_object(roofed, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), mat)
    add_object(roofed, *quad((-200, -200, 0.5), (0, 400, 0), (400, 0, 0)), mat)  # facing down
    ao = bake(roofed, 0, tri, bary, samples=256, passes=["AO"], ao_distance=1.0).film_pass("AO")
    # 64 texels x 256 samples of p = 0.25: the mean's standard deviation is 0.0034.
    assert abs(float(ao.mean()) - 0.25) < 0.015
    assert float(ao.max()) < 0.5


def test_roughness_and_environment_bakes():
    s = pc.Scene()
    glossy = s.add_shader("glossy", glossy_program((0.8, 0.8, 0.8), 0.3))
    diffuse = s.add_material("grey", (0.5, 0.5, 0.5))
    pos, tris = quad((-1, -1, 0), (2, 0, 0), (0, 2, 0))
    s.add_instance(s.add_mesh(pos, tris, material_slots=[glossy]), np.eye(4, dtype=np.float32))
    s.add_instance(s.add_mesh(pos + np.float32([0, 0, -3]), tris, material_slots=[diffuse]), np.eye(4, dtype=np.float32))
    s.set_world_color((0.2, 0.4, 0.6))
    tri, bary = random_texels(np.random.default_rng(6), W * H, 2)
    r = bake(s, 0, tri, bary, mode="roughness").film().reshape(-1, 4)
    np.testing.assert_allclose(r[:, :3], 0.3, rtol=1e-5)
    # Diffuse lobes have no roughness in Cycles' pass: a diffuse surface reads its fallback 1.
    r = bake(s, 1, tri, bary, mode="roughness").film().reshape(-1, 4)
    np.testing.assert_allclose(r[:, :3], 1.0)
    e = bake(s, 0, tri, bary, mode="environment").film().reshape(-1, 4)
    np.testing.assert_allclose(e[:, :3], np.tile([0.2, 0.4, 0.6], (W * H, 1)), rtol=1e-6)


def test_bake_is_the_same_for_any_thread_count_and_deterministic():
    s = pc.Scene()
    mat = s.add_material("grey", (0.6, 0.5, 0.4))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), mat)
    add_object(s, *quad((-3, -3, 0.7), (0, 6, 0), (6, 0, 0)), mat)  # a roof: noisy light
    s.add_point_light((0.3, 0.2, 0.4), (5.0, 5.0, 5.0), radius=0.1)
    s.set_world_color((0.5, 0.5, 0.5))
    tri, bary = random_texels(np.random.default_rng(7), 16 * 16, 2)
    diff = np.tile([0.02, 0.0, 0.0, 0.02], (16 * 16, 1))
    a = bake(s, 0, tri, bary, samples=4, diff=diff, width=16, height=16, threads=1, passes=["DiffDir"]).film()
    b = bake(s, 0, tri, bary, samples=4, diff=diff, width=16, height=16, threads=3, passes=["DiffDir"]).film()
    assert np.array_equal(a, b)
    assert np.std(a[..., 0]) > 0.0  # (noisy enough that a different stream would show)


def test_bad_bake_input_is_refused():
    s = pc.Scene()
    mat = s.add_material("grey", (0.5, 0.5, 0.5))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), mat)
    tri, bary = random_texels(np.random.default_rng(8), W * H, 2)
    with pytest.raises(ValueError, match="unknown instance"):
        bake(s, 3, tri, bary)
    bad = tri.copy()
    bad[0] = 2
    with pytest.raises(ValueError, match="not one of the instance's mesh"):
        bake(s, 0, bad, bary)
    with pytest.raises(ValueError, match="width x height"):
        bake(s, 0, tri[:10], bary[:10])
    with pytest.raises(ValueError, match="mode"):
        bake(s, 0, tri, bary, mode="normal")
    nan = bary.copy()
    nan[3, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        bake(s, 0, tri, nan)
    with pytest.raises(ValueError, match="finite"):
        bake(s, 0, tri, bary, diff=np.full((W * H, 4), np.inf, np.float32))
