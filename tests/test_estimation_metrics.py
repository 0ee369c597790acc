"""Metrics against hand-computed values; the Kalman smoother and fingerprint matcher on synthetic data."""

from __future__ import annotations

import io
import math
import sys

import numpy as np
import pytest
import torch

from estimation import (
    FingerprintMatcher,
    kalman_forecast,
    rts_smoother,
    summarise,
    summarise_by_kind,
    trajectory_rmse,
)
from estimation.noise import fingerprint_bits
from estimation.synthetic import toy_grid
from mmwsim.trajectories import KINDS


def test_trajectory_rmse_by_hand():
    true = np.zeros((2, 2, 2))
    pred = np.array(
        [
            [[3.0, 4.0], [0.0, 0.0]],  # errors 5 and 0 -> sqrt(25 / 2)
            [[1.0, 0.0], [0.0, 1.0]],
        ]
    )  # errors 1 and 1 -> 1
    assert np.allclose(trajectory_rmse(pred, true), [math.sqrt(12.5), 1.0])
    with pytest.raises(ValueError):
        trajectory_rmse(pred[:, :1], true)


def test_summaries_by_hand():
    r = np.arange(1.0, 21.0)  # 1..20
    s = summarise(r)
    assert s["n"] == 20 and s["mean"] == 10.5 and s["median"] == 10.5
    assert s["p95"] == pytest.approx(19.05)  # position 0.95 * 19 = 18.05 -> 19 + 0.05 * (20 - 19)
    kind = np.array([KINDS.index("pedestrian")] * 10 + [KINDS.index("vehicle")] * 10)
    by = summarise_by_kind(r, kind)
    assert by["pedestrian"]["mean"] == 5.5 and by["vehicle"]["mean"] == 15.5 and by["all"]["n"] == 20
    assert math.isnan(summarise(np.array([]))["mean"])


def _cv_tracks(n=300, T=15, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T)
    p0, v = rng.uniform(0, 100, (n, 2)), rng.normal(0, 5, (n, 2))
    return p0[:, None] + v[:, None] * t[None, :, None]


def test_rts_smoother_on_constant_velocity_track():
    true = _cv_tracks()
    # exact measurements of a constant-velocity track are kept (up to the prior on the first step)
    assert np.abs(rts_smoother(true, q=0.01, r=0.01)[:, 1:] - true[:, 1:]).max() < 1e-3
    rng = np.random.default_rng(1)
    z = true + rng.normal(0, 3.0, true.shape)
    raw = trajectory_rmse(z, true).mean()
    smooth = trajectory_rmse(rts_smoother(z, q=0.01, r=3.0), true).mean()
    assert raw == pytest.approx(3 * math.sqrt(2), rel=0.05)
    # a line fitted to 15 points: error ~ r sqrt(2 * 2 / 15) in theory; allow some slack
    assert smooth < 0.45 * raw
    # gating removes a gross outlier that would otherwise drag the track
    z_out = true.copy()
    z_out[:, 7] += 80.0
    gated = rts_smoother(z_out, q=0.1, r=1.0, gate=4.0)
    assert (
        trajectory_rmse(gated, true).mean()
        < 0.5
        < trajectory_rmse(rts_smoother(z_out, q=0.1, r=1.0), true).mean()
    )


def test_kalman_forecast_extrapolates_constant_velocity():
    true = _cv_tracks(T=8)
    pred = kalman_forecast(true[:, :5], 3, q=0.01, r=0.01)
    assert np.abs(pred - true[:, 5:]).max() < 0.05


def test_matcher_finds_the_right_grid_point():
    xy, pdp = toy_grid(12, 12, n_beams=6, n_bins=10, seed=2)
    m = FingerprintMatcher(torch.from_numpy(pdp), xy, sigma=3.0, threshold=-115.0)
    rows = np.arange(0, len(xy), 7)
    exact = torch.from_numpy(pdp[rows] >= -115.0).float()
    assert np.array_equal(m.match(exact), xy[rows])  # noiseless fingerprints: the point itself
    noisy = fingerprint_bits(torch.from_numpy(pdp[rows]), 3.0, -115.0, torch.Generator().manual_seed(0))
    err = np.linalg.norm(m.match(noisy[None])[0] - xy[rows], axis=-1)
    assert np.median(err) <= 1.0
    # chunking over grid points does not change the result
    m2 = FingerprintMatcher(torch.from_numpy(pdp), xy, sigma=3.0, threshold=-115.0, chunk=13)
    assert np.array_equal(m2.match(noisy), m.match(noisy))


