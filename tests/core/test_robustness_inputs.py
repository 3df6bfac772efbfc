"""Hostile input to the core module (issue 7): every call either raises a clear Python exception
or renders cleanly (finite, non-negative film, no dropped samples); nothing crashes, hangs or
reads memory it does not own. Inputs that crashed the module run in a fresh interpreter, so a
regression fails one test instead of killing the run (and a sanitizer build reports it there)."""
import gc
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from core_scenes import REPO, add_object, camera, core, cornell, quad, render

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
TESTS = REPO / "tests" / "core"
CLEAN_ERRORS = (ValueError, RuntimeError, TypeError)  # TypeError: pybind11's wrong-argument-type error


def run_isolated(code, timeout=60, env=None):
    """Run `code` in a fresh Python with the core importable as in the tests (pc = the module).
    Returns the CompletedProcess; a crash shows as a negative returncode (the signal)."""
    prelude = (f"import sys; sys.path[:0] = [{str(REPO)!r}, {str(TESTS)!r}]\n"
               "import numpy as np\nfrom core_scenes import *\npc = core()\n")
    return subprocess.run([sys.executable, "-c", prelude + textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=timeout, env=env)


def assert_clean_exit(proc):
    assert proc.returncode == 0, (f"exit code {proc.returncode} (negative: killed by that signal)\n"
                                  f"stdout: {proc.stdout[-2000:]}\nstderr: {proc.stderr[-4000:]}")


def scene_with_camera():
    s = pc.Scene()
    s.set_camera(camera(pc, (0, -3, 1), (0, 0, 0)))
    return s


def settings(w=4, h=4, samples=1, **kw):
    st = pc.RenderSettings()
    st.width, st.height, st.samples = w, h, samples
    for k, v in kw.items():
        setattr(st, k, v)
    return st


def finish(sess, limit=20.0):
    t = time.perf_counter()
    while not sess.wait(0.5):
        assert time.perf_counter() - t < limit, "render did not finish"
    return sess


def film_is_clean(img, stats):
    assert np.isfinite(img).all(), "NaN/Inf in the film"
    assert img.min() >= 0.0, f"negative film value {img.min()}"
    assert stats["nonfinite_samples"] == 0, stats["nonfinite_samples"]


P, TRI = quad((-1, -1, 0), (2, 0, 0), (0, 2, 0))


def render_mesh(positions, triangles, *args):
    """add_mesh + instance + a tiny render; returns the scene's stats after a clean render."""
    s = scene_with_camera()
    s.set_world_color((0.5, 0.5, 0.5))
    mesh = s.add_mesh(positions, triangles, *args)
    s.add_instance(mesh, np.eye(4, dtype=np.float32))
    img, stats = render(pc, s, 4, 4, samples=1)
    film_is_clean(img, stats)
    return s.stats()


# ---------------------------------------------------------------- arrays: dtypes, shapes, layout

@pytest.mark.parametrize("positions", [
    P.astype(np.float64), P.astype(np.float16), P.astype(np.int32), P.astype(np.uint8), P.tolist(),
    np.asfortranarray(P), np.repeat(P, 2, axis=1)[:, ::2], P[::-1][::-1], P.astype(">f4"),
], ids=["f64", "f16", "i32", "u8", "list", "fortran", "strided", "negstride", "bigendian"])
def test_positions_of_any_numeric_layout_are_converted(positions):
    ref = render_mesh(P, TRI)
    assert render_mesh(positions, TRI)["triangles"] == ref["triangles"] == 2


@pytest.mark.parametrize("triangles", [
    TRI.astype(np.int64), TRI.astype(np.uint32), TRI.astype(np.uint16), TRI.astype(np.int8),
    TRI.tolist(), np.asfortranarray(TRI), np.repeat(TRI, 2, axis=0)[::2], TRI.astype(">i4"),
], ids=["i64", "u32", "u16", "i8", "list", "fortran", "strided", "bigendian"])
def test_triangles_of_any_integer_layout_are_converted(triangles):
    assert render_mesh(P, triangles)["triangles"] == 2


@pytest.mark.filterwarnings("ignore:invalid value encountered in cast")
@pytest.mark.parametrize("positions,triangles,match", [
    (P[:, :2], TRI, "positions"),
    (P.ravel(), TRI, "positions"),
    (P[None], TRI, "positions"),
    (np.zeros((0,), np.float32), TRI, "positions"),
    (None, TRI, "positions"),
    (P, TRI[:, :2], "triangles"),
    (P, TRI.ravel(), "triangles"),
    (P, TRI[None], "triangles"),
    (P, TRI + 10, "out of range"),
    (P, TRI - 1, "out of range"),
    (P, np.array([[0, 1, 2**31]], np.int64), "out of range"),
    (P, np.array([[0, 1, 2**40]], np.int64), "out of range"),
    (P, np.array([[0, 1, 2**32 + 1]], np.int64), "out of range"),   # would wrap to 1 in 32 bits
    (P, np.array([[0, 1, -2**63]], np.int64), "out of range"),
    (P, np.array([[0, 1, 2**64 - 1]], np.uint64), "out of range"),
    (P, np.array([[0, 1, np.nan]]), "out of range"),
    (np.zeros((0, 3), np.float32), TRI, "out of range"),
], ids=["pos2", "pos1d", "pos3d", "pos0", "posNone", "tri2", "tri1d", "tri3d", "idx+10", "idx-1",
        "idx2^31", "idx2^40", "idx2^32+1", "idx-2^63", "idxu64max", "idxNaN", "nopositions"])
def test_malformed_mesh_arrays_raise_value_error(positions, triangles, match):
    s = scene_with_camera()
    with pytest.raises(ValueError, match=match):
        s.add_mesh(positions, triangles)


@pytest.mark.filterwarnings("ignore::numpy.ComplexWarning")
@pytest.mark.parametrize("bad", [np.array([["a", "b", "c"]] * 4), {"x": 1}, "positions", 3.0,
                                 np.zeros((4, 3), np.complex64) + 1j])
def test_non_numeric_positions_raise_or_convert(bad):
    s = scene_with_camera()
    try:
        s.add_mesh(bad, TRI)
    except CLEAN_ERRORS:
        pass


def test_empty_meshes_render_the_world():
    s = scene_with_camera()
    s.set_world_color((0.25, 0.5, 1.0))
    for pos, tris in ((np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)),
                      (P, np.zeros((0, 3), np.int32)),
                      (np.zeros((0, 3)), np.zeros((0, 3), np.uint32))):
        s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    s.commit()
    assert s.stats()["triangles"] == 0
    img, stats = render(pc, s, 6, 5, samples=2)
    film_is_clean(img, stats)
    assert np.allclose(img[..., :3], [0.25, 0.5, 1.0])
    t, prim, _, _ = s.intersect(np.zeros((3, 3), np.float32), np.eye(3, dtype=np.float32))
    assert (prim == -1).all() and np.isinf(t).all()
    assert not s.occluded(np.zeros((3, 3), np.float32), np.eye(3, dtype=np.float32)).any()


