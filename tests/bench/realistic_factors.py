"""The two factors of a realistic bench scene's equal-time ratio, Pathlight against Cycles, at
the bench's settings (tests/bench/bench_realistic.py): the relative variance of one sample and
the CPU time of one sample, and where the variance is (by image region and, for Pathlight, by
path class). Load-independent where wall time is not: variance is counted in samples, time in
process CPU seconds (all threads of both engines run in this process). Not named bench_*:
build.py runs those.

    .venv/bin/python tests/bench/realistic_factors.py [--scene hdri_model] [--seeds N] [--spp S] [--classes]
        [--threads T] [--time-only]

Each engine renders the scene N times at S spp with different seeds. A region's score is the
mean over its pixels of var * S / (ref^2 + 1e-2), ref the mean of both engines' renders (the
relative MSE of the bench at one sample). The expected equal-time ratio (Cycles' error over
Pathlight's) is Cycles' variance x CPU time over Pathlight's. Regions are each mesh object's
projected bounding box (spheres: their projected disc), the rest of the image outside them.
--classes: Pathlight's variance split by the path classes of guiding_path_classes.py (the
guided kernel with guide probability 0: the plain estimator)."""
import argparse
import ast
import os
import sys
import time
from pathlib import Path

import bpy
import numpy as np
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

os.environ.setdefault("PATHLIGHT_CYCLES_REFS", "render")  # nothing goes to tests/cycles_refs
sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
from guiding_path_classes import CLASSES  # noqa: E402
from core_bench import override_render_settings, print_outliers  # noqa: E402
import realistic_scenes as rs  # noqa: E402

MAX_BOUNCES = 12
SETTINGS = {}  # extra RenderSettings for Pathlight (path classes)
THREADS = 0  # --threads: render threads of both engines (0: all)


def object_masks(scene):
    """Per mesh object (not a floor or ground), a mask (row 0 = top): a sphere's projected disc
    (0.95 of its radius), else its projected bounding box; and 'sky': the pixels whose camera
    ray misses the floor (a plane named Floor at z = 0) and the objects' masks."""
    bpy.context.view_layer.update()  # the builders' matrices are stale until then
    w, h = scene.render.resolution_x, scene.render.resolution_y
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    out = {}
    for ob in scene.objects:
        if ob.type != 'MESH' or ob.hide_render or ob.name in ("Floor", "Ground", "Host"):
            continue
        if ob.name.startswith(("Chrome", "Sphere")) or "sphere" in ob.data.name.lower():
            c = world_to_camera_view(scene, scene.camera, ob.matrix_world.translation)
            r = max(ob.dimensions) / 2
            e = world_to_camera_view(scene, scene.camera, ob.matrix_world.translation + Vector((r, 0.0, 0.0)))
            rad = abs(e.x - c.x) * w * 0.95
            out[ob.name] = (xx - c.x * w) ** 2 + (yy - (1.0 - c.y) * h) ** 2 < rad * rad
            continue
        pts = [world_to_camera_view(scene, scene.camera, ob.matrix_world @ Vector(b)) for b in ob.bound_box]
        x0, x1 = min(p.x for p in pts) * w, max(p.x for p in pts) * w
        y0, y1 = (1.0 - max(p.y for p in pts)) * h, (1.0 - min(p.y for p in pts)) * h
        out[ob.name] = (xx > x0) & (xx < x1) & (yy > y0) & (yy < y1)
    floor = scene.objects.get("Floor")
    if floor is not None:
        cam = scene.camera
        frame = [cam.matrix_world @ v for v in cam.data.view_frame(scene=scene)]  # tr, br, bl, tl
        o = np.array(cam.matrix_world.translation)
        tl, tr, bl = (np.array(frame[i]) for i in (3, 0, 2))
        u, v = (xx / w)[..., None], (yy / h)[..., None]
        d = tl + u * (tr - tl) + v * (bl - tl) - o
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[2] / d[..., 2]
        hit = o[:2] + t[..., None] * d[..., :2]
        half = np.array(floor.dimensions[:2]) / 2
        on_floor = (t > 0) & (np.abs(hit - np.array(floor.location[:2])) < half).all(-1)
        out["sky"] = ~on_floor
    return out


