"""A Hypothesis fuzzer for the core module's scene-building API (issue 7).

Each example is a small "program": a list of calls with random and malformed arguments to
add_material / add_mesh / add_instance / add_*_light / set_world_* / set_camera, then
RenderSettings, a Session and a tiny render (at most 6x6 pixels, 1-2 samples), plus a few ray
queries and film reads. The invariant: every call either raises ValueError, RuntimeError or
TypeError (pybind11's wrong-argument error) or succeeds, and a render that starts finishes
within seconds with a finite, non-negative film and no dropped (non-finite) samples.

CI mode (default): derandomized, FUZZ_EXAMPLES examples, well under a minute.
Long mode: PATHLIGHT_FUZZ_EXAMPLES=5000 (random seed, printed by Hypothesis on failure;
PATHLIGHT_FUZZ_SEED=N fixes it).

Crashes: before each example the program is written as JSON to PATHLIGHT_FUZZ_LAST (default
<tmp>/pathlight_fuzz_last.json), fsynced, so a segfault leaves its input behind. Copy that file
to tests/core/fuzz/ (add "xfail": "<reason>" while the bug is open): test_fuzz_regressions replays
every file there in a fresh interpreter, so a crash fails one test rather than the run.
"""
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, assume, event, given, note, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

from core_scenes import REPO, core  # noqa: E402

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
FUZZ_DIR = Path(__file__).resolve().parent / "fuzz"
LONG = "PATHLIGHT_FUZZ_EXAMPLES" in os.environ
EXAMPLES = int(os.environ.get("PATHLIGHT_FUZZ_EXAMPLES", "500"))
LAST = Path(os.environ.get("PATHLIGHT_FUZZ_LAST", Path(tempfile.gettempdir()) / "pathlight_fuzz_last.json"))
ALLOWED = (ValueError, RuntimeError, TypeError)
RENDER_LIMIT_S = 20.0


# ---------------------------------------------------------------- (de)serialisation

def encode(x):
    if isinstance(x, np.ndarray):
        if x.dtype == object:
            return {"__list__": [encode(v) for v in x.tolist()]}
        return {"__array__": x.tolist(), "dtype": x.dtype.str, "shape": list(x.shape),
                "fortran": bool(x.flags.f_contiguous and not x.flags.c_contiguous)}
    if isinstance(x, (list, tuple)):
        return [encode(v) for v in x]
    if isinstance(x, dict):
        return {"__dict__": {k: encode(v) for k, v in x.items()}}
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


def decode(x):
    if isinstance(x, dict):
        if "__array__" in x:
            a = np.array(x["__array__"], dtype=np.dtype(x["dtype"])).reshape(x["shape"])
            return np.asfortranarray(a) if x.get("fortran") else a
        if "__list__" in x:
            return [decode(v) for v in x["__list__"]]
        return {k: decode(v) for k, v in x["__dict__"].items()}
    if isinstance(x, list):
        return [decode(v) for v in x]
    return x


def save(program, path):
    text = json.dumps(encode(program), allow_nan=True)
    with open(path, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())


def save_regression(program, path, xfail=None, note=None):
    """Write a regression input for tests/core/fuzz/ (xfail: the reason while the bug is open)."""
    meta = {"program": encode(program)}
    if xfail:
        meta["xfail"] = xfail
    if note:
        meta["note"] = note
    Path(path).write_text(json.dumps(meta, allow_nan=True, indent=1) + "\n")


def load(path):
    data = json.loads(Path(path).read_text())
    return decode(data["program"] if isinstance(data, dict) and "program" in data else data)


# ---------------------------------------------------------------- execution

def _note(msg):
    if hypothesis.currently_in_test_context():
        note(msg)


def _event(msg):
    if hypothesis.currently_in_test_context():
        event(msg)
    else:
        print(msg)  # replayed from tests/core/fuzz/: shows in the test's output

CAMERA_FIELDS = ("lens", "sensor_width", "sensor_height", "sensor_fit", "shift_x", "shift_y", "clip_start",
                 "clip_end", "pixel_aspect_x", "pixel_aspect_y")
# Panoramic cameras: drawn after the fields above, with their own enum and tuple values.
PANO_FIELDS = ("type", "panorama_type", "fisheye_fov", "fisheye_lens", "latitude_min", "longitude_max",
               "fisheye_polynomial", "central_cylindrical_radius", "central_cylindrical_range_v_max",
               "aperture_size")
