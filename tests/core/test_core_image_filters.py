"""Image Texture filters and projections through the core module alone, against a numpy model
of Cycles' CPU kernel (kernel/device/cpu/image.h: interp_closest / _linear / _cubic with its
wrap_periodic, wrap_clamp, wrap_mirror and read_clip; svm_image.h: texco_remap_square,
map_to_sphere, map_to_tube and svm_node_tex_image_box). The lookups sit near and across the
image's borders, where the extensions differ. The comparisons with Cycles' renders are in
tests/blender/test_image_projection_cycles.py."""
import numpy as np
import pytest

from core_scenes import core, emission_film

pc = core()
pytestmark = pytest.mark.sanitize

# A 3 x 4 RGBA image (row 0 = bottom), every texel different, alpha varying too.
IMG = np.random.default_rng(7).uniform(0.05, 1.0, size=(3, 4, 4)).astype(np.float32)
TILE2 = np.tile(np.array([0.0, 1.0, 0.0, 1.0], np.float32), (2, 2, 1))


# ---------------------------------------------------------------- numpy model of Cycles

def _frac(x):
    """Cycles' frac(x, &ix): float_to_int(x) - (x < 0)."""
    x = np.float32(x)
    i = int(x) - (1 if x < 0 else 0)
    return np.float32(x - np.float32(i)), i


def _wrap(i, n, ext):
    if ext == "REPEAT":
        i %= n
        return i
    if ext == "EXTEND":
        return min(max(i, 0), n - 1)
    if ext == "MIRROR":
        m = abs(i + (1 if i < 0 else 0)) % (2 * n)
        return 2 * n - m - 1 if m >= n else m
    return i  # CLIP: read_clip below


def _read(img, x, y):
    h, w = img.shape[:2]
    if x < 0 or x >= w or y < 0 or y >= h:
        return np.zeros(4, np.float32)
    return img[y, x].astype(np.float64)


def _weights(t):
    t = float(t)
    return [(((-1 / 6) * t + 0.5) * t - 0.5) * t + 1 / 6, ((0.5 * t - 1.0) * t) * t + 2 / 3,
            ((-0.5 * t + 0.5) * t + 0.5) * t + 1 / 6, (1 / 6) * t * t * t]


def cycles_lookup(img, u, v, interp, ext):
    h, w = img.shape[:2]
    fx, fy = np.float32(u) * np.float32(w), np.float32(v) * np.float32(h)
    if interp == "CLOSEST":
        _, ix = _frac(fx)
        _, iy = _frac(fy)
        if ext == "CLIP" and (ix < 0 or ix >= w or iy < 0 or iy >= h):
            return np.zeros(4)
        return _read(img, _wrap(ix, w, ext), _wrap(iy, h, ext))
    tx, ix = _frac(fx - np.float32(0.5))
    ty, iy = _frac(fy - np.float32(0.5))
    if interp == "LINEAR":
        if ext == "CLIP" and (ix < -1 or ix >= w or iy < -1 or iy >= h):
            return np.zeros(4)
        xs, ys = [ix, ix + 1], [iy, iy + 1]
        wx, wy = [1 - float(tx), float(tx)], [1 - float(ty), float(ty)]
    else:  # CUBIC
        if ext == "CLIP" and (ix < -2 or ix > w or iy < -2 or iy > h):
            return np.zeros(4)
        xs, ys = [ix - 1, ix, ix + 1, ix + 2], [iy - 1, iy, iy + 1, iy + 2]
        wx, wy = _weights(tx), _weights(ty)
    r = np.zeros(4)
    for j, y in enumerate(ys):
        for i, x in enumerate(xs):
            r += wy[j] * wx[i] * _read(img, _wrap(x, w, ext), _wrap(y, h, ext))
    return r


def cycles_sphere(co):
    c = (np.asarray(co, np.float64) - 0.5) * 2.0
    l2 = float(c @ c)
    if l2 <= 0:
        return 0.0, 0.0
    u = 0.0 if c[0] == 0 and c[1] == 0 else 0.5 - np.arctan2(c[0], c[1]) / (2 * np.pi)
    return u, 1.0 - np.arccos(np.clip(c[2] / np.sqrt(l2), -1, 1)) / np.pi


def cycles_tube(co):
    c = (np.asarray(co, np.float64) - 0.5) * 2.0
    ln = np.hypot(c[0], c[1])
    if ln <= 0:
        return 0.0, 0.0
    return (1.0 - np.arctan2(c[0] / ln, c[1] / ln) / np.pi) * 0.5, (c[2] + 1.0) * 0.5


