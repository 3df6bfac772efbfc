"""Per-corner MikkTSpace tangents through add_mesh (issue 21): the Normal Map and Tangent ops
interpolate the mesh's tangents across each triangle, unnormalised and in object space, and
turn the result to world space as Cycles' svm_node_normal_map does. The comparison with
Cycles on a smooth normal-mapped sphere is in tests/blender/test_normal_map_tangents.py."""
import numpy as np
import pytest

from core_scenes import camera, core, quad, render

pc = core()
pytestmark = pytest.mark.sanitize

SIZE = 8
UV = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)


def tangent_field(p):
    """Object-space tangent at object-space points p (..., 3): linear, so that interpolating
    it from the corners gives it exactly at every point; its length varies (2 to ~2.8)."""
    p = np.asarray(p, np.float32)
    return np.stack([np.full(p.shape[:-1], 2.0, np.float32), p[..., 0], np.zeros(p.shape[:-1], np.float32)], -1)


def film(ops, tangents=True, sign=1.0, matrix=None):
    """8x8 film (one sample per pixel centre) of a 4x4 quad at z = 0 seen straight down whose
    emission is register 10 plus 1 (so that negative components stay emissive)."""
    s = pc.Scene()
    prog = list(ops) + [("const", 20, (1.0, 1.0, 1.0, 0.0)), ("const", 21, (1.0,)),
                        ("vector_math", 22, 10, 20, 20, 21, "ADD"),
                        ("closure", "emission", None, {"color": 22})]
    m = s.add_shader("m", prog)
    pos, tris = quad((-2, -2, 0), (4, 0, 0), (0, 4, 0))
    corner = pos[tris]  # (T, 3, 3)
    kw = {}
    if tangents:
        t = np.concatenate([tangent_field(corner), np.full(corner.shape[:-1] + (1,), sign, np.float32)], -1)
        kw["tangents"] = {0: np.ascontiguousarray(t, np.float32)}
    mesh = s.add_mesh(pos, tris, None, None, [m], uvs={0: UV}, **kw)
    s.add_instance(mesh, np.eye(4, dtype=np.float32) if matrix is None else np.asarray(matrix, np.float32))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, 0.0, 4.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
    img, stats = render(pc, s, SIZE, SIZE, samples=1, max_bounces=0, filter_width=0.01)
    assert stats["nonfinite_samples"] == 0
    return img[..., :3] - 1.0


def pixel_points():
    """World points (8, 8, 3) at the pixel centres (50 mm lens, 4 units away; row 0 = bottom)."""
    half = 18.0 / 50.0 * 4.0
    c = ((np.arange(SIZE) + 0.5) / SIZE * 2.0 - 1.0) * half
    x, y = np.meshgrid(c, c)
    return np.stack([x, y, np.zeros_like(x)], -1)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def normal_map(color, strength=None):
    ops = [("const", 0, tuple(color) + (1.0,))]
    if strength is not None:
        ops.append(("const", 1, (strength,)))
    return ops + [("normal_map", 10, 0, 1 if strength is not None else None, 0)]


def test_normal_map_follows_the_interpolated_tangent():
    # Colour (1, 0.5, 0.5) is the tangent itself: it turns across each triangle as the corner
    # tangents do (a per-triangle tangent would be one colour per triangle).
    img = film(normal_map((1.0, 0.5, 0.5)))
    expected = unit(tangent_field(pixel_points()))
    assert np.allclose(img, expected, atol=2e-3), np.abs(img - expected).max()
    below = np.tril_indices(SIZE, -1)  # rows below the diagonal: all in the first triangle
    assert np.ptp(img[below][:, 1]) > 0.3


