"""Caustic light paths with motion blur and panoramic cameras (issue 25; integrator_caustics.cpp,
trace_path.inl, Camera::pano_view; docs/design/sampling.md "Caustic light paths with motion blur
and panoramic cameras"). A light path draws a shutter time as the camera rays do, traces the
scene then and connects to the camera's frame then; a pinhole panorama's connection inverts its
map (direction -> raster) and takes its pixel density per unit solid angle (the map's Jacobian),
on both sides of the MIS. The image agrees with the plain path tracer's within its noise, with
less of it; few or many light paths give the same image (the densities agree); deterministic."""
import numpy as np
import pytest

from core_scenes import add_object, closure, core, quad, uv_sphere
# (the caustic tests' scenes, cameras, seeds' renders and their converged check)
from test_caustic_light_paths import (LAMP_CAM, PANEL_CAM, assert_same_within_noise, lens_renders, lensed,
                                      mirror_scene, shaded_panel_scene, sun_env)

pc = core()
W, H = 48, 36


def affine(linear, shift):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = linear, shift
    return m.astype(np.float32)


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def moving(cam, turn=0.08, shift=0.25, dolly=0.0, ks=(-1.0, 0.0, 1.0)):
    """The camera turning by k turn radians about the world's z axis, sliding k shift along x and
    k dolly along its view axis at its motion steps k in ks (the default: about the still frame,
    a centred shutter; (0, 0.5, 1): from it, as a shutter that opens on the frame)."""
    m = np.asarray(cam.matrix_world, np.float64)
    fwd = -m[:3, 2]
    cam.motion = np.stack([affine(rot_z(k * turn) @ m[:3, :3], rot_z(k * turn) @ (m[:3, 3] + k * dolly * fwd) +
                                  (k * shift, 0.0, 0.0)) for k in ks])
    return cam


def moving_casters_scene():
    """mirror_scene's floor, chrome ball and tilted chrome panel under its sun environment, the ball
    sliding +-0.3 along x and the panel turning +-0.25 rad over the shutter (object motion)."""
    s = pc.Scene()
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), s.add_material("floor", (0.7, 0.7, 0.7)))
    m = s.add_shader("chrome", closure("glossy", color=(0.95, 0.95, 0.95), roughness=0.05))
    pos, tris, nrm = uv_sphere(0.4)
    slide = np.stack([affine(np.eye(3), (-0.6 + dx, 0.3, 0.4)) for dx in (-0.3, 0.0, 0.3)])
    s.add_instance(s.add_mesh(pos, tris, nrm, None, [m]), slide[1], motion=slide)
    turn = np.stack([affine(rot_z(a), (0.8, 1.2, 0.0)) for a in (-0.25, 0.0, 0.25)])
    s.add_instance(s.add_mesh(*quad((-0.5, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.3, 1.0)), None, None, [m]), turn[1],
                   motion=turn)
    s.set_world_texture(sun_env())
    s.commit()
    return s


def pano(view, kind, **kw):
    """A pinhole panorama of `kind` where view's camera is (Cycles' panorama space: its x is the
    camera's view axis, its z the camera's up)."""
    cam = lensed(view, 3.0, aperture=0.0)
    cam.type, cam.panorama_type = "PANO", kind
    for k, v in kw.items():
        setattr(cam, k, v)
    return cam


def glass_scene(slide=0.0, angle=4.0):
    """test_caustic_glass.py's floor and smooth glass ball (IOR 1.45) under a sun lamp of `angle`
    degrees (its mirror panel left out): the ball's focused caustic on the floor. slide: the ball
    moving +-slide along x over the shutter."""
    s = pc.Scene()
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), s.add_material("floor", (0.7, 0.7, 0.7)))
    g = s.add_shader("glass", closure("glass", color=(0.98, 0.98, 0.98), roughness=0.0, ior=1.45))
    pos, tris, nrm = uv_sphere(0.4)
    steps = np.stack([affine(np.eye(3), (dx, 0.3, 0.45)) for dx in (-slide, 0.0, slide)])
    s.add_instance(s.add_mesh(pos, tris, nrm, None, [g]), steps[1], motion=steps if slide else None)
    s.set_world_color((0.03, 0.03, 0.04))
    s.add_sun_light((0.25, 0.55, 0.8), (3.0, 3.0, 3.0), angle=np.radians(angle))
    s.commit()
    return s


