"""The OpenVDB reader and sparse volume grid (issue 23), without Blender: .vdb files written by
tests/core/vdb_writer.py (every codec, active-mask metadata kind, half floats, value type,
transform and tile level), the decompressors against known data, sampling and the majorant, and
hostile files (truncated, flipped, absurd counts), each of which must raise a Python exception.
Blender-written files (VolumeGrids.save) are read in tests/blender/test_vdb_files.py."""
import struct
import zlib

import numpy as np
import pytest

import vdb_writer as vw
from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
ERRORS = (RuntimeError, ValueError)


def f_analytic(i, j, k):
    return 0.25 + 0.01 * i - 0.02 * j + 0.005 * k * k


def grid_with_leaves(origins, fn=f_analytic, active=None, **kw):
    g = vw.Grid(**kw)
    for o in origins:
        idx = np.indices((8, 8, 8))
        vals = fn(idx[0] + o[0], idx[1] + o[1], idx[2] + o[2])
        act = np.ones((8, 8, 8), bool) if active is None else active(idx[0] + o[0], idx[1] + o[1], idx[2] + o[2])
        g.leaves[tuple(o)] = (vals, act)
    return g


ORIGINS = [(0, 0, 0), (8, 0, 0), (0, 8, 16), (120, 128, -8), (-4096, 4088, 0)]


def expected_leaf(g, o):
    return np.asarray(g.leaves[o][0], np.float64)


# ---------------------------------------------------------------- codecs

def test_lz4_decodes_literals_matches_and_overlapping_runs():
    rng = np.random.default_rng(1)
    cases = [b"", b"a", bytes(rng.integers(0, 256, 1000, dtype=np.uint8)), b"ab" * 700,
             bytes(300) + b"xyz" * 50 + bytes(rng.integers(0, 4, 3000, dtype=np.uint8))]
    for data in cases:
        comp = vw.lz4_compress(data)
        assert pc.vdb_decompress("lz4", comp, len(data)) == data
    assert len(vw.lz4_compress(b"ab" * 700)) < 40  # long overlapping match, length extensions
    # Hand-made block: literal "abc", then a match of 10 at offset 3 (overlapping copy), then "!".
    block = bytes([0x36]) + b"abc" + struct.pack("<H", 3) + bytes([0x10]) + b"!"
    assert pc.vdb_decompress("lz4", block, 14) == b"abcabcabcabca!"


@pytest.mark.parametrize("bad", [b"\x36abc\x00\x00\x10!",   # offset 0
                                 b"\x36abc\x09\x00\x10!",   # offset before the output
                                 b"\xf0\xff\xff",           # literal length past the data
                                 b"\x36ab"])                # truncated literals
def test_lz4_refuses_corrupt_blocks(bad):
    with pytest.raises(RuntimeError, match="LZ4"):
        pc.vdb_decompress("lz4", bad, 14)


