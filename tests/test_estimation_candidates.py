"""tn-match: the transformer over fingerprint-match candidates and its hidden-Markov smoother."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
import torch

from estimation import (
    EstimationError,
    Estimator,
    MatchSmoother,
    TrainConfig,
    noisy_bits,
    train,
    trajectory_rmse,
)
from estimation.evaluation import NetworkMethod
from estimation.models import CandidateTransformer
from estimation.models.candidate_transformer import KIND_TABLE, KIND_TABLE_MIN, NET_REACH
from estimation.smoothing.beam import motion_arrays
from estimation.smoothing.forecast import extrapolate, forecast_tracks
from estimation.smoothing.hmm import (
    STEP_SIGMAS,
    candidate_features,
    motion_posterior,
    subcell_mean,
    velocity_posterior,
)
from estimation.smoothing.memory import MotionMemory
from estimation.smoothing.motion import (
    WALK_COPIES,
    WALK_SCALES,
    MixtureMotion,
    MotionTable,
    snap_to_lattice,
    speed_scaled,
)
from estimation.smoothing.online import FILTER_CANDIDATES, MODE_CHAIN, WALKER_SPEED_PRIOR
from estimation.synthetic import toy_sequence_set
from estimation.training import _inputs as training_inputs
from mmwsim.trajectories.motion import KINDS


def test_motion_posterior_one_step_is_the_likelihood():
    logp = torch.log_softmax(torch.tensor([[[0.0, 1.0, -2.0]]]), -1)
    xy = torch.rand(1, 1, 3, 2)
    assert torch.allclose(motion_posterior(xy, logp, 3.0), logp, atol=1e-6)


def test_motion_posterior_two_steps_by_hand():
    """Two steps, two candidates each: the posterior of candidate i at step 0 is proportional to
    l0_i * sum_j A_ij l1_j with A_ij = exp(-d_ij^2 / 2 s^2)."""
    xy = torch.tensor([[[[0.0, 0.0], [10.0, 0.0]], [[1.0, 0.0], [10.0, 3.0]]]])
    like = torch.tensor([[[0.6, 0.4], [0.3, 0.7]]])
    s = 2.0
    got = motion_posterior(xy, like.log(), s).exp()[0]
    d = torch.cdist(xy[0, 0], xy[0, 1])
    A = torch.exp(-(d**2) / (2 * s**2))
    p0 = like[0, 0] * (A @ like[0, 1])
    p1 = like[0, 1] * (A.T @ like[0, 0])
    assert torch.allclose(got[0], p0 / p0.sum(), atol=1e-6)
    assert torch.allclose(got[1], p1 / p1.sum(), atol=1e-6)


def test_motion_posterior_against_enumeration_of_all_paths():
    g = torch.Generator().manual_seed(2)
    xy = torch.rand(4, 3, 2, generator=g) * 8  # 4 steps, 3 candidates
    like = torch.rand(4, 3, generator=g) + 0.1
    s = 2.5
    marg = torch.zeros(4, 3, dtype=torch.float64)
    for path in itertools.product(range(3), repeat=4):
        p = math.prod(float(like[t, j]) for t, j in enumerate(path))
        for t in range(3):
            p *= math.exp(-float((xy[t + 1, path[t + 1]] - xy[t, path[t]]).square().sum()) / (2 * s**2))
        for t, j in enumerate(path):
            marg[t, j] += p
    got = motion_posterior(xy[None], like.log()[None], s).exp()[0].double()
    assert torch.allclose(got, marg / marg.sum(1, keepdim=True), atol=1e-6)


def test_motion_posterior_of_unreachable_steps_falls_back_to_the_likelihoods():
    """Steps whose candidates lie kilometres apart: every transition underflows; the posterior
    stays finite and becomes each step's own likelihood."""
    xy = torch.tensor([[[0.0, 0.0], [0.0, 5.0]], [[3000.0, 0.0], [3000.0, 5.0]]])[None]
    logp = torch.log_softmax(torch.tensor([[[0.0, 2.0], [1.0, -1.0]]]), -1)
    got = motion_posterior(xy, logp, 2.0)
    assert torch.isfinite(got).all()
    assert torch.allclose(got, logp, atol=1e-5)


def _path_posterior_by_enumeration(xy, like, motion):
    """Marginals of the second-order model by summing over every path of candidates."""
    T, K = like.shape
    marg = torch.zeros(T, K, dtype=torch.float64)
    for path in itertools.product(range(K), repeat=T):
        x = torch.stack([xy[t, j] for t, j in enumerate(path)])
        logp = sum(math.log(float(like[t, j])) for t, j in enumerate(path))
        logp += float(motion.log_first(x[1] - x[0]))
        for t in range(1, T - 1):
            logp += float(motion.log_accel(x[t] - x[t - 1], x[t + 1] - 2 * x[t] + x[t - 1]))
        if isinstance(motion, MotionTable):  # each position given the step into it (out of it at 0)
            logp += float(motion.log_place_ratio(x[1] - x[0], x[0]))
            logp += sum(float(motion.log_place_ratio(x[t] - x[t - 1], x[t])) for t in range(1, T))
        for t, j in enumerate(path):
            marg[t, j] += math.exp(logp)
    return marg / marg.sum(1, keepdim=True)


def _straight_tracks(n=400, length=8, seed=0):
    """Users at 1.4 or 8 m/step in random headings whose speed changes along the motion only."""
    rng = np.random.default_rng(seed)
    speed = rng.choice([1.4, 8.0], n)[:, None] + np.cumsum(
        rng.choice([-1.0, 0.0, 0.0, 1.0], (n, length - 1)), 1
    )
    heading = rng.uniform(0, 2 * np.pi, n)[:, None]
    steps = speed[..., None] * np.stack([np.cos(heading), np.sin(heading)], -1)
    return np.concatenate([np.zeros((n, 1, 2)), np.cumsum(steps, 1)], 1) + rng.uniform(0, 300, (n, 1, 2))


def _laned():
    """A motion table whose place table has fast users only in the band 1 < y < 3."""
    tracks = _straight_tracks()
    lane = np.stack([np.arange(8) * 3.0, np.full(8, 2.0)], -1)[None].repeat(50, 0)
    return MotionTable().fit(tracks).fit_place(lane, (-1.0, -1.0), 1.0, (30, 8), speed=1.0, floor=0.2)


@pytest.mark.parametrize(
    "motion",
    [MixtureMotion(first_step_sigma=5.0), MotionTable().fit(_straight_tracks()), _laned()],
    ids=["mixture", "table", "table-with-place"],
)
def test_velocity_posterior_against_enumeration_of_all_paths(motion):
    g = torch.Generator().manual_seed(4)
    xy = torch.rand(4, 3, 2, generator=g) * 6  # 4 steps, 3 candidates
    like = torch.rand(4, 3, generator=g) + 0.1
    got = velocity_posterior(xy[None], like.log()[None], motion).exp()[0].double()
    assert torch.allclose(got, _path_posterior_by_enumeration(xy, like, motion), atol=1e-5)
    one = velocity_posterior(xy[None, :1], like.log()[None, :1], motion)
    assert torch.allclose(one.exp()[0, 0], like[0] / like[0].sum(), atol=1e-6)


