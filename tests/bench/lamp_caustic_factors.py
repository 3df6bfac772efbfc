"""The two factors of caustic light paths from lamps (issue 25) on the lamp scene of
tests/core/test_caustic_light_paths.py (a point lamp, a spot and a sun, all without extent, over
a floor with glossy casters out of view; --extent: with Blender's radius 0.1 and a sun of 3 degrees;
--glass sun|point|env: tests/core/test_caustic_glass.py's smooth glass sphere and mirror panel under a
sun of 4 degrees, a point of radius 0.1 or the environment's sun): the relative variance of one sample
and the CPU time of one sample, against the plain path tracer. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/lamp_caustic_factors.py [--size 96] [--seeds 16] [--spp 16]
        [--paths 0.1 0.25 0.5] [--extent] [--glass sun]

Relative variance as realistic_factors.py: the mean over pixels of var * spp / (ref^2 + 1e-2),
ref the plain renders' mean. CPU time is this process's (one render at a time, all threads), so
the gain = variance ratio x time ratio holds under load only as far as the load is even; count
instructions with callgrind (--callgrind, one thread) for a load-free cost."""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from core_scenes import render  # noqa: E402
import test_caustic_glass as tg  # noqa: E402
import test_caustic_light_paths as tc  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--size", type=int, default=96)
ap.add_argument("--seeds", type=int, default=16)
ap.add_argument("--spp", type=int, default=16)
ap.add_argument("--paths", type=float, nargs="*", default=[0.1, 0.25, 0.5])
ap.add_argument("--callgrind", type=float, default=None, help="render once at these paths (one thread)")
ap.add_argument("--extent", action="store_true", help="the lamps with extent (lamp_scene(extent=True))")
ap.add_argument("--glass", choices=["sun", "point", "env"], help="test_caustic_glass.glass_scene(GLASS) instead")
a = ap.parse_args()
w, h = a.size, a.size * 3 // 4
scene = tg.glass_scene(a.glass) if a.glass else tc.lamp_scene(extent=a.extent)
if a.callgrind is not None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from kernel_scenes import instrumented_render  # noqa: E402
    st = tc.pc.RenderSettings()
    st.width, st.height, st.samples, st.threads, st.seed = w, h, a.spp, 1, 1
    st.caustic_light_paths = a.callgrind
    print(instrumented_render(tc.pc, scene, st))
    sys.exit()


def run(paths):
    imgs, cpu = [], 0.0
    for seed in range(1, a.seeds + 1):
        t = time.process_time()
        img, st = render(tc.pc, scene, w, h, samples=a.spp, seed=seed, caustic_light_paths=paths)
        cpu += time.process_time() - t
        imgs.append(np.asarray(img)[..., :3].astype(np.float64))
    return np.array(imgs), cpu / (a.seeds * a.spp), st


plain, cpu0, _ = run(0.0)
ref = plain.mean(0)
norm = ref ** 2 + 1e-2


def rel_var(x):
    return float((x.var(0, ddof=1) * a.spp / norm).mean())


v0 = rel_var(plain)
print(f"{w}x{h}, {a.seeds} seeds x {a.spp} spp; mean {plain.mean():.5f}")
print(f"plain: rel. variance {v0:.4g}, CPU {cpu0 * 1e3:.2f} ms per sample")
for p in a.paths:
    lt, cpu, st = run(p)
    v = rel_var(lt)
    print(f"paths {p}: {st['caustics']}, mean {lt.mean():.5f}, rel. variance {v:.4g} ({v0 / v:.2f}x lower), "
          f"CPU {cpu * 1e3:.2f} ms per sample ({cpu / cpu0:.3f}x), equal-time gain {v0 * cpu0 / (v * cpu):.2f}x")
