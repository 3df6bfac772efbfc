"""Instruction counts per sample of bench_rays' generated scene (a bumpy sphere on a ground plane
among 36 smaller spheres: 38 objects, about 1M triangles by default), in the final render's
layout (one merged world-space BVH) or the viewport's dynamic one (--dynamic: every object its
own BVH under the top level), for callgrind:

    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=cg.out \\
        .venv/bin/python tests/bench/callgrind_objects.py [--dynamic] [--tris 1000000] [--size 64] [--spp 4]

Each mesh is stored about its own centre under a translation (as Blender objects are), so the
dynamic layout traces through real transforms. Only the render is instrumented (one thread, a
fixed seed), as in callgrind_cornell.py; PL_CORE_DIR=<dir> imports pathlight_core from <dir>."""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from kernel_scenes import core, instrumented_render, settings  # noqa: E402

sys.modules.setdefault("addon.pathlight_core", core())  # PL_CORE_DIR's module for bench_rays too
from bench_rays import make_scene, pc  # noqa: E402
from core_scenes import camera  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--dynamic", action="store_true", help="Scene(dynamic=True), the viewport's layout")
ap.add_argument("--tris", type=int, default=1_000_000)
ap.add_argument("--size", type=int, default=64)
ap.add_argument("--spp", type=int, default=4)
a = ap.parse_args()
s = pc.Scene(dynamic=a.dynamic)
grey = s.add_material("Grey", (0.6, 0.6, 0.6))
for pos, tris in make_scene(a.tris):
    c = (pos.min(0) + pos.max(0)) * 0.5
    m = np.eye(4, dtype=np.float32)
    m[:3, 3] = c
    s.add_instance(s.add_mesh((pos - c).astype(np.float32), tris, None, None, [grey]), m)
s.add_sun_light((0.3, -0.4, -1.0), (3.0, 3.0, 3.0), 2.0, True)
s.set_world_color((0.2, 0.2, 0.25))
s.set_camera(camera(pc, (0.0, -5.5, 1.6), (0.0, 0.0, -0.3), lens=35.0))
s.commit()
print(s.stats())
print(instrumented_render(pc, s, settings(pc, a.size, a.size, a.spp, threads=1)))
