"""Instruction counts of the volume bench scenes (tests/bench/volume_scenes.py: the smoke grid
from a .vdb under an area light, the fog-filled Cornell box), for callgrind:

    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=cg.out \\
        .venv/bin/python tests/bench/callgrind_volumes.py [--scene smoke|fog] [--size 32] [--spp 4]
        [--old-nee] [--no-phase-mis] [--majorant-scale 1]

The scene is exported by the add-on as a render would; only the render is instrumented (one
thread, a fixed seed, max bounces 12 of every kind), as in callgrind_cornell.py. Without
valgrind it prints the stats and the wall time. --old-nee: the heterogeneous media's light
sample only where delta tracking scatters (RenderSettings.volume_segment_nee off).
--no-phase-mis: a homogeneous segment's phase sample weighed against its own point's light
sample only (RenderSettings.volume_phase_mis off). --cycles:
Cycles renders the same scene instead (CPU, one thread, the same samples, bounces and filter;
instructions are not time, but they do not move with the machine's load either).
PL_CORE_DIR=<dir> renders with the module in <dir>."""
import argparse
import sys
import time
from pathlib import Path

import bpy

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon  # noqa: E402
from kernel_scenes import core, instrumented_render  # noqa: E402
import volume_scenes  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--scene", choices=("smoke", "fog"), default="smoke")
ap.add_argument("--size", type=int, default=32)
ap.add_argument("--spp", type=int, default=4)
ap.add_argument("--threads", type=int, default=1)
ap.add_argument("--old-nee", action="store_true")
ap.add_argument("--majorant-scale", type=float, default=1.0)
ap.add_argument("--cycles", action="store_true")
ap.add_argument("--no-phase-mis", action="store_true")
a = ap.parse_args()
pc = core()
sys.modules.setdefault("addon.pathlight_core", pc)  # PL_CORE_DIR's module for the add-on too
addon = load_addon()
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402

build = {"smoke": volume_scenes.smoke_grid, "fog": volume_scenes.fog_box}[a.scene]
scene = build(a.size, a.size)
if a.cycles:
    import os
    import subprocess
    from blender_util import _setup_cycles  # noqa: E402
    scene.render.engine = "CYCLES"
    _setup_cycles(scene.cycles, 12)
    scene.cycles.samples, scene.cycles.seed = a.spp, 1
    scene.cycles.pixel_filter_type, scene.cycles.filter_width = "BOX", 1.0
    scene.render.threads_mode, scene.render.threads = "FIXED", a.threads
    scene.render.use_persistent_data = True
    bpy.ops.render.render()  # (scene sync and kernel set-up once, outside the count)
    scene.cycles.seed = 2
    t = time.perf_counter()
    subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], capture_output=True)
    bpy.ops.render.render()
    subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], capture_output=True)
    print(f"Cycles render {time.perf_counter() - t:.3f} s")
    sys.exit(0)
scene.render.engine = "PATHLIGHT"
data = export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None)
core_scene = to_core(pc, data)
if a.majorant_scale != 1.0:
    core_scene.set_majorant_scale(a.majorant_scale)
core_scene.commit()
st = pc.RenderSettings()
st.width = st.height = a.size
st.max_bounces = 12
st.diffuse_bounces = st.glossy_bounces = st.transmission_bounces = st.volume_bounces = 1024
st.samples, st.threads, st.seed = a.spp, a.threads, 1
st.adaptive_threshold = 0.0
st.filter_type, st.filter_width = "box", 1.0
if a.no_phase_mis:
    st.volume_phase_mis = False
if a.old_nee and hasattr(st, "volume_segment_nee"):
    st.volume_segment_nee = False
t = time.perf_counter()
print(instrumented_render(pc, core_scene, st))
print(f"render {time.perf_counter() - t:.3f} s")
