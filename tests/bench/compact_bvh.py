"""Compressed (quantised) wide BVH nodes against float ones on bench_rays' ~1M-triangle scene and
rays: bytes per triangle (Scene.stats()), nodes and triangles visited per ray
(Scene.traversal_counts), whether the hits are the same, and the time of the batch calls, both
trees and Embree interleaved in one process (best of --repeats; wall clock, so noisy on a
shared machine: the ratios measured in the same run are the result). A one-off measurement,
not part of `build.py bench`:

    .venv/bin/python tests/bench/compact_bvh.py [--tris 1000000] [--res 512] [--repeats 5]

Under callgrind (--instr-atstart=no), `--callgrind primary|shadow|diffuse --compact on|off`
instruments only that batch call of that tree (instructions per ray = total / rays printed)."""
import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_rays  # noqa: E402
from bench_rays import camera_rays, embree_scene, make_scene, pc, secondary_rays, world_triangles  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--tris", type=int, default=1_000_000)
ap.add_argument("--res", type=int, default=512)
ap.add_argument("--repeats", type=int, default=5)
ap.add_argument("--callgrind", choices=("primary", "shadow", "diffuse"))
ap.add_argument("--compact", choices=("on", "off"), default="on")
ap.add_argument("--no-embree", action="store_true")
a = ap.parse_args()


def scene(meshes, compact):
    s = pc.Scene()
    s.compact_bvh = compact
    for pos, tris in meshes:
        s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    s.commit()
    return s


meshes = make_scene(a.tris)
tv = world_triangles(meshes)
rng = np.random.default_rng(5)
o, d = camera_rays(a.res)
if a.callgrind:
    s = scene(meshes, a.compact)
    hit = s.intersect(o, d)
    so, sd, bd = secondary_rays(tv, o, d, hit, rng)
    ro, rd = {"primary": (o, d), "shadow": (so, sd), "diffuse": (so, bd)}[a.callgrind]
    subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], capture_output=True)
    s.occluded(ro, rd, 1.0) if a.callgrind == "shadow" else s.intersect(ro, rd)
    subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], capture_output=True)
    print(f"{a.callgrind} compact={a.compact} rays={len(ro)} layout={s.stats()['bvh_layout']}")
    sys.exit(0)

trees = {c: scene(meshes, c) for c in ("off", "on")}
hit = trees["off"].intersect(o, d)
so, sd, bd = secondary_rays(tv, o, d, hit, rng)
rays = {"primary": (o, d), "shadow": (so, sd), "diffuse": (so, bd)}
es = None if a.no_embree else embree_scene(tv)[0]
for c, s in trees.items():
    st = s.stats()
    print(f"compact={c}: {st['bvh_layout']}, compact nodes {st['bvh_compact']}, wide nodes {st['bvh_wide_nodes']}, "
          f"BVH {st['bvh_bytes'] / st['triangles']:.1f} B/triangle ({st['triangles']} triangles)")
for kind, (ro, rd) in rays.items():
    if kind != "shadow":
        h = [trees[c].intersect(ro, rd) for c in ("off", "on")]
        same = all(np.array_equal(x, y) for x, y in zip(*h))
        cnt = [trees[c].traversal_counts(ro, rd) for c in ("off", "on")]
        print(f"{kind}: same hits {same}; nodes/ray {cnt[0][0].mean():.2f} -> {cnt[1][0].mean():.2f}, "
              f"triangles/ray {cnt[0][1].mean():.2f} -> {cnt[1][1].mean():.2f}")
    else:
        same = np.array_equal(trees["off"].occluded(ro, rd, 1.0), trees["on"].occluded(ro, rd, 1.0))
        print(f"{kind}: same occlusion {same}")
    best = {"off": np.inf, "on": np.inf, "embree": np.inf}
    for _ in range(a.repeats):
        for c in ("off", "on", "embree"):
            if c == "embree":
                if es is None:
                    continue
                t = time.perf_counter()
                if kind == "shadow":
                    es.run(ro, rd, dists=np.ones(len(ro), np.float32), query="OCCLUDED")
                else:
                    es.run(ro, rd, output=True)
            else:
                t = time.perf_counter()
                trees[c].occluded(ro, rd, 1.0) if kind == "shadow" else trees[c].intersect(ro, rd)
            best[c] = min(best[c], time.perf_counter() - t)
    n = len(ro)
    line = f"  {kind}: float {n / best['off'] / 1e6:.2f} Mrays/s, compact {n / best['on'] / 1e6:.2f} Mrays/s " \
           f"(time compact/float {best['on'] / best['off']:.3f})"
    if es is not None:
        line += f"; Embree/Pathlight time: float {best['off'] / best['embree']:.3f}x, compact {best['on'] / best['embree']:.3f}x"
    print(line)