def test_track_candidates_look_where_the_user_goes_when_a_fingerprint_says_nothing():
    # 40 x 40 points 1 m apart; only the strip x < 5 has signal (every point its own bins), the
    # rest none: an empty fingerprint there is equally likely at 1400 points
    g = np.arange(40.0)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    pdp = np.full((len(xy), 1, 200), -np.inf, dtype=np.float32)
    lit = np.flatnonzero(xy[:, 0] < 5)
    pdp[lit, 0, np.arange(len(lit))] = -100.0
    m = FingerprintMatcher(torch.from_numpy(pdp), xy, sigma=3.0, threshold=-115.0)
    # a user at 2 m per step along y = 20: three steps in the strip, then two without signal
    path = np.stack([np.arange(0.0, 10.0, 2.0), np.full(5, 20.0)], -1)
    rows = [int(np.flatnonzero((xy == p).all(1))[0]) for p in path]
    bits = torch.from_numpy(pdp[rows] >= -115.0).float()[None]
    xy_g, score_g, refs = m.track_candidates(bits, 8)
    score_p, rows_p = m.candidates(bits, 8)  # the plain top 8
    xy_p = torch.from_numpy(xy[rows_p.numpy()]).float()
    near = lambda c, t: float(np.linalg.norm(c[0, t].numpy() - path[t], axis=-1).min())  # noqa: E731
    # the informative steps keep their most likely points; the empty ones look where the user
    # goes, which the plain top 8 of 1400 ties do not
    assert torch.equal(xy_g[:, :3], xy_p[:, :3]) and torch.equal(score_g[:, :3], score_p[:, :3])
    assert near(xy_g, 3) == 0.0 and near(xy_g, 4) == 0.0
    assert near(xy_p, 3) > 5.0
    # the scores are the plain log-likelihoods of the points chosen
    chosen = [int(np.flatnonzero((xy == c).all(1))[0]) for c in xy_g[0, 3].numpy()]
    assert torch.allclose(score_g[0, 3], m.scores(bits[:, 3])[0, chosen])
    # a prefix's candidates are a prefix of the whole's, and a step at a time continues exactly
    one = m.track_candidates(bits[:, :4], 8)
    assert torch.equal(one[0], xy_g[:, :4]) and torch.equal(one[1], score_g[:, :4])
    step = m.track_candidates(bits[:, 4:], 8, one[2])
    assert torch.equal(step[0], xy_g[:, 4:]) and np.array_equal(step[2], refs)
    assert np.array_equal(refs[0], path[3:])
    # the users of a batch are searched as each alone: a second user leaves the strip a step in
    path2 = np.stack([np.arange(3.0, 13.0, 2.0), np.full(5, 10.0)], -1)
    rows2 = [int(np.flatnonzero((xy == p).all(1))[0]) for p in path2]
    both = torch.cat([bits, torch.from_numpy(pdp[rows2] >= -115.0).float()[None]])
    xy_b, score_b, refs_b = m.track_candidates(both, 8)
    alone = m.track_candidates(both[1:], 8)
    assert torch.equal(xy_b[:1], xy_g) and torch.equal(score_b[:1], score_g)
    assert torch.equal(xy_b[1:], alone[0]) and torch.equal(score_b[1:], alone[1])
    assert np.array_equal(refs_b, np.concatenate([refs, alone[2]]))
    assert all(np.linalg.norm(alone[0][0, t].numpy() - path2[t], axis=-1).min() == 0.0 for t in (2, 3, 4))