GLASS_CAM = ((0.0, -2.2, 2.4), (0.0, 0.1, 0.0), 35.0, (0.0, 0.0, 1.0))  # test_caustic_glass.py's
# Level with the ball's top, looking along +y (up z): the caustic ~50 degrees below the horizon,
# where the equirectangular map's sin(theta) is ~0.6; and looking away from the ball, down to
# the side, so that the caustic lies ~60 degrees off the fisheye's axis.
GLASS_LEVEL = ((0.0, -1.2, 1.5), (0.0, 1.0, 1.5), 35.0, (0.0, 0.0, 1.0))
GLASS_SIDE = ((0.0, -1.0, 1.5), (0.0, -2.0, 0.0), 35.0, (0.0, 0.0, 1.0))
CONVERGED = {
    "camera": lambda: (glass_scene(), moving(lensed(GLASS_CAM, 3.0, aperture=0.0), turn=0.1, shift=0.4)),
    "caster": lambda: (glass_scene(slide=0.4), lensed(GLASS_CAM, 3.0, aperture=0.0)),
    "equirect": lambda: (glass_scene(), pano(GLASS_LEVEL, "EQUIRECTANGULAR", longitude_min=np.radians(-60.0),
                                             longitude_max=np.radians(60.0), latitude_min=np.radians(-85.0),
                                             latitude_max=np.radians(-15.0))),
    "fisheye": lambda: (glass_scene(), pano(GLASS_SIDE, "FISHEYE_EQUIDISTANT", fisheye_fov=np.radians(160.0))),
}


@pytest.fixture(scope="module", params=list(CONVERGED))
def converged(request):
    s, cam = CONVERGED[request.param]()
    plain, st0 = lens_renders(s, cam, 384, (1, 2, 3))
    lt, st = lens_renders(s, cam, 128, (1, 2, 3), caustic_light_paths=0.5)
    return request.param, plain, lt, st0, st


def test_converges_to_the_path_tracers_image(converged):
    # The whole image within 1 %, each 4 x 4 region within 3 sd of the two estimates' seed spread
    # or 3 % (test_caustic_glass.py's check; the plain image at 3x the samples: its caustic
    # fireflies). Measured: means 0.998 (camera), 0.995 (caster), 1.000 (equirect), 1.008
    # (fisheye); the worst region at 0.33, 0.57, 0.76, 0.54 of its bound. Checked to fail with
    # the splat at the still frame (camera: 4.3x the bound), the light path at the frame's time
    # (caster: 2.9x) and the equirectangular Jacobian's sin(theta) dropped (2.1x).
    kind, plain, lt, st0, st = converged
    assert st["caustics"] == "on" and st0["caustics"] == ""
    assert ("motion blur" in st["features"]) == (kind in ("camera", "caster"))
    assert_same_within_noise(plain, lt, regions=4)


def test_lowers_the_variance(converged):
    # per sample (the plain image has 3x the samples); measured 0.18x, 0.14x, 0.07x, 0.09x
    _, plain, lt, _, _ = converged
    assert 128 * lt.var(0, ddof=1).mean() < 0.35 * 384 * plain.var(0, ddof=1).mean()


POLY = (-1.1735e-05, -0.019989, -3.3525e-06, 3.0993e-08, -2.6065e-11)  # Blender's default lens polynomial
INVERSE_CASES = {
    "equirect": ("EQUIRECTANGULAR", {}),
    "equirect_ranges": ("EQUIRECTANGULAR", dict(longitude_min=-2.1, longitude_max=1.4, latitude_min=-1.0,
                                                latitude_max=0.5)),
    "equidistant": ("FISHEYE_EQUIDISTANT", dict(fisheye_fov=np.pi)),
    "equisolid": ("FISHEYE_EQUISOLID", dict(fisheye_lens=10.5, fisheye_fov=np.pi)),
    "polynomial": ("FISHEYE_LENS_POLYNOMIAL", dict(fisheye_polynomial=POLY, fisheye_fov=np.pi)),
    "mirrorball": ("MIRRORBALL", {}),
    "cubeface": ("EQUIANGULAR_CUBEMAP_FACE", {}),
    "cylindrical": ("CENTRAL_CYLINDRICAL", dict(central_cylindrical_range_v_min=-1.5,
                                                central_cylindrical_range_v_max=0.8)),
}


