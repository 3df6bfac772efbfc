"""Instruction counts of the instanced forest of the realistic bench (64 instances of a 20 480-
triangle icosphere under a sun and a sky colour), or with --scene another realistic scene
(hdri_model: the textured model under an HDRI), for callgrind:

    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=cg.out \\
        .venv/bin/python tests/bench/callgrind_forest.py [--scene instanced_forest] [--size 48] [--spp 4]
        [--dof FSTOP FOCUS] [--set NAME=VALUE ...]

The scene is realistic_scenes.instanced_forest (or --scene's builder), exported by the add-on as
a render would; only the render is instrumented (one thread, a fixed seed), as in
callgrind_cornell.py. Without valgrind it prints the stats and the wall time. PL_CORE_DIR=<dir>
renders with the module in <dir>."""
import argparse
import ast
import sys
import time
from pathlib import Path

import bpy

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon  # noqa: E402
from kernel_scenes import core, instrumented_render  # noqa: E402
import realistic_scenes  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--scene", default="instanced_forest", help="a builder of realistic_scenes.py")
ap.add_argument("--size", type=int, default=48, help="image width (height 3/4 of it)")
ap.add_argument("--spp", type=int, default=4)
ap.add_argument("--threads", type=int, default=1)
ap.add_argument("--dof", type=float, nargs=2, default=None, metavar=("FSTOP", "FOCUS"),
                help="depth of field on the scene's camera: F-stop and focus distance")
ap.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE",
                help="RenderSettings for the render, a Python literal each (e.g. caustic_light_paths=1.0)")
a = ap.parse_args()
pc = core()
sys.modules.setdefault("addon.pathlight_core", pc)  # PL_CORE_DIR's module for the add-on too
addon = load_addon()
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402
from addon.session import render_settings  # noqa: E402

scene = getattr(realistic_scenes, a.scene)(a.size, a.size * 3 // 4)
if a.dof:
    dof = scene.camera.data.dof
    dof.use_dof, dof.aperture_fstop, dof.focus_distance = True, a.dof[0], a.dof[1]
scene.render.engine = "PATHLIGHT"
data = export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None)
core_scene = to_core(pc, data)
core_scene.commit()
st = render_settings(pc, scene)
st2 = pc.RenderSettings()
for k in ("width", "height", "max_bounces"):
    setattr(st2, k, getattr(st, k))
st2.max_bounces = 12
st2.diffuse_bounces = st2.glossy_bounces = st2.transmission_bounces = 1024
st2.samples, st2.threads, st2.seed = a.spp, a.threads, 1
st2.adaptive_threshold = 0.0
st2.filter_type, st2.filter_width = "box", 1.0
for name, value in (kv.split("=", 1) for kv in a.set):
    setattr(st2, name, ast.literal_eval(value))
print(core_scene.stats())
t = time.perf_counter()
print(instrumented_render(pc, core_scene, st2))
print(f"render {time.perf_counter() - t:.3f} s")
