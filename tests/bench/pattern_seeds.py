"""pytest plugin (issue 25, docs/design/sampling.md "Blue noise as the default: is it sound?"):
renders the first Pathlight render of each test that asks for at least MEAS_MIN samples over
MEAS_SEEDS seeds and MEAS_PATTERNS Noise Patterns, and saves the images with the test's Cycles
render to MEAS_OUT/<test>.npz ("<PATTERN>_<seed>" and "cycles"), for region factors, pixel
variance and pass rates by seed. The test then goes on with its own render (Independent Pixels,
the last seed) and checks. Usage:

    MEAS_SEEDS=0,1,2,3 MEAS_OUT=/tmp/out PYTHONPATH=tests/bench python3 build.py test -- \
        -q -p no:cacheprovider -p pattern_seeds -s "tests/blender/test_hair.py::test_huang_ellipse_needs_the_curve_normals"

MEAS_SPP renders at that many samples instead of the test's (cheaper seeds, same scene).
"""
import os
import re
import sys
import time

import numpy as np
import pytest

SEEDS = [int(s) for s in os.environ.get("MEAS_SEEDS", "0,1,2,3").split(",")]
MIN = int(os.environ.get("MEAS_MIN", "256"))
PATTERNS = os.environ.get("MEAS_PATTERNS", "INDEPENDENT,BLUE_NOISE").split(",")
OUT = os.environ.get("MEAS_OUT", "/tmp")
SPP = int(os.environ.get("MEAS_SPP", "0"))
state = {}


def _wrap(orig):
    def render_to_array(scene=None, engine="PATHLIGHT", **overrides):
        if engine == "CYCLES":
            img = orig(scene, engine, **overrides)
            state.setdefault("cycles", img)
            return img
        if state.get("done") or overrides.get("samples", 0) < MIN:
            return orig(scene, engine, **overrides)
        state["done"] = True
        imgs = {}
        for p in PATTERNS:
            for s in SEEDS:
                t = time.time()
                imgs[(p, s)] = orig(scene, engine, **dict(overrides, seed=s, pixel_pattern=p, **({"samples": SPP} if SPP else {})))
                print(f"[pattern_seeds] {state['name']} {p} seed {s}: {time.time() - t:.1f} s", file=sys.stderr, flush=True)
        state["imgs"], state["samples"] = imgs, SPP or overrides.get("samples")
        return orig(scene, engine, **dict(overrides, pixel_pattern='INDEPENDENT'))
    return render_to_array


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    import blender_util
    orig = blender_util.render_to_array
    w = _wrap(orig)
    patched = [m for m in list(sys.modules.values()) if getattr(m, "render_to_array", None) is orig]
    for m in patched:  # (test modules and material_scenes import it by name)
        m.render_to_array = w
    state.clear()
    state["name"] = re.sub(r"[^A-Za-z0-9_.-]", "_", item.nodeid.split("::", 1)[1])
    try:
        yield
    finally:
        for m in patched:
            m.render_to_array = orig
        if "imgs" in state:
            arr = {f"{p}_{s}": v for (p, s), v in state["imgs"].items()}
            if "cycles" in state:
                arr["cycles"] = state["cycles"]
            np.savez_compressed(f"{OUT}/{state['name']}.npz", samples=state["samples"], **arr)
