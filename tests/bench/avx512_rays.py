"""AVX-512 against AVX2 8-wide BVH kernel (the same module, PL_BVH_KERNEL picks): ray rates of
bench_rays' scene and rays (primary, shadow, diffuse bounce) and Embree's on the same rays, by
the calling thread's CPU time (best of --repeats), in fresh processes alternating the kernels.

    .venv/bin/python tests/bench/avx512_rays.py [--rounds 3] [--tris 1000000] [--res 512]

Prints one line per process and the medians per kernel. The hits must be the same bits."""
import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def one(a):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_rays as br
    pc = br.pc
    meshes = br.make_scene(a.tris)
    s, _ = br.pathlight_scene(meshes)
    es = None
    if a.embree:
        es, _ = br.embree_scene(br.world_triangles(meshes))
    o, d = br.camera_rays(a.res)
    hit = s.intersect(o, d)
    so, sd, bd = br.secondary_rays(br.world_triangles(meshes), o, d, hit, np.random.default_rng(3))

    def best(f):
        b, out = np.inf, None
        for _ in range(a.repeats):
            t = time.thread_time()
            out = f()
            b = min(b, time.thread_time() - t)
        return b, out

    out = {"kernel": pc.build_info()["bvh_kernel"]}
    digest = []
    for kind, (oo, dd) in {"primary": (o, d), "shadow": (so, sd), "diffuse": (so, bd)}.items():
        if kind == "shadow":
            t, r = best(lambda: s.occluded(oo, dd, 1.0))
            digest.append(r.tobytes())
            te = best(lambda: es.run(oo, dd, dists=np.ones(len(oo), np.float32), query="OCCLUDED"))[0] if es else 0
        else:
            t, r = best(lambda: s.intersect(oo, dd))
            digest += [x.tobytes() for x in r]
            te = best(lambda: es.run(oo, dd, output=True))[0] if es else 0
        out[kind] = 1e9 * t / len(oo)          # ns per ray, Pathlight
        out["embree_" + kind] = 1e9 * te / len(oo)
    import hashlib
    out["hits_md5"] = hashlib.md5(b"".join(digest)).hexdigest()
    print(json.dumps(out), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--tris", type=int, default=1_000_000)
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-embree", dest="embree", action="store_false")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        return one(a)
    res = {"avx2": [], "avx512": []}
    for r in range(a.rounds):
        for k in ("avx2", "avx512"):
            env = dict(os.environ, PL_BVH_KERNEL=k)
            cmd = [sys.executable, __file__, "--one", "--tris", str(a.tris), "--res", str(a.res),
                   "--repeats", str(a.repeats)] + ([] if a.embree else ["--no-embree"])
            line = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout.strip().splitlines()[-1]
            print(f"round {r} {k}: {line}  load {os.getloadavg()[0]:.1f}", flush=True)
            res[k].append(json.loads(line))
    assert len({x["hits_md5"] for v in res.values() for x in v}) == 1, "kernels disagree"
    for kind in ("primary", "shadow", "diffuse"):
        m2 = np.median([x[kind] for x in res["avx2"]])
        m5 = np.median([x[kind] for x in res["avx512"]])
        me = np.median([x["embree_" + kind] for v in res.values() for x in v])
        print(f"{kind}: avx2 {m2:.0f} ns ({1e3 / m2:.2f} Mrays/s), avx512 {m5:.0f} ns ({1e3 / m5:.2f} Mrays/s), "
              f"avx2/avx512 {m2 / m5:.3f}x; embree {me:.0f} ns: embree/avx2 {me / m2:.2f}x, embree/avx512 {me / m5:.2f}x")


if __name__ == "__main__":
    main()