def test_motion_table_is_a_density_in_the_frame_of_the_motion():
    table = MotionTable().fit(_straight_tracks())
    assert bool(table.fitted) and not bool(MotionTable().fitted)
    # every speed band's acceleration table and the displacement table integrate to one
    assert torch.allclose(table.log_accel_table.exp().sum((1, 2)) * table.bin**2, torch.ones(12), atol=1e-4)
    r = (torch.arange(len(table.log_step_table)) + 0.5) * table.bin
    assert abs(float((table.log_step_table.exp() * 2 * math.pi * r).sum() * table.bin) - 1) < 1e-4
    # the tracks change speed along their heading, never across it, whatever the heading
    for v in ([8.0, 0.0], [0.0, -8.0], [5.6, 5.6]):
        v = torch.tensor(v)
        u = v / v.norm()
        along, across = table.log_accel(v, u), table.log_accel(v, torch.stack([-u[1], u[0]]))
        assert float(along - across) > 3.0
    # speeds seen (1.4 and 8 m/step) are far more likely first steps than one never seen
    first = table.log_first(torch.tensor([[1.4, 0.0], [0.0, 8.0], [20.0, 0.0]]))
    assert float(first[:2].min() - first[2]) > 3.0
    with pytest.raises(ValueError, match="shape"):
        MotionTable().fit(np.zeros((3, 2, 2)))
    with pytest.raises(ValueError, match="NaN"):
        MotionTable().fit(np.full((3, 4, 2), np.nan))


def test_broadened_table_mixes_turns_and_steering_noise_into_the_measured_one():
    table = MotionTable().fit(_straight_tracks()).fit_place(_straight_tracks(), (0.0, 0.0), 2.0, (200, 200))
    wide = table.broadened()
    assert table.has_place and not wide.has_place and bool(wide.fitted)
    # still densities where the turn ring fits inside the table's reach (mid speeds <= 6 per step)
    edges = table.speed_edges.tolist()
    mids = [(lo + hi) / 2 for lo, hi in zip([0.0] + edges, edges + [1.4 * edges[-1]], strict=True)]
    low = [b for b, s in enumerate(mids) if s <= 6.0]
    mass = wide.log_accel_table[low].double().exp().sum((1, 2)) * wide.bin**2
    assert torch.allclose(mass, torch.ones(len(low), dtype=torch.float64), atol=1e-3)
    # a reversal at 8 m/step, next to impossible for the straight tracks, is a plain turn now
    v, back = torch.tensor([8.0, 0.0]), torch.tensor([-16.0 + 0.25, 0.25])
    assert float(wide.log_accel(v, back) - table.log_accel(v, back)) > 5.0
    # no weight on the alternatives: the measured table itself
    same = table.broadened(turn=0.0, steer=0.0, flat_step=0.0)
    assert torch.allclose(same.log_accel_table, table.log_accel_table, atol=1e-5)
    assert torch.allclose(same.log_step_table, table.log_step_table, atol=1e-5)
    # steering noise alone, its spread given in metres, on a table of 0.5 m units
    b = 2  # speeds 1.2 .. 1.6 units, mid 1.4
    only = table.broadened(unit=0.5, turn=0.0, steer=1.0)
    sd = (0.7 + 0.1 * 1.4 * 0.5) / 0.5
    c = table.bin / 2  # the bin centre next to zero acceleration
    expected = math.log(math.exp(-(2 * c * c) / (2 * sd**2)) / (2 * math.pi * sd**2))
    assert float(only.log_accel_table[b, 32, 32]) == pytest.approx(expected, abs=1e-5)
    with pytest.raises(ValueError, match="weights"):
        table.broadened(turn=0.6, steer=0.6)
    # with walls: a second set of classes, for the steps whose way straight ahead is blocked
    walled = table.broadened(turn=0.1, steer=0.8, blocked=(0.9, 0.05))
    n = len(table.log_accel_table)
    assert walled.wall_classes == n and len(walled.log_accel_table) == 2 * n
    assert torch.equal(walled.log_accel_table[:n], table.broadened(turn=0.1, steer=0.8).log_accel_table)
    assert torch.equal(walled.log_accel_table[n:], table.broadened(turn=0.9, steer=0.05).log_accel_table)
    assert walled.walls is None and table.wall_classes == 0
    with pytest.raises(ValueError, match="wall classes already"):
        walled.broadened()
    with pytest.raises(ValueError, match="no wall classes"):
        table.with_walls(np.ones((2, 2), bool), (0.0, 0.0), 1.0)
    with pytest.raises(ValueError, match="weights"):
        table.broadened(blocked=(0.9, 0.2))
    with pytest.raises(ValueError, match="origin"):
        walled.with_walls(np.ones((2, 2), bool), (0.0, np.nan), 1.0)


def test_speed_pooled_table_mixes_the_fast_bands_by_their_samples():
    tracks = _straight_tracks()
    table = MotionTable().fit(tracks).fit_place(tracks, (0.0, 0.0), 2.0, (200, 200))
    counts = table.band_count.numpy()
    assert counts.sum() == len(tracks) * (tracks.shape[1] - 2)  # every acceleration sample once
    pooled = table.speed_pooled(6.0)
    lower = np.concatenate([[0.0], table.speed_edges.numpy()])
    fast, slow = np.flatnonzero(lower >= 6.0), np.flatnonzero(lower < 6.0)
    assert (counts[fast] > 0).sum() >= 2 and pooled.has_place
    assert torch.equal(pooled.log_accel_table[slow], table.log_accel_table[slow])
    # one density for every fast band: the count-weighted mixture of theirs, still a density
    dens = table.log_accel_table[fast].double().exp()
    expected = (dens * torch.from_numpy(counts[fast] / counts[fast].sum())[:, None, None]).sum(0)
    for b in fast:
        assert torch.allclose(pooled.log_accel_table[b].double().exp(), expected, rtol=1e-4, atol=1e-12)
    assert float(pooled.log_accel_table[fast[0]].double().exp().sum() * pooled.bin**2) == pytest.approx(
        1, abs=1e-3
    )
    # a steady user at 10 per step (a band the tracks only cross while speeding up or slowing
    # down) now reads the steady driving of all fast bands
    v, steady = torch.tensor([10.0, 0.0]), torch.tensor([0.1, 0.1])
    assert float(pooled.log_accel(v, steady)) > float(table.log_accel(v, steady))
    # nothing to pool: not fitted, no fast users, or saved before the counts were kept
    assert MotionTable().speed_pooled() is None
    assert MotionTable().fit(tracks / 8.0).speed_pooled(6.0) is None
    state = {k: v for k, v in table.state_dict().items() if k != "band_count"}
    old = MotionTable()
    old.load_state_dict(state)
    assert bool(old.fitted) and old.speed_pooled(6.0) is None


