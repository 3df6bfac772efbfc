"""Numerical stress of the compiled core (issue 7): the same image at every scene scale, the
float32 limit far from the origin (measured, with xfails documenting it), no shadow acne,
self-intersection and watertightness over millions of rays, nearly touching surfaces,
degenerate shading input that must neither create energy nor produce NaN/Inf, and
determinism. Every render is tiny; the whole file runs in a few seconds.

Float32 limits measured on the 2-unit Cornell box (32x32, 128 spp, same seed) with the core's
error-bound ray offsets (pbrt-v4 style, commit 58b10d8); "noise" is the difference between two
seeds: worst 8x8-pixel region mean 0.012, image mean 0.2 %:
  scale      1e-4 .. 1e6: identical to 0.03 % (1e-5: +0.8 %, a region 0.024 off)
  translated 1e2 .. 1e3: within noise (worst region 0.002)
             1e4: mean -0.25 %, a region 0.013 off      (passes)
             3e4: mean -1.3 %, a region 0.044 off       (failed until light samples of emissive
                  triangles were taken in solid angle: now mean -0.27 %, a region 0.013 off,
                  passes: the limit; with area sampling it is still -1.1 %, a region 0.035 off)
             1e5: mean -3 %, a region 0.063 off         (fails; -2.8 %, 0.050 with solid angle)
             1e6: mean -24 %, broken
So geometry stays right while its features (here the light's 0.02 gap under the ceiling) are
larger than ~1e-6 x their distance from the origin (float32's relative error bound gamma(7) ~ 4e-7).
Before that commit the limits were 1e-3 .. 1e5 in scale and ~3e2 in translation.
The furnace (convex) stays exact to 0.1 % everywhere: its rays never come back to a surface.
"""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, cornell, look_at_matrix, quad, random_rotation, region_means, render, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


# ---------------------------------------------------------------- helpers

def transform(scale=1.0, shift=0.0, rotation=None):
    """Object-to-world float32 matrix: rotate, then scale, then translate by `shift` (all axes)."""
    m = np.eye(4)
    r = np.eye(3) if rotation is None else np.asarray(rotation, float)
    m[:3, :3] = scale * r
    m[:3, 3] = shift
    return m.astype(np.float32)


def move_camera(cam, scale, shift, rotation=None):
    """The camera of a scene scaled/translated like its geometry (Blender ignores camera scale)."""
    m = np.array(cam.matrix_world, np.float64)
    r = np.eye(3) if rotation is None else np.asarray(rotation, float)
    m[:3, :3] = r @ m[:3, :3]
    m[:3, 3] = scale * (r @ m[:3, 3]) + shift
    cam.matrix_world = m.astype(np.float32)
    cam.clip_start *= scale
    cam.clip_end *= scale
    return cam


class _TransformedScene:
    """A pc.Scene whose instances and camera are scaled and translated on the way in, so that
    the builders of core_scenes.py (cornell) build the same scene anywhere."""

    def __init__(self, scale, shift):
        self.real, self.scale, self.shift = pc.Scene(), scale, shift

    def __getattr__(self, name):
        return getattr(self.real, name)

    def add_instance(self, mesh, matrix):
        m = transform(self.scale, self.shift).astype(np.float64) @ np.asarray(matrix, np.float64)
        return self.real.add_instance(mesh, m.astype(np.float32))

    def set_camera(self, cam):
        return self.real.set_camera(move_camera(cam, self.scale, self.shift))


class _TransformedCore:
    def __init__(self, scale, shift):
        self.scale, self.shift = scale, shift

    def __getattr__(self, name):
        return getattr(pc, name)

    def Scene(self):  # noqa: N802 (the module's class name)
        return _TransformedScene(self.scale, self.shift)


def cornell_at(scale=1.0, shift=0.0):
    return cornell(_TransformedCore(scale, shift)).real


def furnace_at(scale=1.0, shift=0.0, albedo=0.8, normals="smooth", nu=32, nv=16):
    s = pc.Scene()
    m = s.add_material("sphere", (albedo,) * 3)
    pos, tris, nrm = uv_sphere(1.0, nu=nu, nv=nv)
    if isinstance(normals, str):
        normals = nrm if normals == "smooth" else None
    add_object(s, pos, tris, m, normals, matrix=transform(scale, shift))
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(move_camera(camera(pc, (0.0, -5.0, 0.0), (0.0, 0.0, 0.0)), scale, shift))
    return s


def film_is_clean(img, stats):
    assert np.isfinite(img).all(), "NaN/Inf in the film"
    assert img.min() >= 0.0, f"negative film value {img.min()}"
    assert stats["nonfinite_samples"] == 0, stats["nonfinite_samples"]


# ---------------------------------------------------------------- 1. scale and translation

BOX_RES, BOX_SPP = 32, 128
_box_ref = {}


def box_reference():
    if not _box_ref:
        _box_ref["img"], _ = render(pc, cornell_at(), BOX_RES, BOX_RES, samples=BOX_SPP, seed=1)
    return _box_ref["img"]