def test_a_million_duplicate_triangles_build_and_render_fast():
    tris = np.tile(TRI, (500_000, 1))  # 10^6 triangles, two distinct ones
    s = scene_with_camera()
    s.set_world_color((1.0, 1.0, 1.0))
    add_object(s, P, tris, s.add_material("m", (0.5, 0.5, 0.5)))
    t = time.perf_counter()
    s.commit()
    assert time.perf_counter() - t < 5.0
    st = s.stats()
    assert st["triangles"] == 10**6 and st["bvh_max_depth"] <= 96  # stays within traversal stacks
    img, stats = render(pc, s, 8, 8, samples=1)
    film_is_clean(img, stats)
    t, prim, _, _ = s.intersect(np.array([[0.1, 0.2, 1.0]], np.float32), np.array([[0, 0, -1]], np.float32))
    assert prim[0] >= 0 and abs(t[0] - 1.0) < 1e-6


def test_triangles_all_on_one_point_are_dropped():
    pos = np.zeros((100, 3), np.float32)
    tris = np.random.default_rng(0).integers(0, 100, (10_000, 3)).astype(np.int32)
    s = scene_with_camera()
    add_object(s, pos, tris, s.add_material("m"))
    s.commit()
    assert s.stats()["dropped_triangles"] == 10_000 and s.stats()["triangles"] == 0




def test_triangles_near_float_max_do_not_crash_the_bvh_build():
    proc = run_isolated("""
        s = pc.Scene()
        v = np.array([[3e38, 0, 0], [3e38, 1, 0], [3e38, 0, 1],
                      [3e38, 0, 2], [3e38, 1, 2], [3e38, 0, 3]], np.float32)
        add_object(s, v, np.array([[0, 1, 2], [3, 4, 5]], np.int32), s.add_material("m"))
        s.commit()
        print(s.stats()["triangles"])
    """)
    assert_clean_exit(proc)


