"""Cryptomatte in the compiled core: the MurmurHash3 ids, and the per-pixel (id, coverage)
slots of a plane seen through a partly transparent one, against values known in closed form."""
import struct

import numpy as np
import pytest

from core_scenes import camera, core, quad, run_session

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif(not hasattr(pc, "cryptomatte_hash"), reason="core without Cryptomatte")]

EYE = (0.0, -5.0, 0.0)  # looking along +y at the plane y = 0


def as_bits(f):
    return struct.unpack("<I", struct.pack("<f", f))[0]


def test_murmur3_and_the_float_conversion():
    # Published MurmurHash3_x86_32 values (seed 0).
    assert pc.cryptomatte_hash("") == 0
    assert pc.cryptomatte_hash("hello") == 0x248BFA47
    assert pc.cryptomatte_hash("Hello, world!") == 0xC0363E43
    assert pc.cryptomatte_hash("The quick brown fox jumps over the lazy dog") == 0x2E4FF723
    # UTF-8 bytes, as Blender's names (tail lengths 1..3 all taken).
    assert pc.cryptomatte_hash("é") != pc.cryptomatte_hash("e")
    # uint32_to_float32: the bits, with the exponent kept in 1..254 (no 0, denormal, inf, NaN).
    for name in ("Cube", "Suzanne", "Material.001"):
        h = pc.cryptomatte_hash(name)
        if 1 <= (h >> 23) & 0xFF <= 254:  # (else the exponent is clamped, below)
            assert as_bits(np.float32(pc.cryptomatte_id(h))) == h
    assert as_bits(np.float32(pc.cryptomatte_id(0))) == 0x00800000
    assert as_bits(np.float32(pc.cryptomatte_id(0xFFFFFFFF))) == 0xFF7FFFFF
    assert as_bits(np.float32(pc.cryptomatte_id(0x3F800000))) == 0x3F800000


def wall(scene, mat, y, x0, x1, half=3.0, crypto=None):
    """A rectangle in the plane y, from x0 to x1 and -half to half in z, facing the camera."""
    pos, tris = quad((x0, y, -half), (0, 0, 2 * half), (x1 - x0, 0, 0))
    mesh = scene.add_mesh(pos, tris, None, None, [mat])
    scene.add_instance(mesh, np.eye(4, dtype=np.float32), cryptomatte=crypto)


def crypto_scene(transparency=0.25):
    """A grey back wall "Back" over the whole view; before it, over the left half (x < 0), a
    sheet "Sheet" whose material is a diffuse mixed with a Transparent BSDF of weight
    `transparency`; a small square "Patch" of the back wall's material on the right. Back and
    Patch share the asset "Set"."""
    s = pc.Scene()
    grey = s.add_material("Grey", (0.5, 0.5, 0.5))
    s.set_material_cryptomatte(grey, "Grey")
    w = 1.0 - transparency
    prog = [("const", 0, (0.8, 0.8, 0.8, 1.0)), ("const", 1, (w, w, w, 1.0)),
            ("closure", "diffuse", 1, {"color": 0}),
            ("const", 2, (transparency,) * 3 + (1.0,)), ("const", 3, (1.0, 1.0, 1.0, 1.0)),
            ("closure", "transparent", 2, {"color": 3})]
    veil = s.add_shader("Veil", prog)
    s.set_material_cryptomatte(veil, "Veil")
    wall(s, grey, 0.0, -10.0, 10.0, half=10.0, crypto=("Back", "Set"))
    wall(s, veil, -1.0, -10.0, 0.0, half=10.0, crypto=("Sheet", "Sheet"))
    wall(s, grey, -0.5, 0.3, 0.5, half=0.1, crypto=("Patch", "Set"))
    s.add_sun_light((0.0, -1.0, 0.3), (1.0, 1.0, 1.0))
    s.set_camera(camera(pc, EYE, (0, 0, 0)))
    return s


@pytest.fixture(scope="module")
def crypto_render():
    sess = run_session(pc, crypto_scene(), 32, 16, 16, threads=2, cryptomatte=["object", "material", "asset"],
                       cryptomatte_depth=4)
    return sess


def ids(*names):
    return [np.float32(pc.cryptomatte_id(pc.cryptomatte_hash(n))) for n in names]


