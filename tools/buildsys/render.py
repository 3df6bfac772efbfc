"""`render`: the arguments checked and turned into plain data, then the render itself in
headless bpy under .venv's Python (`build.py _render`)."""

import json
import os
import re
import signal
import sys
import threading
import time
from pathlib import Path

from .common import ROOT, VENV, VENV_PY, UserError, hard_exit, rel, run_internal
from .compile import runtime_env, setup_and_build
from .progress import ProgressPrinter, StatusLineFilter


OUTPUT_FORMATS = {".png": "PNG", ".exr": "EXR"}


def render_options(args):
    """Check the render arguments before any slow setup, and turn them into plain data for the venv side."""
    scene = Path(args.scene)
    if not scene.is_file():
        raise UserError(f"scene not found: {args.scene}")
    if scene.suffix.lower() not in (".blend", ".obj"):
        raise UserError(f"expected a .blend or .obj file, got {args.scene}")
    out = Path(args.output)
    ext_format = OUTPUT_FORMATS.get(out.suffix.lower())
    fmt = args.format or ext_format
    if fmt is None:
        raise UserError(f"cannot tell the image format from '{out.name}': name it .png or .exr, or pass --format")
    if args.format and ext_format and args.format != ext_format:
        raise UserError(f"--format {args.format} does not match the file name {out.name}")
    if out.parent != Path("") and not out.parent.resolve().is_dir():
        raise UserError(f"output directory does not exist: {out.parent}")
    for name, low in (("samples", 1), ("threads", 1), ("time_limit", 0)):
        value = getattr(args, name)
        if value is not None and value < low:
            raise UserError(f"--{name.replace('_', '-')} must be at least {low}")
    if args.threads is not None and args.threads > 1024:
        raise UserError("--threads must be at most 1024 (Blender's limit)")
    sample_offset = getattr(args, "sample_offset", None)  # the options added later are optional
    if sample_offset is not None and sample_offset < 0:
        raise UserError("--sample-offset must be at least 0")
    frame_samples = getattr(args, "frame_samples", None)
    if frame_samples is not None and frame_samples < 0:
        raise UserError("--frame-samples must be at least 0")
    frames = frame_range(args)
    if frames[0] != frames[1] and "#" not in out.name:
        # Blender's convention: '#'s become the zero-padded frame number.
        out = out.with_name(f"{out.stem}_####{out.suffix}")
    return {
        "scene": str(scene.resolve()), "output": str(out.resolve()), "format": fmt,
        "samples": args.samples, "time_limit": args.time_limit, "threads": args.threads,
        "seed": args.seed, "frame": frames[0], "frame_end": frames[1], "verbose": args.verbose,
        "sample_offset": sample_offset, "frame_samples": frame_samples,
    }


def frame_range(args):
    """(first, last) frame from --frame, --frames A-B or --frame-start/--frame-end."""
    first = last = args.frame
    frames = getattr(args, "frames", None)
    start, end = getattr(args, "frame_start", None), getattr(args, "frame_end", None)
    if frames is not None:
        if start is not None or end is not None:
            raise UserError("give either --frames or --frame-start/--frame-end")
        m = re.fullmatch(r"\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*)?", frames)
        if not m:
            raise UserError(f"--frames takes FIRST-LAST (e.g. 1-3) or one frame, not '{frames}'")
        first = int(m.group(1))
        last = int(m.group(2)) if m.group(2) is not None else first
    elif start is not None or end is not None:
        first = start if start is not None else args.frame
        last = end if end is not None else first
    if last < first:
        raise UserError(f"the frame range {first}-{last} is empty")
    return first, last


def numbered(path, frame):
    """path with its last run of '#' replaced by the zero-padded frame number (Blender's rule)."""
    runs = list(re.finditer(r"#+", path))
    if not runs:
        return path
    m = runs[-1]
    return path[:m.start()] + f"{frame:0{len(m.group())}d}" + path[m.end():]


def cmd_render(args):
    opts = render_options(args)
    setup_and_build(args)
    # Hand over to the venv's Python (bpy lives there); exec so signals and the exit code pass straight through.
    argv = [str(VENV_PY), str(ROOT / "build.py"), "_render", json.dumps(opts)]
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(str(VENV_PY), argv, runtime_env(args))