def test_huge_but_safe_coordinates_render_cleanly():
    # Coordinates up to 1e37 whose centroids do not overflow, mixed with normal geometry.
    s = scene_with_camera()
    s.set_world_color((1.0, 1.0, 1.0))
    m = s.add_material("m", (0.5, 0.5, 0.5))
    add_object(s, *quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)), m)
    add_object(s, *quad((1e37, 0, 0), (1e36, 0, 0), (0, 1e36, 0)), m)
    add_object(s, *quad((-1e37, -1e37, 5), (1e30, 0, 0), (0, 1e30, 0)), m)
    img, stats = render(pc, s, 8, 8, samples=2)
    film_is_clean(img, stats)


@pytest.mark.parametrize("normals", [
    np.zeros((2, 3, 3), np.float64), np.full((2, 3, 3), np.nan), np.full((2, 3, 3), np.inf),
    np.zeros((2, 3, 3, 2), np.float32)[..., 0], np.asfortranarray(np.ones((2, 3, 3), np.float32)),
], ids=["zeros64", "nan", "inf", "strided", "fortran"])
def test_odd_corner_normals_are_accepted(normals):
    render_mesh(P, TRI, normals)


@pytest.mark.parametrize("normals", [np.zeros((3, 3, 3)), np.zeros((2, 3)), np.zeros((2, 3, 4)), np.zeros(18)])
def test_corner_normals_of_the_wrong_shape_raise(normals):
    with pytest.raises(ValueError, match="corner_normals"):
        scene_with_camera().add_mesh(P, TRI, normals)


def test_material_indices_and_slots_out_of_range_use_the_default():
    s = scene_with_camera()
    s.set_world_color((1, 1, 1))
    red = s.add_material("red", (1.0, 0.0, 0.0))
    mesh = s.add_mesh(P, TRI, None, np.array([2**40, -2**40], np.int64), [red, 2**40, -5, 2**31])
    s.add_instance(mesh, np.eye(4, dtype=np.float32))
    img, stats = render(pc, s, 4, 4, samples=1)
    film_is_clean(img, stats)
    with pytest.raises(ValueError, match="material_indices"):
        s2 = scene_with_camera()
        s2.add_mesh(P, TRI, None, np.zeros(5, np.int32), [red])
    with pytest.raises(CLEAN_ERRORS):
        scene_with_camera().add_mesh(P, TRI, None, None, [2**70])


@pytest.mark.parametrize("mesh_id", [-1, 1, 2**31, 2**32, 2**64])
def test_instances_of_unknown_meshes_raise(mesh_id):
    s = scene_with_camera()
    s.add_mesh(P, TRI)
    with pytest.raises(CLEAN_ERRORS):
        s.add_instance(mesh_id, np.eye(4))


@pytest.mark.parametrize("matrix", [np.eye(3), np.eye(4)[None], np.zeros(16), np.full((4, 4), np.nan),
                                    np.full((4, 4), np.inf), "eye"])
def test_bad_instance_matrices_raise(matrix):
    s = scene_with_camera()
    mesh = s.add_mesh(P, TRI)
    with pytest.raises(CLEAN_ERRORS):
        s.add_instance(mesh, matrix)


@pytest.mark.parametrize("matrix", [np.zeros((4, 4)), np.diag([1e30, 1e30, 1e30, 1.0]), np.diag([1e-30, 1.0, 1.0, 1.0]),
                                    np.diag([1.0, 0.0, 1.0, 1.0]), np.diag([-1.0, 1.0, 1.0, 1.0]),
                                    np.array([[0, 0, 0, 1], [0, 0, 0, 1], [0, 0, 0, 1], [0, 0, 0, 0.0]])])
def test_singular_or_extreme_instance_matrices_render_cleanly(matrix):
    s = scene_with_camera()
    s.set_world_color((1, 1, 1))
    nrm = np.tile(np.float32([0, 0, 1]), (2, 3, 1))
    mesh = s.add_mesh(P, TRI, nrm)
    s.add_instance(mesh, matrix)
    s.add_instance(mesh, np.eye(4))
    s.add_point_light((0, 0, 2), (5, 5, 5))
    img, stats = render(pc, s, 8, 8, samples=2)
    film_is_clean(img, stats)


# ---------------------------------------------------------------- materials, lights, world

@pytest.mark.parametrize("color", [(1, 2), (1, 2, 3, 4), "red", None, 5.0, (np.nan, "x", 1), [[1, 2, 3]]])
def test_bad_colours_raise(color):
    with pytest.raises(CLEAN_ERRORS):
        pc.Scene().add_material("m", color)