PANORAMA_TYPES = ["EQUIRECTANGULAR", "EQUIANGULAR_CUBEMAP_FACE", "MIRRORBALL", "FISHEYE_EQUIDISTANT",
                  "FISHEYE_EQUISOLID", "FISHEYE_LENS_POLYNOMIAL", "CENTRAL_CYLINDRICAL", "FISHEYE"]
SETTINGS_FIELDS = ("width", "height", "samples", "max_bounces", "seed", "threads", "tile_size", "use_nee",
                   "sampler", "adaptive_threshold", "adaptive_min_samples", "time_limit",
                   "diffuse_bounces", "glossy_bounces", "transmission_bounces", "clamp_direct",
                   "clamp_indirect", "filter_glossy", "caustics_reflective", "caustics_refractive")


def look_at(eye, target):
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right = right / np.linalg.norm(right) if np.linalg.norm(right) > 1e-9 else np.array([1.0, 0.0, 0.0])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
    return m.astype(np.float32)


def execute(program):
    """Run a program against the core and check the invariant; returns a short summary."""
    scene = pc.Scene()
    ids = {"mesh": [], "material": [0]}
    rendered = None
    for op, args in program:
        try:
            if op == "material":
                ids["material"].append(scene.add_material(*args))
            elif op == "mesh":
                positions, triangles, normals, mat_idx, slots = args
                slots = [ids["material"][s % len(ids["material"])] if isinstance(s, int) and 0 <= s < 64 else s
                         for s in slots]
                ids["mesh"].append(scene.add_mesh(positions, triangles, normals, mat_idx, slots))
            elif op == "instance":
                which, matrix = args
                mesh = ids["mesh"][which % len(ids["mesh"])] if ids["mesh"] and isinstance(which, int) and which >= 0 else which
                scene.add_instance(mesh, matrix)
            elif op == "point":
                scene.add_point_light(*args)
            elif op == "spot":
                scene.add_spot_light(*args)
            elif op == "sun":
                scene.add_sun_light(*args)
            elif op == "area":
                scene.add_area_light(*args)
            elif op == "portal":
                scene.add_portal_light(*args)
            elif op == "world_color":
                scene.set_world_color(*args)
            elif op == "world_texture":
                scene.set_world_texture(*args)
            elif op == "camera":
                eye, target, fields = args
                cam = pc.Camera()
                cam.matrix_world = look_at(eye, target) if not isinstance(eye, np.ndarray) else eye
                for k, v in fields.items():
                    setattr(cam, k, v)
                scene.set_camera(cam)
            elif op == "commit":
                scene.commit(*args)
            elif op == "render":
                rendered = render(scene, args)
            elif op == "rays":
                rays(scene, *args)
            else:
                raise AssertionError(f"unknown op {op}")
            if op == "render":
                _event("a render finished")
        except ALLOWED as e:
            _note(f"{op}: {type(e).__name__}: {e}")
            if op == "render":
                _event(f"render raised {type(e).__name__}: {str(e)[:40]}")
    return rendered