def ray_dir(cam, x, y, time):
    o, d, tmax = cam.generate_ray(W, H, x, y, None, time)
    return np.array(o), np.array(d), tmax


@pytest.mark.parametrize("moves", [False, True], ids=["still", "moving"])
@pytest.mark.parametrize("case", list(INVERSE_CASES))
def test_pano_view_inverts_the_camera_rays_with_their_density(case, moves):
    # The light path's connection to a panorama (Camera::pano_view, through lens_view) inverts
    # the camera's own rays: every point along the ray through raster (x, y) maps back to (x, y),
    # with its distance from the camera and the pixel density per unit solid angle of the
    # direction, 1 / (the solid angle one pixel spans there: the map's Jacobian, here by central
    # differences of the camera's directions). Moving: the camera's frame at the ray's time.
    kind, kw = INVERSE_CASES[case]
    cam = pano(LAMP_CAM, kind, **kw)
    if moves:
        moving(cam, turn=0.3, shift=0.5)
    rng = np.random.default_rng(5)
    h, checked = 0.05, 0
    for _ in range(60):
        x, y, t = rng.uniform(1, W - 1), rng.uniform(1, H - 1), float(rng.uniform()) if moves else None
        o, d, tmax = ray_dir(cam, x, y, t)
        if tmax == 0.0:  # outside the image (a fisheye's circle): the camera has no ray there
            continue
        dirs = [ray_dir(cam, x + a, y + b, t) for a, b in ((h, 0), (-h, 0), (0, h), (0, -h))]
        if any(r[2] == 0.0 for r in dirs):
            continue
        dx, dy = (dirs[0][1] - dirs[1][1]) / (2 * h), (dirs[2][1] - dirs[3][1]) / (2 * h)
        want = 1.0 / abs(np.dot(np.cross(dx, dy), d))
        for dist in (0.5, 3.0):
            p = o + d * dist
            got = cam.lens_view(W, H, tuple(p), time=t)
            assert got is not None
            rx, ry, dd, pdf, eye = got
            assert abs(rx - x) < 2e-3 and abs(ry - y) < 2e-3
            assert dd == pytest.approx(np.linalg.norm(p - np.array(eye)), rel=1e-5)
            assert pdf == pytest.approx(want, rel=5e-3)
        checked += 1
    assert checked > 20
    if moves:  # the frame at another time sees the point elsewhere
        o, d, _ = ray_dir(cam, 20.0, 15.0, 0.1)
        rx, ry = cam.lens_view(W, H, tuple(o + d * 3.0), time=0.9)[:2]
        assert abs(rx - 20.0) + abs(ry - 15.0) > 0.5


def test_pano_view_outside_the_image_or_the_clipping_range_is_none():
    fish = pano(LAMP_CAM, "FISHEYE_EQUIDISTANT", fisheye_fov=np.radians(100.0))
    o, d, _ = ray_dir(fish, 24.0, 18.0, None)  # the view axis
    assert fish.lens_view(W, H, tuple(o + d * 2.0)) is not None
    side = np.cross(d, (1.0, 0.0, 0.0))
    assert fish.lens_view(W, H, tuple(o + 2.0 * side)) is None  # 90 degrees off the axis: outside 50
    assert fish.lens_view(W, H, tuple(o - d * 2.0)) is None  # behind
    eq = pano(LAMP_CAM, "EQUIRECTANGULAR")
    eq.clip_start = 0.5
    o, d, _ = ray_dir(eq, 10.0, 10.0, None)  # o: 0.5 along d from the camera
    assert eq.lens_view(W, H, tuple(o - d * 0.2)) is None and eq.lens_view(W, H, tuple(o + d * 0.2)) is not None


def test_perspective_lens_view_at_a_time_inverts_the_moving_camera():
    # A moving camera with a lens: the camera ray from lens sample u at time t maps back to its
    # raster position through the lens point, from the camera's frame at t.
    cam = moving(lensed(LAMP_CAM, 2.0, aperture=0.2, blades=5), turn=0.3, shift=0.5)
    rng = np.random.default_rng(7)
    for _ in range(30):
        x, y, t = rng.uniform(0, W), rng.uniform(0, H), float(rng.uniform())
        u = (float(rng.uniform()), float(rng.uniform()))
        o, d, _ = cam.generate_ray(W, H, x, y, u, t)
        p = np.array(o) + np.array(d) * 2.5
        rx, ry, dist, pdf, eye = cam.lens_view(W, H, tuple(p), u, t)
        assert abs(rx - x) < 2e-3 and abs(ry - y) < 2e-3
        assert np.allclose((p - np.array(eye)) / dist, d, atol=1e-5)


