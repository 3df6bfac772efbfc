"""Farm splitting: sample offsets, the merge of partial EXR renders, and build.py's frame
ranges and numbered outputs."""

import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

import build
from core_scenes import core, cornell

REPO = Path(__file__).resolve().parents[2]


def _has_offset():
    try:
        return hasattr(core().RenderSettings(), "sample_offset")
    except ImportError:
        return False


needs_offset = pytest.mark.skipif(not _has_offset(), reason="core without sample_offset")


def _session_film(pc, scene, samples, offset, threads=2):
    st = pc.RenderSettings()
    st.width = st.height = 24
    st.samples, st.sample_offset, st.seed, st.threads = samples, offset, 7, threads
    sess = pc.Session(scene, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    return sess.film()


@needs_offset
def test_core_partial_ranges_add_up_to_the_whole():
    pc = core()
    scene = cornell(pc)
    whole = _session_film(pc, scene, 16, 0)
    parts = [_session_film(pc, scene, 4, 4 * k) for k in range(4)]
    np.testing.assert_allclose(np.mean(parts, axis=0), whole, rtol=2e-5, atol=2e-6)
    # Different ranges really are different samples (not the same four samples again).
    assert not np.allclose(parts[0], parts[1])
    with pytest.raises(ValueError):
        _session_film(pc, scene, 4, -1)


def _blender_partial(tmp, name, samples, offset, frame_samples=0):
    """A Cornell box render through the add-on into an EXR (with its metadata); frame_samples:
    the frame's total, which the default blue noise lays its chunks out for (docs/farm.md)."""
    import bpy
    from blender_util import _setup_pathlight, load_addon, open_fixture
    load_addon()
    sc = open_fixture("cornell_box")
    sc.render.engine = "PATHLIGHT"
    _setup_pathlight(sc.pathlight)
    sc.pathlight.samples, sc.pathlight.sample_offset, sc.pathlight.seed = samples, offset, 3
    sc.pathlight.frame_samples = frame_samples
    sc.render.resolution_percentage = 12  # 30 x 30
    sc.render.use_compositing = sc.render.use_sequencer = False
    image = sc.render.image_settings
    image.file_format, image.color_mode, image.color_depth = 'OPEN_EXR', 'RGBA', '32'
    path = Path(tmp) / name
    sc.render.filepath, sc.render.use_file_extension = str(path), False
    bpy.ops.render.render(write_still=True, scene=sc.name)
    return path


@needs_offset
def test_four_partial_blender_renders_merge_into_one():
    with tempfile.TemporaryDirectory(prefix="pathlight_farm_") as tmp:
        parts = [_blender_partial(tmp, f"part{k}.exr", 4, 4 * k, 16) for k in range(4)]
        whole = _blender_partial(tmp, "whole.exr", 16, 0)
        out = Path(tmp) / "merged.exr"
        info = build.merge_exr([str(p) for p in parts], str(out))
        assert info["samples"] == 16 and info["weights"] == "samples per file"
        with OpenEXR.File(str(out)) as a, OpenEXR.File(str(whole)) as b:
            merged, single = a.channels()["RGBA"].pixels.copy(), b.channels()["RGBA"].pixels.copy()
            assert a.header()["Pathlight Samples"] == "16"
            assert a.header()["Pathlight Sample Offset"] == "0"
        assert merged.mean() > 0.01
        np.testing.assert_allclose(merged, single, rtol=2e-5, atol=2e-6)
        # Overlapping ranges would count samples twice: refused.
        with pytest.raises(build.UserError, match="overlap"):
            build.merge_exr([str(parts[0]), str(parts[0])], str(out))


def _write_exr(path, rgb, count=None, samples=None):
    channels = {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]}
    if count is not None:
        channels["ViewLayer.Sample Count"] = count.astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION}
    if samples is not None:
        header["Pathlight Samples"] = str(samples)
    OpenEXR.File(header, {k: np.ascontiguousarray(v, np.float32) for k, v in channels.items()}
                 ).write(str(path))