def render(build, engine, spp, seed):
    scene = build()
    if THREADS:  # both engines follow the scene's thread setting
        scene.render.threads_mode = "FIXED"
        scene.render.threads = THREADS
    if engine == "CYCLES":
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 1.0
    t = time.process_time()
    img = render_to_array(scene, engine, max_bounces=MAX_BOUNCES, samples=spp, seed=seed)
    return img[..., :3].astype(np.float64), time.process_time() - t, scene


def cpu_per_sample(build, engine, spp, repeats=2):
    """CPU seconds of one sample (all threads): the difference between renders at spp and at 1
    spp over spp - 1, the least of `repeats` pairs (export and sync cancel out)."""
    best = np.inf
    for k in range(repeats):
        _, t1, _ = render(build, engine, 1, 50 + k)
        _, tn, _ = render(build, engine, spp, 50 + k)
        best = min(best, (tn - t1) / (spp - 1))
    return best


def rel_var(imgs, ref, spp):
    return (imgs.var(0, ddof=1) * spp / (ref ** 2 + 1e-2)).mean(-1)


def reference_terms(pl, cy, ref, t_pl, t_cy, args):
    """What the bench's reference adds to its error estimates, predicted from the per-pixel
    variances (as if Gaussian: heavy tails make the real spread larger). With w = 1 / (ref^2 +
    0.01) and e the errors against the converged image, the bench's estimate of a render x's
    error, mean(w (x - R)^2) less the floor mean(w (P - C)^2) / 4 (R = (P + C) / 2, P and C each
    engine's reference), is mean(w e_x^2) - 2 mean(w e_x e_R) + mean(w e_P e_C); the cross-halves
    estimate mean(w (x - R1)(x - R2)) (R1, R2 from the engines' first and second halves) has
    mean(w e_R1 e_R2) in the last term's place. Both last terms are 0 on average: their spread
    across references is what a reference adds to every render's error estimate alike."""
    w = 1.0 / (ref ** 2 + 1e-2)
    v_pl, v_cy = pl.var(0, ddof=1) * args.spp, cy.var(0, ddof=1) * args.spp  # one sample's variance
    n = w.size
    threads = os.cpu_count() or 1
    print(f"\nThe bench's references ({threads} threads: {threads / t_pl:.0f} / {threads / t_cy:.0f} spp/s "
          "Pathlight / Cycles from the CPU times above)")
    print(f"{'ref spp':>7s} {'floor':>9s} {'sd bench':>9s} {'sd halves':>9s}   " +
          " ".join(f"{'err P ' + f'{t:g} s':>10s}" for t in (1, 8)))
    for spp in (1024, 4096, 16384):
        floor = np.mean(w * (v_pl + v_cy) / spp) / 4.0
        sd_bench = np.sqrt(np.sum(w ** 2 * v_pl * v_cy / spp ** 2)) / n
        sd_halves = np.sqrt(np.sum(w ** 2 * ((v_pl + v_cy) / (2.0 * spp)) ** 2)) / n
        errs = " ".join(f"{np.mean(w * v_pl) / (t * threads / t_pl):10.3g}" for t in (1, 8))
        print(f"{spp:7d} {floor:9.3g} {sd_bench:9.3g} {sd_halves:9.3g}   {errs}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="hdri_model", help="a builder of realistic_scenes.py")
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--time-spp", type=int, default=64, help="spp of the CPU-time renders")
    ap.add_argument("--classes", action="store_true", help="Pathlight's variance by path class")
    ap.add_argument("--pathlight-only", action="store_true", help="Cycles' figures from the cache file")
    ap.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE",
                    help="Pathlight RenderSettings for every render (e.g. guiding=1), a Python literal each")
    ap.add_argument("--threads", type=int, default=0, help="render threads of both engines (default: all)")
    ap.add_argument("--time-only", action="store_true", help="only the CPU seconds per sample of both engines")
    ap.add_argument("--cache", default="/tmp/realistic_factors_{scene}_{seeds}x{spp}.npz")
    args = ap.parse_args()
    build = getattr(rs, args.scene)
    addon = load_addon()
    override_render_settings(addon, SETTINGS)
    base = {k: ast.literal_eval(v) for k, v in (kv.split("=", 1) for kv in args.set)}
    SETTINGS.update(base)

    global THREADS
    THREADS = args.threads
    if args.time_only:
        t_pl, t_cy = (cpu_per_sample(build, e, args.time_spp) for e in ("PATHLIGHT", "CYCLES"))
        print(f"{args.scene}, {args.threads or 'all'} threads: CPU seconds per sample Pathlight {t_pl:.4g}, "
              f"Cycles {t_cy:.4g} (Cycles / Pathlight {t_cy / t_pl:.2f}x)")
        return
    cache = Path(args.cache.format(scene=args.scene, seeds=args.seeds, spp=args.spp))
    pl = np.stack([render(build, "PATHLIGHT", args.spp, 1000 + s)[0] for s in range(args.seeds)])
    if args.pathlight_only and cache.exists():
        z = np.load(cache)
        cy, t_cy = z["cy"], float(z["t_cy"])
    else:
        cy = np.stack([render(build, "CYCLES", args.spp, 1000 + s)[0] for s in range(args.seeds)])
        t_cy = cpu_per_sample(build, "CYCLES", args.time_spp)
        np.savez(cache, cy=cy, t_cy=t_cy)
    t_pl = cpu_per_sample(build, "PATHLIGHT", args.time_spp)
    masks = object_masks(build())
    ref = 0.5 * (pl.mean(0) + cy.mean(0))
    var = {"pl": rel_var(pl, ref, args.spp), "cy": rel_var(cy, ref, args.spp)}
    vp, vc = var["pl"].mean(), var["cy"].mean()
    print(f"{args.scene}: {args.seeds} seeds x {args.spp} spp")
    print(f"relative variance of one sample: Pathlight {vp:.4g}, Cycles {vc:.4g} (Cycles / Pathlight {vc / vp:.2f}x)")
    print(f"CPU seconds per sample (all threads): Pathlight {t_pl:.4g}, Cycles {t_cy:.4g} "
          f"(Cycles / Pathlight {t_cy / t_pl:.2f}x)")
    print(f"expected equal-time ratio (Cycles' error over Pathlight's): {vc * t_cy / (vp * t_pl):.2f}x")
    print(f"\n{'region':16s} {'pixels':>6s} {'Pathlight':>10s} {'Cycles':>10s} {'C/P':>6s} "
          f"{'share of P':>10s} {'mean P/C':>8s}")
    rest = np.ones(ref.shape[:2], bool)
    total = var["pl"].sum()
    for name, m in list(masks.items()) + [("rest", None), ("all", None)]:
        if m is None:
            m = rest if name == "rest" else np.ones_like(rest)
        else:
            m = m & rest  # first come first served where boxes overlap
            rest &= ~m
        p, c = var["pl"][m].mean(), var["cy"][m].mean()
        print(f"{name:16s} {int(m.sum()):6d} {p:10.4g} {c:10.4g} {c / p:6.2f} {var['pl'][m].sum() / total:10.2f} "
              f"{pl.mean(0)[m].mean() / cy.mean(0)[m].mean():8.4f}")
    label = np.full(rest.shape, "rest", dtype=object)
    for name, m in masks.items():
        label[m & (label == "rest")] = name
    for key, imgs in (("Pathlight", pl), ("Cycles", cy)):
        print_outliers(key, imgs, label, args.spp)

    reference_terms(pl, cy, ref, t_pl, t_cy, args)

    if args.classes:
        print("\nPathlight by path class (plain estimator in the guided kernel): relative variance of one sample")
        print(f"{'class':30s} " + " ".join(f"{n[:10]:>10s}" for n in list(masks) + ["rest", "all"]))
        for cid, cname in enumerate(CLASSES):
            SETTINGS.clear()
            SETTINGS.update(base, guiding=True, guiding_probability=0.0, guiding_photons=0.0,
                            guiding_class_mask=1 << cid)
            imgs = np.stack([render(build, "PATHLIGHT", args.spp, 1000 + s)[0] for s in range(args.seeds)])
            v = rel_var(imgs, ref, args.spp)
            rest = np.ones(ref.shape[:2], bool)
            cells = []
            for name, m in list(masks.items()) + [("rest", None), ("all", None)]:
                if m is None:
                    m = rest if name == "rest" else np.ones_like(rest)
                else:
                    m = m & rest
                    rest &= ~m
                cells.append(v[m].mean())
            print(f"{cname:30s} " + " ".join(f"{c:10.4g}" for c in cells))
        SETTINGS.clear()
        SETTINGS.update(base)


if __name__ == "__main__":
    main()
