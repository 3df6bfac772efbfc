"""Per-instance object attributes (add_instance's attributes, the object_attribute op) and the
normal_map op's object / world spaces through the core module: each instance reads its own
slots, missing slots read 0, non-finite values become 0, bad input is refused. Agreement with
Cycles is tested through Blender (tests/blender/test_object_attributes.py)."""
import numpy as np
import pytest

from core_scenes import camera, core, quad, render

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run


def two_quads(program, attributes):
    """Two unit quads facing the camera, left and right, one per attributes entry."""
    s = pc.Scene()
    m = s.add_shader("t", program)
    pos, tris = quad((-0.5, -0.5, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    mesh = s.add_mesh(pos, tris, material_slots=[m])
    for x, attrs in zip((-0.6, 0.6), attributes):
        mat = np.eye(4, dtype=np.float32)
        mat[0, 3] = x
        kw = {} if attrs is None else {"attributes": np.asarray(attrs, np.float32)}
        s.add_instance(mesh, mat, **kw)
    s.set_world_color((0.0, 0.0, 0.0))
    cam = camera(pc, (0.0, 0.0, 6.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    s.set_camera(cam)
    img, stats = render(pc, s, 16, 8, samples=1, max_bounces=1)
    assert stats["nonfinite_samples"] == 0
    return img[3:5, 5:7, :3].mean(axis=(0, 1)), img[3:5, 9:11, :3].mean(axis=(0, 1))


@pytest.mark.parametrize("output, pick", [("COLOR", lambda v: v[:3]), ("FAC", lambda v: [np.mean(v[:3])] * 3),
                                          ("ALPHA", lambda v: [v[3]] * 3)])
def test_each_instance_reads_its_slots(output, pick):
    a = [[0.1, 0.2, 0.3, 0.4], [0.9, 0.5, 0.25, 0.75]]
    b = [[0.6, 0.7, 0.8, 0.2], [0.05, 0.1, 0.15, 0.5]]
    prog = [("object_attribute", 0, 1, output), ("closure", "emission", None, {"color": 0})]
    left, right = two_quads(prog, [a, b])
    assert np.allclose(left, pick(a[1]), atol=1e-5), left
    assert np.allclose(right, pick(b[1]), atol=1e-5), right


def test_missing_slots_and_non_finite_values_read_zero():
    prog = [("object_attribute", 0, 2, "COLOR"), ("object_attribute", 1, 0, "COLOR"),
            ("vector_math", 2, 0, 1, None, None, "ADD"), ("closure", "emission", None, {"color": 2})]
    left, right = two_quads(prog, [None, [[np.nan, np.inf, 0.5, 1.0]]])
    assert np.allclose(left, 0.0) and np.allclose(right, (0.0, 0.0, 0.5), atol=1e-5), (left, right)


@pytest.mark.parametrize("attrs", [np.zeros((9, 4)), np.zeros((2, 3)), np.zeros(4)])
def test_bad_instance_attributes_are_refused(attrs):
    s = pc.Scene()
    m = s.add_material("m")
    pos, tris = quad((0, 0, 0), (1, 0, 0), (0, 1, 0))
    mesh = s.add_mesh(pos, tris, material_slots=[m])
    with pytest.raises((ValueError, TypeError)):
        s.add_instance(mesh, np.eye(4, dtype=np.float32), attributes=attrs.astype(np.float32))


@pytest.mark.parametrize("op", [("object_attribute", 1, 8, "COLOR"), ("object_attribute", 1, 0, "NAME"),
                                ("normal_map", 1, 0, None, 0, "SCREEN")])
def test_bad_op_settings_are_refused(op):
    s = pc.Scene()
    with pytest.raises((ValueError, TypeError)):
        s.add_shader("bad", [("const", 0, (0.5, 0.5, 1.0)), op, ("closure", "emission", None, {"color": 1})])


@pytest.mark.parametrize("space, expect", [
    ("WORLD", (0.0, 0.6, 0.8)), ("BLENDER_WORLD", (0.0, -0.6, -0.8)),
    # A quarter turn about z: object +y is world -x.
    ("OBJECT", (-0.6, 0.0, 0.8)), ("BLENDER_OBJECT", (0.6, 0.0, -0.8)),
])
def test_normal_map_spaces(space, expect):
    """The normal map's normal (emitted as n / 2 + 1/2) of the colour (0.5, 0.8, 0.9): 2c - 1 =
    (0, 0.6, 0.8), y and z negated in the Blender spaces, turned by the instance in object space."""
    prog = [("const", 0, (0.5, 0.8, 0.9)), ("normal_map", 1, 0, None, 0, space),
            ("const", 2, (0.5, 0.5, 0.5)), ("vector_math", 3, 1, 2, 2, None, "MULTIPLY_ADD"),
            ("closure", "emission", None, {"color": 3})]
    s = pc.Scene()
    m = s.add_shader("t", prog)
    pos, tris = quad((-1.0, -1.0, 0.0), (2.0, 0.0, 0.0), (0.0, 2.0, 0.0))
    mesh = s.add_mesh(pos, tris, material_slots=[m])
    turn = np.array([[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], np.float32)
    s.add_instance(mesh, turn)
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, 0.0, 6.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
    img, stats = render(pc, s, 8, 8, samples=1, max_bounces=1)
    n = img[3:5, 3:5, :3].mean(axis=(0, 1)) * 2.0 - 1.0
    # Emission is clamped at 0: compare where n / 2 + 1/2 is positive (all of it here).
    assert np.allclose(n, expect, atol=1e-4), (space, n)


def two_strand_sets(program, attributes):
    """Two Curves objects of one thick vertical strand each, left and right, one per attributes
    entry (None: no attributes): the program's colour at each."""
    s = pc.Scene()
    m = s.add_shader("t", program)
    pts = np.array([[0.0, -2.0, 0.0], [0.0, 2.0, 0.0]], np.float32)
    for x, attrs in zip((-0.6, 0.6), attributes):
        mat = np.eye(4, dtype=np.float32)
        mat[0, 3] = x
        kw = {} if attrs is None else {"attributes": np.asarray(attrs, np.float32)}
        s.add_curves(pts, np.array([0, 2]), np.full(2, 0.5, np.float32), m, matrix=mat,
                     curve_type="poly", **kw)
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0.0, 0.0, 6.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
    img, stats = render(pc, s, 16, 8, samples=1, max_bounces=1)
    assert stats["nonfinite_samples"] == 0
    return img[3:5, 5:7, :3].mean(axis=(0, 1)), img[3:5, 9:11, :3].mean(axis=(0, 1))


def test_curves_read_their_own_slots():
    """add_curves' attributes: each Curves object reads its own slots (as add_instance's), a
    set without them or a slot past its count reads 0, non-finite values read 0."""
    a = [[0.1, 0.2, 0.3, 0.4], [0.9, 0.5, 0.25, 0.75]]
    b = [[0.6, 0.7, 0.8, 0.2], [0.05, np.nan, 0.15, 0.5]]
    prog = [("object_attribute", 0, 1, "COLOR"), ("closure", "emission", None, {"color": 0})]
    left, right = two_strand_sets(prog, [a, b])
    assert np.allclose(left, a[1][:3], atol=1e-5), left
    assert np.allclose(right, (0.05, 0.0, 0.15), atol=1e-5), right
    left, right = two_strand_sets(prog, [None, a[:1]])
    assert np.allclose(left, 0.0) and np.allclose(right, 0.0), (left, right)


@pytest.mark.parametrize("attrs", [np.zeros((9, 4)), np.zeros((2, 3)), np.zeros(4)])
def test_bad_curves_attributes_are_refused(attrs):
    s = pc.Scene()
    m = s.add_material("m")
    with pytest.raises((ValueError, TypeError)):
        s.add_curves(np.zeros((2, 3), np.float32) + [[0, 0, 0], [0, 1, 0]], np.array([0, 2]), None, m,
                     attributes=attrs.astype(np.float32))