def test_merge_weighs_by_the_per_pixel_sample_count_when_present():
    """With a Sample Count pass (adaptive sampling: each pixel its own count) the weights are
    per pixel, and the counts add up."""
    with tempfile.TemporaryDirectory(prefix="pathlight_merge_") as tmp:
        a, b = np.full((2, 3, 3), 1.0), np.full((2, 3, 3), 4.0)
        ca, cb = np.array([[1, 3, 0], [2, 2, 5]]), np.array([[3, 1, 4], [2, 0, 0]])
        _write_exr(Path(tmp) / "a.exr", a, ca, samples=8)
        _write_exr(Path(tmp) / "b.exr", b, cb, samples=8)
        out = Path(tmp) / "m.exr"
        info = build.merge_exr([str(Path(tmp) / "a.exr"), str(Path(tmp) / "b.exr")], str(out))
        assert info["weights"] == "per-pixel sample counts"
        with OpenEXR.File(str(out)) as f:
            ch = {k: v.pixels.copy() for k, v in f.channels().items()}
        expect = np.where(ca + cb > 0, (ca * 1.0 + cb * 4.0) / np.maximum(ca + cb, 1), 0.0)
        rgb = ch["RGB"] if "RGB" in ch else np.stack([ch[c] for c in "RGB"], -1)  # OpenEXR 3 groups
        np.testing.assert_allclose(rgb[..., 0], expect, rtol=1e-6)
        np.testing.assert_allclose(rgb[..., 2], expect, rtol=1e-6)
        np.testing.assert_array_equal(ch["ViewLayer.Sample Count"], ca + cb)
        # Files without counts or metadata cannot be weighed.
        _write_exr(Path(tmp) / "c.exr", a)
        with pytest.raises(build.UserError, match="Sample Count"):
            build.merge_exr([str(Path(tmp) / "c.exr")] * 2, str(out))


def test_frame_ranges_and_numbered_names():
    args = build.parse_args(["render", "x.blend", "-o", "out.png", "--frames", "2-4"])[0]
    assert build.frame_range(args) == (2, 4)
    args = build.parse_args(["render", "x.blend", "-o", "o.png", "--frame-start", "5",
                             "--frame-end", "6"])[0]
    assert build.frame_range(args) == (5, 6)
    args = build.parse_args(["render", "x.blend", "-o", "o.png", "--frame", "7"])[0]
    assert build.frame_range(args) == (7, 7)
    for bad in ("3-1", "a-b"):
        args = build.parse_args(["render", "x.blend", "-o", "o.png", "--frames", bad])[0]
        with pytest.raises(build.UserError):
            build.frame_range(args)
    assert build.numbered("/r/out_####.png", 12) == "/r/out_0012.png"
    assert build.numbered("/r/shot##_v2.exr", 3) == "/r/shot03_v2.exr"
    assert build.numbered("/r/out.png", 3) == "/r/out.png"


