"""Hashes of small renders of the realistic bench scenes and the lamp-lit scenes with the add-on's
own settings (Automatic caustic light paths and all), for checking that a change to the automatic
rule leaves a scene's image bit for bit as it was (issue 25). Run it with the old module
(PL_CORE_DIR=<old build dir>) and the new one and compare the lines.

    .venv/bin/python tests/bench/auto_caustics_hashes.py [--size 48] [--spp 4]"""
import argparse
import hashlib
import sys
from pathlib import Path

import bpy
import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("core", "blender")]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from blender_util import load_addon  # noqa: E402
from kernel_scenes import core  # noqa: E402
import lamp_glass_scenes as lg  # noqa: E402
import realistic_scenes as rs  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--size", type=int, default=48)
ap.add_argument("--spp", type=int, default=4)
a = ap.parse_args()
pc = core()
sys.modules.setdefault("addon.pathlight_core", pc)
load_addon()
from addon.export import export_scene  # noqa: E402
from addon.scene_writer import to_core  # noqa: E402
from addon.session import render_settings  # noqa: E402

builders = [getattr(rs, n) for n in ("window_room", "window_room_portal", "lamp_room", "hdri_model",
                                     "principled_spheres", "instanced_forest")]
builders += [lg.product_glossy, lg.sun_interior, lg.product_shot, lg.sun_interior_offscreen]
for build in builders:
    scene = build(a.size, a.size * 3 // 4)
    scene.render.engine = "PATHLIGHT"
    data = export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None)
    cs = to_core(pc, data)
    cs.commit()
    st = render_settings(pc, scene)  # the add-on's defaults: Automatic on
    st.samples, st.seed, st.adaptive_threshold = a.spp, 1, 0.0
    sess = pc.Session(cs, st)
    sess.start()
    while not sess.wait(1.0):
        pass
    img = np.ascontiguousarray(np.asarray(sess.film()), dtype=np.float32)
    print(f"{build.__name__:24s} {hashlib.sha256(img.tobytes()).hexdigest()[:16]} {sess.stats()['caustics']}",
          flush=True)
