"""The blue-noise pixel pattern (RenderSettings.pixel_pattern, core/util/pixel_pattern.h): pixels
take consecutive chunks of one shared Sobol sequence along a scrambled Morton curve, so that
neighbours' errors cancel over a region while each pixel stays as noisy as before
(docs/design/sampling.md "Blue-noise pattern")."""
import numpy as np
import pytest

from core_scenes import add_object, camera, core, cornell, quad, run_session

pytestmark = pytest.mark.sanitize


@pytest.fixture(scope="module")
def pc():
    return core()


def _first_draws(pc, pattern, pixels, samples, length, seed=5, width=64, dim=0):
    """Dimension `dim`'s 2-D draw of each (x, y) in pixels for each sample: (n, 2)."""
    out = []
    for x, y in pixels:
        for s in samples:
            draws, _, _, _ = pc.pattern_sampler_values(pattern, seed, length, x, y, width, s, dim + 1)
            out.append(draws[dim])
    return np.array(out, dtype=np.float64)


def _is_net(points):
    """Whether n = 2^m points in [0, 1)^2 are a (0, m, 2)-net in base 2: every elementary box
    of area 1/n (2^-a by 2^-(m-a)) holds exactly one point."""
    n = len(points)
    m = n.bit_length() - 1
    assert 1 << m == n
    for a in range(m + 1):
        ix = np.floor(points[:, 0] * (1 << a)).astype(np.int64)
        iy = np.floor(points[:, 1] * (1 << (m - a))).astype(np.int64)
        if len(set(zip(ix.tolist(), iy.tolist()))) != n:
            return False
    return True


def test_neighbouring_chunks_together_are_nets(pc):
    """Each pixel's chunk of 4 samples is a net (so a pixel is no noisier), and so are the 16
    samples of a 2x2 quad and the 64 of a 4x4 block together (the blue noise); with
    independent pixels the quad is not."""
    quad = [(x, y) for y in (8, 9) for x in (4, 5)]
    block = [(x, y) for y in range(8, 12) for x in range(4, 8)]
    for dim in (0, 3):  # the pixel filter's pair and a bounce's
        for p in block:
            assert _is_net(_first_draws(pc, "blue_noise", [p], range(4), 4, dim=dim))
        assert _is_net(_first_draws(pc, "blue_noise", quad, range(4), 4, dim=dim))
        assert _is_net(_first_draws(pc, "blue_noise", block, range(4), 4, dim=dim))
        assert not _is_net(_first_draws(pc, "independent", quad, range(4), 4, dim=dim))
    # Round: 3 samples take chunks of 4, so the quad's 4 x 4 indices are one block.
    idx = sorted(pc.pattern_sampler_values("blue_noise_round", 5, 3, x, y, 64, s, 1)[2]
                 for x, y in quad for s in range(4))
    assert idx == list(range(idx[0], idx[0] + 16)) and idx[0] % 16 == 0


def test_chunks_fit_32_bits_in_blocks(pc):
    """Chunks never overflow the 32-bit index: blocks shrink from 1024 pixels a side as the
    frame's samples grow, and each block has its own sequence."""
    for length, levels in ((1, 10), (4096, 10), (4097, 9), (1 << 20, 6), (1 << 24, 4), ((1 << 31) - 1, 0)):
        _, key, index, got = pc.pattern_sampler_values("blue_noise", 1, length, 1023, 1023, 4096, length - 1, 1)
        assert got == levels
        # the pixel's chunk, not wrapped round: its place on the block's curve, then the sample
        assert index // length < 4 ** levels and index % length == length - 1
        size = 1 << levels
        corner = 1023 & ~(size - 1)  # the block's first pixel shares its sequence ...
        assert pc.pattern_sampler_values("blue_noise", 1, length, corner, corner, 4096, 0, 1)[1] == key
        # ... the next block's does not
        assert pc.pattern_sampler_values("blue_noise", 1, length, corner + size, corner, 4096, 0, 1)[1] != key
    # All 1024 x 1024 pixels' chunks of a 4096-sample frame are distinct (a permutation).
    rng = np.random.default_rng(0)
    xs, ys = rng.integers(0, 1024, 300), rng.integers(0, 1024, 300)
    starts = {pc.pattern_sampler_values("blue_noise", 9, 4096, int(x), int(y), 2048, 0, 1)[2]
              for x, y in set(zip(xs.tolist(), ys.tolist()))}
    assert len(starts) == len(set(zip(xs.tolist(), ys.tolist())))
    assert all(s % 4096 == 0 for s in starts)