def test_place_table_keeps_fast_users_in_their_lanes_and_leaves_slow_ones_alone():
    # fast users (3 m/step) only along the lane y = 2; walkers (0.5 m/step) anywhere
    lane = np.stack([np.arange(8) * 3.0, np.full(8, 2.0)], -1)[None].repeat(50, 0)
    rng = np.random.default_rng(0)
    walk = rng.uniform(0, 25, (200, 1, 2)) + np.cumsum(rng.normal(0, 0.35, (200, 8, 2)), 1)
    tracks = np.concatenate([lane, np.clip(walk, 0, 25)])
    table = MotionTable().fit(tracks)
    assert not table.has_place
    table.fit_place(tracks, (-0.5, -0.5), 1.0, (26, 26), speed=1.0, floor=0.25)
    fast, slow = torch.tensor([3.0, 0.0]), torch.tensor([0.5, 0.0])
    at = torch.tensor([[12.0, 2.0], [12.0, 10.0], [100.0, 2.0]])  # lane, off lane, outside (edge)
    r = table.log_place_ratio(fast, at)
    off = math.log(0.25 / 1.25)  # where no fast user went, inside the area or outside it
    assert float(r[0]) > 1.5 and float(r[1]) == pytest.approx(off, abs=2e-3)
    assert float(r[2]) == pytest.approx(off, abs=2e-3)
    # the table covers the fast users' box only: a lane in a huge area costs a small table (and no
    # array of the whole area while measuring)
    alone = MotionTable().fit_place(lane, (-0.5, -0.5), 1.0, (10**6, 10**6), speed=1.0, floor=0.25)
    assert alone.log_place.numel() < 200
    far = torch.tensor([[12.0, 2.0], [12.0, 900.0], [-50.0, 2.0]])
    got = alone.log_place_ratio(fast, far)
    assert float(got[0]) > off + 1 and torch.allclose(
        got[1:].double(), torch.full((2,), off, dtype=torch.float64), atol=2e-3
    )
    assert torch.equal(table.log_place_ratio(slow, at), torch.zeros(3))
    # two equally likely candidates per step, on the lane and 0.6 m beside it (the next cell)
    xs = torch.arange(5, dtype=torch.float32)[:, None]
    for step, lane_share in ((3.0, 0.9), (0.3, None)):
        x = xs * step
        xy = torch.stack(
            [torch.cat([x, torch.full_like(x, 2.0)], 1), torch.cat([x, torch.full_like(x, 2.6)], 1)], 1
        )
        with_place = velocity_posterior(xy[None], torch.zeros(1, 5, 2), table).exp()[0, :, 0]
        without = velocity_posterior(xy[None], torch.zeros(1, 5, 2), MotionTable().fit(tracks)).exp()[0, :, 0]
        if lane_share is None:  # walkers: no preference
            assert torch.allclose(with_place, without, atol=1e-6)
        else:  # the motion alone hardly tells the lanes apart, the place table does
            assert ((without - 0.5).abs() < 0.1).all() and (with_place > lane_share).all()
    # the table travels with the state dict, whatever its size; a model saved before place tables
    # existed loads with none
    fresh = MotionTable()
    fresh.load_state_dict(table.state_dict())
    assert fresh.has_place and torch.equal(fresh.log_place, table.log_place)
    old = {k: v for k, v in MotionTable().fit(tracks).state_dict().items() if "place" not in k}
    legacy = MotionTable()
    legacy.load_state_dict(old)
    assert not legacy.has_place and torch.equal(legacy.log_place_ratio(fast, at), torch.zeros(3))
    assert not table.drop_place().has_place
    with pytest.raises(ValueError, match="shape"):
        MotionTable().fit_place(np.zeros((3, 1, 2)), (0, 0), 1.0, (4, 4))
    with pytest.raises(ValueError, match="NaN"):
        MotionTable().fit_place(np.full((3, 4, 2), np.nan), (0, 0), 1.0, (4, 4))


def test_place_table_from_street_lines_is_the_lane_of_drivers_spread_along_them():
    # 20 m of centre line along y = 2 over 100 cells users can be in: on average 0.2 m of line per
    # cell, a full cell on the line holds 1 m, the end cells half that
    line = np.array([[[0.0, 2.0], [20.0, 2.0]]])
    table = MotionTable().fit_place_lines(
        line, (-0.5, -0.5), 1.0, (30, 8), visited=100, speed=1.0, floor=0.25, smooth=0.0
    )
    assert table.has_place and float(table.place_speed) == 1.0
    at = torch.tensor([[10.0, 2.0], [0.2, 2.0], [10.0, 5.0], [10.0, 2.6]])
    r = table.log_place_ratio(torch.tensor([3.0, 0.0]), at).double()
    expect = [math.log((m + 0.25 * 0.2) / (1.25 * 0.2)) for m in (1.0, 0.5, 0.0, 0.0)]
    assert torch.allclose(r, torch.tensor(expect, dtype=torch.float64), atol=2e-3)
    assert torch.equal(table.log_place_ratio(torch.tensor([0.5, 0.0]), at), torch.zeros(4))
    # a diagonal line counts its length per cell, smoothed as the measured tables are
    diag = MotionTable().fit_place_lines(
        np.array([[[0.0, 0.0], [10.0, 10.0]]]), (-0.5, -0.5), 1.0, (12, 12), 144
    )
    on, off = diag.log_place_ratio(torch.tensor([6.0, 0.0]), torch.tensor([[5.0, 5.0], [5.0, 0.0]]))
    assert float(on) > 1.0 and float(off) == pytest.approx(math.log(3 / 4), abs=2e-3)
    for bad, match in ((np.zeros((1, 3, 2)), "shape"), (np.full((1, 2, 2), np.nan), "NaN")):
        with pytest.raises(ValueError, match=match):
            MotionTable().fit_place_lines(bad, (0, 0), 1.0, (4, 4), 16)
    with pytest.raises(ValueError, match="visited"):
        MotionTable().fit_place_lines(line, (0, 0), 1.0, (4, 4), 0)


