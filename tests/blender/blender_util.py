"""Helpers for the tests that run Blender headless (the `bpy` module)."""

import math
import sys
import tempfile
from pathlib import Path

import bpy
import numpy as np
import OpenEXR

import cycles_refs

REPO = Path(__file__).resolve().parents[2]
SCENES = REPO / "blender_scenes"


def load_addon():
    """Import the add-on package as `addon` and register it (registering is idempotent)."""
    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    import addon
    addon.register()
    return addon


def core_available():
    try:
        load_addon().core.get_core()
    except RuntimeError:
        return False
    return True


def core_has(cls, name):
    """Whether the built core's class `cls` ("Scene", "Session", ...) has attribute `name`."""
    if not core_available():
        return False
    return hasattr(getattr(load_addon().core.get_core(), cls), name)


class RecordingLayout:
    """A stand-in for a panel's UILayout: records the properties drawn (each must exist on its
    data); any other call (column, row, split, ...) returns the layout itself."""

    def __init__(self):
        self.props = []

    def __getattr__(self, name):
        if name in {"use_property_split", "use_property_decorate", "active", "enabled"}:
            raise AttributeError(name)
        return lambda *a, **kw: self

    def prop(self, data, name, **kw):
        assert hasattr(data, name), name
        self.props.append(name)

    def prop_search(self, data, name, search_data, search_name, **kw):
        assert hasattr(data, name) and hasattr(search_data, search_name), (name, search_name)
        self.props.append(name)

    def separator(self, **kw):
        pass


def core_session(scene):
    """The scene rendered to completion by a core Session held by the test, through the add-on's
    export and render settings as the scene's Pathlight settings stand (for what a Blender
    render result cannot show: sample counts, timing, the film before Blender's result)."""
    from addon import session
    from addon.core import get_core
    from addon.export import export_scene
    from addon.scene_writer import to_core
    pc = get_core()
    warnings = []
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warnings.append)
    sess = pc.Session(to_core(pc, data, warnings.append), session.render_settings(pc, scene))
    sess.start()
    while not sess.wait(1.0):
        pass
    return sess


