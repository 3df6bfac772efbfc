"""True displacement in the core (Scene.displace_mesh, scene/displace.h) without Blender: a
material's displacement program moves each vertex once by its world offset turned to object
space, normals are recomputed ('DISPLACEMENT') or kept ('BOTH'), deformation steps move with the
frame, and bad offsets are dropped or shortened, never crash."""
import numpy as np
import pytest

from core_scenes import core

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

DIFFUSE = [("const", 0, (0.8, 0.8, 0.8, 1.0)), ("closure", "diffuse", None, {"color": 0})]


def grid(n=6):
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    pos = np.stack([x, y, np.zeros_like(x)], -1).reshape(-1, 3).astype(np.float32)
    i = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    tris = np.concatenate([np.stack([i, i + 1, i + n + 2], 1), np.stack([i, i + n + 2, i + n + 1], 1)])
    nrm = np.tile(np.float32([0, 0, 1]), (len(pos), 1))
    return pos, tris.astype(np.int32), nrm


def height_program(amount):
    """Offset along the shading normal by `amount` times the world x coordinate."""
    return [("position", 0), ("separate", 1, 0, 0), ("const", 2, (amount, amount, amount, 1.0)),
            ("math", 3, 1, 2, "MULTIPLY", False), ("normal", 4),
            ("vector_math", 5, 4, 4, 4, 3, "SCALE"),
            ("closure", "displacement", None, {"offset": 5})]


def const_program(v):
    return [("const", 0, tuple(v) + (0.0,)), ("closure", "displacement", None, {"offset": 0})]


def scene_with(program, method="DISPLACEMENT"):
    s = pc.Scene()
    plain = s.add_shader("plain", DIFFUSE)
    disp = s.add_shader("disp", DIFFUSE, displacement=program, displacement_method=method)
    return s, plain, disp


def test_vertices_move_by_the_program_at_their_world_position_in_object_space():
    pos, tris, nrm = grid()
    s, _, disp = scene_with(height_program(0.5))
    m = np.diag([2.0, 2.0, 4.0, 1.0]).astype(np.float32)
    m[:3, 3] = (1.0, 0.0, 0.0)
    out = s.displace_mesh(pos, tris, material_slots=[disp], matrix=m, normals=nrm, normal_indices=tris)
    assert out["displaced"] == len(pos) and out["clamped"] == 0
    world_x = 2.0 * pos[:, 0] + 1.0
    # World offset 0.5 * x along +Z, back to object space through the scale 4.
    np.testing.assert_allclose(out["positions"][:, 2], 0.5 * world_x / 4.0, atol=1e-5)
    np.testing.assert_allclose(out["positions"][:, :2], pos[:, :2], atol=1e-6)
    # 'DISPLACEMENT': the normals are the displaced faces' (a tilted plane's), per vertex.
    n = out["normals"][out["normal_indices"]]
    want = np.float32([-0.5 * 2.0 / 4.0, 0.0, 1.0])  # d(z_obj)/d(x_obj) = 0.25
    want /= np.linalg.norm(want)
    np.testing.assert_allclose(n.reshape(-1, 3), np.broadcast_to(want, (n.size // 3, 3)), atol=1e-4)


def test_both_keeps_the_normals_and_bump_only_materials_change_nothing():
    pos, tris, nrm = grid()
    s, plain, disp = scene_with(height_program(0.5), method="BOTH")
    out = s.displace_mesh(pos, tris, material_slots=[disp], normals=nrm, normal_indices=tris)
    assert not np.allclose(out["positions"], pos)
    n = out.get("normals")
    if n is not None:
        np.testing.assert_allclose(n[out["normal_indices"]].reshape(-1, 3), nrm[tris].reshape(-1, 3))
    assert s.displace_mesh(pos, tris, material_slots=[plain], normals=nrm, normal_indices=tris) is None


def test_a_vertex_shared_with_an_undisplaced_triangle_moves_once_and_the_rest_stay():
    pos, tris, nrm = grid()
    s, plain, disp = scene_with(const_program((0.0, 0.0, 0.3)))
    mats = np.zeros(len(tris), np.int32)
    mats[: len(tris) // 2] = 1  # the first half displaces
    out = s.displace_mesh(pos, tris, material_indices=mats, material_slots=[plain, disp],
                          normals=nrm, normal_indices=tris)
    moved = np.unique(tris[: len(tris) // 2])
    assert out["displaced"] == len(moved)
    dz = out["positions"][:, 2] - pos[:, 2]
    np.testing.assert_allclose(dz[moved], 0.3, atol=1e-6)
    rest = np.setdiff1d(np.arange(len(pos)), moved)
    np.testing.assert_allclose(dz[rest], 0.0)


def test_flat_triangles_take_their_displaced_face_normal_and_motion_steps_move_too():
    pos, tris, nrm = grid(2)
    s, _, disp = scene_with(height_program(1.0), method="BOTH")
    steps = np.stack([pos, pos + np.float32([0.0, 0.1, 0.0])])
    out = s.displace_mesh(pos, tris, material_slots=[disp], normals=nrm, normal_indices=tris,
                          flat=np.ones(len(tris), bool), motion_positions=steps)
    d = out["positions"] - pos
    np.testing.assert_allclose(out["motion_positions"] - steps, np.stack([d, d]), atol=1e-6)
    p = out["positions"][tris]
    face = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    face /= np.linalg.norm(face, axis=1, keepdims=True)
    n = out["normals"][out["normal_indices"]]
    np.testing.assert_allclose(n, np.repeat(face[:, None], 3, 1), atol=1e-5)


OVERFLOW = [("const", 0, (1e30, 0.0, 0.0, 0.0)),  # 1e30 * 1e30: inf in x, 0 * inf: nan in y
            ("const", 1, (1e30, 1e30, 0.0, 0.0)), ("const", 2, (0.0, 0.0, 0.0, 0.0)),
            ("vector_math", 3, 0, 1, 2, 2, "MULTIPLY"), ("vector_math", 4, 3, 3, 2, 2, "MULTIPLY"),
            ("closure", "displacement", None, {"offset": 4})]


@pytest.mark.parametrize("program", [OVERFLOW, const_program((1e30, 0.0, 0.0))], ids=["non-finite", "huge"])
def test_bad_offsets_are_dropped_or_shortened(program):
    pos, tris, nrm = grid(2)
    s, _, disp = scene_with(program)
    out = s.displace_mesh(pos, tris, material_slots=[disp], normals=nrm, normal_indices=tris)
    assert np.isfinite(out["positions"]).all() and np.isfinite(out["normals"]).all()
    d = out["positions"] - pos
    assert np.all(np.linalg.norm(d, axis=1) <= 1e4 * 1.0001)
    if program is not OVERFLOW:  # (the shader VM itself already zeroes non-finite values)
        assert out["clamped"] == len(pos)
        np.testing.assert_allclose(d[:, 0], 1e4, rtol=1e-5)


def test_bad_displacement_programs_raise():
    s = pc.Scene()
    with pytest.raises(ValueError):
        s.add_shader("x", DIFFUSE, displacement=[("const", 0, (0, 0, 1, 0))])  # no output op
    with pytest.raises(ValueError):
        s.add_shader("x", DIFFUSE, displacement=const_program((0, 0, 1)), displacement_method="BUMP")
    pos, tris, nrm = grid(2)
    with pytest.raises(ValueError):
        s.displace_mesh(pos, tris, flat=np.ones(3, bool))
