"""Instruction counts per sample of the Cornell box fixture's replica, for callgrind:

    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=cg.out \
        .venv/bin/python tests/bench/callgrind_cornell.py [--general] [--glass] [--size 64] [--spp 16]

Only the render itself is instrumented (callgrind_control switches instrumentation on and off
around it), so the counts are of the render: one thread, a fixed seed. PL_CORE_DIR=<dir> imports
pathlight_core from <dir> (a build with -g, for callgrind_annotate)."""
import argparse
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from kernel_scenes import cornell_fixture, core, settings  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--general", action="store_true")
ap.add_argument("--glass", action="store_true", help="the glass-sphere variant")
ap.add_argument("--size", type=int, default=64)
ap.add_argument("--spp", type=int, default=16)
a = ap.parse_args()
pc = core()
scene = cornell_fixture(pc, glass=a.glass)
scene.commit()
st = settings(pc, a.size, a.size, a.spp, threads=1)
if a.general and hasattr(st, "force_general_kernel"):
    st.force_general_kernel = True
sess = pc.Session(scene, st)
subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], capture_output=True)
sess.start()
while not sess.wait(1.0):
    pass
subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], capture_output=True)
print(sess.stats())
