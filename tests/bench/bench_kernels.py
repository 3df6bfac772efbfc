"""Scene-specialised integrator kernels against the general kernel, in one process on the same
scenes: samples per second of each (fixed-sample renders, runs alternated so that a change in
the machine's load hits both alike; the ratio is the median of the per-pair ratios), and, where
valgrind is installed, callgrind's instruction count per sample of each on the diffuse Cornell
box (one thread; independent of the load). Both kernels render the same image (checked here
too). Writes docs/bench/kernels.md.

The scenes are core-only replicas of blender_scenes/cornell_box.blend (tests/bench/kernel_scenes.py):
the diffuse Cornell box (the diffuse kernel) and the same box with a clear glass sphere (the
surfaces kernel)."""
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from benchutil import parse_args, section_dir, write_section  # noqa: E402
from kernel_scenes import cornell_fixture, core, settings  # noqa: E402

pc = core()
SCENES = {"Cornell box (diffuse)": False, "Cornell box, glass sphere": True}


def render(scene, general, size, spp):
    st = settings(pc, size, size, spp, force_general_kernel=general)
    sess = pc.Session(scene, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    s = sess.stats()
    return s["paths"] / s["elapsed_s"], s["kernel"], sess.film()


def callgrind_per_sample(general, size=64, spp=16):
    """Instructions per sample of a one-thread render of the diffuse Cornell box (render only)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cg.out"
        cmd = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}",
               sys.executable, str(HERE / "callgrind_cornell.py"), "--size", str(size), "--spp", str(spp)]
        proc = subprocess.run(cmd + (["--general"] if general else []), capture_output=True, text=True,
                              env=dict(os.environ))
        m = re.search(r"Collected : (\d+)", proc.stderr)
        if proc.returncode != 0 or not m:
            raise RuntimeError(f"callgrind failed:\n{proc.stderr[-2000:]}")
        return int(m.group(1)) / (size * size * spp)


def main():
    args = parse_args("fewer, smaller runs (smoke run)")
    size, spp, pairs = (64, 8, 2) if args.quick else (128, 32, 6)
    rows = []
    for name, glass in SCENES.items():
        scene = cornell_fixture(pc, glass=glass)
        scene.commit()
        render(scene, False, 32, 1)  # warm-up
        sps = {False: [], True: []}
        kernels, films = {}, {}
        for i in range(pairs):
            for general in ((False, True) if i % 2 == 0 else (True, False)):
                r, kernels[general], films[general] = render(scene, general, size, spp)
                sps[general].append(r)
        ratios = [a / b for a, b in zip(sps[False], sps[True])]
        rows.append(dict(name=name, kernel=kernels[False], spec=float(np.median(sps[False])),
                         gen=float(np.median(sps[True])), ratio=float(np.median(ratios)),
                         lo=min(ratios), hi=max(ratios), same=bool(np.array_equal(films[False], films[True]))))
        print(rows[-1], flush=True)
    ir = None
    if shutil.which("valgrind") and shutil.which("callgrind_control"):
        ir = {g: callgrind_per_sample(g, 32 if args.quick else 64, 4 if args.quick else 16) for g in (False, True)}
        print("instructions per sample", ir, flush=True)

    lines = ["## Scene-specialised kernels", "",
             f"Samples per second of the kernel the core picks for the scene and of the general kernel "
             f"(`force_general_kernel`), {size}x{size} pixels, {spp} samples, all threads, "
             f"{pairs} alternated runs of each; speed-up: the median of the per-pair ratios (their range in "
             "brackets). Scenes: core-only replicas of the Cornell box fixture (Blackman-Harris 1.5 px filter).", "",
             "| Scene | Kernel | Samples/s, specialised | Samples/s, general | Speed-up | Same image |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['name']} | {r['kernel']} | {r['spec'] / 1e6:.2f} M | {r['gen'] / 1e6:.2f} M "
                     f"| {r['ratio']:.2f}x ({r['lo']:.2f}-{r['hi']:.2f}) | {'yes' if r['same'] else 'NO'} |")
    lines.append("")
    if ir:
        lines += ["Instructions per sample (callgrind, one thread, the diffuse Cornell box, render only): "
                  f"specialised {ir[False]:,.0f}, general {ir[True]:,.0f} "
                  f"({ir[True] / ir[False]:.2f}x as many in the general kernel).", ""]
    else:
        lines += ["(valgrind is not installed: no instruction counts.)", ""]
    out = section_dir(args)
    write_section(out, "kernels", lines)


if __name__ == "__main__":
    main()