def assert_same_box_image(img, stats):
    """Same seed, same image within noise: the image mean within 0.5 % and every 8x8-pixel
    region mean within 0.02 (1.7 x the seed-to-seed difference of this render)."""
    film_is_clean(img, stats)
    ref = box_reference()
    mean_rel = img[..., :3].mean() / ref[..., :3].mean() - 1.0
    region = np.abs(region_means(img, 4) - region_means(ref, 4)).max()
    assert abs(mean_rel) < 0.005 and region < 0.02, f"image mean {mean_rel:+.4f}, worst region {region:.4f}"


@pytest.mark.parametrize("scale", [1e-4, 1e-2, 1.0, 1e2, 1e4, 1e5])
def test_white_furnace_is_the_same_image_at_every_scale(scale):
    ref, _ = render(pc, furnace_at(), 32, 32, samples=32, seed=1)
    img, stats = render(pc, furnace_at(scale), 32, 32, samples=32, seed=1)
    film_is_clean(img, stats)
    assert abs(img[12:20, 12:20, :3].mean() - 0.8) < 0.01  # the analytic furnace value
    assert abs(img[..., :3].mean() - ref[..., :3].mean()) < 1e-3
    assert np.abs(region_means(img, 4) - region_means(ref, 4)).max() < 3e-3


@pytest.mark.parametrize("shift", [1e2, 1e4, 1e5])
def test_white_furnace_far_from_the_origin(shift):
    # Convex: a ray leaving the sphere never meets it again, so only the camera and the hit
    # points lose precision, and the image stays right even at 1e5.
    ref, _ = render(pc, furnace_at(), 32, 32, samples=32, seed=1)
    img, stats = render(pc, furnace_at(shift=shift), 32, 32, samples=32, seed=1)
    film_is_clean(img, stats)
    assert abs(img[12:20, 12:20, :3].mean() - 0.8) < 0.01
    assert np.abs(region_means(img, 4) - region_means(ref, 4)).max() < 3e-3


@pytest.mark.parametrize("scale", [1e-4, 1e-3, 1e-2, 1e2, 1e4, 1e5, 1e6])
def test_cornell_box_is_the_same_image_at_every_scale(scale):
    img, stats = render(pc, cornell_at(scale), BOX_RES, BOX_RES, samples=BOX_SPP, seed=1)
    assert_same_box_image(img, stats)


FAR_REASON = (
    "float32 limit (measured, see the module docstring): at 1e5 units from the origin a point's "
    "rounding error bound gamma(7)|p| ~ 0.04 exceeds the box's 0.02 light gap under the "
    "ceiling: image mean -2.8 % at 1e5 (noise 0.2 %). Correct within noise up to 3e4 "
    "units for this 2-unit box, i.e. features must exceed ~1e-6 x their distance from the origin")


@pytest.mark.parametrize("shift", [
    1e2, 1e3, 1e4, 3e4,
    pytest.param(1e5, marks=pytest.mark.xfail(reason=FAR_REASON, strict=True))])
def test_cornell_box_translated_far_from_the_origin(shift):
    img, stats = render(pc, cornell_at(shift=shift), BOX_RES, BOX_RES, samples=BOX_SPP, seed=1)
    assert_same_box_image(img, stats)


def test_cornell_box_far_away_still_renders_cleanly():
    # Beyond the precision limit the image is wrong, but never NaN, Inf or negative.
    for shift in (1e5, 1e6, 1e7):
        img, stats = render(pc, cornell_at(shift=shift), 16, 16, samples=4, seed=1)
        film_is_clean(img, stats)


# ---------------------------------------------------------------- shadow acne

def grid(n, half):
    """An n x n grid of quads spanning [-half, half]^2 at z = 0 (2 n^2 triangles, shared vertices)."""
    g = np.linspace(-half, half, n + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1).astype(np.float32)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    b, c, d = a + (n + 1), a + (n + 2), a + 1
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    return pos, tris


ACNE_W, ACNE_H = 32, 4.0  # image size; camera height over the plane
ACNE_LIGHT = np.array([0.9, -0.6, 3.0])
ACNE_ALBEDO = 0.5


def acne_expected():
    """The analytic radiance of each pixel centre (point light, Lambertian plane, straight-down
    camera: Blender's 50 mm lens on a 36 mm sensor), row 0 = bottom."""
    half = 0.5 * 36.0 / 50.0 * ACNE_H
    c = -half + (np.arange(ACNE_W) + 0.5) * (2 * half / ACNE_W)
    X, Y = np.meshgrid(c, c)  # rows follow y: row 0 is the bottom
    d = ACNE_LIGHT[None, None] - np.stack([X, Y, np.zeros_like(X)], -1)
    r2 = (d ** 2).sum(-1)
    return ACNE_ALBEDO / np.pi * d[..., 2] / np.sqrt(r2) / r2  # unit intensity


@pytest.mark.parametrize("scale,shift", [(1e-4, 0.0), (1e-2, 0.0), (1.0, 0.0), (1e2, 0.0), (1e4, 0.0),
                                         (1e5, 0.0), (1.0, 1e4), (1.0, 1e5)])