def test_first_pattern_keeps_sample_zero_apart(pc):
    """Blue-Noise (First): sample 0 from a 1-spp sequence of its own, samples 1.. in chunks of
    length - 1."""
    quad = [(x, y) for y in (2, 3) for x in (6, 7)]
    firsts = _first_draws(pc, "blue_noise_first", quad, [0], 5)
    assert _is_net(firsts)
    rest = _first_draws(pc, "blue_noise_first", quad, range(1, 5), 5)
    assert _is_net(rest)
    # The viewport's renders: its 1-2 sample low-resolution pass and the full one.
    scene = cornell(pc)
    for spp in (1, 2, 5):
        img = run_session(pc, scene, 24, 24, spp, pixel_pattern="blue_noise_first").film()
        assert np.isfinite(img).all() and img[..., :3].mean() > 0.05


def _region_draws(pc, pattern, seed, length=4, size=8, draws=18, x0=16, y0=8):
    """Every draw (the camera's and 7 bounce sets' Sobol draws, then the PCG tail) of each
    sample of an aligned size x size region: (pixels, samples, 2 * draws)."""
    v = np.empty((size * size, length, draws, 2))
    for i in range(size * size):
        for s in range(length):
            v[i, s] = pc.pattern_sampler_values(pattern, seed, length, x0 + i % size, y0 + i // size, 64, s, draws)[0]
    return v.reshape(size * size, length, 2 * draws)


def _factors(values):
    """values (seeds, pixels, samples): (the region's variance over its pixels' mean variance /
    pixels, the pixels' mean variance), over the seeds."""
    pix = values.mean(axis=2)
    pv = pix.var(axis=0, ddof=1).mean()
    return pix.mean(axis=1).var(ddof=1) / (pv / pix.shape[1]), pv


def test_a_blocks_pixels_share_no_draw_but_the_stratified_ones(pc):
    """Blue noise (issue 25, docs/design/sampling.md "Blue noise as the default"): over 48
    seeds of an 8x8 region at 4 samples, the region's Sobol coordinates are stratified jointly
    (factor far below 1), while what must stay as independent as between independent pixels
    does: the PCG tail past the Sobol draws (keyed by the pixel, not the shared sequence) and
    products of two different sets' coordinates (each set its own shuffle); and with a
    power-of-two chunk no pixel is noisier, for smooth and for indicator integrands of one set."""
    seeds = range(48)
    v = {p: np.array([_region_draws(pc, p, seed) for seed in seeds]) for p in ("independent", "blue_noise")}
    sobol, pcg = range(32), range(32, 36)  # coordinates: 16 Sobol draws, then PCG32
    f = {p: [_factors(x[..., c] - 0.5) for c in range(36)] for p, x in v.items()}
    assert max(f["blue_noise"][c][0] for c in sobol) < 0.2
    for c in pcg:
        assert 0.4 < f["blue_noise"][c][0] < 1.8, (c, f["blue_noise"][c])
    cross = [(a, b) for a in sobol for b in sobol if a < b and a // 4 != b // 4] + \
            [(a, b) for a in sobol for b in pcg]
    prod = {p: [_factors((x[..., a] - 0.5) * (x[..., b] - 0.5)) for a, b in cross] for p, x in v.items()}
    fb = np.array([q[0] for q in prod["blue_noise"]])
    assert fb.mean() < 1.15 and np.percentile(fb, 99) < 2.0, (fb.mean(), np.percentile(fb, 99))
    # One set's pairs: the pixel's variance as independent pixels have it (mean over the pairs).
    same = [(a, b) for a in sobol for b in sobol if a < b and a // 4 == b // 4]
    for g in (lambda x, a, b: (x[..., a] - 0.5) * (x[..., b] - 0.5),
              lambda x, a, b: ((x[..., a] < 0.3) & (x[..., b] < 0.6)) - 0.18):
        ratio = np.mean([_factors(g(v["blue_noise"], a, b))[1] / _factors(g(v["independent"], a, b))[1]
                         for a, b in same])
        assert 0.85 < ratio < 1.15, ratio


def _lit_floor(pc):
    """A diffuse floor under a square area light, seen obliquely: smooth, direct light only."""
    s = pc.Scene()
    white = s.add_material("white", (0.8, 0.8, 0.8))
    light = s.add_material("light", (0.0, 0.0, 0.0), (5.0, 5.0, 5.0))
    add_object(s, *quad((-5, -5, 0), (10, 0, 0), (0, 10, 0)), white)
    add_object(s, *quad((-0.5, -0.5, 1.5), (0, 1, 0), (1, 0, 0)), light)
    s.set_camera(camera(pc, (0.0, -3.0, 1.0), (0.0, 0.0, 0.0), lens=30.0))
    return s


def _seed_stats(pc, scene, pattern, seeds, size=32, spp=4, region=8):
    """Over seeds: the mean image, the mean per-pixel variance and the median region's factor
    (its mean's variance over its pixels' variance / pixels: 1 for independent pixels)."""
    imgs = []
    for seed in seeds:
        sess = run_session(pc, scene, size, size, spp, seed=seed, pixel_pattern=pattern, threads=2, max_bounces=1)
        imgs.append(sess.film()[..., :3].mean(axis=2).astype(np.float64))
    imgs = np.array(imgs)
    g = size // region
    regions = imgs.reshape(len(seeds), g, region, g, region).mean(axis=(2, 4))
    pix = imgs.var(axis=0, ddof=1)
    pix_regions = pix.reshape(g, region, g, region).mean(axis=(1, 3))
    lit = pix.reshape(g, region, g, region).min(axis=(1, 3)) > 0  # (not the black sky above)
    factor = np.median(regions.var(axis=0, ddof=1)[lit] / (pix_regions[lit] / region ** 2))
    return imgs.mean(axis=0), pix.mean(), factor


@pytest.mark.release_only
def test_region_error_drops_pixel_error_does_not(pc):
    """Region averages converge far faster with blue noise, while each pixel's variance and the
    image's mean stay what they were (16 seeds of a 32x32 lit floor at 4 spp)."""
    scene, seeds = _lit_floor(pc), range(16)
    mean_i, pix_i, factor_i = _seed_stats(pc, scene, "independent", seeds)
    mean_b, pix_b, factor_b = _seed_stats(pc, scene, "blue_noise", seeds)
    assert 0.6 < factor_i < 1.5, factor_i
    assert factor_b < factor_i / 3, (factor_b, factor_i)
    assert 0.85 < pix_b / pix_i < 1.15, (pix_b, pix_i)
    # The means agree within the independent render's noise of the image mean.
    sd = np.sqrt(pix_i / mean_i.size / len(seeds))
    assert abs(mean_b.mean() - mean_i.mean()) < 4 * np.sqrt(2) * sd, (mean_b.mean(), mean_i.mean(), sd)


def test_threads_and_tiles_do_not_change_the_image(pc):
    scene = cornell(pc)
    a = run_session(pc, scene, 40, 24, 5, seed=3, pixel_pattern="blue_noise", threads=1, tile_size=8).film()
    b = run_session(pc, scene, 40, 24, 5, seed=3, pixel_pattern="blue_noise", threads=2, tile_size=32).film()
    assert np.array_equal(a, b)
    c = run_session(pc, scene, 40, 24, 5, seed=3, pixel_pattern="independent", threads=2).film()
    assert not np.array_equal(a, c)


def test_border_renders_its_part_of_the_frame(pc):
    """Blue noise is keyed by the full-frame pixel: a border renders exactly that part."""
    scene = cornell(pc)
    full = run_session(pc, scene, 48, 32, 3, seed=2, pixel_pattern="blue_noise").film()
    part = run_session(pc, scene, 48, 32, 3, seed=2, pixel_pattern="blue_noise", border_x=13, border_y=5,
                       border_width=20, border_height=17).film()
    assert np.array_equal(part, full[5:22, 13:33])


def test_farm_pieces_compose_into_one_render(pc):
    """Pieces [0, 3) and [3, 8) of an 8-sample frame, told the frame's total, merge into the
    8-sample render (to float rounding of the running means); pieces that lay their chunks out
    for their own counts do not."""
    scene = cornell(pc)
    kw = dict(seed=4, pixel_pattern="blue_noise", threads=2)
    one = run_session(pc, scene, 32, 32, 8, **kw).film().astype(np.float64)
    a = run_session(pc, scene, 32, 32, 3, pattern_samples=8, **kw).film().astype(np.float64)
    b = run_session(pc, scene, 32, 32, 5, sample_offset=3, pattern_samples=8, **kw).film().astype(np.float64)
    merged = (3 * a + 5 * b) / 8
    assert np.abs(merged - one).max() <= 2e-5 * max(1.0, np.abs(one).max())
    a_own = run_session(pc, scene, 32, 32, 3, **kw).film().astype(np.float64)  # chunks of 3
    assert np.abs((3 * a_own + 5 * b) / 8 - one).max() > 1e-2
    with pytest.raises(ValueError, match="pattern_samples"):
        run_session(pc, scene, 8, 8, 5, sample_offset=3, pattern_samples=7, **kw)


def test_time_limited_render_keeps_the_chunk_of_all_samples(pc):
    """A time limit stops a blue-noise render early without error: pixels used the start of
    chunks laid out for all the samples (as Cycles), and the image is the same scene."""
    scene = cornell(pc)
    sess = run_session(pc, scene, 32, 32, 1 << 20, seed=1, pixel_pattern="blue_noise", time_limit=0.5)
    done = sess.progress()["samples_done"]
    assert 1 <= done < 1 << 20
    img = sess.film()[..., :3]
    assert np.isfinite(img).all()
    ref = run_session(pc, scene, 32, 32, 16, seed=1).film()[..., :3]
    assert abs(img.mean() / ref.mean() - 1.0) < 0.1
