"""Analytic lights with extent found by rays (issues 24, 25): the MIS pdf of a ray's hit on a
light is the pdf its light sample has for the same point, light sampling alone, ray hits alone
and both weighted by MIS render the same image, and the per-light Multiple Importance and ray
visibility flags do what Cycles' do."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, run_session

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def shader(s, name, kind, **params):
    regs, prog = {}, []
    for i, (k, v) in enumerate(params.items()):
        prog.append(("const", i, v if isinstance(v, tuple) else (v,)))
        regs[k] = i
    prog.append(("closure", kind, None, regs))
    return s.add_shader(name, prog)


def spot_matrix(pos, rot_x=0.0):
    m = np.eye(4, dtype=np.float32)
    c, s_ = np.cos(rot_x), np.sin(rot_x)
    m[:3, :3] = [[1, 0, 0], [0, c, -s_], [0, s_, c]]
    m[:3, 3] = pos
    return m


def area_matrix(pos, rot_x=0.0, shear=0.0):
    m = spot_matrix(pos, rot_x)
    m[0, 1] = shear
    return m


# Each light (core call, its keyword arguments), placed above the plane z = 0.
LIGHTS = {
    "point": ("add_point_light", dict(position=(0.3, 0.2, 1.5), intensity=(8.0, 8.0, 8.0), radius=0.4)),
    "spot": ("add_spot_light", dict(matrix=spot_matrix((0.2, -0.3, 1.6), 0.3), intensity=(8.0, 8.0, 8.0), radius=0.4,
                                    spot_size=1.8, spot_blend=0.4)),
    # Soft Falloff off: emitting spheres (the spot's sphere cone partly cut by its cone)
    "sphere": ("add_point_light", dict(position=(0.3, 0.2, 1.0), intensity=(8.0, 8.0, 8.0), radius=0.6,
                                       soft_falloff=False)),
    "sphere spot": ("add_spot_light", dict(matrix=spot_matrix((0.2, -0.3, 1.2), 0.3), intensity=(8.0, 8.0, 8.0),
                                           radius=0.5, spot_size=1.8, spot_blend=0.4, soft_falloff=False)),
    "rect": ("add_area_light", dict(matrix=area_matrix((0.0, 0.2, 1.4), 0.4), size_x=1.0, size_y=0.6,
                                    radiance=(3.0, 3.0, 3.0))),
    "rect sheared": ("add_area_light", dict(matrix=area_matrix((0.0, 0.2, 1.4), 0.2, shear=0.3), size_x=0.8,
                                            size_y=0.6, radiance=(3.0, 3.0, 3.0))),
    "ellipse": ("add_area_light", dict(matrix=area_matrix((0.1, 0.0, 1.3), -0.3), size_x=1.0, size_y=0.7,
                                       radiance=(3.0, 3.0, 3.0), ellipse=True)),
    # Spread below 180 degrees: sampled over the light clipped to the part that can reach the point
    "rect spread": ("add_area_light", dict(matrix=area_matrix((0.0, 0.2, 1.4), 0.3), size_x=1.6, size_y=1.0,
                                           radiance=(3.0, 3.0, 3.0), spread=1.6)),
    "ellipse spread": ("add_area_light", dict(matrix=area_matrix((0.1, 0.0, 1.3), -0.3), size_x=1.4, size_y=1.0,
                                              radiance=(3.0, 3.0, 3.0), ellipse=True, spread=1.8)),
    # a round one: the lens where the light's disk and the spread's overlap, or the smaller disk
    "disk spread": ("add_area_light", dict(matrix=area_matrix((0.2, 0.1, 0.9), 0.2), size_x=1.2, size_y=1.2,
                                           radiance=(3.0, 3.0, 3.0), ellipse=True, spread=2.0)),
    "sun": ("add_sun_light", dict(direction=(0.2, -0.3, 1.0), irradiance=(2.0, 2.0, 2.0), angle=0.25)),
}


def add_light(s, name, **extra):
    fn, kw = LIGHTS[name]
    getattr(s, fn)(**kw, **extra)


def plane_scene(name, material="glossy", roughness=0.35, tree=False, **extra):
    s = pc.Scene()
    m = shader(s, "floor", "glossy", roughness=roughness) if material == "glossy" else s.add_material("floor", (0.6,) * 3)
    pos, tris = quad((-3, -3, 0), (6, 0, 0), (0, 6, 0))
    add_object(s, pos, tris, m)
    add_light(s, name, **extra)
    if tree:  # dim lamps far away, so that the light tree chooses among ten lights
        for i in range(9):
            s.add_point_light(position=(-20.0 + 5 * i, 25.0, 3.0), intensity=(0.01,) * 3, radius=0.05)
        s.light_tree = "on"
    s.set_camera(camera(pc, (0.0, -3.5, 2.5), (0.0, 0.0, 0.3)))
    return s


@pytest.mark.parametrize("tree", [False, True], ids=["power", "tree"])
@pytest.mark.parametrize("name", list(LIGHTS))
def test_mis_pdf_of_a_hit_is_the_light_samples_pdf(name, tree):
    s = plane_scene(name, tree=tree)
    s.commit()
    rng = np.random.default_rng(1)
    n = 4000
    pts = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(0.01, 0.8, n)]).astype(np.float32)
    nrm = np.tile(np.float32([0, 0, 1]), (n, 1))
    u = rng.random((n, 3), dtype=np.float32)
    if tree:
        u[:, 0] *= 0.3  # mostly the light under test (it has most of the power)
    ok, wi, dist, pdf, pdf_hit, t_hit = s.light_samples(pts, u, normals=nrm if tree else None)
    ok = ok & (pdf > 0)
    if tree:  # only the samples of the light under test
        near = (np.isinf(dist) if name == "sun" else dist < 3.0)
        ok &= near
    assert ok.sum() > n // 4
    # Every sample's ray finds the light it sampled, at its distance, with its pdf.
    if name == "sun":
        assert np.isinf(t_hit[ok]).all()
    else:
        np.testing.assert_allclose(t_hit[ok], dist[ok], rtol=2e-3, atol=1e-4)
    np.testing.assert_allclose(pdf_hit[ok], pdf[ok], rtol=2e-3)


def test_rays_miss_lights_without_extent_or_multiple_importance():
    for kind in ("point", "sun"):
        s = pc.Scene()
        if kind == "point":
            s.add_point_light(position=(0, 0, 2), intensity=(1, 1, 1), radius=0.0)
        else:
            s.add_sun_light(direction=(0, 0, 1), irradiance=(1, 1, 1), angle=0.0)
        s.add_point_light(position=(0, 0, 5), intensity=(1, 1, 1), radius=0.5, use_mis=False)
        pos, tris = quad((-3, -3, -1), (6, 0, 0), (0, 6, 0))
        add_object(s, pos, tris, s.add_material("f", (0.5,) * 3))
        s.commit()
        assert "light hits" not in s.stats()["features"]
        pts = np.float32([[0, 0, 0]])
        ok, wi, dist, pdf, pdf_hit, t_hit = s.light_samples(pts, np.float32([[0.1, 0.5, 0.5]]))
        assert ok[0] and pdf_hit[0] == 0 and np.isinf(t_hit[0])


def renders(s, seeds=4, spp=64, size=16, **kw):
    out = [np.asarray(run_session(pc, s, size, size, spp, seed=7 + k, max_bounces=1, **kw).film())[..., :3]
           for k in range(seeds)]
    return np.stack(out).astype(np.float64)


# (The ellipse and disk spreads and the sun are long; under the sanitizer the rect spread and
# the others run the same sampling code.)
LONG = pytest.mark.converged


@pytest.mark.parametrize("name", ["point", "spot", "sphere", "sphere spot", "rect", "ellipse", "rect spread",
                                  pytest.param("ellipse spread", marks=LONG), pytest.param("disk spread", marks=LONG),
                                  pytest.param("sun", marks=LONG)])
def test_light_samples_ray_hits_and_mis_render_alike(name):
    """Light samples alone (light_hits off), BSDF rays alone (no light sampling) and both with
    MIS: the same image within noise, on a rough glossy floor. A wrong MIS pdf on either side
    shifts the MIS image from the other two."""
    imgs = {}
    s = plane_scene(name)
    s.light_hits = False
    imgs["nee"] = renders(s)
    s = plane_scene(name)
    # (the sun's cone and the spread lights' narrow emission are spiky for rays alone)
    imgs["bsdf"] = renders(s, spp=2048 if name == "sun" or "spread" in name else 256, use_nee=False)
    imgs["mis"] = renders(s)
    reg = lambda im: im.reshape(im.shape[0], 4, 4, 4, 4, 3).mean(axis=(2, 4, 5))
    r = {k: reg(v) for k, v in imgs.items()}
    ref = r["nee"].mean(0)
    lit = ref > 0.05 * ref.max()
    # MIS against light samples alone: 4 x 4 regions within 5 standard errors.
    se = np.sqrt((r["mis"].var(0, ddof=1) + r["nee"].var(0, ddof=1)) / r["mis"].shape[0]) + 1e-4 * ref.max()
    z = np.abs(r["mis"].mean(0) - ref) / se
    assert z[lit].max() < 5.0, z[lit].max()
    assert abs(imgs["mis"].mean() / imgs["nee"].mean() - 1) < 0.01
    # Rays alone (spiky: the light is small seen from the floor): the image mean within 3 %,
    # the bright regions within 10 %.
    assert abs(imgs["bsdf"].mean() / imgs["nee"].mean() - 1) < 0.03, (imgs["bsdf"].mean(), imgs["nee"].mean())
    if name != "sun":  # (a cone of 0.25 rad: too spiky for regions at this sample count)
        bright = ref > 0.2 * ref.max()
        rel = np.abs(r["bsdf"].mean(0)[bright] / ref[bright] - 1)
        assert rel.max() < 0.1, rel.max()
    # MIS helps the glossy floor: per-sample variance below the light samples' alone.
    var = {k: imgs[k].var(0, ddof=1).mean() for k in ("nee", "mis")}
    assert var["mis"] < 1.05 * var["nee"], var


def view_scene(name, **extra):
    """A dark world; the camera looks at the light (its emitting side)."""
    s = pc.Scene()
    add_light(s, name, **extra)
    pos, tris = quad((-30, -30, -5), (60, 0, 0), (0, 60, 0))
    add_object(s, pos, tris, s.add_material("black", (0.0,) * 3))
    if name == "sun":
        s.set_camera(camera(pc, (0.0, 0.0, 0.0), (0.2, -0.3, 1.0), lens=200.0))
    else:
        s.set_camera(camera(pc, (0.0, -0.2, -1.0), LIGHTS[name][1].get("position", (0.0, 0.2, 1.4)), lens=35.0))
    return s


@pytest.mark.parametrize("name", ["point", "sphere", "rect", "ellipse", "sun"])
def test_lights_visible_to_the_camera(name):
    s = view_scene(name, visible_camera=True)
    img = np.asarray(run_session(pc, s, 24, 24, 16).film())[..., 0]
    if name in ("point", "sphere"):  # the disk's radiance and the sphere's are both I / (pi r^2)
        le = 8.0 / (np.pi * LIGHTS[name][1]["radius"] ** 2)
    elif name == "sun":
        le = 2.0 / (np.pi * np.sin(0.125) ** 2)
    else:
        le = 3.0
    assert np.isclose(img.max(), le, rtol=1e-4), (img.max(), le)
    assert (img > 0.5 * le).sum() >= 4
    s = view_scene(name)  # the default: not visible to the camera
    assert np.asarray(run_session(pc, s, 24, 24, 4).film())[..., 0].max() == 0.0


def mirror_scene(mis=True, **extra):
    """A perfect mirror floor reflecting a rectangle light into the camera."""
    s = pc.Scene()
    m = shader(s, "mirror", "glossy", roughness=0.0)
    pos, tris = quad((-3, -3, 0), (6, 0, 0), (0, 6, 0))
    add_object(s, pos, tris, m)
    s.add_area_light(matrix=area_matrix((0.0, 0.8, 1.0), 0.6), size_x=2.0, size_y=2.0, radiance=(3.0, 3.0, 3.0),
                     use_mis=mis, **extra)
    s.set_camera(camera(pc, (0.0, -2.5, 1.5), (0.0, 0.5, 0.0)))
    return s


def test_a_mirror_shows_a_light_with_multiple_importance_only():
    img = np.asarray(run_session(pc, mirror_scene(), 24, 24, 4).film())[..., 0]
    assert 1.0 < img.max() <= 3.0  # the light's radiance times the mirror's colour
    assert (img > 0.5 * img.max()).sum() >= 8
    off = np.asarray(run_session(pc, mirror_scene(mis=False), 24, 24, 4).film())[..., 0]
    assert off.max() == 0.0
    # Glossy visibility off: the mirror does not show it either.
    off = np.asarray(run_session(pc, mirror_scene(visible_glossy=False), 24, 24, 4).film())[..., 0]
    assert off.max() == 0.0


@pytest.mark.parametrize("flag", ["visible_diffuse", "visible_glossy"])
def test_ray_visibility_off_removes_the_light_from_those_closures(flag):
    kind = "diffuse" if flag == "visible_diffuse" else "glossy"
    other = "glossy" if kind == "diffuse" else "diffuse"
    means = {}
    for mat in (kind, other):
        for on in (True, False):
            s = plane_scene("rect", material=mat, roughness=0.4, **{flag: on})
            means[mat, on] = np.asarray(run_session(pc, s, 16, 16, 64, max_bounces=1).film())[..., :3].mean()
    assert means[kind, True] > 0.01 and means[kind, False] == 0.0
    assert np.isclose(means[other, True], means[other, False], rtol=1e-6)


def test_camera_sees_lights_through_transparent_surfaces():
    s = view_scene("rect", visible_camera=True)
    # A half-transparent sheet between the camera (0, -0.2, -1) and the light (z = 1.4).
    pos, tris = quad((-5, -5, 0.2), (10, 0, 0), (0, 10, 0))
    add_object(s, pos, tris, shader(s, "veil", "transparent", color=(0.5, 0.5, 0.5)))
    img = np.asarray(run_session(pc, s, 24, 24, 16).film())[..., 0]
    assert np.isclose(img.max(), 0.5 * 3.0, rtol=1e-4), img.max()