def test_no_shadow_acne_on_a_lit_plane(scale, shift):
    rot = random_rotation(3)  # an oblique plane: its points are never exactly representable
    s = pc.Scene()
    m = s.add_material("plane", (ACNE_ALBEDO,) * 3)
    pos, tris = grid(16, 2.0)
    add_object(s, pos, tris, m, matrix=transform(scale, shift, rot))
    light = scale * (rot @ ACNE_LIGHT) + shift
    s.add_point_light(light, (scale * scale,) * 3)  # the same irradiance at every scale
    cam = pc.Camera()
    cm = np.eye(4, dtype=np.float32)
    cm[2, 3] = ACNE_H
    cam.matrix_world = cm
    s.set_camera(move_camera(cam, scale, shift, rot))
    img, stats = render(pc, s, ACNE_W, ACNE_W, samples=4, max_bounces=0)
    film_is_clean(img, stats)
    exp = acne_expected()
    ratio = img[..., 0] / exp
    dark = (ratio < 0.5).mean()
    assert dark == 0.0, f"{dark:.1%} of the pixels are speckled (below half the analytic value)"
    assert abs(ratio.mean() - 1.0) < 0.02, ratio.mean()


# ---------------------------------------------------------------- 2. self-intersection

def triangle_soup(kind, n, rng):
    """n disjoint triangles of one kind, each in its own cell of a lattice (float32)."""
    cells = np.stack(np.meshgrid(*[np.arange(int(np.ceil(n ** (1 / 3))))] * 3, indexing="ij"), -1).reshape(-1, 3)[:n]
    if kind == "tiny":        # 1e-4 across, 1e-2 apart, near the origin
        size, spacing, base = 1e-4, 1e-2, 0.0
    elif kind == "tiny_far":  # 1e-2 across, far away
        size, spacing, base = 1e-2, 1.0, 1e3
    elif kind == "huge":      # 1e4 across
        size, spacing, base = 1e4, 3e4, 0.0
    elif kind == "unit_far":
        size, spacing, base = 1.0, 3.0, 1e4
    elif kind == "sliver":    # 10 long, 1e-3 wide (aspect 1e4), up to ~400 units out
        size, spacing, base, width = 10.0, 30.0, 0.0, 1e-3
    elif kind == "needle":    # 1 long, 1e-5 wide (aspect 1e5), within 10 units of the origin
        size, spacing, base, width = 1.0, 1.5, -9.0, 1e-5
    elif kind == "thin":      # 10 long, 1e-1 wide (aspect 100)
        size, spacing, base, width = 10.0, 30.0, 0.0, 1e-1
    centers = base + cells * spacing + rng.uniform(0, 0.2 * spacing, (n, 3))
    if kind in ("sliver", "needle", "thin"):
        # Long and thin, randomly oriented.
        a = rng.normal(size=(n, 3))
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        b = np.cross(a, rng.normal(size=(n, 3)))
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        v = np.stack([centers, centers + size * a, centers + 0.5 * size * a + width * b], 1)
    else:
        v = centers[:, None, :] + rng.normal(size=(n, 3, 3)) * size
    pos = v.reshape(-1, 3).astype(np.float32)
    return pos, np.arange(3 * n, dtype=np.int32).reshape(n, 3)