@pytest.mark.parametrize("name", ["", "x" * 100_000, "\u00e9\u4e2d\U0001f600", "a\x00b"])
def test_any_material_name_is_accepted(name):
    s = pc.Scene()
    assert s.add_material(name, (0.5, 0.5, 0.5)) == 1


def test_huge_python_numbers_as_colours():
    s = pc.Scene()
    s.add_material("m", (2**200, 10**30, -(2**200)), (1e300, -1e300, 1e-300))  # overflow to inf: black
    s.add_point_light((0, 0, 1), (1e300, 1, 1))


@pytest.mark.parametrize("pixels", [np.zeros((0, 0, 3)), np.zeros((0, 4, 3)), np.zeros((4, 0, 4)), np.zeros((2, 2, 2)),
                                    np.zeros((2, 2, 5)), np.zeros((2, 2)), np.zeros((1, 70000, 3), np.float32), None])
def test_bad_world_textures_raise(pixels):
    with pytest.raises(CLEAN_ERRORS):
        pc.Scene().set_world_texture(pixels)


@pytest.mark.parametrize("rotation", [np.eye(4), np.eye(2), np.full((3, 3), np.nan), np.full((3, 3), np.inf), "r"])
def test_bad_world_rotations_raise(rotation):
    with pytest.raises(CLEAN_ERRORS):
        pc.Scene().set_world_texture(np.ones((2, 2, 3), np.float32), 1.0, rotation)


@pytest.mark.parametrize("strength", [np.nan, np.inf, -1.0, 0.0, 1e-45, 1e38])
def test_world_strength_extremes_render_cleanly(strength):
    s = scene_with_camera()
    add_object(s, P, TRI, s.add_material("m"))
    s.set_world_texture(np.random.default_rng(0).uniform(0, 1, (4, 8, 3)).astype(np.float32), strength)
    img, stats = render(pc, s, 6, 6, samples=2)
    film_is_clean(img, stats)


def test_light_parameters_raise_or_render_cleanly():
    calls = [
        lambda s: s.add_point_light((0, 0, 1), (1, 1, 1), radius=np.nan),
        lambda s: s.add_point_light((0, 0, 1), (1, 1, 1), radius=np.inf),
        lambda s: s.add_point_light((0, 0, np.inf), (1, 1, 1)),
        lambda s: s.add_point_light((0, 0), (1, 1, 1)),
        lambda s: s.add_point_light("here", (1, 1, 1)),
        lambda s: s.add_spot_light(np.full((4, 4), np.nan), (1, 1, 1)),
        lambda s: s.add_spot_light(np.eye(4), (1, 1, 1), spot_size=np.nan),
        lambda s: s.add_spot_light(np.eye(4), (1, 1, 1), spot_size=-1.0),
        lambda s: s.add_spot_light(np.eye(4), (1, 1, 1), spot_blend=np.inf),
        lambda s: s.add_spot_light(np.eye(4), (1, 1, 1), spot_size=1e30, spot_blend=1e30),
        lambda s: s.add_sun_light((np.nan, 0, 1), (1, 1, 1)),
        lambda s: s.add_sun_light((0, 0, 0), (1, 1, 1)),
        lambda s: s.add_sun_light((0, 0, 1e-30), (1, 1, 1)),
        lambda s: s.add_sun_light((0, 0, 1e30), (1, 1, 1)),
        lambda s: s.add_sun_light((0, 0, 1), (1, 1, 1), angle=np.nan),
        lambda s: s.add_sun_light((0, 0, 1), (1, 1, 1), angle=-1.0),
        lambda s: s.add_sun_light((0, 0, 1), (1, 1, 1), angle=100.0),
        lambda s: s.add_area_light(np.eye(4), np.nan, 1.0, (1, 1, 1)),
        lambda s: s.add_area_light(np.eye(4), -1.0, 1.0, (1, 1, 1)),
        lambda s: s.add_area_light(np.eye(4), 1e30, 1e30, (1, 1, 1)),
        lambda s: s.add_area_light(np.zeros((4, 4)), 1.0, 1.0, (1, 1, 1)),
        lambda s: s.add_area_light(np.diag([1e30, 1e30, 1e30, 1.0]), 1e10, 1e10, (1, 1, 1)),
    ]
    for i, call in enumerate(calls):
        s = scene_with_camera()
        add_object(s, P, TRI, s.add_material("m"))
        try:
            call(s)
        except CLEAN_ERRORS:
            continue
        img, stats = render(pc, s, 6, 6, samples=2)
        assert np.isfinite(img).all() and img.min() >= 0.0, i
        assert stats["nonfinite_samples"] == 0, (i, stats["nonfinite_samples"])


