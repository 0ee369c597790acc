"""The acceleration memory: its measured ratios, the paths drawn from a beam, and the filter's use."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from estimation.smoothing.beam import sample_paths
from estimation.smoothing.memory import MotionMemory
from estimation.smoothing.motion import MotionTable, snap_to_lattice
from estimation.smoothing.online import CandidateFilter
from estimation.synthetic import toy_sequence_set
from mmwsim._threads import set_threads

from .test_online import MOTION, _candidates


def _steady(n=300, length=12, speed=1.8, seed=0):
    """Walkers at one exact speed along x, each from its own phase, snapped to the lattice
    (grid units): 5.4 lattice steps per step, so 5 and 6 steps in a fixed pattern."""
    start = np.random.default_rng(seed).uniform(0, 1, (n, 1, 2))
    t = np.arange(length)[None, :, None]
    return snap_to_lattice(start + t * np.array([speed, 0.0]))


def _code(ax, ay, reach=2):
    return (ax + reach) * (2 * reach + 1) + ay + reach


def test_a_steady_users_pattern_makes_a_second_speed_up_unlikely():
    mem = MotionMemory().fit(_steady())
    assert bool(mem.fitted)
    band = int(np.searchsorted(mem.edges.numpy(), 5.4))
    ratio = mem.log_ratio[band]
    # +1 (5 to 6 steps) is followed by -1 (back to 5) more often than +1 is on its own, and by
    # another +1 (to 7) never
    assert ratio[_code(1, 0), _code(-1, 0)] > 0.5
    assert ratio[_code(1, 0), _code(1, 0)] < -2.0
    # a path that keeps the pattern weighs more than one that speeds up by the same steps
    keep = np.cumsum([[0, 0], [5, 0], [6, 0], [5, 0], [5, 0], [6, 0]], 0)[None] / 3.0
    speed_up = np.cumsum([[0, 0], [5, 0], [6, 0], [7, 0], [8, 0], [9, 0]], 0)[None] / 3.0
    assert mem.log_weight(keep)[0] > mem.log_weight(speed_up)[0] + 3.0
    # fewer than four points hold no pair of accelerations
    assert mem.log_weight(keep[:, :3]).shape == (1,) and mem.log_weight(keep[:, :3])[0] == 0.0


def test_two_accelerations_back_tell_a_pattern_one_back_cannot():
    # at 1.75 m/s (5.25 lattice steps per step) a walker goes 5, 5, 5, 6, ...: accelerations 0,
    # 0, +1, -1. After 0 comes 0 or +1; after -1, 0 only 0, and after 0, 0 only +1.
    mem = MotionMemory().fit(_steady(speed=1.75))
    band = int(np.searchsorted(mem.edges.numpy(), 5.25))
    one, two = mem.log_ratio[band], mem.log_ratio_two[band]
    assert one[_code(0, 0), _code(0, 0)] > -0.5 and one[_code(0, 0), _code(1, 0)] > 0.5
    assert two[_code(-1, 0), _code(0, 0), _code(0, 0)] > 0.5
    assert two[_code(-1, 0), _code(0, 0), _code(1, 0)] < -2.0
    assert two[_code(0, 0), _code(0, 0), _code(1, 0)] > 0.5
    assert two[_code(0, 0), _code(0, 0), _code(0, 0)] < -2.0
    # a path that keeps the four-step pattern outweighs one that moves its 6 a step early, which
    # the acceleration before alone does not tell (it even finds the early 6 more likely)
    keep = np.cumsum([[0, 0], [5, 0], [5, 0], [5, 0], [6, 0], [5, 0], [5, 0], [5, 0], [6, 0]], 0)[None] / 3.0
    early = np.cumsum([[0, 0], [5, 0], [5, 0], [5, 0], [6, 0], [5, 0], [5, 0], [6, 0], [5, 0]], 0)[None] / 3.0
    assert mem.log_weight(keep)[0] > mem.log_weight(early)[0] + 3.0
    alone = MotionMemory().fit(_steady(speed=1.75))
    alone.log_ratio_two.zero_()
    assert alone.log_weight(keep)[0] < alone.log_weight(early)[0]


def test_the_memory_is_the_same_however_the_lattice_is_turned():
    u = _steady(seed=1)
    turned = u[..., ::-1] * [1.0, -1.0]  # a quarter turn: (x, y) -> (y, -x)
    a, b = MotionMemory().fit(u), MotionMemory().fit(turned)
    assert torch.equal(a.log_ratio, b.log_ratio) and torch.equal(a.log_ratio_two, b.log_ratio_two)
    path = u[:3]
    np.testing.assert_allclose(a.log_weight(path), a.log_weight(path[..., ::-1] * [-1.0, 1.0]))


def test_an_unfitted_memory_weighs_nothing_and_bad_positions_are_refused():
    mem = MotionMemory()
    assert not bool(mem.fitted) and not mem.log_weight(_steady(3)).any()
    with pytest.raises(ValueError, match="L >= 4"):
        mem.fit(np.zeros((5, 3, 2)))
    bad = _steady(4)
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        mem.fit(bad)
    # a model saved before the memory existed loads without one
    fresh = MotionMemory()
    fresh.load_state_dict({}, strict=True)
    assert not bool(fresh.fitted)
    # a memory of another reach loads as it was measured
    wide = MotionMemory(reach=3).fit(_steady())
    fresh.load_state_dict(wide.state_dict())
    assert fresh.reach == 3 and torch.equal(fresh.log_ratio, wide.log_ratio)
    np.testing.assert_array_equal(fresh.log_weight(_steady(5)), wide.log_weight(_steady(5)))
    # one saved before it looked two accelerations back looks one back only
    old = {k: v for k, v in MotionMemory().fit(_steady()).state_dict().items() if k != "log_ratio_two"}
    fresh.load_state_dict(old)
    assert (
        fresh.reach == 2 and torch.equal(fresh.log_ratio, old["log_ratio"]) and not fresh.log_ratio_two.any()
    )
    with pytest.raises(ValueError, match="backoff"):
        MotionMemory().fit(_steady(), backoff=0.0)


def test_paths_drawn_from_an_unpruned_beam_follow_the_smoothed_marginals():
    xy, score = _candidates(B=2, T=5, S=6)
    f = CandidateFilter(MOTION, k=6, beam=36, vague_gate=None).run(xy, score)
    smoothed = np.exp(f.cells.smooth([5])[0])  # (B, T, K), the backward pass's
    m = f.cells.m
    pi, ci, la = (p.upto(4) for p in f.cells._pairs)
    n = 20000
    idx = sample_paths(
        f.cells.points(5), f.cells.likelihoods(5), pi, ci, la, 5, n, 3, m.speed_edges, m.headings,
        m.heading_slopes, m.accel_table, m.bin, m.reach, m.place, m.accel_prob, m.walls,
    )  # fmt: skip
    freq = np.stack([np.bincount(idx[b, :, t], minlength=6) for b in range(2) for t in range(5)]) / n
    np.testing.assert_allclose(freq, smoothed.reshape(10, 6), atol=0.015)
    # a shorter prefix draws from its own posterior, the steps after it unseen
    short = sample_paths(
        f.cells.points(3), f.cells.likelihoods(3), pi, ci, la, 3, n, 3, m.speed_edges, m.headings,
        m.heading_slopes, m.accel_table, m.bin, m.reach, m.place, m.accel_prob, m.walls,
    )  # fmt: skip
    three = np.exp(f.cells.smooth([3])[0])
    freq = np.stack([np.bincount(short[b, :, t], minlength=6) for b in range(2) for t in range(3)]) / n
    np.testing.assert_allclose(freq, three.reshape(6, 6), atol=0.015)


def _lattice_filter(memory, **kw):
    tr = toy_sequence_set(64, 6, seed=0)
    lattice = MotionTable.lattice().fit(snap_to_lattice(tr.positions - tr.grid_xy.min(0)))
    return CandidateFilter(MOTION, lattice, 1.0, k=8, beam=30, fine_k=3, fine_beam=60, memory=memory, **kw)


def test_paths_drawn_with_the_backward_passes_are_the_ones_drawn_alone():
    # smooth_and_sample draws the memory's paths in the same kernel as the prefixes' backward
    # passes, from the densities worked out once for both: the same paths as sample_paths,
    # and the same marginals as smooth
    xy, score = _candidates(B=6, T=7, S=12)
    f = _lattice_filter(None).run(torch.round(xy), score)
    fine = f._models[0].fine
    lengths = [2, 4, 7, 5, 1]
    draw = np.zeros((6, 5), bool)
    draw[[0, 3, 5], 1] = draw[:, 2] = draw[1, 3] = True
    marg, paths = fine.smooth_and_sample(lengths, draw, 32, seed=4)
    for got, want in zip(marg, fine.smooth(lengths), strict=True):
        assert np.array_equal(got, want)
    assert paths[0].shape == (0, 32, 2) and paths[4] is None
    for i in (1, 2, 3):
        rows = np.flatnonzero(draw[:, i])
        assert np.array_equal(paths[i], fine.sample(lengths[i], 32, rows, seed=4))
    # one prefix with paths keeps the densities for the draws: the same marginals as without
    marg, paths = fine.smooth_and_sample([6], np.ones((6, 1), bool), 8)
    assert np.array_equal(marg[0], fine.smooth([6])[0])
    assert np.array_equal(paths[0], fine.sample(6, 8))


def test_the_filter_moves_its_sub_cell_tracks_by_the_memory_and_only_by_it():
    xy, score = _candidates(B=6, T=7, S=12)
    xy = torch.round(xy)
    tr = toy_sequence_set(64, 6, seed=0)
    fitted = MotionMemory().fit(snap_to_lattice(tr.positions - tr.grid_xy.min(0)))
    plain = _lattice_filter(None).run(xy, score).smooth()
    moved = _lattice_filter(fitted).run(xy, score).smooth()
    # the candidates and posteriors are the first-order smoother's; the tracks move a little
    assert torch.equal(plain[0], moved[0]) and torch.equal(plain[1], moved[1])
    shift = (moved[2] - plain[2]).norm(dim=-1)
    assert 0 < shift.max() < 1.0
    # the shift is the paths' mean weighed by the memory (softmax of their log weights) less
    # their plain mean
    f = _lattice_filter(fitted, memory_paths=64).run(xy, score)
    fine = f._models[0].fine
    idx = fine.sample(7, 64)
    pts = fine.points(7)[np.arange(6)[:, None, None], np.arange(7), idx]  # (B, n, T, 2)
    w = torch.softmax(torch.from_numpy(fitted.log_weight(pts)), 1).numpy()
    expect = (w[..., None, None] * pts).sum(1) - pts.mean(1)
    shift = f._memory_shift(fine, 7, np.arange(6))
    np.testing.assert_allclose(shift, expect, atol=1e-12)
    assert np.abs(expect).max() > 0
    # users a motion model does not count for (posterior weight below MEMORY_WEIGHT) are not
    # moved by its paths; the others are moved as before
    some = f._memory_shift(fine, 7, np.array([1, 4]))
    assert np.array_equal(some[[1, 4]], shift[[1, 4]]) and not some[[0, 2, 3, 5]].any()
    # prefixes too short for a pair of accelerations are not moved
    for T in (1, 2, 3):
        plain_prefix = _lattice_filter(None).run(xy, score).smooth(T)[2]
        assert torch.equal(_lattice_filter(fitted).run(xy, score).smooth(T)[2], plain_prefix)
    # a memory that says nothing (fitted, all ratios zero) moves nothing: the paths' weighted
    # mean less their plain mean is zero, whatever was drawn
    silent = MotionMemory().fit(snap_to_lattice(tr.positions - tr.grid_xy.min(0)))
    silent.log_ratio.zero_()
    silent.log_ratio_two.zero_()
    assert torch.equal(_lattice_filter(silent).run(xy, score).smooth()[2], plain[2])
    # an unfitted memory is none
    assert _lattice_filter(MotionMemory()).memory is None
    with pytest.raises(ValueError, match="memory_paths"):
        _lattice_filter(fitted, memory_paths=0)


def test_the_memory_leaves_the_paths_of_the_models_it_skips_unweighed():
    xy, score = _candidates(B=6, T=7, S=12)
    xy = torch.round(xy)
    tr = toy_sequence_set(64, 6, seed=0)
    u = snap_to_lattice(tr.positions - tr.grid_xy.min(0))
    lattice, mem = MotionTable.lattice().fit(u), MotionMemory().fit(u)

    def track(memory, skips=()):
        # two identical models: their evidence is the same, so their weights are their priors
        f = CandidateFilter(
            MOTION, lattice, 1.0, k=8, beam=30, fine_k=3, fine_beam=60, vague_gate=None,
            alternative=[(MOTION, lattice)], alternative_prior=0.3, memory=memory, memory_skips=skips,
        )  # fmt: skip
        return f.run(xy, score).smooth()[2].double()

    plain, both, first = track(None), track(mem), track(mem, (0,))
    assert (both - plain).abs().max() > 1e-3
    # each model's paths move its share of the track; the skipped one's share stays put
    torch.testing.assert_close(first - plain, 0.7 * (both - plain), atol=1e-5, rtol=0)
    with pytest.raises(ValueError, match="memory_skips"):
        track(mem, (1,))


def test_the_memorys_tracks_are_the_same_whatever_the_batch_and_the_threads():
    xy, score = _candidates(B=40, T=6, S=12)
    xy = torch.round(xy)
    tr = toy_sequence_set(64, 6, seed=0)
    mem = MotionMemory().fit(snap_to_lattice(tr.positions - tr.grid_xy.min(0)))
    runs = []
    for n in (1, 2):
        set_threads(n)
        try:
            runs.append(_lattice_filter(mem).run(xy, score).smooth()[2])
        finally:
            set_threads(None)
    one = _lattice_filter(mem).run(xy[33:34], score[33:34]).smooth()[2]
    assert torch.equal(runs[0], runs[1]) and torch.equal(runs[0][33:34], one)
