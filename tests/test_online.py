"""Online tracking: the beam filter over match candidates, its prefix smoother and the tracker."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from estimation import EstimationError, Estimator, TrainConfig, noisy_bits
from estimation.smoothing.beam import motion_arrays
from estimation.smoothing.hmm import velocity_posterior
from estimation.smoothing.motion import HEADINGS, MixtureMotion, MotionTable, snap_to_lattice
from estimation.smoothing.online import CandidateFilter, _mode_means
from estimation.synthetic import toy_sequence_set
from mmwsim._threads import set_threads


def _tracks(n=400, length=8, seed=0):
    rng = np.random.default_rng(seed)
    speed = rng.choice([1.4, 6.0], n)[:, None] + np.cumsum(rng.choice([-0.5, 0.0, 0.5], (n, length - 1)), 1)
    heading = rng.uniform(0, 2 * np.pi, n)[:, None] + np.cumsum(rng.normal(0, 0.2, (n, length - 1)), 1)
    steps = speed[..., None] * np.stack([np.cos(heading), np.sin(heading)], -1)
    return np.concatenate([np.zeros((n, 1, 2)), np.cumsum(steps, 1)], 1)


def _candidates(B=3, T=6, S=10, seed=1, true=None):
    """Candidates scattered around true tracks (continuous positions: no ties on table bins)."""
    g = np.random.default_rng(seed)
    true = _tracks(B, T, seed) if true is None else true
    xy = true[:, :, None] + g.normal(0, 2.0, (B, T, S, 2))
    xy[:, :, 0] = true + g.normal(0, 0.3, (B, T, 2))
    score = -np.square(xy - true[:, :, None]).sum(-1) / 4.0 + g.normal(0, 0.5, (B, T, S))
    return torch.from_numpy(xy).float(), torch.from_numpy(score).float()


MOTION = MotionTable().fit(_tracks())
# The same with a place table of the fast users (speed 6 per step; the walkers at 1.4 are not in it).
PLACED = (
    MotionTable().fit(_tracks()).fit_place(_tracks(), (-60.0, -60.0), 2.0, (60, 60), speed=3.0, floor=0.3)
)
# The same tracks in the lattice frame (heading bins within the octant), as tn-match's tables are.
LATTICE_FRAME = MotionTable(headings=HEADINGS).fit(_tracks())


@pytest.mark.parametrize(
    "motion", [MOTION, PLACED, LATTICE_FRAME], ids=["motion", "with-place", "lattice-frame"]
)
def test_unpruned_beam_is_the_dense_constant_velocity_smoother(motion):
    xy, score = _candidates()
    # 10 x 10 pairs: nothing pruned; the toy scores look vague, so the vague-step rule is off
    f = CandidateFilter(motion, k=10, beam=100, vague_gate=None).run(xy, score)
    kxy, post, _ = f.smooth()
    dense = velocity_posterior(kxy.double(), post[..., 0].double(), motion)
    assert torch.allclose(post[..., -1].double(), dense.clamp(min=-30), atol=1e-4)
    # every prefix's smoothed marginals are the dense smoother's of that prefix
    for T in (1, 2, 3):
        kxy, post, _ = f.smooth(T)
        dense = velocity_posterior(kxy.double(), post[..., 0].double(), motion)
        assert torch.allclose(post[..., -1].double(), dense.clamp(min=-30), atol=1e-4)


@pytest.mark.parametrize("beam", [100, 12])
@pytest.mark.parametrize(
    "motion", [MOTION, PLACED, LATTICE_FRAME], ids=["motion", "with-place", "lattice-frame"]
)
def test_forward_filter_equals_the_smoothers_last_step_marginal(beam, motion):
    xy, score = _candidates(T=7)
    f = CandidateFilter(motion, k=10, beam=beam)
    for t in range(7):
        f.update(xy[:, t], score[:, t])
        smoothed_last = f.cells.smooth([t + 1])[0][:, -1]
        np.testing.assert_allclose(np.exp(f.cells.marg[-1]), np.exp(smoothed_last), atol=1e-9)


def test_the_beam_keeps_the_largest_pairs_in_index_order_ties_included_by_index():
    from estimation.smoothing.beam import _NEG, _keep_best

    dense = np.array([[1.0, 5.0, 3.0], [3.0, _NEG, 4.0], [3.0, 2.0, 0.5]])
    pi, ci, la = np.empty(4, np.int64), np.empty(4, np.int64), np.empty(4)
    # the 4 largest: 5 and 4, then two of the three 3s, the first two in index order
    assert _keep_best(dense, 4, pi, ci, la) == 4
    assert list(zip(pi, ci, la, strict=True)) == [(0, 1, 5.0), (0, 2, 3.0), (1, 0, 3.0), (1, 2, 4.0)]
    # a beam wider than the finite entries keeps them all, in index order, then padding
    pi, ci, la = np.empty(10, np.int64), np.empty(10, np.int64), np.empty(10)
    assert _keep_best(dense, 10, pi, ci, la) == 8
    assert list(la[:8]) == [1.0, 5.0, 3.0, 3.0, 4.0, 3.0, 2.0, 0.5] and (la[8:] == _NEG).all()
    assert list(pi[:8]) == [0, 0, 0, 1, 1, 2, 2, 2]
    # above a floor (the forward step's keys, most of them zero): the cut among the entries above
    # it, a tie at the cut again taken in index order
    keys = np.array([[0.0, 2.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 3.0]])
    pi, ci, la = np.empty(3, np.int64), np.empty(3, np.int64), np.empty(3)
    assert _keep_best(keys, 3, pi, ci, la, 0.0) == 3
    assert list(zip(pi, ci, la, strict=True)) == [(0, 1, 2.0), (1, 2, 1.0), (2, 2, 3.0)]


def _forward_reference(xpp, xp, xc, pi, ci, la, lp, M, motion):
    """pair_forward written out in logs: each new pair's message is the log-sum-exp over the kept
    pairs it continues of message plus acceleration density, plus its likelihood and place; the
    M largest kept in index order."""
    B, Kp, K = xp.shape[0], xp.shape[1], xc.shape[1]
    out = []
    for b in range(B):
        dense = np.full((Kp, K), -np.inf)
        for q in np.flatnonzero(la[b] > -1e299):
            a0, a1 = pi[b, q], ci[b, q]
            v = torch.from_numpy(xp[b, a1] - xpp[b, a0]).expand(K, 2)
            a = torch.from_numpy(xc[b] - xp[b, a1]) - v
            dense[a1] = np.logaddexp(dense[a1], la[b, q] + motion.log_accel(v, a).double().numpy())
        w = torch.from_numpy(xc[b][None] - xp[b][:, None])
        place = motion.log_place_ratio(w, torch.from_numpy(xc[b]).expand(Kp, K, 2)).double().numpy()
        dense = (dense + lp[b][None] + place).ravel()
        keep = np.sort(np.argsort(-dense, kind="stable")[:M])
        keep = keep[np.isfinite(dense[keep])]
        out.append((keep // K, keep % K, dense[keep]))
    return out


@pytest.mark.parametrize(
    "motion", [MOTION, PLACED, LATTICE_FRAME], ids=["motion", "with-place", "lattice-frame"]
)
@pytest.mark.parametrize("M", [15, 64], ids=["pruned", "all"])
@pytest.mark.parametrize("far", [False, True], ids=["near", "far-likelihoods"])
def test_a_forward_step_keeps_the_pairs_and_messages_a_log_domain_step_keeps(motion, M, far):
    """The kernel picks the kept pairs by products of probabilities (one logarithm per kept pair);
    where products underflow (likelihoods 800 nats apart) it falls back to logs."""
    from estimation.smoothing.beam import pair_forward, pair_start

    xy, score = _candidates(B=4, T=3, S=8, seed=3)
    xy, lp = xy.double().numpy(), torch.log_softmax(score.double(), -1).numpy()
    if far:
        lp[:, 2, 5:] -= 800.0
    m = motion_arrays(motion)
    pi, ci, la, _ = pair_start(xy[:, 0], xy[:, 1], lp[:, 0], lp[:, 1], 64, m.step_table, m.bin, m.place)
    args = (xy[:, 0], xy[:, 1], xy[:, 2], pi, ci, la, lp[:, 2])
    npi, nci, nla, marg = pair_forward(
        *args,
        M,
        m.speed_edges,
        m.headings,
        m.heading_slopes,
        m.accel_table,
        m.bin,
        m.reach,
        m.place,
        m.accel_prob,
        m.accel_max,
        m.walls,
    )
    for b, (rpi, rci, rla) in enumerate(_forward_reference(*args, M, motion)):
        n = len(rla)
        assert n == min(M, 64) and (nla[b, n:] <= -1e299).all()
        np.testing.assert_array_equal(npi[b, :n], rpi)
        np.testing.assert_array_equal(nci[b, :n], rci)
        np.testing.assert_allclose(nla[b, :n], rla, rtol=0, atol=1e-5)
    assert np.allclose(np.exp(marg).sum(1), 1.0)


def test_the_filter_stores_its_pairs_in_two_byte_indices_and_refuses_more_candidates():
    """A filter keeps every step's kept pairs until its backward passes (a batch of 512 users,
    four motion models: hundreds of megabytes at seven steps), so their candidate indices are
    int16; a beam over more candidates than those index is refused, not wrapped around."""
    from estimation.smoothing.beam import MAX_CANDIDATES, pair_start

    xy, score = _candidates(B=2, T=3, S=8, seed=3)
    f = CandidateFilter(MOTION, None, 1.0, k=8, beam=16, vague_gate=None).run(xy, score)
    for stack in f.cells._pairs[:2]:
        assert stack.upto(2).dtype == np.int16
    with pytest.raises(ValueError, match="at most 32767"):
        CandidateFilter(MOTION, None, 1.0, k=MAX_CANDIDATES + 1)
    with pytest.raises(ValueError, match="at most"):
        CandidateFilter(MOTION, None, 1.0, fine_k=4000, n_sub=3)
    m = motion_arrays(MOTION)
    x1 = np.zeros((1, MAX_CANDIDATES + 1, 2))
    with pytest.raises(ValueError, match="MAX_CANDIDATES"):
        pair_start(
            x1[:, :1],
            x1,
            np.zeros((1, 1)),
            np.zeros((1, MAX_CANDIDATES + 1)),
            4,
            m.step_table,
            m.bin,
            m.place,
        )


@pytest.mark.parametrize("place", [False, True], ids=["motion", "with-place"])
def test_sub_cell_stage_without_pruning_is_the_dense_sub_cell_smoother(place):
    tr = toy_sequence_set(64, 6, seed=0)
    lattice = MotionTable.lattice().fit(snap_to_lattice(tr.positions - tr.grid_xy.min(0)))
    if place:
        lattice.fit_place(snap_to_lattice(_tracks()), (-60.5, -60.5), 1 / 3, (363, 363), speed=3.0)
    xy, score = _candidates(B=2, T=4, S=4)
    xy = torch.round(xy)  # grid points of a 1 m grid
    f = CandidateFilter(
        MOTION, lattice, 1.0, k=4, beam=16, fine_k=4, fine_beam=36 * 36, vague_gate=None, mode_chain=math.inf
    )
    f.run(xy, score)
    kxy, post, fine = f.smooth()
    # every cell split into its 3 x 3 lattice points, each with its cell's likelihood
    sxy = (kxy.double()[:, :, :, None] + torch.tensor(f._offsets)).reshape(2, 4, 36, 2)
    slp = post[..., 0].double()[..., None].expand(-1, -1, -1, 9).reshape(2, 4, 36)
    # the dense smoother in float64 (in float32 a lattice step of exactly one bin can round down)
    w = velocity_posterior(sxy, slp, lattice).exp()
    assert torch.allclose(fine.double(), (w[..., None] * sxy).sum(2), atol=1e-5)


def test_each_mode_of_the_split_cells_holds_its_cells_mass_at_its_own_sub_cell_mean():
    # Two modes 10 m apart. The cells put 0.8 on the far one; the sub-cell beam lost it (its paths
    # all pass the near cells), so its mean over all split cells lies in the near mode.
    cells = np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0], [11.0, 0.0]])[None, None]  # (1, 1, 4, 2) m
    p = np.array([0.1, 0.1, 0.4, 0.4])[None, None]
    top = np.arange(4)[None, None]
    offsets = np.array([[-0.25, 0.0], [0.25, 0.0]])  # two lattice points per cell, grid units
    points = (cells[:, :, :, None] + offsets).reshape(1, 1, 8, 2)
    w = np.array([0.3, 0.2, 0.25, 0.25, 0, 0, 0, 0])[None, None]
    shift = np.zeros((1, 1, 2))
    near = (w[0, 0, :, None] * points[0, 0]).sum(0)  # (0.45, 0)
    whole = _mode_means(p, cells, top, w, points, shift, 1.0, math.inf)
    np.testing.assert_allclose(whole[0, 0], near)  # one mode: all the mass at the beam's mean
    modes = _mode_means(p, cells, top, w, points, shift, 1.0, 1.0)
    np.testing.assert_allclose(modes[0, 0], 0.2 * near + 0.4 * cells[0, 0, 2] + 0.4 * cells[0, 0, 3])
    # sharpened: the shares go as the masses squared, 0.04 : 0.64
    sharp = _mode_means(p, cells, top, w, points, shift, 1.0, 1.0, 2.0)
    np.testing.assert_allclose(sharp[0, 0], (0.04 * near + 0.64 * np.array([10.5, 0.0])) / 0.68)
    # where the beam holds the far mode too, each mode's mass goes to its own sub-cell mean
    w2 = np.array([0.3, 0.2, 0.25, 0.25, 0.0, 0.0, 0.0, 0.0]) + np.array([0, 0, 0, 0, 0.1, 0.1, 0.1, 0.1])
    w2 = (w2 / w2.sum())[None, None]
    far = (w2[0, 0, 4:, None] * points[0, 0, 4:]).sum(0) / w2[0, 0, 4:].sum()
    near2 = (w2[0, 0, :4, None] * points[0, 0, :4]).sum(0) / w2[0, 0, :4].sum()
    np.testing.assert_allclose(_mode_means(p, cells, top, w2, points, shift + 0.5, 2.0, 2.0)[0, 0],
                               2.0 * (0.2 * (near2 + 0.5) + 0.8 * (far + 0.5)))  # fmt: skip


def test_a_user_whose_sub_cell_beam_keeps_one_mode_is_placed_as_before():
    # walkers' candidates near their tracks: the split cells of a step are one chained mode
    tr = toy_sequence_set(64, 6, seed=0)
    lattice = MotionTable.lattice().fit(snap_to_lattice(tr.positions - tr.grid_xy.min(0)))
    xy, score = _candidates(B=2, T=4, S=4)
    xy = torch.round(xy * 0.2)  # grid points of a 1 m grid, within a few metres of each other
    runs = [
        CandidateFilter(MOTION, lattice, 1.0, k=4, beam=16, fine_k=4, fine_beam=512, mode_chain=c).run(
            xy, score
        )
        for c in (math.inf, 4.0, 0.0)
    ]
    (_, _, whole), (_, _, chained), (_, _, apart) = (f.smooth() for f in runs)
    assert torch.allclose(chained, whole, atol=1e-5)
    assert not torch.allclose(apart, whole, atol=1e-3)  # cells apart: the cells' own mass counts
    with pytest.raises(ValueError, match="mode_chain"):
        CandidateFilter(MOTION, lattice, mode_chain=float("nan"))


def test_a_driver_that_stops_keeps_the_sub_cell_beams_split_between_modes():
    # steps of 8, 0, 0, 8, 8 m: a mean of 4.8 below the place table's 5.5 per step, a median above
    x = np.cumsum([0.0, 8.0, 0.0, 0.0, 8.0, 8.0])
    driver = np.stack([x, 0.5 * x], -1)[None]
    placed = (
        MotionTable().fit(_tracks()).fit_place(_tracks(), (-60.0, -60.0), 2.0, (60, 60), speed=5.5, floor=0.3)
    )
    lattice = MotionTable.lattice().fit(snap_to_lattice(_tracks()))

    def fine(true, chain):
        xy, score = _candidates(B=1, T=6, S=8, true=true)
        f = CandidateFilter(placed, lattice, 1.0, k=8, beam=64, fine_k=4, fine_beam=512, mode_chain=chain)
        return f.run(xy, score).smooth()[2]

    assert torch.equal(fine(driver, 0.0), fine(driver, math.inf))
    walker = driver * 0.2  # the same track at 1.6 m per step: placed by modes
    assert not torch.allclose(fine(walker, 0.0), fine(walker, math.inf), atol=1e-3)


def test_a_prefix_never_sees_the_steps_after_it():
    xy, score = _candidates(T=19)
    # 19 steps: the stored steps outgrow their first buffers (8 steps) twice
    longer = CandidateFilter(MOTION, k=6, beam=20).run(xy, score)
    for T in (4, 9, 17):
        short = CandidateFilter(MOTION, k=6, beam=20).run(xy[:, :T], score[:, :T]).smooth()
        for a, b in zip(short, longer.smooth(T), strict=True):
            assert torch.equal(a, b)
    xy, score = xy[:, :7], score[:, :7]
    # smoothing between updates (what it keeps for the next prefix) changes nothing
    stepwise = CandidateFilter(MOTION, k=6, beam=20)
    for t in range(7):
        stepwise.update(xy[:, t], score[:, t])
        got = stepwise.smooth()
    for a, b in zip(got, CandidateFilter(MOTION, k=6, beam=20).run(xy, score).smooth(), strict=True):
        assert torch.equal(a, b)


def test_all_prefixes_at_once_are_each_prefix_smoothed_alone():
    tr = toy_sequence_set(64, 6, seed=0)
    lattice = MotionTable.lattice().fit(snap_to_lattice(tr.positions - tr.grid_xy.min(0)))
    xy, score = _candidates(B=5, T=9, S=12)
    xy = torch.round(xy)

    def make():
        # both stages, an alternative model and a pruned beam, as tn-match runs it
        return CandidateFilter(
            MOTION,
            lattice,
            1.0,
            k=8,
            beam=30,
            fine_k=3,
            fine_beam=40,
            alternative=(MOTION.broadened(), lattice.broadened()),
        ).run(xy, score)

    f = make()
    lengths = [9, 2, 5, 1, 5, 7]  # any order, repeats and the first step alone
    together = f.smooth_prefixes(lengths)
    for T, got in zip(lengths, together, strict=True):
        for a, b in zip(got, make().smooth(T), strict=True):
            assert torch.equal(a, b)
    with pytest.raises(ValueError, match="can smooth 1..9 steps"):
        f.smooth_prefixes([3, 10])


def test_random_walks_of_every_prefix_are_the_sums_over_all_their_paths():
    from estimation.smoothing.beam import rw_smooth

    g = np.random.default_rng(4)
    B, T, K = 2, 4, 3
    xy = g.uniform(0, 8, (B, T, K, 2))
    lp = np.log(g.uniform(0.1, 1.0, (B, T, K)))
    scales = np.array([1.5, 4.0])
    lengths = np.array([4, 1, 3, 2])
    got = rw_smooth(xy, lp, 0.5 / scales**2, lengths)
    assert got.shape == (B, lengths.sum(), K, len(scales))
    start = np.cumsum([0, *lengths])
    for b, (si, s), (n, L) in itertools.product(range(B), enumerate(scales), enumerate(lengths)):
        marg = np.zeros((L, K))
        for path in itertools.product(range(K), repeat=int(L)):
            logp = sum(lp[b, t, j] for t, j in enumerate(path))
            for t in range(L - 1):
                logp -= np.square(xy[b, t + 1, path[t + 1]] - xy[b, t, path[t]]).sum() / (2 * s**2)
            marg[np.arange(L), path] += np.exp(logp)
        want = np.log(marg / marg.sum(1, keepdims=True))
        np.testing.assert_allclose(got[b, start[n] : start[n + 1], :, si], want, atol=1e-12)
    # steps kilometres apart: every weight underflows, and each step keeps its own likelihoods
    far = xy.copy()
    far[:, 1::2] += 3000.0
    got = rw_smooth(far, lp, 0.5 / scales**2, np.array([4]))
    want = lp - np.log(np.exp(lp).sum(-1, keepdims=True))
    np.testing.assert_allclose(got, np.repeat(want[..., None], 2, -1), atol=1e-12)
    with pytest.raises(ValueError, match="prefix lengths must lie in 1..T"):
        rw_smooth(xy, lp, 0.5 / scales**2, np.array([2, 5]))


def test_a_tables_kernel_arrays_are_made_once_and_again_when_it_changes():
    table = MotionTable().fit(_tracks(50))
    first = motion_arrays(table)
    assert motion_arrays(table) is first
    table.log_accel_table[0, 0, 0] += 1.0  # changed in place
    changed = motion_arrays(table)
    assert changed is not first and changed.accel_table[0, 0, 0] == pytest.approx(
        first.accel_table[0, 0, 0] + 1.0
    )
    table.log_place = table.log_place.clone()  # a buffer replaced
    assert motion_arrays(table) is not changed
    table.bin = table.bin * 2  # a plain attribute
    assert motion_arrays(table).bin == 2 * changed.bin


def test_same_bytes_whatever_the_batch_and_the_threads():
    xy, score = _candidates(B=70, T=5, S=12)
    runs = []
    for n in (1, 2):
        set_threads(n)
        try:
            runs.append(CandidateFilter(MOTION, k=8, beam=30).run(xy, score).smooth())
        finally:
            set_threads(None)
    one = CandidateFilter(MOTION, k=8, beam=30).run(xy[5:6], score[5:6]).smooth()
    for a, b, c in zip(*runs, one, strict=True):
        assert torch.equal(a, b) and torch.equal(a[5:6], c)


def test_hand_set_mixture_is_tabulated_at_its_densities():
    mix = MixtureMotion()
    arr = motion_arrays(mix)
    centre = -arr.reach + (np.arange(arr.accel_table.shape[1]) + 0.5) * arr.bin
    i, j = np.searchsorted(centre, 0.125), np.searchsorted(centre, 3.125)
    a = torch.tensor([[centre[i], centre[j]]], dtype=torch.float64)
    exact = mix.log_accel(torch.zeros(1, 2, dtype=torch.float64), a)
    assert arr.accel_table[0, i, j] == pytest.approx(float(exact[0]), abs=1e-5)


def test_prediction_in_chunks_is_prediction_at_once():
    from estimation import estimator as estimator_module

    va = toy_sequence_set(70, 4, seed=2)
    bits = noisy_bits(va, 6.0, torch.Generator().manual_seed(3))
    torch.manual_seed(0)
    cfg = TrainConfig(model="tn-match", sigma=6.0, options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, va.n_beams, va.n_bins, va.normaliser()).attach(va)
    x = est.inputs(bits.float())
    chunked = est.predict(x)  # 70 sequences: chunks of 64 and 6
    assert chunked.shape == (70, 4, 2)
    old, estimator_module.PREDICT_CHUNK = estimator_module.PREDICT_CHUNK, 1000
    try:
        whole = est.predict(x)
    finally:
        estimator_module.PREDICT_CHUNK = old
    assert torch.allclose(chunked, whole, atol=1e-5)
    assert torch.equal(est.predict(bits.float()), chunked)  # from the bits: the same inputs
    assert est.predict(tuple(t[:0] for t in x)).shape == (0, 4, 2)


def test_prediction_and_prefixes_side_by_side_are_the_same_bytes_on_any_threads(monkeypatch):
    from estimation import evaluation

    va = toy_sequence_set(200, 5, seed=4)
    bits = noisy_bits(va, 6.0, torch.Generator().manual_seed(5))
    torch.manual_seed(0)
    cfg = TrainConfig(model="tn-match", sigma=6.0, options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, va.n_beams, va.n_bins, va.normaliser()).attach(va)
    method = evaluation.NetworkMethod(est, "toy", 0.0, 0)
    monkeypatch.setattr(evaluation, "_PART", 48)  # five parts
    runs = []
    for n in (1, 2):
        set_threads(n)  # two: blocks of 100 and parts of 48 side by side, one torch thread each
        try:
            runs.append((est.predict(bits), method.predict_lengths(bits, [2, 5])))
        finally:
            set_threads(None)
    (one, one_prefixes), (two, two_prefixes) = runs
    assert one.shape == (200, 5, 2) and torch.equal(one, two)
    for L in (2, 5):
        assert np.array_equal(one_prefixes[L][0], two_prefixes[L][0]) and two_prefixes[L][1] > 0
        assert np.allclose(two_prefixes[L][0], est.predict(bits[:, :L]).numpy(), atol=1e-5)


def test_online_tracker_updates_per_step_and_tracks_like_predict():
    va = toy_sequence_set(64, 5, seed=2)
    bits = noisy_bits(va, 12.0, torch.Generator().manual_seed(3))  # noisy enough for aliases
    torch.manual_seed(0)
    cfg = TrainConfig(model="tn-match", sigma=12.0, options={"search": 32, "k": 8, "d": 16, "ff": 32})
    est = Estimator(cfg, va.n_beams, va.n_bins, va.normaliser()).attach(va)
    tracker = est.tracker()
    now = [tracker.update(bits[:, t]) for t in range(5)]
    assert tracker.steps == 5 and now[-1].shape == (64, 2) and np.isfinite(now).all()
    assert np.array_equal(np.stack(now, 1), np.stack(tracker.filter.positions, 1))
    assert torch.allclose(tracker.track(), est.predict(bits.float()), atol=1e-5)
    # the current estimates beat each step's single best match
    err_now = np.linalg.norm(np.stack(now, 1) - va.positions, axis=-1).mean()
    err_match = np.linalg.norm(est.matcher.match(bits) - va.positions, axis=-1).mean()
    assert err_now < 0.95 * err_match
    with pytest.raises(EstimationError, match="one step's fingerprints"):
        tracker.update(bits[:, 0, :3])
    with pytest.raises(EstimationError, match="after steps of 64"):
        tracker.update(bits[:3, 0])


def test_evidence_of_an_unpruned_beam_is_the_sum_over_all_paths():
    xy, score = _candidates(B=2, T=4, S=3)
    f = CandidateFilter(PLACED, k=3, beam=9).run(xy, score)
    lp = torch.log_softmax(score.double(), -1)
    x = xy.double()
    for b in range(2):
        for T in range(1, 5):
            terms = []
            for path in itertools.product(range(3), repeat=T):
                p = torch.stack([x[b, t, j] for t, j in enumerate(path)])
                logp = sum(float(lp[b, t, j]) for t, j in enumerate(path))
                if T > 1:
                    logp += float(PLACED.log_first(p[1] - p[0]) + PLACED.log_place_ratio(p[1] - p[0], p[0]))
                    logp += sum(float(PLACED.log_place_ratio(p[t] - p[t - 1], p[t])) for t in range(1, T))
                    logp += sum(
                        float(PLACED.log_accel(p[t] - p[t - 1], p[t + 1] - 2 * p[t] + p[t - 1]))
                        for t in range(1, T - 1)
                    )
                terms.append(logp)
            assert f.cells.evidence[T - 1][b] == pytest.approx(
                float(torch.tensor(terms).logsumexp(0)), abs=1e-4
            )


def test_an_alternative_that_is_the_same_model_changes_nothing():
    xy, score = _candidates(T=5)
    one = CandidateFilter(MOTION, k=8, beam=30).run(xy, score)
    two = CandidateFilter(MOTION, k=8, beam=30, alternative=(MOTION, None), alternative_prior=0.3).run(
        xy, score
    )
    np.testing.assert_allclose(two.model_weights(), np.tile([0.7, 0.3], (3, 1)), atol=1e-12)
    for a, b in zip(one.smooth(), two.smooth(), strict=True):
        assert torch.allclose(a, b, atol=1e-5)
    np.testing.assert_allclose(np.stack(one.positions), np.stack(two.positions), atol=1e-9)
    with pytest.raises(ValueError, match="prior"):
        CandidateFilter(MOTION, alternative=(MOTION, None), alternative_prior=1.0)
    # several alternatives share the prior evenly: two copies of one are that one
    three = CandidateFilter(
        MOTION, k=8, beam=30, alternative=[(MOTION, None), (MOTION, None)], alternative_prior=0.3
    ).run(xy, score)
    np.testing.assert_allclose(three.model_weights(), np.tile([0.7, 0.15, 0.15], (3, 1)), atol=1e-12)
    for a, b in zip(one.smooth(), three.smooth(), strict=True):
        assert torch.allclose(a, b, atol=1e-5)
    # or one prior each; the measured model has the rest
    each = CandidateFilter(
        MOTION, k=8, beam=30, alternative=[(MOTION, None), (MOTION, None)], alternative_prior=(0.2, 0.06)
    ).run(xy, score)
    np.testing.assert_allclose(each.model_weights(), np.tile([0.74, 0.2, 0.06], (3, 1)), atol=1e-12)
    for a, b in zip(one.smooth(), each.smooth(), strict=True):
        assert torch.allclose(a, b, atol=1e-5)
    for bad in ((0.5, 0.5), (0.2,), (0.2, 0.0), (0.2, float("nan")), (0.3, -0.1)):
        with pytest.raises(ValueError, match="priors"):
            CandidateFilter(MOTION, alternative=[(MOTION, None), (MOTION, None)], alternative_prior=bad)


def _turning_tracks(n, length, seed):
    """Users at 6 m/step who take a new random heading at every step."""
    rng = np.random.default_rng(seed)
    heading = rng.uniform(0, 2 * np.pi, (n, length - 1))
    steps = 6.0 * np.stack([np.cos(heading), np.sin(heading)], -1)
    return np.concatenate([np.zeros((n, 1, 2)), np.cumsum(steps, 1)], 1)


def _beam_run(motion, xy, lp, beam=60):
    """A beam of ``motion`` over the steps of ``xy (B, T, K, 2)``, ``lp (B, T, K)``."""
    from estimation.smoothing.online import _Beam

    b = _Beam(motion, beam)
    for t in range(xy.shape[1]):
        b.update(np.ascontiguousarray(xy[:, t]), np.ascontiguousarray(lp[:, t]))
    return b


def test_walls_read_the_blocked_classes_where_the_way_ahead_is_blocked():
    """A table with wall classes reads its second set where the way straight ahead is blocked
    (the step's end or its middle), in the forward pass and in the smoother alike."""
    steer = MOTION.broadened(turn=0.0, steer=1.0)
    turn = MOTION.broadened(turn=1.0, steer=0.0)
    walled = MOTION.broadened(turn=0.0, steer=1.0, blocked=(1.0, 0.0))
    # one candidate a step: east at 4 per step, then a quarter turn north
    path = np.array([[[[0.0, 0.0]], [[4.0, 0.0]], [[4.0, 4.0]]]])
    lp = np.zeros((1, 3, 1))
    free = np.ones((60, 60), bool)  # points -20 .. 39 each way
    evidence = {name: _beam_run(m, path, lp).evidence[-1] for name, m in (("steer", steer), ("turn", turn))}
    assert float(evidence["turn"][0] - evidence["steer"][0]) > 3.0  # the densities differ there
    for wall, reads in (((28, 20), "turn"), ((26, 20), "turn"), ((30, 20), "steer"), (None, "steer")):
        f = free.copy()
        if wall is not None:
            f[wall] = False  # (8, 0): the end straight ahead; (6, 0): its middle; (10, 0): past it
        walled.with_walls(f, (-20.0, -20.0), 1.0)
        np.testing.assert_allclose(_beam_run(walled, path, lp).evidence[-1], evidence[reads], rtol=1e-12)
    # walls or none, the kernels see one type: compiled once for both
    from numba import typeof

    assert typeof(motion_arrays(walled).walls) == typeof(motion_arrays(MOTION).walls)
    # many candidates, every point free or every point blocked: the filter and smoother of the
    # steering or of the turning classes, to the last digit
    xy, score = _candidates(B=4, T=6, S=10, seed=3)
    xy, score = xy.double().numpy(), torch.log_softmax(score.double(), -1).numpy()
    for value, same in ((True, steer), (False, turn)):
        walled.with_walls(np.full((300, 300), value), (-150.0, -150.0), 1.0)
        got, want = _beam_run(walled, xy, score), _beam_run(same, xy, score)
        np.testing.assert_array_equal(got.evidence[-1], want.evidence[-1])
        np.testing.assert_array_equal(got.smooth([6])[0], want.smooth([6])[0])


def test_the_evidence_picks_the_motion_a_user_follows():
    """The measured table's own users keep it; users who turn at random go over to the broadened
    alternative, and the averaged filter tracks each group as well as the better single model."""
    # measured as the candidates see them: with their 0.3 m scatter about the truth
    tracks = _tracks(20000, seed=9)
    motion = MotionTable().fit(tracks + np.random.default_rng(9).normal(0, 0.3, tracks.shape))
    groups = {"ours": _tracks(60, 7, seed=5), "turning": _turning_tracks(60, 7, seed=6)}
    for name, true in groups.items():
        xy, score = _candidates(B=60, T=7, S=12, seed=7, true=true)
        alone = CandidateFilter(motion, k=12, beam=60).run(xy, score)
        broad = CandidateFilter(motion.broadened(), k=12, beam=60).run(xy, score)
        both = CandidateFilter(motion, k=12, beam=60, alternative=(motion.broadened(), None)).run(xy, score)
        err = {
            key: np.linalg.norm(f.smooth()[2].double().numpy() - true, axis=-1).mean()
            for key, f in (("alone", alone), ("broad", broad), ("both", both))
        }
        w_alt = both.model_weights()[:, 1].mean()
        if name == "ours":
            assert w_alt < 0.3
        else:
            assert w_alt > 0.9 and err["both"] < 0.6 * err["alone"]
        assert err["both"] <= 1.02 * min(err["alone"], err["broad"]), (name, err)


def test_vague_steps_far_off_the_track_go_onto_it():
    """A step whose fingerprint says little and whose estimate is far off the track of the
    informative steps around it is put on that track: extrapolated back before the first,
    interpolated between two, extrapolated on after the last; near ones, informative ones and
    users without an informative step are kept."""
    from estimation.smoothing.online import VAGUE_GATE, _vague_shift

    line = np.stack([5.0 * np.arange(7), np.zeros(7)], -1)  # 5 m per step along x
    pos = np.repeat(line[None], 5, 0)
    vague = np.zeros((5, 7), bool)
    pos[0, 0] += (200.0, 90.0)  # vague first step far away
    vague[0, 0] = True
    pos[1, 3] += (0.0, 60.0)  # vague middle step, with a vague neighbour
    vague[1, 2:4] = True
    pos[2, 6] += (-80.0, 0.0)  # vague last step
    vague[2, 6] = True
    pos[3, 2] += (0.0, 0.9 * (VAGUE_GATE + 5.0))  # vague but within reach of step 1: kept
    vague[3, 2] = True
    pos[3, 4] += (0.0, 70.0)  # far but informative: kept
    pos[4] += (0.0, 40.0) * (np.arange(7) % 2)[:, None]  # nothing informative: kept
    vague[4] = True
    # A right-angle turn at 12 m per step inside a vague run (steps 2-5): step 3, the corner, is
    # 20 m off the chord between steps 1 and 6 (more than the gate plus the chord's step) but
    # within reach of step 1 at the user's speed: kept.
    fast = 12.0 * np.arange(4)
    turn = np.concatenate([np.stack([fast, 0 * fast], -1), np.stack([36.0 + 0 * fast[1:], fast[1:]], -1)])
    pos = np.concatenate([pos, turn[None]])
    vague = np.concatenate([vague, np.isin(np.arange(7), [2, 3, 4, 5])[None]])
    chord = turn[1] + 2 * (turn[6] - turn[1]) / 5
    assert np.linalg.norm(turn[3] - chord) > VAGUE_GATE + np.linalg.norm(turn[6] - turn[1]) / 5
    out = pos + _vague_shift(pos, vague)
    np.testing.assert_allclose(out[0], line, atol=1e-12)
    # steps 1 and 4 anchor steps 2 and 3 at constant velocity between them
    np.testing.assert_allclose(out[1], line, atol=1e-12)
    np.testing.assert_allclose(out[2], line, atol=1e-12)
    np.testing.assert_array_equal(out[3:], pos[3:])


def test_steps_after_blank_first_steps_keep_the_candidates_their_fingerprints_favour():
    """A first fingerprint with no bit set, all its candidates 150 m off (any of thousands of alike
    points), then informative ones whose candidates hold both points near the user and, less
    likely, points near those first ones. The filter keeps half of them: walks from the first
    step's points keep the far ones at every step, and the track stays 150 m off, unless the
    filter is told that the first step was blank."""
    B, T, S, k = 2, 6, 20, 10
    g = np.random.default_rng(4)
    true = np.stack([np.stack([1.4 * np.arange(T), 0.5 * np.arange(T)], -1)] * B)
    far = true[:, :1] + (150.0, 130.0)
    near = true[:, :, None] + g.normal(0, 1.0, (B, T, S // 2, 2))
    away = far[:, :, None] + g.normal(0, 1.0, (B, T, S // 2, 2))
    xy = np.concatenate([near, away], 2)
    score = np.concatenate(
        [-np.square(near - true[:, :, None]).sum(-1), -8.0 - np.square(away - far[:, :, None]).sum(-1)], 2
    )
    xy[:, 0] = far[:, 0, None] + g.normal(0, 1.0, (B, S, 2))  # the blank first step
    score[:, 0] = -0.1 * np.arange(S)
    xy, score = torch.from_numpy(xy).float(), torch.from_numpy(score).float()
    blank = np.zeros((B, T), bool)
    blank[:, 0] = True

    def kept_and_error(blank):
        kxy, _, fine = CandidateFilter(MOTION, k=k, beam=50).run(xy, score, blank).smooth()
        kept = np.linalg.norm(kxy[:, 1:].numpy() - true[:, 1:, None], axis=-1).min(-1)
        return kept, np.linalg.norm(fine.numpy() - true, axis=-1).max()

    kept, err = kept_and_error(blank)
    assert (kept < 2.0).all() and err < 3.0  # a point near the user kept at every step
    kept, err = kept_and_error(None)
    assert (kept > 100.0).all() and err > 100.0
    # a blank step after an informative one changes nothing: the walks know where to look, even
    # where the next step's likelihoods alone would keep the far points
    late = np.zeros((B, T), bool)
    late[:, 2] = True
    swapped = score.clone()
    swapped[:, 3, : S // 2] -= 20.0
    a = CandidateFilter(MOTION, k=k, beam=50).run(xy[:, 1:], swapped[:, 1:], late[:, 1:]).smooth()[2]
    b = CandidateFilter(MOTION, k=k, beam=50).run(xy[:, 1:], swapped[:, 1:]).smooth()[2]
    torch.testing.assert_close(a, b, atol=0, rtol=0)
    assert np.linalg.norm(a.numpy() - true[:, 1:], axis=-1).max() < 3.0


def test_blank_steps_are_the_fingerprints_with_no_bit_set():
    from estimation.matching import blank_steps

    bits = np.zeros((2, 3, 4, 5), np.uint8)
    bits[0, 1, 2, 3] = 1
    bits[1, :, 0, 0] = 1
    np.testing.assert_array_equal(blank_steps(bits), [[True, False, True], [False, False, False]])
    np.testing.assert_array_equal(blank_steps(torch.from_numpy(bits).float()), blank_steps(bits))


def test_the_filter_puts_a_vague_first_step_where_the_steps_after_it_lead():
    """An empty first fingerprint: every candidate alike likely and all 200 m away (the matcher
    had no step before to look near). The smoothed estimate of that step is the track's
    extrapolation, its candidates move with it, and a prefix of that step alone is left as is."""
    B, T, S = 2, 6, 10
    true = np.stack([np.stack([4.0 * np.arange(T), 1.5 * np.arange(T)], -1)] * B)
    xy, score = _candidates(B=B, T=T, S=S, seed=3, true=true)
    xy, score = xy.clone(), score.clone()
    xy[:, 0] = torch.from_numpy(true[:, 0] + (150.0, 130.0))[:, None].float() + torch.randn(B, S, 2)
    score[:, 1:] *= 10.0  # informative: tens of nats between the best and the rest
    score[:, 0] = -0.1 * torch.arange(S, dtype=torch.float32)  # within the vague span
    f = CandidateFilter(MOTION, k=S, beam=50).run(xy, score)
    kxy, _, fine = f.smooth()
    # extrapolated from steps 1 and 2 (each smoothed to about a metre): 200 m -> a few metres
    assert np.linalg.norm(fine[:, 0].numpy() - true[:, 0], axis=-1).max() < 4.0
    before, _, fine1 = f.smooth(1)
    moved = fine[:, 0] - fine1[:, 0]
    assert moved.norm(dim=-1).min() > 150.0
    torch.testing.assert_close(kxy[:, 0], before[:, 0] + moved[:, None], atol=1e-3, rtol=0)
    torch.testing.assert_close(kxy[:, 1:], torch.from_numpy(f.cells.points(T)[:, 1:]).float())
