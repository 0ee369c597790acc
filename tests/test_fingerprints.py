"""Fingerprint bits: statistics against the Gaussian tail, freshness and determinism."""

import numpy as np
import pytest
from scipy.stats import norm

from mmwsim.errors import MmwsimError
from mmwsim.fingerprints import FingerprintSampler, NoiseModel

OFFSETS = np.array([-20.0, -9.0, -3.0, 0.0, 2.0, 6.0, 12.0, 40.0])  # dB above the threshold


def pdp_with_offsets(threshold=-115.0, n_rx=1):
    """(n_rx, 8, 120) PDPs: beam i holds threshold + OFFSETS[i] in bins 1..81, no signal elsewhere."""
    pdp = np.full((n_rx, len(OFFSETS), 120), -np.inf, dtype=np.float32)
    pdp[:, :, 1:82] = (threshold + OFFSETS)[None, :, None]
    return pdp


def check_tail(bits, sigma, n):
    expected = norm.sf(-OFFSETS / sigma)  # P(N >= threshold - pdp)
    frac = bits.reshape(-1, len(OFFSETS), bits.shape[-1]).mean(axis=(0, 2))
    se = np.sqrt(expected * (1 - expected) / n) + 1e-12
    assert np.all(np.abs(frac - expected) <= 5 * se + 1e-9), (frac, expected)


@pytest.mark.parametrize("sigma", [6.0, 2.0])
def test_fraction_of_ones_is_the_gaussian_tail(sigma):
    rng = np.random.default_rng(0)
    pdp = pdp_with_offsets()
    n_samples = 2000
    bits = NoiseModel(sigma).bits(np.repeat(pdp, n_samples, axis=0), rng)
    assert bits.shape == (n_samples, 8, 81) and bits.dtype == np.uint8
    check_tail(bits, sigma, n_samples * 81)
    sampler = FingerprintSampler(pdp, NoiseModel(sigma))
    bits = sampler.sample(np.zeros(n_samples, np.int64), rng)
    assert bits.shape == (n_samples, 8, 81)
    check_tail(bits, sigma, n_samples * 81)
    np.testing.assert_allclose(NoiseModel(sigma).probability(pdp[0, :, 1]), norm.sf(-OFFSETS / sigma))


def test_empty_bins_never_fire_and_window_is_respected():
    rng = np.random.default_rng(1)
    pdp = pdp_with_offsets()
    pdp[:, :, 0] = 0.0  # strong, but outside the default window 1..81
    pdp[:, :, 82:] = 0.0
    for bits in (
        NoiseModel().bits(np.repeat(pdp, 50, axis=0), rng),
        FingerprintSampler(pdp).sample([0] * 50, rng),
    ):
        assert bits.shape == (50, 8, 81)
        assert bits[:, 7].all()  # 40 dB above threshold: a sure one
    empty = np.full((1, 4, 120), -np.inf, np.float32)
    assert not NoiseModel().bits(np.repeat(empty, 100, axis=0), rng).any()
    assert not FingerprintSampler(empty).sample(np.zeros(100, int), rng).any()
    # no receivers at all: no fingerprints, of the right shape
    assert FingerprintSampler(pdp).sample(np.zeros(0, int), rng).shape == (0, 8, 81)
    # no noise: a plain threshold
    b = NoiseModel(0.0).bits(pdp, rng)
    np.testing.assert_array_equal(b[0, :, 0], OFFSETS >= 0)
    np.testing.assert_array_equal(
        FingerprintSampler(pdp, NoiseModel(0.0)).sample([0], rng)[0, :, 0], OFFSETS >= 0
    )


def test_sampler_is_fresh_deterministic_and_thread_independent():
    rng = np.random.default_rng(5)
    pdp = -115.0 + rng.normal(0, 10, size=(50, 32, 120)).astype(np.float32)
    pdp[rng.random(pdp.shape) < 0.8] = -np.inf
    sampler = FingerprintSampler(pdp)
    idx = rng.integers(0, 50, 5000)
    a = sampler.sample(idx, np.random.default_rng(7), threads=1)
    b = sampler.sample(idx, np.random.default_rng(7), threads=2)
    np.testing.assert_array_equal(a, b)
    g = np.random.default_rng(7)
    first, second = sampler.sample(idx, g), sampler.sample(idx, g)
    assert (first != second).any()  # fresh noise per use
    # per-entry frequency matches the detection probability
    many = sampler.sample(np.zeros(4000, np.int64), g).mean(axis=0)
    p = NoiseModel().probability(pdp[0, :, 1:82])
    assert np.all(np.abs(many - p) <= 5 * np.sqrt(p * (1 - p) / 4000) + 1e-9)


def test_bad_inputs():
    with pytest.raises(MmwsimError, match="bin window"):
        NoiseModel().bits(np.zeros((1, 2, 50)), np.random.default_rng(0))
    with pytest.raises(MmwsimError, match="out of range"):
        FingerprintSampler(np.zeros((3, 2, 120))).sample([3], np.random.default_rng(0))
    # a mask or a fraction is not read as receivers 0 and 1, or rounded down
    sampler = FingerprintSampler(np.zeros((3, 2, 120)))
    with pytest.raises(MmwsimError, match="boolean mask"):
        sampler.sample(np.array([True, False, True]), np.random.default_rng(0))
    with pytest.raises(MmwsimError, match="whole numbers, got 1.5"):
        sampler.sample(np.array([1.0, 1.5]), np.random.default_rng(0))
    assert sampler.sample(np.array([1.0, 2.0]), np.random.default_rng(0)).shape == (2, 2, 81)
    with pytest.raises(MmwsimError, match="sigma"):
        NoiseModel(-1.0)
    with pytest.raises(MmwsimError, match="threshold"):
        NoiseModel(6.0, float("nan"))


def test_numpy_and_torch_back_ends_are_one_model():
    """The torch back-end (estimation.noise) draws the bits and scores them like the numpy one."""
    import torch

    from estimation.noise import fingerprint_bits, log_detection_probabilities

    model = NoiseModel(6.0, -115.0, (0, 81))
    pdp = pdp_with_offsets()[0, :, 1:82]  # (8, 81)
    log_p, log_q = log_detection_probabilities(
        torch.from_numpy(pdp).double(), model.sigma_db, model.threshold_dbm
    )
    np.testing.assert_allclose(np.exp(log_p.numpy()), model.probability(pdp), rtol=1e-9, atol=1e-300)
    np.testing.assert_allclose(np.exp(log_q.numpy()), 1 - model.probability(pdp), rtol=1e-9, atol=1e-12)
    g = torch.Generator().manual_seed(0)
    many = fingerprint_bits(
        torch.from_numpy(np.repeat(pdp[None], 2000, 0)), model.sigma_db, model.threshold_dbm, g
    )
    check_tail(many.numpy(), model.sigma_db, 2000 * 81)