@needs_offset
def test_build_py_renders_a_frame_range_into_numbered_files():
    with tempfile.TemporaryDirectory(prefix="pathlight_frames_") as tmp:
        out = Path(tmp) / "out.png"
        proc = subprocess.run([sys.executable, str(REPO / "build.py"), "render",
                               str(REPO / "blender_scenes" / "cornell_box.blend"), "-o", str(out),
                               "--frames", "1-2", "--samples", "1", "--sample-offset", "5"],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert sorted(p.name for p in Path(tmp).iterdir()) == ["out_0001.png", "out_0002.png"]


def test_build_py_merge_command():
    with tempfile.TemporaryDirectory(prefix="pathlight_mergecli_") as tmp:
        a, b = Path(tmp) / "a.exr", Path(tmp) / "b.exr"
        _write_exr(a, np.full((2, 2, 3), 1.0), samples=1)
        _write_exr(b, np.full((2, 2, 3), 4.0), samples=3)
        out = Path(tmp) / "m.exr"
        proc = subprocess.run([sys.executable, str(REPO / "build.py"), "merge", str(a), str(b),
                               "-o", str(out)], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert "4 samples" in proc.stdout
        with OpenEXR.File(str(out)) as f:
            rgb = next(iter(f.channels().values())).pixels.copy()
            assert f.header()["Pathlight Samples"] == "4"
        np.testing.assert_allclose(rgb, (1.0 * 1 + 4.0 * 3) / 4, rtol=1e-6)
        proc = subprocess.run([sys.executable, str(REPO / "build.py"), "merge", str(a),
                               "-o", str(Path(tmp) / "m.png")], capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 1 and "must be an .exr" in proc.stderr


@needs_offset
def test_merge_uses_the_sample_count_pass_of_adaptive_renders():
    """Adaptive partial renders with the Sample Count pass (multilayer EXR): each pixel is
    weighted by its own count, and the merged file's counts are the sums."""
    import bpy
    from blender_util import load_addon, open_fixture
    load_addon()
    with tempfile.TemporaryDirectory(prefix="pathlight_farm_ml_") as tmp:
        paths = []
        for k in range(2):
            sc = open_fixture("cornell_box")
            sc.render.engine = "PATHLIGHT"
            if not hasattr(sc.view_layers[0], "pathlight"):
                pytest.skip("add-on without render passes")
            p = sc.pathlight
            p.samples, p.sample_offset, p.seed = 32, 32 * k, 3
            p.use_adaptive_sampling, p.adaptive_threshold = True, 0.05
            sc.view_layers[0].pathlight.use_pass_sample_count = True
            sc.render.resolution_percentage = 12
            image = sc.render.image_settings
            image.file_format, image.color_depth = 'OPEN_EXR_MULTILAYER', '32'
            paths.append(str(Path(tmp) / f"part{k}.exr"))
            sc.render.filepath, sc.render.use_file_extension = paths[-1], False
            bpy.ops.render.render(write_still=True, scene=sc.name)
        out = Path(tmp) / "merged.exr"
        info = build.merge_exr(paths, str(out))
        assert info["weights"] == "per-pixel sample counts"
        parts = []
        for path in paths + [str(out)]:
            with OpenEXR.File(path) as f:
                ch = f.channels()
                parts.append((ch["ViewLayer.Combined"].pixels.copy(),
                              ch["ViewLayer.Sample Count.X"].pixels.astype(np.float64)))
        (a, ca), (b, cb), (m, cm) = parts
        assert ca.min() < ca.max()  # adaptive: the counts differ per pixel
        np.testing.assert_array_equal(cm, ca + cb)
        expect = (a * ca[..., None] + b * cb[..., None]) / np.maximum(ca + cb, 1)[..., None]
        np.testing.assert_allclose(m, expect, rtol=1e-5, atol=1e-7)


# ---------------------------------------------------------------- Flamenco job type

SPLIT_JOB = REPO / "tools" / "flamenco" / "pathlight_split_frame.js"
NODE = shutil.which("node")
needs_node = pytest.mark.skipif(NODE is None, reason="Node.js (node) not installed")


def _compile_job(settings):
    """Runs the job type under tests/blender/flamenco_mock.js (Flamenco's job-compiler globals)."""
    proc = subprocess.run([NODE, str(REPO / "tests" / "blender" / "flamenco_mock.js"), str(SPLIT_JOB),
                           json.dumps({"settings": settings})],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout)


def _split_settings(samples, pieces, frame=7):
    return dict(frame=frame, samples=samples, pieces=pieces, render_output_root="/farm/out",
                blendfile="/farm/shots/heavy.blend")


def _task_range(task):
    """(offset, count) from the task's Python expression (what Blender will run)."""
    expr = task["commands"][0]["parameters"]["args"][1]
    count = int(re.search(r"pathlight\.samples = (\d+)", expr).group(1))
    offset = int(re.search(r"pathlight\.sample_offset = (\d+)", expr).group(1))
    return offset, count


@needs_node
@pytest.mark.parametrize("samples,pieces", [(1024, 4), (10, 4), (7, 3), (5, 5), (3, 8),
                                            (1, 1), (1000, 7)])
def test_flamenco_split_frame_tasks_cover_the_samples_once(samples, pieces):
    out = _compile_job(_split_settings(samples, pieces))
    assert "error" not in out, out
    assert out["job_type"]["label"] == "Pathlight Split Frame"
    keys = {s["key"] for s in out["job_type"]["settings"]}
    assert {"frame", "samples", "pieces", "render_output_root", "blendfile"} <= keys
    *tasks, merge = out["tasks"]
    assert len(tasks) == min(samples, pieces)  # pieces > samples: one sample per task
    ranges = [_task_range(t) for t in tasks]
    # Every piece knows the frame's total, which blue noise lays its chunks out for.
    for t in tasks:
        assert f"pathlight.frame_samples = {samples};" in t["commands"][0]["parameters"]["args"][1]
    # Consecutive, disjoint, covering [0, samples) exactly once; balanced to within one.
    covered = np.zeros(samples, int)
    for offset, count in ranges:
        assert count >= 1
        covered[offset:offset + count] += 1
    assert (covered == 1).all()
    assert [o for o, _ in ranges] == sorted(o for o, _ in ranges)
    counts = [c for _, c in ranges]
    assert max(counts) - min(counts) <= 1 and sum(counts) == samples
    names = [t["name"] for t in tasks]
    assert names == [f"samples-{o}-{o + c}" for o, c in ranges] and len(set(names)) == len(names)
    for k, task in enumerate(tasks):
        assert task["type"] == "blender" and len(task["commands"]) == 1
        assert task["dependencies"] == []
        cmd = task["commands"][0]
        assert cmd["name"] == "blender-render"
        # What the worker runs: Blender, the Manager's arguments, the file, then ours: the
        # Python expression first (it runs once the file is loaded), the frame last (Blender
        # renders when it reads --render-frame, with everything before it applied).
        cli = cmd["cli"]
        assert cli[:4] == ["{blender}", "{blenderArgs}", "/farm/shots/heavy.blend",
                           "--python-expr"]
        assert cli[5:] == ["--render-output", f"/farm/out/part{k}_######",
                           "--render-frame", "7"]
        compile(cli[4], "<python-expr>", "exec")  # valid Python
    # The merge runs after every render task, in Blender without a file.
    assert merge["name"] == "merge" and merge["type"] == "blender"
    assert sorted(merge["dependencies"]) == sorted(names)
    cli = merge["commands"][0]["cli"]
    assert cli[:3] == ["{blender}", "{blenderArgs}", "--python-expr"] and len(cli) == 4
    compile(cli[3], "<python-expr>", "exec")
    call = cli[3].rsplit("; ", 1)[1]
    assert call.startswith("merge(7, ")
    parts = json.loads(call[len("merge(7, "):call.rindex("], ") + 1])
    assert parts == [[f"/farm/out/part{k}_######", o, c] for k, (o, c) in enumerate(ranges)]
    assert call.endswith(', "/farm/out/frame_######")')


@needs_node
@pytest.mark.parametrize("bad", [dict(samples=0), dict(pieces=0), dict(samples=-3),
                                 dict(pieces=2.5), dict(frame="x")])
def test_flamenco_split_frame_refuses_bad_settings(bad):
    out = _compile_job(dict(_split_settings(8, 2), **bad))
    assert "error" in out and not out.get("tasks")


@needs_node
@needs_offset
def test_flamenco_split_frame_tasks_render_and_merge_into_the_whole_frame():
    """The compiled tasks' Python expressions, run in Blender on the Cornell box, render the
    pieces; the merge task's expression (the add-on's farm_merge, in Blender) writes what
    `build.py merge` writes, which equals one render of all samples."""
    import bpy
    from blender_util import _setup_pathlight, load_addon, open_fixture
    out = _compile_job(dict(_split_settings(9, 4, frame=1)))
    with tempfile.TemporaryDirectory(prefix="pathlight_flamenco_") as tmp:
        def render(name, expr=None, samples=None):
            load_addon()
            sc = open_fixture("cornell_box")
            sc.render.engine = "PATHLIGHT"
            _setup_pathlight(sc.pathlight)
            sc.pathlight.seed = 3
            sc.render.resolution_percentage = 12  # 30 x 30
            sc.render.use_sequencer = False
            if expr is not None:
                # The artist's settings that would spoil a piece; the task turns them off.
                sc.render.use_compositing = sc.pathlight.use_adaptive_sampling = True
                sc.pathlight.time_limit = 100.0
                sc.render.image_settings.file_format = 'PNG'
                exec(expr, {})  # what --python-expr runs in the task
                assert not sc.render.use_compositing and not sc.pathlight.use_adaptive_sampling
                assert sc.pathlight.time_limit == 0
                assert sc.render.image_settings.file_format == 'OPEN_EXR'
                assert sc.render.image_settings.color_depth == '32'
            else:
                sc.pathlight.samples, sc.pathlight.sample_offset = samples, 0
                sc.render.use_compositing = False
                sc.render.image_settings.file_format = 'OPEN_EXR'
                sc.render.image_settings.color_depth = '32'
            sc.render.filepath = str(Path(tmp) / name)  # what --render-output sets
            sc.render.use_file_extension = True
            # --render-frame 1 is RE_RenderAnim(frame 1..1): a one-frame animation job.
            sc.frame_start = sc.frame_end = 1
            bpy.ops.render.render(animation=True, scene=sc.name)
            return Path(sc.render.frame_path(frame=1))

        *tasks, merge_task = out["tasks"]
        parts = []
        for task in tasks:
            args = task["commands"][0]["parameters"]["args"]
            name = Path(args[args.index("--render-output") + 1]).name
            parts.append(render(name, expr=args[1]))
        assert [p.name for p in parts] == [f"part{k}_000001.exr" for k in range(4)]
        whole = render("whole_######", samples=9)
        reference = Path(tmp) / "reference.exr"
        info = build.merge_exr([str(p) for p in parts], str(reference))
        assert info["samples"] == 9
        # The merge task, run in Blender (outputs under tmp instead of /farm/out).
        expr = merge_task["commands"][0]["parameters"]["args"][1]
        exec(expr.replace("/farm/out", tmp), {})
        merged = Path(tmp) / "frame_000001.exr"
        with OpenEXR.File(str(merged)) as a, OpenEXR.File(str(whole)) as b, \
                OpenEXR.File(str(reference)) as c:
            m, w = a.channels()["RGBA"].pixels.copy(), b.channels()["RGBA"].pixels.copy()
            r = c.channels()["RGBA"].pixels.copy()
        assert m.dtype == np.float32 and m.mean() > 0.01
        np.testing.assert_allclose(m, r, rtol=1e-6, atol=1e-7)  # = build.py merge
        np.testing.assert_allclose(m, w, rtol=2e-5, atol=2e-6)  # = one render of all samples


def test_blender_side_merge_weighs_and_refuses():
    """addon/farm_merge.py (the Flamenco merge task): the sample-weighted mean of the pieces
    in a 32-bit float EXR, rows kept in place; overlapping ranges, differently sized pieces and
    non-float images refused."""
    import bpy
    from blender_util import load_addon
    load_addon()
    from addon.farm_merge import frame_file, merge_pieces
    with tempfile.TemporaryDirectory(prefix="pathlight_bmerge_") as tmp:
        rng = np.random.default_rng(5)
        a, b = rng.uniform(0, 50, (3, 4, 3)), rng.uniform(-1, 2, (3, 4, 3))
        a[0, 0] = (1e-7, 3e4, 0.5)  # tiny, huge and exact values survive
        pa, pb = str(Path(tmp) / "a.exr"), str(Path(tmp) / "b.exr")
        _write_exr(pa, a)
        _write_exr(pb, b)
        out = str(Path(tmp) / "m.exr")
        assert merge_pieces([(pa, 0, 3), (pb, 3, 1)], out) == 4
        with OpenEXR.File(out) as f:
            ch = f.channels()
            rgba = ch["RGBA"].pixels.copy()
        assert rgba.dtype == np.float32 and rgba.shape == (3, 4, 4)
        expect = ((3 * a.astype(np.float32).astype(np.float64) + b.astype(np.float32)) / 4)
        np.testing.assert_allclose(rgba[..., :3], expect, rtol=1e-6)
        with pytest.raises(ValueError, match="overlap"):
            merge_pieces([(pa, 0, 3), (pb, 2, 1)], out)
        _write_exr(Path(tmp) / "small.exr", a[:2])
        with pytest.raises(ValueError, match="the first piece"):
            merge_pieces([(pa, 0, 3), (str(Path(tmp) / "small.exr"), 3, 1)], out)
        img = bpy.data.images.new("png", 2, 2)
        img.filepath_raw, img.file_format = str(Path(tmp) / "p.png"), 'PNG'
        img.save()
        with pytest.raises(ValueError, match="float"):
            merge_pieces([(str(Path(tmp) / "p.png"), 0, 1)], out)
        with pytest.raises(RuntimeError):
            merge_pieces([(str(Path(tmp) / "missing.exr"), 0, 1)], out)
        # Blender's naming of a frame's file, as --render-output/--render-frame write it.
        assert frame_file(str(Path(tmp) / "part0_######"), 7) == str(Path(tmp) / "part0_000007.exr")
