"""Two-level BVH (issue 6) and transform edits (issue 8), through the compiled module.

The same scene is built three ways and must agree: "merged" (every instance its own mesh: final
renders merge single-use meshes into one world-space BLAS, no top level), "shared" (one mesh,
several instances: one object-space BLAS under a top level) and "dynamic" (Scene(dynamic=True),
the viewport's mode: every instance real, so moving one rebuilds only the top level).
"""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, cornell, quad, random_rotation as rotation, region_means, render, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

MODES = ["merged", "shared", "dynamic"]


def affine(linear, shift):
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = shift
    return m.astype(np.float32)


# Linear parts of the instances, by kind (each also rotated and moved apart).
KINDS = {
    "rotated": lambda i: rotation(i),
    "scaled": lambda i: rotation(i) * (0.3 + 0.4 * i),
    "nonuniform": lambda i: rotation(i) @ np.diag([0.4, 1.3, 0.7]) @ rotation(i + 50),
    "mirrored": lambda i: rotation(i) @ np.diag([-0.8, 0.9, 1.1]),  # negative determinant
    "sheared": lambda i: rotation(i) @ np.array([[1.0, 0.6, 0.0], [0.0, 1.0, 0.3], [0.0, 0.0, 0.8]]),
    "translated": lambda i: np.eye(3),  # moved only: the top level shifts rays without matrix products
}


