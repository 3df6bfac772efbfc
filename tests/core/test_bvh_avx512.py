"""The AVX-512 8-wide BVH kernel (bvh8_avx512.cpp) against the AVX2 one it must equal bit for bit:
the same closest hits (t, triangle, barycentrics), occlusions and traversal counts (so the same
visiting order, which decides one-ulp near-ties) on awkward rays, float and compressed nodes,
instanced scenes through the top level, leaves of every size and a rendered image. The kernel is
chosen per process (set_bvh_kernel, or PL_BVH_KERNEL=avx2 at load), so both run on one machine;
the comparisons skip where the CPU has no AVX-512."""
import os
import subprocess
import sys

import numpy as np
import pytest

from core_scenes import REPO, core, cornell, random_rotation as rotation, render
from test_bvh import awkward_rays, awkward_soup, books, noisy_sphere

pc = core()
pytestmark = pytest.mark.sanitize  # also run on the sanitizer build by .ci/run
HAS_AVX2 = pc.build_info()["bvh"] == "bvh8"
HAS_AVX512 = pc.build_info()["avx512"]
needs_avx512 = pytest.mark.skipif(not HAS_AVX512, reason="this CPU has no AVX-512: the AVX2 kernel runs")


def affine(linear, shift):
    m = np.eye(4, dtype=np.float32)
    m[:3, :3], m[:3, 3] = linear, shift
    return m


def with_kernel(kernel, f):
    """f() with the 8-wide tree run by `kernel`; the choice at load restored afterwards."""
    try:
        assert pc.set_bvh_kernel(kernel) == kernel
        return f()
    finally:
        pc.set_bvh_kernel("auto")


def both(f):
    return with_kernel("avx2", f), with_kernel("avx512", f)


def assert_same(a, b):
    for x, y in zip(a, b):
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f")


def test_kernel_setting():
    default = pc.build_info()["bvh_kernel"]
    if os.environ.get("PL_BVH_KERNEL") != "avx2":
        assert default == ("avx512" if HAS_AVX512 else "avx2" if HAS_AVX2 else "sse2")
    try:
        assert pc.set_bvh_kernel("avx2") == ("avx2" if HAS_AVX2 else "sse2")
        assert pc.build_info()["bvh_kernel"] == ("avx2" if HAS_AVX2 else "sse2")
        # Asked of a CPU without it, AVX-512 falls back to AVX2.
        assert pc.set_bvh_kernel("avx512") == ("avx512" if HAS_AVX512 else "avx2" if HAS_AVX2 else "sse2")
        with pytest.raises(ValueError):
            pc.set_bvh_kernel("avx1024")
    finally:
        assert pc.set_bvh_kernel("auto") == default


@pytest.mark.skipif(not HAS_AVX2, reason="no AVX2: no 8-wide kernel to choose")
def test_environment_forces_the_avx2_kernel():
    # (This process, without the variable, runs AVX-512 where it can: test_kernel_setting.)
    code = "from core_scenes import core; print(core().build_info()['bvh_kernel'])"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO / "tests" / "core", capture_output=True,
                         text=True, check=True, env=dict(os.environ, PL_BVH_KERNEL="avx2")).stdout
    assert out.strip() == "avx2"


@pytest.fixture(scope="module")
def awkward():
    rng = np.random.default_rng(7)
    meshes = [noisy_sphere(120, rng), awkward_soup(rng)]
    out = {}
    for compact in ("off", "on"):
        s = pc.Scene()
        s.compact_bvh = compact
        for pos, tris in meshes:
            s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
        s.commit(bvh="bvh8")
        assert s.stats()["bvh_compact"] == (compact == "on")
        out[compact] = s
    return out


@needs_avx512
@pytest.mark.parametrize("compact", ["off", "on"])
def test_hits_occlusions_and_counts_are_the_avx2_kernels(awkward, compact):
    s = awkward[compact]
    o, d = awkward_rays(np.random.default_rng(11), 24_000)
    for tmax in (np.inf, 0.5):
        a, b = both(lambda: s.intersect(o, d, tmax))
        assert 0.05 < (a[1] >= 0).mean() < 0.95  # the rays do test something
        assert_same(a, b)
        a, b = both(lambda: s.occluded(o, d, tmax))
        assert 0.05 < a.mean() < 0.95
        assert np.array_equal(a, b)
    # Per-ray tmax, and the nodes and triangles visited: the same traversal, step for step.
    tm = np.random.default_rng(5).uniform(0.1, 6.0, len(o)).astype(np.float32)
    a, b = both(lambda: s.traversal_counts(o, d, tm))
    assert a[0].sum() > 4 * len(o)
    assert_same(a, b)


@needs_avx512
def test_instances_through_the_top_level():
    # One mesh under rotated, scaled, sheared and mirrored transforms (a BLAS per mesh, the top
    # level above): every ray's BLAS calls go through the chosen kernel.
    rng = np.random.default_rng(3)
    pos, tris = noisy_sphere(40, rng)
    s = pc.Scene()
    mesh = s.add_mesh(pos, tris)
    shear = np.array([[1.0, 0.6, 0.0], [0.0, 1.0, 0.3], [0.0, 0.0, 0.8]])
    for i in range(27):
        lin = rotation(i) @ (shear if i % 3 == 0 else np.diag([-0.8, 0.9, 1.1]) if i % 3 == 1 else np.eye(3))
        s.add_instance(mesh, affine(lin * (0.4 + 0.03 * i), (3.0 * (i % 3), 3.0 * (i // 3 % 3), 3.0 * (i // 9))))
    s.commit(bvh="bvh8")
    o = rng.uniform(-2.0, 8.0, (40_000, 3)).astype(np.float32)
    d = rng.normal(size=(40_000, 3)).astype(np.float32)
    a, b = both(lambda: s.intersect(o, d, np.inf, instances=True))
    assert 0.1 < (a[1] >= 0).mean() < 0.95 and len(np.unique(a[4])) > 20
    assert_same(a, b)
    a, b = both(lambda: s.occluded(o, d, 3.0))
    assert 0.05 < a.mean() < 0.95
    assert np.array_equal(a, b)


@needs_avx512
def test_leaves_of_every_size():
    # One leaf per book of 3 to 8 pages: the four- and eight-lane block tests, their lanes and
    # the scalar fallback on the spines (edge functions exactly zero: ties by triangle order).
    sizes = [3, 4, 5, 6, 7, 8, 8, 7, 6, 5, 4, 3]
    pos, tris, o, d, spine = books(sizes)
    s = pc.Scene()
    s.add_instance(s.add_mesh(pos, tris), np.eye(4, dtype=np.float32))
    s.commit(bvh="bvh8")
    for oo, dd in ((o, d), (spine, np.tile(np.array([[0.3, 0.0, -1.0]], np.float32), (len(spine), 1)))):
        a, b = both(lambda: s.intersect(oo, dd))
        assert (a[1] >= 0).all()
        assert_same(a, b)
    for tmax in (0.0099, 0.0101):
        a, b = both(lambda: s.occluded(o, d, tmax))
        assert np.array_equal(a, b) and a.all() == (tmax > 0.01)


@needs_avx512
def test_cornell_image_is_bit_for_bit_the_avx2_kernels():
    a, b = both(lambda: render(pc, cornell(pc), 24, 24, 4, seed=3, threads=2)[0])
    assert a.mean() > 0.01
    assert np.array_equal(a, b)