def test_an_attached_street_map_gives_lanes_where_no_training_user_drove():
    tr = toy_sequence_set(128, 5, seed=1)
    cfg = TrainConfig(model="tn-match", options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, tr.n_beams, tr.n_bins, tr.normaliser())
    est.net.fit_motion(tr.positions, tr.grid_xy, tr.index)
    net = est.net
    assert est.attach(tr)._lane_motion() == (net.motion, net.motion_fine)  # no map: measured lanes
    street = np.array([[[0.0, 20.0], [31.0, 20.0]]])
    est.attach(dataclasses.replace(tr, streets=street))
    cells, fine = est._lane_motion()
    assert est._lane_motion()[0] is cells  # made once per map and set of tables
    street[0, 0, 1] = 0.0  # the caller's array changed in place: the estimator kept its own copy
    assert est._lane_motion()[0] is cells
    street[0, 0, 1] = 20.0
    net.motion.log_accel_table[0, 0, 0] += 1.0  # a table changed in place: its lanes made again
    assert est._lane_motion()[0] is not cells
    net.motion.log_accel_table[0, 0, 0] -= 1.0
    cells, fine = est._lane_motion()
    fast = torch.tensor([6.0, 0.0])
    on, off = cells.log_place_ratio(fast, torch.tensor([[12.0, 20.0], [12.0, 5.0]]))
    assert float(on) > 1.0 and float(off) == pytest.approx(math.log(3 / 4), abs=2e-3)
    on, off = fine.log_place_ratio(fast, torch.tensor([[12.0, 20.0], [12.0, 5.0]]))  # grid units (1 m)
    assert float(on) > 1.0 and float(off) == pytest.approx(math.log(3 / 4), abs=2e-3)
    # only the place tables are the map's; the motion is the measured one
    assert torch.equal(cells.log_accel_table, net.motion.log_accel_table)
    assert torch.equal(fine.log_step_table, net.motion_fine.log_step_table)
    assert not torch.equal(cells.log_place, net.motion.log_place)
    # the filter reads them
    used = est.candidate_filter(robust=False)._models[0]
    assert np.array_equal(used.cells.m.place[1], cells.log_place.float().numpy())
    assert np.array_equal(used.fine.m.place[1], fine.log_place.float().numpy())
    # the forecast follows the map's streets, made into a graph once per map
    graph = est._street_network()
    assert graph is est._street_network() and np.array_equal(graph.lines(), street)
    driver = torch.tensor([[[18.0, 20.0], [24.0, 20.0]]])  # 6 m per step, 7 m before the dead end
    assert torch.allclose(est.forecast(driver, 2), torch.tensor([[[30.0, 20.0], [26.0, 20.0]]]))
    est.street_forecast = False  # carried along the lanes instead: no turn at the dead end
    assert est.forecast(driver, 2)[0, 1, 0] > 35.0
    est.street_forecast = True
    est.street_lanes = False
    assert est._lane_motion() == (net.motion, net.motion_fine) and est._street_network() is None
    est.street_lanes = True
    net.motion.drop_place()  # a model trained without place tables keeps none
    assert est._lane_motion() == (net.motion, net.motion_fine)


def test_velocity_posterior_follows_the_straight_line_a_random_walk_cannot_tell():
    """At the last step two equally likely aliases lie equally far from the previous point, one
    straight ahead and one to the side: only the constant-velocity model prefers the first."""
    xy = torch.tensor(
        [[[[0.0, 0.0], [0.0, 0.0]], [[5.0, 0.0], [5.0, 0.0]], [[10.0, 0.0], [5.0, 5.0]]]]
    )  # (1, 3 steps, 2 candidates, 2)
    logp = torch.zeros(1, 3, 2)
    walk = motion_posterior(xy, logp, 3.0).exp()[0, 2]
    assert torch.allclose(walk[0], walk[1], atol=1e-6)
    line = velocity_posterior(xy, logp).exp()[0, 2]
    assert line[0] > 0.99


def test_candidate_features_keep_the_smoothed_best():
    g = torch.Generator().manual_seed(0)
    xy = torch.rand(3, 4, 20, 2, generator=g) * 100
    score = torch.randn(3, 4, 20, generator=g)
    kxy, post = candidate_features(xy, score, 5, block=2)
    assert kxy.shape == (3, 4, 5, 2) and post.shape == (3, 4, 5, 2 + len(STEP_SIGMAS))
    full = torch.stack([motion_posterior(xy, torch.log_softmax(score, -1), s) for s in STEP_SIGMAS], -1)
    best = full.amax(-1).max(-1).values  # the kept first candidate is the best smoothed one
    assert torch.allclose(post[:, :, 0, 1:-1].amax(-1), best.clamp(min=-30), atol=1e-6)
    assert bool((post >= -30).all())
    # the last feature is the constant-velocity posterior over the kept candidates
    cv = velocity_posterior(kxy, post[..., 0]).clamp(min=-30)
    assert torch.allclose(post[..., -1], cv, atol=1e-5)


def test_untrained_network_is_the_velocity_smoother_and_translation_invariant():
    torch.manual_seed(0)
    net = CandidateTransformer(search=20, k=6, d=16, ff=32, dropout=0.0).eval()
    g = torch.Generator().manual_seed(1)
    xy, post = candidate_features(
        torch.rand(2, 5, 20, 2, generator=g) * 50, torch.randn(2, 5, 20, generator=g), 6
    )
    out = net(xy, post)
    w = torch.softmax(post[..., -1], -1)  # weight of the constant-velocity posterior
    assert torch.allclose(out, (w[..., None] * xy).sum(2), atol=1e-4)
    shift = torch.tensor([123.0, -45.0])
    assert torch.allclose(net(xy + shift, post), out + shift, atol=1e-3)


def test_the_network_reads_its_first_k_of_the_candidates_a_filter_carries():
    """The filter carries more candidates per step than the network's ``k`` (FILTER_CANDIDATES);
    the network reads the first ``k``, whatever follows them."""
    torch.manual_seed(0)
    net = CandidateTransformer(search=20, k=6, d=16, ff=32, dropout=0.0).eval()
    g = torch.Generator().manual_seed(1)
    xy, post = candidate_features(
        torch.rand(2, 5, 20, 2, generator=g) * 50, torch.randn(2, 5, 20, generator=g), 10
    )
    fine = (torch.softmax(post[..., -1], -1)[..., None] * xy).sum(2)
    out = net(xy[:, :, :6], post[:, :, :6], fine)
    assert torch.equal(net(xy, post, fine), out)
    assert torch.equal(net(xy, torch.cat([post[:, :, :6], post[:, :, 6:] * 0 + 5.0], 2), fine), out)


def test_the_network_moves_no_step_further_than_its_reach():
    # a network that takes each step's candidate of the highest constant-velocity posterior: at
    # the first step that is an alias 60 m away, and there the classical estimate stands
    torch.manual_seed(0)
    net = CandidateTransformer(search=6, k=6, d=16, ff=32, dropout=0.0).eval()
    with torch.no_grad():
        net.gate.weight.zero_()
        net.gate.bias.fill_(1.0)
        net.offset.weight.zero_()
        net.offset.bias.zero_()
        net.prior.mul_(50.0)
    T, K = 4, 6
    xy = torch.zeros(1, T, K, 2)
    xy[..., 0] = torch.arange(T, dtype=torch.float32)[:, None] * 1.4
    xy[..., 1] = torch.arange(K, dtype=torch.float32) * 0.5  # candidates 0.5 m apart across the walk
    post = torch.zeros(1, T, K, 2 + len(STEP_SIGMAS))
    post[..., -1] = -5.0
    post[0, :, 2, -1] = 0.0  # the network's pick: 1 m off the classical estimate at every step
    xy[0, 0, 2] = torch.tensor([60.0, 1.0])  # but at step 0 that candidate lies 60 m away
    fine = xy[:, :, 0].clone()
    out = net.track(xy, post, fine)
    assert torch.equal(out[0, 0], fine[0, 0])  # the alias is out of reach: the estimate stands
    moved = (out - fine).norm(dim=-1)[0, 1:]
    assert (moved > 0.9).all() and (moved <= NET_REACH * float(net.grid_step)).all()


