"""Instruction counts per sample of the Cornell box fixture's replica, for callgrind:

    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=cg.out \
        .venv/bin/python tests/bench/callgrind_cornell.py [--general] [--glass] [--principled] [--dynamic] [--no-rect] [--compact auto|on|off] [--size 64] [--spp 16] [--sampler sobol] [--pattern blue_noise]

Only the render itself is instrumented (callgrind_control switches instrumentation on and off
around it), so the counts are of the render: one thread, a fixed seed. PL_CORE_DIR=<dir> imports
pathlight_core from <dir> (a build with -g, for callgrind_annotate)."""
import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402

import kernel_scenes  # noqa: E402
from kernel_scenes import cornell_fixture, core, instrumented_render, settings  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--general", action="store_true")
ap.add_argument("--glass", action="store_true", help="the glass-sphere variant")
ap.add_argument("--principled", action="store_true",
                help="the white surfaces of Blender's default material (Principled, Multiscatter GGX)")
ap.add_argument("--dynamic", action="store_true", help="Scene(dynamic=True), the viewport's layout")
ap.add_argument("--transformed", action="store_true",
                help="each object's mesh in object space (centred, turned) under a matrix, as Blender objects are")
ap.add_argument("--no-rect", action="store_true",
                help="the quad light as two spherical triangles (Scene.rect_groups off), as before rectangle groups")
ap.add_argument("--compact", choices=("auto", "on", "off"), default="auto",
                help="Scene.compact_bvh: compressed (quantised) wide BVH nodes")
ap.add_argument("--size", type=int, default=64)
ap.add_argument("--spp", type=int, default=16)
ap.add_argument("--sampler", default="sobol", help="RenderSettings.sampler (sobol4d_deep, ...)")
ap.add_argument("--pattern", default="independent", help="RenderSettings.pixel_pattern (blue_noise, ...)")
a = ap.parse_args()
pc = core()
if a.transformed:
    # Objects as blender_scenes/cornell_box.blend has them: walls with identity matrices, the
    # lamp and the sphere moved, the box moved, turned 28 degrees and scaled; each mesh in its
    # own object space (the same world-space triangles up to rounding).
    calls = []

    def add_object_transformed(s, pos, tris, material, normals=None, matrix=None):
        k = len(calls)
        calls.append(k)
        m = np.eye(4)
        if k == 6:  # the box
            ang = np.radians(28.0)
            rot = np.array([[np.cos(ang), -np.sin(ang), 0.0], [np.sin(ang), np.cos(ang), 0.0], [0.0, 0.0, 1.0]])
            m[:3, :3] = rot @ np.diag([0.55, 0.55, 1.2])
            m[:3, 3] = (-0.35, 0.3, 0.6)
        elif k >= 5:  # the lamp, the sphere
            m[:3, 3] = (pos.min(0) + pos.max(0)) * 0.5
        m = m.astype(np.float32)
        inv = np.linalg.inv(m.astype(np.float64))
        local = (pos.astype(np.float64) @ inv[:3, :3].T + inv[:3, 3]).astype(np.float32)
        nl = None if normals is None else (normals.astype(np.float64) @ m[:3, :3].astype(np.float64)).astype(np.float32)
        mesh = s.add_mesh(local, tris, nl, None, [material])
        s.add_instance(mesh, m)
        return mesh
    kernel_scenes.add_object = add_object_transformed
scene = cornell_fixture(pc, glass=a.glass, principled=a.principled)
if a.dynamic:
    scene.dynamic = True
if a.no_rect:
    scene.rect_groups = False
if hasattr(scene, "compact_bvh"):
    scene.compact_bvh = a.compact
scene.commit()
st = settings(pc, a.size, a.size, a.spp, threads=1, sampler=a.sampler,
              **({"pixel_pattern": a.pattern} if a.pattern != "independent" else {}))
if a.general and hasattr(st, "force_general_kernel"):
    st.force_general_kernel = True
print(instrumented_render(pc, scene, st))
