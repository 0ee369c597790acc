"""Forecasts carried through the motion table or along the streets (estimation.smoothing.forecast):
drawn accelerations follow the table in either frame, vehicles follow their lanes round a corner
where the constant velocity forecast leaves them, steady users are carried on exactly, and a user's
forecast is its own whatever its batch; along a street map, drivers keep their speed and their
side of the centre line round a corner, split evenly at a junction, turn at a dead end, and users
off the streets are carried by the table."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from estimation.smoothing.forecast import STREET_REACH, carry, extrapolate, follow_streets, forecast_tracks
from estimation.smoothing.motion import MotionTable, snap_to_lattice
from mmwsim.trajectories import StreetNetwork, TrajectoryError, streets

SPEED = 6.0  # grid units per step: above the place tables' speed (5)


def _l_drives(n: int, length: int, seed: int) -> np.ndarray:
    """``(n, length, 2)`` vehicles at SPEED along an L: east along y = 10 to the corner (40, 10),
    then north along x = 40, each reaching the corner at one of the first seven steps."""
    k = np.random.default_rng(seed).integers(0, 7, n)[:, None]
    s = 40.0 - SPEED * k + SPEED * np.arange(length)
    east = np.stack([s, np.full_like(s, 10.0)], -1)
    north = np.stack([np.full_like(s, 40.0), 10.0 + (s - 40.0)], -1)
    return np.where((s <= 40.0)[..., None], east, north)


def _lane_table() -> MotionTable:
    """A lattice-frame table measured on the L drives, with the L as its lanes in an area of 200 x
    200 cells that users visit (lanes are a small part of a city)."""
    table = MotionTable.lattice().fit(_l_drives(400, 8, 0))
    lines = np.array([[[0.0, 10.0], [40.0, 10.0]], [[40.0, 10.0], [40.0, 60.0]]])
    return table.fit_place_lines(lines, np.array([-0.5, -0.5]), 1.0, (61, 61), visited=200 * 200, speed=5.0)


@pytest.mark.parametrize(
    "table", [MotionTable(), MotionTable.lattice()], ids=["motion frame", "lattice frame"]
)
def test_drawn_accelerations_follow_the_table_in_either_frame(table):
    rng = np.random.default_rng(0)
    walks = np.cumsum(rng.normal(size=(400, 8, 2)) + np.array([2.0, 0.7]), axis=1)
    table.fit(walks if int(table.headings) == 0 else snap_to_lattice(walks))
    n_acc = table.log_accel_table.shape[1]
    for v in ([2.0, 0.7], [-0.3, -2.5], [0.0, 0.0]):
        vs = torch.tensor(v, dtype=torch.float64).expand(40000, 2)
        u = torch.from_numpy(rng.random(40000))
        a = table.sample_accel(vs, u)
        # read back through the table's own frame and bins, every draw lands in a bin of its class
        # with the class's probability
        along, across, cls = table._classify(vs, a)
        assert (cls == cls[0]).all()
        k = table._acc_index(along + 1e-9) * n_acc + table._acc_index(across + 1e-9)
        drawn = np.bincount(k.numpy(), minlength=n_acc * n_acc) / len(k)
        p = torch.softmax(table.log_accel_table[cls[0]].double().reshape(-1), 0).numpy()
        top = np.argsort(-p)[:20]  # the bins most draws fall in, each within 5 standard errors
        assert (np.abs(drawn[top] - p[top]) < 5 * np.sqrt(p[top] / len(k))).all()
        assert abs(drawn[top].sum() - p[top].sum()) < 0.01
    # the same uniform numbers draw the same accelerations
    assert torch.equal(table.sample_accel(vs, u), a)


def test_vehicles_follow_their_lane_round_a_corner():
    table = _lane_table()
    # seen for four steps, reaching the corner at the first or second step after them
    drives = _l_drives(64, 7, 1)
    near = (drives[:, 3, 0] == 40.0 - SPEED) | (drives[:, 3, 0] == 40.0 - 2 * SPEED)
    seen, future = torch.from_numpy(drives[near, :4]), drives[near, 4:]
    assert near.sum() >= 8
    carried = carry(table, seen[:, -2], seen[:, -1], 3).numpy()
    straight = extrapolate(seen, 3).numpy()
    err = lambda p: np.linalg.norm(p - future, axis=-1).max(0)  # noqa: E731
    assert (err(carried) < 0.5).all(), err(carried)  # every one of them turns with its lane
    assert (err(straight)[1:] > 5.0).all()  # where the constant-velocity forecast goes on east


def test_steady_users_are_carried_on_and_forecasts_do_not_depend_on_the_batch():
    table = _lane_table()
    # on the straight part, far from the corner: the constant-velocity forecast
    seen = torch.tensor([[[2.0, 10.0], [8.0, 10.0]], [[5.0, 10.0], [11.0, 10.0]]], dtype=torch.float64)
    carried = carry(table, seen[:, 0], seen[:, 1], 2)
    assert torch.allclose(carried, extrapolate(seen, 2), atol=1e-3)
    # a batch's forecasts are each user's alone
    drives = torch.from_numpy(_l_drives(16, 4, 2))
    batch = carry(table, drives[:, -2], drives[:, -1], 3)
    for i in (0, 7, 15):
        assert torch.equal(carry(table, drives[i : i + 1, -2], drives[i : i + 1, -1], 3)[0], batch[i])


def test_only_fast_users_of_a_table_with_lanes_are_carried():
    table = _lane_table()
    spacing = 2.0  # metres per grid unit
    drives = torch.from_numpy(_l_drives(8, 4, 3)) * spacing
    slow = (
        torch.stack([torch.arange(4.0)[:, None].expand(4, 2) * 1.2 + 30.0] * 3) * spacing
    )  # 1.7 units per step
    tracked = torch.cat([drives, slow]).float()
    out = forecast_tracks(tracked, 3, table, spacing)
    assert out.dtype == tracked.dtype and out.shape == (11, 3, 2)
    expect = carry(table, tracked[:8, -2].double() / spacing, tracked[:8, -1].double() / spacing, 3) * spacing
    assert torch.allclose(out[:8], expect.float())
    assert torch.equal(out[8:], extrapolate(tracked[8:], 3))
    # no lanes, or no velocity to carry: the constant-velocity forecast for all
    assert torch.equal(forecast_tracks(tracked, 3, MotionTable.lattice(), spacing), extrapolate(tracked, 3))
    assert torch.equal(forecast_tracks(tracked[:, -1:], 2, table, spacing), extrapolate(tracked[:, -1:], 2))


# The L of _l_drives as a street map, and a crossing: four streets meeting at (40, 10).
L_STREETS = np.array([[[0.0, 10.0], [40.0, 10.0]], [[40.0, 10.0], [40.0, 60.0]]])
CROSS = np.array(
    [
        [[0.0, 10.0], [40.0, 10.0]],
        [[40.0, 10.0], [80.0, 10.0]],
        [[40.0, 10.0], [40.0, 60.0]],
        [[40.0, 10.0], [40.0, -40.0]],
    ]
)


def test_street_segments_make_the_network_they_came_from(monkeypatch):
    net = StreetNetwork.from_segments(CROSS)
    assert len(net.nodes) == 5 and len(net.edges) == 4
    assert sorted(net.degree.tolist()) == [1, 1, 1, 1, 4]
    # from the west into the crossing: each of the three other streets for a third of the uniform
    # numbers, never back; at a dead end, back
    centre = int(np.flatnonzero(net.degree == 4)[0])
    west = int(np.flatnonzero((net.nodes == [0.0, 10.0]).all(1))[0])
    u = (np.arange(12) + 0.5) / 12
    nxt = net.onward(np.full(12, centre), np.full(12, west), u)
    assert west not in nxt and np.array_equal(np.bincount(nxt, minlength=5)[nxt[::4]], [4, 4, 4])
    assert np.array_equal(net.onward(np.array([west]), np.array([centre]), np.array([0.7])), [centre])
    again = StreetNetwork.from_segments(net.lines())
    assert np.array_equal(again.nodes, net.nodes) and np.array_equal(again.edges, net.edges)
    # the ways from the west end: 40 m to the crossing, 80 or 90 m on to the other ends; kept
    length, pred = net.ways_from(west)
    assert sorted(length) == pytest.approx([0.0, 40.0, 80.0, 90.0, 90.0]) and length[centre] == 40.0
    assert pred[centre] == west and (pred[length > 40.0] == centre).all()
    assert net.ways_from(west)[0] is length and not length.flags.writeable
    near, _ = net.ways_from(west, limit=45.0)  # a limit of its own
    assert near[centre] == 40.0 and np.isinf(near).sum() == 3
    monkeypatch.setattr(streets, "_WAYS_KEPT_BYTES", 1)  # room for one result: the oldest goes
    net.ways_from(centre)
    assert net.ways_from(west)[0] is not length
    for bad, match in ((np.zeros((2, 3, 2)), "shape"), (np.full((1, 2, 2), np.inf), "NaN")):
        with pytest.raises(TrajectoryError, match=match):
            StreetNetwork.from_segments(bad)


def test_drivers_follow_the_street_round_a_corner_at_their_speed():
    net = StreetNetwork.from_segments(L_STREETS)
    drives = _l_drives(64, 7, 1)
    seen, future = drives[:, :4], drives[:, 4:]
    out, on = follow_streets(net, seen[:, -2], seen[:, -1], 3)
    assert on.all() and out.shape == (64, 3, 2)
    # one onward street: the distance along the centre line is exact, round the corner too
    assert np.abs(out - future).max() < 1e-9
    assert np.abs(extrapolate(torch.from_numpy(seen), 3).numpy() - future).max() > 5.0
    # a driver 1.5 m right of the centre line keeps to that side: south heading east, east
    # heading north
    right = seen[:, -2:] - np.array([0.0, 1.5])
    east = (seen[:, -1, 0] < 40.0) & (seen[:, -2, 0] < seen[:, -1, 0])
    out, on = follow_streets(net, right[east, 0], right[east, 1], 3)
    assert on.all()
    turned = future[east][:, :, 1] > 10.0
    assert np.allclose(out[turned][:, 0], 41.5) and np.allclose(out[~turned][:, 1], 8.5)
    assert np.allclose(out[turned][:, 1], future[east][turned][:, 1])
    # just round the corner, the displacement runs along the street left (6 m east, 2 m north) but
    # the driver is on the new one, at the 8 m per step it drove round the corner: on north, not
    # on east past the corner and round it, nor at the chord's 6.3 m
    out, on = follow_streets(net, np.array([[34.0, 10.0]]), np.array([[40.0, 12.0]]), 2)
    assert on.all() and np.allclose(out[0], [[40.0, 20.0], [40.0, 28.0]])
    # no velocity, across the street or beyond the street's reach: not driving along it
    x = np.array([[20.0, 10.0], [20.0, 10.0], [20.0, 10.0 + STREET_REACH + 0.5]])
    out, on = follow_streets(net, x - np.array([[0.0, 0.0], [0.0, 6.0], [6.0, 0.0]]), x, 2)
    assert not on.any() and np.array_equal(out, np.repeat(x[:, None], 2, axis=1))


def test_a_junction_splits_the_forecast_evenly_and_a_dead_end_turns_back():
    net = StreetNetwork.from_segments(CROSS)
    # 6 m per step from 4 m before the crossing: 2 m past it on one of three streets
    out, on = follow_streets(net, np.array([[30.0, 10.0]]), np.array([[36.0, 10.0]]), 1)
    # (42, 10), (40, 12) and (40, 8) in equal shares: their geometric median (the Fermat point,
    # where each pair subtends 120 degrees), not their mean (41.33, 10)
    assert on.all() and np.allclose(out[0, 0], [40.0 + 2.0 / np.sqrt(3.0), 10.0], atol=0.05)
    # a dead end: back along the same street
    out, _ = follow_streets(net, np.array([[70.0, 10.0]]), np.array([[76.0, 10.0]]), 1)
    assert np.allclose(out[0, 0], [78.0, 10.0])
    # a user's forecast is its own whatever its batch
    drives = _l_drives(16, 4, 2) + np.array([0.0, 0.3])
    batch, _ = follow_streets(net, drives[:, -2], drives[:, -1], 3)
    for i in (0, 7, 15):
        alone, _ = follow_streets(net, drives[i : i + 1, -2], drives[i : i + 1, -1], 3)
        assert np.array_equal(alone[0], batch[i])


def test_fast_users_on_a_street_map_follow_it_and_the_others_are_carried():
    table = _lane_table()
    spacing = 2.0
    net = StreetNetwork.from_segments(L_STREETS * spacing)
    drives = torch.from_numpy(_l_drives(8, 4, 3)) * spacing
    off = drives + torch.tensor([-20.0, 20.0]) * spacing  # streets away from the map's
    tracked = torch.cat([drives, off])
    out = forecast_tracks(tracked, 3, table, spacing, net)
    along, on = follow_streets(net, drives[:, -2].numpy(), drives[:, -1].numpy(), 3)
    assert on.all() and torch.equal(out[:8], torch.from_numpy(along))
    expect = carry(table, off[:, -2] / spacing, off[:, -1] / spacing, 3) * spacing
    assert torch.equal(out[8:], expect)


def test_fast_users_who_just_stopped_do_what_the_training_users_did_next():
    # drives at 6 units per step that stop for one step (at 2 / 3 / 4) and drive on at 6, then
    # drives that stop for good: the median next step after a stop is 6, then 0
    t = np.arange(8.0)
    pause = np.stack([np.minimum(6.0 * t, 6.0 * np.maximum(t - 1, k)) for k in (2, 3, 4)] * 10)
    stay = np.stack([np.minimum(6.0 * t, 6.0 * k) for k in (2, 3, 4)] * 10)
    on_line = lambda x: np.stack([x, np.full_like(x, 10.0)], -1)  # noqa: E731
    lines = L_STREETS[:1] * np.array([[4.0, 1.0]])  # a long street along y = 10
    table = MotionTable.lattice()
    table.fit(on_line(pause)).fit_place(on_line(pause), np.array([-0.5, -0.5]), 1.0, (200, 21), speed=5.0)
    assert float(table.restart_step) == pytest.approx(6.0)
    net = StreetNetwork.from_segments(lines)
    stopped = torch.from_numpy(on_line(np.array([[0.0, 6.0, 6.0]])))
    out = forecast_tracks(stopped, 2, table, 1.0, net)
    assert torch.allclose(out, torch.from_numpy(on_line(np.array([[12.0, 18.0]]))))
    # without the street map, or where stopped users stayed, a stopped user stays
    assert torch.equal(forecast_tracks(stopped, 2, table, 1.0), extrapolate(stopped, 2))
    table.fit_place(on_line(stay), np.array([-0.5, -0.5]), 1.0, (200, 21), speed=5.0)
    assert float(table.restart_step) == 0.0
    assert torch.equal(forecast_tracks(stopped, 2, table, 1.0, net), extrapolate(stopped, 2))
