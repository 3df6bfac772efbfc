"""Caustic light paths on the lamp-lit glass and chrome scenes of lamp_glass_scenes.py (issue 25,
the automatic rule for lamps): per-sample variance and instructions, plain against light paths.
Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/lamp_glass_factors.py --scene sun_interior [--size 96] [--seeds 16]
        [--spp 16] [--paths 0.1 0.25 0.5]
    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=/tmp/cg.%p \\
        .venv/bin/python tests/bench/lamp_glass_factors.py --scene sun_interior --callgrind [--size 48]

The scene is exported once by the add-on, then rendered by the core at the bench's settings (box
filter, 12 bounces, adaptive sampling off, the automatic mode off) with seeds 1..N for each
number of light paths. Relative variance as realistic_factors.py: the mean over pixels of
var * spp / (ref^2 + 1e-2), ref a separate render with light paths (--ref);
"trimmed" leaves out the 1 % of pixels with the largest such variance in that run (caustic
error is firefly-dominated: this says whether a gain is more than a few pixels'). "mse" is the
same measure against ref rather than each run's own mean. With --callgrind, each setting renders
at 2 and 6 spp with the instrumentation on around the render alone, and the instructions per
sample are the difference over 4 (one thread; set-up, export and the probes cancel)."""
import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import bpy
import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon  # noqa: E402
from kernel_scenes import core  # noqa: E402
import lamp_glass_scenes as lg  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--scene", default="sun_interior", help="a builder of lamp_glass_scenes.py")
ap.add_argument("--size", type=int, default=96)
ap.add_argument("--seeds", type=int, default=16)
ap.add_argument("--spp", type=int, default=16)
ap.add_argument("--paths", type=float, nargs="*", default=[0.1, 0.25, 0.5])
ap.add_argument("--callgrind", action="store_true", help="instructions per sample (under valgrind)")
ap.add_argument("--save", default=None, help="write the renders to this .npz")
ap.add_argument("--ref", type=float, nargs=2, default=[0.5, 64], metavar=("PATHS", "SPP"),
                help="the reference: light paths PATHS per sample, SPP spp x the seeds 1001.. (default 0.5 64)")
a = ap.parse_args()

pc = core()
sys.modules.setdefault("addon.pathlight_core", pc)
load_addon()
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402

w, h = a.size, a.size * 3 // 4
scene = getattr(lg, a.scene)(w, h)
scene.render.engine = "PATHLIGHT"
data = export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None)
core_scene = to_core(pc, data)
core_scene.commit()


def settings(spp, seed, paths, threads=0, auto=False):
    st = pc.RenderSettings()
    st.width, st.height = w, h
    st.max_bounces = 12
    st.diffuse_bounces = st.glossy_bounces = st.transmission_bounces = 1024
    st.samples, st.threads, st.seed = spp, threads, seed
    st.adaptive_threshold = 0.0
    st.filter_type, st.filter_width = "box", 1.0
    st.caustic_light_paths = paths
    st.caustic_light_paths_auto = auto
    return st


def run(st, instrument=False):
    sess = pc.Session(core_scene, st)
    if instrument:
        subprocess.run(["callgrind_control", "-z", str(os.getpid())], capture_output=True)
        subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], capture_output=True)
    sess.start()
    while not sess.wait(1.0):
        pass
    if instrument:
        subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], capture_output=True)
        subprocess.run(["callgrind_control", "-d", str(os.getpid())], capture_output=True)  # one file per render
    return sess


auto_sess = run(settings(1, 1, 0.0, auto=True))
print(f"{a.scene} {w}x{h}: automatic: {auto_sess.stats()['caustics']}")

if a.callgrind:
    # The dumps (one per render, in order) hold the counts: read them after the run with
    # callgrind_annotate or the 'totals:' line of each /tmp/cg.PID.N file.
    for p in [0.0] + a.paths:
        for spp in (2, 6):
            run(settings(spp, 1, p, threads=1), instrument=True)
            print(f"dumped: paths {p} spp {spp}", flush=True)
    sys.exit()

runs = {}
for p in [0.0] + a.paths:
    imgs, cpu = [], 0.0
    for seed in range(1, a.seeds + 1):
        t = time.process_time()
        sess = run(settings(a.spp, seed, p))
        cpu += time.process_time() - t
        imgs.append(np.asarray(sess.film())[..., :3].astype(np.float64))
    runs[p] = (np.array(imgs), cpu / (a.seeds * a.spp), sess.stats()["caustics"])
    print(f"rendered paths {p}: {runs[p][2]}", flush=True)
if a.save:
    np.savez_compressed(a.save, **{f"p{p}": r[0] for p, r in runs.items()})

# The reference: separate seeds (so its noise is independent of every run's), with light paths
# (the plain path tracer's mean is a few rare fireflies of the sun through the glass: its
# typical render lacks them, and one seed's firefly moves the mean by several %).
refs = [np.asarray(run(settings(int(a.ref[1]), 1001 + s, a.ref[0])).film())[..., :3].astype(np.float64)
        for s in range(a.seeds)]
ref = np.mean(refs, axis=0)
norm = ref ** 2 + 1e-2


def measures(imgs):
    pix = (imgs.var(0, ddof=1) * a.spp / norm).mean(-1).ravel()
    mse = (((imgs - ref) ** 2).mean(0) * a.spp / norm).mean(-1).ravel()
    keep = pix <= np.quantile(pix, 0.99)
    keep_m = mse <= np.quantile(mse, 0.99)
    return pix.mean(), pix[keep].mean(), mse.mean(), mse[keep_m].mean()


print(f"{a.seeds} seeds x {a.spp} spp; reference {a.seeds} x {int(a.ref[1])} spp at {a.ref[0]} paths, "
      f"mean {ref.mean():.5f}")
v0 = measures(runs[0.0][0])
cpu0 = runs[0.0][1]
print(f"{'paths':>6s} {'mean/ref':>9s} {'median':>7s} {'rel.var':>9s} {'trimmed':>9s} {'mse':>9s} {'mse trim':>9s} "
      f"{'CPU ms':>7s}  lower than plain by")
for p, (imgs, cpu, note) in runs.items():
    v = measures(imgs)
    med = np.median(imgs.mean((1, 2, 3))) / ref.mean()  # a typical seed's mean
    print(f"{p:6.2f} {imgs.mean() / ref.mean():9.4f} {med:7.4f} {v[0]:9.4g} {v[1]:9.4g} {v[2]:9.4g} {v[3]:9.4g} "
          f"{cpu * 1e3:7.2f}  var {v0[0] / v[0]:.2f}x, mse {v0[2] / v[2]:.2f}x, trimmed mse {v0[3] / v[3]:.2f}x "
          f"(CPU {cpu / cpu0:.2f}x)")