def test_training_drops_no_attention_weights():
    """Dropout stays on the residual and feed-forward paths, not on the attention weights (whose
    dropout keeps training's attention from running fused)."""
    torch.manual_seed(0)
    net = CandidateTransformer(search=20, k=6, d=16, ff=32, dropout=0.5).train()
    h = torch.randn(3, 30, 16)
    for layer in net.encoder.layers:
        attn = layer.self_attn
        trained = attn(h, h, h, need_weights=False)[0]
        assert torch.allclose(trained, attn.eval()(h, h, h, need_weights=False)[0], atol=1e-6)
        attn.train()
    # the feed-forward path still drops: two training passes differ
    assert not torch.equal(net.encoder(h), net.encoder(h))


def test_match_cv_is_the_untrained_network_and_beats_the_per_step_match():
    va = toy_sequence_set(64, 6, seed=2)
    bits = noisy_bits(va, 12.0, torch.Generator().manual_seed(3))  # noisy enough for aliases
    smoother = MatchSmoother(va, 12.0, search=32, k=8)
    pred = smoother.predict(bits)
    assert pred.shape == (64, 6, 2) and np.isfinite(pred).all()
    per_step = smoother.matcher.match(bits)
    assert trajectory_rmse(pred, va.positions).mean() < 0.6 * trajectory_rmse(per_step, va.positions).mean()
    torch.manual_seed(0)
    cfg = TrainConfig(model="tn-match", sigma=12.0, options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, va.n_beams, va.n_bins, va.normaliser()).attach(va)
    assert np.allclose(est.predict(bits).numpy(), pred, atol=1e-3)


def test_evaluation_attaches_the_likelihood_at_the_noise_it_evaluates():
    """A tn-match trained at 6 dB and evaluated at 12 dB scores candidates with the 12 dB
    likelihood: untrained, it is then match-cv at 12 dB, not at 6 dB."""
    va = toy_sequence_set(32, 5, seed=2)
    bits = noisy_bits(va, 12.0, torch.Generator().manual_seed(3))
    torch.manual_seed(0)
    cfg = TrainConfig(model="tn-match", sigma=6.0, options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, va.n_beams, va.n_bins, va.normaliser()).attach(va)
    assert est.matcher.sigma == 6.0
    at12 = MatchSmoother(va, 12.0, search=32, k=8).predict(bits)
    assert not np.allclose(est.predict(bits).numpy(), at12, atol=1e-3)
    method = NetworkMethod(est, "tn-match").for_sigma(12.0, va)
    assert method.est.matcher.sigma == 12.0
    assert np.allclose(method.predict_lengths(bits, [5])[5][0], at12, atol=1e-3)


def test_methods_on_one_grid_at_one_noise_share_one_matcher_and_its_tables():
    import gc

    from estimation import KnnKalman

    va = toy_sequence_set(32, 5, seed=2)
    cfg = TrainConfig(model="tn-match", sigma=6.0, options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, va.n_beams, va.n_bins, va.normaliser()).attach(va)
    cv, knn = MatchSmoother(va, 6.0, search=32, k=8), KnnKalman(va, 6.0)
    assert cv.matcher is est.matcher is knn.matcher
    assert est.matcher._tiles is not None  # built once, by the first
    # another noise, or other arrays (a copy of the same grid), get their own
    assert MatchSmoother(va, 9.0).matcher is not cv.matcher
    copied = dataclasses.replace(va, grid_pdp=va.grid_pdp.clone())
    assert MatchSmoother(copied, 6.0).matcher is not cv.matcher
    # kept only while in use
    first = id(cv.matcher)
    del est, cv, knn
    gc.collect()
    from estimation.matching import _IN_USE

    assert all(id(m) != first for m in _IN_USE.values())


def test_tn_match_needs_the_grid():
    d = toy_sequence_set(8, 4, nx=16, ny=16, n_beams=4, n_bins=8)
    est = Estimator(TrainConfig(model="tn-match", options={"search": 16, "k": 4}), 4, 8, d.normaliser())
    with pytest.raises(EstimationError, match="attach"):
        est.predict(torch.zeros(1, 3, 4, 8))
    assert est.attach(d).predict(torch.zeros(1, 3, 4, 8)).shape == (1, 3, 2)


@pytest.mark.parametrize("model", ["tn-match", "lstm"])
def test_fingerprints_that_are_not_bits_are_refused_by_name(model):
    """Bits from outside reach the matcher and the networks: a NaN, an infinite or a soft value
    (which the matcher would read as a one) and a wrong shape are each one clear error."""
    d = toy_sequence_set(8, 4, nx=16, ny=16, n_beams=4, n_bins=8)
    est = Estimator(
        TrainConfig(model=model, options={"search": 16, "k": 4} if model == "tn-match" else {}),
        4,
        8,
        d.normaliser(),
    ).attach(d)
    good = torch.zeros(2, 3, 4, 8)
    good[:, :, 1, 2] = 1.0
    expect = est.predict(good)
    for same in (good.bool(), good.numpy().astype(np.uint8)):  # any dtype, tensor or array
        assert torch.equal(est.predict(same), expect)
    for value, shown in ((float("nan"), "nan"), (float("inf"), "inf"), (0.5, "0.5"), (-1.0, "-1.0")):
        bad = good.clone()
        bad[1, 2, 3, 4] = value
        with pytest.raises(EstimationError, match=f"0 or 1, got {shown} \\(at 1 of 192 entries\\)"):
            est.predict(bad)
        with pytest.raises(EstimationError, match="0 or 1"):
            est.tracker().update(bad[:, 2])
    with pytest.raises(EstimationError, match=r"\(B, T, 4, 8\) bits, got shape \(2, 3, 8, 4\)"):
        est.predict(good.transpose(-1, -2))
    if est.uses_grid:  # the classical trackers read the same matcher
        with pytest.raises(EstimationError, match="0 or 1"):
            MatchSmoother(d, 6.0, search=16, k=4).predict(torch.full((1, 3, 4, 8), float("nan")))


