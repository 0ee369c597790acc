"""Steady users at speeds the training users did not keep: the sub-cell table measured on the
training trajectories at other speeds (``speed_scaled``), and the filter that tells it from the
measured table by their sub-cell evidence (``CandidateFilter(fine_weighed=...)``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from estimation.metrics import trajectory_rmse
from estimation.smoothing.motion import WALK_COPIES, WALK_SCALES, MotionTable, snap_to_lattice, speed_scaled
from estimation.smoothing.online import WALKER_SPEED_PRIOR, CandidateFilter


def _drivers(n, speed, seed, length=7):
    """Users at exactly ``speed`` grid units per step along one of the grid's axes (as vehicles on
    streets along grid lines), from anywhere."""
    rng = np.random.default_rng(seed)
    axis = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])[rng.integers(0, 4, n)]
    start = rng.uniform(0, 100, (n, 2))
    return start[:, None] + speed * np.arange(length)[None, :, None] * axis[:, None]


def _walkers(n, speed, seed, length=7, turn=0.15):
    """Users at ``speed`` grid units per step from anywhere, heading anywhere and turning a little
    (``turn`` radians rms per step), as people on foot in open space."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0, 2 * np.pi, (n, 1)) + np.cumsum(rng.normal(0, turn, (n, length - 1)), 1)
    steps = speed * np.stack([np.cos(heading), np.sin(heading)], -1)
    start = rng.uniform(0, 100, (n, 1, 2))
    return np.concatenate([start, start + np.cumsum(steps, 1)], 1)


def _cell_candidates(true):
    """Each step's 3 x 3 grid points around the one the user is nearest to, the nearest most likely:
    a fingerprint tells its grid point, never where in the cell the user is."""
    cell = np.rint(true)
    off = np.stack(np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]), -1).reshape(-1, 2)
    xy = cell[:, :, None] + off
    score = -5.0 * np.abs(off).sum(-1) * np.ones(true.shape[:2] + (1,))
    return torch.from_numpy(xy).float(), torch.from_numpy(score).float()


def test_speed_scaled_copies_are_the_paths_scaled_about_their_start_and_shifted():
    p = _drivers(50, 8.0, 0)
    out = speed_scaled(p, spread=0.2, copies=3, seed=4)
    assert out.shape == (150, 7, 2)
    np.testing.assert_array_equal(out, speed_scaled(p, spread=0.2, copies=3, seed=4))
    for c in range(3):
        q = out[c * 50 : (c + 1) * 50]
        step, orig = np.diff(q, axis=1), np.diff(p, axis=1)
        scale = np.linalg.norm(step, axis=-1) / np.linalg.norm(orig, axis=-1)
        assert np.allclose(scale, scale[:, :1])  # one factor per copy of a trajectory
        assert 0.8 <= scale.min() and scale.max() <= 1.2 and scale.std() > 0.05
        shift = q[:, 0] - p[:, 0]  # the start moves by under one unit along each axis
        assert (shift >= 0).all() and (shift < 1).all()
    assert not np.array_equal(out, speed_scaled(p, seed=5))
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="spread"):
            speed_scaled(p, spread=bad)
    with pytest.raises(ValueError, match="copies"):
        speed_scaled(p, copies=0)
    with pytest.raises(ValueError, match="shape"):
        speed_scaled(p[0])


def test_speed_scaled_copies_from_ranges_take_factors_from_either_range_alone():
    p = _drivers(400, 2.0, 0)
    out = speed_scaled(p, copies=2, seed=1, ranges=WALK_SCALES)
    assert out.shape == (800, 7, 2)
    np.testing.assert_array_equal(out, speed_scaled(p, copies=2, seed=1, ranges=WALK_SCALES))
    step = np.linalg.norm(np.diff(out, axis=1), axis=-1) / 2.0
    assert np.allclose(step, step[:, :1])
    scale = step[:, 0]
    (a, b), (c, d) = WALK_SCALES
    low, high = (a <= scale) & (scale <= b), (c <= scale) & (scale <= d)
    assert (low | high).all() and 0.4 < low.mean() < 0.6  # never between them, both alike
    assert scale.min() < a + 0.05 and scale.max() > d - 0.05
    for bad in ((), ((0.5,),), ((0.0, 0.8),), ((0.8, 0.5),), ((0.5, float("inf")),)):
        with pytest.raises(ValueError, match="range"):
            speed_scaled(p, ranges=bad)