def spawn_rays(scene, pos, tris, n_rays, rng):
    """Rays found the way the integrator finds them: shoot at the triangles, rebuild each hit
    point from its barycentrics in float32 (as the core does), offset it with the core's rule to
    a random side and leave in a random direction of that side (half of them grazing).
    Returns (origins, directions, prim of the hit) of the new rays."""
    v = pos[tris]  # (T, 3, 3)
    k = rng.integers(0, len(tris), n_rays)
    b = rng.uniform(0.02, 0.98, (n_rays, 2))
    flip = b.sum(1) > 1
    b[flip] = 1 - b[flip]
    aim = (v[k, 0] * (1 - b[:, :1] - b[:, 1:]) + v[k, 1] * b[:, :1] + v[k, 2] * b[:, 1:])
    ng = np.cross(v[k, 1].astype(np.float64) - v[k, 0], v[k, 2].astype(np.float64) - v[k, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    side = np.where(rng.uniform(size=n_rays) < 0.5, 1.0, -1.0)[:, None]
    span = np.linalg.norm(v[k, 1] - v[k, 0], axis=1, keepdims=True)
    org = (aim + ng * side * span * 0.5).astype(np.float32)
    t, prim, b1, b2 = scene.intersect(org, (aim - org).astype(np.float32))
    ok = prim >= 0
    prim, b1, b2 = prim[ok], b1[ok][:, None], b2[ok][:, None]
    hv = v[prim]
    one = np.float32(1)
    p = hv[:, 0] * (one - b1 - b2) + hv[:, 1] * b1 + hv[:, 2] * b2  # float32, the core's order
    n = np.cross(hv[:, 1] - hv[:, 0], hv[:, 2] - hv[:, 0])
    n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
    n *= np.where(rng.uniform(size=len(n)) < 0.5, one, -one)[:, None]
    d = rng.normal(size=(len(n), 3)).astype(np.float32)
    d *= np.sign((d * n).sum(1))[:, None]
    half = len(d) // 2  # grazing: almost tangent, still on the offset side
    d[:half] -= n[:half] * ((d[:half] * n[:half]).sum(1) * np.float32(0.9999))[:, None]
    return offset(p, n, hv, b1, b2), d, prim


def offset(p, n, hv, b1, b2):
    """pc.offset_ray_origin with the error bound the integrator passes for a point interpolated
    on triangle hv (T, 3, 3) at barycentrics b1, b2 (columns): gamma(7) sum |b_i v_i|."""
    b0 = np.float32(1) - b1 - b2
    err = (np.abs(hv[:, 0] * b0) + np.abs(hv[:, 1] * b1) + np.abs(hv[:, 2] * b2)) * np.float32(pc.barycentric_error_bound())
    return pc.offset_ray_origin(p, n, err.astype(np.float32))


KINDS = ["tiny", "tiny_far", "huge", "unit_far", "thin", "sliver", "needle"]


@pytest.mark.parametrize("kind", KINDS)
def test_spawned_rays_never_rehit_their_triangle(kind):
    rng = np.random.default_rng(sum(map(ord, kind)))
    pos, tris = triangle_soup(kind, 2000, rng)
    s = pc.Scene()
    add_object(s, pos, tris, s.add_material("m"))
    s.commit()
    assert s.stats()["dropped_triangles"] == 0  # so prim ids are the rows of `tris`
    o, d, own = spawn_rays(s, pos, tris, 400_000, rng)
    assert len(own) > 300_000  # most aimed rays found their triangle
    _, prim, _, _ = s.intersect(o, d)
    rehit = (prim == own).sum()
    assert rehit == 0, f"{rehit} of {len(own)} spawned rays re-hit the triangle they left ({kind})"


def world_vertices(pos, matrix):
    """Vertices as Scene.commit transforms them (float32 row-by-row dot products)."""
    m = np.asarray(matrix, np.float32)
    return (pos[:, :1] * m[:3, 0] + pos[:, 1:2] * m[:3, 1] + pos[:, 2:3] * m[:3, 2] + m[:3, 3]).astype(np.float32)


def surface_points(scene, wv, tris, origins, targets):
    """Hit points of rays origins -> targets rebuilt the integrator's way: from the barycentrics
    in float32, with the float32 geometric normal of the hit triangle. wv/tris: all triangles in
    scene order (no triangle dropped)."""
    t, prim, b1, b2 = scene.intersect(origins.astype(np.float32), (targets - origins).astype(np.float32))
    assert (prim >= 0).all()
    hv = wv[tris[prim]]
    b1, b2 = b1[:, None], b2[:, None]
    p = hv[:, 0] * (np.float32(1) - b1 - b2) + hv[:, 1] * b1 + hv[:, 2] * b2
    ng = np.cross(hv[:, 1] - hv[:, 0], hv[:, 2] - hv[:, 0])
    ng = (ng / np.linalg.norm(ng, axis=1, keepdims=True)).astype(np.float32)
    return p, ng, (hv, b1, b2)


SHADOW_EPSILON = 1e-4  # the integrator's shadow rays to surface points end at t = 1 - 1e-4


def facing_shadow_rays(scale):
    """Two parallel oblique grids 1e-4 x their size apart, facing each other, and shadow rays
    between points on the facing sides, each end offset towards the other as the integrator
    does. Half the pairs are close laterally (steep rays), half anywhere (grazing rays).
    Returns (scene, origins, directions, cos at both ends)."""
    rng = np.random.default_rng(int(np.log10(scale)) + 10)
    rot = random_rotation(int(np.log10(scale)) + 20)
    gap = 1e-4 * 2.0  # relative to the 2-unit grids
    s = pc.Scene()
    m = s.add_material("m")
    pos, tris = grid(8, 1.0)
    lower = transform(scale, 0.0, rot)
    upper = (lower.astype(np.float64) @ transform(1.0, (0.0, 0.0, gap))).astype(np.float32)
    add_object(s, pos, tris, m, matrix=lower)
    add_object(s, pos, tris, m, matrix=upper)
    s.commit()
    wv = np.concatenate([world_vertices(pos, lower), world_vertices(pos, upper)])
    all_tris = np.concatenate([tris, tris + len(pos)])
    n = 300_000
    nz = rot @ [0.0, 0.0, 1.0]
    la = rng.uniform(-0.95, 0.95, (n, 2))
    lb = rng.uniform(-0.95, 0.95, (n, 2))
    lb[: n // 2] = np.clip(la[: n // 2] + rng.uniform(-5, 5, (n // 2, 2)) * gap, -0.95, 0.95)
    a = (np.c_[la, np.zeros(n)] * scale) @ rot.T
    b = (np.c_[lb, np.full(n, gap)] * scale) @ rot.T
    pa, na, ea = surface_points(s, wv, all_tris, a - nz * scale, a)      # lower surface from below
    pb, nb, eb = surface_points(s, wv, all_tris, b + nz * scale, b)      # upper surface from above
    na *= np.sign(na @ nz)[:, None].astype(np.float32)                   # facing up, towards b
    nb *= -np.sign(nb @ nz)[:, None].astype(np.float32)                  # facing down, towards a
    o = offset(pa, na, *ea)
    d = offset(pb, nb, *eb) - o
    u = d.astype(np.float64) / np.linalg.norm(d.astype(np.float64), axis=1, keepdims=True)
    return s, o, d, np.abs(u @ nz)


@pytest.mark.parametrize("scale", [1e-4, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3, 1e4])
def test_shadow_rays_between_nearly_touching_surfaces_are_not_blocked(scale):
    s, o, d, cos = facing_shadow_rays(scale)
    blocked = s.occluded(o, d, 1.0 - SHADOW_EPSILON)
    steep = cos > 1e-2
    assert steep.sum() > 100_000 and (~steep).sum() > 100_000
    assert blocked[steep].sum() == 0, f"{blocked[steep].sum()} of {steep.sum()} steep shadow rays falsely blocked"
    # Grazing ones carry cos_a * cos_b of the energy: what is lost must be negligible.
    lost = (cos[blocked] ** 2).sum() / (cos ** 2).sum()
    assert lost < 1e-6, f"{blocked.sum()} falsely blocked shadow rays lose {lost:.2e} of the energy"


# Grazing shadow rays (cosine <= 3.5e-4 at both ends) used to be blocked at t in [0.99978, 0.9999)
# by the target's own surface: the fixed shadow epsilon (1e-4 of the length) is shorter than the
# triangle test's t error there, which grows as 1 / cos. Any-hit traversal now counts a hit only
# when t plus its error bound is below tmax. Repro of the old failure (scale 1): triangle
# (-0.21469665, -0.25235566, -0.12337753), (-0.24731885, -0.036481887, -0.0015813475),
# (-1.3284622e-05, 9.6533637e-05, -0.00017465616); occluded(o=(-0.26817152, -0.58716506,
# -0.30413288), d=(0.14367548, 0.5319505, 0.28285575), tmax=1-1e-4) was True.
@pytest.mark.parametrize("scale", [1e-4, 1e-2, 1.0, 1e2, 1e3, 1e4])
def test_no_grazing_shadow_ray_between_nearly_touching_surfaces_is_blocked(scale):
    s, o, d, cos = facing_shadow_rays(scale)
    blocked = s.occluded(o, d, 1.0 - SHADOW_EPSILON)
    assert blocked.sum() == 0, f"{blocked.sum()} of {len(o)} shadow rays falsely blocked (max cos {cos[blocked].max():.1e})"


# ---------------------------------------------------------------- watertightness

def icosphere(subdiv):
    from test_core import closed_icosphere
    return closed_icosphere(subdiv)


@pytest.mark.parametrize("scale,shift", [(1e-3, 0.0), (1.0, 0.0), (1e3, 0.0), (1.0, 1e3), (1e-2, 1e2),
                                         (1.0, 1e5), (1e4, 1e5)])
def test_rays_at_shared_edges_and_vertices_never_pass_through(scale, shift):
    pos, tris = icosphere(3)
    rot = random_rotation(7)
    world = (((pos.astype(np.float64) @ rot.T) * scale) + shift).astype(np.float32)
    s = pc.Scene()
    add_object(s, world, tris, s.add_material("m"))
    s.commit()
    edges = np.unique(np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), 1), axis=0)
    a, b = world[edges[:, 0]], world[edges[:, 1]]
    targets = np.concatenate([world, (a + b) * np.float32(0.5),                       # vertices, midpoints
                              a + (b - a) * np.float32(0.25), a + (b - a) * np.float32(0.9)])
    rng = np.random.default_rng(11)
    # From inside: the sphere's centre and random points; from outside: random points further out.
    inside = rng.uniform(-0.4, 0.4, (60, 3))
    inside[0] = 0.0
    outside = rng.normal(size=(60, 3))
    outside *= (rng.uniform(1.5, 4.0, 60) / np.linalg.norm(outside, axis=1))[:, None]
    radial = targets.astype(np.float64) - shift
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    for origins, name in ((inside, "inside"), (outside, "outside")):
        org = ((origins * scale) + shift).astype(np.float32)
        o = np.repeat(org, len(targets), 0)
        d = np.tile(targets, (len(org), 1)) - o
        if name == "outside":
            # Only targets clearly on the near or the far side: a ray grazing the silhouette
            # may touch it or not, but a ray that meets the surface must not slip through it.
            dn = d.astype(np.float64) / np.linalg.norm(d.astype(np.float64), axis=1, keepdims=True)
            facing = (dn * np.tile(radial, (len(org), 1))).sum(1)
            near, far = facing < -0.2, facing > 0.2
            keep = near | far
            o, d, near = o[keep], d[keep], near[keep]
        t, prim, _, _ = s.intersect(o, d)
        miss = prim < 0
        assert miss.sum() == 0, f"{miss.sum()} of {len(o)} rays from {name} passed through (scale {scale}, shift {shift})"
        tol = 1e-3 + 1e-6 * abs(shift) / scale
        if name == "inside":  # nothing else in the way: the hit is at the aimed point
            assert np.abs(t - 1.0).max() < tol
        else:                 # at the aimed point on the near side, before it for the far side
            assert np.abs(t[near] - 1.0).max() < tol
            # (the near side is met first, at least 2 * 0.2 * radius / |d| >= 0.08 earlier)
            assert t[~near].max() < 0.98


# ---------------------------------------------------------------- 3. degenerate shading

def bent_normals(kind, tris_count, rng, pos=None, tris=None):
    """Per-corner normals of one hostile kind, float32 (T, 3, 3)."""
    if kind == "random":      # anything, mostly far from the geometric normal
        n = rng.normal(size=(tris_count, 3, 3))
    elif kind == "flipped":   # all pointing into the surface (back-facing shading normals)
        p = pos[tris].astype(np.float64)
        n = -p / np.linalg.norm(p, axis=2, keepdims=True)
    elif kind == "tangent":   # bent just below the surface
        p = pos[tris].astype(np.float64)
        radial = p / np.linalg.norm(p, axis=2, keepdims=True)
        tangent = np.cross(radial, rng.normal(size=radial.shape))
        tangent /= np.linalg.norm(tangent, axis=2, keepdims=True)
        n = tangent - 0.05 * radial
    elif kind == "zero":
        n = np.zeros((tris_count, 3, 3))
    elif kind == "nan":
        n = rng.normal(size=(tris_count, 3, 3))
        n[::2, 1] = np.nan
        n[1::3, 2, 0] = np.inf
    elif kind == "huge":
        n = rng.normal(size=(tris_count, 3, 3)) * 1e37  # finite, but |n|^2 overflows
    elif kind == "denormal":
        n = rng.normal(size=(tris_count, 3, 3)) * 1e-42
    return n.astype(np.float32)


@pytest.mark.parametrize("kind", ["random", "flipped", "tangent", "zero", "nan", "huge", "denormal"])
def test_bent_corner_normals_never_create_energy(kind):
    # Furnace with albedo 1 and a constant world 1: every path carries at most 1, whatever the
    # shading normals, so every pixel is <= 1 and the sphere is never brighter than the world.
    rng = np.random.default_rng(5)
    pos, tris, _ = uv_sphere(1.0, nu=32, nv=16)
    normals = bent_normals(kind, len(tris), rng, pos, tris)
    s = furnace_at(albedo=1.0, normals=normals)
    img, stats = render(pc, s, 24, 24, samples=16)
    film_is_clean(img, stats)
    assert img[..., :3].max() <= 1.0 + 1e-5, img[..., :3].max()
    centre = img[8:16, 8:16, :3].mean()
    if kind == "flipped":
        # Normals into the sphere: their diffuse lobes are lit from inside, so the sphere is
        # black, as in Cycles (whose diffuse eval has no view test: light from inside only).
        assert centre < 0.05
    elif kind in ("random", "tangent"):
        # About half the normals face out (random), or all lie in the surface (tangent): lit
        # from their own side, about half the light.
        assert 0.3 < centre < 0.7
    else:
        # Unusable normals shade flat: energy is not lost wholesale, the sphere stays white-ish.
        assert centre > 0.5


def test_grazing_camera_rays_along_a_plane():
    # The camera sits a hair above a huge plane and looks along it: most rays graze it.
    for height in (1e-3, 1e-5, 0.0):
        s = pc.Scene()
        m = s.add_material("m", (0.9, 0.9, 0.9))
        pos, tris = grid(4, 1e4)
        add_object(s, pos, tris, m)
        s.set_world_color((1.0, 1.0, 1.0))
        s.add_point_light((0.0, 50.0, 1.0), (100.0, 100.0, 100.0))
        s.set_camera(camera(pc, (0.0, 0.0, height), (0.0, 1.0, height), lens=20.0))
        img, stats = render(pc, s, 24, 24, samples=4)
        film_is_clean(img, stats)
        assert img[16:, :, :3].mean() > 0.5  # the sky above the horizon is there


@pytest.mark.parametrize("intensity", [0.0, 1e-30, 1e-12, 1e12, 1e30])
def test_tiny_and_huge_point_light_intensities_are_linear(intensity):
    def scene(k):
        s = pc.Scene()
        m = s.add_material("m", (0.5, 0.5, 0.5))
        add_object(s, *quad((-2, -2, 0), (4, 0, 0), (0, 4, 0)), m)
        pos, tris, nrm = uv_sphere(0.5, nu=16, nv=8, center=(0, 0, 0.5))
        add_object(s, pos, tris, m, nrm)
        s.add_point_light((0.5, -0.5, 2.0), (k, k, k))
        s.set_camera(camera(pc, (0, -4, 3), (0, 0, 0.3)))
        return s

    ref, _ = render(pc, scene(1.0), 16, 16, samples=8, seed=3)
    img, stats = render(pc, scene(intensity), 16, 16, samples=8, seed=3)
    film_is_clean(img, stats)
    if intensity == 0.0:
        assert img[..., :3].max() == 0.0
    else:
        np.testing.assert_allclose(img[..., :3] / intensity, ref[..., :3], rtol=1e-4, atol=1e-6)


def test_point_light_near_float_max_is_not_silently_dropped():
    s = pc.Scene()
    m = s.add_material("m", (0.5, 0.5, 0.5))
    add_object(s, *quad((-2, -2, 0), (4, 0, 0), (0, 4, 0)), m)
    s.add_point_light((0.0, 0.0, 2.0), (3e38, 3e38, 3e38))
    s.set_camera(camera(pc, (0, -4, 3), (0, 0, 0)))
    img, stats = render(pc, s, 8, 8, samples=2)
    film_is_clean(img, stats)
    assert img[..., :3].max() > 1e30


def test_zero_area_and_degenerate_lights_render_cleanly():
    s = pc.Scene()
    m = s.add_material("m", (0.5, 0.5, 0.5))
    add_object(s, *quad((-2, -2, 0), (4, 0, 0), (0, 4, 0)), m)
    up = transform(1.0, 0.0)
    up[:3, 3] = (0, 0, 1)
    s.add_area_light(up, 0.0, 1.0, (5.0, 5.0, 5.0))                 # zero width
    s.add_area_light(up, 1.0, 0.0, (5.0, 5.0, 5.0), ellipse=True)   # zero height
    s.add_area_light(up, 1e-30, 1e-30, (1e30, 1e30, 1e30))          # area underflows to 0
    flat = up.copy()
    flat[2, 2] = 0.0                                                 # no extent along z: fine
    s.add_area_light(flat, 1.0, 1.0, (1.0, 1.0, 1.0))
    s.add_point_light((0, 0, 0), (1.0, 1.0, 1.0))                   # exactly on the plane
    s.add_spot_light(up, (10.0, 10.0, 10.0), spot_size=0.0)          # a cone of zero angle
    s.add_spot_light(up, (10.0, 10.0, 10.0), spot_size=np.pi, spot_blend=0.0)
    s.add_sun_light((0, 0, 1), (1.0, 1.0, 1.0), angle=0.0)
    s.add_sun_light((0, 0, 1), (1.0, 1.0, 1.0), angle=1e30)          # angle clamped below pi
    s.set_camera(camera(pc, (0, -4, 3), (0, 0, 0)))
    img, stats = render(pc, s, 16, 16, samples=8)
    film_is_clean(img, stats)
    assert img[..., :3].mean() > 0.0


@pytest.mark.parametrize("kind", ["point", "spot"])
def test_soft_light_with_vanishing_radius_is_the_point_light_limit(kind):
    def scene(radius):
        s = pc.Scene()
        m = s.add_material("m", (0.5, 0.5, 0.5))
        add_object(s, *quad((-2, -2, 0), (4, 0, 0), (0, 4, 0)), m)
        if kind == "point":
            s.add_point_light((0, 0, 1), (1.0, 1.0, 1.0), radius=radius)
        else:
            s.add_spot_light(transform(1.0, (0.0, 0.0, 1.0)), (1.0, 1.0, 1.0), radius=radius, spot_size=3.0)
        s.set_camera(camera(pc, (0, -4, 3), (0, 0, 0)))
        return s

    img, stats = render(pc, scene(1e-30), 16, 16, samples=8, max_bounces=0)
    film_is_clean(img, stats)
    ref, _ = render(pc, scene(0.0), 16, 16, samples=8, max_bounces=0)
    np.testing.assert_allclose(img, ref, rtol=1e-3, atol=1e-6)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, -1.0, -1e30])
