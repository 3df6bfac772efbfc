"""md5 hashes of small core renders on every path tracing kernel, for checking that a change to
trace_path.inl (a speed change) leaves every image bit for bit as it was: run it with the module
before the change (PL_CORE_DIR=<its dir>) and after, and compare the lines.

    .venv/bin/python tests/bench/kernel_hashes.py [--size 32] [--spp 8] [--only NAME ...]

Each line: the render's name, its kernel and the md5 of its film (and of its passes, light
groups or bake result where it has some). The renders: test_kernels.py's scenes on their own
kernel and on the general one, the Cornell fixture (plain, glass, Principled, glass on the
general kernel, clamped, guided), caustic light paths, light-vertex connections, light groups,
a fog box with the light passes, a shadow catcher, sky samples, a Ray Portal, the Hair BSDF
and two bakes."""
import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

here = Path(__file__).resolve().parent
sys.path[:0] = [str(here.parents[0] / "core"), str(here)]
from kernel_scenes import core, cornell_fixture  # noqa: E402

pc = core()
import core_scenes  # noqa: E402

core_scenes.core = lambda: pc  # (the test modules below take the module under test)

ap = argparse.ArgumentParser()
ap.add_argument("--size", type=int, default=32)
ap.add_argument("--spp", type=int, default=8)
ap.add_argument("--only", nargs="*", default=None)
a = ap.parse_args()
W, H = a.size, a.size * 3 // 4

import test_kernels as tk  # noqa: E402
from test_caustic_connections import CONN, shaded_scene  # noqa: E402
from test_caustic_light_paths import mirror_scene  # noqa: E402
from test_core_light_passes import COMPONENTS, mixed_box  # noqa: E402
from test_light_groups import studio  # noqa: E402
from test_ray_portal_core import MIXED, ground_under  # noqa: E402
from test_world_samples import grove  # noqa: E402


def md5(x):
    return hashlib.md5(np.ascontiguousarray(np.asarray(x), dtype=np.float32).tobytes()).hexdigest()[:12]


def run(name, build, passes=(), groups=0, bake=None, **fields):
    if a.only and name not in a.only:
        return
    st = pc.RenderSettings()
    st.width, st.height, st.samples, st.threads, st.seed = W, H, a.spp, 2, 7
    st.passes = list(passes)
    if groups:
        st.light_groups = groups
    for k, v in fields.items():
        setattr(st, k, v)
    scene = build()
    sess = pc.Session(scene, st, bake=bake(scene)) if bake else pc.Session(scene, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    parts = [md5(sess.film())]
    parts += [f"{p}={md5(sess.film_pass(p))}" for p in passes]
    parts += [f"g{i}={md5(sess.film_light_group(i))}" for i in range(groups)]
    print(f"{name:34s} {sess.stats()['kernel']:22s} {' '.join(parts)}", flush=True)


for name, (build, fields, _, _) in tk.CASES.items():
    fields = dict(fields)
    passes = fields.pop("passes", [])
    run(f"kernels/{name}", build, passes, **fields)
    run(f"kernels/{name} (general)", build, passes, force_general_kernel=True, **fields)

run("plain", lambda: cornell_fixture(pc))
run("glass", lambda: cornell_fixture(pc, glass=True))
run("principled", lambda: cornell_fixture(pc, principled=True))
run("glass general", lambda: cornell_fixture(pc, glass=True), force_general_kernel=True)
run("glass clamped", lambda: cornell_fixture(pc, glass=True), clamp_direct=2.0, clamp_indirect=0.5)
run("glass filter glossy", lambda: cornell_fixture(pc, glass=True), filter_glossy=1.0, caustics_refractive=False)
run("guided", lambda: cornell_fixture(pc, glass=True), guiding=True)
run("caustic light paths", lambda: mirror_scene(sun_light=True), caustic_light_paths=1.0)
run("light-vertex connections", shaded_scene, **CONN)
run("light groups", studio, groups=4)
run("light groups general", studio, groups=4, force_general_kernel=True)
run("fog box light passes", mixed_box, passes=COMPONENTS + ["Emit", "Env"])
run("fog box", mixed_box)
run("shadow catcher", lambda: tk.flagged_cornell(shadow_catcher=True), passes=["Shadow Catcher"])
# Paths through the kernels' rarer branches: sky samples and a Ray Portal, a sky alone, the
# Hair BSDF (its sampled value), and both again on the general kernel.
run("portal under a sky", lambda: ground_under(MIXED))
run("portal under a sky general", lambda: ground_under(MIXED), force_general_kernel=True)
run("grove under a sky", lambda: grove(False, True))
run("hair cards", lambda: tk.with_sphere(lambda s: s.add_shader("hair", [
    ("const", 0, (0.8, 0.6, 0.4)), ("const", 1, (0.0,)), ("const", 2, (0.3,)), ("const", 3, (0.2,)),
    ("closure", "hair_reflection", None, {"color": 0, "offset": 1, "roughness_u": 2, "roughness_v": 3})]))())
run("hair cards general", lambda: tk.with_sphere(lambda s: s.add_shader("hair", [
    ("const", 0, (0.8, 0.6, 0.4)), ("const", 1, (0.0,)), ("const", 2, (0.3,)), ("const", 3, (0.2,)),
    ("closure", "hair_reflection", None, {"color": 0, "offset": 1, "roughness_u": 2, "roughness_v": 3})]))(),
    force_general_kernel=True)


def bake_floor(scene):
    """Texels on the fixture's floor (instance 0, two triangles) at fixed barycentrics."""
    rng = np.random.default_rng(5)
    b = rng.random((W * H, 2)).astype(np.float32)
    flip = b.sum(axis=1) > 1.0
    b[flip] = 1.0 - b[flip]
    return {"instance": 0, "triangle": rng.integers(0, 2, W * H).astype(np.int32), "bary": b, "mode": "surface"}


run("bake", lambda: cornell_fixture(pc, glass=True), bake=bake_floor)
run("bake passes", lambda: cornell_fixture(pc, glass=True), passes=["Normal"], bake=bake_floor)
