"""Materials as shader programs, through the core module: closed-form furnace, Beer's law,
textures (Closest vs Linear), transparency and transparent shadows, normal maps, and program
validation."""
import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, quad, render, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def furnace(program, samples=64, size=32, world=1.0, **kw):
    s = pc.Scene()
    m = s.add_shader("m", program, **kw)
    pos, tris, nrm = uv_sphere(1.0, nu=64, nv=32)
    add_object(s, pos, tris, m)
    s.set_world_color((world, world, world))
    s.set_camera(camera(pc, (0, -4, 0), (0, 0, 0), lens=60.0))
    # Grazing rays can stay trapped by total internal reflection for many bounces.
    img, stats = render(pc, s, size, size, samples=samples, max_bounces=1024)
    assert stats["nonfinite_samples"] == 0
    return img[..., :3]


def test_smooth_glass_and_mirror_vanish_in_a_white_furnace():
    for prog in (closure("glass", roughness=0.0, ior=1.5), closure("glossy", roughness=0.0),
                 closure("principled", base_color=(1.0, 1.0, 1.0), metallic=1.0, roughness=0.0)):
        img = furnace(prog, samples=64)
        assert np.abs(img - 1.0).max() < 0.02, prog[-1]


def test_rough_glass_loses_only_a_little_energy():
    img = furnace(closure("glass", roughness=0.3, ior=1.5), samples=128)
    assert 0.9 < img[12:20, 12:20].mean() <= 1.01


def test_principled_dielectric_conserves_energy_roughly():
    # White base, default specular: the layered approximation must stay at or just under 1.
    img = furnace(closure("principled", base_color=(1.0, 1.0, 1.0), roughness=0.5), samples=128)
    centre = img[12:20, 12:20].mean()
    assert 0.93 < centre <= 1.02, centre


def test_beer_law_through_an_index_matched_box():
    # IOR 1 glass: no refraction, no Fresnel; only absorption: exp(-density * (1 - color) * d).
    s = pc.Scene()
    m = s.add_shader("absorber", closure("glass", roughness=0.0, ior=1.0),
                     volume_absorption=((0.5, 0.8, 1.0), 2.0))
    d = 0.7
    pos = np.array([[x, y, z] for x in (-1, 1) for y in (-d / 2, d / 2) for z in (-1, 1)], np.float32)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = np.array([t for a, b, c, e in faces for t in ((a, b, c), (a, c, e))], np.int32)
    n = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    assert (np.einsum("ij,ij->i", n, pos[tris].mean(1)) > 0).all()  # outward, as the medium needs
    add_object(s, pos, tris, m)
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0, -5, 0), (0, 0, 0), lens=200.0))
    img, _ = render(pc, s, 8, 8, samples=16)
    expected = np.exp(-2.0 * (1 - np.array([0.5, 0.8, 1.0])) * d)
    # The centre pixels look straight through (off-centre rays travel up to 0.5 % further).
    assert np.allclose(img[3:5, 3:5, :3].reshape(-1, 3), expected, rtol=2e-3), (img[4, 4, :3], expected)
    assert (img[..., :3] <= expected + 1e-4).all()


def checker(high=1.0, low=0.0, alpha=1.0):
    tex = np.full((4, 4, 4), low, np.float32)
    tex[..., 3] = alpha
    tex[::2, ::2, :3] = high   # a checker with 1-texel squares
    tex[1::2, 1::2, :3] = high
    return tex


def textured_plane(interp, tex=None, srgb=False, unassociate=None):
    s = pc.Scene()
    tex = checker() if tex is None else tex
    img_id = s.add_image(tex, srgb=True) if srgb else s.add_image(tex)
    op = ("image", 1, 0, img_id, interp, "REPEAT") + (() if unassociate is None else (unassociate,))
    prog = [("uv", 0, 0), op, ("closure", "emission", None, {"color": 1})]
    m = s.add_shader("tex", prog)
    pos, tris = quad((-1, 0, -1), (2, 0, 0), (0, 0, 2))
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    mesh = s.add_mesh(pos, tris, None, None, [m], uvs={0: uv})
    s.add_instance(mesh, np.eye(4, dtype=np.float32))
    # The plane exactly fills the view: 32 px over 4 texels, 8 px per texel.
    cam = pc.Camera()
    cam.matrix_world = np.array([[1, 0, 0, 0], [0, 0, -1, -1], [0, 1, 0, 0], [0, 0, 0, 1]], np.float32)
    cam.lens, cam.sensor_width = 18.0, 36.0
    s.set_camera(cam)
    img, _ = render(pc, s, 32, 32, samples=16)
    return img[..., 0]