def turning_panel_scene():
    """shaded_panel_scene(extent=True) with its glossy panel turning +-0.2 rad about its vertical
    axis over the shutter."""
    s = pc.Scene()
    add_object(s, *quad((-3, -3, 0), (6, 0, 0), (0, 6, 0)), s.add_material("floor", (0.7, 0.7, 0.7)))
    add_object(s, *quad((-3, -3, 2.0), (0, 3, 0), (6, 0, 0)), s.add_material("shade", (0.0, 0.0, 0.0)))
    m = s.add_shader("chrome", closure("glossy", color=(0.95, 0.95, 0.95), roughness=0.27))
    turn = np.stack([affine(rot_z(a), (0.0, 1.0, 0.0)) for a in (-0.2, 0.0, 0.2)])
    s.add_instance(s.add_mesh(*quad((-1.0, 0.0, 0.0), (0.0, 0.0, 1.5), (2.0, 0.0, 0.0)), None, None, [m]), turn[1],
                   motion=turn)
    s.set_world_color((0.0, 0.0, 0.0))
    s.add_point_light((0.3, -0.5, 2.5), (8.0, 8.0, 8.0), radius=0.3)
    s.add_sun_light((0.1, -0.3, 1.0), (1.0, 1.0, 1.0), angle=np.radians(10.0))
    s.commit()
    return s


# The shaded panel's views: PANEL_CAM's with the panel turning and the camera, from its frame over
# the shutter (a shutter that opens on the frame), turning by 0.3 rad, sliding 0.3 and moving 0.6
# along its axis (the distance and the angle to the axis in the path tracer's density change with
# the frame; a shutter centred on the frame would cancel a wrong frame's error to first order);
# level (up z, along +y) with the floor's caustic 25-88
# degrees below the horizon (sin(theta) 0.03-0.9); a fisheye looking away and down, the caustic
# off its axis.
PANEL_LEVEL = ((0.0, -0.9, 1.6), (0.0, 1.0, 1.6), 30.0, (0.0, 0.0, 1.0))
PANEL_SIDE = ((0.0, -0.9, 1.6), (0.0, -2.0, 0.4), 30.0, (0.0, 0.0, 1.0))
FEW_MANY = {
    "motion": lambda: (turning_panel_scene(), moving(lensed(PANEL_CAM, 3.0, aperture=0.0), turn=0.3, shift=0.3,
                                                     dolly=0.6, ks=(0.0, 0.5, 1.0))),
    "equirect": lambda: (shaded_panel_scene(extent=True),
                         pano(PANEL_LEVEL, "EQUIRECTANGULAR", longitude_min=np.radians(-60.0),
                              longitude_max=np.radians(60.0), latitude_min=np.radians(-88.0),
                              latitude_max=np.radians(-25.0))),
    "fisheye": lambda: (shaded_panel_scene(extent=True),
                        pano(PANEL_SIDE, "FISHEYE_EQUIDISTANT", fisheye_fov=np.radians(170.0))),
}


@pytest.fixture(scope="module", params=list(FEW_MANY))
def few_many(request):
    s, cam = FEW_MANY[request.param]()
    few, st = lens_renders(s, cam, 128, (1, 2, 3, 4), caustic_light_paths=0.03)
    many, _ = lens_renders(s, cam, 32, (1, 2, 3, 4), caustic_light_paths=3.0)
    return request.param, few, many, st


def test_few_or_many_light_paths_give_the_same_image(few_many):
    # The MIS weights sum to 1 only if both sides use the same densities: with few light paths
    # (0.03 per sample) they split between the path tracer and the light paths over most of the
    # caustic, with many (3) the light paths take nearly all. The shaded panel (its floor lit
    # by the caustics of a point of radius 0.3 and a sun of 10 degrees alone) seen by a moving
    # camera with a turning panel, an equirectangular and a fisheye camera.
    # Measured 0.986, 1.005, 1.007 (few-path seed spread 2-3 %). Checked to fail with the path
    # tracer's density from the still frame (motion 0.928), the splat at the still frame (1.107),
    # and a panorama's density off by sin(elevation) on the path tracer's side (equirect 0.928)
    # or the light tracer's (1.196, fisheye 1.067).
    kind, few, many, st = few_many
    assert st["caustics"] == "on"
    assert abs(few.mean() / many.mean() - 1.0) < 0.06