def test_normal_map_weights_the_unnormalised_tangent_and_signed_bitangent():
    # (1, 0.5, 1) -> T + n with T unnormalised (|T| >= 2), as Cycles; an orthonormal frame
    # would give (T / |T| + n) instead.
    img = film(normal_map((1.0, 0.5, 1.0)))
    p = pixel_points()
    expected = unit(tangent_field(p) + np.array([0.0, 0.0, 1.0]))
    assert np.allclose(img, expected, atol=2e-3), np.abs(img - expected).max()
    # (0.5, 1, 0.5) -> sign * cross(n, T) with the corners' sign.
    img = film(normal_map((0.5, 1.0, 0.5)), sign=-1.0)
    expected = -unit(np.cross([0.0, 0.0, 1.0], tangent_field(p)))
    assert np.allclose(img, expected, atol=2e-3), np.abs(img - expected).max()


def test_normal_map_strength_blends_towards_the_shading_normal():
    img = film(normal_map((1.0, 0.5, 0.5), strength=0.5))
    mapped = unit(tangent_field(pixel_points()))
    n = np.array([0.0, 0.0, 1.0])
    expected = unit(n + (mapped - n) * 0.5)
    assert np.allclose(img, expected, atol=2e-3), np.abs(img - expected).max()


@pytest.mark.parametrize("matrix", [
    [[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],  # a quarter turn about z
    [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],   # non-uniform scale
])
def test_normal_map_is_computed_in_object_space_and_turned_as_a_normal(matrix):
    m = np.asarray(matrix, np.float64)
    img = film(normal_map((1.0, 0.5, 1.0)), matrix=m)
    p_obj = pixel_points() @ np.linalg.inv(m[:3, :3]).T
    n_obj = unit(tangent_field(p_obj) + np.array([0.0, 0.0, 1.0]))
    expected = unit(n_obj @ np.linalg.inv(m[:3, :3]))  # the inverse transpose
    assert np.allclose(img, expected, atol=2e-3), np.abs(img - expected).max()


def test_tangent_node_uses_the_interpolated_tangent():
    img = film([("tangent", 10, "UV_MAP", 0)])
    expected = unit(tangent_field(pixel_points()))  # already perpendicular to n = z
    assert np.allclose(img, expected, atol=2e-3), np.abs(img - expected).max()


def test_without_tangents_the_per_triangle_tangent_stays():
    img = film(normal_map((1.0, 0.5, 0.5)), tangents=False)
    # One uv-derived tangent (+x) for the whole quad, as before.
    assert np.allclose(img, [1.0, 0.0, 0.0], atol=2e-3), img


def test_tangents_are_validated():
    s = pc.Scene()
    pos, tris = quad((-2, -2, 0), (4, 0, 0), (0, 4, 0))
    with pytest.raises(ValueError, match="tangents must have shape"):
        s.add_mesh(pos, tris, uvs={0: UV}, tangents={0: np.zeros((2, 3, 3), np.float32)})
    with pytest.raises(ValueError, match="tangent set index"):
        s.add_mesh(pos, tris, uvs={0: UV}, tangents={8: np.zeros((2, 3, 4), np.float32)})


@pytest.mark.parametrize("tangents", [True, False])
def test_every_op_that_reads_uv_tangents_still_gets_them(tangents):
    # A hit computes the uv tangents only for materials with an op that reads them
    # (Material::uses_tangents); each reader must still find them, from the mesh's tangents or
    # from the triangle's uvs (+x here).
    expected = unit(tangent_field(pixel_points())) if tangents else np.array([1.0, 0.0, 0.0])
    for ops in ([("tangent", 10, "UV_MAP", 0)], normal_map((1.0, 0.5, 0.5)),
                [("const", 0, (0.25, 0.0, 0.0)), ("tangent_displacement", 10, 0, 0)]):
        img = film(ops, tangents=tangents)
        if ops[-1][0] == "tangent_displacement":  # a quarter of the object-space tangent
            img = unit(img)  # (|T| <= 2.8 times 0.25: no component of the emission below 0)
        assert np.allclose(img, expected, atol=2e-3), (ops[-1][0], np.abs(img - expected).max())
