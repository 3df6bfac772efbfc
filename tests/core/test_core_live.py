"""The core's live edits (issue 8): camera override per session, material and light
replacement on a committed scene without a BVH rebuild."""

import numpy as np
import pytest

from core_scenes import camera, core, cornell, look_at_matrix

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif(not hasattr(pc.Scene, "set_shader"), reason="core without live edits")]


def _render(scene, samples=2, size=16, **kw):
    st = pc.RenderSettings()
    st.width = st.height = size
    st.samples, st.seed, st.threads = samples, 1, 2
    sess = pc.Session(scene, st, **kw)
    sess.start()
    while not sess.wait(1.0):
        pass
    return sess.film()


def test_camera_override_equals_setting_the_camera():
    scene = cornell(pc)
    other = camera(pc, (0.3, -0.9, 1.2), (0.0, 1.0, 0.8))
    over = _render(scene, camera=other)
    assert scene.stats()["geometry_builds"] == 1
    base = _render(scene)
    assert not np.allclose(over, base)  # the override is used, the scene's camera is kept
    scene.set_camera(other)  # allowed on a committed scene: no rebuild
    np.testing.assert_array_equal(_render(scene), over)
    assert scene.stats()["geometry_builds"] == 1
    bad = pc.Camera()
    bad.lens = -1.0
    with pytest.raises(ValueError):
        _render(scene, camera=bad)


def test_material_and_light_edits_keep_the_bvh():
    scene = pc.Scene()
    grey = scene.add_material("grey", base_color=(0.8, 0.8, 0.8))
    pos = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], np.float32)
    scene.add_mesh(pos, np.array([[0, 1, 2], [0, 2, 3]]), material_slots=[grey])
    scene.add_instance(0, np.eye(4, dtype=np.float32))
    scene.add_point_light((0.0, 0.0, 2.0), (10.0, 10.0, 10.0))
    cam = pc.Camera()
    cam.matrix_world = look_at_matrix((0.0, -4.0, 4.0), (0.0, 0.0, 0.0))
    scene.set_camera(cam)
    lit = _render(scene)
    assert scene.stats()["geometry_builds"] == 1 and scene.stats()["light_builds"] == 1

    scene.set_material(grey, "red", base_color=(0.8, 0.0, 0.0))
    red = _render(scene)
    assert scene.stats()["geometry_builds"] == 1 and scene.stats()["light_builds"] == 2
    assert red[..., 1].max() == 0.0 and red[..., 0].mean() == pytest.approx(lit[..., 0].mean(), rel=1e-3)

    # An emissive replacement becomes a light: the light distribution is rebuilt for it.
    scene.clear_lights()
    scene.set_shader(grey, "glow", [("const", 0, (1.0, 1.0, 1.0, 1.0)), ("closure", "emission", 0, {"color": 0})])
    glow = _render(scene)
    assert scene.stats()["lights"] == 0 and scene.stats()["emissive_triangles"] == 2
    assert scene.stats()["geometry_builds"] == 1
    np.testing.assert_allclose(glow[..., :3], 1.0, rtol=1e-5)  # the view sees only the plane

    with pytest.raises(ValueError):
        scene.set_material(0, "default")  # the fallback material stays
    with pytest.raises(ValueError):
        scene.set_material(99, "nothing")
    with pytest.raises(ValueError):
        scene.set_shader(grey, "bad", [("closure", "nope", 0, {})])


def test_commit_rebuilds_geometry_only_for_a_new_bvh_kind():
    scene = cornell(pc)
    scene.commit(bvh="binary")
    n = scene.stats()["geometry_builds"]
    scene.commit(bvh="binary")  # nothing changed: the lights only
    assert scene.stats()["geometry_builds"] == n
    scene.commit(bvh="bvh4")  # another kernel: the geometry is rebuilt for it
    assert scene.stats()["geometry_builds"] == n + 1
    hits = scene.intersect(np.array([[0.0, -3.0, 1.0]], np.float32), np.array([[0.0, 1.0, 0.0]], np.float32))
    assert hits[0][0] > 0  # a usable scene after the switch
