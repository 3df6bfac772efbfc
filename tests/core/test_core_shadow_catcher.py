"""Shadow catchers and holdout objects through the module (Cycles' shadow catcher split and
passes, core/render/integrator.h PathAovs), on a catcher floor lit by a sun, with and without a
box that shadows it. Cycles comparisons: tests/blender/test_shadow_catcher.py."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, run_session

pc = core()
pytestmark = [pytest.mark.sanitize,
              pytest.mark.skipif("Shadow Catcher" not in pc.render_passes(), reason="core without shadow catchers")]


def scene(caster=True, holdout=False, catcher=True):
    s = pc.Scene()
    grey = s.add_material("grey", (0.5, 0.5, 0.5))
    pos, tris = quad((-4, -4, 0), (8, 0, 0), (0, 8, 0))  # the floor z = 0
    s.add_instance(s.add_mesh(pos, tris, None, None, [grey]), np.eye(4, dtype=np.float32), shadow_catcher=catcher)
    if caster:  # a slab above the middle; the sun's slant casts its shadow beside it
        pos, tris = quad((-0.5, -0.5, 1.0), (1, 0, 0), (0, 1, 0))
        s.add_instance(s.add_mesh(pos, tris, None, None, [grey]), np.eye(4, dtype=np.float32), holdout=holdout)
    s.add_sun_light(SUN, (3.0, 3.0, 3.0), 0.0)
    s.set_world_color((0.2, 0.2, 0.2))
    s.set_camera(camera(pc, (0.0, 0.0, 6.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)))
    s.commit()
    return s


SUN = (-1.2, 0.0, 1.0)  # towards the sun


def session(s, **kw):
    return run_session(pc, s, 16, 16, 8, threads=2, **kw)


def test_no_caster_is_identity():
    sess = session(scene(caster=False), film_transparent=True, passes=["Shadow Catcher"])
    np.testing.assert_allclose(sess.film_pass("Shadow Catcher"), 1.0, atol=1e-6)
    matte = sess.film_pass("Shadow Catcher Matte")
    np.testing.assert_allclose(matte, 0.0, atol=1e-6)  # nothing but the catcher: transparent, black
    np.testing.assert_allclose(session(scene(caster=False), film_transparent=True).film(), 0.0, atol=1e-6)
    assert np.all(sess.film_pass("Shadow Catcher Sample Count") == 1.0)


def test_shadow_beside_the_caster():
    sess = session(scene(), film_transparent=True, passes=["Shadow Catcher"])
    sc = sess.film_pass("Shadow Catcher").mean(-1)
    alpha = sess.film_pass("Shadow Catcher Matte")[..., 3]
    assert alpha[8, 8] == 1.0 and alpha[0, 0] == 0.0  # the slab is the matte's, the floor is not
    floor = alpha == 0.0
    # In the shadow only the world lights the floor: pi W / (E cos + pi W) = 0.628 / (1.92 + 0.628)
    # = 0.246 (W = 0.2, E = 3, cos = 1 / sqrt(1 + 1.2^2)), a little less where the slab hides sky.
    # Elsewhere 1, or a little more where the slab's underside lights the floor back.
    assert 0.2 < sc[floor].min() < 0.25 and abs(np.median(sc[floor]) - 1.0) < 1e-4 and sc[floor].max() < 1.05
    assert (sc[floor] < 0.5).sum() >= 4


def test_approximate_alpha_is_the_shadow():
    # The sun a little tilted: the slab's shadow falls beside it, where the camera sees the floor.
    s = scene()
    sess = session(s, film_transparent=True, passes=["Shadow Catcher"])
    sc = sess.film_pass("Shadow Catcher").mean(-1)
    alpha_matte = sess.film_pass("Shadow Catcher Matte")[..., 3]
    approx = session(s, film_transparent=True).film()
    floor = alpha_matte == 0.0
    np.testing.assert_allclose(approx[..., 3][floor], np.clip(1.0 - sc[floor], 0, 1), atol=1e-5)


def test_opaque_film_composites_over_the_world():
    s = scene(caster=False)
    img = session(s).film()
    # No shadow anywhere: the world behind the catcher, alpha 1.
    np.testing.assert_allclose(img[..., :3], 0.2, atol=1e-5)
    np.testing.assert_allclose(img[..., 3], 1.0, atol=1e-6)


def test_holdout_object():
    s = scene(holdout=True, catcher=False)
    img = session(s).film()
    assert img[8, 8, 3] == 0.0 and np.all(img[8, 8, :3] == 0.0)  # the slab: transparent, no colour
    assert img[0, 0, 3] == 1.0


def test_curves_and_points_as_holdouts_and_catchers():
    # A strand and a sphere held out over a plain floor: transparent where the camera sees them.
    s = scene(caster=False, catcher=False)
    grey = 0
    s.add_curves(np.array([(-3.0, 1.0, 1.0), (3.0, 1.0, 1.0)], np.float32), np.array([0, 2]),
                 np.full(2, 0.4, np.float32), grey, curve_type="poly", holdout=True)
    s.add_points(np.array([(0.0, -1.0, 1.0)], np.float32), np.full(1, 0.5, np.float32), grey, holdout=True)
    img = session(s).film()
    assert img[12, 8, 3] == 0.0 and img[3, 8, 3] == 0.0  # (rows count from the bottom)
    assert img[8, 8, 3] == 1.0 and img[8, 8, :3].min() > 0.0  # the floor between them
    # The same sphere as a shadow catcher under the slab: the matte leaves it transparent and the
    # pass sees the slab's shadow on it (the sun is off to -x: the shadow falls to its +x side).
    s = scene(catcher=False)
    s.add_points(np.array([(1.3, 0.0, 0.0)], np.float32), np.full(1, 0.6, np.float32), grey, shadow_catcher=True)
    sess = session(s, film_transparent=True, passes=["Shadow Catcher"])
    alpha = sess.film_pass("Shadow Catcher Matte")[..., 3]
    on_sphere = alpha == 0.0
    assert on_sphere.sum() >= 4 and alpha[0, 0] == 1.0  # the sphere; the plain floor
    assert sess.film_pass("Shadow Catcher").mean(-1)[on_sphere].min() < 0.5
