"""Ray throughput of Pathlight's BVH against Embree (through embreex), side by side in one process
on exactly the same rays: primary (camera), shadow (any hit, to points on a light) and diffuse
bounce (cosine-distributed from the primary hit points) rays on a generated scene of about a
million triangles; whether both find the same hits; BVH build time, SAH cost and memory; and
how the time per ray scales with the triangle count and the resolution. Writes
docs/bench/rays.md and log-log plots docs/bench/rays_*.png.

Both batch APIs trace on the calling thread (embreex loops over rtcIntersect1/rtcOccluded1 on
one thread, Scene.intersect/occluded do the same), so the comparison is one thread against one
thread. Each timing is the best of a few repetitions, which filters out the other processes of
a shared machine; ratios are measured in the same run."""
import sys
import time
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
from benchutil import parse_args, section_dir, write_section  # noqa: E402
from core_scenes import core, look_at_matrix  # noqa: E402

pc = core()
REPEATS = 3
BUILD_REPEATS = 3  # builds per engine in the build table (the fastest counts)


# ---------------------------------------------------------------- scene

def cube_sphere(n, center, radius, rng, bumps=0.08):
    """A sphere from the six n x n grids of a cube, displaced by smooth noise of the direction
    (a function of the position, so faces sharing an edge agree and no triangle degenerates)."""
    u = np.linspace(-1.0, 1.0, n + 1)
    a, b = np.meshgrid(u, u, indexing="ij")
    one = np.ones_like(a)
    faces = [(one, a, b), (-one, b, a), (a, one, b), (b, -one, a), (a, b, one), (b, a, -one)]
    k = rng.normal(size=(4, 3)) * 3.0
    ph = rng.uniform(0, 2 * np.pi, 4)
    pos, tris = [], []
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    q = (i * (n + 1) + j).ravel()
    quad = np.concatenate([np.stack([q, q + n + 1, q + 1], 1), np.stack([q + 1, q + n + 1, q + n + 2], 1)])
    for f, (x, y, z) in enumerate(faces):
        d = np.stack([x, y, z], -1).reshape(-1, 3)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        r = 1.0 + bumps * sum(np.sin(d @ k[m] + ph[m]) for m in range(4)) / 4.0
        pos.append(center + radius * d * r[:, None])
        tris.append(quad + f * (n + 1) ** 2)
    return np.concatenate(pos).astype(np.float32), np.concatenate(tris).astype(np.int32)


def ground(n, size):
    u = np.linspace(-size, size, n + 1)
    x, y = np.meshgrid(u, u, indexing="ij")
    pos = np.stack([x, y, np.full_like(x, -1.2)], -1).reshape(-1, 3).astype(np.float32)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    q = (i * (n + 1) + j).ravel()
    return pos, np.concatenate([np.stack([q, q + 1, q + n + 1], 1),
                                np.stack([q + 1, q + n + 2, q + n + 1], 1)]).astype(np.int32)


def make_scene(target_tris, seed=1):
    """A bumpy sphere (about 80 % of the triangles) on a ground plane with 36 smaller bumpy
    spheres of assorted sizes around it: long thin and small triangles, empty space, overlap."""
    rng = np.random.default_rng(seed)
    meshes = []
    n_main = max(4, int(round(np.sqrt(0.8 * target_tris / 12))))
    meshes.append(cube_sphere(n_main, np.zeros(3), 1.0, rng))
    meshes.append(ground(max(2, int(np.sqrt(0.04 * target_tris / 2))), 6.0))
    per_small = 0.16 * target_tris / 36
    for m in range(36):
        ang = 2 * np.pi * m / 36 + rng.uniform(-0.05, 0.05)
        dist = rng.uniform(1.6, 5.0)
        rad = rng.uniform(0.1, 0.45)
        c = np.array([dist * np.cos(ang), dist * np.sin(ang), -1.2 + rad])
        meshes.append(cube_sphere(max(2, int(round(np.sqrt(per_small / 12)))), c, rad, rng, bumps=0.2))
    return meshes