def _box_weights(sn, blend):
    """Cycles' Box weights of the three axes for object-space normal `sn`."""
    a = np.abs(sn)
    with np.errstate(invalid="ignore"):  # (a zero normal: NaN, as Cycles)
        a = a / a.sum()
    w = np.zeros(3)
    limit = 0.5 * (1 + blend)
    if a[0] > limit * (a[0] + a[1]) and a[0] > limit * (a[0] + a[2]):
        w[0] = 1
    elif a[1] > limit * (a[0] + a[1]) and a[1] > limit * (a[1] + a[2]):
        w[1] = 1
    elif a[2] > limit * (a[0] + a[2]) and a[2] > limit * (a[1] + a[2]):
        w[2] = 1
    elif blend > 0:
        if a[2] < (1 - limit) * (a[1] + a[0]):
            w[0] = np.clip((a[0] / (a[0] + a[1]) - 0.5 * (1 - blend)) / blend, 0, 1)
            w[1] = 1 - w[0]
        elif a[0] < (1 - limit) * (a[1] + a[2]):
            w[1] = np.clip((a[1] / (a[1] + a[2]) - 0.5 * (1 - blend)) / blend, 0, 1)
            w[2] = 1 - w[1]
        elif a[1] < (1 - limit) * (a[0] + a[2]):
            w[0] = np.clip((a[0] / (a[0] + a[2]) - 0.5 * (1 - blend)) / blend, 0, 1)
            w[2] = 1 - w[0]
        else:
            w = ((2 - limit) * a + (limit - 1)) / (2 * limit - 1)
    else:
        w[0] = 1
    return w


def cycles_box(img, co, n, blend, interp, ext):
    sn = np.asarray(n, np.float64)
    w = _box_weights(sn, blend)
    x, y, z = co
    r = np.zeros(4)
    if w[0] > 0:
        r += w[0] * cycles_lookup(img, 1 - y if sn[0] < 0 else y, z, interp, ext)
    if w[1] > 0:
        r += w[1] * cycles_lookup(img, 1 - x if sn[1] > 0 else x, z, interp, ext)
    if w[2] > 0:
        r += w[2] * cycles_lookup(img, 1 - y if sn[2] > 0 else y, x, interp, ext)
    return r


# ---------------------------------------------------------------- the core's lookups

def run(ops_of, cases):
    """The RGB each case's program emits (1x1 renders of an emission quad): ops_of(scene, case)
    gives the value ops, whose register 9 is emitted. (Filtering treats the channels alike, so
    RGB stands for alpha too.)"""
    out = []
    for case in cases:
        img, _ = emission_film(pc, lambda s: ops_of(s, case), 9)
        out.append(img[0, 0, :3])
    return np.array(out)


def image_ops(uv, interp, ext, tiled=False):
    def ops(s, case):
        img = s.add_image(IMG)
        if tiled:
            img = s.add_image_tiles([(1001, img), (1002, s.add_image(TILE2))])
        return [("const", 0, (uv[case][0], uv[case][1], 0.0, 0.0)), ("image", 9, 0, img, interp, ext)]
    return ops


BORDER_UVS = [(u, v) for u in (-0.61, -0.13, -0.02, 0.03, 0.11, 0.37, 0.52, 0.88, 0.97, 1.04, 1.19, 1.71)
              for v in (-0.4, 0.06, 0.5, 0.94, 1.3)]


@pytest.mark.parametrize("interp", ["CUBIC", "LINEAR", "CLOSEST"])
@pytest.mark.parametrize("ext", ["REPEAT", "EXTEND", "CLIP", "MIRROR"])
def test_filters_at_the_borders_as_cycles(interp, ext):
    uvs = BORDER_UVS
    got = run(image_ops(uvs, interp, ext), range(len(uvs)))
    want = np.array([cycles_lookup(IMG, u, v, interp, ext)[:3] for u, v in uvs])
    assert np.allclose(got, want, atol=2e-5), np.abs(got - want).max(axis=1)


@pytest.mark.parametrize("interp", ["CUBIC", "LINEAR"])
@pytest.mark.parametrize("ext", ["MIRROR", "CLIP"])
def test_a_tile_set_filters_each_tile_on_its_own(interp, ext):
    """Cubic and Mirror on tile 1001 of a set read what the image alone reads (in (-1, 0), which
    truncation gives to tile 1001, too); tile 1002 (green) never bleeds in."""
    uvs = [(0.02, 0.5), (0.97, 0.2), (0.5, 0.98), (-0.3, 0.4), (0.4, -0.7)]
    got = run(image_ops(uvs, interp, ext, tiled=True), range(len(uvs)))
    want = np.array([cycles_lookup(IMG, u, v, interp, ext)[:3] for u, v in uvs])
    assert np.allclose(got, want, atol=2e-5), np.abs(got - want).max(axis=1)


def test_cubic_is_the_b_spline_not_linear():
    """Cubic smooths a texel's own value (a B-spline does not interpolate): at a texel centre it
    reads 2/3 of it and 1/6 of each neighbour along each axis."""
    uv = [(1.5 / 4, 1.5 / 3)]  # texel (1, 1)'s centre
    got = run(image_ops(uv, "CUBIC", "REPEAT"), [0])[0]
    k = np.array([1 / 6, 2 / 3, 1 / 6])
    want = np.einsum("i,j,ijc->c", k, k, IMG[0:3, 0:3, :3].astype(np.float64))
    assert np.allclose(got, want, atol=2e-5)
    assert not np.allclose(got, IMG[1, 1, :3], atol=1e-3)


