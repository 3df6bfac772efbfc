"""Materials as shader programs, through the core module: closed-form furnace, Beer's law,
textures (Closest vs Linear), transparency and transparent shadows, normal maps, and program
validation."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, render, uv_sphere

pc = core()


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


def closure(kind, **params):
    regs, prog = {}, []
    for i, (k, v) in enumerate(params.items()):
        prog.append(("const", i, v if isinstance(v, tuple) else (v,)))
        regs[k] = i
    prog.append(("closure", kind, None, regs))
    return prog


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
                 [("closure", "velvet", None, {})], [("math", 0, 0, 0, "TANGENT", False)],
                 [("mapping", 0, 0, np.zeros((2, 2)))], [("uv", 0, 9)]):
        with pytest.raises((ValueError, RuntimeError)):
            s.add_shader("bad", prog)
    with pytest.raises(ValueError):
        s.add_image(np.zeros((4, 4, 3), np.float32))
    # NaN constants become 0 rather than poisoning renders.
    s.add_shader("nan", [("const", 0, (np.nan, 1.0, 1.0)), ("closure", "diffuse", None, {"color": 0})])
