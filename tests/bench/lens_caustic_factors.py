"""Caustic light paths with depth of field (issue 25): the relative variance of one sample of a
realistic bench scene (default: hdri_model, the textured model and the chrome ball under an HDRI
with a sun) whose camera gets a thin lens, with the light paths off and at the given numbers per
sample. Not named bench_*: build.py runs those.

    .venv/bin/python tests/bench/lens_caustic_factors.py [--scene hdri_model] [--seeds 16] [--spp 32]
        [--fstop 1.0] [--focus 4.75] [--paths 0.1]

Relative variance as realistic_factors.py: the mean over pixels of var * spp / (ref^2 + 1e-2),
ref the mean of every render here (all variants are unbiased). Instructions per sample: run
callgrind_forest.py --scene hdri_model --dof FSTOP FOCUS --set caustic_light_paths=C."""
import argparse
import os
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("PATHLIGHT_CYCLES_REFS", "render")
sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon, render_to_array  # noqa: E402
from core_bench import override_render_settings  # noqa: E402
import realistic_scenes as rs  # noqa: E402


def with_dof(scene, fstop, focus):
    dof = scene.camera.data.dof
    dof.use_dof, dof.aperture_fstop, dof.focus_distance = True, fstop, focus
    return scene


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="hdri_model")
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--fstop", type=float, default=1.0)
    ap.add_argument("--focus", type=float, default=4.75, help="along the view axis (hdri_model: Suzanne at ~4.75)")
    ap.add_argument("--paths", type=float, nargs="*", default=[0.1])
    a = ap.parse_args()
    build = getattr(rs, a.scene)
    addon = load_addon()
    settings = {}
    override_render_settings(addon, settings)
    imgs = {}
    for c in [0.0] + a.paths:
        settings.clear()
        settings.update(caustic_light_paths=c, caustic_light_paths_auto=False)
        out = []
        for s in range(a.seeds):
            scene = with_dof(build(), a.fstop, a.focus)
            img = render_to_array(scene, "PATHLIGHT", max_bounces=12, samples=a.spp, seed=1000 + s)
            out.append(img[..., :3].astype(np.float64))
        imgs[c] = np.stack(out)
    ref = np.mean([v.mean(0) for v in imgs.values()], axis=0)
    base = None
    print(f"{a.scene}, thin lens F {a.fstop} focused at {a.focus}: {a.seeds} seeds x {a.spp} spp")
    for c, v in imgs.items():
        rv = (v.var(0, ddof=1) * a.spp / (ref ** 2 + 1e-2)).mean()
        base = rv if base is None else base
        print(f"light paths {c:g}: relative variance of one sample {rv:.4g} ({base / rv:.2f}x lower than off), "
              f"mean / ref {v.mean() / ref.mean():.4f}")


if __name__ == "__main__":
    main()
