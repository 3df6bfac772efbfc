"""Per-sphere variance of one sample on the realistic bench's Principled spheres (issue 24),
Pathlight against Cycles at equal samples, and the brightest single-render outliers: which
sphere's noise is out of line, independent of machine load. Not named bench_*: build.py runs
those.

    .venv/bin/python tests/bench/principled_spheres_variance.py [--seeds N] [--spp S]

Each engine renders the scene N times at S spp with different seeds (both with the bench's
settings: 1-pixel box filter, max bounces 12, no clamping, no denoising). A sphere's score is
the mean over its pixels of var * S / (ref^2 + 1e-2), ref the mean of both engines' renders
(the relative variance the equal-time bench's relative MSE uses). Spheres are masked by their
projected centre and radius; 'rest' is the floor and the sky."""
import argparse
import sys
from pathlib import Path

import bpy
import numpy as np
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
from core_bench import print_outliers  # noqa: E402
import realistic_scenes as rs  # noqa: E402


def sphere_masks(scene, radius=0.45):
    """Per sphere object, the pixels (row 0 = top) inside 0.9 of its projected radius."""
    w, h = scene.render.resolution_x, scene.render.resolution_y
    yy, xx = np.mgrid[0:h, 0:w]
    out = {}
    for ob in scene.objects:
        if ob.type != 'MESH' or ob.name == "Floor":
            continue
        c = world_to_camera_view(scene, scene.camera, ob.location)
        e = world_to_camera_view(scene, scene.camera, ob.location + Vector((radius, 0.0, 0.0)))
        r = abs(e.x - c.x) * w * 0.9
        out[ob.name] = (xx + 0.5 - c.x * w) ** 2 + (yy + 0.5 - (1.0 - c.y) * h) ** 2 < r * r
    return out


def renders(engine, seeds, spp):
    imgs = []
    for s in range(seeds):
        scene = rs.principled_spheres()
        if engine == "CYCLES":
            scene.cycles.pixel_filter_type = "BOX"
            scene.cycles.filter_width = 1.0
        img = render_to_array(scene, engine, max_bounces=12, samples=spp, seed=1000 + s)
        imgs.append(img[..., :3].astype(np.float64))
    return np.stack(imgs), sphere_masks(scene)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--spp", type=int, default=64)
    args = ap.parse_args()
    load_addon()
    pl, masks = renders("PATHLIGHT", args.seeds, args.spp)
    cy, _ = renders("CYCLES", args.seeds, args.spp)
    ref = 0.5 * (pl.mean(0) + cy.mean(0))
    var = {k: (v.var(0, ddof=1) * args.spp / (ref**2 + 1e-2)).mean(-1) for k, v in (("pl", pl), ("cy", cy))}
    rest = np.ones(ref.shape[:2], bool)
    print(f"{args.seeds} seeds x {args.spp} spp: relative variance of one sample")
    print(f"{'region':16s} {'Pathlight':>10s} {'Cycles':>10s} {'ratio':>6s} {'mean ratio':>10s}")
    for name, m in list(masks.items()) + [("rest", None), ("all", None)]:
        if m is None:
            m = rest if name == "rest" else np.ones_like(rest)
        else:
            rest &= ~m
        p, c = var["pl"][m].mean(), var["cy"][m].mean()
        print(f"{name:16s} {p:10.4g} {c:10.4g} {p / c:6.2f} {pl.mean(0)[m].mean() / cy.mean(0)[m].mean():10.4f}")
    label = np.full(rest.shape, "rest", dtype=object)
    for name, m in masks.items():
        label[m] = name
    for key, imgs in (("Pathlight", pl), ("Cycles", cy)):
        print_outliers(key, imgs, label, args.spp)


if __name__ == "__main__":
    main()