def test_bad_colours_are_black(bad):
    # NaN/Inf/negative colours are treated as 0 (documented): the image equals the one with 0.
    def scene(v):
        s = pc.Scene()
        m = s.add_material("m", (0.5, v, 0.5), (v, 0.0, 0.0))
        add_object(s, *quad((-2, -2, 0), (4, 0, 0), (0, 4, 0)), m)
        s.add_point_light((0, 0, 2), (10.0, v, 10.0))
        s.set_world_color((0.1, v, 0.1))
        s.set_camera(camera(pc, (0, -4, 3), (0, 0, 0)))
        return s

    img, stats = render(pc, scene(bad), 12, 12, samples=4)
    film_is_clean(img, stats)
    ref, _ = render(pc, scene(0.0), 12, 12, samples=4)
    np.testing.assert_array_equal(img, ref)


def env_scene(pixels, strength=1.0, rotation=None):
    s = pc.Scene()
    m = s.add_material("m", (0.8, 0.8, 0.8))
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), m)
    pos, tris, nrm = uv_sphere(0.6, nu=16, nv=8, center=(0, 0, 0.6))
    add_object(s, pos, tris, m, nrm)
    s.set_world_texture(pixels, strength=strength, rotation=rotation)
    s.set_camera(camera(pc, (0, -4, 2.5), (0, 0, 0.4)))
    return s


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, -5.0])
def test_environment_with_bad_pixels_equals_black_pixels(bad):
    rng = np.random.default_rng(1)
    px = rng.uniform(0, 2, (8, 16, 4)).astype(np.float32)
    px[2:4, 3:9, :3] = bad
    px[6, 0] = bad
    img, stats = render(pc, env_scene(px), 16, 16, samples=8)
    film_is_clean(img, stats)
    clean = px.copy()
    clean[~np.isfinite(clean) | (clean < 0)] = 0.0
    ref, _ = render(pc, env_scene(clean), 16, 16, samples=8)
    np.testing.assert_array_equal(img, ref)