def world_triangles(meshes):
    return np.concatenate([pos[tris] for pos, tris in meshes]).astype(np.float32)  # (T, 3, 3)


def pathlight_scene(meshes, bvh="auto", quality="auto"):
    s = pc.Scene()
    s.build_quality = quality
    for pos, tris in meshes:
        s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    t = time.perf_counter()
    s.commit(bvh=bvh)
    wall = time.perf_counter() - t
    assert s.stats()["dropped_triangles"] == 0  # prim ids then index world_triangles()
    return s, wall


def embree_scene(tri_verts):
    from embreex.mesh_construction import TriangleMesh
    from embreex.rtcore_scene import EmbreeScene
    es = EmbreeScene()
    TriangleMesh(es, tri_verts)
    o = np.zeros((1, 3), np.float32)
    t = time.perf_counter()
    es.run(o, np.array([[0, 0, 1]], np.float32))  # embreex builds on the first query
    return es, time.perf_counter() - t


# ---------------------------------------------------------------- rays

def camera_rays(res, eye=(0.0, -5.5, 1.6), target=(0.0, 0.0, -0.3), fov=0.75):
    m = look_at_matrix(eye, target)
    h = np.tan(fov / 2)
    y, x = np.meshgrid((np.arange(res) + 0.5) / res, (np.arange(res) + 0.5) / res, indexing="ij")
    d = np.stack([(2 * x - 1) * h, (2 * y - 1) * h, -np.ones_like(x)], -1).reshape(-1, 3)
    d = d @ m[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(m[:3, 3], d.shape)
    return np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32)


def secondary_rays(tv, o, d, hit, rng):
    """From the primary hits: shadow rays to uniform points on a 2 x 2 light above the scene
    (tmax 1, unnormalised directions) and cosine-weighted diffuse bounces, both leaving from
    the offset hit point on the side the camera ray came from."""
    t, prim, b1, b2 = hit
    m = prim >= 0
    v = tv[prim[m]]
    b1, b2 = b1[m][:, None], b2[m][:, None]
    b0 = np.float32(1) - b1 - b2
    p = v[:, 0] * b0 + v[:, 1] * b1 + v[:, 2] * b2
    err = (np.abs(v[:, 0] * b0) + np.abs(v[:, 1] * b1) + np.abs(v[:, 2] * b2)) * pc.barycentric_error_bound()
    ng = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    ng *= -np.sign(np.sum(ng * d[m], 1, keepdims=True))
    org = pc.offset_ray_origin(p.astype(np.float32), ng.astype(np.float32), err.astype(np.float32))
    n = len(org)
    light = np.stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), np.full(n, 4.0)], 1)
    sd = (light - org).astype(np.float32)
    # Cosine-weighted directions around ng.
    u1, u2 = rng.uniform(size=n), rng.uniform(size=n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0, 1 - u1))], 1)
    a = np.where(np.abs(ng[:, :1]) > 0.9, [[0, 1, 0]], [[1, 0, 0]])
    tx = np.cross(a, ng)
    tx /= np.linalg.norm(tx, axis=1, keepdims=True)
    ty = np.cross(ng, tx)
    bd = (tx * local[:, :1] + ty * local[:, 1:2] + ng * local[:, 2:]).astype(np.float32)
    return np.ascontiguousarray(org, np.float32), sd, bd


def best_time(f, repeats=REPEATS):
    best, out = np.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t)
    return best, out


