"""Per-sample variance around a rough glass sphere and its floor caustic (issue 25's minimal
scene), Pathlight against Cycles at equal samples. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/glass_caustic_variance.py [--seeds N] [--spp S] [--hdri] ...

A Principled glass sphere (Transmission 1, roughness 0.2) on a grey floor (Diffuse BSDF, or
--floor principled: the bench's), lit by a 300 W point light of radius 0.2 m (Soft Falloff on)
where the bench's Principled spheres have theirs; no world light, or --hdri the bench's. The
camera is the bench's at --lens 40, else (default 100) it frames the sphere and its caustic;
--shift moves it. Each engine renders N times at S spp with seeds seed0.. (1-pixel box filter,
max bounces 12, no clamping, no denoising); --limits D,G,T sets both engines' diffuse, glossy
and transmission bounce limits. Per region ('caustic': the floor the sphere shadows from the
light's centre; 'sphere': 0.9 of its projected radius; 'rest'): the ratio of the engines'
summed per-pixel variances with a 90 % bootstrap interval over the seeds (single pixels'
variances are heavy-tailed: 8 seeds can put either engine 5x ahead), and of their means."""
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
import material_scenes as ms  # noqa: E402
import realistic_scenes as rs  # noqa: E402

CENTRE, RADIUS, LIGHT = Vector((0.0, 0.0, 0.45)), 0.45, Vector((2.0, -2.5, 3.5))


def glass_scene(width, height, roughness=0.2, lens=100.0, floor="diffuse", shift=(0.0, 0.0), hdri=False):
    scene = rs._empty(width, height)
    mat = rs.principled("Frosted glass", (0.95, 0.98, 1.0), roughness, Transmission_Weight=1.0)
    ms.add_sphere("Glass", RADIUS, mat, location=tuple(CENTRE))
    if floor == "diffuse":
        fmat, _ = ms.bsdf_material("Floor", "ShaderNodeBsdfDiffuse", Color=(0.5, 0.5, 0.5, 1.0))
    else:
        fmat = rs.principled("Floor", (0.5, 0.5, 0.5), 0.6)
    ms.add_plane("Floor", 10.0, fmat)
    if hdri:  # the bench's synthetic HDRI
        rs.ls.world_image(rs.ls.load_image(rs.ls.synthetic_hdr(256, 128, sun_peak=50.0), name="BenchHDR"))
    else:
        ms.set_world((0.0, 0.0, 0.0))
    bpy.ops.object.light_add(type='POINT', location=tuple(LIGHT))
    bpy.context.active_object.data.energy = 300.0
    bpy.context.active_object.data.shadow_soft_size = 0.2
    # The bench's camera (lens 40); longer lenses frame the sphere and its caustic.
    cam = ms.add_camera((0.0, -5.2, 3.6), (0.0, 0.0, 0.3) if lens <= 40.0 else (-0.15, 0.15, 0.3), lens=lens)
    cam.data.shift_x, cam.data.shift_y = shift
    return scene


def masks(scene):
    """(sphere, caustic): the pixels (row 0 = top) inside 0.9 of the sphere's projected radius,
    and those of floor points whose segment to the light's centre crosses the sphere."""
    w, h = scene.render.resolution_x, scene.render.resolution_y
    yy, xx = np.mgrid[0:h, 0:w]
    c = world_to_camera_view(scene, scene.camera, CENTRE)
    e = world_to_camera_view(scene, scene.camera, CENTRE + Vector((RADIUS, 0.0, 0.0)))
    r = abs(e.x - c.x) * w
    sphere_full = (xx + 0.5 - c.x * w) ** 2 + (yy + 0.5 - (1.0 - c.y) * h) ** 2 < (1.05 * r) ** 2
    sphere = (xx + 0.5 - c.x * w) ** 2 + (yy + 0.5 - (1.0 - c.y) * h) ** 2 < (0.9 * r) ** 2
    hits = np.zeros((h, w), int)
    total = np.zeros((h, w), int)
    for x in np.linspace(-3.0, 3.0, 241):
        for y in np.linspace(-3.0, 3.0, 241):
            p = Vector((x, y, 0.0))
            d = (LIGHT - p).normalized()
            oc = p - CENTRE
            b = oc.dot(d)
            shadow = b * b - (oc.dot(oc) - RADIUS * RADIUS) > 0.0 and b < 0.0
            v = world_to_camera_view(scene, scene.camera, p)
            px, py = int(v.x * w), int((1.0 - v.y) * h)
            if 0 <= px < w and 0 <= py < h and v.z > 0.0:
                total[py, px] += 1
                hits[py, px] += shadow
    caustic = (total > 0) & (hits == total) & ~sphere_full
    return sphere, caustic


def renders(engine, seeds, spp, size, limits, roughness, lens, floor, shift, seed0=1000, hdri=False):
    imgs = []
    for s in range(seeds):
        scene = glass_scene(*size, roughness=roughness, lens=lens, floor=floor, shift=shift, hdri=hdri)
        extra = {}
        if engine == "CYCLES":
            extra = dict(pixel_filter_type="BOX", filter_width=1.0)
        if limits:
            extra.update(diffuse_bounces=limits[0], glossy_bounces=limits[1], transmission_bounces=limits[2])
        img = render_to_array(scene, engine, max_bounces=12, samples=spp, seed=seed0 + s, **extra)
        imgs.append(img[..., :3].astype(np.float64))
    return np.stack(imgs), masks(scene)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", default="64,48")
    ap.add_argument("--limits", default="")
    ap.add_argument("--roughness", type=float, default=0.2)
    ap.add_argument("--lens", type=float, default=100.0)
    ap.add_argument("--floor", default="diffuse", choices=("diffuse", "principled"))
    ap.add_argument("--shift", default="0,0", help="the camera's shift_x,shift_y")
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--hdri", action="store_true", help="the bench's HDRI as the world")
    ap.add_argument("--engines", default="PATHLIGHT,CYCLES")
    ap.add_argument("--save", default="")
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split(","))
    limits = tuple(int(v) for v in args.limits.split(",")) if args.limits else None
    load_addon()
    out = {}
    for engine in args.engines.split(","):
        out[engine], (sphere, caustic) = renders(engine, args.seeds, args.spp, size, limits, args.roughness, args.lens, args.floor,
                                                    tuple(float(v) for v in args.shift.split(",")), args.seed0, args.hdri)
    if args.save:
        np.savez(args.save, sphere=sphere, caustic=caustic, **out)
    print(f"{args.seeds} seeds x {args.spp} spp, limits {limits}: caustic {caustic.sum()} px, "
          f"sphere {sphere.sum()} px")
    if len(out) != 2:
        return
    pl, cy = out.values()
    rng = np.random.default_rng(0)
    rest = ~caustic & ~sphere
    for region, m in (("caustic", caustic), ("sphere", sphere), ("rest", rest), ("all", np.ones_like(rest))):
        if not m.any():
            continue
        a, b = pl[:, m].mean(-1), cy[:, m].mean(-1)  # seeds x pixels, the channels' mean
        ratio = a.var(0, ddof=1).sum() / b.var(0, ddof=1).sum()
        boot = [a[rng.integers(0, len(a), len(a))].var(0, ddof=1).sum() /
                b[rng.integers(0, len(b), len(b))].var(0, ddof=1).sum() for _ in range(300)]
        lo, hi = np.percentile(boot, [5, 95])
        print(f"{region:8s} variance Pathlight / Cycles {ratio:6.3f} [{lo:.2f}, {hi:.2f}]  "
              f"mean {a.mean() / b.mean():.4f}")


if __name__ == "__main__":
    main()
