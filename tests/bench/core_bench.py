"""Core renders of a bpy scene for the one-off measurement scripts (not named bench_*: build.py
runs those): the scene exported once with the bench's settings (max bounces 12, no per-type
limit, the 1-pixel box filter, no adaptive sampling) and a render timed in process CPU time."""
import time

import bpy
import numpy as np

from blender_util import load_addon


def export_for_core(scene, threads=1, max_bounces=12):
    """(core module, core scene, RenderSettings) for `scene`, as the bench renders it."""
    addon = load_addon()
    from addon.export import export_scene
    from addon.scene_writer import to_core
    from addon.session import render_settings
    pc = addon.core.get_core()
    scene.render.engine = "PATHLIGHT"
    cs = to_core(pc, export_scene(bpy.context.evaluated_depsgraph_get(), lambda m: None))
    st = render_settings(pc, scene)
    st.adaptive_threshold = 0.0
    st.max_bounces = max_bounces
    st.diffuse_bounces = st.glossy_bounces = st.transmission_bounces = 1024
    st.threads = threads
    st.filter_type, st.filter_width = "box", 1.0
    return pc, cs, st


def render_cpu(pc, cs, st):
    """One render: (RGB float64 image, rays per path, the process's CPU seconds for it)."""
    c = time.process_time()
    sess = pc.Session(cs, st)
    sess.start()
    while not sess.wait(0.2):
        pass
    cpu = time.process_time() - c
    stats = sess.stats()
    return np.asarray(sess.film())[..., :3].astype(np.float64), stats["rays"] / max(stats["paths"], 1), cpu


def override_render_settings(addon, overrides, cast=False):
    """Make the add-on's renders take `overrides` (a dict the caller may change between renders)
    on top of the RenderSettings it builds; `cast` converts each value to the setting's type."""
    inner = addon.session.render_settings

    def patched(pc, scene, warn=None):
        st = inner(pc, scene, warn)
        for k, v in overrides.items():
            setattr(st, k, type(getattr(st, k))(v) if cast else v)
        return st
    addon.session.render_settings = patched


def print_outliers(key, imgs, label, spp, count=6):
    """The brightest single-render pixels of `imgs` (seeds x H x W x 3) over the seeds' median,
    with the region `label` (H x W) each lies in: where a scene's fireflies are."""
    lum = imgs.mean(-1)
    med = np.median(lum, 0)
    dev = (lum - med) / (med + 0.1)
    print(f"{key}: largest single-render outliers (one sample's excess over the median, x spp)")
    for i in np.argsort(dev.ravel())[::-1][:count]:
        s, y, x = np.unravel_index(i, dev.shape)
        print(f"  seed {s:2d} pixel ({y:2d}, {x:2d}) {label[y, x]:16s} {(lum[s, y, x] - med[y, x]) * spp:8.1f}")
