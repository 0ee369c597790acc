"""Walkers smoothed along straight lines at the measured speeds (estimation.smoothing.line)."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from estimation import Estimator, TrainConfig
from estimation import estimator as estimator_module
from estimation.smoothing import line
from estimation.smoothing.line import (
    LINE_BINS,
    LINE_MIN_STEPS,
    LINE_SHIFT,
    line_track,
    line_weight,
    walk_speeds,
)
from estimation.smoothing.motion import MotionTable
from estimation.synthetic import toy_sequence_set
from tests.helpers.candidates import grid_candidates


def _speeds(*steps: float, n: int = 120) -> np.ndarray:
    """A measured speed prior with its steps ``steps`` grid spacings long, in equal shares."""
    p = np.zeros(n)
    for s in steps:
        p[int(round(s * LINE_BINS))] += 1.0 / len(steps)
    return p


def _walkers(n: int, step: float, T: int = 7, seed: int = 0) -> np.ndarray:
    """``n`` straight walks at ``step`` metres per step, at any phase and heading."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(0, 2 * np.pi, n)
    start = rng.uniform(0, 1, (n, 2)) + 20.0
    heading = np.stack([np.cos(h), np.sin(h)], -1)
    return start[:, None] + step * np.arange(T)[None, :, None] * heading[:, None]


def test_steady_walkers_are_found_inside_their_cells():
    # 1.4 m per step at a known speed: the cells' edges cut the line at many phases, which read
    # the walk to well inside a cell (the per-step cells are 0.38 m off)
    true = _walkers(40, 1.4)
    xy, lp, cells = grid_candidates(true)
    track, delta = line_track(cells, xy, lp, _speeds(1.4), 1.0)
    err = np.linalg.norm(track - true, axis=-1).mean()
    assert err < 0.5 * np.linalg.norm(cells - true, axis=-1).mean()
    assert (line_weight(delta) > 0.5).all()
    # a speed prior that misses the walk's speed by more than LINE_SPEEDS weighs no line
    _, slower = line_track(cells, xy, lp, _speeds(0.5), 1.0)
    assert np.isneginf(slower).all()


def test_a_walker_who_turns_is_left_to_the_smoother():
    t = np.arange(7.0)
    true = np.stack([20.3 + 1.4 * np.minimum(t, 3), 20.6 + 1.4 * np.maximum(t - 3, 0)], -1)[None]
    xy, lp, cells = grid_candidates(true)
    _, delta = line_track(cells, xy, lp, _speeds(1.4), 1.0)
    assert line_weight(delta)[0] < 0.01
    straight = _walkers(1, 1.4, seed=3)
    xy, lp, cells = grid_candidates(straight)
    assert line_track(cells, xy, lp, _speeds(1.4), 1.0)[1][0] > delta[0] + 20.0


def test_the_pass_is_the_posterior_mean_over_its_lines(monkeypatch):
    # the compiled pass against every line's likelihood read from the candidates directly, in
    # one stage (the later ones draw the same lines within a smaller box)
    monkeypatch.setattr(line, "LINE_STAGES", 1)
    true = _walkers(3, 1.1, T=5, seed=5)
    xy, lp, cells = grid_candidates(true, radius=2)
    lp = lp + np.random.default_rng(1).uniform(-2, 0, lp.shape)
    speeds = _speeds(1.1, 1.15, 1.4)
    track, delta = line_track(cells, xy, lp, speeds, 1.0)
    T = 5
    ts = np.arange(T) - (T - 1) / 2
    for b in range(3):
        c = cells[b].mean(0)
        v = (ts[:, None] * cells[b]).sum(0) / (ts**2).sum()
        s0, h0 = np.hypot(*v), np.arctan2(v[1], v[0])
        j = np.flatnonzero(speeds > 0)
        j = j[np.abs(j / LINE_BINS - s0) <= line.LINE_SPEEDS]
        o = line._OFFSETS
        centre = c + (2 * o[:, :2] - 1) * line.LINE_REACH
        h = h0 + (2 * o[:, 2] - 1) * line.LINE_TURN
        jb = j[np.minimum((o[:, 3] * len(j)).astype(int), len(j) - 1)]
        u = (jb / LINE_BINS)[:, None] * np.stack([np.cos(h), np.sin(h)], -1)
        p = centre[:, None] + ts[None, :, None] * u[:, None]  # (N, T, 2)
        at = np.rint(p)[:, :, None] == xy[b][None]  # (N, T, K, 2)
        hit = at.all(-1)
        step_ll = np.where(hit, lp[b][None], -np.inf).max(-1)
        step_ll = np.where(np.isfinite(step_ll), step_ll, lp[b].min(-1)[None])
        ll = np.log(speeds[jb]) + step_ll.sum(1)
        w = np.exp(ll - ll.max())
        assert np.allclose(track[b], (w[:, None, None] * p).sum(0) / w.sum(), atol=1e-9)
        expected = ll.max() + np.log(w.mean()) - lp[b].max(-1).sum()
        assert delta[b] == pytest.approx(expected, abs=1e-9)