@pytest.mark.parametrize("huge", [1e10, 1e30])
def test_environment_with_huge_pixels_stays_finite(huge):
    px = np.full((8, 16, 3), 0.1, np.float32)
    px[5, 7] = huge
    img, stats = render(pc, env_scene(px), 16, 16, samples=8)
    film_is_clean(img, stats)
    assert img[..., :3].max() > 1e-3 * huge  # the hot pixel is not dropped


def test_environment_texel_times_strength_overflow_is_not_nonfinite():
    px = np.full((4, 8, 3), 0.5, np.float32)
    px[1, 1] = 3e38
    img, stats = render(pc, env_scene(px, strength=10.0), 8, 8, samples=4)
    film_is_clean(img, stats)


def test_one_pixel_environment_is_a_constant_world():
    px = np.array([[[0.25, 0.5, 1.0]]], np.float32)
    a, stats = render(pc, env_scene(px, strength=2.0), 12, 12, samples=4)
    film_is_clean(a, stats)
    s = env_scene(np.zeros((1, 1, 3), np.float32))
    s.set_world_color((0.5, 1.0, 2.0))
    b, _ = render(pc, s, 12, 12, samples=4)
    np.testing.assert_allclose(a, b, rtol=1e-6)
    for shape in [(1, 2, 3), (2, 1, 3), (1, 7, 4), (3, 1, 4)]:  # one row / one column, not constant
        px = np.random.default_rng(2).uniform(0, 1, shape).astype(np.float32)
        img, stats = render(pc, env_scene(px), 8, 8, samples=4)
        film_is_clean(img, stats)
        assert img[..., :3].max() > 0.0


