"""Light-vertex connections (RenderSettings.caustic_connections, issue 25): the caustic light
paths keep their rough vertex y in a per-sample cache, and a camera path's first rough vertices
x connect to one of them, for the caustics seen after further rough bounces (L S+ D D+ E),
weighed by the power heuristic against the path tracer's own way to make those paths
(docs/design/sampling.md, "Caustics seen after further rough bounces"). The scene: a tall glossy
panel (roughness 0.27: still the light paths' smooth class) under a low sun lamp of 10 degrees
reflects it onto a floor under a black shade; the camera sees only a grey ceiling under the
shade, lit by that floor: nearly all of the image is L S D D+ E, and none of it L S D E."""
import numpy as np
import pytest

from core_scenes import add_object, camera, closure, core, quad, render, uv_sphere
from test_caustic_light_paths import GUIDED, assert_same_within_noise, renders

pc = core()


def shaded_scene(roughness=0.27, angle=10.0):
    s = pc.Scene()
    grey = s.add_material("grey", (0.7, 0.7, 0.7))
    black = s.add_material("black", (0.0, 0.0, 0.0))
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 3, 0)), grey)  # the floor under the shade
    add_object(s, *quad((-3, 0, 0), (6, 0, 0), (0, 3, 0)), black)  # the sunlit floor: no light from it
    add_object(s, *quad((-3, -3, 2.0), (0, 3, 0), (6, 0, 0)), black)  # the shade, facing down
    add_object(s, *quad((-2, -2.8, 1.9), (0, 2.6, 0), (4, 0, 0)), grey)  # the ceiling in view
    m = s.add_shader("chrome", closure("glossy", color=(0.95, 0.95, 0.95), roughness=roughness))
    add_object(s, *quad((-1.0, 2.0, 0.0), (0.0, 0.0, 3.0), (2.0, 0.0, 0.0)), m)  # facing -y
    s.set_world_color((0.0, 0.0, 0.0))
    s.add_sun_light((0.05, -0.866, 0.5), (1.0, 1.0, 1.0), angle=np.radians(angle))
    s.set_camera(camera(pc, (0.0, -0.3, 0.4), (0.0, -1.6, 1.9), lens=30.0))
    s.commit()
    return s


CONN = dict(caustic_light_paths=0.5, caustic_connections=2)


@pytest.fixture(scope="module")
def shaded_renders():
    s = shaded_scene()
    plain, _ = renders(s, 256, (1, 2, 3))
    conn, st = renders(s, 64, (1, 2, 3), **CONN)
    return plain, conn, st


def per_sample_variance(imgs, spp):
    return imgs.var(0, ddof=1).mean() * spp / imgs.mean() ** 2


def test_converged_image_equals_the_path_tracers_within_noise(shaded_renders):
    plain, conn, st = shaded_renders
    assert st["caustics"] == "on"
    assert_same_within_noise(plain, conn)


def test_connections_lower_the_variance(shaded_renders):
    # Measured per sample: plain 14.6 (the light paths alone change nothing here: no L S D E in
    # view), with connections 2.1.
    plain, conn, _ = shaded_renders
    assert per_sample_variance(conn, 64) < 0.3 * per_sample_variance(plain, 256)


def test_weights_sum_to_one():
    # The ceiling's light split between the path tracer's BSDF ray and light sample and the
    # connection, by the densities both sides compute: with connections off the path tracer
    # makes all of it; with few (0.03 per sample) or many (3) light paths, at the first 2 or at
    # every rough vertex, the connections take most. The means agree only if each path's
    # weights sum to 1 and the connection's value is right. Measured: few 0.996, many 0.999
    # (the seeds' spread ~0.3 % each).
    s = shaded_scene()
    off, _ = renders(s, 256, (5, 6, 7, 8), caustic_light_paths=0.5)
    few, _ = renders(s, 128, (5, 6, 7, 8), caustic_light_paths=0.03, caustic_connections=2)
    many, _ = renders(s, 32, (5, 6, 7, 8), caustic_light_paths=3.0, caustic_connections=8)
    assert abs(few.mean() / off.mean() - 1.0) < 0.02
    assert abs(many.mean() / off.mean() - 1.0) < 0.02