def render(scene, fields):
    st_ = pc.RenderSettings()
    for k, v in fields.items():
        setattr(st_, k, v)  # a wrong type raises TypeError/ValueError here: caught by the caller
    sess = pc.Session(scene, st_)
    sess.start()
    t = time.perf_counter()
    while not sess.wait(0.5):
        assert time.perf_counter() - t < RENDER_LIMIT_S, "the render did not finish (hang?)"
    film = sess.film()
    stats = sess.stats()
    assert film.shape == (st_.height, st_.width, 4) and film.dtype == np.float32
    assert np.isfinite(film).all(), "NaN/Inf in the film"
    assert film.min() >= 0.0, f"negative value {film.min()} in the film"
    assert stats["nonfinite_samples"] == 0, f"{stats['nonfinite_samples']} non-finite samples dropped"
    counts = sess.sample_counts()
    assert counts.max() <= st_.samples
    w, h = st_.width, st_.height
    np.testing.assert_array_equal(sess.film_rect(0, 0, w, h), film)
    for x, y, rw, rh in ((w // 2, h // 2, (w + 1) // 2, (h + 1) // 2), (w, h, 0, 0)):
        assert sess.film_rect(x, y, rw, rh).shape == (rh, rw, 4)
    for bad in ((-1, 0, 1, 1), (0, 0, w + 1, 1), (w, 0, 1, 1)):
        with pytest.raises(ValueError):
            sess.film_rect(*bad)
    return float(film[..., :3].mean(dtype=np.float64))


def rays(scene, origins, directions, tmax):
    scene.commit()
    t, prim, b1, b2 = scene.intersect(origins, directions, tmax)
    occ = scene.occluded(origins, directions, tmax)
    n = len(t)
    assert prim.shape == occ.shape == b1.shape == b2.shape == (n,)
    hit = prim >= 0
    assert np.isfinite(t[hit]).all() and (t[hit] > 0).all()
    assert (prim[hit] < scene.stats()["triangles"]).all()
    assert np.isinf(t[~hit]).all()


# ---------------------------------------------------------------- known open bugs (see the xfails)

def known_crash(program):
    """Inputs that hit a known, xfailed crash or out-of-bounds read; filtered out until fixed
    (they would abort the run, or a sanitizer run). Add a class when a crash is found and
    remove it when its bug is fixed. None is open."""
    return False


# ---------------------------------------------------------------- strategies

SPECIAL = [float(np.float32(v)) for v in  # float32-exact, so arrays hold them unchanged
           (0.0, -0.0, 1e-45, -1e-45, 1e-38, 1e-30, 1e30, 3e38, -3e38, math.nan, math.inf, -math.inf, -1.0)]
any_float = st.one_of(st.floats(width=32), st.sampled_from(SPECIAL))
sane = st.floats(-4.0, 4.0, width=32)
coord = st.one_of(sane, sane, sane, sane, any_float)
colour_val = st.one_of(st.floats(0.0, 2.0, width=32), st.floats(0.0, 2.0, width=32), any_float)
colour = st.one_of(st.tuples(colour_val, colour_val, colour_val),
                   st.lists(colour_val, min_size=0, max_size=5).map(tuple),
                   st.sampled_from(["red", None]))
index_dtypes = st.sampled_from([np.int32, np.int32, np.int64, np.uint32, np.int16, np.float64])
float_dtypes = st.sampled_from([np.float32, np.float32, np.float32, np.float64, np.float16, np.int32])


@st.composite
def mesh_args(draw):
    nv = draw(st.integers(0, 24))
    shape = draw(st.sampled_from([(nv, 3)] * 6 + [(nv,), (nv, 2), (nv, 4), (nv, 3, 1)]))
    dtype = np.dtype(draw(float_dtypes))
    if dtype.kind != "f":
        elements = st.integers(-4, 4)
    elif dtype.itemsize == 2:
        elements = st.floats(-4, 4, width=16) | st.sampled_from([math.nan, math.inf, -math.inf, 65504.0])
    else:
        elements = coord
    positions = draw(hnp.arrays(dtype, shape, elements=elements))
    if draw(st.integers(0, 9)) == 0:
        positions = np.asfortranarray(positions)
    nt = draw(st.integers(0, 40))
    tshape = draw(st.sampled_from([(nt, 3)] * 8 + [(nt,), (nt, 2)]))
    itype = draw(index_dtypes)
    hi = max(nv - 1, 0)
    idx = st.one_of(st.integers(0, hi), st.integers(0, hi), st.integers(0, hi),
                    st.integers(-3, nv + 3), st.sampled_from([2**31 - 1, 2**32 + 1, -2**31]))
    if np.dtype(itype).kind == "u":
        idx = st.integers(0, hi + 3)
    elif np.dtype(itype).kind == "f":
        idx = st.floats(-1.0, hi + 1.5)
    elif np.dtype(itype).itemsize < 8:
        info = np.iinfo(itype)
        idx = st.integers(max(info.min, -3), min(info.max, hi + 3))
    triangles = draw(hnp.arrays(itype, tshape, elements=idx))
    normals = None
    kind = draw(st.integers(0, 5))
    if kind == 1:
        normals = draw(hnp.arrays(np.float32, (nt, 3, 3), elements=any_float))
    elif kind == 2:
        normals = draw(hnp.arrays(np.float32, (nt, 3, 3), elements=st.floats(-1, 1, width=32)))
    elif kind == 3:
        normals = draw(hnp.arrays(np.float32, draw(st.sampled_from([(nt, 3), (nt + 1, 3, 3), (nt, 3, 2)])),
                                  elements=sane))
    mat_idx = None
    if draw(st.booleans()):
        mat_idx = draw(hnp.arrays(np.int64, draw(st.sampled_from([(nt,), (nt,), (nt + 1,), (nt, 1)])),
                                  elements=st.integers(-2**40, 2**40) | st.integers(-1, 4)))
    slots = draw(st.lists(st.integers(-3, 8) | st.sampled_from([2**31, 2**40, -2**40]), max_size=4))
    return positions, triangles, normals, mat_idx, slots


@st.composite
def matrix(draw):
    kind = draw(st.integers(0, 9))
    if kind <= 5:  # an affine transform: rotation-ish, scale, translation
        m = np.eye(4)
        m[:3, :3] = draw(hnp.arrays(np.float64, (3, 3), elements=st.floats(-2, 2))) + np.eye(3) * draw(
            st.sampled_from([1.0, 1.0, 1e-6, 1e6, 0.0, -1.0]))
        m[:3, 3] = draw(hnp.arrays(np.float64, (3,), elements=st.floats(-5, 5)))
        return m.astype(np.float32)
    if kind <= 7:
        return draw(hnp.arrays(np.float32, (4, 4), elements=any_float))
    return draw(hnp.arrays(np.float32, draw(st.sampled_from([(3, 3), (4,), (4, 4, 1), (0, 4)])), elements=sane))


light_pos = st.tuples(coord, coord, coord) | st.lists(coord, max_size=4).map(tuple)
intensity = colour
size = st.one_of(st.floats(0.0, 3.0, width=32), any_float)


@st.composite
def op(draw):
    kind = draw(st.sampled_from(["material", "material", "mesh", "mesh", "mesh", "instance", "instance", "instance",
                                 "point", "spot", "sun", "area", "portal", "world_color", "world_texture", "camera", "commit",
                                 "rays"]))
    if kind == "material":
        return kind, (draw(st.text(max_size=8)), draw(colour), draw(colour))
    if kind == "mesh":
        return kind, draw(mesh_args())
    if kind == "instance":
        return kind, (draw(st.integers(0, 5) | st.sampled_from([-1, 2**32, 2**31])), draw(matrix()))
    if kind == "point":
        return kind, (draw(light_pos), draw(intensity), draw(size), draw(st.booleans()))
    if kind == "spot":
        return kind, (draw(matrix()), draw(intensity), draw(size), draw(size), draw(size), draw(st.booleans()))
    if kind == "sun":
        return kind, (draw(light_pos), draw(intensity), draw(size), draw(st.booleans()))
    if kind == "area":
        return kind, (draw(matrix()), draw(size), draw(size), draw(intensity), draw(st.booleans()), draw(st.booleans()))
    if kind == "portal":
        return kind, (draw(matrix()), draw(size), draw(size), draw(st.booleans()))
    if kind == "world_color":
        return kind, (draw(colour),)
    if kind == "world_texture":
        h, w = draw(st.integers(0, 5)), draw(st.integers(0, 9))
        shape = draw(st.sampled_from([(h, w, 3), (h, w, 4), (h, w, 3), (h, w), (h, w, 2)]))
        px = draw(hnp.arrays(np.float32, shape, elements=st.floats(0, 4, width=32) | any_float))
        rot = draw(st.none() | st.just(np.eye(3)) | hnp.arrays(np.float32, draw(st.sampled_from([(3, 3), (3, 3), (4, 4)])),
                                                               elements=sane | any_float))
        return kind, (px, draw(st.floats(0, 4, width=32) | any_float), rot)
    if kind == "camera":
        eye = draw(st.tuples(sane, sane, sane))
        target = draw(st.tuples(sane, sane, sane))
        assume(np.linalg.norm(np.subtract(eye, target)) > 1e-3)
        if draw(st.integers(0, 9)) == 9:
            eye = draw(matrix())  # a raw matrix_world
        fields = {}
        for name in CAMERA_FIELDS:
            if draw(st.integers(0, 3)) == 0:
                fields[name] = (draw(st.sampled_from(["AUTO", "HORIZONTAL", "VERTICAL", "DIAGONAL"]))
                                if name == "sensor_fit" else draw(st.floats(0.01, 100.0) | any_float))
        for name in PANO_FIELDS:
            if draw(st.integers(0, 3)) == 0:
                if name == "type":
                    fields[name] = draw(st.sampled_from(["PERSP", "ORTHO", "PANO", "PANO"]))
                elif name == "panorama_type":
                    fields[name] = draw(st.sampled_from(PANORAMA_TYPES))
                elif name == "fisheye_polynomial":
                    fields[name] = tuple(draw(st.floats(-1.0, 1.0) | any_float) for _ in range(5))
                else:
                    fields[name] = draw(st.floats(-10.0, 100.0) | any_float)
        return kind, (eye, target, fields)
    if kind == "commit":
        return kind, (draw(st.integers(-2, 4)),)
    n = draw(st.integers(0, 20))
    o = draw(hnp.arrays(np.float32, (n, 3), elements=coord))
    d = draw(hnp.arrays(np.float32, draw(st.sampled_from([(n, 3), (n, 3), (n + 1, 3), (n, 2)])), elements=coord))
    return kind, (o, d, draw(st.floats(0, 100) | any_float))


@st.composite
def render_fields(draw):
    f = {"width": draw(st.integers(1, 6)), "height": draw(st.integers(1, 6)), "samples": draw(st.integers(1, 2)),
         "threads": draw(st.integers(1, 3)), "tile_size": draw(st.integers(4, 8)), "max_bounces": draw(st.integers(0, 4))}
    if draw(st.booleans()):
        f["seed"] = draw(st.integers(0, 2**32 - 1))
    if draw(st.booleans()):
        f["sampler"] = draw(st.sampled_from(["sobol", "random"]))
    if draw(st.booleans()):
        f["use_nee"] = draw(st.booleans())
    if draw(st.integers(0, 3)) == 3:
        f["adaptive_threshold"] = draw(st.floats(0, 1) | st.floats(0, 1) | any_float)
        f["adaptive_min_samples"] = draw(st.integers(0, 4))
    if draw(st.integers(0, 3)) == 3:  # Clamping: tiny limits cut every contribution
        f["clamp_direct"] = draw(st.floats(0, 4, width=32) | any_float)
        f["clamp_indirect"] = draw(st.floats(0, 4, width=32) | any_float)
    if draw(st.integers(0, 3)) == 3:  # Filter Glossy and the caustics toggles
        f["filter_glossy"] = draw(st.floats(0, 4, width=32) | any_float)
        f["caustics_reflective"] = draw(st.booleans())
        f["caustics_refractive"] = draw(st.booleans())
    if draw(st.integers(0, 11)) == 11:  # an invalid or odd value somewhere
        name = draw(st.sampled_from(SETTINGS_FIELDS))
        f[name] = draw(st.integers(-2, 70000) | any_float | st.sampled_from(["x", None]))
    return f


@st.composite
def programs(draw):
    ops = draw(st.lists(op(), min_size=0, max_size=10))
    if draw(st.integers(0, 9)) != 9:  # usually a camera (0, the simplest value, inserts one) that sees the origin, so there is something to render
        ops.insert(draw(st.integers(0, len(ops))), ("camera", ((0.0, -6.0, 1.0), (0.0, 0.0, 0.0), {})))
    ops.append(("render", draw(render_fields())))
    if draw(st.booleans()):
        ops.append(("render", draw(render_fields())))  # rendering twice in a row
    return ops


FUZZ_SETTINGS = settings(
    max_examples=EXAMPLES,
    deadline=None if LONG else 10_000,
    derandomize=not LONG,
    database=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
)


def _seeded(test):
    seed = os.environ.get("PATHLIGHT_FUZZ_SEED")
    return hypothesis.seed(int(seed))(test) if LONG and seed else test


@_seeded
@FUZZ_SETTINGS
@given(programs())
def test_fuzz_scene_api(program):
    assume(not known_crash(program))
    save(program, LAST)  # a crash leaves its input here
    execute(program)


# ---------------------------------------------------------------- regressions: tests/core/fuzz/*.json

def regression_files():
    return sorted(FUZZ_DIR.glob("*.json"))


def regression_params():
    params = []
    for path in regression_files():
        meta = json.loads(path.read_text())
        marks = ([pytest.mark.xfail(reason=meta["xfail"], strict=True)]
                 if isinstance(meta, dict) and meta.get("xfail") else [])
        params.append(pytest.param(path, id=path.stem, marks=marks))
    return params


@pytest.mark.parametrize("path", regression_params())
def test_fuzz_regressions(path):
    # A fresh interpreter per input: a crash (negative return code) fails this test only.
    code = (f"import sys; sys.path[:0] = [{str(REPO)!r}, {str(Path(__file__).parent)!r}]\n"
            "import test_fuzz_core as f\n"
            f"print('summary', f.execute(f.load({str(path)!r})))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, (f"{path.name}: exit code {proc.returncode} (negative: killed by that "
                                  f"signal)\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")


def test_serialisation_round_trips(tmp_path):
    program = [("mesh", (np.full((2, 3), np.nan, np.float32), np.asfortranarray(np.zeros((1, 3), np.int64)),
                         None, np.array([1], np.int64), [0, 2**40])),
               ("camera", ((0.0, -6.0, 1.0), (0.0, 0.0, 0.0), {"lens": math.inf})),
               ("render", {"width": 2, "height": 2, "samples": 1, "sampler": None})]
    save(program, tmp_path / "p.json")
    back = load(tmp_path / "p.json")
    assert np.isnan(back[0][1][0]).all() and back[0][1][0].dtype == np.float32
    assert back[0][1][1].dtype == np.int64 and back[0][1][1].flags.f_contiguous
    assert back[1][1][2]["lens"] == math.inf and back[2][1]["sampler"] is None