def test_texture_closest_and_linear():
    closest = textured_plane("CLOSEST")
    linear = textured_plane("LINEAR")
    # Closest: exactly the checker at texel centres, hard edges (only 0 and 1 away from edges).
    centres = closest[4::8, 4::8]
    assert np.array_equal(centres, np.array([[1, 0, 1, 0], [0, 1, 0, 1]] * 2, np.float32))
    interior = np.concatenate([closest[1:7, 1:7].ravel(), closest[9:15, 9:15].ravel()])
    assert set(np.unique(interior)) <= {0.0, 1.0}
    # Linear: near texel centres the value stays close (the pixel right of a centre averages
    # the tent over 1/8 texel: 1 - 2/16 + ...), texel boundaries blend towards 0.5.
    assert np.abs(linear[4::8, 4::8] - centres).max() < 0.15
    assert abs(linear[4, 8] - 0.5) < 0.1 and len(np.unique(np.round(linear, 2))) > 10


def srgb_to_linear(c):
    c = np.asarray(c, np.float64)
    return np.where(c < 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def test_srgb_textures_are_filtered_before_decoding():
    """Cycles keeps 8-bit sRGB textures encoded, interpolates the encoded values and decodes
    each lookup: texel centres read the decoded texel, a boundary between 0.9 and 0.1 reads
    the decoded mean of the encoded values (about 0.21), not the mean of the decoded ones (0.40)."""
    tex = checker(0.9, 0.1)
    closest = textured_plane("CLOSEST", tex, srgb=True)
    expect = np.where(np.array([[1, 0, 1, 0], [0, 1, 0, 1]] * 2) == 1, *srgb_to_linear([0.9, 0.1]))
    assert np.allclose(closest[4::8, 4::8], expect, rtol=1e-5)
    linear = textured_plane("LINEAR", tex, srgb=True)
    as_linear = textured_plane("LINEAR", srgb_to_linear(tex).astype(np.float32))
    # Pixels 7 and 8 straddle the boundary between texels 0 and 1 (each 1/8 texel wide).
    boundary = linear[4, 7:9].mean()
    assert abs(boundary - srgb_to_linear(0.5)) < 0.03, boundary
    assert as_linear[4, 7:9].mean() > boundary + 0.15


def test_image_unassociates_after_filtering():
    """With the Alpha output linked Cycles divides the filtered (associated) colour by the
    filtered alpha: a uniform straight colour stays uniform across texels of different alpha."""
    tex = np.zeros((4, 4, 4), np.float32)
    tex[..., 3] = np.where(checker()[..., 0] == 1.0, 1.0, 0.25)
    tex[..., :3] = 0.6 * tex[..., 3:4]  # associated
    straight = textured_plane("LINEAR", tex, unassociate=True)
    assert np.allclose(straight[2:30, 2:30], 0.6, rtol=1e-4)
    assoc = textured_plane("LINEAR", tex, unassociate=False)
    assert assoc.min() < 0.3 and assoc.max() - assoc.min() > 0.25  # 0.6 x alpha, filtered


def test_transparent_card_and_its_shadow():
    def scene(alpha):
        s = pc.Scene()
        floor = s.add_material("floor", (0.5, 0.5, 0.5))
        pos, tris = quad((-5, -5, 0), (10, 0, 0), (0, 10, 0))
        add_object(s, pos, tris, floor)
        # The opaque part is black, so no light bounces back from the card into its shadow.
        prog = [("const", 0, (alpha,)), ("const", 1, (1 - alpha,)), ("const", 2, (0.0,)),
                ("closure", "transparent", 1, {}), ("closure", "diffuse", 0, {"color": 2})]
        card = s.add_shader("card", prog)
        pos, tris = quad((-0.5, -0.5, 1.0), (1, 0, 0), (0, 1, 0))
        add_object(s, pos, tris, card)
        s.add_point_light((0.0, 0.0, 2.0), (10.0, 10.0, 10.0))
        cam = pc.Camera()
        mw = np.eye(4, dtype=np.float32)
        mw[2, 3] = 4.0
        cam.matrix_world = mw
        s.set_camera(cam)
        img, _ = render(pc, s, 32, 32, samples=32)
        return img[..., 0]

    opaque, half, clear = scene(1.0), scene(0.5), scene(0.0)
    ring = (slice(6, 8), slice(14, 18))  # floor in the card's shadow but outside its silhouette
    assert opaque[ring].max() == 0.0
    assert np.allclose(half[ring], 0.5 * clear[ring], rtol=0.02)


def test_normal_map_tilts_the_shading_normal():
    def scene(color):
        s = pc.Scene()
        prog = [("const", 0, color), ("normal_map", 1, 0, None, 0), ("closure", "diffuse", None, {"normal": 1})]
        m = s.add_shader("nm", prog)
        pos, tris = quad((-5, -5, 0), (10, 0, 0), (0, 10, 0))
        uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
        mesh = s.add_mesh(pos, tris, None, None, [m], uvs={0: uv})
        s.add_instance(mesh, np.eye(4, dtype=np.float32))
        s.add_sun_light((0.0, 0.0, 1.0), (np.pi, np.pi, np.pi))
        cam = pc.Camera()
        mw = np.eye(4, dtype=np.float32)
        mw[2, 3] = 4.0
        cam.matrix_world = mw
        s.set_camera(cam)
        img, _ = render(pc, s, 8, 8, samples=4)
        return img[..., 0].mean()

    flat = scene((0.5, 0.5, 1.0))
    assert abs(flat - 1.0) < 1e-3  # albedo 1 (default colour white), E = pi: radiance 1
    # Tangent-space (x = +u = world +X): a normal tilted 45 degrees towards +X.
    tilted = scene((0.5 + 0.5 * np.sqrt(0.5), 0.5, 0.5 + 0.5 * np.sqrt(0.5)))
    assert abs(tilted - np.sqrt(0.5)) < 0.01


def test_mix_of_diffuse_and_glossy_weights():
    for fac in (0.2, 0.5, 1.0):
        prog = [("const", 0, (fac,)), ("const", 1, (1.0 - fac,)), ("const", 2, (0.0,)),
                ("closure", "diffuse", 1, {}), ("closure", "glossy", 0, {"roughness": 2})]
        img = furnace(prog, samples=32)
        assert np.abs(img - 1.0).max() < 0.02, fac  # both lobes conserve energy: invisible


def test_bad_programs_raise():
    s = pc.Scene()
    for prog in ([("nonsense", 0)], [("const", 99, (1,))], [("image", 0, 0, 5, "LINEAR", "REPEAT")],
                 [("closure", "velvet", None, {})], [("math", 0, 0, 0, "HYPOTENUSE", False)],
                 [("mapping", 0, 0, np.zeros((2, 2)))], [("uv", 0, 9)],
                 [("closure", "principled", None, {"sheen_weight": 99})],  # a PrincipledExtra operand
                 [("closure", "principled", None, {"subsurface_radius": -5})]):
        with pytest.raises((ValueError, RuntimeError)):
            s.add_shader("bad", prog)
    with pytest.raises(ValueError):
        s.add_image(np.zeros((4, 4, 3), np.float32))
    # NaN constants become 0 rather than poisoning renders.
    s.add_shader("nan", [("const", 0, (np.nan, 1.0, 1.0)), ("closure", "diffuse", None, {"color": 0})])


# ---------------------------------------------------------------- value ops of issue 3

import math  # noqa: E402

from blender_util import load_addon  # noqa: E402

load_addon()
from addon.export import shader as sh  # noqa: E402  (the compiler: Ramp tables, folding)
import shader_reference as ref  # noqa: E402  (Python references of the core's ops)


def emitted(ops, tilt=0.0, size=3, eye_dist=20.0, texspace=None, matrix=None):
    """The emission an (uncoloured) program's register 'out' gives at the image centre: a
    plane (normal towards the camera, tilted by `tilt` radians about x) fills the view."""
    s = pc.Scene()
    out = max(op[1] for op in ops if op[0] != "closure") if ops else 0
    m = s.add_shader("ops", list(ops) + [("closure", "emission", None, {"color": out})])
    c, sn = math.cos(tilt), math.sin(tilt)
    pos, tris = quad((-50, 0, -50), (100, 0, 0), (0, 100 * sn, 100 * c))
    pos -= pos.mean(axis=0)  # centred on the camera axis
    uvs = {0: np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)}
    if matrix is not None:  # the same world plane, from an object space
        pos = (np.linalg.inv(matrix) @ np.c_[pos, np.ones(len(pos))].T).T[:, :3].astype(np.float32)
    mesh = s.add_mesh(pos, tris, None, None, [m], uvs=uvs, texspace=texspace)
    s.add_instance(mesh, np.eye(4, dtype=np.float32) if matrix is None else matrix.astype(np.float32))
    s.set_camera(camera(pc, (0, -eye_dist, 0), (0, 0, 0), lens=5000.0))  # nearly parallel rays
    img, _ = render(pc, s, size, size, samples=1)
    return img[size // 2, size // 2, :3]


def consts(*values):
    return [("const", i, tuple(v) if isinstance(v, (tuple, list)) else (v,)) for i, v in enumerate(values)]


@pytest.mark.parametrize("conversion", ["RGB_TO_HSV", "HSV_TO_RGB", "RGB_TO_HSL", "HSL_TO_RGB"])
def test_colour_conversions_match_the_compilers_folding(conversion):
    for c in ((0.8, 0.3, 0.2), (0.2, 0.9, 0.4), (0.1, 0.2, 0.7), (0.5, 0.5, 0.5), (0.95, 0.0, 0.6)):
        got = emitted(consts(c + (1.0,)) + [("color_space", 1, 0, conversion)])
        assert got == pytest.approx(ref._COLOR_SPACES[conversion](c), abs=1e-5), c


def test_colour_adjustment_ops_match_the_compilers_folding():
    c = (0.8, 0.3, 0.2, 1.0)
    got = emitted(consts(c, 0.6, 0.5, 1.2, 0.75) + [("hsv", 5, 0, 1, 2, 3, 4)])
    assert got == pytest.approx(ref._hsv_node(c[:3], 0.6, 0.5, 1.2, 0.75), abs=1e-5)
    got = emitted(consts(c, 2.2) + [("gamma", 2, 0, 1)])
    assert got == pytest.approx(ref._gamma(c[:3], 2.2), abs=1e-5)
    got = emitted(consts(c, 0.1, 0.4) + [("bright_contrast", 3, 0, 1, 2)])
    assert got == pytest.approx([max(1.4 * x - 0.1, 0.0) for x in c[:3]], abs=1e-5)
    for lo, hi, kind in ((0.2, 0.5, "MINMAX"), (0.5, 0.2, "RANGE"), (0.5, 0.2, "MINMAX")):
        got = emitted(consts(0.7, lo, hi) + [("clamp", 3, 0, 1, 2, kind)])
        assert got[0] == pytest.approx(ref._clamp(0.7, lo, hi, kind))
    for mode in ("LINEAR", "STEPPED", "SMOOTHSTEP", "SMOOTHERSTEP"):
        for v in (0.3, 0.62, 0.83, 1.4):  # away from float-rounded step edges
            args = (v, 0.5, 1.0, 3.0, 7.0, 4.0)
            got = emitted(consts(*args) + [("map_range", 6, 0, 1, 2, 3, 4, 5, mode, True)])
            assert got[0] == pytest.approx(ref._map_range(*args, mode, True), abs=1e-5), (mode, v)
        # The vector variant: per component, its own parameters (a zero range gives to_min).
        vec = [(0.3, 0.62, 1.4), (0.5, 0.0, 1.0), (1.0, 0.0, 1.0), (3.0, 0.1, 0.2), (7.0, 0.9, 0.5),
               (4.0, 2.0, 3.0)]
        got = emitted(consts(*[x + (0.0,) for x in vec]) + [("map_range_vector", 6, 0, 1, 2, 3, 4, 5, mode, True)])
        assert got == pytest.approx(ref._map_range_vector(*vec, mode, True), abs=1e-5), mode


@pytest.mark.parametrize("op", sorted(ref.VECTOR_MATH_OPS))
def test_vector_math_matches_the_compilers_folding(op):
    a, b, c, scale = (0.7, -0.4, 2.5), (1.5, 0.3, -0.8), (0.2, 0.9, 0.1), 0.6
    expect = ref._vector_math(op, a, b, c, scale)
    expect = (expect,) * 3 if op in ref.VECTOR_MATH_VALUE_OPS else expect
    # Emission shows only positive values: look at the result and at its negation.
    prog = consts(a + (0.0,), b + (0.0,), c + (0.0,), scale, -1.0) + [
        ("vector_math", 5, 0, 1, 2, 3, op)]
    pos = emitted(prog)
    neg = emitted(prog + [("vector_math", 6, 5, 5, 5, 4, "SCALE")])
    got = np.where(np.asarray(expect) >= 0, pos, -neg)
    assert got == pytest.approx(expect, abs=1e-4)


def test_ramp_op_matches_the_compilers_lookup():
    table = np.stack([np.linspace(0, 1, 8), np.linspace(1, 0, 8) ** 2,
                      (np.arange(8) % 2).astype(float), np.ones(8)], axis=1).astype(np.float32)
    for f in (-0.3, 0.0, 0.1, 0.5, 0.93, 1.0, 1.2):
        for interp, extrap in ((True, False), (False, False), (True, True)):
            got = emitted(consts(f) + [("ramp", 1, 0, table, interp, extrap, 0.0, 1.0, False)])
            expect = np.clip(ref.ramp_lookup(table.astype(np.float64), f, interp, extrap)[:3], 0, None)
            assert got == pytest.approx(expect, abs=1e-5), (f, interp, extrap)
    # Per-channel lookups over a range (RGB Curves).
    got = emitted(consts((0.5, 1.0, 2.0, 1.0)) + [("ramp", 1, 0, table, True, False, 0.0, 2.0, True)])
    expect = [ref.ramp_lookup(table.astype(np.float64), x / 2.0, True, False)[i]
              for i, x in enumerate((0.5, 1.0, 2.0))]
    assert got == pytest.approx(expect, abs=1e-5)


def test_fresnel_and_layer_weight_follow_the_view_angle():
    def fresnel(cos_i, eta):  # the Fresnel equations for unpolarised light, from the angles
        sin_t = math.sqrt(max(0.0, 1 - cos_i ** 2)) / eta
        cos_t = math.sqrt(1 - sin_t ** 2)
        rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
        rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
        return 0.5 * (rs * rs + rp * rp)
    for deg in (0.0, 45.0, 70.0):
        cos_i = math.cos(math.radians(deg))
        got = emitted(consts(1.5) + [("fresnel", 1, 0, None)], tilt=math.radians(deg))
        assert got[0] == pytest.approx(fresnel(cos_i, 1.5), rel=5e-3, abs=1e-4), deg  # pixel jitter: +-0.07 degrees
        got = emitted(consts(0.25) + [("layer_weight", 1, 0, None, "FACING")], tilt=math.radians(deg))
        assert got[0] == pytest.approx(1 - cos_i ** 0.5, abs=2e-3), deg
        got = emitted(consts(0.3) + [("layer_weight", 1, 0, None, "FRESNEL")], tilt=math.radians(deg))
        assert got[0] == pytest.approx(fresnel(cos_i, 1 / 0.7), rel=5e-3, abs=1e-4), deg  # pixel jitter: +-0.07 degrees


def test_bump_tilts_the_normal_by_the_height_slope():
    # Height = slope * x over the plane y = 0 facing -y (the camera): the bumped normal is
    # normalize(n - distance * grad h) = normalize((-distance * slope, -1, 0)).
    for slope, distance, invert in ((-0.5, 1.0, False), (-2.0, 0.3, False), (0.5, 1.0, True)):
        prog = [("position", 0), ("position", 1, 1), ("position", 2, 2), ("const", 3, (slope,)),
                ("separate", 4, 0, 0), ("separate", 5, 1, 0), ("separate", 6, 2, 0),
                ("math", 7, 4, 3, "MULTIPLY", False), ("math", 8, 5, 3, "MULTIPLY", False),
                ("math", 9, 6, 3, "MULTIPLY", False), ("const", 10, (1.0,)), ("const", 11, (distance,)),
                ("bump", 12, 7, 8, 9, 10, 11, None, invert),
                ("vector_math", 13, 12, 12, 12, 10, "ABSOLUTE")]
        d = -distance if invert else distance
        n = np.array([-d * slope, -1.0, 0.0])
        got = emitted(prog)
        assert got == pytest.approx(np.abs(n / np.linalg.norm(n)), abs=2e-3), (slope, distance)
    # A uv height (u grows along +x): the same through the uv offsets.
    prog = [("uv", 0, 0), ("uv", 1, 0, 1), ("uv", 2, 0, 2), ("const", 3, (-0.01,)),
            ("separate", 4, 0, 0), ("separate", 5, 1, 0), ("separate", 6, 2, 0),
            ("math", 7, 4, 3, "MULTIPLY", False), ("math", 8, 5, 3, "MULTIPLY", False),
            ("math", 9, 6, 3, "MULTIPLY", False), ("const", 10, (1.0,)),
            ("bump", 11, 7, 8, 9, 10, 10, None, False),
            ("vector_math", 12, 11, 11, 11, 10, "ABSOLUTE")]
    n = np.array([0.01 / 100.0, -1.0, 0.0])  # u spans 100 units
    assert emitted(prog) == pytest.approx(np.abs(n / np.linalg.norm(n)), abs=1e-5)


def test_object_and_generated_coordinates_per_instance():
    # The plane's centre (world origin) in object space, and in its texture space: the
    # bounding box of the object-space vertices (Blender's automatic one) unless given.
    m = np.array([[0.0, -2.0, 0.0, 3.0], [1.0, 0.0, 0.0, 5.0], [0.0, 0.0, 0.5, 7.0], [0, 0, 0, 1]])
    centre = np.linalg.inv(m) @ np.array([0.0, 0.0, 0.0, 1.0])
    got = emitted([("object", 0), ("vector_math", 1, 0, 0, 0, 0, "ABSOLUTE")], matrix=m)
    assert got == pytest.approx(np.abs(centre[:3]), abs=0.06)  # pixel jitter: +-0.024 world
    # Auto texture space: the box's centre maps to 0.5 (where it has extent; y is flat: 0.5 too).
    assert emitted([("generated", 0)], matrix=m) == pytest.approx((0.5, 0.5, 0.5), abs=1e-3)
    loc, size = (centre[0] + 10.0, centre[1], centre[2] - 20.0), (40.0, 2.0, 80.0)
    expect = (np.asarray(centre[:3]) - loc) / size * 0.5 + 0.5
    got = emitted([("generated", 0)], matrix=m, texspace=(loc, size))
    assert got == pytest.approx(expect, abs=5e-3)
    # Object normals: the world normal (0, -1, 0) seen from the object: M^T n, normalised.
    n = m[:3, :3].T @ np.array([0.0, -1.0, 0.0])
    got = emitted([("object_normal", 0), ("vector_math", 1, 0, 0, 0, 0, "ABSOLUTE")], matrix=m)
    assert got == pytest.approx(np.abs(n / np.linalg.norm(n)), abs=1e-4)


@pytest.mark.parametrize("op", sorted(ref.MATH_OPS))
def test_math_ops_match_the_compilers_folding(op):
    for a, b, c in ((0.7, 2.5, 0.3), (-1.3, 0.4, 0.5), (2.0, -0.75, 1.5), (0.25, 0.25, 0.0)):
        expect = ref._math(op, a, b, c)
        name = "math3" if op in ref.MATH_OPS_3 else "math"
        operands = (0, 1, 2) if name == "math3" else (0, 1)
        prog = consts(a, b, c, -1.0) + [(name, 4) + operands + (op, False)]
        # Emission shows positive values only: the result and its negation.
        pos = emitted(prog)[0]
        neg = emitted(prog + [("math", 5, 4, 3, "MULTIPLY", False)])[0]
        got = pos if expect >= 0 else -neg
        assert got == pytest.approx(expect, rel=1e-5, abs=1e-5), (op, a, b, c)


def test_value_ops_with_extreme_inputs_render_finite():
    """Every value op of issue 3 with zero, tiny, huge and negative inputs (also as normals
    and closure inputs): the render stays finite, with no dropped samples."""
    table = np.array([[0, 0, 0, 1], [1e30, -1e30, 3e38, 1]], np.float32)
    bad = [0.0, 1e-30, -1e-30, 3e38, -3e38, 1.0]
    heads = [("position", 0), ("uv", 1, 0, 1), ("object", 2, 2), ("generated", 3), ("object_normal", 4)]
    for k, x in enumerate(bad):
        y = bad[(k + 1) % len(bad)]
        ops = heads + [("const", 5, (x, y, -x, 1.0)), ("const", 6, (y,)), ("const", 7, (x,))]
        tail = [("fresnel", 8, 6, 5), ("layer_weight", 9, 7, 5, "FACING"),
                ("bump", 10, 6, 7, 8, 9, 7, 5, True), ("ramp", 11, 5, table, True, True, x, y, True),
                ("ramp", 12, 7, table, False, False, 0.0, 1.0, False), ("color_space", 13, 5, "RGB_TO_HSV"),
                ("color_space", 14, 13, "HSV_TO_RGB"), ("color_space", 15, 5, "HSL_TO_RGB"),
                ("hsv", 16, 5, 6, 7, 6, 7), ("gamma", 17, 5, 6), ("bright_contrast", 18, 5, 6, 7),
                ("clamp", 19, 6, 7, 6, "RANGE"), ("map_range", 20, 6, 7, 7, 6, 7, 6, "STEPPED", True),
                ("vector_math", 21, 5, 10, 0, 6, "REFRACT"), ("vector_math", 22, 5, 21, 2, 7, "WRAP"),
                ("math3", 23, 6, 7, 6, "SMOOTH_MIN", False), ("math", 24, 6, 7, "PINGPONG", False),
                ("math", 25, 7, 6, "LOGARITHM", False), ("separate", 26, 22, 1), ("combine", 27, 23, 24, 25, True)]
        ops += tail
        s = pc.Scene()
        closures = [("closure", "diffuse", 27, {"color": 11, "normal": 10}),
                    ("closure", "glossy", 14, {"roughness": 26, "normal": 21}),
                    ("closure", "principled", 16, {"base_color": 17, "roughness": 19, "normal": 22}),
                    ("closure", "emission", 20, {"color": 18})]
        m = s.add_shader("extreme", ops + closures)
        pos, tris = quad((-2, -2, 0), (4, 0, 0), (0, 4, 0))
        uv = np.array([[[0, 0], [x, 0], [1, y]], [[0, 0], [1, 1], [0, 1]]], np.float32)
        mesh = s.add_mesh(pos, tris, None, None, [m], uvs={0: uv}, texspace=((x, y, 0), (y, 0, x)))
        s.add_instance(mesh, np.eye(4, dtype=np.float32))
        s.set_world_color((1.0, 1.0, 1.0))
        s.set_camera(camera(pc, (0, -3, 3), (0, 0, 0)))
        img, stats = render(pc, s, 6, 6, samples=2)
        assert np.isfinite(img).all() and stats["nonfinite_samples"] == 0, (x, y)


def test_no_russian_roulette_through_a_stack_of_clear_sheets():
    """Four tinted refraction slabs (eight delta crossings, past the roulette's start) in front of
    an emitter: every camera path carries exactly E * tint^8, so the film has no noise at all.
    A roulette at delta vertices would kill some paths and amplify the rest (unbiased, but noisy:
    in glass it cut the caustic chains before they reach the light)."""
    s = pc.Scene()
    g, e = 0.8, 2.0
    sheet = s.add_shader("sheet", closure("refraction", color=(g, g, g), roughness=0.0, ior=1.5))
    for i in range(4):  # a slab: a sheet facing the camera (entered), then one facing away (left)
        y = -2.0 + 0.5 * i
        for dy, flip in ((0.0, False), (0.1, True)):
            pos, tris = quad((-20, y + dy, -20), (0, 0, 40), (40, 0, 0))  # normal -y
            add_object(s, pos, tris[:, ::-1].copy() if flip else tris, sheet)
    pos, tris = quad((-50, 1.0, -50), (0, 0, 100), (100, 0, 0))
    add_object(s, pos, tris, s.add_material("light", (0.0, 0.0, 0.0), (e, e, e)))
    s.set_camera(camera(pc, (0, -5, 0), (0, 0, 0), lens=50.0))
    img, stats = render(pc, s, 16, 16, samples=8)
    assert stats["nonfinite_samples"] == 0
    np.testing.assert_allclose(img[..., :3], e * g**8, rtol=1e-4)


# ---------------------------------------------------------------- the core's op table (issue 22)

def _blender_enum(node_type, prop):
    import bpy
    node = bpy.data.node_groups.new("ops", "ShaderNodeTree").nodes.new(node_type)
    return {e.identifier for e in node.bl_rna.properties[prop].enum_items}


# Blender operations the core does not have: the compiler warns and falls back for these.
MISSING_MIX_BLENDS = {"BURN", "DODGE", "HUE", "SATURATION", "VALUE", "COLOR", "SOFT_LIGHT",
                      "LINEAR_LIGHT", "EXCLUSION"}


def test_the_core_op_table_matches_the_references_and_blender():
    table = core().shader_op_table()
    names = {kind: [e["name"] for e in entries] for kind, entries in table.items() if kind != "ops"}
    assert set(names["math"]) == ref.MATH_OPS and len(names["math"]) == len(ref.MATH_OPS)
    assert {e["name"] for e in table["math"] if e["operands"] == 3} == ref.MATH_OPS_3
    assert set(names["vector_math"]) == ref.VECTOR_MATH_OPS
    assert {e["name"] for e in table["vector_math"] if e["value_out"]} == ref.VECTOR_MATH_VALUE_OPS
    assert set(names["mix"]) == ref.MIX_BLENDS
    assert set(names["color_space"]) == set(ref._COLOR_SPACES)
    # Every Blender Math / Vector Math operation is in the core; Mix blends as listed.
    assert _blender_enum("ShaderNodeMath", "operation") == set(names["math"])
    assert _blender_enum("ShaderNodeVectorMath", "operation") == set(names["vector_math"])
    assert _blender_enum("ShaderNodeMix", "blend_type") - set(names["mix"]) == MISSING_MIX_BLENDS
    assert set(names["map_range"]) == _blender_enum("ShaderNodeMapRange", "interpolation_type")
    assert set(names["clamp"]) == _blender_enum("ShaderNodeClamp", "clamp_type")
    # The add-on reads the same table.
    assert set(sh.math_ops()) == set(names["math"]) and set(sh.mix_blends()) == set(names["mix"])


@pytest.mark.parametrize("op", sorted(ref.MATH_OPS))
def test_folding_is_the_cores_float_math(op):
    # The compiler folds through the core (float), the reference is double: they agree to
    # float precision, and the folded value is the one the renderer computes.
    from addon.export.shader.values import const_float
    for a, b, c in ((0.7, 2.5, 0.3), (-1.3, 0.4, 0.5), (2.0, -0.75, 1.5), (0.25, 0.25, 0.0)):
        name = "math3" if op in ref.MATH_OPS_3 else "math"
        vals = tuple(const_float(x) for x in ((a, b, c) if name == "math3" else (a, b)))
        got = sh.fold("float", name, vals, op, False).const[0]
        assert got == pytest.approx(ref._math(op, a, b, c), rel=1e-5, abs=1e-5), (op, a, b, c)
        f32 = np.float32
        assert got == float(f32(got))  # a float's value: no double left over


def test_fold_constant_refuses_ops_that_read_the_shading_point():
    with pytest.raises(ValueError):
        core().fold_constant([("position", 0)], 0)
    with pytest.raises(ValueError):
        core().fold_constant([("const", 0, (1.0,))], 99)
    with pytest.raises(ValueError, match="pure value ops"):  # Fresnel reads the view
        core().fold_constant([("const", 0, (1.5,)), ("fresnel", 1, 0, None)], 1)


def test_fold_constant_folds_every_pure_op_of_the_table():
    # Which ops fold follows from the op table (no kVarying, no image): a texture of constants
    # folds too, to what the renderer computes.
    pc = core()
    prog = [("const", 0, (0.3, 0.7, 0.2)), ("const", 1, (1.0, 0.0, 0.0)), ("const", 2, (0.0, 0.0, 1.0)),
            ("const", 3, (2.0,)), ("checker", 4, 0, 1, 2, 3, "COLOR")]
    got = pc.fold_constant(prog, 4)
    # Cycles' checker at (0.3, 0.7, 0.2) x 2: floor parts (0, 1, 0), odd sum: colour 1.
    assert got[:3] == pytest.approx((1.0, 0.0, 0.0))
    assert pc.fold_constant([("const", 0, (1500.0,)), ("blackbody", 1, 0)], 1)[0] > 0.0


def test_the_parser_accepts_exactly_the_tables_value_ops():
    pc = core()
    ops = pc.shader_op_table()["ops"]
    for name in ops:  # known: refused for its missing operands, not as an unknown op
        with pytest.raises(ValueError) as e:
            pc.fold_constant([(name, 0)], 0)
        assert "unknown shader op" not in str(e.value), name
    with pytest.raises(ValueError, match="unknown shader op"):
        pc.fold_constant([("no_such_op", 0)], 0)
    # The add-on's register allocation reads the same counts.
    from addon.export.shader.registers import _operands
    assert all(_operands(name) == n for name, n in ops.items())
