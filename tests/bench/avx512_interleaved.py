"""The AVX2 and AVX-512 8-wide kernels timed alternately in one process (set_bvh_kernel between
batches, thread CPU time, min and median of --reps per kernel), on a forest-like instanced scene
(64 instances of a 20,480-triangle icosphere on a ground plane, as realistic_scenes'
instanced_forest) and on bench_rays' 1M-triangle scene: camera, shadow (towards a sun) and
diffuse-like rays. Alternating batches in one process cancels the slow drifts of a shared
machine's load that separate fresh processes see.

    .venv/bin/python tests/bench/avx512_interleaved.py [--reps 9] [--res 256]"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_rays as br  # noqa: E402

pc = br.pc


def icosphere(subdiv):
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdiv):
        cache, nf = {}, []

        def mid(a, b):
            k = (min(a, b), max(a, b))
            if k not in cache:
                m = v[a] + v[b]
                v.append(m / np.linalg.norm(m))
                cache[k] = len(v) - 1
            return cache[k]
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = nf
    return (0.35 * np.array(v)).astype(np.float32), np.array(f, np.int32)


def forest():
    s = pc.Scene()
    mesh = s.add_mesh(*icosphere(5))  # 20,480 triangles
    rng = np.random.default_rng(1)
    for i in range(64):
        m = np.eye(4, dtype=np.float32)
        m[:3, :3] *= rng.uniform(0.6, 1.3)
        m[:3, 3] = (-3.0 + 6.0 * (i % 8) / 7, -3.0 + 6.0 * (i // 8) / 7, 0.0)
        s.add_instance(mesh, m)
    g = 6.0
    pos = np.array([[-g, -g, -0.3], [g, -g, -0.3], [g, g, -0.3], [-g, g, -0.3]], np.float32)
    s.add_instance(s.add_mesh(pos, np.array([[0, 1, 2], [0, 2, 3]], np.int32)), np.eye(4, dtype=np.float32))
    s.commit()
    return s, dict(eye=(0.0, -7.5, 3.2), target=(0.0, 0.0, 0.0), fov=0.9)


def rays(s, res, cam, rng):
    o, d = br.camera_rays(res, **cam)
    t = s.intersect(o, d)[0]
    m = np.isfinite(t)
    p = (o[m] + d[m] * (t[m, None] * (1 - 1e-4))).astype(np.float32)
    n = len(p)
    sun = np.tile(np.array([[0.4, -0.3, 0.85]], np.float32), (n, 1))
    bd = rng.normal(size=(n, 3)).astype(np.float32)
    bd *= -np.sign(np.sum(bd * d[m], 1, keepdims=True))
    return {"primary": (o, d), "shadow": (p, sun), "diffuse": (p, bd)}


def run(name, s, rs, reps):
    for kind, (o, d) in rs.items():
        f = (lambda: s.occluded(o, d)) if kind == "shadow" else (lambda: s.intersect(o, d))
        ts = {"avx2": [], "avx512": []}
        outs = {}
        for r in range(reps):
            for k in (("avx2", "avx512") if r % 2 == 0 else ("avx512", "avx2")):  # neither always first
                pc.set_bvh_kernel(k)
                t = time.thread_time()
                outs[k] = f()
                ts[k].append(time.thread_time() - t)
        a, b = outs["avx2"], outs["avx512"]
        same = all(np.array_equal(x, y) for x, y in zip(a, b)) if isinstance(a, tuple) else np.array_equal(a, b)
        n = len(o)
        m2, m5 = 1e9 * np.min(ts["avx2"]) / n, 1e9 * np.min(ts["avx512"]) / n
        d2, d5 = 1e9 * np.median(ts["avx2"]) / n, 1e9 * np.median(ts["avx512"]) / n
        print(f"{name} {kind}: avx2 {m2:.0f} ns (median {d2:.0f}), avx512 {m5:.0f} ns (median {d5:.0f}); "
              f"avx2/avx512 min {m2 / m5:.3f}x, median {d2 / d5:.3f}x; same hits {same}", flush=True)
    pc.set_bvh_kernel("auto")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=9)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--tris", type=int, default=1_000_000)
    a = ap.parse_args()
    rng = np.random.default_rng(3)
    s, cam = forest()
    run("forest", s, rays(s, a.res, cam, rng), a.reps)
    s2, _ = br.pathlight_scene(br.make_scene(a.tris))
    run("1M", s2, rays(s2, a.res, dict(eye=(0.0, -5.5, 1.6), target=(0.0, 0.0, -0.3), fov=0.75), rng), a.reps)


if __name__ == "__main__":
    main()