def test_the_scaled_table_tracks_steady_users_at_other_speeds_and_ours_as_well():
    """Measured on users at 8 units per step (24 lattice steps: on the lattice they never
    accelerate), the sub-cell table takes a steady user at 9.5 (28.5: 28 and 29 in turn) for one
    that keeps changing speed. Weighed against it by the sub-cell evidence, the table measured on
    the same users at other speeds tracks those users closer (0.32 against 0.41 units; by the
    cell-level evidence, which cannot tell the two apart, 0.36), and ours as well as before."""
    train = _drivers(3000, 8.0, 1)
    cell = MotionTable().fit(np.rint(train))
    measured = MotionTable.lattice().fit(snap_to_lattice(train))
    scaled = MotionTable.lattice().fit(snap_to_lattice(speed_scaled(train)))
    err, weight = {}, {}
    for name, speed in (("ours", 8.0), ("other", 9.5)):
        true = _drivers(200, speed, 2)
        xy, score = _cell_candidates(true)
        runs = {
            "measured": CandidateFilter(cell, measured, k=9),
            "cell-weighed": CandidateFilter(cell, measured, k=9, alternative=(cell, scaled)),
            "fine-weighed": CandidateFilter(
                cell, measured, k=9, alternative=(cell, scaled), fine_weighed=(0,)
            ),
        }
        for key, f in runs.items():
            f.run(xy, score)
            err[name, key] = trajectory_rmse(f.smooth()[2].double().numpy(), true).mean()
        weight[name] = runs["fine-weighed"].model_weights()[:, 1].mean()
        # the cell-level tables are one: by the cell evidence alone the weights stay the priors
        np.testing.assert_allclose(runs["cell-weighed"].model_weights(), np.tile([0.5, 0.5], (200, 1)))
    assert weight["ours"] < 0.2 and weight["other"] > 0.8, weight
    assert err["other", "fine-weighed"] < 0.85 * err["other", "measured"], err
    assert err["other", "fine-weighed"] < 0.95 * err["other", "cell-weighed"], err
    assert err["ours", "fine-weighed"] <= 1.05 * err["ours", "measured"], err


def test_fine_weighed_models_need_sub_cell_tables_and_an_identical_one_keeps_the_priors():
    train = _drivers(500, 8.0, 3)
    cell = MotionTable().fit(np.rint(train))
    fine = MotionTable.lattice().fit(snap_to_lattice(train))
    xy, score = _cell_candidates(_drivers(20, 8.0, 4))
    f = CandidateFilter(
        cell,
        fine,
        k=9,
        alternative=[(cell.broadened(), None), (cell, fine)],
        alternative_prior=0.4,
        fine_weighed=(1,),
    ).run(xy, score)
    w = f.model_weights()
    # the same tables: the measured model and its copy share their joint weight by the priors
    np.testing.assert_allclose(w[:, 2] / (w[:, 0] + w[:, 2]), 0.2 / 0.8, rtol=1e-9)
    np.testing.assert_allclose(w.sum(1), 1.0)
    with pytest.raises(ValueError, match="sub-cell"):
        CandidateFilter(cell, fine, alternative=[(cell.broadened(), None)], fine_weighed=(0,))
    with pytest.raises(ValueError, match="sub-cell"):
        CandidateFilter(cell, None, alternative=[(cell, fine)], fine_weighed=(0,))
    for bad in ((1,), (-1,)):
        with pytest.raises(ValueError, match="indices"):
            CandidateFilter(cell, fine, alternative=[(cell, fine)], fine_weighed=bad)


def test_the_walkers_tables_at_other_speeds_track_walkers_at_paces_of_their_own():
    """Measured on walkers at 1.4 units per step, the tables mark walkers at 0.7 or 2.4 as
    speeding up or slowing down at every step. The same walkers at speeds scaled by
    WALK_SCALES, weighed at a prior of WALKER_SPEED_PRIOR alone, take the slower ones from 0.35
    to 0.23 units and the faster from 0.30 to 0.26, and leave ours where they were: they
    explain them worse than the measured tables (weight about 0.001)."""
    train = _walkers(3000, 1.4, 1, length=15)
    cell, fine = MotionTable().fit(np.rint(train)), MotionTable.lattice().fit(snap_to_lattice(train))
    u = speed_scaled(train, copies=WALK_COPIES, ranges=WALK_SCALES)
    walk = (MotionTable().fit(np.rint(u)), MotionTable.lattice().fit(snap_to_lattice(u)))
    err, weight = {}, {}
    for speed in (0.7, 1.4, 2.4):
        true = _walkers(300, speed, 2)
        xy, score = _cell_candidates(true)
        plain = CandidateFilter(cell, fine, k=9).run(xy, score)
        both = CandidateFilter(cell, fine, k=9, alternative=[walk], alternative_prior=(WALKER_SPEED_PRIOR,))
        both.run(xy, score)
        err[speed] = [trajectory_rmse(f.smooth()[2].double().numpy(), true).mean() for f in (plain, both)]
        weight[speed] = both.model_weights()[:, 1].mean()
    assert err[0.7][1] < 0.75 * err[0.7][0] and err[2.4][1] < 0.92 * err[2.4][0], err
    assert err[1.4][1] < 1.01 * err[1.4][0] and weight[1.4] < 0.02, (err, weight)
    assert weight[0.7] > 0.9 and weight[2.4] > 0.9, weight