def test_constant_velocity_forecast_is_exact():
    g = torch.Generator().manual_seed(0)
    start, v = torch.rand(5, 1, 2, generator=g) * 100, torch.randn(5, 1, 2, generator=g) * 4
    track = start + v * torch.arange(7.0)[None, :, None]
    assert torch.allclose(extrapolate(track[:, :4], 3), track[:, 4:], atol=1e-4)
    # only the last velocity counts: a turn before it is forgotten
    turned = torch.cat([track[:, :1] + v.flip(-1), track[:, 1:4]], 1)
    assert torch.allclose(extrapolate(turned, 3), track[:, 4:], atol=1e-4)
    # one observed step: no velocity to carry on
    assert torch.equal(extrapolate(track[:, :1], 2), track[:, :1].expand(-1, 2, -1))
    with pytest.raises(ValueError, match="shape"):
        extrapolate(torch.zeros(3, 2), 1)


def test_tn_match_forecasts_through_its_tracks(tmp_path):
    """Trained for forecasting, tn-match tracks the observed steps and carries them on; on the
    toy grid's straight tracks that beats standing still at the last estimate."""
    torch.manual_seed(0)
    tr = toy_sequence_set(256, 6, seed=1)
    va = toy_sequence_set(64, 6, seed=2)
    cfg = TrainConfig(
        model="tn-match",
        task="forecasting",
        t_obs=4,
        horizon=2,
        epochs=1,
        epoch_size=128,
        sigma=6.0,
        options={"search": 32, "k": 8, "d": 16, "ff": 32},
    )
    train(tr, va, cfg, tmp_path / "run", progress=False, record=False, log=lambda s: None)
    method = NetworkMethod.from_run(tmp_path / "run").for_sigma(6.0, va)
    assert (method.task, method.t_obs, method.horizon) == ("forecasting", 4, 2)
    bits = noisy_bits(va, 6.0, torch.Generator().manual_seed(3))
    pred = method.predict_lengths(bits, [4])[4][0]
    assert pred.shape == (64, 2, 2) and np.isfinite(pred).all()
    est = method.est
    xy, post, fine = est.inputs(bits[:, :4])
    with torch.no_grad():
        tracked = est.net.eval().track(xy, post, fine)
    # users faster than the place table's speed go on along the filter's lanes, the others at their
    # last velocity, as in training
    lanes = est._lane_motion()[1]
    assert np.allclose(pred, forecast_tracks(tracked, 2, lanes, float(est.net.grid_step)).numpy(), atol=1e-4)
    est.lane_forecast = False
    assert np.allclose(est.predict(bits[:, :4]).numpy(), extrapolate(tracked, 2).numpy(), atol=1e-4)
    true = va.positions[:, 4:6]
    stand = tracked[:, -1:].expand(-1, 2, -1).numpy()
    assert trajectory_rmse(pred, true).mean() < trajectory_rmse(stand, true).mean()


