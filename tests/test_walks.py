"""The walkers' passes composed, with a second search for fast walkers (estimation.smoothing.walks)."""

from __future__ import annotations

import numpy as np

from estimation.smoothing import walks
from estimation.smoothing.line import line_track, line_weight
from estimation.smoothing.two_lines import two_line_track
from estimation.smoothing.walks import WALK_FREE_PRIOR, free_speeds, near_best, walk_track
from tests.helpers.candidates import grid_candidates
from tests.test_line import _speeds, _walkers


def _slowed(true: np.ndarray, factor: float) -> np.ndarray:
    """``true (B, T, 2)`` read ``factor`` times as fast about its middle step, as a smoother that
    holds a fast walker back reads it."""
    mid = true[:, true.shape[1] // 2][:, None]
    return mid + factor * (true - mid)


def _both_searches(step: float, factor: float, speeds: np.ndarray, n: int, seed: int):
    """Walkers at ``step`` metres per step read ``factor`` times as fast: their true walks, the two
    passes' track and evidence around that track, and ``walk_track``'s."""
    true = _walkers(n, step, seed=seed)
    xy, lp, _ = grid_candidates(true, radius=2)
    slow = _slowed(true, factor)
    line, delta = line_track(slow, xy, lp, speeds, 1.0)
    first, d_first = two_line_track(slow, xy, lp, speeds, 1.0, line, delta)
    return true, (slow, xy, lp), (first, d_first), walk_track(slow, xy, lp, speeds, 1.0)


def test_near_best_takes_the_likeliest_candidate_within_reach():
    tracked = np.zeros((2, 1, 2))
    xy = np.array([[[[0.5, 0.0], [3.0, 0.0], [0.0, 1.5]]], [[[9.0, 0.0], [0.0, 9.0], [6.0, 0.0]]]])
    lp = np.array([[[-2.0, 0.0, -1.0]], [[0.0, -1.0, -2.0]]])
    got = near_best(tracked, xy, lp, np.array([2.0, 2.0]))
    # the likeliest (3 m away) is out of reach: the likelier of the two within it
    np.testing.assert_array_equal(got[0, 0], [0.0, 1.5])
    # none within reach: the tracked point
    np.testing.assert_array_equal(got[1, 0], [0.0, 0.0])
    np.testing.assert_array_equal(
        near_best(tracked, xy, lp, np.array([3.0, 9.5]))[:, 0], [[3.0, 0.0], [9.0, 0.0]]
    )


def test_a_fast_walker_read_too_slow_is_found_by_the_second_search():
    # cyclists at 3.4 m per step whose track the smoother read at 70 % of their speed: the lines
    # around that track search speeds near 2.4 m and miss them; around their likeliest
    # candidates near the track they are found, to well inside the cells
    true, _, (first, d_first), (track, d) = _both_searches(3.4, 0.7, _speeds(2.4, 3.4), 20, seed=5)
    err = np.linalg.norm(track - true, axis=-1).mean()
    assert err < 0.3 < np.linalg.norm(first - true, axis=-1).mean()
    assert (line_weight(d) > 0.5).all() and (line_weight(d_first) < 0.01).all()
    assert (d >= np.where(np.isfinite(d_first), d_first, -np.inf)).all()


def test_a_slow_walker_is_searched_once(monkeypatch):
    # pedestrians at 1.4 m per step, read too slow too: no second search, the two passes' own
    speeds = _speeds(0.7, 1.4)
    true, inputs, (first, d_first), (track, d) = _both_searches(1.4, 0.5, speeds, 10, seed=6)
    np.testing.assert_array_equal(track, first)
    np.testing.assert_array_equal(d, d_first)
    # with the gate below their speed they are searched again, and found
    monkeypatch.setattr(walks, "WALK_FAST", 0.5)
    again, _ = walk_track(*inputs, speeds, 1.0)
    assert np.linalg.norm(again - true, axis=-1).mean() < 0.5 * np.linalg.norm(first - true, axis=-1).mean()


def test_walkers_at_speeds_of_their_own_are_found_with_the_flat_prior_beside_the_measured_one():
    # the training walkers kept 1.1, 1.4 and 1.7 m per step; walkers at 2.2 or 0.8 find no line at
    # those speeds (none weighs anything), so their tracks stay at the cells; with the flat prior
    # beside the measured one they are read well inside the cells
    speeds = _speeds(1.1, 1.4, 1.7)

    def mixed(true, free_prior):
        xy, lp, cells = grid_candidates(true, radius=2)
        track, delta = walk_track(cells, xy, lp, speeds, 1.0, free_prior=free_prior)
        w = line_weight(delta)[:, None, None]
        return np.linalg.norm(w * track + (1 - w) * cells - true, axis=-1).mean(), cells

    for step, seed in ((2.2, 3), (0.8, 4)):
        true = _walkers(20, step, seed=seed)
        alone, cells = mixed(true, 0.0)
        both, _ = mixed(true, WALK_FREE_PRIOR)
        cell_err = np.linalg.norm(cells - true, axis=-1).mean()
        assert alone > 0.95 * cell_err and both < 0.75 * cell_err
    # walkers at a measured speed keep the measured prior's walk
    true = _walkers(20, 1.4, seed=5)
    alone, cells = mixed(true, 0.0)
    both, _ = mixed(true, WALK_FREE_PRIOR)
    assert both < 1.05 * alone < 0.5 * np.linalg.norm(cells - true, axis=-1).mean()


def test_the_flat_prior_spreads_over_every_speed_a_line_is_weighed_at():
    p = free_speeds(np.zeros(120))
    assert p.shape == (120,) and np.isclose(p.sum(), 1.0)
    assert (p[:10] == 0).all() and np.allclose(p[10:], p[10])  # from half a spacing per step
