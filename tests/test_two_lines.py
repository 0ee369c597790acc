"""Walkers whose walk is two lines: a stop, a turn at a wall or a change of speed (estimation.smoothing.two_lines)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from estimation.smoothing import two_lines
from estimation.smoothing.line import LINE_BINS, fill_raster, line_track, line_weight
from estimation.smoothing.motion import MotionTable
from estimation.smoothing.two_lines import free_raster, two_line_track, walk_restarts
from tests.helpers.candidates import grid_candidates
from tests.test_line import _estimator, _speeds, _walkers


def _stoppers(n: int, step: float, stop: int, T: int = 7, seed: int = 0) -> np.ndarray:
    """``n`` walks at ``step`` metres per step that stand still from step ``stop`` to the next,
    then go on at the same speed in a heading of their own."""
    rng = np.random.default_rng(seed)
    h1, h2 = rng.uniform(0, 2 * np.pi, (2, n))
    start = rng.uniform(0, 1, (n, 2)) + 20.0
    out = np.empty((n, T, 2))
    for t in range(T):
        if t <= stop:
            d = step * t * np.stack([np.cos(h1), np.sin(h1)], -1)
        else:
            d = step * stop * np.stack([np.cos(h1), np.sin(h1)], -1)
            d = d + step * (t - stop - 1) * np.stack([np.cos(h2), np.sin(h2)], -1)
        out[:, t] = start + d
    return out


def test_restarts_and_stops_are_measured_on_the_walkers():
    t = np.arange(5.0)
    walkers = np.stack(
        [
            np.stack([np.r_[0, 1.4, 1.4, 2.8, 4.2], np.zeros(5)], -1),  # a stop, set off at 1.4
            np.stack([np.r_[0, 1.1, 2.2, 2.2, 3.9], np.ones(5)], -1),  # a stop, set off at 1.7
            np.stack([1.4 * t, 2 * np.ones(5)], -1),
        ]
    )
    driver = np.stack([8.0 * t, np.zeros(5)], -1)[None]  # its stop is not a walker's
    driver[0, 2:] -= 8.0
    restarts, share = walk_restarts(np.concatenate([walkers, driver]), 5.0)
    assert np.flatnonzero(restarts).tolist() == [28, 34] and restarts[28] == pytest.approx(0.5)
    # moving steps a stop follows: 2 of the 7 walkers' moving steps with a step after them
    assert share == pytest.approx(2 / 7)
    assert walk_restarts(walkers[2:], 5.0)[0].size == 0 and walk_restarts(walkers[2:], 5.0)[1] == 0.0
    table = MotionTable().fit_walks(walkers, 5.0)
    assert np.array_equal(table.walk_restarts.numpy(), walk_restarts(walkers, 5.0)[0])
    assert float(table.walk_stop) == pytest.approx(walk_restarts(walkers, 5.0)[1])


def test_a_walker_who_stops_is_read_along_its_two_lines():
    # 1.4 m per step, a stop at step 3, then 1.4 m per step in another heading: no straight line
    # explains it, the stop family does, to well inside the cells
    true = _stoppers(30, 1.4, stop=3)
    xy, lp, cells = grid_candidates(true)
    speeds, restarts = _speeds(1.4), _speeds(1.4)
    line, delta = line_track(cells, xy, lp, speeds, 1.0)
    track, mixed = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, restarts, 0.1)
    cell_err = np.linalg.norm(cells - true, axis=-1).mean()
    assert np.linalg.norm(track - true, axis=-1).mean() < 0.6 * cell_err
    assert (line_weight(mixed) > 0.4).all() and (line_weight(delta) < 0.02).all()
    assert (mixed > delta + 10).all()
    # restarting at a speed the walkers never set off at, the stop family explains nothing
    _, wrong = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, _speeds(0.6), 0.1)
    assert np.median(line_weight(wrong)) < 0.5 * np.median(line_weight(mixed))
    assert (wrong < mixed - 5).mean() >= 0.85


def _pacers(n: int, before: float, after: float, at: int, T: int = 7, seed: int = 0) -> np.ndarray:
    """``n`` straight walks at ``before`` metres per step up to step ``at``, ``after`` from there."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(0, 2 * np.pi, n)
    start = rng.uniform(0, 1, (n, 2)) + 20.0
    t = np.arange(T)
    along = np.where(t <= at, before * t, before * at + after * (t - at))
    return start[:, None] + along[None, :, None] * np.stack([np.cos(h), np.sin(h)], -1)[:, None]