def exit_on_signals():
    """Ctrl-C must stop a headless render: bpy installs no signal handlers and cannot be interrupted
    from Python while it is inside C code. Block the signals in every thread and let one thread wait
    for them and end the process at once."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, sigs)  # before bpy starts threads, so they inherit it

    def wait():
        sig = signal.sigwait(sigs)
        sys.stderr.write("\ninterrupted; the render was not saved\n")
        hard_exit(128 + sig)

    threading.Thread(target=wait, name="pathlight-signals", daemon=True).start()


def internal_render(argv):
    """`build.py _render OPTIONS_JSON`: the `render` command's second half, under .venv's Python."""
    run_internal(lambda: render_in_venv(json.loads(argv[0])))


def render_in_venv(opts):
    exit_on_signals()
    try:
        import bpy
    except ImportError as exc:
        raise UserError(f"bpy does not import in {rel(VENV)} ({exc}); run `python3 build.py setup`")

    # Blender prints a Python error raised inside a RenderEngine callback through sys.excepthook and
    # carries on; record such errors so a failed render exits non-zero.
    engine_errors = []
    default_hook = sys.excepthook

    def hook(*exc_info):
        engine_errors.append(exc_info[1])
        default_hook(*exc_info)
    sys.excepthook = hook

    sys.path.insert(0, str(ROOT))
    if opts["scene"].lower().endswith(".obj"):
        # Blender's OBJ importer into an empty scene, a camera framing it and a world light.
        from addon.obj_scene import ObjSceneError, load_obj_scene
        try:
            load_obj_scene(opts["scene"])
        except ObjSceneError as exc:
            raise UserError(str(exc))
    else:
        try:
            bpy.ops.wm.open_mainfile(filepath=opts["scene"])
        except RuntimeError as exc:
            raise UserError(f"could not open {opts['scene']}: {exc}")

    try:
        import addon
        addon.register()
    except Exception as exc:
        raise UserError(f"the Pathlight add-on failed to load: {type(exc).__name__}: {exc}")

    scene = bpy.context.scene
    try:
        scene.render.engine = "PATHLIGHT"
    except TypeError:
        raise UserError("the add-on did not register a render engine called PATHLIGHT")
    if scene.camera is None:
        raise UserError(f"scene '{scene.name}' has no active camera")

    settings = getattr(scene, "pathlight", None)
    for name in ("samples", "time_limit", "seed", "sample_offset", "frame_samples"):
        if opts.get(name) is not None:
            if settings is None or not hasattr(settings, name):
                raise UserError(f"the add-on has no scene.pathlight.{name} setting")
            setattr(settings, name, opts[name])
    if opts["threads"] is not None:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = opts["threads"]
    first, last = opts["frame"], opts.get("frame_end", opts["frame"])
    scene.frame_set(first)

    image = scene.render.image_settings
    if opts["format"] == "EXR":
        image.file_format = "OPEN_EXR"
        image.color_depth = "32"
        image.exr_codec = "ZIP"
    else:
        keep_depth = image.file_format == "PNG"  # the scene may ask for 16-bit PNG
        image.file_format = "PNG"
        if not keep_depth:
            image.color_depth = "8"
    # Write exactly the path given: no extension appended.
    scene.render.use_file_extension = False
    scene.render.filepath = opts["output"]

    r = scene.render
    width = r.resolution_x * r.resolution_percentage // 100
    height = r.resolution_y * r.resolution_percentage // 100
    samples = getattr(settings, "samples", None)
    time_limit = getattr(settings, "time_limit", 0)
    frames = f"frame {first}" if first == last else f"frames {first}-{last}"
    print(f"Rendering {Path(opts['scene']).name}, {frames}, {width}x{height}"
          + (f", {samples} samples" if samples is not None else "")
          + (f", time limit {time_limit:g} s" if time_limit else "")
          + f" -> {opts['output']}", flush=True)

    progress = ProgressPrinter(sys.stderr)
    session = getattr(addon, "session", None)
    listening = session is not None and hasattr(session, "set_progress_listener")
    status_filter = StatusLineFilter(progress)
    if listening:
        session.set_progress_listener(progress)
        if not opts.get("verbose"):
            status_filter.start()

    outs = [Path(numbered(opts["output"], f)) for f in range(first, last + 1)]

    def failed(msg):
        # Blender saves whatever the film held even when the engine failed; don't leave that
        # looking like a finished render.
        for out in outs:
            if out.is_file() and out.stat().st_mtime >= start - 1:
                out.unlink()
                msg += f"; removed the incomplete {out.name}"
        return UserError(msg)

    start = time.time()
    try:
        if first == last:
            scene.render.filepath = str(outs[0])
            result = bpy.ops.render.render(write_still=True)
        else:
            # One animation job, as `blender -a`: meshes that do not change between frames are
            # exported once (the add-on's export cache lives for the job).
            scene.frame_start, scene.frame_end, scene.frame_step = first, last, 1
            result = bpy.ops.render.render(animation=True)
    except RuntimeError as exc:  # the engine's ERROR reports surface here
        raise failed(f"render failed: {str(exc).strip()}")
    finally:
        status_filter.stop()
        progress.finish()
        if listening:
            session.set_progress_listener(None)
    elapsed = time.time() - start

    if engine_errors:
        raise failed("render failed: the add-on raised an error during the render (see above)")
    if "FINISHED" not in result:
        raise failed(f"render failed: the render operator returned {sorted(result)}")
    for out in outs:
        if not out.is_file() or out.stat().st_mtime < start - 1:
            raise UserError(f"the render finished but {out} was not written")

    info = progress.last or {}
    if info.get("samples_total"):
        done = f"{info.get('samples_done', 0)}/{info['samples_total']} samples"
    else:
        done = f"{samples} samples" if samples is not None else "done"
    where = outs[0] if len(outs) == 1 else f"{outs[0]} ... {outs[-1].name}"
    print(f"Rendered {done}{'' if len(outs) == 1 else ' per frame'} in {elapsed:.1f} s -> {where}",
          flush=True)
