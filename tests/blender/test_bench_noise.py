"""The realistic bench's converged check states each engine's own seed noise beside the two
references' agreement (bench_realistic.own_noise; docs/design/sampling.md, "The window room
converged"): on synthetic renders, noise alone reads about 1 and a 5 % bias well above it."""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_realistic as br  # noqa: E402


def _halves(truth, rng, sigma):
    return [truth + rng.normal(0.0, sigma, truth.shape) for _ in range(2)]


def test_own_noise_tells_noise_from_a_difference():
    rng = np.random.default_rng(25)
    truth = rng.uniform(0.1, 1.0, (72, 96, 3))
    halves = {"PATHLIGHT": _halves(truth, rng, 0.2), "CYCLES": _halves(truth, rng, 0.3)}
    refs = {e: 0.5 * (a + b) for e, (a, b) in halves.items()}
    own, z = br.own_noise(halves, refs)
    # A region averages 108 pixels of 3 channels: its relative noise at these sigmas is a few %,
    # Cycles' (the larger sigma) the larger.
    assert 0.01 < own["PATHLIGHT"] < own["CYCLES"] < 0.2, own
    assert 0.7 < z < 1.4, z
    biased = dict(refs, PATHLIGHT=refs["PATHLIGHT"] * 1.05)
    _, zb = br.own_noise(halves, biased)
    assert zb > 1.8, zb