class _Offset:
    """A fake method that knows the truth and adds a fixed offset: RMSE is exactly |offset|."""

    task, t_obs, horizon, n_parameters, train_seconds, epochs = "tracking", 0, 0, 0, 0.0, 0

    def __init__(self, data, offset, name):
        self.data, self.offset, self.name = data, np.asarray(offset), name

    def for_sigma(self, sigma, validation):
        return self

    def predict_lengths(self, bits, lengths):
        assert bits.shape[:2] == self.data.index.shape
        return {L: (self.data.positions[:, :L] + self.offset, 0.0) for L in lengths}


def test_evaluation_bookkeeping_with_known_errors():
    from estimation import evaluate
    from estimation.synthetic import toy_sequence_set

    d = toy_sequence_set(20, 6, nx=16, ny=16, n_beams=4, n_bins=8, seed=4)
    methods = [_Offset(d, [0.0, 0.0], "oracle"), _Offset(d, [3.0, 4.0], "off5")]
    ev = evaluate(methods, {"test": d}, [6.0], None, lengths=[2, 4], table_length=5, log=lambda *a: None)
    assert {r["length"] for r in ev.rows} == {2, 4, 5}
    for r in ev.rows:
        assert r["mean"] == pytest.approx(0.0 if r["method"] == "oracle" else 5.0)
        assert r["p95"] == pytest.approx(r["mean"])
    kinds = {r["kind"] for r in ev.rows}
    assert "all" in kinds and kinds - {"all"} <= set(KINDS)
    assert ev.examples["test"]["off5"].shape[1:] == (5, 2)


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_evaluation_shows_a_bar_of_its_runs_on_a_terminal(monkeypatch):
    """One step per method, noise level and split, the runs' lines still logged; none with
    ``progress=False`` or where stderr is not a terminal."""
    from estimation import evaluate
    from estimation.synthetic import toy_sequence_set

    d = toy_sequence_set(12, 4, nx=16, ny=16, n_beams=4, n_bins=8, seed=4)
    methods = [_Offset(d, [0.0, 0.0], "oracle"), _Offset(d, [3.0, 4.0], "off5")]
    for progress, terminal, shown in ((True, True, True), (False, True, False), (True, False, False)):
        err = _Terminal() if terminal else io.StringIO()
        monkeypatch.setattr(sys, "stderr", err)
        lines: list[str] = []
        evaluate(
            methods, {"a": d, "b": d}, [6.0, 9.0], None, table_length=4, progress=progress, log=lines.append
        )
        assert len(lines) == 8  # 2 methods x 2 noise levels x 2 splits
        assert ("evaluate:" in err.getvalue() and "/8 [" in err.getvalue()) == shown


def test_matcher_likelihood_is_exact_far_in_the_tails():
    """Log-likelihoods are built in log space: a bit 95 dB below threshold that fires costs its
    exact log probability (about -500), not an underflow to -inf, down to the floor ``log eps``."""
    pdp = torch.tensor([[[-110.0, -210.0, -float("inf")]], [[-120.0, -116.0, -114.0]]])  # (G=2, M=1, 3)
    xy = np.array([[0.0, 0.0], [1.0, 0.0]])
    bits = torch.tensor([[[1.0, 1.0, 0.0]], [[0.0, 0.0, 1.0]]])
    m = FingerprintMatcher(pdp, xy, sigma=3.0, threshold=-115.0, eps=1e-300)
    got = m.scores(bits).double()
    z = (pdp.double().reshape(2, 3) - -115.0) / 3.0
    log_p, log_q = torch.special.log_ndtr(z), torch.special.log_ndtr(-z)
    floor = math.log(1e-300)
    log_p, log_q = log_p.clamp(min=floor), log_q.clamp(min=floor)
    x = bits.reshape(2, 3).double()
    want = x @ log_p.T + (1 - x) @ log_q.T  # (fingerprints, grid points)
    assert torch.isfinite(got).all()
    assert torch.allclose(got, want, rtol=1e-4)
    assert float(want[0, 0]) < -400  # the second bit of fingerprint 0 is far in the tail