def test_tn_match_trains_and_beats_the_per_step_match(tmp_path):
    """On a toy grid, the trained network's tracks are better than the likelihood's best point."""
    torch.manual_seed(0)
    tr = toy_sequence_set(256, 6, seed=1)
    va = toy_sequence_set(64, 6, seed=2)
    cfg = TrainConfig(
        model="tn-match",
        epochs=2,
        epoch_size=128,
        sigma=6.0,
        options={"search": 32, "k": 8, "d": 16, "ff": 32},
    )
    summary = train(tr, va, cfg, tmp_path / "run", progress=False, record=False, log=lambda s: None)
    assert summary["epochs"] == 2 and math.isfinite(summary["best_val_rmse"])
    est = Estimator.load(tmp_path / "run").attach(va)
    bits = noisy_bits(va, 6.0, torch.Generator().manual_seed(3))
    pred = est.predict(bits).numpy()
    per_step = est.matcher.match(bits)
    assert trajectory_rmse(pred, va.positions).mean() < trajectory_rmse(per_step, va.positions).mean()
    assert np.isfinite(pred).all()
    # training measured the smoother's motion statistics and place tables (32 x 32 grid of 1 m)
    # and saved them with the weights
    lo = tr.grid_xy.min(0)
    expect = MotionTable().fit(tr.grid_xy[tr.index]).fit_place(tr.grid_xy[tr.index], lo - 0.5, 1.0, (32, 32))
    assert bool(est.net.motion.fitted) and est.net.motion.has_place
    assert torch.equal(est.net.motion.log_accel_table, expect.log_accel_table)
    assert torch.equal(est.net.motion.log_place, expect.log_place)
    # (the measured motion alone: the robust filter also weighs in its broadened copy, test_online,
    # the tables of steady users at other speeds and the walkers' at other speeds, test_speed_scaled)
    found = est.search(bits[:4])
    assert est.candidate_filter().run(*found).model_weights().shape == (4, 4)
    # the walkers' tables: the training pedestrians at other speeds, no place table; the last
    # hypothesis, at its own prior beside the others' shared one, its paths not weighed by the
    # acceleration memory (measured at the training speeds)
    walkers = tr.positions[tr.kind == KINDS.index("pedestrian")]
    u = speed_scaled(walkers - lo, copies=WALK_COPIES, ranges=WALK_SCALES)
    assert torch.equal(
        est.net.motion_walk.log_accel_table, MotionTable().fit(lo + np.rint(u)).log_accel_table
    )
    walk_fine = MotionTable.lattice().fit(snap_to_lattice(u))
    assert torch.equal(est.net.motion_walk_fine.log_accel_table, walk_fine.log_accel_table)
    assert not est.net.motion_walk.has_place and not est.net.motion_walk_fine.has_place
    f = est.candidate_filter()
    assert f._models[-1].cells.m is motion_arrays(est.net.motion_walk) and not f._models[-1].remembers
    np.testing.assert_allclose(
        np.exp(f._log_prior), [0.5 - WALKER_SPEED_PRIOR, 0.25, 0.25, WALKER_SPEED_PRIOR]
    )
    # fewer walkers than KIND_TABLE_MIN measure none; nor does a model saved before they existed
    for other in ("vehicle", "hybrid"):  # cyclists are no walkers here (WALKER_KINDS)
        est.net.fit_walker_speeds(tr.positions, tr.grid_xy, np.full(len(tr.kind), KINDS.index(other)))
        assert not bool(est.net.motion_walk.fitted)
    assert est.candidate_filter().run(*found).model_weights().shape == (4, 3)
    np.testing.assert_allclose(np.exp(est.candidate_filter()._log_prior), [0.5, 0.25, 0.25])
    est.net.fit_walker_speeds(tr.positions, tr.grid_xy, tr.kind)
    assert torch.equal(est.net.motion_walk_fine.log_accel_table, walk_fine.log_accel_table)
    with pytest.raises(ValueError, match="codes"):
        est.net.fit_walker_speeds(tr.positions, tr.grid_xy, tr.kind[:-1])
    saved = torch.load(tmp_path / "run" / "model.pt", weights_only=True)
    saved["state_dict"] = {k: v for k, v in saved["state_dict"].items() if not k.startswith("motion_walk")}
    torch.save(saved, tmp_path / "before.pt")
    before = Estimator.load(tmp_path / "before.pt").attach(va)
    assert not bool(before.net.motion_walk.fitted)
    assert before.candidate_filter().run(*found).model_weights().shape == (4, 3)
    # the broadened copies are made once per set of tables, not once per filter
    broad = est._broadened_motion()
    assert est._broadened_motion() is broad
    # read against the attached grid's free space: the cell table in metres, the lattice's in
    # grid units
    free, origin, res = est._free_space()
    step = float(est.net.grid_step)
    for table, unit in zip(broad, (1.0, step), strict=True):
        assert table.wall_classes == len(table.log_accel_table) // 2 > 0
        np.testing.assert_array_equal(table.walls[0], free)
        np.testing.assert_allclose(table.walls[1], origin / unit)
        assert table.walls[2] == pytest.approx(res / unit)
    est.net.motion_fine.log_step_table[0] += 1.0
    assert est._broadened_motion() is not broad
    est.net.motion_fine.log_step_table[0] -= 1.0
    est.robust_motion = False
    assert est.candidate_filter().run(*found).model_weights().shape == (4, 1)
    plain = est.candidate_filter()
    assert plain.memory is est.net.memory
    plain.memory = None  # the first-order smoother alone
    xy, post, fine = plain.run(*found).smooth()
    # it carries the search's 32 candidates per step (FILTER_CANDIDATES, at most the search's),
    # more than the 8 the network reads; where its beam of pairs kept a candidate, the
    # first-order posterior is the dense smoother's (the pruned ones sit at the floor)
    assert xy.shape[2] == min(FILTER_CANDIDATES, 32) > est.net.k
    dense = velocity_posterior(xy, post[..., 0], expect).clamp(min=-30)
    kept = dense > -20
    assert kept.any(-1).all() and torch.allclose(post[..., -1][kept], dense[kept], atol=1e-5)
    # training reads a filter of the network's own k (prediction's estimate, from more, is
    # better), its split cells one mode
    trained_on = training_inputs(est, bits[:4])
    assert trained_on[0].shape[2] == est.net.k
    one_mode = est.candidate_filter(candidates=est.net.k, mode_chain=math.inf).run(*est.search(bits[:4]))
    assert torch.equal(trained_on[2], one_mode.smooth()[2])
    assert (
        est.candidate_filter().mode_chain == MODE_CHAIN
        and est.candidate_filter(mode_chain=2.0).mode_chain == 2.0
    )
    # and the sub-cell table, on the training positions snapped to the lattice (toy grid: 1 m)
    u = snap_to_lattice(tr.positions - lo)
    lattice = MotionTable.lattice().fit(u).fit_place(u + lo, lo - 0.5, 1 / 3, (96, 96))
    assert float(est.net.grid_step) == 1.0 and torch.equal(est.net.motion_fine.log_place, lattice.log_place)
    assert torch.equal(est.net.motion_fine.log_accel_table, lattice.log_accel_table)
    # the online filter splits the cells it finds likely so far and prunes pairs, so it is the
    # dense sub-cell smoother up to a few centimetres (exactly when nothing is pruned: test_online)
    assert (fine - subcell_mean(xy, post[..., 0], post[..., -1], lattice)).norm(dim=-1).max() < 0.05
    # training measured the acceleration memory on the same lattice positions; the filter weighs
    # its paths by it, which moves the sub-cell tracks by a little
    measured = MotionMemory().fit(u)
    assert torch.equal(est.net.memory.log_ratio, measured.log_ratio)
    assert torch.equal(est.net.memory.log_ratio_two, measured.log_ratio_two)
    moved = (est.candidate_filter().run(*found).smooth()[2] - fine).norm(dim=-1)
    assert 0 < moved.max() < 0.5
    # tables measured on fast users too (bands of 6 per step and up with samples) give the
    # robust filter a third hypothesis, the speed-pooled tables, made once per set of tables
    est.robust_motion = True
    rng = np.random.default_rng(4)
    speed = rng.choice([6.5, 8.0, 9.5], (300, 1, 1))
    fast = (
        lo
        + 2.0
        + np.concatenate(
            [np.zeros((300, 1, 2)), np.cumsum(np.broadcast_to(speed * [1.0, 0.0], (300, 3, 2)), 1)], 1
        )
    )
    est.net.fit_motion(np.concatenate([fast, tr.positions[:, :4]]), tr.grid_xy)
    # the sub-cell table measured again on speed-scaled copies of the trajectories, with the
    # measured place table; told from the measured one by the sub-cell evidence
    both = np.concatenate([fast, tr.positions[:, :4]]) - lo
    scaled = MotionTable.lattice().fit(snap_to_lattice(speed_scaled(both)))
    assert torch.equal(est.net.motion_scaled.log_accel_table, scaled.log_accel_table)
    assert torch.equal(est.net.motion_scaled.log_place, est.net.motion_fine.log_place)
    steady = est._steady_motion()
    assert steady is not None and est._steady_motion() is steady and steady[1].has_place
    assert torch.equal(steady[0].log_accel_table, est.net.motion.speed_pooled(6.0).log_accel_table)
    f = est.candidate_filter()
    assert f._fine_group == [0, 2] and f.run(*found).model_weights().shape == (4, 3)
    # the memory weighs the paths of every model but the steady users' at other speeds
    assert [h.remembers for h in f._models] == [True, True, False]
    # a model saved before the scaled table existed loads without it and weighs the pooled tables
    # by their cell-level evidence, as it did
    saved = torch.load(tmp_path / "run" / "model.pt", weights_only=True)
    saved["state_dict"] = {
        k: v for k, v in est.net.state_dict().items() if not k.startswith(("motion_scaled.", "memory."))
    }
    torch.save(saved, tmp_path / "old.pt")
    old = Estimator.load(tmp_path / "old.pt").attach(va)
    assert not bool(old.net.motion_scaled.fitted) and not old._scaled_fine()
    assert not bool(old.net.memory.fitted) and old.candidate_filter().memory is None
    f = old.candidate_filter()
    assert f._fine_group == [] and f.run(*found).model_weights().shape == (4, 3)
    pooled = old._steady_motion()
    expect = est.net.motion_fine.speed_pooled(6.0)
    assert torch.equal(pooled[1].log_accel_table, expect.log_accel_table)
    # Told the trajectories' kinds, training also measures both tables on the cyclists alone
    # (no place table), a fourth hypothesis; with fewer than KIND_TABLE_MIN of them, none.
    kind = tr.kind.copy()
    assert not (kind == KINDS.index(KIND_TABLE)).any() and not bool(est.net.motion_kind.fitted)
    kind[:KIND_TABLE_MIN] = KINDS.index(KIND_TABLE)
    est.net.fit_motion(tr.positions, tr.grid_xy, tr.index, kind=kind)
    mine = slice(0, KIND_TABLE_MIN)
    cell = MotionTable().fit(tr.grid_xy[tr.index][mine])
    assert torch.equal(est.net.motion_kind.log_accel_table, cell.log_accel_table)
    assert not est.net.motion_kind.has_place and not est.net.motion_kind_fine.has_place
    fine_kind = MotionTable.lattice().fit(snap_to_lattice(tr.positions[mine] - lo))
    assert torch.equal(est.net.motion_kind_fine.log_accel_table, fine_kind.log_accel_table)
    est._steady = est._broadened = None
    f = est.candidate_filter()
    assert f._fine_group == [0, 2] and f.run(*found).model_weights().shape == (4, 5)
    assert f._models[3].cells.m is motion_arrays(est.net.motion_kind)
    # saved and loaded with the weights; a model saved before they existed has them unfitted
    est.save(tmp_path / "kind.pt")
    loaded = Estimator.load(tmp_path / "kind.pt").attach(va)
    assert torch.equal(loaded.net.motion_kind_fine.log_accel_table, fine_kind.log_accel_table)
    assert loaded.candidate_filter().run(*found).model_weights().shape == (4, 5)
    kind[0] = KINDS.index("pedestrian")
    est.net.fit_motion(tr.positions, tr.grid_xy, tr.index, kind=kind)
    assert not bool(est.net.motion_kind.fitted) and not bool(est.net.motion_kind_fine.fitted)
    with pytest.raises(ValueError, match="codes"):
        est.net.fit_motion(tr.positions, tr.grid_xy, tr.index, kind=kind[:-1])


