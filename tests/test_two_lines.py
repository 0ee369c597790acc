"""Walkers whose walk is two lines (a stop, a turn at a wall or a change of speed) or three (two stops):
estimation.smoothing.two_lines."""

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


def _family_inputs(true: np.ndarray):
    """One walk's tracked cells and its raster, as :func:`two_lines._two_line_kernel` fills them."""
    xy, lp, cells = grid_candidates(true)
    T = true.shape[1]
    side = 2 * two_lines.TWO_LINE_HALF + 1
    raster, ox, oy = np.empty((T, side, side)), np.empty(T), np.empty(T)
    track = np.ascontiguousarray(cells[0])
    fill_raster(xy[0], lp[0], track, 1.0, raster, ox, oy)
    return track, raster, ox, oy


def _buffers(T: int):
    n, M, K = len(two_lines._OFFSETS6), two_lines.STOP_POINTS, two_lines.STOP_PIECES
    lines = np.empty(n), np.empty((n, T)), np.empty((n, T))
    return lines, (np.empty((M, K)), np.empty((M, K)), np.empty(M)), np.empty((T, 2))


def _run_family(kind, track, jv, speeds, restarts, raster, ox, oy, free=None):
    lines, stops, mean = _buffers(len(track))
    no_walls = (np.zeros((0, 0), bool), np.zeros(2), 1.0) if free is None else free
    ev = two_lines._family(
        kind, track, jv, speeds, restarts, 1.0, two_lines._OFFSETS6, two_lines._STOP_POINTS6,
        two_lines._STOP_PIECES2, ox, oy, raster, *no_walls, lines, stops, mean, -np.inf,
    )  # fmt: skip
    return ev, lines, mean


def test_a_familys_later_stages_draw_speeds_where_its_posterior_is():
    # a change of speed at step 3 from 3.4 to 4.35 m per step, walk speeds from 2 to 6 m per
    # step: the stages narrow the second piece's speeds to the bins the posterior holds, so the
    # last stage's lines all go on near 4.35 m
    true = _pacers(1, 3.4, 4.35, at=3)
    track, raster, ox, oy = _family_inputs(true)
    speeds = _speeds(*np.arange(2.0, 6.01, 0.05), n=140)
    ev, (_, px, py), mean = _run_family(two_lines._PACE, track, 3, speeds, np.zeros(0), raster, ox, oy)
    after = np.hypot(px[:, -1] - px[:, -2], py[:, -1] - py[:, -2])
    assert np.isfinite(ev)
    assert 3.9 < after.min() and after.max() < 4.8
    assert np.linalg.norm(mean - true[0], axis=-1).mean() < 0.4


def test_a_stop_sets_off_at_the_speed_its_posterior_holds():
    # a stop at step 3 and a restart table from 0.3 to 3 m per step: the family's walks set off
    # near 1.4 m, the walker's own speed, and follow it to within the cells
    true = _stoppers(1, 1.4, stop=3)
    track, raster, ox, oy = _family_inputs(true)
    restarts = _speeds(*np.arange(0.3, 3.01, 0.05))
    ev, _, mean = _run_family(two_lines._STOP, track, 3, _speeds(1.4), restarts, raster, ox, oy)
    assert np.isfinite(ev)
    assert abs(np.linalg.norm(mean[-1] - mean[-2]) - 1.4) < 0.15
    assert np.linalg.norm(mean - true[0], axis=-1).mean() < 0.4