def test_singular_environment_rotation_is_rejected():
    px = np.random.default_rng(0).uniform(size=(4, 8, 3)).astype(np.float32)
    s = pc.Scene()
    with pytest.raises(ValueError, match="rotation"):
        s.set_world_texture(px, 1.0, np.zeros((3, 3), np.float32))


def test_environment_rotation_that_scales_is_harmless():
    # A rotation matrix with scale (not orthonormal, but invertible) must not break the image.
    px = np.random.default_rng(0).uniform(0.1, 1, (8, 16, 3)).astype(np.float32)
    img, stats = render(pc, env_scene(px, rotation=np.eye(3) * 1e-20), 12, 12, samples=4)
    film_is_clean(img, stats)
    img, stats = render(pc, env_scene(px, rotation=np.eye(3) * 1e20), 12, 12, samples=4)
    film_is_clean(img, stats)


@pytest.mark.parametrize("albedo", [0.0, 0.5, 1.0, 2.0, 1e30])
def test_furnace_never_brighter_than_the_world(albedo):
    # Albedo above 1 is clamped to 1 (documented): whatever is asked for, no energy is created.
    img, stats = render(pc, furnace_at(albedo=albedo), 24, 24, samples=16)
    film_is_clean(img, stats)
    assert img[..., :3].max() <= 1.0 + 1e-5
    expect = min(albedo, 1.0)
    assert abs(img[9:15, 9:15, :3].mean() - expect) < 0.03 + 0.02 * expect