def test_a_second_stage_reads_the_posterior_as_many_more_lines_do(monkeypatch):
    # steady walkers at speeds between the measured ones, candidates with noisy likelihoods: the
    # two-stage pass lies nearer one stage of 32 times its lines than one stage of its own does
    true = _walkers(24, 1.23, seed=7)
    xy, lp, cells = grid_candidates(true, radius=2)
    lp = lp + np.random.default_rng(2).normal(0, 1.5, lp.shape)
    speeds = _speeds(1.1, 1.15, 1.2, 1.25, 1.3, 1.4)
    two, d_two = line_track(cells, xy, lp, speeds, 1.0)
    monkeypatch.setattr(line, "LINE_STAGES", 1)
    one, d_one = line_track(cells, xy, lp, speeds, 1.0)
    monkeypatch.setattr(line, "_OFFSETS", line._offsets(32 * line.LINE_LINES))
    dense, d_dense = line_track(cells, xy, lp, speeds, 1.0)
    off_two = np.linalg.norm(two - dense, axis=-1).mean()
    off_one = np.linalg.norm(one - dense, axis=-1).mean()
    assert off_two < 0.5 * off_one
    # and its evidence is the same integral: as near the dense one's as the first stage's is
    assert np.abs(d_two - d_dense).mean() < max(np.abs(d_one - d_dense).mean(), 0.05)


def test_a_stage_narrows_its_speed_bins_to_the_posterior():
    # bins 10..19 of a table; the posterior holds bins 13 and 15 (bin 17's share is below 1e-4):
    # the next stage reads 12..16, one more either side, and never leaves 10..19
    mass = np.zeros(10)
    mass[[3, 5, 7]] = [0.6, 0.4, 0.5e-4]
    assert line.narrow_bins(mass, 10, 19, 1.0) == (12, 16)
    edge = np.zeros(10)
    edge[[0, 9]] = 0.5
    assert line.narrow_bins(edge, 10, 19, 1.0) == (10, 19)
    assert line.narrow_bins(np.ones(1), 4, 4, 1.0) == (4, 4)


def test_walk_speeds_are_measured_on_the_walkers():
    t = np.arange(5.0)
    walkers = np.stack(
        [
            np.stack([1.4 * t, np.zeros(5)], -1),
            np.stack([np.r_[0, 1.4, 1.4, 2.8, 4.5], np.ones(5)], -1),  # a stop, then faster
        ]
    )
    driver = np.stack([8.0 * t, np.zeros(5)], -1)[None]
    static = np.zeros((1, 5, 2))
    speeds = walk_speeds(np.concatenate([walkers, driver, static]), 5.0)
    assert np.flatnonzero(speeds).tolist() == [28, 34]  # 1.4 and 1.7 spacings, the stop left out
    assert speeds[28] == pytest.approx(6 / 7) and speeds.sum() == pytest.approx(1.0)
    assert not len(walk_speeds(np.concatenate([driver, static]), 5.0))
    assert np.array_equal(
        MotionTable().fit_walks(walkers, 5.0).walk_speeds.numpy(), walk_speeds(walkers, 5.0)
    )
    with pytest.raises(ValueError):
        MotionTable().fit_walks(np.full((1, 3, 2), np.nan), 5.0)