def test_a_cyclist_who_changes_speed_is_read_along_both_speeds():
    # 3.4 m per step, then 4.35 from step 3 on, straight ahead: no line at one speed explains it,
    # the family that changes speed does (the cells leave the step of the change a step uncertain)
    true = _pacers(30, 3.4, 4.35, at=3)
    xy, lp, cells = grid_candidates(true)
    speeds = _speeds(2.45, 3.4, 4.35)
    line, delta = line_track(cells, xy, lp, speeds, 1.0)
    track, mixed = two_line_track(cells, xy, lp, speeds, 1.0, line, delta)
    err = lambda a: np.linalg.norm(a - true, axis=-1).mean()  # noqa: E731
    assert err(track) < 0.8 * err(cells) and err(track) < 0.4 * err(line)
    assert (mixed > delta + 5).mean() >= 0.85 and (mixed >= delta).all()
    w, w_line = line_weight(mixed)[:, None, None], line_weight(delta)[:, None, None]
    assert err(w * track + (1 - w) * cells) < 0.8 * err(w_line * line + (1 - w_line) * cells)
    # at one speed throughout, the lines at that speed keep most of the weight
    same = _pacers(30, 3.4, 3.4, at=3)
    xy, lp, cells = grid_candidates(same)
    line, delta = line_track(cells, xy, lp, speeds, 1.0)
    kept, _ = two_line_track(cells, xy, lp, speeds, 1.0, line, delta)
    off = lambda a: np.linalg.norm(a - same, axis=-1).mean()  # noqa: E731
    assert off(kept) < 1.2 * off(line) and off(kept) < 0.6 * off(cells)
    # at a walker's speeds, no change of speed is weighed
    slow = _pacers(30, 1.4, 1.7, at=3)
    xy, lp, cells = grid_candidates(slow)
    line, delta = line_track(cells, xy, lp, _speeds(1.4, 1.7), 1.0)
    kept, d2 = two_line_track(cells, xy, lp, _speeds(1.4, 1.7), 1.0, line, delta)
    assert np.array_equal(kept, line) and np.array_equal(d2, delta)


def test_a_familys_later_stages_draw_speeds_where_its_posterior_is():
    # a stop at step 3 and a restart table from 0.3 to 3 m per step: the stages narrow the restart
    # speeds to the bins the posterior holds, so the last stage's lines all set off near 1.4 m
    true = _stoppers(1, 1.4, stop=3)
    xy, lp, cells = grid_candidates(true)
    T = true.shape[1]
    side = 2 * two_lines.TWO_LINE_HALF + 1
    raster, ox, oy = np.empty((T, side, side)), np.empty(T), np.empty(T)
    track = np.ascontiguousarray(cells[0])
    fill_raster(xy[0], lp[0], track, 1.0, raster, ox, oy)
    n = len(two_lines._OFFSETS6)
    buffers, mean = (np.empty(n), np.empty((n, T)), np.empty((n, T))), np.empty((T, 2))
    restarts = _speeds(*np.arange(0.3, 3.01, 0.05))
    no_walls = np.zeros((0, 0), bool), np.zeros(2), 1.0
    ev = two_lines._family(
        two_lines._STOP,
        track,
        3,
        _speeds(1.4),
        restarts,
        1.0,
        two_lines._OFFSETS6,
        ox,
        oy,
        raster,
        *no_walls,
        buffers,
        mean,
        -np.inf,
    )
    _, px, py = buffers
    set_off = np.hypot(px[:, -1] - px[:, -2], py[:, -1] - py[:, -2])
    assert np.isfinite(ev)
    assert 0.9 < set_off.min() and set_off.max() < 2.1
    assert np.linalg.norm(mean - true[0], axis=-1).mean() < 0.4


def test_walkers_without_a_short_step_keep_their_lines():
    true = _walkers(20, 1.4)
    xy, lp, cells = grid_candidates(true)
    speeds = _speeds(1.4)
    line, delta = line_track(cells, xy, lp, speeds, 1.0)
    track, mixed = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, _speeds(1.4), 0.1)
    assert np.array_equal(track, line) and np.array_equal(mixed, delta)
    # nor does a model that measured no restarts, or no stops
    for restarts, share in ((np.zeros(0), 0.1), (_speeds(1.4), 0.0)):
        t2, d2 = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, restarts, share)
        assert np.array_equal(t2, line) and np.array_equal(d2, delta)


def test_a_straight_walker_who_slows_at_one_step_stays_on_its_line():
    # a short step that is not a stop: the straight family keeps most of the weight
    true = _walkers(20, 1.4, seed=4)
    xy, lp, cells = grid_candidates(true)
    speeds = _speeds(1.4)
    line, delta = line_track(cells, xy, lp, speeds, 1.0)
    short = cells.copy()
    short[:, 3] = np.rint(0.5 * (true[:, 2] + true[:, 3]))  # the track's step 2 -> 3 under 1 m
    track, _ = two_line_track(short, xy, lp, speeds, 1.0, line, delta, speeds, 0.1)
    assert np.linalg.norm(track - line, axis=-1).mean() < 0.05