def matrices(kind, n=4):
    return [affine(KINDS[kind](i), (2.5 * (i % 2) - 1.25, 2.5 * (i // 2) - 1.25, 0.0)) for i in range(n)]


def clean(pos, tris, nrm):
    """Without the poles' (near-)degenerate triangles: which of those are dropped depends on
    rounding in object or world space, and flattened prim ids count only kept triangles."""
    e = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    keep = np.linalg.norm(e, axis=1) > 1e-6
    return pos, tris[keep], nrm[keep]


def sphere_mesh():
    pos, tris, nrm = clean(*uv_sphere(0.8, nu=24, nv=12))
    uv = np.stack([pos[tris][..., 0], pos[tris][..., 2]], -1).astype(np.float32) * 0.5 + 0.5
    return pos, tris, nrm, uv


def build(mode, mats, material=None, mesh=None, scene=None):
    """The sphere (or `mesh`) under every matrix, as `mode` asks; returns the Scene (not committed)."""
    s = scene if scene is not None else pc.Scene(dynamic=(mode == "dynamic"))
    m = s.add_material("m", (0.6, 0.5, 0.4)) if material is None else material(s)
    pos, tris, nrm, uv = sphere_mesh() if mesh is None else mesh
    add = lambda: s.add_mesh(pos, tris, nrm, None, [m], uvs={0: uv})  # noqa: E731
    shared = add() if mode != "merged" else None
    for mat in mats:
        s.add_instance(add() if mode == "merged" else shared, mat)
    return s


def random_rays(n, seed, radius=6.0):
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3))
    o *= (radius / np.linalg.norm(o, axis=1))[:, None]
    target = rng.uniform(-2.2, 2.2, (n, 3)) * [1.0, 1.0, 0.6]
    return o.astype(np.float32), (target - o).astype(np.float32)


def assert_same_hits(a, b, min_hits=1000):
    ta, pa, _, _, ia, ra = a
    tb, pb, _, _, ib, rb = b
    hit = pa >= 0
    assert hit.sum() >= min_hits
    # Rays through a shared edge may pick either triangle under different rounding: a handful.
    same = pa == pb
    assert (~same).sum() <= max(3, 1e-3 * len(pa)), f"{(~same).sum()} of {len(pa)} rays hit other triangles"
    both = same & hit
    assert np.array_equal(ia[both], ib[both]) and np.array_equal(ra[both], rb[both])
    # t to rounding: vertices rounded in world space against rays rounded into object space;
    # grazing hits amplify that (as 1 / cos), hence the looser bound on a few.
    rel = np.abs(ta[both] - tb[both]) / np.maximum(ta[both], 1e-6)
    assert (rel < 1e-5).mean() > 0.99 and rel.max() < 1e-3, (np.mean(rel < 1e-5), rel.max())


# ---------------------------------------------------------------- hits and stats

def test_merged_hits_name_their_instance_with_empty_instances_between():
    """The merged BLAS finds a hit's instance from its runs of triangles (one per instance, in
    instance order); instances whose triangles are all dropped own no run and must not shift the
    instances after them."""
    s = pc.Scene()
    m = s.add_material("m", (0.5, 0.5, 0.5))
    pos, tris, nrm, _ = sphere_mesh()
    centers = {}
    for i in range(12):
        if i % 3 == 1:  # a mesh of one zero-area triangle: dropped at commit
            s.add_instance(s.add_mesh(np.zeros((3, 3), np.float32), np.array([[0, 1, 2]], np.int32)),
                           np.eye(4, dtype=np.float32))
            continue
        centers[i] = np.array([3.0 * (i % 4), 3.0 * (i // 4), 0.0], np.float32)
        s.add_instance(s.add_mesh(pos, tris, nrm, None, [m]), affine(np.eye(3), centers[i]))
    s.commit()
    st = s.stats()
    assert st["tlas_instances"] == 0 and st["dropped_triangles"] == 4  # one merged BLAS, traced directly
    rng = np.random.default_rng(3)
    expect, origins = [], []
    for i, c in centers.items():
        for _ in range(50):
            origins.append(c + np.array([*rng.uniform(-0.5, 0.5, 2), 5.0], np.float32))
            expect.append(i)
    origins = np.array(origins, np.float32)
    dirs = np.tile(np.array([0.0, 0.0, -1.0], np.float32), (len(origins), 1))
    t, prim, _, _, inst, row = s.intersect(origins, dirs, instances=True)
    assert (prim >= 0).all()
    np.testing.assert_array_equal(inst, expect)
    assert (row >= 0).all() and (row < len(tris)).all()
    # Without instances=True the batch skips the instance outputs; the four it returns are the same.
    plain = s.intersect(origins, dirs)
    assert len(plain) == 4
    for x, y in zip(plain, s.intersect(origins, dirs, instances=True)[:4]):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_instanced_hits_agree_with_merged(kind):
    mats = matrices(kind)
    o, d = random_rays(40_000, 3)
    res = {}
    for mode in MODES:
        s = build(mode, mats)
        s.commit()
        res[mode] = s.intersect(o, d, instances=True)
        st = s.stats()
        assert st["instances"] == 4
        assert st["triangles"] == 4 * st["blas_triangles"] if mode != "merged" else st["triangles"] == st["blas_triangles"]
        if mode == "merged":
            assert st["blases"] == 1 and st["tlas_instances"] == 0 and st["real_instances"] == 0
        else:
            assert st["blases"] == 1 and st["tlas_instances"] == 4 and st["real_instances"] == 4
        assert st["dynamic"] == (mode == "dynamic")
    assert_same_hits(res["merged"], res["shared"])
    assert_same_hits(res["merged"], res["dynamic"])
    # Instance ids name add_instance order; each instance is hit.
    t, prim, _, _, inst, row = res["shared"]
    assert set(inst[prim >= 0].tolist()) == {0, 1, 2, 3}
    assert (inst[prim < 0] == -1).all() and (row[prim < 0] == -1).all()


@pytest.mark.parametrize("tmax", [0.78, 0.85, 0.95])
def test_occluded_agrees_with_intersect_through_instances(tmax):
    s = build("shared", matrices("nonuniform"))
    s.commit()
    o, d = random_rays(40_000, 5)
    t, prim, _, _ = s.intersect(o, d, tmax)
    occ = s.occluded(o, d, tmax)
    hit = prim >= 0
    assert hit.sum() > 2000 and (~hit).sum() > 2000
    # Any-hit counts only hits certainly before tmax: every occluded ray has a closest hit, and
    # every hit clearly before tmax occludes.
    assert not (occ & ~hit).any()
    assert_clear_hits_occlude(occ, hit, t, tmax)


def assert_clear_hits_occlude(occ, hit, t, tmax):
    # "Certainly before tmax" is t plus the triangle test's error bound, which is scale-invariant
    # (the same for a ray and for it with its direction scaled) and grows for grazing hits: every
    # hit 1 % before tmax occludes, and all but a rare grazing one 0.01 % before it.
    assert occ[hit & (t < tmax * (1 - 1e-2))].all()
    near = hit & (t < tmax * (1 - 1e-4))
    assert (~occ[near]).sum() <= max(2, 1e-3 * near.sum()), f"{(~occ[near]).sum()} hits before tmax not found"


def test_ten_thousand_instances_cost_one_mesh_of_memory_and_match_the_flattened_scene():
    pos, tris, nrm = clean(*uv_sphere(0.3, nu=8, nv=4))
    rng = np.random.default_rng(1)
    n = 10_000
    mats = []
    for i in range(n):
        lin = rotation(i) * rng.uniform(0.5, 1.2)
        mats.append(affine(lin, (i % 100 - 49.5, i // 100 - 49.5, rng.uniform(-0.5, 0.5))))
    inst = pc.Scene()
    m = inst.add_material("m", (0.7, 0.7, 0.7))
    mesh = inst.add_mesh(pos, tris, nrm, None, [m])
    for mat in mats:
        inst.add_instance(mesh, mat)
    inst.add_sun_light((0.3, -0.4, 1.0), (3.0, 3.0, 3.0))
    inst.set_world_color((0.2, 0.2, 0.25))
    inst.set_camera(camera(pc, (0.0, -60.0, 40.0), (0.0, 0.0, 0.0), lens=35.0))
    inst.commit()
    one = pc.Scene()
    add_object(one, pos, tris, one.add_material("m"), nrm)
    one.commit()
    # Flattened: all instances' world vertices as one mesh (merged, no top level).
    M = np.stack(mats).astype(np.float64)
    world = (np.einsum("nij,vj->nvi", M[:, :3, :3], pos.astype(np.float64)) + M[:, None, :3, 3]).astype(np.float32)
    wn = np.einsum("nij,tcj->ntci", np.linalg.inv(M[:, :3, :3]).transpose(0, 2, 1), nrm.astype(np.float64))
    flat = pc.Scene()
    fm = flat.add_material("m", (0.7, 0.7, 0.7))
    flat_tris = (tris[None] + (np.arange(n) * len(pos))[:, None, None]).reshape(-1, 3)
    add_object(flat, world.reshape(-1, 3), flat_tris, fm, wn.reshape(-1, 3, 3).astype(np.float32))
    flat.add_sun_light((0.3, -0.4, 1.0), (3.0, 3.0, 3.0))
    flat.set_world_color((0.2, 0.2, 0.25))
    flat.set_camera(camera(pc, (0.0, -60.0, 40.0), (0.0, 0.0, 0.0), lens=35.0))
    flat.commit()

    si, s1, sf = inst.stats(), one.stats(), flat.stats()
    assert si["triangles"] == sf["triangles"] == n * s1["triangles"]
    assert si["blases"] == 1 and si["blas_triangles"] == s1["triangles"] and si["tlas_instances"] == n
    # One mesh's BVH plus a per-instance constant (top-level node, entry, transforms).
    assert si["bvh_bytes"] < 3 * s1["bvh_bytes"] + 400 * n, (si["bvh_bytes"], s1["bvh_bytes"])
    assert si["bvh_bytes"] < sf["bvh_bytes"] / 5
    assert si["geometry_bytes"] + si["bvh_bytes"] < (sf["geometry_bytes"] + sf["bvh_bytes"]) / 5

    rng = np.random.default_rng(2)
    o = np.c_[rng.uniform(-55, 55, (50_000, 2)), np.full(50_000, 20.0)].astype(np.float32)
    d = np.c_[rng.uniform(-0.3, 0.3, (50_000, 2)), -np.ones(50_000)].astype(np.float32)
    a = inst.intersect(o, d, instances=True)
    b = flat.intersect(o, d, instances=True)
    assert (a[1] >= 0).sum() > 5_000
    # The flat scene is one instance: its rows are the flattened ids, the instanced ids the same.
    tb, pb = b[0], b[1]
    b = (tb, pb, None, None, np.where(pb >= 0, pb // len(tris), -1), np.where(pb >= 0, pb % len(tris), -1))
    assert_same_hits(a, b)
    # The render: the same image to noise (the difference of two seeds of the flat one).
    img_i, _ = render(pc, inst, 32, 32, samples=16, seed=1)
    img_f, _ = render(pc, flat, 32, 32, samples=16, seed=1)
    img_f2, _ = render(pc, flat, 32, 32, samples=16, seed=2)
    noise = np.abs(region_means(img_f, 4) - region_means(img_f2, 4)).max()
    diff = np.abs(region_means(img_i, 4) - region_means(img_f, 4)).max()
    assert img_i[..., :3].mean() > 0.05
    assert diff <= 1.5 * noise + 1e-4, (diff, noise)


# ---------------------------------------------------------------- shading

def passes_image(mode, kind, program=None, passes=("Normal",)):
    def material(s):
        if program is None:
            return s.add_material("m", (0.6, 0.5, 0.4))
        return s.add_shader("m", program)
    s = build(mode, matrices(kind), material)
    s.set_world_color((0.0, 0.0, 0.0))
    if program is None:
        s.add_point_light((1.0, -3.0, 4.0), (40.0, 40.0, 40.0))
    s.set_camera(camera(pc, (0.3, -4.0, 3.0), (0.0, 0.0, 0.0), lens=24.0))
    sess_img = {}
    from core_scenes import run_session
    sess = run_session(pc, s, 40, 40, samples=4, seed=3, passes=list(passes), max_bounces=0)
    for p in passes:
        sess_img[p] = sess.film_pass(p)
    sess_img["Combined"] = sess.film()[..., :3]
    return sess_img


def assert_images_agree(a, b, what):
    diff = np.abs(a - b).max(-1)
    # Silhouette pixels may see slightly different coverage; the rest is the same to rounding.
    assert (diff > 2e-3).mean() < 0.02, f"{what}: {(diff > 2e-3).mean():.3f} of pixels differ"
    assert np.median(diff) < 1e-4, what


@pytest.mark.parametrize("kind", ["nonuniform", "mirrored"])
def test_shading_normals_and_texture_coordinates_agree_with_merged(kind):
    # Emission from uv, Object and Generated coordinates and the shading normal: one image each.
    progs = {
        "uv": [("uv", 0, 0), ("closure", "emission", None, {"color": 0})],
        "object": [("object", 0), ("vector_math", 1, 0, 0, 0, 0, "ABSOLUTE"),
                   ("closure", "emission", None, {"color": 1})],
        "generated": [("generated", 0), ("closure", "emission", None, {"color": 0})],
    }
    ref = {mode: passes_image(mode, kind) for mode in MODES}
    n = ref["merged"]["Normal"]
    assert (np.abs(n).sum(-1) > 0.5).mean() > 0.08  # the spheres are in view
    assert ref["merged"]["Combined"].max() > 0.05
    for mode in ("shared", "dynamic"):
        assert_images_agree(ref[mode]["Normal"], n, f"normals {mode}")
        assert_images_agree(ref[mode]["Combined"], ref["merged"]["Combined"], f"shading {mode}")
    for name, prog in progs.items():
        imgs = {mode: passes_image(mode, kind, prog, passes=())["Combined"] for mode in MODES}
        assert imgs["merged"].max() > 0.1, name
        for mode in ("shared", "dynamic"):
            assert_images_agree(imgs[mode], imgs["merged"], f"{name} {mode}")


def lamp_material(s):
    return s.add_material("lamp", (0.0, 0.0, 0.0), (12.0, 10.0, 8.0))


LAMPS = [affine(rotation(1) @ np.diag([0.3, 0.25, 0.2]), (-0.8, 0.3, 1.2)),
         affine(rotation(2) @ np.diag([-0.25, 0.3, 0.3]), (0.9, -0.2, 0.9))]


def lamp_scene(mode, lamps=LAMPS):
    """A floor lit only by instances of an emissive sphere under `lamps`, committed."""
    s = build(mode, lamps, lamp_material)
    floor = s.add_material("floor", (0.8, 0.8, 0.8))
    pos, tris = quad((-4, -4, 0), (8, 0, 0), (0, 8, 0))
    add_object(s, pos, tris, floor)
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, -5.0, 4.0), (0.0, 0.0, 0.3), lens=30.0))
    s.commit()
    return s


def emitter_scene(mode, use_nee=True, seed=1):
    """lamp_scene and its image."""
    s = lamp_scene(mode)
    img, _ = render(pc, s, 32, 32, samples=256, seed=seed, use_nee=use_nee)
    return s, img


@pytest.mark.converged  # (long; under the sanitizer cheaper tests run its code)
def test_instanced_emitters_light_the_scene_like_merged_ones_with_mis():
    s, merged = emitter_scene("merged")
    _, merged2 = emitter_scene("merged", seed=2)
    noise = np.abs(region_means(merged, 4) - region_means(merged2, 4)).max()
    assert merged[..., :3].mean() > 0.02
    for mode in ("shared", "dynamic"):
        si, img = emitter_scene(mode)
        assert si.stats()["emissive_triangles"] == s.stats()["emissive_triangles"] > 0
        diff = np.abs(region_means(img, 4) - region_means(merged, 4)).max()
        assert diff <= 2.0 * noise + 1e-4, (mode, diff, noise)
        mean_rel = img[..., :3].mean() / merged[..., :3].mean() - 1.0
        assert abs(mean_rel) < 0.02, (mode, mean_rel)
    # Next-event estimation against BSDF sampling alone on the instanced emitters: the same
    # expectation (pdf_emitter must be the pdf sample_direct samples with).
    _, nee = emitter_scene("dynamic")
    _, bsdf = emitter_scene("dynamic", use_nee=False)
    mean_rel = bsdf[..., :3].mean() / nee[..., :3].mean() - 1.0
    assert abs(mean_rel) < 0.03, mean_rel
    assert np.abs(region_means(bsdf, 2) - region_means(nee, 2)).max() < 0.1 * region_means(nee, 2).max()


# ---------------------------------------------------------------- live transform edits

def lit_scene(mode, mats):
    s = build(mode, mats)
    floor = s.add_material("floor", (0.8, 0.8, 0.8))
    pos, tris = quad((-4, -4, -1.5), (8, 0, 0), (0, 8, 0))
    add_object(s, pos, tris, floor)
    s.add_point_light((1.0, -2.0, 4.0), (60.0, 60.0, 60.0))
    s.set_world_color((0.05, 0.05, 0.05))
    s.set_camera(camera(pc, (0.5, -7.0, 4.0), (0.0, 0.0, 0.0), lens=35.0))
    return s


def test_moving_an_instance_in_dynamic_mode_rebuilds_only_the_top_level():
    mats = matrices("scaled")
    s = lit_scene("dynamic", mats)
    s.commit()
    before = render(pc, s, 24, 24, samples=8, seed=4)[0]
    st = s.stats()
    moved = affine(rotation(9) * 0.7, (0.3, 0.2, 0.5))
    s.set_instance_transform(2, moved)
    s.commit()
    st2 = s.stats()
    assert st2["geometry_builds"] == st["geometry_builds"]
    assert st2["top_level_builds"] == st["top_level_builds"] + 1
    assert st2["light_builds"] == st["light_builds"] + 1
    after = render(pc, s, 24, 24, samples=8, seed=4)[0]
    assert not np.array_equal(before, after)
    fresh = lit_scene("dynamic", mats[:2] + [moved] + mats[3:])
    fresh.commit()
    assert fresh.stats()["top_level_builds"] == 0
    expect = render(pc, fresh, 24, 24, samples=8, seed=4)[0]
    assert np.array_equal(after, expect)  # bit-identical: the same BLAS, top level and lights
    # Hits too, instance ids included.
    o, d = random_rays(5000, 8)
    assert all(np.array_equal(x, y) for x, y in zip(s.intersect(o, d, instances=True),
                                                    fresh.intersect(o, d, instances=True)))


def test_moving_a_merged_instance_rebuilds_the_geometry_and_equals_a_fresh_scene():
    mats = matrices("rotated")
    s = lit_scene("merged", mats)
    s.commit()
    g = s.stats()["geometry_builds"]
    moved = affine(rotation(4), (0.0, 0.5, 0.5))
    s.set_instance_transform(0, moved)
    s.commit()
    assert s.stats()["geometry_builds"] == g + 1 and s.stats()["top_level_builds"] == 0
    fresh = lit_scene("merged", [moved] + mats[1:])
    fresh.commit()
    assert np.array_equal(render(pc, s, 24, 24, samples=8, seed=4)[0], render(pc, fresh, 24, 24, samples=8, seed=4)[0])


def test_moving_an_instanced_emitter_moves_its_light():
    s, _ = emitter_scene("dynamic")
    g, lb = s.stats()["geometry_builds"], s.stats()["light_builds"]
    lamp = affine(rotation(1) @ np.diag([0.3, 0.25, 0.2]), (-0.8, 0.3, 2.5))  # LAMPS[0], higher
    s.set_instance_transform(0, lamp)
    s.commit()
    assert s.stats()["geometry_builds"] == g and s.stats()["light_builds"] == lb + 1
    moved = render(pc, s, 32, 32, samples=64, seed=1)[0]
    fresh = lamp_scene("dynamic", [lamp] + LAMPS[1:])
    assert np.array_equal(moved, render(pc, fresh, 32, 32, samples=64, seed=1)[0])


def test_dynamic_mode_switch_and_bad_edits():
    s = lit_scene("shared", matrices("rotated"))
    assert not s.dynamic
    s.commit()
    g = s.stats()["geometry_builds"]
    s.dynamic = True
    s.commit()
    assert s.stats()["geometry_builds"] == g + 1 and s.stats()["dynamic"]
    # The floor (used once) is a real instance now too.
    assert s.stats()["real_instances"] == 5 and s.stats()["tlas_instances"] == 5
    with pytest.raises((ValueError, IndexError)):
        s.set_instance_transform(99, np.eye(4, dtype=np.float32))
    with pytest.raises(ValueError):
        s.set_instance_transform(0, np.eye(3, dtype=np.float32))
    # A singular transform leaves that instance out (as flattening drops its zero-area triangles).
    flat = np.diag([1.0, 1.0, 0.0, 1.0]).astype(np.float32)
    s.set_instance_transform(1, flat)
    s.commit()
    assert s.stats()["real_instances"] == 4
    o, d = random_rays(20_000, 6)
    _, prim, _, _, inst, _ = s.intersect(o, d, instances=True)
    assert (prim >= 0).sum() > 1000 and not (inst == 1).any()
    img, st = render(pc, s, 16, 16, samples=4)
    assert np.isfinite(img).all() and st["nonfinite_samples"] == 0
    # The only instance singular: nothing to trace, nothing hit (no top level, no BLAS traced).
    lone = pc.Scene(dynamic=True)
    lone.add_instance(lone.add_mesh(*sphere_mesh()[:2]), flat)
    lone.commit()
    assert lone.stats()["real_instances"] == 0 and lone.stats()["triangles"] == 0
    assert (lone.intersect(o, d)[1] == -1).all() and not lone.occluded(o, d).any()
    lone.set_instance_transform(0, np.eye(4, dtype=np.float32))
    lone.commit()
    assert lone.stats()["top_level_builds"] == 1 and (lone.intersect(o, d)[1] >= 0).sum() > 1000


# ---------------------------------------------------------------- robustness through transforms

class _Scaled:
    """pc with Scene() returning a dynamic scene whose instances and camera are scaled/moved."""

    def __init__(self, scale, shift, dynamic):
        self.scale, self.shift, self.dyn = scale, shift, dynamic

    def __getattr__(self, name):
        return getattr(pc, name)

    def Scene(self):  # noqa: N802
        outer = self
        real = pc.Scene(dynamic=self.dyn)

        class Wrapped:
            def __getattr__(self, name):
                return getattr(real, name)

            def add_instance(self, mesh, matrix):
                t = np.eye(4)
                t[:3, :3] *= outer.scale
                t[:3, 3] = outer.shift
                return real.add_instance(mesh, (t @ np.asarray(matrix, np.float64)).astype(np.float32))

            def set_camera(self, cam):
                m = np.array(cam.matrix_world, np.float64)
                m[:3, 3] = outer.scale * m[:3, 3] + outer.shift
                cam.matrix_world = m.astype(np.float32)
                cam.clip_start *= outer.scale
                cam.clip_end *= outer.scale
                return real.set_camera(cam)

        w = Wrapped()
        w.real = real
        return w


@pytest.mark.parametrize("scale,shift", [(1e-3, 0.0), (1.0, 0.0), (1e3, 0.0), (1.0, 1e2)])
def test_cornell_box_in_dynamic_mode_is_the_merged_image_at_every_scale(scale, shift):
    """Every wall a real instance, traced through its transform: no acne, no light leaks, the
    same image as the merged box (same seed) within noise."""
    imgs = {}
    for dyn in (False, True):
        sc = cornell(_Scaled(scale, shift, dyn)).real
        sc.commit()
        assert sc.stats()["real_instances"] == (8 if dyn else 0)
        imgs[dyn], st = render(pc, sc, 32, 32, samples=128, seed=1)
        assert np.isfinite(imgs[dyn]).all() and st["nonfinite_samples"] == 0
    mean_rel = imgs[True][..., :3].mean() / imgs[False][..., :3].mean() - 1.0
    region = np.abs(region_means(imgs[True], 4) - region_means(imgs[False], 4)).max()
    assert abs(mean_rel) < 0.005 and region < 0.02, (mean_rel, region)


@pytest.mark.parametrize("scale,shift", [(1e-3, 0.0), (1.0, 0.0), (1e3, 0.0), (1.0, 1e3)])
def test_rays_at_shared_edges_of_an_instance_never_pass_through(scale, shift):
    from test_core import closed_icosphere
    pos, tris = closed_icosphere(3)
    m = affine(rotation(7) @ np.diag([1.0, 0.6, 1.3]) * scale, shift)
    s = pc.Scene(dynamic=True)
    s.add_instance(s.add_mesh(pos, tris, None, None, [s.add_material("m")]), m)
    s.commit()
    assert s.stats()["tlas_instances"] == 1
    M = m.astype(np.float64)
    world = pos.astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    edges = np.unique(np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), 1), axis=0)
    a, b = world[edges[:, 0]], world[edges[:, 1]]
    targets = np.concatenate([world, (a + b) * 0.5, a + (b - a) * 0.25]).astype(np.float32)
    rng = np.random.default_rng(11)
    inside = rng.uniform(-0.3, 0.3, (40, 3)) @ M[:3, :3].T + M[:3, 3]
    o = np.repeat(inside.astype(np.float32), len(targets), 0)
    d = np.tile(targets, (len(inside), 1)) - o
    t, prim, _, _ = s.intersect(o, d)
    assert (prim < 0).sum() == 0, f"{(prim < 0).sum()} of {len(o)} rays passed through"
    assert np.abs(t - 1.0).max() < 1e-3 + 1e-6 * abs(shift) / scale


# ---------------------------------------------------------------- the top level's cost (dynamic mode)

def _room_rays(n, shift, seed):
    """Rays from random points inside the Cornell box (moved by shift) in random directions:
    bounce-like rays, which cross several objects' boxes."""
    rng = np.random.default_rng(seed)
    o = np.stack([rng.uniform(-0.95, 0.95, n), rng.uniform(-0.95, 0.95, n), rng.uniform(0.05, 1.95, n)], 1) + shift
    return o.astype(np.float32), rng.normal(size=(n, 3)).astype(np.float32)


def test_dynamic_room_visits_few_more_nodes_than_the_merged_one():
    """The viewport's layout (every object its own BVH under the top level) against the final
    render's (one merged BVH), on a room whose objects all carry real transforms: BVH nodes
    visited per ray, a deterministic stand-in for the per-sample cost (build.py bench and
    tests/bench/callgrind_*.py --dynamic measure the time). The 8-wide top level holds the
    room's 8 objects in one node; the binary one visited about 7x the merged BVH's nodes."""
    shift = np.array([0.25, -0.5, 0.125])
    counts = {}
    for dyn in (False, True):
        s = cornell(_Scaled(1.0, shift, dyn)).real
        s.commit()
        assert s.stats()["real_instances"] == (8 if dyn else 0)
        o, d = _room_rays(20_000, shift, 5)
        xy = np.stack(np.meshgrid(np.arange(48) + 0.5, np.arange(48) + 0.5), -1).reshape(-1, 2).astype(np.float32)
        co, cd, ct = s.camera_rays(48, 48, xy)
        counts[dyn] = [s.traversal_counts(o, d), s.traversal_counts(co, cd, ct)]
        if dyn:
            assert (s.intersect(o, d)[1] >= 0).all()  # a closed room: every ray hits
    for (mn, mt), (dn, dt) in zip(counts[False], counts[True]):
        assert dn.mean() < 2.0 * mn.mean(), (dn.mean(), mn.mean())
        # Per-object boxes cull at least as well as the merged tree's leaves.
        assert dt.mean() <= mt.mean(), (dt.mean(), mt.mean())


def test_moves_to_and_from_identity_equal_a_fresh_scene():
    """An identity matrix skips the ray transform and a translation the matrix products, so
    moving an object onto or off them changes how it is traced; every state must still render
    and hit exactly as a scene built fresh with those matrices (a function of the matrices, not
    of the edits before)."""
    eye = np.eye(4, dtype=np.float32)
    mats = matrices("scaled")
    s = lit_scene("dynamic", mats)
    s.commit()
    g = s.stats()["geometry_builds"]
    o, d = random_rays(5000, 9)
    moved = affine(np.eye(3), (0.4, 0.1, -0.2))
    steps = [{1: eye, 2: moved}, {1: affine(rotation(3) * 0.5, (0.2, -0.4, 0.3)), 0: eye}, {0: mats[0], 3: eye, 2: mats[2]}]
    current = list(mats)
    for k, step in enumerate(steps):
        for i, m in step.items():
            s.set_instance_transform(i, m)
            current[i] = m
        s.commit()
        st = s.stats()
        assert st["geometry_builds"] == g and st["top_level_builds"] == k + 1
        fresh = lit_scene("dynamic", current)
        fresh.commit()
        assert fresh.stats()["top_level_builds"] == 0 and fresh.stats()["real_instances"] == st["real_instances"] == 5
        got, expect = s.intersect(o, d, instances=True), fresh.intersect(o, d, instances=True)
        assert all(np.array_equal(x, y) for x, y in zip(got, expect)), k
        assert set(got[4][got[1] >= 0].tolist()) >= {0, 1, 2, 3}
        assert np.array_equal(render(pc, s, 24, 24, samples=8, seed=4)[0], render(pc, fresh, 24, 24, samples=8, seed=4)[0]), k


def test_wide_top_level_over_many_lopsided_instances_agrees_with_merged():
    """Hundreds of instances at exponentially growing distances and sizes (lopsided SAH splits,
    a deep top level that falls back to halving by count) and a dense grid of small ones: the
    wide top level finds the merged BVH's hits, and occluded() agrees with intersect()."""
    pos, tris, nrm = clean(*uv_sphere(0.5, nu=8, nv=4))
    mats = []
    for i in range(300):
        r = 1.06 ** i
        mats.append(affine(rotation(i) * (0.2 * r), (r * np.cos(i), r * np.sin(i), 0.0)))
    for i in range(400):
        mats.append(affine(rotation(i + 7) * 0.1, (0.25 * (i % 20) - 2.4, 0.25 * (i // 20) - 2.4, 0.5)))
    res = {}
    for mode in ("merged", "dynamic"):
        s = build(mode, mats, mesh=(pos, tris, nrm, np.zeros((len(tris), 3, 2), np.float32)))
        s.commit()
        res[mode] = s
        assert s.stats()["tlas_instances"] == (700 if mode == "dynamic" else 0)
    rng = np.random.default_rng(4)
    for scale in (3.0, 40.0, 1e4):
        o = rng.normal(size=(6000, 3)) * scale
        o[:, 2] = np.abs(o[:, 2]) + 1.0
        target = rng.normal(size=(6000, 3)) * scale * 0.5
        target[:, 2] *= 0.01
        o, d = o.astype(np.float32), (target - o).astype(np.float32)
        a = res["dynamic"].intersect(o, d, instances=True)
        assert_same_hits(res["merged"].intersect(o, d, instances=True), a, min_hits=300)
        t, prim = a[0], a[1]
        occ = res["dynamic"].occluded(o, d, 1.0)
        assert not (occ & ~(prim >= 0)).any()
        assert_clear_hits_occlude(occ, prim >= 0, t, 1.0)


def test_forest_of_overlapping_instances_agrees_with_merged_for_camera_and_sun_rays():
    """The realistic bench's instanced forest in small: a grid of spheres whose world boxes
    overlap (rays enter several top-level children and instances at once, nearest first) on a
    ground plane, traced by grazing camera rays and by shadow rays from the ground and the
    crowns towards one sun direction. The top level finds the merged BVH's closest hits, and
    occluded() agrees with intersect() for the shadow rays."""
    pos, tris, nrm = clean(*uv_sphere(0.35, nu=16, nv=8))
    rng = np.random.default_rng(11)
    mats = [affine(rotation(i) * rng.uniform(0.6, 1.3), (0.55 * (i % 8) - 1.9, 0.55 * (i // 8) - 1.9, 0.0))
            for i in range(64)]
    ground = quad((-6.0, -6.0, -0.3), (12.0, 0.0, 0.0), (0.0, 12.0, 0.0))
    res = {}
    for mode in ("merged", "shared"):
        s = build(mode, mats, mesh=(pos, tris, nrm, np.zeros((len(tris), 3, 2), np.float32)))
        add_object(s, *ground, s.add_material("g", (0.3, 0.3, 0.2)))
        s.commit()
        res[mode] = s
        assert s.stats()["tlas_instances"] == (65 if mode == "shared" else 0)
    # Camera rays from low over the forest, across it.
    n = 20_000
    o = np.c_[rng.uniform(-3.0, 3.0, n), np.full(n, -6.0), rng.uniform(0.2, 2.0, n)].astype(np.float32)
    target = np.c_[rng.uniform(-2.5, 2.5, n), rng.uniform(-2.5, 2.5, n), rng.uniform(-0.3, 0.4, n)]
    d = (target - o).astype(np.float32)
    cam = res["shared"].intersect(o, d, instances=True)
    assert_same_hits(res["merged"].intersect(o, d, instances=True), cam, min_hits=n // 2)
    assert len(set(cam[4][cam[1] >= 0].tolist())) > 40  # most trees seen, nearest ones first
    # Shadow rays towards the sun from the camera rays' hits (ground and crowns), lifted off
    # the surface along the ray a little.
    t, prim = cam[0], cam[1]
    hit = prim >= 0
    p = o[hit] + d[hit] * (t[hit, None] * (1.0 - 1e-4))
    sun = np.array([0.8, -0.5, 0.4])  # low: long shadows across the trees
    sd = np.broadcast_to(sun / np.linalg.norm(sun) * 10.0, p.shape).astype(np.float32)
    p = p.astype(np.float32)
    for mode in ("merged", "shared"):
        ts, ps = res[mode].intersect(p, sd, 1.0)[:2]
        occ = res[mode].occluded(p, sd, 1.0)
        assert 0.1 < occ.mean() < 0.9
        assert not (occ & ~(ps >= 0)).any()
        assert_clear_hits_occlude(occ, ps >= 0, ts, 1.0)
    shadow = [res[m].occluded(p, sd, 1.0) for m in ("merged", "shared")]
    assert (shadow[0] != shadow[1]).mean() < 1e-3


@pytest.mark.parametrize("shift", [3e3, -2e4])
def test_rays_leaving_an_instance_far_from_the_origin_do_not_hit_it_again(shift):
    """Rays spawned at a far-off instanced sphere's hits (world points, not lifted off the
    surface: half lie just inside it), leaving it (mirrored about the normal). The ray carried
    into object space is moved past its transform's rounding error (pbrt-v4), which at this
    distance also covers the points' own rounding: the instance rarely hits itself again,
    where the merged copy (world space, no transform to move past) does for about half."""
    pos, tris, nrm = clean(*uv_sphere(1.0, nu=32, nv=16))
    mats = [affine(rotation(3) * 2.5, (shift + 4.0 * i, 0.5 * shift, 0.0)) for i in range(2)]
    rng = np.random.default_rng(12)
    n = 20_000
    res = {}
    for mode in ("shared", "merged"):
        s = build(mode, mats, mesh=(pos, tris, nrm, np.zeros((len(tris), 3, 2), np.float32)))
        s.commit()
        c = np.array([shift, 0.5 * shift, 0.0])
        o = (c + rng.normal(size=(n, 3)) * [1.0, 6.0, 6.0] - [8.0, 0.0, 0.0]).astype(np.float32)
        target = c + rng.uniform(-2.2, 2.2, (n, 3))
        d = (target - o).astype(np.float32)
        t, prim, _, _, inst, _ = s.intersect(o, d, instances=True)
        hit = prim >= 0
        assert hit.sum() > n // 3
        p = (o[hit].astype(np.float64) + d[hit] * t[hit, None]).astype(np.float32)
        centre = np.array([mats[k][:3, 3] for k in inst[hit]], np.float64)
        nn = p - centre
        nn /= np.linalg.norm(nn, axis=1)[:, None]
        dd = d[hit] / np.linalg.norm(d[hit], axis=1)[:, None]
        r = (dd - 2.0 * np.sum(dd * nn, 1)[:, None] * nn).astype(np.float32)  # away from the sphere
        t2, prim2, _, _, inst2, _ = s.intersect(p, r, instances=True)
        again = (prim2 >= 0) & (inst2 == inst[hit]) & (t2 < 1e-2)
        res[mode] = again.mean()
    assert res["merged"] > 0.2, res  # the rays do start inside often
    assert res["shared"] < 0.05 and res["shared"] < 0.1 * res["merged"], res