def test_slots_rank_ids_by_coverage_through_a_transparent_sheet(crypto_render):
    back, sheet, patch = ids("Back", "Sheet", "Patch")
    obj0 = crypto_render.film_pass("CryptoObject00")
    obj1 = crypto_render.film_pass("CryptoObject01")
    assert obj0.shape == (16, 32, 4) and obj0.dtype == np.float32
    left, right = obj0[:, :14], obj0[:, 18:]
    # Left: the sheet is hit first by every sample with 1 - 0.25 of its weight; the back wall
    # gets the samples that pass (a quarter, each of weight 1), so the sheet ranks first.
    assert np.all(left[..., 0] == sheet)
    np.testing.assert_allclose(left[..., 1], 0.75, atol=1e-6)
    assert np.all(left[..., 2] == back)
    assert abs(left[..., 3].mean() - 0.25) < 0.03  # binomial noise over 16 x 14 x 16 samples
    np.testing.assert_allclose(left[..., 1] + left[..., 3], 1.0 - 0.25 + left[..., 3], atol=1e-6)
    # Right: the back wall alone, except where the patch covers it.
    pid = (right[..., 0] == patch) | (right[..., 2] == patch)
    assert 0 < pid.sum() < pid.size
    bare = right[~pid]
    assert np.all(bare[:, 0] == back) and np.allclose(bare[:, 1], 1.0) and np.all(bare[:, 2:] == 0)
    # Every pixel's coverage sums to 1 where nothing is missed (all ids fit the 4 slots).
    total = obj0[..., 1] + obj0[..., 3] + obj1[..., 1] + obj1[..., 3]
    np.testing.assert_allclose(total[:, 18:], 1.0, atol=1e-5)
    np.testing.assert_allclose(total[:, :14], 0.75 + left[..., 3], atol=1e-5)
    # Ranked: no later slot heavier than an earlier one.
    w = np.stack([obj0[..., 1], obj0[..., 3], obj1[..., 1], obj1[..., 3]], -1)
    assert np.all(np.diff(w, axis=-1) <= 0)


def test_material_and_asset_layers_merge_shared_names(crypto_render):
    grey, veil = ids("Grey", "Veil")
    mat = crypto_render.film_pass("CryptoMaterial00")
    # The back wall and the patch share the material: one slot of full weight on the right.
    np.testing.assert_array_equal(mat[:, 18:, 0], grey)
    np.testing.assert_allclose(mat[:, 18:, 1], 1.0, atol=1e-6)
    assert np.all(mat[:, :14, 0] == veil)
    asset = crypto_render.film_pass("CryptoAsset00")
    (set_,) = ids("Set")
    np.testing.assert_array_equal(asset[:, 18:, 0], set_)
    np.testing.assert_allclose(asset[:, 18:, 1], 1.0, atol=1e-6)


def test_depth_layers_and_refusals(crypto_render):
    with pytest.raises(ValueError, match="not requested"):
        crypto_render.film_pass("CryptoObject02")  # depth 4: two passes
    st = pc.RenderSettings()
    with pytest.raises(ValueError, match="unknown Cryptomatte layer"):
        st.cryptomatte = ["objects"]
    st.cryptomatte = ["asset", "object"]
    assert st.cryptomatte == ["object", "asset"]
    sess = run_session(pc, crypto_scene(), 8, 4, 1, threads=1, cryptomatte=["material"], cryptomatte_depth=1)
    with pytest.raises(ValueError, match="not requested"):
        sess.film_pass("CryptoObject00")
    assert sess.film_pass("CryptoMaterial00").shape == (4, 8, 4)
    with pytest.raises(ValueError, match="cryptomatte_depth"):
        run_session(pc, crypto_scene(), 8, 4, 1, cryptomatte=["object"], cryptomatte_depth=17)


def test_no_cost_without_the_passes():
    # Without Cryptomatte the render keeps its specialised kernel (compiled without any pass
    # code); with it, a kernel that has the passes.
    plain = run_session(pc, crypto_scene(0.0), 8, 4, 1, threads=1)
    crypto = run_session(pc, crypto_scene(0.0), 8, 4, 1, threads=1, cryptomatte=["object"])
    assert plain.stats()["kernel"] == "diffuse" and crypto.stats()["kernel"] != "diffuse"
    np.testing.assert_array_equal(plain.film(), crypto.film())  # and the same image