def empty_scene_with_camera(resolution=32):
    """The factory-empty scene with a camera at (0, -6, 0) looking at the origin along +y."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    sc = bpy.context.scene
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0.0, -6.0, 0.0)
    cam.rotation_euler = (math.pi / 2, 0.0, 0.0)
    sc.collection.objects.link(cam)
    sc.camera = cam
    sc.render.resolution_x = sc.render.resolution_y = resolution
    sc.render.resolution_percentage = 100
    return sc


def canonical_order(bm):
    """Sorts a BMesh's edges and faces by their vertices' indices, in place. Blender's UV sphere
    (bmesh.ops.create_uvsphere, primitive_uv_sphere_add) comes out with the same faces, corners
    and vertices but its faces in an order that changes from one process to the next; the
    exported triangles follow it and smooth normals sum in face order (Blender's own
    vertex_normals too), so a scene script would render differently in every process
    (docs/design/robustness.md, "Determinism"). Vertex order, and corner order inside a face
    (it decides a quad's split), are kept."""
    bm.verts.index_update()
    for seq in (bm.edges, bm.faces):
        seq.index_update()
        keys = [tuple(sorted(v.index for v in e.verts)) for e in seq]
        rank = [0] * len(keys)
        for r, i in enumerate(sorted(range(len(keys)), key=keys.__getitem__)):
            rank[i] = r
        seq.sort(key=lambda e: rank[e.index])
        seq.index_update()


def open_fixture(name):
    """Open blender_scenes/<name>(.blend) and return its scene."""
    path = SCENES / name
    if path.suffix != ".blend":
        path = path.with_suffix(".blend")
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    return bpy.context.scene


def render_to_array(scene=None, engine="PATHLIGHT", **overrides):
    """Render `scene` (default: the current one) with `engine` ("PATHLIGHT" or "CYCLES") and
    return its linear RGBA as float32 (H, W, 4), row 0 = TOP row (image order, as in image
    files and viewers; the core's film and Blender's pass rects have row 0 = bottom). With
    multiview on (Output > Stereoscopy): {view name: RGBA} of every view.

    overrides: the engine's settings (scene.pathlight.<name> / scene.cycles.<name>) or else
    scene.render.<name>, e.g. samples=16, seed=3, resolution_percentage=25. For CYCLES,
    max_bounces (default 1024) sets every bounce limit, so only the total limits paths, like
    Pathlight's max_bounces. A CYCLES render comes from tests/cycles_refs/ when one of exactly
    this scene is stored there (cycles_refs.py; refs="check" renders and compares with it). For PATHLIGHT, adaptive sampling is off and the per-type bounce
    limits are 1024 unless overridden, so that only max_bounces limits paths there too.
    Pixel filters: Pathlight renders with the 1-pixel box here unless overridden
    (filter_type='GAUSSIAN', filter_width=1.5, ...; Cycles' names pixel_filter_type and
    filter_width also work, so BOX_FILTER sets both engines alike), as before Pathlight had
    filters; Cycles keeps its own default (Blackman-Harris 1.5 px) unless overridden.
    """
    scene = scene or bpy.context.scene
    refs = overrides.pop("refs", None)
    render = scene.render
    if render.engine != engine:  # setting it, even unchanged, tags every ID of the depsgraph
        render.engine = engine
    if engine == "PATHLIGHT":
        settings = scene.pathlight
        _setup_pathlight(settings)
    elif engine == "CYCLES":
        settings = scene.cycles
        _setup_cycles(settings, overrides.pop("max_bounces", 1024))
    else:
        raise ValueError(f"unsupported engine {engine!r}")
    if engine == "PATHLIGHT" and "pixel_filter_type" in overrides:
        overrides["filter_type"] = overrides.pop("pixel_filter_type")
    for name, value in overrides.items():
        target = settings if hasattr(settings, name) else render
        if not hasattr(target, name):
            raise AttributeError(f"no render setting {name!r} for {engine}")
        setattr(target, name, value)

    # Raw render: linear float, no view transform, compositor or sequencer in between.
    scene.view_settings.view_transform = 'Standard'
    scene.view_settings.look = 'None'
    render.use_compositing = False
    render.use_sequencer = False
    image = render.image_settings
    image.file_format = 'OPEN_EXR'
    image.color_mode = 'RGBA'
    image.color_depth = '32'
    image.exr_codec = 'ZIP'

    views = render_views(scene) if render.use_multiview else []
    if views:
        image.views_format = 'INDIVIDUAL'  # one file per view, named with its suffix

    def run():
        with tempfile.TemporaryDirectory(prefix="pathlight_test_") as tmp:
            render.filepath = str(Path(tmp) / "render.exr")
            render.use_file_extension = False
            bpy.ops.render.render(write_still=True, scene=scene.name)
            if views:  # multiview: {"rgba.<view>": image}
                return {f"rgba.{name}": read_exr(Path(tmp) / f"render{suffix}.exr") for name, suffix in views}
            return {"rgba": read_exr(render.filepath)}

    if engine == "CYCLES":
        render.use_file_extension = False
        out = cycles_refs.cached(scene, "rgba", run, refs)
    else:
        out = run()
    if views:
        return {name: out[f"rgba.{name}"] for name, _ in views}
    return out["rgba"]


def render_views(scene):
    """(name, file suffix) of the views a multiview render of `scene` has, in order (Blender's
    BKE_scene_multiview_is_render_view_active: Stereo 3D's left and right, or every enabled view)."""
    r = scene.render
    stereo = r.views_format == 'STEREO_3D'
    return [(v.name, v.file_suffix) for v in r.views
            if v.use and (not stereo or v.name in ("left", "right"))]


def render_multilayer_file(scene, path, refs=None):
    """Renders `scene` with its engine's current settings through Blender's own file output, as a
    32-bit multilayer EXR at `path` (no compositor or sequencer), and reads the first view layer's
    channels back: {"<pass>.<channel>": float32 (H, W)}, row 0 = top. With Cycles the file may
    come from tests/cycles_refs/ (see render_to_array; `refs` likewise)."""
    scene.render.use_compositing = scene.render.use_sequencer = False
    image = scene.render.image_settings
    image.file_format, image.color_depth, image.exr_codec = 'OPEN_EXR_MULTILAYER', '32', 'ZIP'
    scene.render.filepath = str(path)
    scene.render.use_file_extension = False
    layer = scene.view_layers[0].name + "."

    def read(p):
        with OpenEXR.File(str(p), separate_channels=True) as exr:
            return {k[len(layer):]: np.array(v.pixels, np.float32) for k, v in exr.channels().items()
                    if k.startswith(layer)}

    def run():
        bpy.ops.render.render(write_still=True, scene=scene.name)

    if scene.render.engine == "CYCLES":
        cycles_refs.cached_file(scene, "multilayer", path, run, read, refs)
    else:
        run()
    return read(path)



def render_multilayer_pair(scene, tmp, samples, bounces, refs=None):
    """Cycles' and Pathlight's multilayer passes of `scene` (render_multilayer_file into
    tmp / cycles.exr and tmp / pathlight.exr), rendered alike: `samples` each, `bounces` of
    every kind, the 1-pixel box filter, no adaptive sampling or denoising. refs: for Cycles, as
    render_multilayer_file's."""
    scene.render.engine = 'CYCLES'
    _setup_cycles(scene.cycles, bounces)
    scene.cycles.samples = samples
    scene.cycles.pixel_filter_type, scene.cycles.filter_width = BOX_FILTER["pixel_filter_type"], 1.0
    cycles = render_multilayer_file(scene, tmp / "cycles.exr", refs=refs)
    scene.render.engine = 'PATHLIGHT'
    pl = scene.pathlight
    pl.samples, pl.use_adaptive_sampling, pl.max_bounces = samples, False, bounces
    pl.filter_type, pl.filter_width = 'BOX', 1.0
    return cycles, render_multilayer_file(scene, tmp / "pathlight.exr")

def read_exr(path):
    """RGBA float32 (H, W, 4) of an EXR file, row 0 = top (the file's own order)."""
    with OpenEXR.File(str(path)) as exr:  # closing it empties channels(): copy first
        channels = exr.channels()
        if "RGBA" in channels:  # OpenEXR 3.x groups R, G, B, A into one channel by default
            rgba = channels["RGBA"].pixels
        else:
            rgba = np.stack([channels[c].pixels for c in "RGBA"], axis=-1)
        return np.array(rgba, dtype=np.float32)


def _setup_pathlight(settings):
    """Pathlight with every path-length limit but the total off, no adaptive sampling: the
    counterpart of _setup_cycles. (Settings the add-on does not have yet are skipped.)"""
    for name, value in (("use_adaptive_sampling", False), ("diffuse_bounces", 1024),
                        ("glossy_bounces", 1024), ("transmission_bounces", 1024), ("volume_bounces", 1024),
                        ("transparent_bounces", 1024),
                        ("filter_type", 'BOX'), ("filter_width", 1.0)):
        if hasattr(settings, name):
            setattr(settings, name, value)


def _setup_cycles(cycles, bounces):
    """Unbiased, deterministic Cycles on the CPU, comparable with Pathlight."""
    cycles.device = 'CPU'
    cycles.use_denoising = False
    cycles.use_adaptive_sampling = False
    cycles.sample_clamp_direct = 0.0
    cycles.sample_clamp_indirect = 0.0
    cycles.blur_glossy = 0.0
    cycles.max_bounces = bounces
    for name in ("diffuse_bounces", "glossy_bounces", "transmission_bounces",
                 "volume_bounces", "transparent_max_bounces"):
        setattr(cycles, name, bounces)


# The 1-pixel box filter, for per-pixel comparisons (Pathlight's default in render_to_array;
# passing it to either engine sets it).
BOX_FILTER = dict(pixel_filter_type='BOX', filter_width=1.0)


class Warnings(list):
    """A warn() callback that records its messages."""

    def __call__(self, msg):
        self.append(msg)


def node_material(name, node_type, socket="Surface", **inputs):
    """A material whose output's `socket` (Surface or Volume) is fed by one node of node_type
    with constant inputs."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    node = nodes.new(node_type)
    for key, value in inputs.items():
        node.inputs[key.replace("_", " ")].default_value = value
    mat.node_tree.links.new(node.outputs[0], nodes["Material Output"].inputs[socket])
    return mat