@pytest.mark.parametrize("typesize", [1, 2, 4, 12])
@pytest.mark.parametrize("layout", ["one_block", "blocks_leftover", "split", "memcpy", "raw_streams"])
def test_blosc_frames(typesize, layout):
    rng = np.random.default_rng(typesize)
    data = np.repeat(rng.integers(0, 7, 400, dtype=np.uint8), 5).tobytes()[: 2048 - 2048 % typesize + 5]
    args = {"one_block": {}, "blocks_leftover": {"blocksize": 12 * 64}, "split": {"split": True, "blocksize": 1536},
            "memcpy": {"memcpy": True}, "raw_streams": {"compress": False, "blocksize": 12 * 64}}[layout]
    frame = vw.blosc_frame(data, typesize, **args)
    assert pc.vdb_decompress("blosc", frame, len(data)) == data
    with pytest.raises(RuntimeError, match="Blosc"):
        pc.vdb_decompress("blosc", frame, len(data) + 1)  # the frame says another size
    with pytest.raises(RuntimeError):
        pc.vdb_decompress("blosc", frame[: len(frame) // 2], len(data))


def test_blosc_refuses_other_compressors_and_bitshuffle():
    frame = bytearray(vw.blosc_frame(bytes(range(256)) * 4, 4))
    other = bytearray(frame)
    other[2] = (other[2] & 0x1F) | (0 << 5)  # BloscLZ
    with pytest.raises(RuntimeError, match="compressor 0"):
        pc.vdb_decompress("blosc", bytes(other), 1024)
    frame[2] |= 0x4
    with pytest.raises(RuntimeError, match="bit shuffle"):
        pc.vdb_decompress("blosc", bytes(frame), 1024)


def test_zip_codec():
    if not pc.build_info()["zlib"]:
        with pytest.raises(RuntimeError, match="zlib"):
            pc.vdb_decompress("zip", zlib.compress(b"abc"), 3)
        pytest.skip("core built without zlib")
    data = bytes(range(256)) * 10
    assert pc.vdb_decompress("zip", zlib.compress(data), len(data)) == data
    with pytest.raises(RuntimeError, match="ZIP"):
        pc.vdb_decompress("zip", zlib.compress(data)[:-3], len(data))


# ---------------------------------------------------------------- grids

CODECS = ["none", "zip", "zip-raw", "blosc", "blosc-split"]


@pytest.mark.parametrize("codec", CODECS)
@pytest.mark.parametrize("active_mask", [True, False])
@pytest.mark.parametrize("half", [False, True])
def test_float_grid_values_every_codec(codec, active_mask, half):
    if codec.startswith("zip") and not pc.build_info()["zlib"]:
        pytest.skip("core built without zlib")
    act = lambda i, j, k: (i + j + k) % 3 != 0  # noqa: E731  inactive voxels keep their values
    g = grid_with_leaves(ORIGINS, active=act, codec=codec.split("-")[0] if codec != "zip-raw" else codec,
                         active_mask=active_mask, half=half, background=0.0,
                         transform=("ScaleTranslateMap", (0.5, 0.25, 2.0), (1.0, -2.0, 3.0)))
    if codec == "blosc-split":
        g.blosc_args = {"split": True}
    (info,) = pc.read_vdb_bytes(vw.write_vdb([g]))
    assert info["skipped"] is None and info["type"] == "float" and info["half_float"] == half
    flags = {"none": 0, "zip": 1, "zip-raw": 1, "blosc": 4, "blosc-split": 4}[codec] | (2 if active_mask else 0)
    assert info["compression"] == flags
    grid = info["grid"]
    tol = 2e-3 if half else 0
    for o in ORIGINS:
        vals = grid.voxels(o, tuple(c + 7 for c in o))
        idx = np.indices((8, 8, 8))
        exp = f_analytic(idx[0] + o[0], idx[1] + o[1], idx[2] + o[2])
        # The inactive voxels hold many distinct values: written in full (metadata 6) and kept.
        np.testing.assert_allclose(vals, exp.astype(np.float32), rtol=tol, atol=tol)
    n_active = sum(int(act(*(np.indices((8, 8, 8)) + np.reshape(o, (3, 1, 1, 1)))).sum()) for o in ORIGINS)
    assert info["voxel_count"] == n_active
    assert info["bbox_min"] == (-4096, 0, -8) and info["bbox_max"] == (127, 4095, 23)
    assert grid.leaf_count == len(ORIGINS)


def test_inactive_value_kinds_are_restored():
    """Leaves whose inactive voxels hold nothing / -background / one value / {bg, -bg} /
    {bg, v} / {v, w} / many values: the writer picks metadata 0..6 and the reader restores them."""
    bg = 0.5
    patterns = [lambda i: np.full(i.shape, bg), lambda i: np.full(i.shape, -bg), lambda i: np.full(i.shape, 3.0),
                lambda i: np.where(i % 2 == 0, bg, -bg), lambda i: np.where(i % 2 == 0, bg, 7.0),
                lambda i: np.where(i % 2 == 0, 2.0, 9.0), lambda i: i * 0.1]
    g = vw.Grid(codec="blosc", background=bg)
    rng = np.random.default_rng(5)
    for n, pat in enumerate(patterns):
        act = rng.random((8, 8, 8)) < 0.4
        idx = np.arange(512).reshape(8, 8, 8)
        vals = np.where(act, rng.random((8, 8, 8)) + 10, pat(idx))
        g.leaves[(8 * n, 0, 0)] = (vals, act)
    grid = pc.read_vdb_bytes(vw.write_vdb([g]))[0]["grid"]
    assert set(g.node_metadata) >= {0, 1, 2, 3, 4, 5, 6}
    for n in range(len(patterns)):
        np.testing.assert_array_equal(grid.voxels((8 * n, 0, 0), (8 * n + 7, 7, 7)),
                                      g.leaves[(8 * n, 0, 0)][0].astype(np.float32))


def test_tiles_at_every_level_and_the_background():
    g = grid_with_leaves([(0, 0, 0)], background=0.125, codec="zip" if pc.build_info()["zlib"] else "none")
    g.tiles = [(8, (8, 0, 0), 2.0, True), (8, (16, 0, 0), 3.0, False), (128, (128, 0, 0), 4.0, True),
               (4096, (4096, 0, 0), 0.125, True)]
    (info,) = pc.read_vdb_bytes(vw.write_vdb([g]))
    grid = info["grid"]
    assert info["background"] == 0.125
    v = lambda *p: float(grid.voxels(p, p)[0, 0, 0])  # noqa: E731
    assert v(9, 1, 2) == 2.0 and v(23, 7, 7) == 3.0 and v(200, 100, 5) == 4.0
    assert v(5000, 17, 3) == 0.125 and v(-100, 0, 0) == 0.125 and v(24, 0, 0) == 0.125
    assert info["voxel_count"] == 512 + 512 + 128 ** 3 + 4096 ** 3
    assert info["bbox_min"] == (0, 0, 0) and info["bbox_max"] == (8191, 4095, 4095)


def test_root_tile_with_a_value_over_a_huge_extent_is_refused():
    g = grid_with_leaves([(0, 0, 0)])
    g.tiles = [(4096, (0, 0, 4096), 1.0, True)]  # 4096^3 voxels of density 1: no dense table
    with pytest.raises(RuntimeError, match="extent"):
        pc.read_vdb_bytes(vw.write_vdb([g]))


@pytest.mark.parametrize("value_type", ["double", "vec3s", "int32", "bool"])
def test_value_types(value_type):
    if value_type == "vec3s":
        fn = lambda i, j, k: np.stack([i * 1.0, j * 2.0, k - 3.0], -1)  # noqa: E731
        bg = (0.0, 0.0, 0.0)
    elif value_type == "bool":
        fn = lambda i, j, k: (i + j + k) % 2  # noqa: E731
        bg = 0
    else:
        fn = lambda i, j, k: i * 7 - j + 3 * k  # noqa: E731
        bg = 0
    g = grid_with_leaves([(0, 0, 0), (16, 8, 0)], fn=fn, value_type=value_type, background=bg, codec="blosc",
                         name="v")
    (info,) = pc.read_vdb_bytes(vw.write_vdb([g]))
    assert info["type"] == value_type and info["channels"] == (3 if value_type == "vec3s" else 1)
    for o in [(0, 0, 0), (16, 8, 0)]:
        idx = np.indices((8, 8, 8))
        exp = np.asarray(fn(idx[0] + o[0], idx[1] + o[1], idx[2] + o[2]), np.float32)
        np.testing.assert_array_equal(info["grid"].voxels(o, tuple(c + 7 for c in o)), exp)


def test_unknown_types_are_skipped_with_a_message_and_grids_selectable():
    a = grid_with_leaves([(0, 0, 0)], name="density")
    b = grid_with_leaves([(0, 0, 0)], name="temperature", fn=lambda i, j, k: i + 0.0 * j)
    data = vw.write_vdb([a, b]).replace(b"Tree_float_5_4_3", b"Tree_qloat_5_4_3", 1)
    infos = pc.read_vdb_bytes(data)
    assert infos[0]["grid"] is None and "not supported" in infos[0]["skipped"]
    assert infos[1]["name"] == "temperature" and infos[1]["grid"] is not None
    only = pc.read_vdb_bytes(vw.write_vdb([a, b]), grid="temperature")
    assert only[0]["grid"] is None and only[0]["skipped"] == "not requested" and only[1]["grid"] is not None
    topo = pc.read_vdb_bytes(vw.write_vdb([a, b]), topology_only=True)
    assert [t["name"] for t in topo] == ["density", "temperature"]


AFFINE = np.array([[0.0, 0.5, 0, 0], [-0.5, 0.0, 0, 0], [0, 0, 2.0, 0], [1.0, 2.0, 3.0, 1.0]])


@pytest.mark.parametrize("transform, matrix", [
    (("UniformScaleMap", 0.25), np.diag([0.25, 0.25, 0.25, 1.0])),
    (("ScaleMap", (0.1, 0.2, 0.3)), np.diag([0.1, 0.2, 0.3, 1.0])),
    (("UniformScaleTranslateMap", 0.5, (1, 2, 3)), np.array([[.5, 0, 0, 1], [0, .5, 0, 2], [0, 0, .5, 3], [0, 0, 0, 1]])),
    (("ScaleTranslateMap", (1, 2, 4), (-1, 0, 1)), np.array([[1, 0, 0, -1], [0, 2, 0, 0], [0, 0, 4, 1], [0, 0, 0, 1]])),
    (("TranslationMap", (5, 6, 7)), np.array([[1, 0, 0, 5], [0, 1, 0, 6], [0, 0, 1, 7], [0, 0, 0, 1.0]])),
    (("AffineMap", AFFINE), AFFINE.T),
    (("UnitaryMap", AFFINE), AFFINE.T),
])
def test_transforms_and_object_space_sampling(transform, matrix):
    g = grid_with_leaves([(0, 0, 0), (8, 0, 0)], transform=transform)
    (info,) = pc.read_vdb_bytes(vw.write_vdb([g]))
    np.testing.assert_allclose(info["transform"], matrix, atol=1e-12)
    grid = info["grid"]
    ijk = np.array([[1, 2, 3], [9.5, 2.25, 6.75], [0.0, 0.0, 0.0], [15, 7, 7]])
    obj = (matrix @ np.c_[ijk, np.ones(len(ijk))].T).T[:, :3]
    lin = grid.sample(obj.astype(np.float32))
    np.testing.assert_allclose(lin, grid.sample_index(ijk.astype(np.float32)), rtol=1e-5, atol=1e-5)


def test_unsupported_transform_is_an_error():
    g = grid_with_leaves([(0, 0, 0)], transform=("NonlinearFrustumMap", b"\0" * 64))
    with pytest.raises(RuntimeError, match="NonlinearFrustumMap"):
        pc.read_vdb_bytes(vw.write_vdb([g]))
    g = grid_with_leaves([(0, 0, 0)], transform=("ScaleMap", (1.0, 0.0, 1.0)))
    with pytest.raises(RuntimeError, match="singular"):
        pc.read_vdb_bytes(vw.write_vdb([g]))


def test_trilinear_and_closest_sampling():
    lin = lambda i, j, k: 1.0 + 0.5 * i - 0.25 * j + 0.125 * k  # noqa: E731  trilinear reproduces it
    g = grid_with_leaves([(0, 0, 0), (8, 0, 0), (0, 8, 0), (8, 8, 0)], fn=lin, background=0.0)
    grid = pc.read_vdb_bytes(vw.write_vdb([g]))[0]["grid"]
    rng = np.random.default_rng(3)
    p = rng.uniform([0, 0, 0], [15, 15, 7], (500, 3)).astype(np.float32)
    np.testing.assert_allclose(grid.sample_index(p), lin(*p.T.astype(np.float64)), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(grid.sample_index(p, "closest"), lin(*np.floor(p.T.astype(np.float64) + 0.5)),
                               rtol=1e-6)
    # Half a voxel past the last voxel: halfway to the background.
    edge = grid.sample_index(np.array([[15.5, 3, 3]], np.float32))[0]
    assert edge == pytest.approx(0.5 * lin(15, 3, 3), rel=1e-5)
    assert grid.sample_index(np.array([[1e30, 0, 0], [np.nan, 0, 0]], np.float32)).tolist() == [0.0, 0.0]
    with pytest.raises(ValueError, match="mode"):
        grid.sample_index(p, "quadratic")  # ("cubic" is a mode since Cubic interpolation)


def test_trilinear_matches_a_dense_reference_across_bricks_and_tiles():
    rng = np.random.default_rng(9)
    g = grid_with_leaves([(0, 0, 0), (8, 8, 8), (0, 8, 0), (16, 0, 8)],
                         fn=lambda i, j, k: rng.random(np.shape(i)), background=0.25, name="r")
    g.tiles = [(8, (8, 0, 0), 3.0, True)]
    grid = pc.read_vdb_bytes(vw.write_vdb([g]))[0]["grid"]
    dense = grid.voxels((-2, -2, -2), (26, 26, 26)).astype(np.float64)
    p = rng.uniform(-1.5, 25.5, (5000, 3))
    p[:500] = np.floor(p[:500]) + rng.choice([0.0, 0.5, 0.999], (500, 3))  # on and near voxel centres
    i0 = np.floor(p).astype(int)
    t = p - i0
    ref = np.zeros(len(p))
    for n in range(8):
        d = np.array([n & 1, (n >> 1) & 1, n >> 2])
        w = np.prod(np.where(d, t, 1 - t), axis=1)
        ijk = i0 + d + 2
        ref += w * dense[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
    np.testing.assert_allclose(grid.sample_index(p.astype(np.float32)), ref, rtol=2e-5, atol=2e-5)


def test_majorant_bounds_every_sample():
    rng = np.random.default_rng(7)
    origins = [(0, 0, 0), (8, 0, 0), (16, 8, 0), (40, 40, 40)]
    g = grid_with_leaves(origins, fn=lambda i, j, k: rng.random(np.shape(i)) ** 4 * 10)
    grid = pc.read_vdb_bytes(vw.write_vdb([g]))[0]["grid"]
    p = rng.uniform(-12, 60, (20000, 3)).astype(np.float32)
    vals, maj = grid.sample_index(p), grid.majorant(p, index_space=True)
    assert np.all(maj >= vals)
    assert np.mean(maj) < 0.5 * grid.max_value  # and it is not a single global bound
    origin, cell, cells = grid.majorant_grid()
    assert cell == 8 and cells.max() == pytest.approx(grid.max_value)
    assert grid.majorant(np.array([[1e6, 0, 0]], np.float32), index_space=True)[0] == 0.0


def test_nonfinite_values_become_zero_and_are_counted():
    def fn(i, j, k):
        v = np.ones(np.shape(i))
        v[0, 0, 0], v[1, 0, 0], v[2, 0, 0] = np.nan, np.inf, -np.inf
        return v
    g = grid_with_leaves([(0, 0, 0)], fn=fn)
    (info,) = pc.read_vdb_bytes(vw.write_vdb([g]))
    assert info["nonfinite_replaced"] == 3
    vals = info["grid"].voxels((0, 0, 0), (7, 7, 7))
    assert np.all(np.isfinite(vals)) and vals[0, 0, 0] == 0 and vals[3, 0, 0] == 1


def test_memory_is_sparse():
    origins = [(8 * i, 8 * j, 8 * k) for i in range(8) for j in range(8) for k in range(2)]  # 64x64x16 voxels
    origins += [(2048, 2048, 2048)]  # one far leaf: the table spans 256^3 bricks, not voxels
    g = grid_with_leaves(origins, codec="blosc")
    grid = pc.read_vdb_bytes(vw.write_vdb([g]))[0]["grid"]
    bricks = len(origins) * 512 * 4
    table = 257 * 257 * 257 * 4
    assert grid.memory_bytes < 1.2 * bricks + table + 260 ** 3 * 4 + 4096
    assert grid.leaf_count == len(origins)


# ---------------------------------------------------------------- hostile files

def sample_file():
    g = grid_with_leaves(ORIGINS[:3], codec="blosc", active=lambda i, j, k: (i * j + k) % 4 != 0, background=0.0)
    g.tiles = [(8, (32, 0, 0), 2.0, True)]
    h = grid_with_leaves([(0, 0, 0)], codec="zip" if pc.build_info()["zlib"] else "none", name="t", half=True)
    return vw.write_vdb([g, h])


def test_truncations_raise():
    data = sample_file()
    assert len(pc.read_vdb_bytes(data)) == 2
    cuts = sorted({len(data) * n // 16 for n in range(16)} | set(range(0, 200, 7)) | {len(data) - 1})
    for cut in cuts:
        with pytest.raises(ERRORS):
            pc.read_vdb_bytes(data[:cut])


def test_flipped_bytes_raise_or_read():
    data = sample_file()
    rng = np.random.default_rng(11)
    raised = 0
    for _ in range(400):
        b = bytearray(data)
        for pos in rng.integers(0, len(b), rng.integers(1, 4)):
            b[pos] ^= 1 << int(rng.integers(0, 8))
        try:
            for info in pc.read_vdb_bytes(bytes(b)):
                if info["grid"] is not None:
                    assert np.all(np.isfinite(info["grid"].voxels((0, 0, 0), (15, 15, 15))))
        except ERRORS:
            raised += 1
    assert raised > 100


def patch(data, offset, fmt, value):
    b = bytearray(data)
    struct.pack_into(fmt, b, offset, value)
    return bytes(b)


def test_absurd_counts_and_sizes_raise():
    g = grid_with_leaves([(0, 0, 0)], codec="blosc")
    data = vw.write_vdb([g])
    hdr = 8 + 4 + 8 + 1 + 36
    cases = {
        "magic": patch(data, 0, "<q", 0x12345678),
        "version": patch(data, 8, "<I", 300),
        "old version": patch(data, 8, "<I", 221),
        "file metadata count": patch(data, hdr, "<I", 0xFFFFFFFF),
        "grid count": patch(data, hdr + 4, "<i", 2 ** 31 - 1),
        "negative grid count": patch(data, hdr + 4, "<i", -5),
        "name length": patch(data, hdr + 8, "<I", 0xFFFFFFF0),
    }
    name_end = hdr + 8 + 4 + len("density") + 4 + len("Tree_float_5_4_3") + 4
    grid_pos = struct.unpack_from("<q", data, name_end)[0]
    cases["grid offset"] = patch(data, name_end, "<q", -1)
    cases["grid end"] = patch(data, name_end + 16, "<q", 2 ** 62)
    cases["compression flags"] = patch(data, grid_pos, "<I", 0x80)
    cases["grid metadata count"] = patch(data, grid_pos + 4, "<I", 10 ** 9)
    tree = data.index(b"UniformScaleMap") + len("UniformScaleMap") + 5 * 24
    cases["buffer count"] = patch(data, tree, "<i", 7)
    cases["root tiles"] = patch(data, tree + 8, "<I", 0xFFFFFFFF)
    cases["root children"] = patch(data, tree + 12, "<I", 0xFFFFFF)
    cases["root origin"] = patch(data, tree + 16, "<i", 5)
    frame = data.rindex(b"\x02\x01")  # the leaf's Blosc frame header
    cases["blosc nbytes"] = patch(data, frame + 4, "<I", 0x7FFFFFFF)
    cases["blosc blocksize"] = patch(data, frame + 8, "<I", 0)
    cases["blosc cbytes"] = patch(data, frame + 12, "<I", 0xFFFFFFFF)
    cases["compressed size"] = patch(data, frame - 8, "<q", 2 ** 40)
    cases["negative size"] = patch(data, frame - 8, "<q", -(2 ** 40))
    cases["node metadata"] = patch(data, frame - 9, "<b", 42)
    for what, bad in cases.items():
        with pytest.raises(ERRORS):
            pc.read_vdb_bytes(bad)
            pytest.fail(f"{what}: no exception")


def test_leaf_limit_and_missing_files(tmp_path):
    data = vw.write_vdb([grid_with_leaves(ORIGINS)])
    with pytest.raises(RuntimeError, match="limit"):
        pc.read_vdb_bytes(data, max_bricks=2)
    with pytest.raises(RuntimeError, match="cannot open"):
        pc.read_vdb(str(tmp_path / "missing.vdb"))
    (tmp_path / "empty.vdb").write_bytes(b"")
    with pytest.raises(RuntimeError, match="truncated"):
        pc.read_vdb(str(tmp_path / "empty.vdb"))
    (tmp_path / "ok.vdb").write_bytes(data)
    assert pc.read_vdb(str(tmp_path / "ok.vdb"))[0]["leaf_count"] == len(ORIGINS)


def test_hypothesis_mutations_raise_or_read():
    """Hypothesis (derandomized, as test_fuzz_core.py): a valid two-grid file with byte patches
    (anywhere, or inside the tree and buffers), optionally truncated: the reader raises or
    returns grids whose voxels are finite."""
    hypothesis = pytest.importorskip("hypothesis")
    from hypothesis import HealthCheck, given, settings, strategies as st

    data = sample_file()
    patches = st.lists(st.tuples(st.integers(0, len(data) - 1), st.integers(0, 255)), min_size=1, max_size=6)

    @settings(max_examples=300, derandomize=True, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(patches, st.one_of(st.none(), st.integers(0, len(data))), st.sampled_from(["x", "y"]))
    def check(patch_list, cut, _):
        b = bytearray(data)
        for pos, val in patch_list:
            b[pos] = val
        if cut is not None:
            b = b[:cut]
        try:
            infos = pc.read_vdb_bytes(bytes(b))
        except ERRORS:
            return
        for info in infos:
            if info["grid"] is not None:
                g = info["grid"]
                assert np.all(np.isfinite(g.voxels((0, 0, 0), (15, 15, 15))))
                assert np.isfinite(g.sample_index(np.zeros((1, 3), np.float32))).all()
    check()