# ---------------------------------------------------------------- camera

def camera_case(field, value):
    return pytest.param(field, value, id=f"{field}={value}")


def camera_check(field, value):
    """Set one camera field on a scene lit by a world texture; set_camera raises ValueError or
    the render is clean."""
    s = pc.Scene()
    add_object(s, P, TRI, s.add_material("m"))
    s.set_world_texture(np.random.default_rng(0).uniform(0.1, 1, (4, 8, 3)).astype(np.float32))
    cam = camera(pc, (0, -3, 1), (0, 0, 0))
    if field == "matrix_world":
        try:
            cam.matrix_world = np.asarray(value, np.float32)
        except ValueError:
            return
    else:
        setattr(cam, field, value)
    try:
        s.set_camera(cam)
    except ValueError:
        return
    img, stats = render(pc, s, 4, 4, samples=2)
    film_is_clean(img, stats)


@pytest.mark.parametrize("field,value", [
    camera_case("lens", np.nan), camera_case("lens", np.inf), camera_case("lens", 0.0), camera_case("lens", -1.0),
    camera_case("lens", 1e38), camera_case("lens", 1e-38),
    camera_case("sensor_width", np.nan), camera_case("sensor_width", np.inf), camera_case("sensor_width", 1e38),
    camera_case("sensor_width", 1e-38), camera_case("sensor_height", np.inf), camera_case("sensor_height", 0.0),
    camera_case("shift_x", np.nan), camera_case("shift_x", np.inf), camera_case("shift_x", 1e38),
    camera_case("shift_y", np.nan), camera_case("shift_y", -np.inf), camera_case("shift_y", -1.0),
    camera_case("clip_start", np.nan), camera_case("clip_start", -1.0), camera_case("clip_start", np.inf),
    camera_case("clip_start", 0.0), camera_case("clip_end", np.nan), camera_case("clip_end", np.inf),
    camera_case("clip_end", 0.0), camera_case("clip_end", 1e38),
    camera_case("pixel_aspect_x", np.nan), camera_case("pixel_aspect_x", np.inf), camera_case("pixel_aspect_x", 1e-38),
    camera_case("pixel_aspect_y", np.inf), camera_case("pixel_aspect_y", 1e38), camera_case("pixel_aspect_y", 0.0),
])
def test_camera_values_raise_or_render_cleanly(field, value):
    # Once these went through: NaN camera rays, and with a world texture an out-of-bounds read
    # in Environment::lookup (found by AddressSanitizer; fixed in f5b5817).
    camera_check(field, value)


@pytest.mark.parametrize("matrix", [
    np.zeros((4, 4)), np.array([[1, 1, 0, 0], [0, 0, 0, -3], [0, 0, 1, 1], [0, 0, 0, 1.0]]),
    np.diag([1e-30, 1e-30, 1e-30, 1.0]), np.diag([1e30, 1e30, 1e30, 1.0]),
], ids=["zero", "equal_columns", "scale1e-30", "scale1e30"])
def test_degenerate_camera_matrices_raise_or_render_cleanly(matrix):
    camera_check("matrix_world", matrix)


def test_camera_scaled_like_blender_objects_renders_the_same():
    def scene(scale):
        s = cornell(pc)
        cam = camera(pc, (0.0, -0.95, 1.0), (0.0, 1.0, 1.0), lens=16.0)
        m = np.array(cam.matrix_world)
        m[:3, :3] *= scale
        cam.matrix_world = m
        s.set_camera(cam)
        return s

    a, _ = render(pc, scene(1.0), 8, 8, samples=2)
    for scale in (1e-3, 7.0, 1e3):
        b, stats = render(pc, scene(scale), 8, 8, samples=2)
        film_is_clean(b, stats)
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


def test_bad_sensor_fit_raises():
    with pytest.raises(ValueError, match="sensor_fit"):
        pc.Camera().sensor_fit = "DIAGONAL"


# ---------------------------------------------------------------- render settings and sessions