def corner_scene():
    """shaded_scene's floor, shade and panel with a grey wall across the floor under the shade;
    the camera looks along the floor at the wall's foot. There a connection from the wall to the
    lit floor beside it is short (d^2 small), so the path tracer's BSDF ray from the wall finds
    the floor as readily as the connection does: the two strategies share the weight."""
    s = pc.Scene()
    grey = s.add_material("grey", (0.7, 0.7, 0.7))
    black = s.add_material("black", (0.0, 0.0, 0.0))
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 3, 0)), grey)
    add_object(s, *quad((-3, 0, 0), (6, 0, 0), (0, 3, 0)), black)
    add_object(s, *quad((-3, -3, 2.0), (0, 3, 0), (6, 0, 0)), black)
    add_object(s, *quad((-3, -1.5, 0), (0, 0, 2.0), (6, 0, 0)), grey)  # the wall, facing +y
    m = s.add_shader("chrome", closure("glossy", color=(0.95, 0.95, 0.95), roughness=0.27))
    add_object(s, *quad((-1.0, 2.0, 0.0), (0.0, 0.0, 3.0), (2.0, 0.0, 0.0)), m)
    s.set_world_color((0.0, 0.0, 0.0))
    s.add_sun_light((0.05, -0.866, 0.5), (1.0, 1.0, 1.0), angle=np.radians(10.0))
    s.set_camera(camera(pc, (0.0, -0.9, 0.1), (0.0, -1.5, 0.1), lens=80.0))
    s.commit()
    return s


def test_shared_weights_sum_to_one():
    # Where the strategies share the weight, a wrong density on either side shows: measured
    # 0.9989 of the image without connections; with the connection's own heuristic density x 2
    # (its weight alone raised) 1.017, which the shaded scene above cannot see (there the
    # connection takes nearly all the weight). The seeds' spread: ~0.3 % each.
    s = corner_scene()
    off, _ = renders(s, 128, range(5, 13), caustic_light_paths=0.5)
    conn, st = renders(s, 128, range(5, 13), **CONN)
    assert st["caustic_connections"] == 2
    assert abs(conn.mean() / off.mean() - 1.0) < 0.012


def test_guided_connections_equal_the_unguided(shaded_renders):
    plain, _, _ = shaded_renders
    g, st = renders(shaded_scene(), 64, (1, 2, 3), **CONN, **GUIDED)
    assert st["caustics"] == "on" and "+guiding+caustics" in st["kernel"] and st["guiding_iterations"] > 0
    assert_same_within_noise(plain, g)


@pytest.mark.sanitize
def test_deterministic_whatever_the_threads_and_tiles():
    s = shaded_scene()
    for extra in (dict(), GUIDED):
        kw = dict(samples=8, seed=9, **CONN, **extra)
        a, st = render(pc, s, 40, 24, threads=1, tile_size=8, **kw)
        b, _ = render(pc, s, 40, 24, threads=2, tile_size=16, **kw)
        assert st["caustics"] == "on"
        assert np.array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.sanitize
def test_off_leaves_the_image_as_it_was():
    # Connections 0: the light paths' image, bit for bit; connections without light paths: plain.
    s = shaded_scene()
    kw = dict(samples=4, seed=2)
    lt, _ = render(pc, s, 24, 16, caustic_light_paths=0.5, **kw)
    lt0, _ = render(pc, s, 24, 16, caustic_light_paths=0.5, caustic_connections=0, **kw)
    plain, _ = render(pc, s, 24, 16, **kw)
    plain_c, st = render(pc, s, 24, 16, caustic_connections=2, **kw)
    assert np.array_equal(np.asarray(lt), np.asarray(lt0))
    assert np.array_equal(np.asarray(plain), np.asarray(plain_c)) and st["caustics"] == ""
    assert st["caustic_connections"] == 0
    on, st_on = render(pc, s, 24, 16, caustic_light_paths=0.5, caustic_connections=2, **kw)
    assert not np.array_equal(np.asarray(lt), np.asarray(on)) and st_on["caustic_connections"] == 2
