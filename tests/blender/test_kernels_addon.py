"""The add-on's render log names the integrator kernel and the features it was chosen from
(issue 6), and the debug switch renders the same image with the general kernel."""
import logging

import numpy as np
import pytest

from blender_util import core_available, load_addon, open_fixture, render_to_array

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def kernel_lines(caplog):
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith("Pathlight: kernel ")]


def test_render_log_names_the_kernel_and_features(caplog):
    scene = open_fixture("cornell_box")
    with caplog.at_level(logging.INFO, logger="addon.session"):
        img = render_to_array(scene, "PATHLIGHT", samples=4, resolution_percentage=12)
    assert img[..., :3].mean() > 0.0
    lines = kernel_lines(caplog)
    assert len(lines) == 1, lines
    line = lines[0]
    used, unused = line.split("(uses ")[1].rstrip(")").split("; without ")
    assert line.startswith("Pathlight: kernel diffuse (")
    # (the box's sphere is smooth-shaded: Cycles' shadow terminator offset applies to it)
    assert set(used.split(", ")) == {"diffuse", "mesh lights", "shadow terminator"}
    for absent in ("glass", "textures", "environment", "dof", "passes", "transparent film"):
        assert absent in unused.split(", ")


def test_general_kernel_switch_renders_the_same_image(caplog):
    images = []
    for general in (False, True):
        scene = open_fixture("cornell_box")
        scene.pathlight.use_general_kernel = general
        with caplog.at_level(logging.INFO, logger="addon.session"):
            images.append(render_to_array(scene, "PATHLIGHT", samples=4, resolution_percentage=12, seed=3))
    assert kernel_lines(caplog)[-1].startswith("Pathlight: kernel general (")
    assert np.array_equal(images[0], images[1])
