"""Drivers smoothed along their street routes (estimation.smoothing.route)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
import torch

from estimation import Estimator, TrainConfig
from estimation.smoothing import route
from estimation.smoothing.motion import MotionTable
from estimation.smoothing.route import ROUTE_BINS, route_track, street_routes
from estimation.synthetic import toy_sequence_set
from mmwsim.trajectories import StreetNetwork
from tests.helpers.candidates import grid_candidates

# An L of streets: east along y = 0 to (60, 0), then north to (60, 60).
L_STREETS = np.array([[[0.0, 0.0], [60.0, 0.0]], [[60.0, 0.0], [60.0, 60.0]]])


def _along_l(s: np.ndarray) -> np.ndarray:
    """Positions at arc lengths ``s`` along the L."""
    s = np.asarray(s, dtype=np.float64)
    east = np.stack([s, np.zeros_like(s)], -1)
    north = np.stack([np.full_like(s, 60.0), s - 60.0], -1)
    return np.where((s <= 60.0)[..., None], east, north)


def _speeds(step: float, n: int = 400) -> np.ndarray:
    """A measured speed prior with every step ``step`` metres long (1 m grid)."""
    p = np.zeros(n)
    p[int(round(step * ROUTE_BINS))] = 1.0
    return p


def _drive(starts: np.ndarray, step: float, T: int = 7) -> np.ndarray:
    return _along_l(starts[:, None] + step * np.arange(T))


def test_steady_drivers_round_a_corner_are_found_inside_their_cells():
    # 8.3 m per step: over seven steps the cells' edges cut the arc at many phases, which a known
    # route and a steady speed read to far inside a cell; the per-step matches are 0.4 m off
    starts = np.linspace(20.0, 30.0, 17)
    true = _drive(starts, 8.3)
    xy, lp, cells = grid_candidates(true)
    net = StreetNetwork.from_segments(L_STREETS)
    track, on = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert on.all()
    before = np.linalg.norm(cells - true, axis=-1).mean()
    after = np.linalg.norm(track - true, axis=-1).mean()
    assert before > 0.2 and after < 0.25 * before
    # the corner is on the route: every position lies on a street (a posterior mean beside the
    # corner, where it mixes both streets, just inside it)
    assert np.minimum(np.abs(track[..., 1]), np.abs(track[..., 0] - 60.0)).max() < 0.05


def test_a_speed_change_is_followed():
    # 8.3 m per step, then 5.3 from the fourth step: the measured change probability lets it
    s = 25.0 + np.r_[0.0, np.cumsum([8.3, 8.3, 8.3, 5.3, 5.3, 5.3])]
    true = _along_l(s[None])
    xy, lp, cells = grid_candidates(true)
    speeds = _speeds(8.3) + _speeds(5.3)
    track, on = route_track(cells, xy, lp, StreetNetwork.from_segments(L_STREETS), speeds, 0.2, 1.0, 5.0)
    assert (
        on.all()
        and np.linalg.norm(track - true, axis=-1).mean() < 0.5 * np.linalg.norm(cells - true, axis=-1).mean()
    )


@pytest.mark.parametrize("step", [6.8, 10.3])
def test_drivers_at_speeds_of_their_own_are_followed(step):
    # the training drivers all kept 8.3 m per step and changed speed often (corners, stops): a
    # driver keeping a speed none of them kept, slower or faster than all of them, is followed
    # by the motion of speeds of its own, weighed against theirs by how well each explains it;
    # fingerprints that tell little (log-likelihood -0.5 per square metre off) leave it to motion
    true = _drive(np.linspace(20.0, 30.0, 9), step)
    xy, _, cells = grid_candidates(true)
    lp = -0.5 * ((xy - true[..., None, :]) ** 2).sum(-1)
    net = StreetNetwork.from_segments(L_STREETS)
    track, on = route_track(cells, xy, lp, net, _speeds(8.3, 170), 0.4, 1.0, 5.0)
    assert on.all()
    assert np.linalg.norm(track - true, axis=-1).mean() < 0.5 * np.linalg.norm(cells - true, axis=-1).mean()


def _banded(lik: np.ndarray, band: tuple | None) -> np.ndarray:
    """``lik (1, T, S)`` zero outside bins ``band`` at the steps between the first and the last,
    as the wider end windows of ``_relocate_ends`` are, after another user's unbanded ``(1, T,
    S)``: the pass reuses its buffers from user to user, and the second must not read what the
    first left where its band leaves them unwritten."""
    if band is not None:
        inside = np.zeros(lik.shape[-1], dtype=bool)
        inside[slice(*band)] = True
        lik[:, 1:-1, ~inside] = 0.0
    return np.concatenate([np.random.default_rng(9).random(lik.shape), lik])


@pytest.mark.parametrize(
    "S, V, d, band",
    [
        (5, 3, [1, 0], None),
        (3, 8, [1, 3, 1], None),
        (4, 9, [7, 6], None),
        (7, 5, [2, 1, 3], (2, 5)),
        (6, 8, [4, 0], (1, 3)),
    ],
)
def test_the_pass_is_the_exact_posterior_over_arc_and_speed(S, V, d, band):
    # every path of an S-bin window, V speeds and len(d) + 1 steps enumerated: a path advances by
    # its speed, which it keeps or draws again; the pass's posterior and evidence are the sums.
    # With windows that shift little (or much) against the speeds, some speeds can keep a user
    # within the windows at no step: the pass sums those in closed form. With a band, the steps
    # between the ends are zero outside it: the pass visits the band only, and must still sum
    # every path through it.
    rng = np.random.default_rng(3)
    T, change = len(d) + 1, 0.3
    lik, prior, d = _banded(rng.random((1, T, S)), band), rng.dirichlet(np.ones(V)), np.array([d, d])
    post = np.zeros((T, S))
    for i0 in range(S):
        for js in itertools.product(range(V), repeat=T):
            p, i = prior[js[0]] * lik[1, 0, i0], [i0]
            for t in range(T - 1):
                i.append(i[-1] + js[t] - d[1, t])
                keep = (1 - change) * (js[t + 1] == js[t]) + change * prior[js[t + 1]]
                p *= keep * lik[1, t + 1, i[-1]] if 0 <= i[-1] < S else 0.0
            if p > 0:  # a path that leaves the window is none
                post[np.arange(T), i] += p
    got, alive, evidence = route._forward_backward(lik, d, prior, change)
    assert alive.all()
    np.testing.assert_allclose(got[1], post / post.sum(1, keepdims=True), rtol=1e-12)
    np.testing.assert_allclose(np.exp(evidence[1]), post[0].sum(), rtol=1e-12)
    # a window the track cannot reach from the last: no way through
    assert not route._forward_backward(lik, np.full((2, T - 1), -9), prior, change)[1][1]


@pytest.mark.parametrize(
    "S, V, d, band",
    [
        (5, 3, [1, 0], None),
        (3, 8, [1, 3, 1], None),
        (4, 9, [7, 6], None),
        (4, 6, [2], None),
        (7, 5, [2, 1, 3], (2, 5)),
        (6, 8, [4, 0], (1, 3)),
    ],
)
def test_the_pass_of_speeds_of_their_own_is_the_exact_posterior(S, V, d, band):
    # every path enumerated: its first speed drawn from the prior, then at each step kept, or
    # changed by one of the differences, or drawn again; a path that leaves the window is none
    rng = np.random.default_rng(3)
    T, change, redraw = len(d) + 1, 0.3, 0.4
    lik, prior, d = _banded(rng.random((1, T, S)), band), rng.dirichlet(np.ones(V)), np.array([d, d])
    deltas, prob = np.array([-2, 1, 3]), np.array([0.5, 0.3, 0.2])
    post = np.zeros((T, S))
    for i0 in range(S):
        for js in itertools.product(range(V), repeat=T - 1):  # the speed of each move
            p, i = prior[js[0]] * lik[1, 0, i0], [i0]
            for t in range(T - 1):
                i.append(i[-1] + js[t] - d[1, t])
                p *= lik[1, t + 1, i[-1]] if 0 <= i[-1] < S else 0.0
                if t < T - 2:
                    moved = sum(q for k, q in zip(deltas, prob, strict=True) if js[t + 1] == js[t] + k)
                    p *= (1 - change) * (js[t + 1] == js[t]) + change * (
                        (1 - redraw) * moved + redraw * prior[js[t + 1]]
                    )
            if p > 0:
                post[np.arange(T), i] += p
    got, alive, evidence = route._forward_backward_changes(lik, d, prior, change, deltas, prob, redraw)
    assert alive.all()
    np.testing.assert_allclose(got[1], post / post.sum(1, keepdims=True), rtol=1e-12)
    np.testing.assert_allclose(np.exp(evidence[1]), post[0].sum(), rtol=1e-12)
    # every change a draw: the measured speeds' pass
    for a, b in zip(
        route._forward_backward_changes(lik, d, prior, change, deltas, prob, 1.0),
        route._forward_backward(lik, d, prior, change),
        strict=True,
    ):
        np.testing.assert_allclose(a, b, rtol=1e-12)


def test_speed_changes_are_the_differences_between_measured_speeds():
    speeds = _speeds(5.3) + 2 * _speeds(8.3) + _speeds(11.3)
    deltas, prob = route.speed_changes(speeds)
    assert 0 not in deltas and prob.sum() == pytest.approx(1.0)
    by = dict(zip(deltas.tolist(), prob, strict=True))
    # two distinct speeds drawn (probability 10 / 16): 3 m apart with 4 / 16 each way, 6 m with 1 / 16
    assert by[3 * ROUTE_BINS] == pytest.approx(by[-3 * ROUTE_BINS]) == pytest.approx(0.4)
    assert by[6 * ROUTE_BINS] == pytest.approx(by[-6 * ROUTE_BINS]) == pytest.approx(0.1)
    assert len(route.speed_changes(_speeds(8.3))[0]) == 0  # one speed kept: no change to measure


def test_a_driver_at_a_speed_of_its_own_changes_it_as_the_training_drivers_do(monkeypatch):
    # the training drivers kept 5.3 or 8.3 m per step and changed by 3 m; a driver at 7 m per
    # step who slows to 4 is read better knowing how drivers change speed than with any change
    # as likely as any other (fingerprints that tell little leave it to motion)
    s = 20.0 + np.r_[0.0, np.cumsum([7.0, 7.0, 7.0, 4.0, 4.0, 4.0])]
    true = _along_l(s[None] + np.linspace(0.0, 1.0, 9)[:, None])
    xy, _, cells = grid_candidates(true)
    lp = -0.5 * ((xy - true[..., None, :]) ** 2).sum(-1)
    net = StreetNetwork.from_segments(L_STREETS)
    speeds = _speeds(5.3, 170) + _speeds(8.3, 170)

    def error() -> float:
        track, on = route_track(cells, xy, lp, net, speeds, 0.2, 1.0, 3.0)
        assert on.all()
        return float(np.linalg.norm(track - true, axis=-1).mean())

    changed = error()
    monkeypatch.setattr(route, "ROUTE_REDRAW", 1.0)
    assert changed < 0.8 * error()


def test_users_off_the_streets_or_slow_are_left_alone():
    net = StreetNetwork.from_segments(L_STREETS)
    off = _drive(np.array([20.0]), 8.3) + np.array([0.0, 10.0])  # 10 m from the street
    slow = _drive(np.array([20.0]), 1.4)  # a walker on the street
    for true in (off, slow):
        xy, lp, cells = grid_candidates(true)
        track, on = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
        assert not on.any() and np.array_equal(track, cells)


def test_a_user_crossing_a_street_where_its_fingerprints_place_it_keeps_its_track(monkeypatch):
    """A fast user crossing the street at a shallow angle stays within ROUTE_REACH of it for
    seven steps, and the route pass would put it on the street, 1.5 m from where it is; the
    fingerprints put it more than 20 nats likelier on its own track (ROUTE_EVIDENCE)."""
    net = StreetNetwork.from_segments(L_STREETS)
    t = np.arange(7)
    true = np.stack([20.0 + 8.3 * t, -2.5 + 0.5 * t], -1)[None]
    xy, lp, cells = grid_candidates(true)
    track, on = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert not on.any() and np.array_equal(track, cells)
    monkeypatch.setattr(route, "ROUTE_EVIDENCE", np.inf)
    track, on = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert on.all() and np.linalg.norm(track - true, axis=-1).max() > 1.0


def test_a_driver_whose_first_tracked_step_strays_off_the_street_is_smoothed_back_onto_it():
    """The smoother's first step (one fingerprint, no step before it) can stray 3 to 4 m off the
    street while the others are on it: the route still holds the driver (ROUTE_REACH)."""
    net = StreetNetwork.from_segments(L_STREETS)
    true = _drive(np.array([20.0]), 8.3)
    xy, lp, cells = grid_candidates(true)
    tracked = cells.copy()
    tracked[0, 0, 1] += 3.6  # 3.6 m north of the street
    track, on = route_track(tracked, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert on.all()
    assert np.linalg.norm(track - true, axis=-1).max() < 0.5  # the stray step 3.6 m off before


@pytest.mark.parametrize("end", [0, -1])
def test_a_driver_lost_at_an_end_step_is_put_back_where_its_speed_and_fingerprints_agree(end, monkeypatch):
    """The smoother tracked the first (or last) step onto an alias 5 m along the street, past the
    first pass's window: the wider windows at the end steps find the true cell, where the
    driver's speed puts it, and take the track as it moves that step by over a spacing."""
    net = StreetNetwork.from_segments(L_STREETS)
    true = _drive(np.array([20.0]), 8.3)
    xy, lp, cells = grid_candidates(true)
    alias = np.rint(_along_l(20.0 + 8.3 * (6 if end else 0) + (-5.0 if end else 5.0)))  # 5 m inward
    xy[0, end, 0], lp[0, end, 0] = alias, -1.0  # the alias, 1 nat below the true cell
    tracked = cells.copy()
    tracked[0, end] = alias
    track, on = route_track(tracked, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert on.all() and np.linalg.norm(track[0, end] - true[0, end]) < 0.5
    assert np.linalg.norm(track - true, axis=-1).max() < 0.5
    monkeypatch.setattr(route, "ROUTE_END_WINDOW", route.ROUTE_WINDOW)  # one pass only
    first, _ = route_track(tracked, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert np.linalg.norm(first[0, end] - true[0, end]) > 2.0


# A T of streets: east along y = 0 from (-60, 0) to (120, 0), and north from (60, 0) to (60, 60).
T_STREETS = np.array([[[-60.0, 0.0], [60.0, 0.0]], [[60.0, 0.0], [120.0, 0.0]], [[60.0, 0.0], [60.0, 60.0]]])


@pytest.mark.parametrize("end", [0, -1])
def test_a_driver_turning_at_a_junction_in_an_end_step_is_found_on_the_street_it_took(end, monkeypatch):
    """A driver east along y = 0 turns north at the junction in its last step (or, reversed, comes
    from the north street in its first). The smoother carried the end step straight on, onto an
    alias 2 m past the junction, and the route built from that track runs on along y = 0: only
    the branch at the junction holds the true cell."""
    net = StreetNetwork.from_segments(T_STREETS)
    s = 12.2 + 8.3 * np.arange(7)  # the last step ends 2 m up the north street
    true = np.where((s <= 60.0)[:, None], np.stack([s, 0 * s], -1), np.stack([0 * s + 60.0, s - 60.0], -1))[
        None
    ]
    if end == 0:
        true = true[:, ::-1].copy()
    xy, lp, cells = grid_candidates(true)
    alias = np.array([62.0, 0.0])  # straight on through the junction
    xy[0, end, 0], lp[0, end, 0] = alias, -3.0
    tracked = cells.copy()
    tracked[0, end] = alias
    track, on = route_track(tracked, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert on.all() and np.linalg.norm(track - true, axis=-1).max() < 0.5
    monkeypatch.setattr(route, "ROUTE_BRANCHES", False)
    straight, _ = route_track(tracked, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert np.linalg.norm(straight[0, end] - true[0, end]) > 2.0


def test_a_junction_branches_by_each_other_street_at_the_end_steps_that_pass_it():
    # a crossing at (60, 0): the route east along y = 0 may leave it north or south in its last
    # two steps; a junction the track passed earlier, or one farther than the reach, gives none
    streets = np.concatenate([T_STREETS, [[[60.0, 0.0], [60.0, -60.0]]]])
    net = StreetNetwork.from_segments(streets)
    node = {tuple(p): i for i, p in enumerate(net.nodes.tolist())}
    nodes = [node[(-60.0, 0.0)], node[(60.0, 0.0)], node[(120.0, 0.0)]]
    arc = route.ROUTE_EXTEND + 73.2 + 8.3 * np.arange(7)  # the last step ends 3 m past the crossing
    branches = route._end_branches(net, nodes, arc, 6.0)
    assert sorted(b[-1] for b in branches) == sorted([node[(60.0, 60.0)], node[(60.0, -60.0)]])
    assert all(b[:2] == nodes[:2] for b in branches)
    assert route._end_branches(net, nodes, arc - 10.0, 6.0) == []  # the crossing 7 m past the last step
    assert len(route._end_branches(net, nodes, arc + 10.0, 6.0)) == 2  # passed in the step before
    assert route._end_branches(net, nodes, arc + 20.0, 6.0) == []  # passed two steps before


def test_a_dead_end_street_touched_at_its_junction_is_no_turn():
    # a dead end 40 m south of the junction at (60, 0): a track that passes the junction with one
    # position 1.5 m into that street did not drive down it and back; one that came within
    # ROUTE_EXTEND of the dead end did (the network's drivers turn at a dead end)
    streets = np.array([[[0.0, 0.0], [60.0, 0.0]], [[60.0, 0.0], [120.0, 0.0]], [[60.0, 0.0], [60.0, -40.0]]])
    net = StreetNetwork.from_segments(streets)
    x = 20.0 + 8.0 * np.arange(7)
    past = np.stack([x, np.zeros(7)], -1)
    past[5] = [60.6, -1.5]  # nearer the dead-end street than the one it drives
    (route_past,) = street_routes(net, past[None])
    assert route_past is not None and route_past[:, 1].min() > -1.0  # along y = 0 only
    down = np.array(
        [[20.0, 0.0], [35.0, 0.0], [50.0, 0.0], [60.0, -5.0], [60.0, -22.0], [60.0, -10.0], [65.0, 0.0]]
    )
    (route_down,) = street_routes(net, down[None])
    assert route_down is not None and route_down[:, 1].min() == pytest.approx(-40.0)


def test_a_driver_whose_end_step_lies_far_off_the_streets_is_routed_by_its_other_steps():
    """A first (or last) tracked step farther than ROUTE_REACH from every street left the whole
    driver unsmoothed; its route is now the other steps', and the stray step is put back."""
    net = StreetNetwork.from_segments(L_STREETS)
    true = _drive(np.array([20.0]), 8.3)
    xy, lp, cells = grid_candidates(true)
    for end in (0, -1):
        tracked = cells.copy()
        tracked[0, end, 1 + end] += 6.0  # 6 m off the street it is on
        assert street_routes(net, tracked)[0] is not None
        track, on = route_track(tracked, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
        assert on.all() and np.linalg.norm(track - true, axis=-1).max() < 0.5
    both = cells.copy()
    both[0, [0, -1], 1] += 6.0  # both ends off: the other five still make the route
    assert route_track(both, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)[1].all()
    mid = cells.copy()
    mid[0, 3, 1] += 6.0  # a step between off the streets: no route
    assert street_routes(net, mid) == [None]


def test_the_wider_end_windows_leave_drivers_tracked_right_as_they_were(monkeypatch):
    starts = np.linspace(20.0, 30.0, 17)
    true = _drive(starts, 8.3)
    xy, lp, cells = grid_candidates(true)
    net = StreetNetwork.from_segments(L_STREETS)
    track, _ = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    monkeypatch.setattr(route, "ROUTE_END_WINDOW", route.ROUTE_WINDOW)
    first, _ = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert np.array_equal(track, first)


@pytest.mark.parametrize("left", [1.3, -1.7])
def test_drivers_in_a_lane_beside_the_centre_line_are_smoothed_along_it(left):
    # a lane ``left`` metres left of the L's centre line (right where negative), round its corner
    corner = np.array([60.0 - left, left])
    lane = np.array([[0.0, left], corner, [60.0 - left, 80.0]])
    s = 20.0 + 8.3 * np.arange(7)
    first = s <= corner[0]
    true = np.where(
        first[:, None], np.stack([s, np.full(7, left)], -1), corner + np.outer(s - corner[0], [0, 1])
    )
    xy, lp, cells = grid_candidates(true[None])
    net = StreetNetwork.from_segments(L_STREETS)
    track, on = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert on.all()
    # along the lane the steady steps read far inside a cell (before the corner: past it, where
    # on the cells' row the lane lies shifts the way round it); across it, every line within the
    # row reads alike
    assert np.abs(track[0, first, 0] - true[first, 0]).max() < 0.15
    gap = np.where(first, track[0, :, 1] - left, track[0, :, 0] - lane[1, 0])
    assert np.abs(gap).max() < 0.5
    before = np.linalg.norm(cells - true, axis=-1).mean()
    assert np.linalg.norm(track - true, axis=-1).mean() < 0.8 * before


def test_a_lane_less_than_half_a_grid_spacing_off_the_centre_line_is_kept():
    # a 2 m grid, a driver 0.8 m left of the centre line (0.4 spacings): its track keeps to that
    # side, and the lines beside the centre line are weighed, not the centre line alone
    x = 10.3 + 8.3 * np.arange(7)
    true = np.stack([x, np.full(7, 0.8)], -1)[None]
    g = 2.0 * np.arange(-3, 4)
    xy = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2) + 2.0 * np.rint(
        true[..., None, :] / 2.0
    )
    lp = -0.5 * ((xy - true[..., None, :]) ** 2).sum(-1)
    net = StreetNetwork.from_segments(L_STREETS)
    track, on = route_track(true, xy, lp, net, _speeds(8.3, 170), 0.05, 2.0, 5.0)
    assert on.all()
    # within a row every line reads alike: the track lies among them, not on the centre line
    assert (track[0, :, 1] > 0.3).all() and np.abs(track[0, :, 1] - 0.8).mean() < 0.5


def test_a_lane_is_mitred_at_corners_and_crosses_over_where_its_route_turns_back():
    r = np.array([[-20.0, 0.0], [0.0, 0.0], [60.0, 0.0], [60.0, 60.0], [60.0, 80.0], [60.0, 60.0]])
    left = route._offset(r, 1.0)
    # a left turn's inner corner, then the dead end's cross-over to the lane the other way
    assert np.allclose(left, [[-20, 1], [0, 1], [59, 1], [59, 60], [59, 80], [61, 80], [61, 60]])
    right = route._offset(r[:4], -1.5)
    assert np.allclose(right, [[-20, -1.5], [0, -1.5], [61.5, -1.5], [61.5, 60]])
    assert route._offset(r, 0.0) is r


def test_positions_are_put_on_their_route_by_arc_length_and_side():
    # west along a street to its dead end at (0, 0) and back east, 0.5 m north of the centre
    # line, 8.3 m per step: the arc length grows by a step each time, the turn included (near
    # the dead end both legs are as near), and the side is right going west, left going east
    r = np.array([[80.0, 0.0], [60.0, 0.0], [0.0, 0.0], [60.0, 0.0]])
    x = np.abs(30.0 - 8.3 * np.arange(7))
    arc, side = route._arc_of(r, np.stack([x, np.full(7, 0.5)], -1), 8.3)
    np.testing.assert_allclose(arc, 80.0 + np.r_[-x[:4], x[4:]], atol=1e-12)
    np.testing.assert_allclose(side, np.r_[np.full(4, -0.5), np.full(3, 0.5)], atol=1e-12)
    # off the end of a piece: the foot is the piece's end, the side the distance across it
    arc, side = route._arc_of(r[:2], np.array([[90.0, -2.0]]), 1.0)
    assert arc[0] == 0.0 and side[0] == 2.0


def test_drivers_turn_back_at_a_dead_end():
    # west along the L's first street to its dead end at (0, 0) and back, 8.3 m per step: the
    # street network's drivers turn there, and the route turns with them
    x = np.abs(30.0 - 8.3 * np.arange(7))
    true = np.stack([x, np.zeros_like(x)], -1)[None]
    net = StreetNetwork.from_segments(L_STREETS)
    (route,) = street_routes(net, true)
    assert np.allclose(route[:4], [[80.0, 0.0], [60.0, 0.0], [0.0, 0.0], [60.0, 0.0]])
    xy, lp, cells = grid_candidates(true)
    track, on = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert on.all()
    assert np.linalg.norm(track - true, axis=-1).mean() < 0.5 * np.linalg.norm(cells - true, axis=-1).mean()


def test_a_driver_turning_back_mid_street_is_left_alone(monkeypatch):
    # no dead end within reach: the network's drivers never turn there, so no way along the
    # route fits and the track stays as it was (whatever the gate)
    monkeypatch.setattr(route, "ROUTE_GATE", np.inf)
    x = 110.0 + 8.3 * np.r_[0, 1, 2, 3, 2, 1, 0]
    true = np.stack([x, np.zeros_like(x)], -1)[None]
    net = StreetNetwork.from_segments(np.array([[[0.0, 0.0], [100.0, 0.0]], [[100.0, 0.0], [200.0, 0.0]]]))
    xy, lp, cells = grid_candidates(true)
    track, on = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
    assert not on.any() and np.array_equal(track, cells)


def test_candidate_likelihoods_are_looked_up_per_step():
    # a reference by dictionary: each position reads the grid point it rounds to, the likelier of
    # the two where it lies halfway, a point listed twice its first listing, and a point that is
    # no candidate its step's lowest candidate
    rng = np.random.default_rng(5)
    n, T, K, S = 3, 4, 6, 9
    xy = 2.0 * rng.integers(0, 4, (n, T, K, 2)).astype(float)
    xy[0, 0, 1] = xy[0, 0, 0]  # listed twice: the first listing counts
    lp = rng.normal(size=(n, T, K))
    pos = rng.integers(-2, 10, (n, T, S, 2)).astype(float)  # on grid points, halfway, off the candidates
    got = route._candidate_loglik(xy, lp, pos, 2.0)
    for u, t in itertools.product(range(n), range(T)):
        table: dict[tuple[int, int], float] = {}
        for k in range(K):
            table.setdefault((int(xy[u, t, k, 0] // 2), int(xy[u, t, k, 1] // 2)), lp[u, t, k])
        for s in range(S):
            near = [sorted({int(np.floor(c / 2 + 0.5 - e)) for e in (1e-6, -1e-6)}) for c in pos[u, t, s]]
            want = max(table.get((i, j), lp[u, t].min()) for i in near[0] for j in near[1])
            assert got[u, t, s] == want


def test_a_street_halfway_between_grid_rows_reads_the_likelier_row():
    # a 2 m grid whose rows y = 0 and y = 2 lie 1 m either side of the street: which row a
    # driver on it reads is the grid's rounding (here y = 0, whose points tell where along the
    # street it is); the route weighs the likelier row, not one picked by rounding from wherever
    # the candidates start (y = 2, which tells nothing)
    x = 40.3 + 8.3 * np.arange(7)
    gx = 2.0 * np.rint(x / 2.0)[:, None] + 2.0 * np.arange(-3, 4)  # (T, 7)
    xy = np.stack(np.broadcast_arrays(gx[:, None, :], np.array([2.0, 0.0])[:, None]), -1)  # rows 2, 0
    lp = np.where(xy[..., 1] == 0.0, -10.0 * ((xy[..., 0] - x[:, None, None]) / 2.0) ** 2, -20.0)
    xy, lp = xy.reshape(1, 7, -1, 2), lp.reshape(1, 7, -1)
    cells = np.take_along_axis(xy, lp.argmax(-1)[..., None, None], 2)[:, :, 0]
    net = StreetNetwork.from_segments(np.array([[[0.0, 1.0], [100.0, 1.0]], [[100.0, 1.0], [200.0, 1.0]]]))
    speeds = np.ones(150)  # any speed up to 15 m per step, changed at every other step
    # the smoother's track of such a driver lies on the street (the map's lanes pull it there);
    # a track on a row 1 m off, half a spacing, would read as a driver in a lane beside it
    tracked = np.stack([cells[..., 0], np.ones_like(cells[..., 1])], -1)
    track, on = route_track(tracked, xy, lp, net, speeds, 0.5, 2.0, 5.0)
    assert on.all()
    assert np.abs(track[..., 1] - 1.0).max() < 1e-9
    assert np.abs(track[..., 0] - x).mean() < 0.5 * np.abs(cells[..., 0] - x).mean()


def test_routes_follow_the_streets_a_track_passes():
    net = StreetNetwork.from_segments(L_STREETS)
    (route,) = street_routes(net, _drive(np.array([20.0]), 8.3))
    # the corner, and the two streets run on straight past the ends
    assert np.allclose(route, [[-20.0, 0.0], [0.0, 0.0], [60.0, 0.0], [60.0, 60.0], [60.0, 80.0]])
    (back,) = street_routes(net, _drive(np.array([20.0]), 8.3)[:, ::-1])
    assert np.allclose(back, route[::-1])
    assert street_routes(net, np.array([[[5.0, 30.0], [14.0, 30.0]]])) == [None]  # off the streets


def test_drive_speeds_are_measured_on_the_drivers_along_their_streets():
    t = np.arange(5.0)
    drivers = np.stack(
        [
            np.stack([8.0 * t, np.zeros(5)], -1),
            np.stack([np.r_[0, 8, 16, 21, 26.0], np.zeros(5)], -1),
            # 8 m a step round a corner at (12, 0): the step that turns it is a 5.7 m chord
            [[0.0, 0.0], [8.0, 0.0], [12.0, 4.0], [12.0, 12.0], [12.0, 20.0]],
        ]
    )
    walker = np.stack([1.4 * t, np.ones(5)], -1)[None]
    table = MotionTable().fit_drives(np.concatenate([drivers, walker]), 5.0)
    speeds = table.route_speeds.numpy()
    # the corner's chord and the step before it (heading as neither neighbour) are not speeds
    assert np.flatnonzero(speeds).tolist() == [5 * ROUTE_BINS, 8 * ROUTE_BINS]
    assert speeds[8 * ROUTE_BINS] == pytest.approx(8 / 10) and speeds[5 * ROUTE_BINS] == pytest.approx(2 / 10)
    # one change in the seven pairs of steps that head alike; none at the corner
    assert float(table.route_change) == pytest.approx(1 / 7)
    stop = MotionTable().fit_drives(np.stack([np.r_[0, 8, 8, 16, 24.0], np.zeros(5)], -1)[None], 5.0)
    assert float(stop.route_change) == pytest.approx(2 / 3)  # stopping and going on are changes
    assert not len(MotionTable().fit_drives(walker, 5.0).route_speeds)
    with pytest.raises(ValueError):
        MotionTable().fit_drives(np.full((1, 3, 2), np.nan), 5.0)


def test_estimator_smooths_its_drivers_along_the_attached_map():
    tr = toy_sequence_set(128, 5, seed=1)
    cfg = TrainConfig(model="tn-match", options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, tr.n_beams, tr.n_bins, tr.normaliser())
    est.net.fit_motion(tr.positions, tr.grid_xy, tr.index)
    est.net.motion_fine.route_speeds = torch.from_numpy(_speeds(6.3))
    street = np.array([[[0.0, 20.0], [31.0, 20.0]]])
    est.attach(dataclasses.replace(tr, streets=street))
    true = np.stack([2.3 + 6.3 * np.arange(5), np.full(5, 20.0)], -1)[None]  # 6.3 m per step
    xy, lp, cells = grid_candidates(true, radius=2)
    x = (torch.from_numpy(xy).float(), torch.from_numpy(lp).float()[..., None])
    tracked = torch.from_numpy(cells).float()
    out = est._along_routes(tracked, x)
    fine = est._lane_motion()[1]
    expected, on = route_track(
        cells,
        xy,
        lp,
        est._street_network(),
        fine.route_speeds.numpy(),
        float(fine.route_change),
        1.0,
        5.0,
    )
    assert on.all() and np.allclose(out.numpy(), expected, atol=1e-5)
    assert np.linalg.norm(out.numpy() - true, axis=-1).mean() < np.linalg.norm(cells - true, axis=-1).mean()
    est.route_tracking = False
    assert est._along_routes(tracked, x) is tracked
    est.route_tracking = True
    est.street_lanes = False  # no map, no routes
    assert est._along_routes(tracked, x) is tracked


def _street_estimator():
    """A toy ``tn-match`` (its drivers measured at 5.5 m per step) attached to a toy set with one
    street along y = 20 m: ``(set, estimator)``."""
    tr = toy_sequence_set(128, 5, seed=1)
    cfg = TrainConfig(model="tn-match", options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, tr.n_beams, tr.n_bins, tr.normaliser())
    est.net.fit_motion(tr.positions, tr.grid_xy, tr.index)
    est.net.motion_fine.route_speeds = torch.from_numpy(_speeds(5.5))
    est.attach(dataclasses.replace(tr, streets=np.array([[[0.0, 20.0], [31.0, 20.0]]])), sigma=6.0)
    return tr, est


def _street_drivers(tr, n: int, T: int):
    """``n`` drivers along :func:`_street_estimator`'s street at 5.5 m per step for ``T`` steps,
    as a copy of ``tr`` (their fingerprints at their nearest grid points): ``(set, positions)``."""
    x = np.linspace(0.2, 3.7, n)[:, None] + 5.5 * np.arange(T)
    true = np.stack([x, np.full_like(x, 20.0)], -1)
    ij = np.rint(true - tr.grid_xy.min(0)).astype(np.int64)
    drivers = dataclasses.replace(
        tr, index=ij[..., 0] + 32 * ij[..., 1], positions=true.astype(np.float32), kind=np.full(n, 3, np.int8)
    )
    return drivers, true


def test_online_tracker_puts_its_drivers_on_their_routes(monkeypatch):
    from estimation import estimator as estimator_module
    from estimation.noise import noisy_bits

    # 64 drivers along the street at 5.5 m per step, one more step than the online window
    T = estimator_module.ONLINE_ROUTE_STEPS + 1
    tr, est = _street_estimator()
    drivers, true = _street_drivers(tr, 64, T)
    bits = noisy_bits(drivers, 6.0, torch.Generator().manual_seed(4))
    windows = []
    route_tracks = est._route_tracks

    def spy(tracked, xy, lp):
        windows.append(tracked.shape[1])
        return route_tracks(tracked, xy, lp)

    monkeypatch.setattr(est, "_route_tracks", spy)
    now, trackers = {}, {}
    for routes in (True, False):
        est.route_tracking = routes
        trackers[routes] = tracker = est.tracker()
        now[routes] = np.stack([tracker.update(bits[:, t]) for t in range(T)], 1)
    # a window of the last steps at every update: the same cost at every step
    assert windows == [*range(2, T), T - 1]
    # the routed tracker's filter keeps its own estimates (the windows are made of them)
    assert np.array_equal(np.stack(trackers[True].filter.positions, 1), now[False])
    err = {k: np.linalg.norm(v[:, 1:] - true[:, 1:], axis=-1).mean() for k, v in now.items()}
    assert err[True] < 0.85 * err[False]
    assert np.array_equal(now[True][:, 0], now[False][:, 0])


def test_prediction_routes_its_drivers_in_blocks_of_network_chunks(monkeypatch):
    """The network runs in chunks of PREDICT_CHUNK sequences, the route pass once per block of
    at most ROUTE_CHUNK over the threads (its cost per call is mostly fixed), the blocks side by
    side on the threads; the tracks depend on neither size nor on the threads."""
    from estimation import estimator as estimator_module
    from estimation.noise import noisy_bits
    from mmwsim._threads import set_threads

    tr, est = _street_estimator()
    drivers, _ = _street_drivers(tr, 40, 5)
    inputs = est.inputs(noisy_bits(drivers, 6.0, torch.Generator().manual_seed(4)).float())
    blocks, route_tracks = [], est._route_tracks

    def spy(tracked, xy, lp):
        blocks.append(len(tracked))
        return route_tracks(tracked, xy, lp)

    monkeypatch.setattr(est, "_route_tracks", spy)
    monkeypatch.setattr(estimator_module, "PREDICT_CHUNK", 8)
    set_threads(1)
    try:
        out = est.predict(inputs)
        assert blocks == [40]  # five network chunks, one route pass
        monkeypatch.setattr(estimator_module, "ROUTE_CHUNK", 16)
        assert torch.equal(est.predict(inputs), out)
        assert blocks[1:] == [14, 14, 12]  # even blocks of at most 16
        # from bits, each block's candidates are filtered and let go before the next block's
        bits = noisy_bits(drivers, 6.0, torch.Generator().manual_seed(4)).float()
        filtered, make = [], est.inputs
        monkeypatch.setattr(est, "inputs", lambda b: filtered.append(len(b)) or make(b))
        assert torch.equal(est.predict(bits), out) and filtered == [14, 14, 12]
        monkeypatch.setattr(estimator_module, "ROUTE_CHUNK", 1024)
        set_threads(2)  # two blocks side by side
        del blocks[:]
        assert torch.equal(est.predict(inputs), out) and blocks == [20, 20]
    finally:
        set_threads(None)
    est.route_tracking = False
    assert not torch.equal(est.predict(inputs), out)  # the route pass moved them
