"""Procedural texture and scene-input ops through the core module, with ordinary and hostile
operands (NaN, infinities, huge scales, zero and negative parameters): every pixel stays finite
and the ops' parsers refuse bad settings. Their agreement with Cycles is tested through Blender
(tests/test_textures_*.py, tests/blender/test_scene_inputs.py); this file runs on the sanitizer build."""
import itertools
import math

import numpy as np
import pytest

from core_scenes import add_object, camera, core, render, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run

# Constants that are not finite become 0 when the program is added: the hostile operands are
# huge, tiny, zero and negative ones (and what they make of the position).
VALUES = [0.0, 1.0, 5.5, -3.0, 1e30, -1e30, 3e38, -7.0, 1e-30, 1e6]


def emit_program(op_name, n_regs, settings):
    """position -> op(n_regs operands: the position then constants) -> emission."""
    prog = [("position", 0)]
    regs = [0]
    for k in range(1, n_regs):
        prog.append(("const", k, (VALUES[k % len(VALUES)],)))
        regs.append(k)
    prog.append((op_name, 20, *regs, *settings))
    prog.append(("closure", "emission", None, {"color": 20}))
    return prog


def render_program(prog, values=None):
    s = pc.Scene()
    m = s.add_shader("t", prog)
    pos, tris, _ = uv_sphere(1.0, nu=16, nv=8)
    add_object(s, pos * 3.7, tris, m)
    s.set_world_color((0.0, 0.0, 0.0))
    s.set_camera(camera(pc, (0, -12, 0), (0, 0, 0), lens=50.0))
    img, stats = render(pc, s, 8, 8, samples=1, max_bounces=1)
    return img, stats


TEXTURES = [
    ("tex_noise", 9, [dims, kind, norm, color])
    for dims, kind, norm, color in itertools.product(
        (1, 2, 3, 4), ("FBM", "MULTIFRACTAL", "HYBRID_MULTIFRACTAL", "RIDGED_MULTIFRACTAL", "HETERO_TERRAIN"),
        (False, True), (False, True))
] + [
    ("tex_wave", 7, [kind, direction, profile])
    for kind, dirs in (("BANDS", ("X", "Y", "Z", "DIAGONAL")), ("RINGS", ("X", "Y", "Z", "SPHERICAL")))
    for direction in dirs for profile in ("SIN", "SAW", "TRI")
] + [
    ("tex_magic", 3, [depth, color]) for depth in (0, 3, 10) for color in (False, True)
] + [
    ("tex_white_noise", 2, [dims, color]) for dims in (1, 2, 3, 4) for color in (False, True)
] + [
    ("checker", 4, [out]) for out in ("COLOR", "FAC")
] + [
    ("gradient", 1, [kind]) for kind in ("LINEAR", "QUADRATIC", "EASING", "DIAGONAL", "SPHERICAL",
                                         "QUADRATIC_SPHERE", "RADIAL")
] + [
    ("brick", 10, [0.5, 2, 1.0, 1, out]) for out in ("COLOR", "FAC")
] + [
    ("wireframe", 1, [pixels]) for pixels in (False, True)
] + [
    ("bevel", 2, [samples]) for samples in (0, 1, 8)
] + [
    ("voronoi", 9, [dims, feature, metric, norm, out])
    for dims in ("1D", "2D", "3D", "4D")
    for feature in ("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE", "N_SPHERE_RADIUS")
    for metric in ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI")
    for norm in (False, True)
    for out in ("DISTANCE", "COLOR", "POSITION", "W", "RADIUS")
    if (out != "W" or dims in ("1D", "4D")) and (metric == "EUCLIDEAN" or feature in ("F1", "SMOOTH_F1"))
]


@pytest.mark.parametrize("shift", [0, 5])
def test_texture_ops_stay_finite_for_any_operands(shift):
    """Each texture op with its operands drawn from VALUES (rotated by `shift`): finite output."""
    global VALUES
    saved = VALUES
    VALUES = saved[shift:] + saved[:shift]
    try:
        for name, n_regs, settings in TEXTURES:
            img, stats = render_program(emit_program(name, n_regs, settings))
            assert stats["nonfinite_samples"] == 0, (name, settings)
            assert np.isfinite(img).all(), (name, settings)
    finally:
        VALUES = saved


def test_texture_ops_vary_over_the_surface():
    """Sane operands give a pattern, not a constant (the ops read the position)."""
    prog = [("position", 0), ("const", 1, (4.0,)), ("const", 2, (2.0,)), ("const", 3, (0.5,)),
            ("const", 4, (2.0,)), ("const", 5, (1.0,)),
            ("tex_noise", 6, 0, None, 1, 2, 3, 4, None, None, None, 3, "FBM", True, False),
            ("voronoi", 7, 0, None, 1, 2, 3, 4, 5, 5, 5, "3D", "F1", "EUCLIDEAN", False, "DISTANCE"),
            ("math", 8, 6, 7, "ADD", False),
            ("closure", "emission", None, {"color": 8})]
    img, stats = render_program(prog)
    assert stats["nonfinite_samples"] == 0
    centre = img[2:6, 2:6, 0]
    assert centre.std() > 0.02, centre


@pytest.mark.parametrize("op", [
    ("tex_noise", 1, 0, None, None, None, None, None, None, None, None, 5, "FBM", False, False),
    ("tex_noise", 1, 0, None, None, None, None, None, None, None, None, 3, "PERLIN", False, False),
    ("tex_wave", 1, 0, None, None, None, None, None, None, "BANDS", "SPHERICAL", "SIN"),
    ("tex_magic", 1, 0, None, None, 11, False),
    ("gradient", 1, 0, "CONICAL"),
    ("brick", 1, 0, None, None, None, None, None, None, None, None, None, 0.5, 0, 1.0, 1, "COLOR"),
    ("voronoi", 1, 0, None, None, None, None, None, None, None, None, "5D", "F1", "EUCLIDEAN", False,
     "DISTANCE"),
    ("light_path", 1, "IS_PORTAL_RAY"),
    ("geometry", 1, "POINTINESS"),
    ("object_info", 1, "NAME"),
    ("attribute", 1, 8, "COLOR"),
    ("bevel", 1, 0, None, 500),
    ("wireframe", 1, 0, False, 3),
])
def test_bad_op_settings_are_refused(op):
    s = pc.Scene()
    with pytest.raises((ValueError, TypeError)):
        s.add_shader("bad", [("position", 0), op, ("closure", "emission", None, {"color": 1})])


def test_scene_input_ops_without_their_data_read_defaults():
    """Object Info, attributes and Light Path on a mesh with no attributes and a default
    instance: finite, and the defaults (white colour, index 0, attribute 0, a camera ray)."""
    outputs = [("object_info", "COLOR"), ("object_info", "RANDOM"), ("object_info", "LOCATION"),
               ("attribute", 3, "COLOR"), ("attribute", 0, "ALPHA"),
               ("light_path", "IS_CAMERA_RAY"), ("light_path", "RAY_DEPTH"),
               ("geometry", "BACKFACING"), ("geometry", "PARAMETRIC")]
    expect = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, None]
    for (name, *args), want in zip(outputs, expect):
        img, stats = render_program([(name, 0, *args), ("closure", "emission", None, {"color": 0})])
        assert stats["nonfinite_samples"] == 0
        hit = img[3:5, 3:5, 0]
        if want is not None:
            assert np.allclose(hit, want, atol=1e-6), (name, args, hit)