@pytest.mark.parametrize("jv", [0, 2, 5])
def test_a_stops_pieces_weighed_apart_are_every_walk_weighed_whole(jv):
    # each place to stand with every pair of pieces: the stage's mean likelihood, posterior mean,
    # moments and speed-bin weights are those of the M K^2 walks enumerated one by one
    rng = np.random.default_rng(jv)
    T, M, K = 7, 5, 4
    raster = rng.normal(0.0, 2.0, (T, 11, 11))
    ox, oy = np.full(T, -5.0), np.full(T, -5.0)
    points, pieces = rng.uniform(0, 1, (M, 6)), rng.uniform(0, 1, (K, 2))
    at, head, turn = np.array([0.3, -0.2]), np.array([0.4, 2.0]), np.array([0.5, 3.0])
    box = np.array([0.1, 0.9, 0.2, 0.7, 0.0, 1.0, 0.0, 1.0, 0.3, 0.8, 0.0, 1.0])
    bins_a, lp_a = np.array([20, 24, 28]), np.log([0.2, 0.5, 0.3])
    bins_b, lp_b = np.array([26, 30]), np.log([0.6, 0.4])
    range_a, range_b = np.array([1, 2]), np.array([0, 1])
    frac = lambda x: x - np.floor(x)  # noqa: E731
    walks, weights, coords = [], [], []
    n_a = K if jv >= 1 else 1
    n_b = K if jv + 2 <= T - 1 else 1
    for m in range(M):
        g0 = box[0] + points[m, 0] * (box[1] - box[0])
        g1 = box[2] + points[m, 1] * (box[3] - box[2])
        s = at + (2 * np.array([g0, g1]) - 1) * two_lines.LINE_REACH
        for ka in range(n_a):
            fa = box[4] + frac(pieces[ka, 0] + points[m, 2]) * (box[5] - box[4])
            qa = range_a[0] + min(int(frac(pieces[ka, 1] + points[m, 3]) * 2), 1)
            ha = head[0] + (2 * fa - 1) * turn[0]
            a = bins_a[qa] / LINE_BINS * np.array([np.cos(ha), np.sin(ha)])
            for kb in range(n_b):
                fb = box[8] + frac(pieces[kb, 0] + points[m, 4]) * (box[9] - box[8])
                qb = range_b[0] + min(int(frac(pieces[kb, 1] + points[m, 5]) * 2), 1)
                hb = head[1] + (2 * fb - 1) * turn[1]
                b = bins_b[qb] / LINE_BINS * np.array([np.cos(hb), np.sin(hb)])
                walk = np.array([s - (jv - t) * a if t <= jv else s + (t - jv - 1) * b for t in range(T)])
                walk[jv + 1] = s
                ll = (
                    lp_a[qa]
                    + lp_b[qb]
                    + sum(
                        two_lines.raster_at(raster, t, walk[t, 0], walk[t, 1], ox, oy, 1.0) for t in range(T)
                    )
                )
                walks.append(walk)
                weights.append(ll)
                coords.append((g0, g1, fa, qa - range_a[0], fb, qb - range_b[0]))
    ll = np.array(weights)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    coords = np.array(coords)
    la, lb, lm = np.empty((M, K)), np.empty((M, K)), np.empty(M)
    m1, m2, mass_a, mass_b, mean = np.empty(6), np.empty(6), np.empty(2), np.empty(2), np.empty((T, 2))
    args = (jv, at, head, turn, box, bins_a, lp_a, range_a, bins_b, lp_b, range_b, points, pieces, ox, oy)
    log_mean = two_lines._weigh_stop(*args, raster, 1.0, la, lb, lm, True, mean, m1, m2, mass_a, mass_b)
    assert log_mean == pytest.approx(ll.max() + np.log(np.exp(ll - ll.max()).mean()), abs=1e-9)
    assert np.allclose(mean, np.einsum("n,ntd->td", w, np.array(walks)), atol=1e-9)
    two_lines._weigh_stop(*args, raster, 1.0, la, lb, lm, False, mean, m1, m2, mass_a, mass_b)
    for d, c in ((0, 0), (1, 1), (2, 2), (4, 4)):
        if (d == 2 and n_a == 1) or (d == 4 and n_b == 1):
            continue
        assert m1[d] == pytest.approx(w @ coords[:, c], abs=1e-9)
        assert m2[d] == pytest.approx(w @ coords[:, c] ** 2, abs=1e-9)
    assert np.allclose(mass_a, np.bincount(coords[:, 3].astype(int), w, 2), atol=1e-9)
    assert np.allclose(mass_b, np.bincount(coords[:, 5].astype(int), w, 2), atol=1e-9)


