"""Light samples of a constant world colour (Scene.world_light_samples, docs/design/sampling.md
"Sky samples"): where the sky is the only light, it is sampled at every surface vertex besides
the BSDF ray. That must converge to the image of the BSDF ray alone (the old estimator) with a
lower variance per sample; with a sun the BSDF ray alone finds the sky, bit for bit as before."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, quad, region_means, run_session, uv_sphere

pc = core()
pytestmark = pytest.mark.sanitize


def principled(s, name, color, roughness):
    regs, prog = {}, []
    for i, (k, v) in enumerate(dict(base_color=color, roughness=roughness).items()):
        prog.append(("const", i, v if isinstance(v, tuple) else (v,)))
        regs[k] = i
    prog.append(("closure", "principled", None, regs))
    return s.add_shader(name, prog)


def grove(sun=True, world_samples=True):
    """Spheres standing on a ground plane (they shade it from the sun and hide part of the sky),
    rough Principled, under a constant sky colour and, with `sun`, a sharp sun."""
    s = pc.Scene()
    ground = principled(s, "ground", (0.35, 0.3, 0.22), 0.8)
    bark = principled(s, "bark", (0.3, 0.45, 0.2), 0.6)
    pos, tris = quad((-4, -4, 0), (8, 0, 0), (0, 8, 0))
    add_object(s, pos, tris, ground)
    for x, y, r in ((-0.9, 0.2, 0.5), (0.4, -0.3, 0.4), (0.9, 0.8, 0.6), (-0.2, 1.2, 0.35)):
        p, t, n = uv_sphere(r, nu=24, nv=12, center=(x, y, r))
        add_object(s, p, t, bark, n)
    if sun:
        s.add_sun_light((0.5, -0.35, 0.8), (3.0, 3.0, 3.0), angle=0.0)
    s.set_world_color((0.35, 0.45, 0.6))
    s.set_camera(camera(pc, (0.0, -5.0, 2.5), (0.0, 0.3, 0.2), lens=35.0))
    s.world_light_samples = world_samples
    return s


def film(sess):
    return np.asarray(sess.film())[..., :3].astype(np.float64)


def test_world_light_samples_is_a_scene_setting():
    s = pc.Scene()
    assert not s.world_light_samples  # off by default (docs/design/sampling.md)
    s.world_light_samples = True
    assert s.world_light_samples


def test_sky_samples_add_shadow_rays_only_under_a_sky_alone():
    """Under the sky alone: more rays per path (the sky's shadow rays); with a black world, or
    with a sun (the sky is then found by BSDF rays alone), the same image bit for bit."""
    on = run_session(pc, grove(False, True), 24, 24, samples=4).stats()
    off = run_session(pc, grove(False, False), 24, 24, samples=4).stats()
    assert on["rays"] > 1.3 * off["rays"]
    for sun, colour in ((False, (0.0, 0.0, 0.0)), (True, (0.35, 0.45, 0.6))):
        runs = []
        for world_samples in (True, False):
            s = grove(sun, world_samples)
            s.set_world_color(colour)
            runs.append(run_session(pc, s, 24, 24, samples=4))
        assert runs[0].stats()["rays"] == runs[1].stats()["rays"]
        assert np.array_equal(np.asarray(runs[0].film()), np.asarray(runs[1].film()))


@pytest.mark.converged
def test_sky_samples_converge_to_the_bsdf_rays_image():
    """Unbiased: the same image as the BSDF ray alone (mean within 1 %, 8x8 regions within 3 %)."""
    a = film(run_session(pc, grove(False, True), 32, 32, samples=2048, max_bounces=12))
    b = film(run_session(pc, grove(False, False), 32, 32, samples=2048, max_bounces=12))
    assert a.mean() > 0.05
    assert abs(a.mean() / b.mean() - 1.0) < 0.01
    ra, rb = region_means(a, 4), region_means(b, 4)
    assert np.max(np.abs(ra - rb) / np.maximum(rb, 0.02)) < 0.03


def test_sky_samples_lower_the_variance_under_a_sky_alone():
    """With the sky the only light, sampling it besides the BSDF ray lowers the relative variance
    of one sample well below the BSDF ray's alone (measured 1.9x on the forest)."""
    def rel_var(world_samples):
        imgs = np.stack([film(run_session(pc, grove(False, world_samples), 24, 24, samples=4, seed=10 + k))
                         for k in range(12)])
        ref = imgs.mean(0)
        return float(np.mean(imgs.var(0, ddof=1) / (ref ** 2 + 1e-2)))
    assert rel_var(False) > 1.3 * rel_var(True)