def test_snap_to_lattice_keeps_grid_points_for_odd_and_centres_cells_for_even():
    u = np.array([[0.1, -0.2], [0.34, 0.9], [2.49, 4.9]])
    assert np.allclose(snap_to_lattice(u, 3), [[0.0, -1 / 3], [1 / 3, 1.0], [2 + 1 / 3, 5.0]])
    assert np.allclose(snap_to_lattice(u, 2), [[0.25, -0.25], [0.25, 0.75], [2.25, 4.75]])
    assert np.allclose(snap_to_lattice(u, 1), np.round(u))


def test_subcell_mean_against_enumeration_of_all_sub_cell_paths():
    """Each kept cell becomes n_sub^2 points sharing its likelihood; the mean is the exact
    posterior mean over all paths of those points."""
    g = torch.Generator().manual_seed(5)
    xy = torch.rand(3, 4, 2, generator=g) * 4  # 3 steps, 4 candidates
    like = torch.rand(3, 4, generator=g) + 0.1
    rank = torch.tensor([[3.0, 2.0, 1.0, 0.0]]).expand(3, 4)  # keeps the first two per step
    motion = MixtureMotion(first_step_sigma=2.0)
    got = subcell_mean(xy[None], like.log()[None], rank[None], motion, spacing=2.0, n_sub=2, k=2)[0]
    off = torch.tensor([[-0.5, -0.5], [-0.5, 0.5], [0.5, -0.5], [0.5, 0.5]])  # quarter cells of 2 m
    pts = (xy[:, :2, None] + off).reshape(3, 8, 2)
    pts_like = like[:, :2, None].expand(-1, -1, 4).reshape(3, 8)
    # the motion model sees grid units: enumerate in them, then back to metres
    marg = _path_posterior_by_enumeration(pts / 2.0, pts_like, motion)
    assert torch.allclose(got.double(), (marg[..., None] * pts.double()).sum(1), atol=1e-4)


def test_subcell_smoother_finds_positions_inside_the_cells():
    """Users on straight lines, seen only as their grid cells: the lattice table puts them closer
    to the truth than the cells' centres, the quantisation floor of any cell-level estimate."""
    true = _straight_tracks(n=200, length=7, seed=3)
    lattice = MotionTable.lattice().fit(snap_to_lattice(_straight_tracks(n=4000, length=7, seed=4)))
    cells = torch.from_numpy(np.round(true)).float()[:, :, None]  # one candidate: the true cell
    fine = subcell_mean(cells, torch.zeros(cells.shape[:3]), torch.zeros(cells.shape[:3]), lattice)
    cell_err = trajectory_rmse(cells[:, :, 0].numpy(), true).mean()
    fine_err = trajectory_rmse(fine.numpy(), true).mean()
    assert cell_err > 0.35 and fine_err < 0.8 * cell_err


def test_evaluation_of_a_prefix_does_not_see_later_steps():
    """The per-length evaluation searches once over the longest crop, but smooths each prefix alone."""
    from estimation import NetworkMethod

    torch.manual_seed(0)
    d = toy_sequence_set(6, 6, nx=16, ny=16, n_beams=4, n_bins=8)
    est = Estimator(TrainConfig(model="tn-match", options={"search": 16, "k": 4}), 4, 8, d.normaliser())
    est.attach(d)
    bits = noisy_bits(d, 6.0, torch.Generator().manual_seed(0))
    out = NetworkMethod(est, "tn-match").for_sigma(6.0, d).predict_lengths(bits, [3, 6])
    for L in (3, 6):
        assert np.allclose(out[L][0], est.predict(bits[:, :L]).numpy(), atol=1e-5)


def test_evaluation_holds_one_parts_filter_per_thread(monkeypatch):
    """Every prefix of a part is smoothed before its thread makes the next part's filter, and the
    filter is then let go: what evaluation holds is one part's stored messages per thread,
    whatever the number of test trajectories. The predictions are those of the whole set at once."""
    import gc
    import weakref

    import estimation.evaluation as evaluation
    from estimation import NetworkMethod
    from estimation.smoothing.online import CandidateFilter
    from mmwsim._threads import set_threads

    torch.manual_seed(0)
    d = toy_sequence_set(9, 5, nx=16, ny=16, n_beams=4, n_bins=8)
    est = Estimator(TrainConfig(model="tn-match", options={"search": 16, "k": 4}), 4, 8, d.normaliser())
    est.attach(d)
    bits = noisy_bits(d, 6.0, torch.Generator().manual_seed(0))
    made, made_refs, run = [], [], CandidateFilter.run

    def tracked_run(self, *args):
        gc.collect()
        made.append(sum(r() is not None for r in made_refs))  # filters alive when this one runs
        made_refs.append(weakref.ref(self))
        return run(self, *args)

    monkeypatch.setattr(evaluation, "_PART", 4)
    for threads in (1, 2):
        made.clear()
        made_refs.clear()
        monkeypatch.setattr(CandidateFilter, "run", tracked_run)
        set_threads(threads)
        try:
            out = NetworkMethod(est, "tn-match").for_sigma(6.0, d).predict_lengths(bits, [2, 5])
        finally:
            set_threads(None)
        # three parts; on one thread none alive when the next is made, on two the other thread's
        assert len(made) == 3 and max(made) <= threads - 1
        monkeypatch.setattr(CandidateFilter, "run", run)
        for L in (2, 5):
            assert np.allclose(out[L][0], est.predict(bits[:, :L]).numpy(), atol=1e-5)
            assert out[L][1] > 0
