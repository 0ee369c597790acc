"""Fingerprint sequences of trajectories: grid lookup (nearest, bilinear in dB), exact PDPs via a
function, and the loader with fresh noise (fast sampler and Gaussian noise alike). The grid
arrays are small in-test stand-ins with the data set's shapes (pdp (n_rx, n_beams, n_bins) dBm
with -inf, ReceiverGrid, valid); tests/test_trajectories_dataset.py runs on a real data set."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import norm

from mmwsim.constants import BINS as WINDOW
from mmwsim.errors import MmwsimError
from mmwsim.fingerprints import GridField, NoiseModel, TracedField
from mmwsim.scene import ReceiverGrid
from mmwsim.trajectories import SequenceLoader, Trajectories, TrajectoryError, pdp_sequences

FEATURE_BINS = slice(*WINDOW)

GRID = ReceiverGrid((10.0, 20.0), 2.0, (21, 16), 1.5)
BEAMS, BINS = 4, 120
NOSIG = 60  # bins from here on carry no signal


def field(xy: np.ndarray) -> np.ndarray:
    """A PDP linear in position (dB), so bilinear interpolation in dB is exact: (..., BEAMS, BINS)."""
    x, y = xy[..., 0, None, None], xy[..., 1, None, None]
    beam = np.arange(BEAMS)[:, None]
    k = np.arange(BINS)[None, :]
    return -60.0 - 0.5 * x - 0.25 * y - 3.0 * beam - 0.4 * k


@pytest.fixture
def dataset():
    xy = GRID.positions()[:, :2]
    pdp = field(xy).astype(np.float32)
    pdp[:, :, NOSIG:] = -np.inf
    return SimpleNamespace(grid=GRID, pdp=pdp, valid=np.ones(GRID.size, dtype=bool))


def grid_pdp(ds, **kw) -> GridField:
    return GridField(ds.grid, ds.pdp, ds.valid, **kw)


def _trajectories(rng, n=12, length=5) -> Trajectories:
    start = rng.uniform((12.0, 22.0), (45.0, 45.0), size=(n, 2))
    pos = start[:, None] + np.cumsum(rng.uniform(-1.5, 1.5, size=(n, length, 2)), axis=1) * [1, 0.5]
    return Trajectories(pos, np.ones(n), np.arange(n), np.zeros((n, length - 1)))


def test_nearest_lookup(dataset, rng):
    t = _trajectories(rng)
    pdp = pdp_sequences(grid_pdp(dataset), t)
    assert pdp.shape == (12, 5, BEAMS, BINS) and pdp.dtype == np.float32
    snapped = np.rint((t.positions - GRID.origin) / GRID.spacing) * GRID.spacing + GRID.origin
    assert np.allclose(pdp[..., :NOSIG], field(snapped)[..., :NOSIG], atol=1e-3)
    assert np.all(pdp[..., NOSIG:] == -np.inf)


def test_bilinear_lookup_in_db_is_exact_for_linear_field(dataset, rng):
    t = _trajectories(rng)
    pdp = grid_pdp(dataset, method="linear", bins=FEATURE_BINS).pdp_at(t.positions)
    assert pdp.shape == (12, 5, BEAMS, 81)
    want = field(t.positions)[..., 1:82]
    k = NOSIG - 1
    assert np.allclose(pdp[..., :k], want[..., :k], atol=2e-3)
    assert np.all(pdp[..., k:] == -np.inf)


def test_linear_lookup_ignores_invalid_points(dataset):
    ds = dataset
    bad = 3 + GRID.shape[0] * 4  # grid point (16, 28)
    ds.valid[bad] = False
    ds.pdp[bad] = 50.0  # garbage where there is no data
    p = np.array([[[16.5, 28.5]]])  # next to the invalid point
    got = grid_pdp(ds, method="linear").pdp_at(p)[0, 0, :, :NOSIG]
    corners = np.array([[18.0, 28.0], [16.0, 30.0], [18.0, 30.0]])
    vals = field(corners)[:, :, :NOSIG]
    assert np.all(got >= vals.min(axis=0) - 1e-3) and np.all(got <= vals.max(axis=0) + 1e-3)


def test_traced_pdp_at_continuous_positions(rng):
    t = _trajectories(rng)
    heights = []

    def trace(points):
        heights.append(points[:, 2])
        return field(points[:, :2])

    pdp = pdp_sequences(TracedField(trace, height=1.5, bins=FEATURE_BINS), t)
    assert np.allclose(pdp, field(t.positions)[..., 1:82], atol=1e-3)
    assert np.all(np.concatenate(heights) == 1.5)


def test_noise_statistics_match_closed_form(rng):
    threshold, sigma = -115.0, 6.0
    delta = np.array([-9.0, -3.0, 0.0, 4.0, 12.0, -np.inf])
    pdp = np.broadcast_to(threshold + delta, (20000, 6))
    bits = NoiseModel(sigma, threshold, (0, 6)).bits(pdp, rng)
    assert bits.dtype == np.uint8
    assert np.allclose(bits.mean(axis=0), norm.cdf(delta / sigma), atol=0.012)
    assert np.array_equal(NoiseModel(0.0, threshold, (0, 6)).bits(pdp[:1], rng)[0], delta >= 0)
    np.testing.assert_allclose(NoiseModel(sigma, threshold).probability(pdp[0]), norm.cdf(delta / sigma))


def test_loader_batches_fresh_noise_and_determinism(dataset, rng):
    t = _trajectories(rng, n=10, length=7)
    source = grid_pdp(dataset, bins=FEATURE_BINS)
    loader = SequenceLoader(source, t, batch_size=4, seed=9)
    epoch1 = list(loader)
    assert len(loader) == 3 and [b[0].shape for b in epoch1] == [(4, 7, BEAMS, 81)] * 2 + [(2, 7, BEAMS, 81)]
    fp, pos = epoch1[0]
    assert fp.dtype == np.float32 and pos.dtype == np.float32 and pos.shape == (4, 7, 2)
    seen = np.concatenate([b[1] for b in epoch1])
    assert sorted(map(tuple, seen[:, 0].round(3))) == sorted(
        map(tuple, t.positions[:, 0].astype(np.float32).round(3))
    )
    epoch2 = list(loader)
    assert not all(
        np.array_equal(a[0], b[0]) for a, b in zip(epoch1, epoch2, strict=True)
    )  # fresh noise and order
    again = SequenceLoader(source, t, batch_size=4, seed=9, cache=False)
    assert all(
        np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) for a, b in zip(epoch1, again, strict=True)
    )
    # Bins without signal never fire; a static user gets independent noise at every step.
    static = Trajectories(np.full((1, 7, 2), 30.0), [0], [0], np.zeros((1, 6)))
    fp = next(iter(SequenceLoader(source, static, batch_size=1, sigma_db=6.0, threshold_dbm=-110.0)))[0][0]
    assert not fp[:, :, NOSIG - 1 :].any() and fp[:, :, : NOSIG - 1].any()
    assert len({fp[k].tobytes() for k in range(7)}) > 1


def test_fast_sampler_draws_the_gaussian_distribution(dataset, rng):
    """The nearest lookup draws through a FingerprintSampler: exactly the thresholded PDP rows
    without noise, and the Gaussian tail probabilities with it (as the Gaussian-noise path)."""
    t = _trajectories(rng, n=40, length=6)
    source = grid_pdp(dataset, bins=FEATURE_BINS)
    pdp = source.pdp_at(t.positions)
    exact = SequenceLoader(source, t, batch_size=40, sigma_db=0.0, threshold_dbm=-100.0, shuffle=False)
    assert exact.sampler is not None and exact.sampler.noise.bins == (1, 82)
    bits = next(iter(exact))[0]
    assert np.array_equal(bits, (pdp >= -100.0).astype(np.float32))
    # one static user repeated: the fraction of ones per entry against Q((threshold - PDP) / sigma)
    static = Trajectories(
        np.full((3000, 3, 2), [30.0, 40.0]), np.zeros(3000), np.arange(3000), np.zeros((3000, 2))
    )
    want = NoiseModel(6.0, -100.0).probability(source.pdp_at(static.positions[:1, :1])[0, 0])
    for fast in (True, False):
        loader = SequenceLoader(
            source, static, batch_size=3000, sigma_db=6.0, threshold_dbm=-100.0, fast=fast
        )
        assert (loader.sampler is not None) == fast
        got = next(iter(loader))[0].reshape(-1, BEAMS, 81).mean(axis=0)
        assert np.abs(got - want).max() < 0.02  # 9000 draws: 4.5 standard errors at p = 1/2
    # interpolated PDPs have no grid row: Gaussian noise on them
    assert SequenceLoader(grid_pdp(dataset, method="linear", bins=FEATURE_BINS), t).sampler is None


def test_loader_bad_parameters(dataset, rng):
    t = _trajectories(rng)
    with pytest.raises(TrajectoryError, match="batch size"):
        SequenceLoader(grid_pdp(dataset), t, batch_size=0)
    with pytest.raises(MmwsimError, match="sigma"):
        SequenceLoader(grid_pdp(dataset), t, sigma_db=-1.0)
    with pytest.raises(MmwsimError, match="does not fit"):
        GridField(GRID, np.zeros((5, 2, 3)))


def test_traced_pdp_from_scene_matches_grid_trace():
    """Exact tracing at continuous positions agrees with the grid trace where they coincide."""
    import scenes
    from mmwsim.antennas import make_codebook
    from mmwsim.fingerprints import power_delay_profile
    from mmwsim.tracer import trace

    scene = scenes.load("street_canyon")
    grid_pdp = power_delay_profile(
        trace(scene, n_rays=20000), make_codebook("rotating_horn", scene.frequency)
    )
    source = TracedField.from_scene(scene, n_rays=20000)
    on_grid = scene.receivers.positions()[[3, 10, 50], :2]
    assert np.array_equal(
        source.pdp_at(on_grid[None])[0], GridField(scene.receivers, grid_pdp).pdp_at(on_grid)
    )
    off = on_grid + [1.3, 0.7]
    assert not np.array_equal(source.pdp_at(off), GridField(scene.receivers, grid_pdp).pdp_at(off))


def test_traced_field_traces_at_its_receiver_height():
    """The height a traced field is built for is the z of every traced point (not the grid's)."""
    import scenes
    from mmwsim.antennas import make_codebook
    from mmwsim.fingerprints import power_delay_profile
    from mmwsim.tracer import Tracer

    scene = scenes.load("ground_only")
    xy = np.array([[30.0, 0.0], [0.0, -45.0]])
    high = TracedField.from_scene(scene, n_rays=20000, height=4.0).pdp_at(xy)
    low = TracedField.from_scene(scene, n_rays=20000).pdp_at(xy)  # the grid's 1.5 m
    book = make_codebook("rotating_horn", scene.frequency)
    at4 = power_delay_profile(Tracer(scene, n_rays=20000).trace(np.column_stack([xy, [4.0, 4.0]])), book)
    np.testing.assert_array_equal(high, at4)
    # over ground the two-ray interference differs with the receiver height
    fin = np.isfinite(high) & np.isfinite(low)
    assert fin.any() and np.abs(high[fin] - low[fin]).max() > 0.5
