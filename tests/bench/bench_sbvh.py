"""Spatial splits (SBVH; Scene.spatial_splits) against the plain binned SAH BVH, in one process on
the same rays: BVH build time, SAH cost, references per triangle, and the time per ray of each
against Embree (embreex, one thread each, best of 3) for primary and diffuse bounce rays, on a
scene where spatial splits matter (tests/core_scenes.sliver_room: a rotated room of huge
triangles with long thin beams and small spheres, a procedural stand-in for Sponza; camera
inside) and on the ~1M-triangle scene of bench_rays.py (bumpy spheres on a ground grid: small
triangles, where they should change little). Writes docs/bench/sbvh.md."""
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path[:0] = [str(HERE.parent / d) for d in ("core", "blender")]
from bench_rays import best_time, camera_rays, embree_scene, make_scene, secondary_rays  # noqa: E402
from benchutil import parse_args, section_dir, write_section  # noqa: E402
from core_scenes import core, sliver_room  # noqa: E402

pc = core()


def build(meshes, spatial):
    s = pc.Scene()
    for pos, tris in meshes:
        s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    s.spatial_splits = spatial
    t = time.perf_counter()
    s.commit()
    wall = time.perf_counter() - t
    assert s.stats()["dropped_triangles"] == 0  # prim ids index the triangle list below
    return s, wall


def measure(name, meshes, eye, target, res, rng):
    tv = np.concatenate([pos[tris] for pos, tris in meshes]).astype(np.float32)
    es, embree_build = embree_scene(tv)
    o, d = camera_rays(res, eye, target)
    scenes, rows = {}, []
    for spatial in (False, True):
        builds = [build(meshes, spatial) for _ in range(2)]  # best of two builds
        scenes[spatial] = min(builds, key=lambda b: b[0].stats()["bvh_build_ms"])[0]
        st = scenes[spatial].stats()
        rows.append(dict(spatial=spatial, tris=st["triangles"], refs=st["bvh_references"],
                         splits=st["bvh_spatial_splits"], build_ms=st["bvh_build_ms"], sah=st["bvh_sah_cost"]))
        del builds
    hit = scenes[False].intersect(o, d)
    so, _, bd = secondary_rays(tv, o, d, hit, rng)
    for kind, (ro, rd) in {"primary": (o, d), "diffuse": (so, bd)}.items():
        # Alternated, best of 3 each: a change in the machine's load hits all three alike.
        best = {"embree": np.inf, False: np.inf, True: np.inf}
        for _ in range(3):
            best["embree"] = min(best["embree"], best_time(lambda: es.run(ro, rd, output=True), 1)[0])
            for spatial in (False, True):
                best[spatial] = min(best[spatial], best_time(lambda: scenes[spatial].intersect(ro, rd), 1)[0])
        for r in rows:
            r[kind] = (best[r["spatial"]] / len(ro), best["embree"] / len(ro))
            nodes, tested = scenes[r["spatial"]].traversal_counts(ro, rd)  # independent of the machine's load
            r[kind + " counts"] = (float(nodes.mean()), float(tested.mean()))
    for r in rows:
        print(name, r, flush=True)
    return rows, embree_build


def main():
    args = parse_args("smaller scenes and fewer rays (smoke run)")
    quick = args.quick
    rng = np.random.default_rng(5)
    out = section_dir(args)
    res = 192 if quick else 512
    scenes = {
        "Sliver room": ([sliver_room(spheres=150 if quick else 600)], (0.0, -1.5, 0.3), (0.3, 1.0, -0.2)),
        "1M-triangle spheres on a grid": (make_scene(100_000 if quick else 1_000_000), (0.0, -5.5, 1.6),
                                          (0.0, 0.0, -0.3)),
    }
    results = {name: measure(name, m, eye, target, res, rng) for name, (m, eye, target) in scenes.items()}
    lines = [
        "## Spatial splits (SBVH)",
        "",
        f"`tests/bench/bench_sbvh.py`: the BVH with spatial splits (`Scene.spatial_splits`) against the plain one, "
        f"same rays ({res}x{res} camera rays, diffuse bounces from their hits), one thread each, best of 3 "
        "alternated runs (builds: best of 2, all threads). Ray times are shown as Embree's time over Pathlight's (above 1: Pathlight "
        "faster), both measured in this run; SAH cost: expected triangle tests of a random ray (node visits "
        "weighted). Spatial splits are off by default (Render ▸ Performance ▸ Spatial Splits).",
        "",
        "| Scene | Triangles | Spatial splits | References / triangle | BVH build (ms) | Build ratio | SAH cost "
        "| Primary: Embree / Pathlight | Diffuse: Embree / Pathlight | Speed-up, primary / diffuse |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, (rows, _) in results.items():
        base = rows[0]
        for r in rows:
            lines.append(
                f"| {name} | {r['tris']:,} | {'on' if r['spatial'] else 'off'} ({r['splits']:,} nodes) "
                f"| {r['refs'] / r['tris']:.3f} | {r['build_ms']:.0f} | {r['build_ms'] / base['build_ms']:.2f}x "
                f"| {r['sah']:.1f} | {r['primary'][1] / r['primary'][0]:.2f}x | {r['diffuse'][1] / r['diffuse'][0]:.2f}x "
                f"| {base['primary'][0] / r['primary'][0]:.2f}x / {base['diffuse'][0] / r['diffuse'][0]:.2f}x |")
    lines += [
        "",
        "Work per ray (independent of the machine's load): BVH nodes visited and triangles tested per ray "
        "(`Scene.traversal_counts`: wide nodes visited, triangles in the leaves tested).",
        "",
        "| Scene | Spatial splits | Primary: nodes / triangles per ray | Diffuse: nodes / triangles per ray |",
        "|---|---|---|---|",
    ]
    for name, (rows, _) in results.items():
        for r in rows:
            p, q = r["primary counts"], r["diffuse counts"]
            lines.append(f"| {name} | {'on' if r['spatial'] else 'off'} | {p[0]:.1f} / {p[1]:.1f} | {q[0]:.1f} / {q[1]:.1f} |")
    lines += ["", "Embree's build (on the first query, through embreex): " + ", ".join(
        f"{name} {eb * 1e3:.0f} ms" for name, (_, eb) in results.items()) + "."]
    write_section(out, "sbvh", lines + [""])


if __name__ == "__main__":
    main()