@pytest.mark.parametrize("field,value,match", [
    ("width", 0, "resolution"), ("height", -5, "resolution"), ("width", 65537, "too large"),
    ("width", 100_000, "too large"), ("samples", 0, "samples"), ("samples", -1, "samples"),
    ("max_bounces", -1, "bounces"), ("max_bounces", 1025, "bounces"), ("time_limit", np.nan, "time_limit"),
    ("time_limit", -1.0, "time_limit"), ("threads", -1, "threads"), ("threads", 1025, "threads"),
    ("tile_size", 3, "tile_size"), ("tile_size", 1025, "tile_size"), ("tile_size", 0, "tile_size"),
    ("adaptive_threshold", np.nan, "adaptive"), ("adaptive_threshold", np.inf, "adaptive"),
    ("adaptive_threshold", -0.1, "adaptive"), ("adaptive_min_samples", -1, "adaptive"),
    ("diffuse_bounces", -1, "bounce"), ("glossy_bounces", -1, "bounce"), ("transmission_bounces", -1, "bounce"),
    ("transparent_bounces", -1, "bounce"),
])
def test_bad_settings_raise_before_rendering(field, value, match):
    st = settings(8, 8, 1)
    setattr(st, field, value)
    with pytest.raises(ValueError, match=match):
        pc.Session(cornell(pc), st)


def test_huge_resolutions_raise_before_allocating():
    s = cornell(pc)
    for w, h in ((100_000, 100_000), (65536, 65536), (65536, 6104), (2**31 - 1, 1), (1, 2**31 - 1)):
        with pytest.raises(ValueError, match="too large"):
            pc.Session(s, settings(w, h))


UNDER_ASAN = "asan" in os.environ.get("LD_PRELOAD", "")


@pytest.mark.skipif(UNDER_ASAN, reason="AddressSanitizer's shadow memory cannot live under an address-space limit")
def test_largest_allowed_resolution_fails_cleanly_without_the_memory():
    # 20000 x 20000 passes validation (400 MP, ~10 GB of film): with 2 GB of address space the
    # allocation must fail as a Python MemoryError, not a crash.
    proc = run_isolated("""
        import resource
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
        st = pc.RenderSettings(); st.width = st.height = 20000
        try:
            pc.Session(cornell(pc), st)
        except (MemoryError, ValueError) as e:
            print("clean", type(e).__name__)
    """)
    assert_clean_exit(proc)
    assert "clean" in proc.stdout


@pytest.mark.parametrize("field,value", [("width", 2**40), ("samples", 2**31), ("seed", -1), ("seed", 2**32),
                                         ("threads", "4"), ("use_nee", "yes"), ("sampler", "halton"),
                                         ("sampler", None), ("time_limit", "1")])
def test_settings_of_the_wrong_type_raise(field, value):
    st = pc.RenderSettings()
    with pytest.raises(CLEAN_ERRORS):
        setattr(st, field, value)


def test_one_pixel_renders():
    for w, h in ((1, 1), (1, 7), (7, 1)):
        img, stats = render(pc, cornell(pc), w, h, samples=3, tile_size=4)
        film_is_clean(img, stats)
        assert img.shape == (h, w, 4) and (img[..., 3] == 1.0).all()


@pytest.mark.parametrize("threads", [0, 1, 2, 3, 7, 16, 33, 64])
def test_any_thread_count_renders_the_same(threads):
    ref, _ = render(pc, cornell(pc), 5, 3, samples=2, threads=1, tile_size=4)
    img, stats = render(pc, cornell(pc), 5, 3, samples=2, threads=threads, tile_size=4)
    np.testing.assert_array_equal(img, ref)
    assert stats["threads"] == (threads or stats["threads"]) and stats["threads"] >= 1


@pytest.mark.parametrize("tile_size", [4, 5, 1023, 1024])
def test_tile_sizes_at_the_bounds(tile_size):
    ref, _ = render(pc, cornell(pc), 9, 6, samples=2, tile_size=32)
    img, stats = render(pc, cornell(pc), 9, 6, samples=2, tile_size=tile_size)
    np.testing.assert_array_equal(img, ref)


@pytest.mark.parametrize("field,value", [("time_limit", np.inf), ("time_limit", 1e300), ("seed", 2**32 - 1),
                                         ("max_bounces", 1024), ("diffuse_bounces", 2**31 - 1),
                                         ("adaptive_threshold", 1e-30), ("adaptive_threshold", 1e30),
                                         ("adaptive_min_samples", 2**31 - 1), ("adaptive_threshold", 1e-38)])
def test_extreme_but_valid_settings_render_cleanly(field, value):
    st = settings(6, 6, 4, **{field: value})
    sess = pc.Session(cornell(pc), st)
    sess.start()
    finish(sess)
    film_is_clean(sess.film(), sess.stats())
    assert sess.progress()["samples_done"] <= 4


def test_cancel_immediately_after_start():
    for _ in range(20):
        sess = pc.Session(cornell(pc), settings(64, 64, 1_000_000))
        sess.start()
        sess.cancel()
        t = time.perf_counter()
        finish(sess, limit=2.0)
        assert time.perf_counter() - t < 1.0
        assert sess.progress()["cancelled"] and sess.is_finished()
        assert np.isfinite(sess.film()).all()




