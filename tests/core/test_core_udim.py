"""UDIM tile sets through the core module alone: the Image Texture lookup of a tile set picks
the tile from the UV's integer part (truncated, as Cycles' svm_node_tex_image) and reads it at
the fractional part under the node's interpolation and extension, each tile on its own (a
Linear lookup at a tile's edge never blends in its neighbour); a UV outside the tiles reads
Cycles' missing-texture magenta. The comparisons with Cycles are in
tests/blender/test_image_sources_cycles.py."""
import numpy as np
import pytest

from core_scenes import core, emission_film

pc = core()
pytestmark = pytest.mark.sanitize

RED = np.array([[[1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]],   # row 0 (bottom): red, black
                [[1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 1.0, 0.5]]], np.float32)  # white, half blue
GREEN = np.tile(np.array([0.0, 1.0, 0.0, 1.0], np.float32), (2, 2, 1))
BLUE = np.tile(np.array([0.0, 0.0, 1.0, 1.0], np.float32), (2, 2, 1))
MAGENTA = (1.0, 0.0, 1.0)


def lookups(uvs, interp="LINEAR", ext="REPEAT", plain=False):
    """The Image Texture colours (RGB) at each (u, v) of `uvs` of a tile set 1001 (RED),
    1002 (GREEN), 1011 (BLUE); plain: of the 1001 image alone."""
    def ops_at(u, v):
        def ops(s):
            red = s.add_image(RED)
            ids = [red, s.add_image(GREEN), s.add_image(BLUE)]
            tiles = s.add_image_tiles([(1001, ids[0]), (1002, ids[1]), (1011, ids[2])])
            return [("const", 0, (u, v, 0.0, 0.0)), ("image", 1, 0, red if plain else tiles, interp, ext)]
        return ops
    out = []
    for u, v in uvs:
        img, _ = emission_film(pc, ops_at(u, v), 1)
        out.append(img[0, 0, :3])
    return np.array(out)


@pytest.mark.parametrize("interp", ["LINEAR", "CLOSEST"])
def test_the_tile_of_the_uvs_integer_part(interp):
    got = lookups([(1.5, 0.5), (1.0, 0.25), (0.5, 1.5), (0.25, 1.0), (1.75, 0.999)], interp)
    assert np.allclose(got, [(0, 1, 0), (0, 1, 0), (0, 0, 1), (0, 0, 1), (0, 1, 0)], atol=1e-6)


@pytest.mark.parametrize("uv", [(1.5, 1.5), (2.5, 0.5), (-1.25, 0.5), (0.5, -1.5), (10.5, 0.5),
                                (-3e9, 0.5), (0.5, 1e30)])
def test_a_uv_outside_the_tiles_reads_magenta(uv):
    assert np.allclose(lookups([uv]), [MAGENTA])


@pytest.mark.parametrize("interp", ["LINEAR", "CLOSEST"])
@pytest.mark.parametrize("ext", ["REPEAT", "EXTEND", "CLIP"])
def test_each_tile_is_filtered_on_its_own_at_its_borders(interp, ext):
    """Near and across tile 1001's borders (and in (-1, 0), which truncation gives to tile
    1001) the set reads exactly what the 1001 image alone reads at the same UV."""
    uvs = [(0.999, 0.3), (0.001, 0.3), (0.3, 0.999), (0.999, 0.999), (-0.25, 0.3), (0.3, -0.6),
           (-0.999, -0.999), (0.5, 0.5)]
    tiled, plain = lookups(uvs, interp, ext), lookups(uvs, interp, ext, plain=True)
    assert np.allclose(tiled, plain, atol=1e-6), (tiled, plain)
    assert not np.allclose(tiled, tiled[:1])  # the cases do read different texels


def test_linear_at_a_tile_edge_never_blends_the_neighbour():
    # u = 0.999: texel column 1 of tile 1001, clamped (Extend) or wrapped to column 0 (Repeat);
    # tile 1002 is green, which neither may contain.
    extend, repeat = lookups([(0.999, 0.25)], "LINEAR", "EXTEND")[0], lookups([(0.999, 0.25)])[0]
    assert np.allclose(extend, RED[0, 1, :3], atol=1e-6)  # black: column 1 only
    t = 0.999 * 2 - 0.5 - 1  # x = 1.498: column 1, then 0.498 of column 2 = column 0 (wrapped)
    assert np.allclose(repeat, (1 - t) * RED[0, 1, :3] + t * RED[0, 0, :3], atol=1e-5), repeat
    assert extend[1] == 0.0 and repeat[1] == 0.0


def test_bad_tile_sets_are_refused():
    s = pc.Scene()
    a = s.add_image(GREEN)
    tiles = s.add_image_tiles([(1001, a)])
    for bad, why in [([], "at least one"), ([(1000, a)], "outside"), ([(2001, a)], "outside"),
                     ([(1001, a + 5)], "unknown image"), ([(1001, tiles)], "unknown image"),
                     ([(1001, a), (1001, a)], "twice")]:
        with pytest.raises(ValueError, match=why):
            s.add_image_tiles(bad)


def test_clip_fades_the_border_texels_as_cycles():
    """Clip as Cycles' kernel: texels beyond the image read zero, so Linear blends the border
    texel with zero within half a texel of the edge (inside and outside), Closest is the
    texel up to the edge and zero past it."""
    w = RED.shape[1]  # 2 texels: texel 0 of row 0 is red
    u = [0.5 / w, 0.25 / w, -0.25 / w, -0.6 / w, 1.0]
    linear = lookups([(x, 0.25) for x in u], "LINEAR", "CLIP", plain=True)[:, 0]
    # fx - 0.5 = -0.25 and -0.75: 0.75 and 0.25 of texel 0, the rest zero
    assert np.allclose(linear, [1.0, 0.75, 0.25, 0.0, 0.0], atol=1e-5), linear
    closest = lookups([(x, 0.25) for x in u], "CLOSEST", "CLIP", plain=True)[:, 0]
    assert np.allclose(closest, [1.0, 1.0, 0.0, 0.0, 0.0], atol=1e-6), closest