def test_the_estimator_mixes_stops_in_where_its_model_measured_them():
    est = _estimator(_speeds(1.4))
    true = _stoppers(8, 1.4, stop=2, T=6, seed=1)
    xy, lp, cells = grid_candidates(true, radius=2)
    x = (torch.from_numpy(xy).float(), torch.from_numpy(lp).float()[..., None])
    tracked = torch.from_numpy(cells).float()
    fine = est.net.motion_fine
    fine.walk_restarts, fine.walk_stop = torch.zeros(0, dtype=torch.float64), torch.tensor(0.0)
    plain = est._along_lines(tracked, x)  # as a model saved before restarts were measured
    fine.walk_restarts = torch.from_numpy(_speeds(1.4))
    fine.walk_stop = torch.tensor(0.1, dtype=torch.float64)
    out = est._along_lines(tracked, x)
    line, delta = line_track(cells, xy.astype(np.float32), lp.astype(np.float32), _speeds(1.4), 1.0)
    mixed, d = two_line_track(
        cells, xy, lp, _speeds(1.4), 1.0, line, delta, _speeds(1.4), 0.1, est._free_space()
    )
    w = line_weight(d)[:, None, None]
    assert np.allclose(out.numpy(), w * mixed + (1 - w) * cells, atol=1e-5)
    err = lambda a: np.linalg.norm(a.numpy() - true, axis=-1).mean()  # noqa: E731
    assert err(out) < 0.8 * err(plain)


def test_restart_bins_are_the_line_bins():
    # the restart table's bins are the walk speeds' (1 / LINE_BINS of a spacing)
    walker = np.stack([np.r_[0, 1.0, 1.0, 2.25], np.zeros(4)], -1)[None]
    restarts, _ = walk_restarts(walker, 5.0)
    assert np.flatnonzero(restarts).tolist() == [round(1.25 * LINE_BINS)]


def _turners(n: int, step: float = 1.4, T: int = 7, at: int = 3, seed: int = 0):
    """``n`` walks east at ``step`` metres per step that turn north at step ``at`` (a wall ahead),
    and the free space: every grid point east of the turn's column blocked."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(0, 1, (n, 2)) + np.array([20.0, 20.0]) + 40.0 * np.arange(n)[:, None] * [0, 1]
    t = np.arange(T)
    east = step * np.minimum(t, at)
    north = step * np.maximum(t - at, 0)
    true = start[:, None] + np.stack([east, north], -1)[None]
    free = np.ones((80, 40 * n + 60), bool)
    for k in range(n):
        col = int(np.rint(true[k, at, 0])) + 1
        row = slice(int(start[k, 1]) - 10, int(start[k, 1]) + 20)
        free[col:, row] = False
    return true, (free, np.zeros(2), 1.0)


def test_a_walker_who_turns_at_a_wall_is_read_along_its_two_lines():
    true, free = _turners(12)
    xy, lp, cells = grid_candidates(true)
    speeds = _speeds(1.4)
    line, delta = line_track(cells, xy, lp, speeds, 1.0)
    track, mixed = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, free=free)
    err = lambda a: np.linalg.norm(a - true, axis=-1).mean()  # noqa: E731
    assert err(track) < 0.5 * err(cells) and (mixed > delta + 10).all()
    w = line_weight(mixed)[:, None, None]
    assert err(w * track + (1 - w) * cells) < 0.75 * err(cells)
    # no wall ahead anywhere: no turn is weighed, the straight lines stand as they were
    open_space = (np.ones_like(free[0]), free[1], free[2])
    same, d2 = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, free=open_space)
    assert np.array_equal(same, line) and np.array_equal(d2, delta)


def test_a_turn_with_the_way_ahead_free_is_weighed_down():
    # the same walks with the wall moved two columns further east: the straight way ahead of the
    # true turn is free, so its lines weigh TURN_FREE instead of TURN_BLOCKED
    true, (free, origin, res) = _turners(12)
    far = np.ones_like(free)
    far[2:] = free[:-2]
    xy, lp, cells = grid_candidates(true)
    speeds = _speeds(1.4)
    line, delta = line_track(cells, xy, lp, speeds, 1.0)
    _, at_wall = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, free=(free, origin, res))
    _, past = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, free=(far, origin, res))
    assert np.median(at_wall - past) > 5.0


def test_the_free_raster_holds_the_grid_points_given():
    xy = np.array([[10.0, 5.0], [12.0, 5.0], [10.0, 7.0]])
    free, origin, res = free_raster(xy, 2.0)
    assert free.shape == (2, 2) and np.array_equal(origin, [10.0, 5.0]) and res == 2.0
    assert free.tolist() == [[True, True], [True, False]]