def test_cancel_before_start_then_wait_returns():
    sess = pc.Session(cornell(pc), settings(16, 16, 1000))
    sess.cancel()
    assert sess.wait(0.2) is True


def test_cancel_before_start_then_start_finishes_at_once():
    sess = pc.Session(cornell(pc), settings(16, 16, 1000))
    sess.cancel()
    sess.start()
    finish(sess, limit=2.0)
    assert sess.progress()["samples_done"] == 0
    assert np.isfinite(sess.film()).all()


def test_session_api_before_start_and_after_finish():
    sess = pc.Session(cornell(pc), settings(8, 8, 2))
    assert sess.film().shape == (8, 8, 4) and not sess.film().any()
    assert sess.sample_counts().sum() == 0 and sess.stats()["paths"] == 0
    assert sess.wait(0.0) is False and not sess.is_finished()
    sess.start()
    finish(sess)
    for _ in range(3):  # waiting on a finished session returns True at once
        t = time.perf_counter()
        assert sess.wait(10.0) is True
        assert time.perf_counter() - t < 0.1
    sess.cancel()  # cancelling a finished session changes nothing
    assert sess.wait(0.0) is True and sess.progress()["samples_done"] == 2
    with pytest.raises(RuntimeError, match="already started"):
        sess.start()


@pytest.mark.parametrize("timeout", [-1.0, 0.0, np.nan, -np.inf])
def test_wait_with_odd_timeouts_returns_promptly(timeout):
    sess = pc.Session(cornell(pc), settings(256, 256, 1_000_000))
    sess.start()
    try:
        t = time.perf_counter()
        try:
            sess.wait(timeout)
        except ValueError:
            pass
        assert time.perf_counter() - t < 1.0
    finally:
        sess.cancel()
        finish(sess)




@pytest.mark.parametrize("timeout", [np.inf, 1e300])
def test_wait_with_an_infinite_timeout_blocks_until_a_pass(timeout):
    sess = pc.Session(cornell(pc), settings(256, 256, 1_000_000, threads=1))
    sess.start()
    try:
        sess.wait(30.0)  # the first (1-sample) pass
        passes = sess.stats()["passes"]
        done = sess.wait(timeout)
        assert done or sess.stats()["passes"] > passes, "wait() returned before anything happened"
    finally:
        sess.cancel()
        finish(sess)


def test_many_sessions_created_and_destroyed():
    s = cornell(pc)
    for i in range(200):
        sess = pc.Session(s, settings(8, 8, 1, threads=2))
        if i % 3:
            sess.start()
        if i % 3 == 2:
            finish(sess)
        del sess  # destroyed unstarted, running, or finished
    gc.collect()
    s.set_world_color((1, 1, 1))  # every session released the scene


def test_destroying_running_sessions_stops_them():
    for _ in range(10):
        sess = pc.Session(cornell(pc), settings(64, 64, 1_000_000))
        sess.start()
        sess.wait(0.01)
        t = time.perf_counter()
        del sess
        gc.collect()
        assert time.perf_counter() - t < 1.0


def test_session_outlives_its_scene_object():
    s = cornell(pc)
    sess = pc.Session(s, settings(16, 16, 4))
    del s
    gc.collect()
    sess.start()
    finish(sess)
    film_is_clean(sess.film(), sess.stats())
    assert sess.film()[..., :3].mean() > 0.05


def test_render_twice_in_a_row_gives_the_same_image():
    s = cornell(pc)
    a, _ = render(pc, s, 12, 12, samples=4, seed=3)
    b, _ = render(pc, s, 12, 12, samples=4, seed=3)
    np.testing.assert_array_equal(a, b)
    s.set_world_color((0.0, 0.0, 0.0))  # editable again between renders
    c, _ = render(pc, s, 12, 12, samples=4, seed=3)
    np.testing.assert_array_equal(a, c)


def test_two_sessions_on_one_scene_at_once():
    s = cornell(pc)
    a = pc.Session(s, settings(16, 16, 8, seed=1))
    b = pc.Session(s, settings(16, 16, 8, seed=1))
    a.start()
    b.start()
    finish(a)
    finish(b)
    np.testing.assert_array_equal(a.film(), b.film())


def test_reading_the_film_while_rendering():
    sess = pc.Session(cornell(pc), settings(64, 64, 1_000_000))
    sess.start()
    t = time.perf_counter()
    while time.perf_counter() - t < 0.5:
        f = sess.film()
        sess.film_rect(3, 5, 17, 9)
        sess.sample_counts()
        sess.progress()
        sess.stats()
        assert np.isfinite(f).all() and f.min() >= 0
    sess.cancel()
    finish(sess)