def test_the_lines_weight_rises_with_their_evidence():
    d = np.array([-np.inf, LINE_SHIFT - 20, LINE_SHIFT, LINE_SHIFT + 1, LINE_SHIFT + 20])
    w = line_weight(d)
    assert w[0] == 0.0 and w[2] == pytest.approx(0.5) and np.all(np.diff(w) > 0) and w[-1] > 0.99


def _estimator(walk: np.ndarray | None, fit: bool = True) -> Estimator:
    """A toy ``tn-match`` with its tables measured (``fit``), its walk speeds ``walk`` where
    given."""
    tr = toy_sequence_set(128, 5, seed=1)
    cfg = TrainConfig(model="tn-match", options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, tr.n_beams, tr.n_bins, tr.normaliser())
    if fit:
        est.net.fit_motion(tr.positions, tr.grid_xy, tr.index)
        assert len(est.net.motion_fine.walk_speeds)  # measured on the toy walkers
    if walk is not None:
        est.net.motion_fine.walk_speeds = torch.from_numpy(walk)
    return est.attach(tr)


def test_estimator_mixes_its_walkers_with_their_lines(monkeypatch):
    est = _estimator(_speeds(1.4))
    true = _walkers(8, 1.4, T=6)
    xy, lp, cells = grid_candidates(true, radius=2)
    x = (torch.from_numpy(xy).float(), torch.from_numpy(lp).float()[..., None])
    tracked = torch.from_numpy(cells).float()
    err = np.linalg.norm(est._along_lines(tracked, x).numpy() - true, axis=-1).mean()
    assert err < 0.6 * np.linalg.norm(cells - true, axis=-1).mean()
    # at the measured speeds alone, the lines' track mixed with the tracked one by its weight
    monkeypatch.setattr(estimator_module, "WALK_FREE_PRIOR", 0.0)
    out = est._along_lines(tracked, x)
    line_xy, delta = line_track(cells, xy.astype(np.float32), lp.astype(np.float32), _speeds(1.4), 1.0)
    w = line_weight(delta)[:, None, None]
    assert np.allclose(out.numpy(), w * line_xy + (1 - w) * cells, atol=1e-5)
    # drivers (faster than the place tables' speed), short sequences, the switch: left alone
    fast = torch.from_numpy(np.rint(_walkers(2, 8.0, T=6))).float()
    assert est._along_lines(fast, (x[0][:2], x[1][:2])) is fast
    short = tracked[:, : LINE_MIN_STEPS - 1]
    assert est._along_lines(short, (x[0][:, :3], x[1][:, :3])) is short
    est.line_tracking = False
    assert est._along_lines(tracked, x) is tracked


def test_a_model_saved_without_walk_speeds_loads_without_the_pass():
    est = _estimator(_speeds(1.4))
    state = {k: v for k, v in est.net.state_dict().items() if not k.endswith("walk_speeds")}
    old = _estimator(None, fit=False)  # as Estimator.load builds it, then loads the saved state
    old.net.load_state_dict(state)
    assert not len(old.net.motion_fine.walk_speeds)
    tracked = torch.from_numpy(np.rint(_walkers(2, 1.4, T=6))).float()
    xy, lp, _ = grid_candidates(tracked.numpy(), radius=1)
    x = (torch.from_numpy(xy).float(), torch.from_numpy(lp).float()[..., None])
    assert old._along_lines(tracked, x) is tracked
    # and one saved with them keeps them
    buf = io.BytesIO()
    torch.save(est.net.state_dict(), buf)
    buf.seek(0)
    again = _estimator(None, fit=False)
    again.net.load_state_dict(torch.load(buf, weights_only=True))
    assert torch.equal(again.net.motion_fine.walk_speeds, est.net.motion_fine.walk_speeds)


def test_prediction_mixes_its_walkers_with_their_lines():
    from estimation.noise import noisy_bits

    est = _estimator(None)  # the toy walkers' own speeds
    tr = toy_sequence_set(32, 6, seed=2)
    x = est.inputs(noisy_bits(tr, 6.0, torch.Generator().manual_seed(0)).float())
    est.line_tracking = False
    plain = est.predict(x)
    est.line_tracking = True
    mixed = est.predict(x)
    assert torch.allclose(mixed, est._along_lines(plain, x)) and not torch.equal(mixed, plain)
