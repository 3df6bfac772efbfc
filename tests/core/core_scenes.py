"""Small analytic scenes built directly with numpy for tests of the compiled core."""
import importlib
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]


def core():
    """The compiled module, imported the way the add-on imports it (as addon.pathlight_core)."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    return importlib.import_module("addon.pathlight_core")


def uv_sphere(radius=1.0, nu=48, nv=24, center=(0.0, 0.0, 0.0), inward=False):
    """Vertices, triangles and per-corner smooth normals of a UV sphere (poles stay degenerate)."""
    th = np.linspace(0.0, np.pi, nv + 1)
    ph = np.linspace(0.0, 2.0 * np.pi, nu + 1)[:-1]
    t, p = np.meshgrid(th, ph, indexing="ij")
    n = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nv), np.arange(nu), indexing="ij")
    a = (i * nu + j).ravel()
    b = (i * nu + (j + 1) % nu).ravel()
    c = ((i + 1) * nu + j).ravel()
    d = ((i + 1) * nu + (j + 1) % nu).ravel()
    tris = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    if inward:
        tris = tris[:, ::-1]
    pos = (n * radius + np.asarray(center)).astype(np.float32)
    normals = (n[tris] * (-1.0 if inward else 1.0)).astype(np.float32)
    return pos, tris.astype(np.int32), normals


def quad(corner, u, v):
    """Two triangles spanning corner, corner+u, corner+u+v, corner+v (normal = u x v)."""
    c = np.asarray(corner, np.float32)
    u = np.asarray(u, np.float32)
    v = np.asarray(v, np.float32)
    pos = np.stack([c, c + u, c + u + v, c + v]).astype(np.float32)
    return pos, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def random_rotation(seed):
    """A uniformly random rotation matrix (from a random unit quaternion)."""
    q = np.random.default_rng(seed).normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def look_at_matrix(eye, target, up=(0.0, 0.0, 1.0)):
    """Blender camera matrix: the camera looks down its local -Z with +Y up."""
    eye, target, up = (np.asarray(x, np.float64) for x in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    upv = np.cross(back, right)
    m = np.eye(4, dtype=np.float32)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, upv, back, eye
    return m


def add_object(pc_scene, pos, tris, material, normals=None, matrix=None):
    mesh = pc_scene.add_mesh(pos, tris, normals, None, [material])
    pc_scene.add_instance(mesh, np.eye(4, dtype=np.float32) if matrix is None else matrix)
    return mesh


def camera(pc, eye, target, lens=50.0, up=(0.0, 0.0, 1.0)):
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix(eye, target, up)
    cam.lens = lens
    return cam


def cornell(pc, light_strength=12.0, light_size=0.5):
    """A closed Cornell-like box (2 units) with an emissive quad under the ceiling and a sphere."""
    s = pc.Scene()
    white = s.add_material("white", (0.73, 0.73, 0.73))
    red = s.add_material("red", (0.65, 0.05, 0.05))
    green = s.add_material("green", (0.12, 0.45, 0.15))
    light = s.add_material("light", (0.0, 0.0, 0.0), (light_strength, light_strength * 0.85, light_strength * 0.6))
    walls = [
        (quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), white),   # floor
        (quad((-1, -1, 2), (0, 2, 0), (2, 0, 0)), white),   # ceiling
        (quad((-1, 1, 0), (2, 0, 0), (0, 0, 2)), white),    # back
        (quad((-1, -1, 0), (0, 2, 0), (0, 0, 2)), red),     # left
        (quad((1, -1, 0), (0, 0, 2), (0, 2, 0)), green),    # right
        (quad((-1, -1, 0), (0, 0, 2), (2, 0, 0)), white),   # front (behind the camera)
        (quad((-light_size / 2, -light_size / 2, 1.98), (light_size, 0, 0), (0, light_size, 0)), light),
    ]
    for (pos, tris), m in walls:
        add_object(s, pos, tris, m)
    pos, tris, nrm = uv_sphere(0.4, center=(0.3, 0.2, 0.4))
    add_object(s, pos, tris, white, nrm)
    s.set_camera(camera(pc, (0.0, -0.95, 1.0), (0.0, 1.0, 1.0), lens=16.0))
    return s


def run_session(pc, scene, width=64, height=64, samples=64, **kw):
    """A finished pc.Session of scene; kw: other RenderSettings fields."""
    st = pc.RenderSettings()
    st.width, st.height, st.samples = width, height, samples
    for k, v in kw.items():
        setattr(st, k, v)
    sess = pc.Session(scene, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    return sess


def render(pc, scene, width=64, height=64, samples=64, **kw):
    sess = run_session(pc, scene, width, height, samples, **kw)
    return sess.film(), sess.stats()


def emission_film(pc, ops_of, reg, size=1, extra=(), cam=None, max_bounces=0):
    """(film, stats) of a 4x4 quad at z = 0 seen straight down from z = 4, one sample at each
    pixel's centre (the smallest box filter), whose emission is register `reg` of the value ops
    ops_of(scene) returns (a function: the ops may add the images they read to the scene).
    extra: (positions, triangles) of grey objects beside it; cam: another camera."""
    s = pc.Scene()
    m = s.add_shader("m", list(ops_of(s)) + [("closure", "emission", None, {"color": reg})])
    pos, tris = quad((-2, -2, 0), (4, 0, 0), (0, 4, 0))
    add_object(s, pos, tris, m)
    for p, t in extra:
        add_object(s, p, t, s.add_material("grey", (0.5, 0.5, 0.5)))
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(cam or camera(pc, (0.0, 0.0, 4.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
    return render(pc, s, size, size, samples=1, max_bounces=max_bounces, filter_width=0.01)


def render_lit_mesh(pc, pos, tris, size=24, samples=4, **mesh_kw):
    """The film of one grey mesh (add_mesh's keywords: normals, uvs, ...) lit by a sun and seen
    obliquely from above: for checking that two ways of passing a mesh render alike."""
    s = pc.Scene()
    mat = s.add_material("grey", base_color=(0.8, 0.8, 0.8))
    s.add_instance(s.add_mesh(pos, tris, material_slots=[mat], **mesh_kw), np.eye(4, dtype=np.float32))
    s.add_sun_light((0.3, -0.5, 0.8), (2.0, 2.0, 2.0))
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix((0.0, -2.5, 2.0), (0.0, 0.0, 0.0))
    s.set_camera(cam)
    return render(pc, s, size, size, samples)[0]


def closure(kind, **params):
    """A shader program of one closure whose named inputs are constants (numbers or tuples)."""
    regs, prog = {}, []
    for i, (k, v) in enumerate(params.items()):
        prog.append(("const", i, v if isinstance(v, tuple) else (v,)))
        regs[k] = i
    prog.append(("closure", kind, None, regs))
    return prog


def region_means(img, grid=8):
    h, w = img.shape[:2]
    return img[: h // grid * grid, : w // grid * grid, :3].reshape(grid, h // grid, grid, w // grid, 3).mean(axis=(1, 3))


def sliver_room(seed=0, spheres=200, beams=60, sphere_res=(24, 12)):
    """An architectural scene where spatial splits matter (a procedural stand-in for Sponza): a
    20 x 20 x 8 room of 12 huge triangles, long thin beams and columns (boxes of sliver
    triangles) and small detailed spheres, all rotated off the axes, so the big triangles' boxes
    overlap everything. Returns (positions, triangles) of one mesh."""
    rng = np.random.default_rng(seed)
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]], float)
    faces = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],
                      [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    parts = [(corners * [20, 20, 8] + [-10, -10, -4], faces)]
    for _ in range(beams):
        y, z = rng.uniform(-9, 9), rng.uniform(-3.5, 3.5)
        parts.append((corners * [19.6, 0.15, 0.15] + [-9.8, y, z], faces))
    for _ in range(beams // 2):
        x, y = rng.uniform(-9, 9, 2)
        parts.append((corners * [0.2, 0.2, 8] + [x, y, -4], faces))
    for _ in range(spheres):
        c = rng.uniform([-9, -9, -3.5], [9, 9, 3.5])
        p, t, _ = uv_sphere(rng.uniform(0.1, 0.4), sphere_res[0], sphere_res[1], c)
        parts.append((p, t))
    pos, tris, base = [], [], 0
    for p, t in parts:
        pos.append(p)
        tris.append(np.asarray(t) + base)
        base += len(p)
    pos = (np.concatenate(pos) @ random_rotation(3).T).astype(np.float32)
    tris = np.concatenate(tris).astype(np.int32)
    v = pos[tris]
    keep = np.any(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]) != 0, axis=1)  # not the spheres' pole slivers
    return pos, tris[keep]


def furnace_scene(pc, albedo, smooth=True):
    """A unit sphere of grey diffuse `albedo` under a constant white world: the white furnace."""
    s = pc.Scene()
    m = s.add_material("sphere", (albedo, albedo, albedo))
    pos, tris, nrm = uv_sphere(1.0, nu=64, nv=32)
    add_object(s, pos, tris, m, nrm if smooth else None)
    s.set_world_color((1.0, 1.0, 1.0))
    s.set_camera(camera(pc, (0.0, -5.0, 0.0), (0.0, 0.0, 0.0), lens=50.0))
    return s


def emitting_enclosure(pc):
    """Inside a closed sphere of emission 0.5 and albedo 0.5: radiance Le / (1 - a) = 1 everywhere."""
    s = pc.Scene()
    m = s.add_material("shell", (0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
    pos, tris, nrm = uv_sphere(1.0, nu=32, nv=16, inward=True)
    add_object(s, pos, tris, m, nrm)
    s.set_camera(camera(pc, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), lens=20.0))
    return s