@pytest.mark.sanitize  # quick: the moving and panoramic connections on the sanitizer build too
@pytest.mark.parametrize("case", ["motion", "equirect360"])
def test_deterministic_whatever_the_threads_and_tiles(case):
    # motion: the moving casters seen by the moving camera; equirect360: the whole sphere, whose
    # Blackman-Harris footprint crosses the seam and the poles (samples there that the inverse
    # map puts on the other side take no light-path weight).
    if case == "motion":
        s, cam = moving_casters_scene(), moving(lensed(LAMP_CAM, 3.0, aperture=0.0))
    else:
        s, cam = mirror_scene(sun_light=True), pano(LAMP_CAM, "EQUIRECTANGULAR")
    kw = dict(caustic_light_paths=1.0, filter_type="blackman_harris", filter_width=1.5)
    a, st = lens_renders(s, cam, 6, (9,), 40, 24, threads=1, tile_size=8, **kw)
    b, _ = lens_renders(s, cam, 6, (9,), 40, 24, threads=2, tile_size=16, **kw)
    assert st["caustics"] == "on" and np.array_equal(a, b)


def test_whole_sphere_with_a_wide_filter_converges_to_the_path_tracers_image():
    # The full equirectangular panorama with Blackman-Harris 1.5, looking up from 1.5 above the
    # floor, so that its seam (straight down) crosses the floor's caustics: the seam's pixels
    # take camera samples past the frame, which the path tracer keeps alone. Measured: seam
    # columns 0.998 and 0.991. (With those samples given the light-path weight, which no
    # light path then takes: 0.988 and 0.991, within the bound: not caught.)
    s = mirror_scene()
    cam = pano(((0.0, -1.3, 1.5), (0.0, -1.3, 5.0), 35.0, (0.0, 1.0, 0.0)), "EQUIRECTANGULAR")
    kw = dict(filter_type="blackman_harris", filter_width=1.5)
    plain, _ = lens_renders(s, cam, 128, (1, 2, 3), **kw)
    lt, st = lens_renders(s, cam, 128, (1, 2, 3), caustic_light_paths=1.0, **kw)
    assert st["caustics"] == "on"
    assert_same_within_noise(plain, lt)
    # the columns at the seam: within 3 % of the plain image's
    for cols in (slice(0, 2), slice(W - 2, W)):
        assert abs(lt[:, :, cols].mean() / plain[:, :, cols].mean() - 1.0) < 0.03


@pytest.mark.sanitize  # quick: tiny renders
def test_a_panoramas_depth_of_field_stays_off_with_the_reason():
    s = mirror_scene()
    cam = pano(LAMP_CAM, "EQUIRECTANGULAR")
    cam.aperture_size = 0.05
    a, _ = lens_renders(s, cam, 2, (1,), 24, 16)
    b, st = lens_renders(s, cam, 2, (1,), 24, 16, caustic_light_paths=1.0)
    assert st["caustics"] == "off: not with a panoramic camera's depth of field"
    assert np.array_equal(a, b)


@pytest.mark.sanitize  # quick: tiny renders
def test_automatic_turns_on_for_moving_and_panoramic_cameras():
    # mirror_scene's sun holds 46 % of its environment's power: on, as for a still perspective
    # camera, and the same image as the explicit 0.1 per sample with the automatic light-vertex
    # connections (2), which motion blur turns off (a cached light vertex holds the scene at its
    # own light path's shutter time), whether automatic or asked for.
    for s, cam, k in ((moving_casters_scene(), moving(lensed(LAMP_CAM, 3.0, aperture=0.0)), 0),
                      (mirror_scene(), pano(LAMP_CAM, "FISHEYE_EQUISOLID"), 2)):
        a, st = lens_renders(s, cam, 4, (1,), 24, 16, caustic_light_paths_auto=True)
        b, sb = lens_renders(s, cam, 4, (1,), 24, 16, caustic_light_paths=0.1, caustic_connections=2)
        assert st["caustics"].startswith("on (automatic)") and np.array_equal(a, b)
        assert st["caustic_connections"] == k and sb["caustic_connections"] == k
