"""Scaling and memory (issue 6): time per sample against the triangle count (10k to 10M) and
against the resolution, and the memory of a 10-million-triangle scene rendered to an image.

Each triangle count runs in its own fresh process: the scene of tests/bench/bench_rays.py
(a bumpy sphere, a ground grid and 36 smaller spheres) is built with numpy, handed to the core
module (add_mesh), committed and rendered by a Session at 128x128 with 8 samples (grey diffuse,
a sun and a grey world, 12 bounces) on all cores; the time per sample is the session's own
elapsed time over its samples. Memory: the process's peak resident size (VmHWM) at the end,
the numpy arrays of the scene included, and the core's own bytes per triangle (geometry:
meshes as added, world-space triangles and shading data; BVH: nodes and triangle blocks). The
10M run is the check that such a scene renders in 24 GiB. Writes docs/bench/scaling.md."""
import json
import sys
import textwrap
from pathlib import Path

from benchutil import parse_args, run_child as run_json_child, section_dir, write_section

TESTS = Path(__file__).resolve().parents[1]
REPO = TESTS.parent
COUNTS = (10_000, 100_000, 1_000_000, 10_000_000)
RESOLUTIONS = (64, 128, 256, 512)
LIMIT_GIB = 24

CHILD = textwrap.dedent("""
    import json, sys, time
    sys.path[:0] = [{tests!r} + "/core", {tests!r} + "/blender", {bench!r}]
    import numpy as np
    from bench_rays import make_scene, pc
    from benchutil import proc_status as status
    from core_scenes import look_at_matrix

    n, resolutions, samples = int(sys.argv[1]), json.loads(sys.argv[2]), int(sys.argv[3])
    meshes = make_scene(n)
    scene = pc.Scene()
    grey = scene.add_material("grey", base_color=(0.7, 0.7, 0.7))
    for pos, tris in meshes:
        scene.add_instance(scene.add_mesh(pos, tris, material_slots=[grey]), np.eye(4, dtype=np.float32))
    del meshes  # the core holds its own copy
    scene.add_sun_light((0.3, -0.4, 0.87), (3.0, 3.0, 3.0), angle=0.05)
    scene.set_world_color((0.2, 0.2, 0.2))
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix((0.0, -5.5, 1.6), (0.0, 0.0, -0.3))
    scene.set_camera(cam)
    t = time.perf_counter()
    scene.commit()
    commit_s = time.perf_counter() - t
    st = scene.stats()
    out = dict(triangles=st["triangles"], commit_s=commit_s, bvh_ms=st["bvh_build_ms"],
               geometry_bytes=st["geometry_bytes"], bvh_bytes=st["bvh_bytes"], per_sample={{}})
    for res in resolutions:
        s = pc.RenderSettings()
        s.width = s.height = res
        s.samples = samples
        sess = pc.Session(scene, s)
        sess.start()
        while not sess.wait(1.0):
            pass
        ss = sess.stats()
        img = sess.film()
        assert ss["samples_done"] == samples and np.isfinite(img).all() and img[..., :3].mean() > 0
        out["per_sample"][str(res)] = ss["elapsed_s"] / ss["samples_done"]
        del sess
    out["peak_rss"] = status("VmHWM")
    print("RESULT " + json.dumps(out), flush=True)
""")


def run_child(n, resolutions, samples):
    code = CHILD.format(tests=str(TESTS), bench=str(TESTS / "bench"))
    return run_json_child([sys.executable, "-c", code, str(n), json.dumps(list(resolutions)), str(samples)],
                          f"scaling run of {n} triangles", 3600)


def main():
    args = parse_args("up to 100k triangles (smoke run)")
    counts = (10_000, 100_000) if args.quick else COUNTS
    samples = 8
    rows = []
    for n in counts:
        # The resolution sweep on the 1M scene (the 100k one in a quick run); 128x128 elsewhere.
        res = RESOLUTIONS if n == (100_000 if args.quick else 1_000_000) else (128,)
        rows.append(run_child(n, res, samples))
        print(n, rows[-1], flush=True)

    gib, mib = 1 << 30, 1 << 20
    biggest = rows[-1]
    lines = ["## Scaling and memory", "",
             f"The scene of `bench_rays.py` at each size, built with numpy and handed to the core module, committed "
             f"and rendered by a Session ({samples} samples, grey diffuse, a sun and a grey world, up to 12 bounces, "
             "all cores), each size in a fresh process. Time per sample: the session's elapsed time over its samples "
             "(one sample = one path per pixel). Peak RSS: the process's peak resident size (VmHWM), the numpy "
             "scene arrays included. Bytes per triangle: the core's geometry (meshes as added, world-space "
             "triangles and shading data) and BVH, as allocated.", "",
             "| Triangles | commit (s) | BVH build (ms) | ms per sample at 128x128 | geometry + BVH bytes/triangle "
             "| peak RSS (MiB) |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        t = r["triangles"]
        lines.append(f"| {t:,} | {r['commit_s']:.2f} | {r['bvh_ms']:.0f} | {r['per_sample']['128'] * 1e3:.1f} "
                     f"| {r['geometry_bytes'] / t:.0f} + {r['bvh_bytes'] / t:.0f} | {r['peak_rss'] / mib:,.0f} |")
    sweep = next(r for r in rows if len(r["per_sample"]) > 1)
    lines += ["", f"Time per sample against resolution on the {sweep['triangles']:,}-triangle scene:", "",
              "| Resolution | ms per sample | ns per pixel sample |", "|---|---|---|"]
    for res, t in sweep["per_sample"].items():
        r = int(res)
        lines.append(f"| {r}x{r} | {t * 1e3:.1f} | {t / (r * r) * 1e9:.0f} |")
    fits = biggest["peak_rss"] < LIMIT_GIB * gib
    lines += ["", f"Memory check: the {biggest['triangles']:,}-triangle scene rendered with a peak of "
              f"{biggest['peak_rss'] / gib:.2f} GiB, {'within' if fits else 'OVER'} the {LIMIT_GIB} GiB budget.", ""]
    out = section_dir(args)
    write_section(out, "scaling", lines)
    if not fits:
        sys.exit(f"peak RSS {biggest['peak_rss'] / gib:.2f} GiB exceeds {LIMIT_GIB} GiB")


if __name__ == "__main__":
    main()