@pytest.mark.parametrize("x,y,w,h", [(-1, 0, 2, 2), (0, -1, 2, 2), (0, 0, -1, 2), (0, 0, 9, 1), (7, 7, 2, 2),
                                     (0, 0, 2**31 - 1, 1), (1, 0, 2**31 - 2, 1)])
def test_film_rect_outside_the_image_raises(x, y, w, h):
    sess = pc.Session(cornell(pc), settings(8, 8, 1))
    with pytest.raises(CLEAN_ERRORS):
        sess.film_rect(x, y, w, h)




def test_film_rect_with_overflowing_bounds_raises():
    proc = run_isolated("""
        st = pc.RenderSettings(); st.width = st.height = 8; st.samples = 1
        sess = pc.Session(cornell(pc), st)
        try:
            sess.film_rect(2**31 - 1, 0, 2, 2)
            print("NO ERROR")
        except ValueError:
            print("ValueError")
    """)
    assert_clean_exit(proc)
    assert "ValueError" in proc.stdout, proc.stdout


def test_scene_edits_are_refused_while_a_session_holds_it():
    s = cornell(pc)
    sess = pc.Session(s, settings(8, 8, 1))
    for edit in (lambda: s.add_material("m"), lambda: s.add_mesh(P, TRI), lambda: s.add_instance(0, np.eye(4)),
                 lambda: s.add_point_light((0, 0, 1), (1, 1, 1)), lambda: s.set_world_color((1, 1, 1)),
                 lambda: s.set_world_texture(np.ones((2, 2, 3), np.float32)), lambda: s.commit(),
                 lambda: s.set_camera(camera(pc, (0, -3, 0), (0, 0, 0)))):
        with pytest.raises(RuntimeError, match="in use"):
            edit()
    sess.start()
    finish(sess)
    del sess
    gc.collect()
    s.set_world_color((1, 1, 1))


def test_ray_queries_with_bad_input():
    s = cornell(pc)
    with pytest.raises(ValueError, match="commit"):
        s.intersect(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))
    s.commit()
    for o, d in ((np.zeros((2, 3)), np.zeros((3, 3))), (np.zeros((2, 2)), np.zeros((2, 2))), (np.zeros(3), np.zeros(3))):
        with pytest.raises(ValueError):
            s.intersect(o, d)
        with pytest.raises(ValueError):
            s.occluded(o, d)
    o = np.array([[np.nan, 0, 1], [0, 0, 1], [0, 0, 1], [np.inf, 0, 1], [0, 0, 1]], np.float32)
    d = np.array([[0, 0, 1], [0, 0, 0], [np.nan, 0, 1], [1, 0, 0], [0, 0, 1e-45]], np.float32)
    for tmax in (np.inf, np.nan, -1.0, 0.0):
        t, prim, b1, b2 = s.intersect(o, d, tmax)
        assert ((prim == -1) | np.isfinite(t)).all()
        s.occluded(o, d, tmax)
    t, prim, _, _ = s.intersect(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))
    assert t.shape == (0,)


def test_offset_ray_origin_with_huge_normals_stays_near_the_point():
    p = np.ones((3, 3), np.float32)
    n = np.array([[0, 1e30, 0], [0, -1e30, 0], [1e10, 0, 0]], np.float32)
    try:
        o = pc.offset_ray_origin(p, n)
    except ValueError:
        return
    assert np.isfinite(o).all() and np.abs(o - p).max() < 0.5, o


def test_offset_ray_origin_with_bad_input():
    with pytest.raises(ValueError):
        pc.offset_ray_origin(np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(CLEAN_ERRORS):
        pc.offset_ray_origin(np.zeros((2, 3)), np.ones((2, 3)), np.zeros((3, 3)))
    o = pc.offset_ray_origin(np.ones((2, 3)), np.ones((2, 3)), np.array([[np.nan, np.inf, -1.0], [0, 0, 0]]))
    assert o.shape == (2, 3)
    o = pc.offset_ray_origin(np.array([[np.nan, 1, np.inf]], np.float32), np.array([[0, 0, 0]], np.float32))
    assert o.shape == (1, 3)
    assert pc.offset_ray_origin(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)


@pytest.mark.parametrize("threads", [-5, 0, 1, 100_000])
def test_commit_with_any_thread_count(threads):
    s = cornell(pc)
    s.commit(threads)
    assert s.stats()["triangles"] > 0