# ---------------------------------------------------------------- 7. determinism

@pytest.mark.parametrize("adaptive", [0.0, 0.05])
def test_same_seed_gives_bit_identical_films_for_any_thread_count(adaptive):
    kw = dict(samples=32, seed=11, adaptive_threshold=adaptive, adaptive_min_samples=8 if adaptive else 0)
    base, _ = render(pc, cornell(pc), 24, 20, threads=1, tile_size=8, **kw)
    for threads in (1, 2, 3, 8):
        img, _ = render(pc, cornell(pc), 24, 20, threads=threads, tile_size=8, **kw)
        np.testing.assert_array_equal(img, base, err_msg=f"threads={threads}")
    if not adaptive:  # adaptive sampling judges convergence per tile; otherwise tiles do not matter
        for tile in (4, 16, 1024):
            img, _ = render(pc, cornell(pc), 24, 20, threads=2, tile_size=tile, **kw)
            np.testing.assert_array_equal(img, base, err_msg=f"tile_size={tile}")
    other, _ = render(pc, cornell(pc), 24, 20, threads=2, tile_size=8, **dict(kw, seed=12))
    assert not np.array_equal(other, base)


@pytest.mark.parametrize("sampler", ["sobol", "random"])
def test_adaptive_sample_counts_are_deterministic_across_threads(sampler):
    def run(threads):
        st = pc.RenderSettings()
        st.width, st.height, st.samples, st.seed = 24, 20, 64, 5
        st.adaptive_threshold, st.adaptive_min_samples = 0.05, 8
        st.threads, st.tile_size, st.sampler = threads, 8, sampler
        sess = pc.Session(cornell(pc), st)
        sess.start()
        while not sess.wait(1.0):
            pass
        return sess.film(), sess.sample_counts()

    f1, c1 = run(1)
    f2, c2 = run(4)
    np.testing.assert_array_equal(c1, c2)
    np.testing.assert_array_equal(f1, f2)
    assert c1.min() < 64  # adaptive sampling did stop some pixels