PROJ_COS = [(0.9, 0.5, 0.5), (0.1, 0.7, 0.2), (0.5, 0.5, 0.95), (0.5, 0.5, 0.5), (0.3, 0.2, 0.8),
            (0.5, 0.5, 0.1), (0.72, 0.29, 0.61), (1.4, -0.3, 0.5)]


@pytest.mark.parametrize("projection", ["SPHERE", "TUBE"])
def test_sphere_and_tube_map_the_vector_as_cycles(projection):
    def ops(s, case):
        img = s.add_image(IMG)
        return [("const", 0, PROJ_COS[case] + (0.0,)), ("image_proj", 1, 0, projection),
                ("image", 9, 1, img, "LINEAR", "REPEAT")]
    got = run(ops, range(len(PROJ_COS)))
    model = cycles_sphere if projection == "SPHERE" else cycles_tube
    want = np.array([cycles_lookup(IMG, *model(co), "LINEAR", "REPEAT")[:3] for co in PROJ_COS])
    assert np.allclose(got, want, atol=2e-5), np.abs(got - want).max(axis=1)


BOX_CASES = [((0.3, 0.6, 0.2), n, blend) for n in
             [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (0.8, 0.5, 0.1),
              (-0.6, 0.62, 0.05), (0.1, -0.55, 0.6), (0.5, 0.1, -0.6), (0.57, 0.58, 0.58),
              (0.4, 0.5, 0.45), (0, 0, 0)]
             for blend in (0.0, 0.3, 1.0)]


@pytest.mark.parametrize("interp", ["LINEAR", "CUBIC"])
def test_box_weights_and_flips_as_cycles(interp):
    def ops(s, case):
        co, n, blend = BOX_CASES[case]
        img = s.add_image(IMG)
        return [("const", 0, co + (0.0,)), ("const", 1, tuple(map(float, n)) + (0.0,)),
                ("image_box", 9, 0, 1, img, interp, "REPEAT", blend)]
    got = run(ops, range(len(BOX_CASES)))
    want = np.array([cycles_box(IMG, co, n, b, interp, "REPEAT")[:3] for co, n, b in BOX_CASES])
    assert np.allclose(got, want, atol=3e-5), np.abs(got - want).max(axis=1)


def test_box_reads_a_tile_sets_first_tile():
    """As Cycles (the Box node gets the handle's first svm slot): tile 1001 at any coordinate,
    never the missing-texture magenta, never tile 1002."""
    cases = [(0.3, 0.6, 0.2), (1.4, 0.5, 0.5), (2.5, 3.5, 7.25)]

    def ops(s, case):
        img = s.add_image_tiles([(1001, s.add_image(IMG)), (1002, s.add_image(TILE2))])
        return [("const", 0, cases[case] + (0.0,)), ("const", 1, (0.2, 0.3, 0.9, 0.0)),
                ("image_box", 9, 0, 1, img, "LINEAR", "REPEAT", 0.0)]
    got = run(ops, range(len(cases)))
    want = np.array([cycles_box(IMG, co, (0.2, 0.3, 0.9), 0.0, "LINEAR", "REPEAT")[:3] for co in cases])
    assert np.allclose(got, want, atol=2e-5)


def test_bad_box_and_projection_ops_are_refused():
    s = pc.Scene()
    img = s.add_image(IMG)
    for prog in ([("const", 0, (0.0,)), ("image_proj", 1, 0, "CUBE")],
                 [("const", 0, (0.0,)), ("image_box", 1, 0, 0, img, "LINEAR", "REPEAT", float("nan"))],
                 [("const", 0, (0.0,)), ("image_box", 1, 0, 0, img + 5, "LINEAR", "REPEAT", 0.0)],
                 [("const", 0, (0.0,)), ("image", 1, 0, img, "SMART", "REPEAT")]):
        with pytest.raises(ValueError):
            s.add_shader("bad", prog + [("closure", "emission", None, {"color": 1})])


def test_box_unassociates_each_lookup_before_weighting():
    """With the Alpha output in use (unassociate), each of Box's lookups is divided by its own
    filtered alpha before the weights apply, as svm_image_texture does per lookup."""
    co, n = (0.3, 0.6, 0.2), (0.57, 0.58, 0.4)

    def ops(s, case, unassociate=True):
        return [("const", 0, co + (0.0,)), ("const", 1, n + (0.0,)),
                ("image_box", 9, 0, 1, s.add_image(IMG), "LINEAR", "REPEAT", 0.5) + ((True,) if unassociate else ())]
    got = run(ops, [0])[0]
    weights = _box_weights(np.asarray(n, np.float64), 0.5)
    assert (weights > 0).sum() == 3  # (all three lookups take part)
    want = np.zeros(3)
    for k, (u, v) in enumerate(((co[1], co[2]), (1 - co[0], co[2]), (1 - co[1], co[0]))):
        r = cycles_lookup(IMG, u, v, "LINEAR", "REPEAT")
        want += weights[k] * r[:3] / r[3]
    assert np.allclose(got, want, atol=3e-5), (got, want)
    plain = run(lambda s, c: ops(s, c, False), [0])[0]
    assert not np.allclose(plain, want, atol=1e-3)  # (the division matters here)