def _two_stoppers(n: int, step: float, j1: int, j2: int, T: int = 7, seed: int = 0) -> np.ndarray:
    """``n`` walks at ``step`` metres per step that stand still at steps ``j1 + 1`` and ``j2 + 1``,
    each piece in a heading of its own."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(0, 2 * np.pi, (n, 3))
    unit = np.stack([np.cos(h), np.sin(h)], -1)  # (n, 3, 2)
    out = np.empty((n, T, 2))
    out[:, 0] = rng.uniform(0, 1, (n, 2)) + 20.0
    piece = 0
    for t in range(1, T):
        moves = t - 1 not in (j1, j2)
        out[:, t] = out[:, t - 1] + (step * unit[:, piece] if moves else 0.0)
        piece += t - 1 in (j1, j2)
    return out


def test_a_walker_who_stops_twice_is_read_along_its_three_pieces():
    # nine steps, stops at steps 2 and 5, three headings: one stop leaves a turn unexplained, two
    # explain it to well inside the cells, by far likelier than either stop alone
    true = _two_stoppers(30, 1.4, 2, 5, T=9)
    assert np.allclose(true[:, 2], true[:, 3]) and np.allclose(true[:, 5], true[:, 6])
    xy, lp, cells = grid_candidates(true)
    speeds, restarts = _speeds(1.4), _speeds(1.4)
    line, delta = line_track(cells, xy, lp, speeds, 1.0)
    track, mixed = two_line_track(cells, xy, lp, speeds, 1.0, line, delta, restarts, 0.1)
    err = lambda a: np.linalg.norm(a - true, axis=-1).mean()  # noqa: E731
    assert err(track) < 0.6 * err(cells)
    # a walker's evidence for two stops against the best single stop's, family by family
    track0, raster, ox, oy = _family_inputs(true[:1])
    two, _, mean = _run_two_stops(track0, 2, 5, speeds, restarts, raster, ox, oy)
    one = max(_run_family(two_lines._STOP, track0, j, speeds, restarts, raster, ox, oy)[0] for j in (2, 5))
    assert two > one + 10
    assert np.linalg.norm(mean - true[0], axis=-1).mean() < 0.4


def _run_two_stops(track, j1, j2, speeds, restarts, raster, ox, oy):
    T, M, K = len(track), two_lines.TWO_STOP_POINTS, two_lines.TWO_STOP_PIECES
    buffers, mean = (np.empty((M, K)), np.empty((M, K)), np.empty(M)), np.empty((T, 2))
    ev = two_lines._two_stop_family(
        track, j1, j2, speeds, restarts, 1.0, two_lines._TWO_STOP_POINTS8, two_lines._TWO_STOP_PIECES2,
        ox, oy, raster, buffers, mean, -np.inf,
    )  # fmt: skip
    return ev, buffers, mean


@pytest.mark.parametrize("j1,j2", [(0, 1), (1, 3), (2, 5)])
def test_two_stops_pieces_weighed_apart_are_every_walk_weighed_whole(j1, j2):
    # each first stand and middle piece with every pair of first and last pieces: the stage's mean
    # likelihood, posterior mean, moments and speed-bin weights are those of the walks enumerated
    rng = np.random.default_rng(10 * j1 + j2)
    T, M, K = 7, 6, 3
    raster = rng.normal(0.0, 2.0, (T, 11, 11))
    ox, oy = np.full(T, -5.0), np.full(T, -5.0)
    points, pieces = rng.uniform(0, 1, (M, 8)), rng.uniform(0, 1, (K, 2))
    at, head, turn = np.array([0.3, -0.2]), np.array([0.4, 2.0, -1.0]), np.array([0.5, 3.0, 0.3])
    box = np.array([0.1, 0.9, 0.2, 0.7, 0.0, 1.0, 0.0, 1.0, 0.3, 0.8, 0.0, 1.0, 0.1, 0.6, 0.0, 1.0])
    bins = np.array([[20, 24, 28], [26, 30, 1], [25, 27, 29]])
    lps = np.log([[0.2, 0.5, 0.3], [0.6, 0.4, 1.0], [0.1, 0.3, 0.6]])
    ranges = np.array([[1, 2], [0, 1], [0, 2]])
    frac = lambda x: x - np.floor(x)  # noqa: E731
    n_mid = j2 - j1 - 1
    n_k = [K if j1 >= 1 else 1, K if j2 + 2 <= T - 1 else 1]

    def piece(p, u, q):
        f = box[4 + 4 * p] + u * (box[5 + 4 * p] - box[4 + 4 * p])
        n = ranges[p, 1] - ranges[p, 0] + 1
        kq = ranges[p, 0] + min(int(q * n), n - 1)
        h = head[p] + (2 * f - 1) * turn[p]
        return f, kq, bins[p, kq] / LINE_BINS * np.array([np.cos(h), np.sin(h)])

    walks, weights, coords = [], [], []
    for m in range(M):
        g = box[[0, 2]] + points[m, :2] * (box[[1, 3]] - box[[0, 2]])
        s1 = at + (2 * g - 1) * two_lines.LINE_REACH
        fb, qb, b = piece(1, points[m, 2], points[m, 3])
        if n_mid == 0:
            b = np.zeros(2)
        s2 = s1 + n_mid * b
        for ka in range(n_k[0]):
            fa, qa, a = piece(0, frac(pieces[ka, 0] + points[m, 4]), frac(pieces[ka, 1] + points[m, 5]))
            for kc in range(n_k[1]):
                fc, qc, c = piece(2, frac(pieces[kc, 0] + points[m, 6]), frac(pieces[kc, 1] + points[m, 7]))
                walk = np.empty((T, 2))
                for t in range(T):
                    if t <= j1:
                        walk[t] = s1 - (j1 - t) * a
                    elif t <= j2:
                        walk[t] = s1 + (t - j1 - 1) * b
                    else:
                        walk[t] = s2 + max(t - j2 - 1, 0) * c
                ll = lps[0, qa] + lps[2, qc] + (lps[1, qb] if n_mid > 0 else 0.0)
                ll += sum(two_lines.raster_at(raster, t, *walk[t], ox, oy, 1.0) for t in range(T))
                walks.append(walk)
                weights.append(ll)
                coords.append((*g, fa, fb, fc, qa - ranges[0, 0], qb - ranges[1, 0], qc - ranges[2, 0]))
    ll = np.array(weights)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    coords = np.array(coords)
    la, lc, lm = np.empty((M, K)), np.empty((M, K)), np.empty(M)
    m1, m2, mass, mean = np.empty(8), np.empty(8), np.empty((3, 3)), np.empty((T, 2))
    args = (j1, j2, at, head, turn, box, bins, lps, ranges, points, pieces, ox, oy, raster, 1.0, la, lc, lm)
    log_mean = two_lines._weigh_two_stops(*args, True, mean, m1, m2, mass)
    assert log_mean == pytest.approx(ll.max() + np.log(np.exp(ll - ll.max()).mean()), abs=1e-9)
    assert np.allclose(mean, np.einsum("n,ntd->td", w, np.array(walks)), atol=1e-9)
    two_lines._weigh_two_stops(*args, False, mean, m1, m2, mass)
    used = [(0, 0), (1, 1)] + [(2, 2)] * (j1 >= 1) + [(4, 3)] * (n_mid > 0) + [(6, 4)] * (n_k[1] > 1)
    for d, c in used:
        assert m1[d] == pytest.approx(w @ coords[:, c], abs=1e-9)
        assert m2[d] == pytest.approx(w @ coords[:, c] ** 2, abs=1e-9)
    for p, c, on in ((0, 5, j1 >= 1), (1, 6, n_mid > 0), (2, 7, n_k[1] > 1)):
        if on:
            assert np.allclose(mass[p], np.bincount(coords[:, c].astype(int), w, 3), atol=1e-9)


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
