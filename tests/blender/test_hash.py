"""The core's XXH64 (hash_buffer), which the mesh fingerprints use: the reference's published
values, every tail length, and any C-contiguous buffer."""

import numpy as np
import pytest

from blender_util import core_available

pytestmark = [pytest.mark.sanitize, pytest.mark.skipif(not core_available(), reason="core module not built")]


def _core():
    from addon.core import get_core
    return get_core()


def test_reference_values():
    pc = _core()
    # Published XXH64 values (xxHash's test vectors; the `xxhash` package gives the same).
    assert pc.hash_buffer(b"") == 0xEF46DB3751D8E999
    assert pc.hash_buffer(b"abc") == 0x44BC2CF5AD770999
    assert pc.hash_buffer(bytes(range(256)) * 3, seed=7) == 0xB1E10F6C5294CD6B


def test_every_byte_and_length_counts():
    """Flipping any bit changes the hash, for lengths around the 32-byte stripes and the 8-
    and 4-byte tails; a trailing zero byte changes it too (the length is hashed)."""
    pc = _core()
    rng = np.random.default_rng(3)
    seen = set()
    for n in (1, 3, 4, 5, 7, 8, 9, 31, 32, 33, 63, 64, 65, 100):
        data = bytearray(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
        base = pc.hash_buffer(bytes(data))
        assert base not in seen
        seen.add(base)
        assert pc.hash_buffer(bytes(data) + b"\0") != base
        for i in range(n):
            flipped = bytearray(data)
            flipped[i] ^= 1 << int(rng.integers(8))
            assert pc.hash_buffer(bytes(flipped)) != base, (n, i)


def test_numpy_arrays_and_non_contiguous_views():
    pc = _core()
    a = np.arange(1000, dtype=np.float32)
    assert pc.hash_buffer(a) == pc.hash_buffer(a.tobytes())
    assert pc.hash_buffer(a.reshape(10, 100)) == pc.hash_buffer(a)  # the same bytes
    with pytest.raises((ValueError, BufferError)):
        pc.hash_buffer(a[::2])  # not contiguous: refused, never hashed with gaps
    with pytest.raises(TypeError):
        pc.hash_buffer(12)
