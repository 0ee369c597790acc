"""Drivers smoothed along their street routes (estimation.smoothing.route)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from estimation import Estimator, TrainConfig
from estimation.smoothing.motion import MotionTable
from estimation.smoothing.route import ROUTE_BINS, route_track, street_routes
from estimation.synthetic import toy_sequence_set
from mmwsim.trajectories import StreetNetwork

# An L of streets: east along y = 0 to (60, 0), then north to (60, 60).
L_STREETS = np.array([[[0.0, 0.0], [60.0, 0.0]], [[60.0, 0.0], [60.0, 60.0]]])


def _along_l(s: np.ndarray) -> np.ndarray:
    """Positions at arc lengths ``s`` along the L."""
    s = np.asarray(s, dtype=np.float64)
    east = np.stack([s, np.zeros_like(s)], -1)
    north = np.stack([np.full_like(s, 60.0), s - 60.0], -1)
    return np.where((s <= 60.0)[..., None], east, north)


def _candidates(true: np.ndarray, radius: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every step's grid points (1 m grid) within ``radius`` of the true one's cell, the cell
    itself the most likely by 10 nats: what a fingerprint tells. Returns the candidates, their
    log-likelihoods and the cells (the per-step best match)."""
    cell = np.rint(true)
    d = np.arange(-radius, radius + 1.0)
    around = np.stack(np.meshgrid(d, d, indexing="ij"), -1).reshape(-1, 2)
    xy = cell[..., None, :] + around  # (B, T, K, 2)
    lp = np.where(np.abs(around).sum(-1) == 0, 0.0, -10.0) * np.ones(xy.shape[:-1])
    return xy, lp, cell


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
    xy, lp, cells = _candidates(true)
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
    xy, lp, cells = _candidates(true)
    speeds = _speeds(8.3) + _speeds(5.3)
    track, on = route_track(cells, xy, lp, StreetNetwork.from_segments(L_STREETS), speeds, 0.2, 1.0, 5.0)
    assert (
        on.all()
        and np.linalg.norm(track - true, axis=-1).mean() < 0.5 * np.linalg.norm(cells - true, axis=-1).mean()
    )


def test_users_off_the_streets_beside_them_or_slow_are_left_alone():
    net = StreetNetwork.from_segments(L_STREETS)
    off = _drive(np.array([20.0]), 8.3) + np.array([0.0, 10.0])  # 10 m from the street
    lane = _drive(np.array([2.0]), 8.3) + np.array([0.0, 1.2])  # in a lane beside the centre line
    slow = _drive(np.array([20.0]), 1.4)  # a walker on the street
    for true in (off, lane, slow):
        xy, lp, cells = _candidates(true)
        track, on = route_track(cells, xy, lp, net, _speeds(8.3), 0.05, 1.0, 5.0)
        assert not on.any() and np.array_equal(track, cells)


def test_routes_follow_the_streets_a_track_passes():
    net = StreetNetwork.from_segments(L_STREETS)
    (route,) = street_routes(net, _drive(np.array([20.0]), 8.3))
    # the corner, and the two streets run on straight past the ends
    assert np.allclose(route, [[-20.0, 0.0], [0.0, 0.0], [60.0, 0.0], [60.0, 60.0], [60.0, 80.0]])
    (back,) = street_routes(net, _drive(np.array([20.0]), 8.3)[:, ::-1])
    assert np.allclose(back, route[::-1])
    assert street_routes(net, np.array([[[5.0, 30.0], [14.0, 30.0]]])) == [None]  # off the streets


def test_drive_speeds_are_measured_on_the_drivers():
    t = np.arange(5.0)
    drivers = np.stack(
        [np.stack([8.0 * t, np.zeros(5)], -1), np.stack([np.r_[0, 8, 16, 21, 26.0], np.zeros(5)], -1)]
    )
    walker = np.stack([1.4 * t, np.ones(5)], -1)[None]
    table = MotionTable().fit_drives(np.concatenate([drivers, walker]), 5.0)
    speeds = table.route_speeds.numpy()
    assert speeds[8 * ROUTE_BINS] == pytest.approx(6 / 8) and speeds[5 * ROUTE_BINS] == pytest.approx(2 / 8)
    assert speeds.sum() == pytest.approx(1.0)
    assert float(table.route_change) == pytest.approx(1 / 6)  # one change in six pairs of steps
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
    xy, lp, cells = _candidates(true, radius=2)
    x = (torch.from_numpy(xy).float(), torch.from_numpy(lp).float()[..., None])
    tracked = torch.from_numpy(cells).float()
    out = est._along_routes(tracked, x)
    fine = est._lane_motion()[1]
    expected, on = route_track(
        cells,
        xy,
        lp,
        est._street_network(True),
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
