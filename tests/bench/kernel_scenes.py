"""Core-only scenes for the kernel benchmarks and callgrind profiles (no bpy, so they run under
valgrind): a replica of blender_scenes/cornell_box.blend (the same walls, light, box, sphere,
camera and materials as make_fixtures.py) built straight into the core."""
import sys
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
import os  # noqa: E402
from core_scenes import add_object, uv_sphere  # noqa: E402
from core_scenes import core as _core  # noqa: E402


def core():
    """The module of addon/, or the one in $PL_CORE_DIR (a profiling build with -g)."""
    if os.environ.get("PL_CORE_DIR"):
        sys.path.insert(0, os.environ["PL_CORE_DIR"])
        import pathlight_core
        return pathlight_core
    return _core()

WHITE, RED, GREEN = (0.73, 0.73, 0.73), (0.63, 0.065, 0.05), (0.14, 0.45, 0.091)


def _quad(corners):
    return np.asarray(corners, np.float32), np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def _box(center, size, angle_z):
    """Blender's create_cube(size=1) scaled by `size`, rotated about z, moved to `center`."""
    c, s = np.cos(angle_z), np.sin(angle_z)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    corners = np.array([[x, y, z] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5)])
    pos = (corners * np.asarray(size)) @ rot.T + np.asarray(center)
    # outward-facing faces (index = 4x + 2y + z)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c_, d in faces for t in ((a, b, c_), (a, c_, d))]
    return pos.astype(np.float32), np.asarray(tris, np.int32)


# Blender's default material as the add-on compiles it: a Principled BSDF with Multiscatter GGX
# and its default inputs (Base Color 0.8, Roughness 0.5, IOR 1.5).
DEFAULT_PRINCIPLED = [("const", 0, (0.8, 0.8, 0.8)), ("const", 1, (0.5,)), ("const", 2, (1.5,)),
                      ("const", 3, (1.0,)),
                      ("closure", "principled", None,
                       {"base_color": 0, "roughness": 1, "ior": 2, "multiscatter": 3})]


def cornell_fixture(pc=None, glass=False, principled=False):
    """The Cornell box fixture, uncommitted; glass: its sphere made of clear glass (IOR 1.5),
    as bench_equal_time's glass Cornell box; principled: its white surfaces made of Blender's
    default material (DEFAULT_PRINCIPLED)."""
    pc = pc or core()
    s = pc.Scene()
    white, red, green = (s.add_material(n, c) for n, c in (("White", WHITE), ("Red", RED), ("Green", GREEN)))
    if principled:
        white = s.add_shader("Material", DEFAULT_PRINCIPLED)
    light = s.add_material("Light", (0.0, 0.0, 0.0), tuple(12.0 * np.array([1.0, 0.85, 0.65])))
    walls = [
        ([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], white),
        ([(-1, -1, 2), (-1, 1, 2), (1, 1, 2), (1, -1, 2)], white),
        ([(-1, 1, 0), (1, 1, 0), (1, 1, 2), (-1, 1, 2)], white),
        ([(-1, -1, 0), (-1, 1, 0), (-1, 1, 2), (-1, -1, 2)], red),
        ([(1, -1, 0), (1, -1, 2), (1, 1, 2), (1, 1, 0)], green),
    ]
    for corners, m in walls:
        add_object(s, *_quad(corners), m)
    q = 0.25
    add_object(s, *_quad([(-q, 0.1 - q, 1.98), (-q, 0.1 + q, 1.98), (q, 0.1 + q, 1.98), (q, 0.1 - q, 1.98)]), light)
    add_object(s, *_box((-0.35, 0.3, 0.6), (0.55, 0.55, 1.2), np.radians(28.0)), white)
    pos, tris, nrm = uv_sphere(0.35, center=(0.42, -0.3, 0.35))
    sphere = white
    if glass:
        sphere = s.add_shader("Glass", [("const", 0, (0.0,)), ("const", 1, (1.5,)),
                                        ("closure", "glass", None, {"roughness": 0, "ior": 1})])
    add_object(s, pos, tris, sphere, nrm)
    cam = pc.Camera()
    m = np.eye(4, dtype=np.float32)
    # rotation_euler (90 deg, 0, 0): local -Z looks along +y, local +Y is world +z
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = (1, 0, 0), (0, 0, 1), (0, -1, 0), (0, -4, 1)
    cam.matrix_world = m
    cam.lens = 50.0
    s.set_camera(cam)
    return s


def settings(pc, width=64, height=64, samples=16, **kw):
    st = pc.RenderSettings()
    st.width, st.height, st.samples = width, height, samples
    st.filter_type, st.filter_width = "blackman_harris", 1.5  # the add-on's default, as Cycles
    for k, v in kw.items():
        setattr(st, k, v)
    return st


def instrumented_render(pc, scene, st):
    """Renders `scene` with callgrind's instrumentation switched on around the render only (the
    process runs under valgrind --instr-atstart=no); returns the session's stats."""
    import subprocess
    sess = pc.Session(scene, st)
    subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], capture_output=True)
    sess.start()
    while not sess.wait(1.0):
        pass
    subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], capture_output=True)
    return sess.stats()