def trace_both(s, es, o, d, kind):
    """Times both engines on the same rays; returns (rays/s Pathlight, rays/s Embree, agreement)."""
    n = len(o)
    if kind == "shadow":
        tp, occ_p = best_time(lambda: s.occluded(o, d, 1.0))
        te, res = best_time(lambda: es.run(o, d, dists=np.ones(n, np.float32), query="OCCLUDED"))
        occ_e = res != -1
        agree = dict(hit=float(np.mean(occ_p == occ_e)), t=float("nan"), prim=float("nan"))
    else:
        tp, hp = best_time(lambda: s.intersect(o, d))
        te, he = best_time(lambda: es.run(o, d, output=True))
        hit_p, hit_e = hp[1] >= 0, he["primID"] >= 0
        both = hit_p & hit_e
        close = np.abs(hp[0][both] - he["tfar"][both]) <= 1e-4 * np.maximum(1.0, np.abs(he["tfar"][both]))
        agree = dict(hit=float(np.mean(hit_p == hit_e)), t=float(np.mean(close)) if both.any() else 1.0,
                     prim=float(np.mean(hp[1][both] == he["primID"][both])) if both.any() else 1.0)
    return n / tp, n / te, agree


# ---------------------------------------------------------------- main

def main():
    args = parse_args("smaller scenes and fewer rays (smoke run)")
    quick = args.quick
    rng = np.random.default_rng(5)
    out = section_dir(args)
    info = pc.build_info()

    # 1. Throughput on the ~1M-triangle scene.
    big = 100_000 if quick else 1_000_000
    meshes = make_scene(big)
    tv = world_triangles(meshes)
    s, commit_s = pathlight_scene(meshes)
    es, embree_build_s = embree_scene(tv)
    st = s.stats()
    res = 256 if quick else 1024
    o, d = camera_rays(res)
    hit = s.intersect(o, d)
    so, sd, bd = secondary_rays(tv, o, d, hit, rng)
    throughput = {}
    for kind, (ro, rd) in {"primary": (o, d), "shadow": (so, sd), "diffuse bounce": (so, bd)}.items():
        throughput[kind] = trace_both(s, es, ro, rd, "shadow" if kind == "shadow" else "closest")
        print(kind, throughput[kind], flush=True)
    # Per-ray cost of the APIs themselves: rays that miss the scene's bounds (one box test each).
    mo = np.ascontiguousarray(o + np.float32(100.0) * np.array([0, 0, 1], np.float32))
    md = np.ascontiguousarray(np.broadcast_to(np.array([0, 0, 1], np.float32), o.shape))
    tpm, _ = best_time(lambda: s.intersect(mo, md))
    tem, _ = best_time(lambda: es.run(mo, md, output=True))
    overhead = (tpm / len(mo), tem / len(mo))
    print("overhead", overhead, flush=True)
    layouts = {}
    for lay in ("binary", "bvh4", "bvh8"):  # the kernels against each other on primary rays
        sl, _ = pathlight_scene(meshes, lay)
        name = sl.stats()["bvh_layout"]
        if name in layouts:
            continue
        tp, _ = best_time(lambda: sl.intersect(o, d))
        tb, _ = best_time(lambda: sl.intersect(so, bd))
        layouts[name] = (len(o) / tp, len(so) / tb)
        del sl
    print("layouts", layouts, flush=True)

    # 2. Build time, SAH cost, memory at 100k and 1M triangles.
    builds = []
    for n in ((10_000, 100_000) if quick else (100_000, 1_000_000)):
        m = make_scene(n)
        tv = world_triangles(m)
        # The fastest of BUILD_REPEATS builds per engine, alternating: one build's time on a
        # shared machine swings by 1.5x and more.
        wall = bvh_ms = eb = fast_ms = np.inf
        for _ in range(BUILD_REPEATS):
            sb, w = pathlight_scene(m)
            sts = sb.stats()
            wall, bvh_ms = min(wall, w), min(bvh_ms, sts["bvh_build_ms"])
            del sb
            built, t = embree_scene(tv)
            eb = min(eb, t)
            del built
            sf, _ = pathlight_scene(m, quality="fast")  # the clustered build (the viewport's, for big meshes)
            stf = sf.stats()
            fast_ms = min(fast_ms, stf["bvh_build_ms"])
            del sf
        builds.append(dict(n=sts["triangles"], wall=wall, bvh_ms=bvh_ms, sah=sts["bvh_sah_cost"],
                           bytes=sts["bvh_bytes"] / sts["triangles"], embree=eb, wide=sts["bvh_wide_nodes"],
                           fast_ms=fast_ms, fast_sah=stf["bvh_sah_cost"]))
        print("build", builds[-1], flush=True)

    # 3. Scaling with triangle count (primary rays at 256^2) and with resolution (1M scene).
    counts = [10_000, 30_000, 100_000] if quick else [10_000, 30_000, 100_000, 300_000, 1_000_000, 3_000_000]
    so2, sd2 = camera_rays(256)
    scaling = []
    for n in counts:
        m = make_scene(n)
        sn, _ = pathlight_scene(m)
        en, _ = embree_scene(world_triangles(m))
        tp, _ = best_time(lambda: sn.intersect(so2, sd2))
        te, _ = best_time(lambda: en.run(so2, sd2, output=True))
        scaling.append((sn.stats()["triangles"], tp / len(so2), te / len(so2)))
        print("scaling", scaling[-1], flush=True)
        del sn, en
    resolutions = [64, 128, 256, 512] if quick else [128, 256, 512, 1024, 2048]
    res_scaling = []
    for r in resolutions:
        ro, rd = camera_rays(r)
        tp, _ = best_time(lambda: s.intersect(ro, rd), 2)
        te, _ = best_time(lambda: es.run(ro, rd, output=True), 2)
        res_scaling.append((r, tp, te))
        print("resolution", res_scaling[-1], flush=True)

    # Plots.
    plots = []
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
        x = [c for c, _, _ in scaling]
        axes[0].loglog(x, [p * 1e9 for _, p, _ in scaling], "o-", label="Pathlight")
        axes[0].loglog(x, [e * 1e9 for _, _, e in scaling], "s--", label="Embree")
        axes[0].set_xlabel("triangles")
        axes[0].set_ylabel("ns per primary ray (1 thread)")
        axes[0].set_title("time per ray against scene size", fontsize=10)
        axes[1].loglog([r * r for r, _, _ in res_scaling], [p for _, p, _ in res_scaling], "o-", label="Pathlight")
        axes[1].loglog([r * r for r, _, _ in res_scaling], [e for _, _, e in res_scaling], "s--", label="Embree")
        axes[1].set_xlabel("primary rays (resolution squared)")
        axes[1].set_ylabel("seconds (1 thread)")
        axes[1].set_title(f"time against resolution, {st['triangles']:,} triangles", fontsize=10)
        kinds = list(throughput)
        xs = np.arange(len(kinds))
        axes[2].bar(xs - 0.2, [throughput[k][0] / 1e6 for k in kinds], 0.4, label="Pathlight")
        axes[2].bar(xs + 0.2, [throughput[k][1] / 1e6 for k in kinds], 0.4, label="Embree")
        axes[2].set_xticks(xs, kinds)
        axes[2].set_ylabel("million rays/s (1 thread)")
        axes[2].set_title("throughput by ray type", fontsize=10)
        for ax in axes:
            ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "rays.png", dpi=110)
        plots.append("rays.png")
    except ImportError:
        pass

    lines = [
        "## Ray throughput against Embree",
        "",
        f"Scene: {st['triangles']:,} triangles (a bumpy cube-sphere, a ground grid and 36 smaller bumpy spheres),",
        f"generated by `tests/bench/bench_rays.py`. Pathlight's batch API (`Scene.intersect`/`occluded`, BVH kernel "
        f"`{st['bvh_layout']}`, core built for `{info['simd']}`) against Embree through embreex {embree_version()} on "
        "the same rays in the same process, one thread each (both batch APIs trace on the calling thread); best of "
        f"{REPEATS} runs. Primary rays: {res}x{res} pinhole camera; shadow rays: from the primary hits to uniform points "
        "on a light quad (any hit, tmax 1); diffuse bounces: cosine-distributed from the primary hits. Agreement: "
        "hit/miss equal, and t within 1e-4 relative where both hit.",
        "",
        "| Rays | Pathlight Mrays/s | Embree Mrays/s | Embree / Pathlight | hit agreement | t agreement |",
        "|---|---|---|---|---|---|",
    ]
    for kind, (p, e, a) in throughput.items():
        t_txt = "-" if np.isnan(a["t"]) else f"{100 * a['t']:.3f} %"
        lines.append(f"| {kind} ({len(o) if kind == 'primary' else len(so):,}) | {p / 1e6:.2f} | {e / 1e6:.2f} | "
                     f"{e / p:.2f}x | {100 * a['hit']:.3f} % | {t_txt} |")
    lines += ["", f"Per-ray cost of each batch API alone (rays that miss the scene's bounds): Pathlight "
              f"{overhead[0] * 1e9:.0f} ns, embreex {overhead[1] * 1e9:.0f} ns; it is included in the rates above.",
              "", "Pathlight's BVH kernels on the same scene (primary rays, diffuse bounces), Mrays/s: "
              + ", ".join(f"{k} {a / 1e6:.2f} / {b / 1e6:.2f}" for k, (a, b) in layouts.items()) + ".", ""]
    lines += [
        "### BVH build",
        "",
        "Pathlight: binned SAH (32 bins, leaves of at most 8 triangles) built on all cores, collapsed into the wide",
        "tree; 'commit' is the whole `Scene.commit()` (flattening, BVH, lights). SAH cost: expected triangle",
        "tests plus node visits of a random ray, of the binary tree. Memory, per triangle: the wide nodes (256 bytes",
        "each) and the leaves' 4-triangle SIMD blocks (144 bytes of coordinates and 16 of triangle indices per block).",
        "The scene keeps its own world-space triangles besides (36 bytes each, for shading and lights). Embree: its",
        "default build (all cores) on the first query. Build times: the fastest of "
        f"{BUILD_REPEATS} builds per engine, alternating. Clustered: `build_quality = 'fast'` (Morton runs under",
        "the binned SAH; what the viewport uses for meshes of 100k triangles or more), its build time and SAH cost.",
        "",
        "| Triangles | BVH build | commit | Embree build | SAH cost | wide nodes | BVH bytes/triangle "
        "| clustered build | clustered SAH cost |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for b in builds:
        lines.append(f"| {b['n']:,} | {b['bvh_ms']:.0f} ms | {b['wall'] * 1e3:.0f} ms | {b['embree'] * 1e3:.0f} ms | "
                     f"{b['sah']:.1f} | {b['wide']:,} | {b['bytes']:.1f} | {b['fast_ms']:.0f} ms | {b['fast_sah']:.1f} |")
    lines += ["", "### Scaling", "",
              "Time per primary ray (256x256 camera, one thread) against the triangle count of the same kind of scene:",
              "", "| Triangles | Pathlight ns/ray | Embree ns/ray | ratio |", "|---|---|---|---|"]
    for n, p, e in scaling:
        lines.append(f"| {n:,} | {p * 1e9:.0f} | {e * 1e9:.0f} | {p / e:.2f} |")
    lines += ["", f"Time against resolution on the {st['triangles']:,}-triangle scene (primary rays, one thread):", "",
              "| Resolution | Pathlight s | Embree s | Pathlight ns/ray |", "|---|---|---|---|"]
    for r, p, e in res_scaling:
        lines.append(f"| {r}x{r} | {p:.3f} | {e:.3f} | {p / (r * r) * 1e9:.0f} |")
    lines.append("")
    for p in plots:
        lines += [f"![time per ray against triangles and resolution; throughput by ray type]({p})", ""]
    write_section(out, "rays", lines)


def embree_version():
    try:
        from importlib.metadata import version
        return version("embreex").split(".post")[0]
    except Exception:
        return "(version unknown)"


if __name__ == "__main__":
    main()
