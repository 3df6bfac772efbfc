"""Per-sample variance of Pathlight and Cycles on the equal-time bench scenes: the part of the
equal-time error that does not depend on machine load.

    .venv/bin/python tests/bench/variance_per_sample.py [--seeds N] [--spp S] [--scenes ...]

Each engine renders the scene N times with S samples per pixel and different seeds; the
per-pixel variance across seeds times S is the variance of one sample (at S spp: Sobol's
stratification shows up as a lower value at higher S). The score is the relative variance the
bench's relative MSE uses, mean over pixels of var / (ref^2 + 1e-2), with ref the mean of both
engines' renders. Pathlight renders through the core directly (the scene exported once by the
add-on), Cycles through bpy. Cycles' results are cached in /tmp (they do not change with our code).
"""
import argparse
import hashlib
import sys
from pathlib import Path

import bpy
import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
from bench_equal_time import SCENES, SCALE  # noqa: E402


def open_scene(fixture, setup):
    from blender_util import open_fixture
    scene = open_fixture(fixture)
    if setup:
        setup(scene)
    return scene


def pathlight_images(fixture, setup, seeds, spp, max_bounces=12, **settings):
    addon = load_addon()
    from addon.export import export_scene
    from addon.scene_writer import to_core
    from addon.session import render_settings
    scene = open_scene(fixture, setup)
    scene.render.resolution_percentage = SCALE
    pc = addon.core.get_core()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None)
    core_scene = to_core(pc, data)
    if pathlight_images.no_rect:  # rectangle lights as two spherical triangles (before rect groups)
        core_scene.rect_groups = False
    st = render_settings(pc, scene)
    st.adaptive_threshold = 0.0
    st.max_bounces = max_bounces
    st.diffuse_bounces = st.glossy_bounces = st.transmission_bounces = 1024
    st.samples = spp
    # The 1-pixel box filter, as Cycles below and the equal-time bench (the add-on's default,
    # Blackman-Harris 1.5 px, blurred edges: mean differences at the light's edges).
    st.filter_type, st.filter_width = "box", 1.0
    for k, v in settings.items():
        setattr(st, k, v)
    out = []
    rays = paths = 0
    for seed in range(seeds):
        st.seed = 1000 + seed
        sess = pc.Session(core_scene, st)
        sess.start()
        while not sess.wait(1.0):
            pass
        out.append(np.asarray(sess.film())[..., :3].astype(np.float64))
        stats = sess.stats()
        rays += stats["rays"]
        paths += stats["paths"]
    pathlight_images.rays_per_path = rays / max(paths, 1)
    return np.stack(out)


pathlight_images.no_rect = False


def cycles_images(fixture, setup, seeds, spp, max_bounces=12, cache=True):
    key = hashlib.sha1(f"{fixture}{setup and setup.__name__}{seeds}{spp}{SCALE}{max_bounces}".encode()).hexdigest()[:12]
    cache_file = Path("/tmp") / f"pathlight_cycles_var_{key}.npy"
    if cache and cache_file.exists():
        return np.load(cache_file)
    out = []
    for seed in range(seeds):
        scene = open_scene(fixture, setup)
        scene.cycles.pixel_filter_type = "BOX"
        scene.cycles.filter_width = 1.0
        img = render_to_array(scene, "CYCLES", resolution_percentage=SCALE, max_bounces=max_bounces,
                              samples=spp, seed=1000 + seed)
        out.append(img[::-1, :, :3].astype(np.float64))  # row 0 = bottom, as the core's film
    out = np.stack(out)
    if cache:
        np.save(cache_file, out)
    return out


def per_sample_variance(fixture, setup, seeds, spp, cache=True):
    """Relative variance of one sample (at `spp` samples per pixel) of Pathlight and Cycles."""
    pl = pathlight_images(fixture, setup, seeds, spp)
    cy = cycles_images(fixture, setup, seeds, spp, cache=cache)
    ref = 0.5 * (pl.mean(axis=0) + cy.mean(axis=0))
    return rel_var(pl, ref, spp), rel_var(cy, ref, spp)


def rel_var(imgs, ref, spp):
    return float(np.mean(imgs.var(axis=0, ddof=1) * spp / (ref**2 + 1e-2)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 16])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--no-cycles", action="store_true")
    ap.add_argument("--max-bounces", type=int, default=12)
    ap.add_argument("--save", help="save the per-pixel variance maps (npz) here")
    ap.add_argument("--no-rect", action="store_true",
                    help="quad lights as two spherical triangles (Scene.rect_groups off), as before rectangle groups")
    args = ap.parse_args()
    pathlight_images.no_rect = args.no_rect
    load_addon()
    maps = {}
    for name in args.scenes:
        fixture, setup = SCENES[name]
        for spp in args.spp:
            pl = pathlight_images(fixture, setup, args.seeds, spp, args.max_bounces)
            line = (f"{name} @ {spp} spp: Pathlight rel. variance/sample {{pl:.4g}} "
                    f"({pathlight_images.rays_per_path:.2f} rays/path)")
            ref = pl.mean(axis=0)
            if not args.no_cycles:
                cy = cycles_images(fixture, setup, args.seeds, spp, args.max_bounces)
                ref = 0.5 * (ref + cy.mean(axis=0))
                c = rel_var(cy, ref, spp)
                line += f", Cycles {c:.4g}, ratio PL/Cycles {{ratio:.3f}}, mean ratio {pl.mean() / cy.mean():.4f}"
                maps[f"{name}/{spp}/cycles"] = cy.var(axis=0, ddof=1) * spp / (ref**2 + 1e-2)
            p = rel_var(pl, ref, spp)
            maps[f"{name}/{spp}/pathlight"] = pl.var(axis=0, ddof=1) * spp / (ref**2 + 1e-2)
            print(line.format(pl=p, ratio=p / c if not args.no_cycles else 0.0), flush=True)
    if args.save:
        np.savez_compressed(args.save, **maps)


if __name__ == "__main__":
    main()
