"""Online tracking over fingerprint-match candidates: a filter updated once per fingerprint.

:class:`CandidateFilter` is ``tn-match``'s classical part run forward in time. Each new step's
candidates (the matcher's most likely grid points) go through three stages, each of which reads
only the steps so far:

1. pruning: random-walk filters at walking and driving step scales (:data:`STEP_SIGMAS`) from the
   last step's kept candidates to this step's; the ``k`` best are kept;
2. cells: the constant-velocity model over pairs of kept candidates, a beam of the most likely
   pairs (:mod:`estimation.smoothing.beam`);
3. sub-cells: the ``fine_k`` most likely cells of the step (by stage 2's filtered marginal) split
   into ``n_sub x n_sub`` lattice points, and the same beam over those with the lattice's motion
   table. The smoothed positions give each mode of the split cells its share of the cells'
   smoothed mass at the sub-cell mean within it: the split was chosen before the later steps
   were seen, and the sub-cell beam may have lost a mode the cells keep.

Stages 2 and 3 run once per motion model: with alternative models (``tn-match`` adds the
measured tables' :meth:`~estimation.smoothing.motion.MotionTable.broadened` copy and tables for
steady users at other speeds) each user's result is the models' average weighted by their
evidence so far.

Each update costs the same whatever the number of steps before it and gives the user's current
position (the filtered sub-cell mean). :meth:`CandidateFilter.smooth` turns the stored messages of
any prefix into the smoothed candidates, posteriors and positions the network reads, by one
backward pass: a prefix's result never depends on the steps after it. With an acceleration memory
(:class:`~estimation.smoothing.memory.MotionMemory`) the smoothed sub-cell positions are those of
the smoother one or two orders higher, by importance sampling: paths drawn from each sub-cell beam's
posterior (:func:`~estimation.smoothing.beam.sample_paths`) are weighed by how the memory rates
each acceleration after the one or two before it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from mmwsim._jit import njit
from mmwsim._threads import batch_map

from ..matching import GUIDE
from .beam import (
    MAX_CANDIDATES,
    beam_smooth,
    motion_arrays,
    pair_forward,
    pair_start,
    rw_smooth,
    rw_step,
    sample_paths,
)
from .hmm import LOGP_FLOOR, STEP_SIGMAS
from .memory import MEMORY_PATHS, MEMORY_WEIGHT, MotionMemory, memory_shift
from .motion import SUBCELLS, MixtureMotion, MotionTable

__all__ = [
    "ADAPTED_PRIOR",
    "ALTERNATIVE_PRIOR",
    "BEAM",
    "FILTER_CANDIDATES",
    "FINE_BEAM",
    "FINE_CELLS",
    "MODE_CHAIN",
    "MODE_SHARPEN",
    "VAGUE_GATE",
    "WALKER_SPEED_PRIOR",
    "CandidateFilter",
]

BEAM = 512  # pairs of cell candidates kept per step
FINE_CELLS = 8  # cells per step split into sub-cells (more than the offline smoother's 6: it
# chooses them by the filtered marginal, which knows less than the smoothed one)
FINE_BEAM = 512  # pairs of sub-cell points kept per step
# Split cells within this many grid steps of each other (chained) form one mode of a step's
# sub-cell positions: a mode holds its cells' smoothed mass, placed at the sub-cell beam's mean
# within it (see _mode_means). One step joins neighbours and leaves an alias apart; 1 to 3 steps
# moved all kinds by -0.8 to -0.5 % on the draws they were chosen on (docs/estimation.md).
MODE_CHAIN = 1.0
# The modes' shares of the split cells' mass go as their masses squared: toward the larger mode.
# A track's RMSE is lower at a mode that holds more than half the mass than at the mean of the
# modes, which lies off both; squared shares moved all kinds by -0.3 +- 0.1 % (powers 2 to 8
# alike). Both together: -0.4 % on fresh draws, pedestrians -0.7 % (docs/estimation.md).
MODE_SHARPEN = 2.0
# Candidates per step a grid-reading network's filter carries where the network reads fewer
# (``tn-match`` reads 48): a driver's true cell, 5 to 11 m from the last one, is often ranked
# below the 48th by the pruning's random walks, and the stages after it cannot bring it back.
# 80 took vehicles' error 7 % lower, all kinds 1.4 %; 128 no lower (docs/estimation.md).
FILTER_CANDIDATES = 80
# Prior probability that a user does not move like the training users (the alternative motion
# model): even odds, untuned; priors of 0.1 to 0.3 moved no figure by more than 3 % (docs/estimation.md).
ALTERNATIVE_PRIOR = 0.5
# Prior probability of the walkers' tables at other speeds (CandidateTransformer.fit_walker_speeds),
# beside the alternatives' ALTERNATIVE_PRIOR. On 500 of our own pedestrians per speed and 1000 per
# split of our own: at 0.06 those at 0.8 and 2.2 m/s were tracked 4.7 and 6.9 % better and ours
# 0.6 to 1.5 % worse (a few near aliases, which the broader tables follow); at 0.03, 3.4 and 5.5 %
# better and ours 0.4 to 0.8 % worse (docs/estimation.md).
WALKER_SPEED_PRIOR = 0.06
# Prior of the tables measured on the network's own tracks of a population's unlabelled
# fingerprints (Estimator.adapt_motion), taken from every other hypothesis in proportion, so that
# the measured tables keep their odds against the alternatives. Replacing the measured tables
# instead costs our own vehicles 4.8x (0.09 to 0.42 m: tables measured on estimates blur their
# exact lattice patterns). Taken from the measured tables' prior alone, 0.4 left them 0.04 and cost
# the 2 m demo model's own vehicles 0.16 -> 0.18 m (steady drivers whose ambiguous steps the
# blurred tables took over); taken in proportion they stay at 0.16 m, and the 1 m model's foreign
# sets of benchmarks/foreign_motion.py keep the gain within 0.6 % (docs/estimation.md).
ADAPTED_PRIOR = 0.4
# A step whose candidates' log-likelihoods span less than this says little about where the user
# is. The matcher's guided search looks near the track where its k most likely points lie within
# log(1 + A) of the best (:data:`~estimation.matching.GUIDE`), and then keeps points up to
# log(1 + A) below those: such a step's candidates span less than twice that.
VAGUE_SPAN = 2 * math.log1p(GUIDE[0])
# Metres (plus the track's step length per step between them) a vague step may lie from the
# nearest informative step before it is put on the track of the informative steps around it
# (see :meth:`CandidateFilter.smooth`): far more than the smoothers' errors (a weak first step
# 2 m off is kept), far less than a jump to an alias.
VAGUE_GATE = 10.0


def _log_softmax(x: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.asarray(torch.log_softmax(torch.from_numpy(x), dim=axis))


class _Steps:
    """Per-step arrays of a batch stacked along axis 1 (capacity doubled as steps come): any
    prefix is a view, so a backward pass needs no copy of the steps before it."""

    def __init__(self) -> None:
        self._buf: np.ndarray | None = None
        self.n = 0

    def append(self, x: np.ndarray) -> None:
        if self._buf is None:
            self._buf = np.empty((x.shape[0], 8, *x.shape[1:]), x.dtype)
        elif self.n == self._buf.shape[1]:
            grown = np.empty((x.shape[0], 2 * self.n, *x.shape[1:]), x.dtype)
            grown[:, : self.n] = self._buf
            self._buf = grown
        self._buf[:, self.n] = x
        self.n += 1

    def step(self, t: int) -> np.ndarray:
        """Step ``t`` (negative: from the end), ``(B, ...)`` contiguous."""
        assert self._buf is not None and -self.n <= t < self.n
        return np.ascontiguousarray(self._buf[:, t % self.n])

    def upto(self, T: int) -> np.ndarray:
        """The first ``T`` steps, ``(B, T, ...)``."""
        assert self._buf is not None and T <= self.n
        return self._buf[:, :T]


class _Beam:
    """The stored forward messages of one beam stage (cells or sub-cells) for a batch."""

    def __init__(self, motion: MotionTable | MixtureMotion, beam: int):
        self.m, self.beam = motion_arrays(motion), int(beam)
        # every step's points (B, K, 2) and log likelihoods (B, K), and the kept pairs (pi, ci,
        # la) of steps 1..
        self.xy, self.lp = _Steps(), _Steps()
        self._pairs = [_Steps() for _ in range(3)]
        self.marg: list[np.ndarray] = []  # (B, K) filtered log marginals
        self.evidence: list[np.ndarray] = []  # (B,) log evidence of the steps so far

    def update(self, xy: np.ndarray, lp: np.ndarray) -> np.ndarray:
        """Add a step's points ``xy (B, K, 2)`` and log likelihoods ``lp (B, K)``; returns the
        step's filtered log marginal ``(B, K)``."""
        m, t = self.m, self.xy.n
        if t == 0:
            pairs, marg = None, _log_softmax(lp)
        elif t == 1:
            *pairs, marg = batch_map(
                pair_start,
                4,
                self.xy.step(0),
                xy,
                self.lp.step(0),
                lp,
                self.beam,
                m.step_table,
                m.bin,
                m.place,
            )
        else:
            *pairs, marg = batch_map(
                pair_forward, 7, self.xy.step(-2), self.xy.step(-1), xy, *(p.step(-1) for p in self._pairs), lp,
                self.beam, m.speed_edges, m.headings, m.heading_slopes, m.accel_table, m.bin, m.reach, m.place, m.accel_prob,
                m.accel_max, m.walls,
            )  # fmt: skip
        self.xy.append(xy)
        self.lp.append(lp)
        for stack, x in zip(self._pairs, pairs or (), strict=False):
            stack.append(x)
        self.marg.append(marg)
        # log p(steps so far | motion) up to the beam's pruning (the pair messages are not
        # normalised; the first step's likelihoods are)
        la = pairs[2] if pairs is not None else lp
        self.evidence.append(np.asarray(torch.logsumexp(torch.from_numpy(la), dim=1)))
        return marg

    def points(self, T: int) -> np.ndarray:
        """The first ``T`` steps' points ``(B, T, K, 2)`` (a view)."""
        return self.xy.upto(T)

    def likelihoods(self, T: int) -> np.ndarray:
        """The first ``T`` steps' log likelihoods ``(B, T, K)`` (a view)."""
        return self.lp.upto(T)

    def sample(self, T: int, n: int, rows: np.ndarray | None = None, seed: int = 0) -> np.ndarray:
        """``n`` paths per sequence drawn from the smoothed posterior of the first ``T >= 2``
        steps of the sequences ``rows`` (default all): ``(len(rows), n, T)`` point indices (see
        :func:`sample_paths`)."""
        m = self.m
        arrays = [self.points(T), self.likelihoods(T), *(p.upto(T - 1) for p in self._pairs)]
        if rows is not None:
            arrays = [a[rows] for a in arrays]
        return batch_map(
            sample_paths, 5, *arrays, T, n, seed, m.speed_edges, m.headings, m.heading_slopes,
            m.accel_table, m.bin, m.reach, m.place, m.accel_prob, m.walls,
        )  # fmt: skip

    def smooth(self, lengths: list[int]) -> list[np.ndarray]:
        """Smoothed log marginals ``(B, T, K)`` of the first ``T`` steps given those ``T`` steps,
        for each ``T`` in ``lengths``."""
        return self.smooth_and_sample(lengths)[0]

    def smooth_and_sample(
        self, lengths: list[int], draw: np.ndarray | None = None, n: int = 0, seed: int = 0
    ) -> tuple[list[np.ndarray], list[np.ndarray | None]]:
        """:meth:`smooth`, and for each ``T`` in ``lengths`` the paths :meth:`sample` draws for
        the sequences ``draw[:, i]`` (``draw (B, len(lengths))`` bool, default none): ``(rows, n,
        T)`` point indices (None where ``T == 1`` or ``draw`` is None), with the work the
        backward passes and the draws share done once."""
        out: list[np.ndarray | None] = [self.marg[0][:, None] if T == 1 else None for T in lengths]
        drawn: list[np.ndarray | None] = [None] * len(lengths)
        longer = [i for i, T in enumerate(lengths) if T > 1]
        if longer:
            m, T_max = self.m, max(lengths[i] for i in longer)
            pi, ci, la = (p.upto(T_max - 1) for p in self._pairs)
            each = np.array([lengths[i] for i in longer], np.int64)
            pick = np.zeros((len(pi), 0), bool) if draw is None else np.asarray(draw, bool)[:, longer]
            rows, paths = batch_map(
                beam_smooth, 6, self.points(T_max), self.likelihoods(T_max), pi, ci, la, pick, each, int(n),
                int(seed), m.speed_edges, m.headings, m.heading_slopes, m.accel_table, m.bin, m.reach, m.place,
                m.accel_prob, m.accel_max - m.accel_min, m.walls,
            )  # fmt: skip
            parts = iter(np.split(rows, np.cumsum(each)[:-1], axis=1))
            out = [next(parts) if o is None else o for o in out]
            if draw is not None:
                # the paths lie sequence by sequence, each one's prefixes in turn
                size = pick * (int(n) * each)
                first = (np.cumsum(size.ravel()) - size.ravel()).reshape(size.shape)
                for c, i in enumerate(longer):
                    who = np.flatnonzero(pick[:, c])
                    at = first[who, c][:, None] + np.arange(int(n) * lengths[i])
                    drawn[i] = paths[at].reshape(len(who), int(n), lengths[i])
        return out, drawn  # type: ignore[return-value]


def _vague_shift(pos: np.ndarray, vague: np.ndarray, gate: float = VAGUE_GATE) -> np.ndarray:
    """``(B, T, 2)`` metres that put each vague step on the track of the informative steps around
    it where it lies farther from the nearest of them than ``gate`` metres plus the track's step
    length (at least the user's median step) per step between them; zero elsewhere.

    A fingerprint that says little (empty where a user enters a coverage gap) has thousands of
    equally likely points; where the steps before it do not say where to look (it comes first, or
    the user is faster than they predict), its candidates may all be far from the user, and the
    smoother, which weighs only those, puts the step there whatever the steps around it say. Such
    a step's candidates are interchangeable, so its estimate is where the motion puts it: at
    constant velocity between the nearest informative steps before and after it, or extrapolated
    from the two at the end it has. ``pos (B, T, 2)`` are the smoothed positions, ``vague (B, T)``
    bool."""
    B, T = vague.shape
    shift = np.zeros_like(pos)
    users, t = np.nonzero(vague)
    if not len(users):
        return shift
    steps = np.arange(T)
    before = np.maximum.accumulate(np.where(vague, -1, steps), axis=1)[users, t]
    after = np.minimum.accumulate(np.where(vague, T, steps)[:, ::-1], axis=1)[:, ::-1][users, t]
    has_b, has_a = before >= 0, after < T
    b, a = np.clip(before, 0, T - 1), np.clip(after, 0, T - 1)
    pb, pa = pos[users, b], pos[users, a]
    # velocity: between the two anchors, else from the anchor's neighbour on its far side
    both = (pa - pb) / np.maximum(a - b, 1)[:, None]
    lead = pos[users, np.minimum(a + 1, T - 1)] - pa
    trail = pb - pos[users, np.maximum(b - 1, 0)]
    v = np.where((has_b & has_a)[:, None], both, np.where(has_a[:, None], lead, trail))
    target = np.where(has_b[:, None], pb + (t - b)[:, None] * v, pa - (a - t)[:, None] * v)
    # Off: farther from the nearest informative step than the track's speed reaches (plus the
    # gate), which no turn explains; a turning user may lie far off the chord, never that far.
    near_b = has_b & (~has_a | (t - b <= a - t))
    away = np.where(near_b, t - b, a - t)
    anchor = np.where(near_b[:, None], pb, pa)
    # the track's speed: its own between the anchors, at least the user's median step (robust to
    # the jumps sought; where one anchor has no neighbour, v is zero)
    median = np.median(np.linalg.norm(np.diff(pos, axis=1), axis=-1), axis=1) if T > 1 else np.zeros(B)
    reach = gate + away * np.maximum(np.linalg.norm(v, axis=1), median[users])
    off = np.linalg.norm(pos[users, t] - anchor, axis=1) > reach
    sel = off & (has_b | has_a)
    shift[users[sel], t[sel]] = target[sel] - pos[users[sel], t[sel]]
    return shift


class _Hypothesis:
    """One motion model's cell and sub-cell beams over the shared candidates."""

    def __init__(
        self, motion: MotionTable | MixtureMotion, motion_fine: MotionTable | None, beam: int, fine_beam: int
    ):
        self.cells = _Beam(motion, beam)
        fitted = motion_fine is not None and bool(motion_fine.fitted)
        self.fine = _Beam(motion_fine, fine_beam) if fitted else None
        self.top: list[np.ndarray] = []  # (B, fine_k) cells split at every step
        self.remembers = True  # whether the acceleration memory weighs its sub-cell paths


_Models = tuple[MotionTable | MixtureMotion, MotionTable | None]  # a cell-level and a sub-cell model


def _log_priors(prior: float | Sequence[float], n: int) -> np.ndarray:
    """Log prior ``(1 + n,)`` of the measured model and ``n`` alternatives whose prior is
    ``prior``: one probability shared evenly, or one per alternative."""
    each = np.asarray(prior, dtype=np.float64)
    if each.ndim == 0:
        shared = float(each)
        if not 0.0 < shared < 1.0:
            raise ValueError(f"the alternative model's prior must lie in (0, 1), got {prior}")
        return np.log([1.0 - shared] + [shared / n] * n)
    if each.shape != (n,) or not (np.isfinite(each).all() and (each > 0).all() and each.sum() < 1.0):
        raise ValueError(
            f"the alternatives' priors must be {n} probabilities above 0 summing to less than 1, got {prior!r}"
        )
    return np.log(np.r_[1.0 - each.sum(), each])


class CandidateFilter:
    """Forward filter (and prefix smoother) over per-step match candidates of a batch of users.

    With ``alternative`` motion models the filter runs every model over the same candidates and
    averages them by their evidence: each user's track is the mixture of the models' results,
    weighted by ``p(model | fingerprints so far)``. A user who moves like the training users keeps
    the measured model's sharp prior; one who does not moves over to an alternative: the broad
    one (:meth:`MotionTable.broadened`) for sharp turns and unsteady speeds, one measured on the
    training trajectories at other speeds (:func:`~estimation.smoothing.motion.speed_scaled`) or
    the speed-pooled one (:meth:`MotionTable.speed_pooled`) for steady driving at speeds the
    training users kept off.

    Parameters
    ----------
    motion : MotionTable or MixtureMotion
        Cell-level motion model, metres.
    motion_fine : MotionTable, optional
        Sub-cell motion model in grid units (:meth:`MotionTable.lattice`); without it (or unfitted)
        the positions are the cell-level posterior means.
    spacing : float, metres
        Grid spacing.
    k : int
        Candidates kept per step.
    beam, fine_beam : int
        Pairs kept per step by the cell and sub-cell stages.
    fine_k : int
        Cells per step split into sub-cells.
    n_sub : int
        Sub-cells per axis.
    alternative : (MotionTable, MotionTable or None), or a list of them, optional
        Other cell-level and sub-cell motion models, as ``motion`` and ``motion_fine``.
    alternative_prior : float or sequence of float
        Prior probability that a user moves by one of the alternatives, in (0, 1), shared
        evenly among them; or one prior per alternative, each above 0, summing to less than 1.
        The measured model has the rest.
    fine_weighed : sequence of int
        Indices into ``alternative`` of models told from the measured one by their sub-cell
        evidence: the cell-level evidence gives these and the measured model their joint weight,
        their sub-cell evidence (with their priors) shares it out. For a model whose sub-cell
        table is what sets it apart (the speed-scaled one: at the cell level a steady user at a
        speed between the training users' is as likely under either). Each needs a fitted
        sub-cell table, as does the measured model.
    vague_gate : float or None
        Metres (plus the track's step length per step) a step whose fingerprint says little may
        lie from the nearest informative step before :meth:`smooth` puts it on their track
        (default :data:`VAGUE_GATE`; None: never).
    memory : MotionMemory, optional
        The measured dependence of an acceleration on the one or two before it (fitted; default none):
        :meth:`smooth` then weighs ``memory_paths`` paths drawn from each sub-cell beam's
        smoothed posterior by it and moves the sub-cell means by the difference between the
        weighted and the plain mean of the paths (the smoother one or two orders higher, by importance
        sampling with the plain mean as control variate).
    memory_paths : int
        Paths drawn per user, prefix and motion model.
    memory_skips : sequence of int
        Indices into ``alternative`` of models whose paths the memory does not weigh: motion at
        speeds the training users did not keep (the speed-scaled tables), whose lattice
        patterns the memory, measured at the training users' speeds, never saw.
    mode_chain : float
        Grid steps (default :data:`MODE_CHAIN`): split cells this close, or chained by such
        links, are one mode of a step; :meth:`smooth` gives each mode a share of the split
        cells' smoothed mass by its own (:data:`MODE_SHARPEN`) at the sub-cell mean within it, for
        users whose median step is no longer than the cell model's place table's speed.
        ``math.inf``: one mode, the sub-cell beam's mean over all split cells.
    """

    def __init__(
        self,
        motion: MotionTable | MixtureMotion,
        motion_fine: MotionTable | None = None,
        spacing: float = 1.0,
        k: int = 48,
        beam: int = BEAM,
        fine_k: int = FINE_CELLS,
        fine_beam: int = FINE_BEAM,
        n_sub: int = SUBCELLS,
        alternative: _Models | list[_Models] | None = None,
        alternative_prior: float | Sequence[float] = ALTERNATIVE_PRIOR,
        vague_gate: float | None = VAGUE_GATE,
        fine_weighed: tuple[int, ...] = (),
        memory: MotionMemory | None = None,
        memory_paths: int = MEMORY_PATHS,
        memory_skips: tuple[int, ...] = (),
        mode_chain: float = MODE_CHAIN,
    ):
        self.k, self.fine_k, self.spacing = int(k), int(fine_k), float(spacing)
        if not mode_chain >= 0:
            raise ValueError(f"mode_chain must be >= 0 grid steps, got {mode_chain}")
        self.mode_chain = float(mode_chain)
        if max(self.k, self.fine_k * int(n_sub) ** 2) > MAX_CANDIDATES:
            raise ValueError(
                f"k = {k} candidates and fine_k * n_sub^2 = {fine_k * n_sub**2} lattice points: a beam "
                f"indexes at most {MAX_CANDIDATES} per step"
            )
        self.vague_gate = vague_gate
        self.memory = memory if memory is not None and bool(memory.fitted) else None
        if memory_paths < 1:
            raise ValueError(f"memory_paths must be >= 1, got {memory_paths}")
        self.memory_paths = int(memory_paths)
        self._models = [_Hypothesis(motion, motion_fine, beam, fine_beam)]
        alternatives = [alternative] if isinstance(alternative, tuple) else list(alternative or [])
        if alternatives:
            self._models += [_Hypothesis(*a, beam, fine_beam) for a in alternatives]
            self._log_prior = _log_priors(alternative_prior, len(alternatives))
        else:
            self._log_prior = np.zeros(1)
        picked = [int(i) for i in fine_weighed]
        if any(not 0 <= i < len(alternatives) for i in picked):
            raise ValueError(
                f"fine_weighed {tuple(fine_weighed)}: indices into the {len(alternatives)} alternatives"
            )
        self._fine_group = [0] + [1 + i for i in picked] if picked else []
        skips = [int(i) for i in memory_skips]
        if any(not 0 <= i < len(alternatives) for i in skips):
            raise ValueError(
                f"memory_skips {tuple(memory_skips)}: indices into the {len(alternatives)} alternatives"
            )
        for i in skips:
            self._models[1 + i].remembers = False
        if any(self._models[i].fine is None for i in self._fine_group):
            raise ValueError(
                f"fine_weighed {tuple(fine_weighed)}: every model weighed by its sub-cell evidence, "
                "and the measured one, needs a fitted sub-cell table"
            )
        off = (np.arange(n_sub) - (n_sub - 1) / 2) / n_sub
        self._offsets = np.stack(np.meshgrid(off, off, indexing="ij"), -1).reshape(-1, 2)
        self._inv_two_s2 = np.array([0.5 / s**2 for s in STEP_SIGMAS])
        self._rw: np.ndarray | None = None  # (B, k, n_s) filtered random-walk posteriors
        self._blank: np.ndarray | None = None  # (B,) bool: every fingerprint so far had no bit set
        self.positions: list[np.ndarray] = []  # (B, 2) filtered estimate of every step
        self.vague: list[np.ndarray] = []  # (B,) bool per step: its fingerprint says little

    @property
    def cells(self) -> _Beam:
        """The (first) motion model's cell beam."""
        return self._models[0].cells

    @property
    def steps(self) -> int:
        """Steps seen so far."""
        return len(self.positions)

    def model_weights(self, T: int | None = None) -> np.ndarray:
        """``(B, n_models)`` posterior probability of each motion model (the measured one first)
        given the first ``T`` steps (default all)."""
        T = self.steps if T is None else int(T)
        ev = np.stack([h.cells.evidence[T - 1] for h in self._models], -1) + self._log_prior
        w = np.asarray(torch.softmax(torch.from_numpy(ev), dim=-1))
        g = self._fine_group
        if g:
            fine = np.stack([self._models[i].fine.evidence[T - 1] for i in g], -1) + self._log_prior[g]
            w[:, g] = w[:, g].sum(1, keepdims=True) * np.asarray(
                torch.softmax(torch.from_numpy(fine), dim=-1)
            )
        return w

    def update(
        self, xy: torch.Tensor | np.ndarray, score: torch.Tensor | np.ndarray, blank: np.ndarray | None = None
    ) -> np.ndarray:
        """Add one step: the matcher's candidates ``xy (B, S, 2)`` metres and their
        log-likelihoods ``score (B, S)`` (as :meth:`FingerprintMatcher.track_candidates` gives
        them), and optionally ``blank (B,)`` bool, whose fingerprints had no bit set. Returns the
        users' current positions ``(B, 2)`` float64 metres."""
        xy = np.asarray(xy, dtype=np.float64)
        score = np.asarray(score, dtype=np.float64)
        lp = _log_softmax(score)
        if self.steps and xy.shape[0] != (n := len(self.cells.xy.upto(1))):
            raise ValueError(f"a step of {xy.shape[0]} users after steps of {n}")
        if self._rw is None:
            rw = np.repeat(lp[..., None], len(self._inv_two_s2), -1)
        else:
            rw = batch_map(rw_step, 4, self.cells.xy.step(-1), self._rw, xy, lp, self._inv_two_s2)
            # A fingerprint with no bit set has thousands of equally likely points, and the kept
            # ones are any of them: walks from them would keep this step's candidates near those,
            # so a user whose fingerprints then place it well would lose every point near it. After
            # nothing but such steps, a step keeps its candidates as a first step does.
            if self._blank is not None:
                rw[self._blank] = lp[self._blank, :, None]
        if self._rw is None:
            self._blank = None if blank is None else np.array(blank, dtype=bool)
        elif self._blank is not None:
            self._blank = None if blank is None else self._blank & np.asarray(blank, dtype=bool)
        # A stable sort keeps ties in the matcher's order, so the result does not depend on the batch.
        keep = np.argsort(-rw.max(-1), axis=1, kind="stable")[:, : self.k]
        kxy = np.take_along_axis(xy, keep[..., None], 1)
        klp = np.take_along_axis(lp, keep, 1)
        self._rw = _log_softmax(np.take_along_axis(rw, keep[..., None], 1), axis=1)
        per_model = []
        for h in self._models:
            marg = h.cells.update(kxy, klp)
            if h.fine is None:
                per_model.append((np.exp(marg)[..., None] * kxy).sum(1))
            else:
                fxy, flp = self._subcells(h, kxy, klp, marg)
                per_model.append((np.exp(h.fine.update(fxy, flp))[..., None] * fxy).sum(1) * self.spacing)
        w = self.model_weights(len(self.positions) + 1)
        pos = sum(w[:, i, None] * p for i, p in enumerate(per_model))
        self.positions.append(pos)
        self.vague.append(score.max(1) - score.min(1) < VAGUE_SPAN)
        return pos

    def run(
        self, xy: torch.Tensor | np.ndarray, score: torch.Tensor | np.ndarray, blank: np.ndarray | None = None
    ) -> CandidateFilter:
        """:meth:`update` with every step of ``xy (B, T, S, 2)`` metres, ``score (B, T, S)`` and
        ``blank (B, T)`` (optional) in turn; returns ``self``."""
        for t in range(xy.shape[1]):
            self.update(xy[:, t], score[:, t], None if blank is None else blank[:, t])
        return self

    def _subcells(
        self, h: _Hypothesis, kxy: np.ndarray, klp: np.ndarray, marg: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``fine_k`` best cells by ``marg`` as lattice points ``(B, fine_k n_sub^2, 2)`` grid
        units with their cells' log likelihoods."""
        top = np.argsort(-marg, axis=1, kind="stable")[:, : self.fine_k]
        h.top.append(top)
        cxy = np.take_along_axis(kxy, top[..., None], 1) / self.spacing
        clp = np.take_along_axis(klp, top, 1)
        B, n = cxy.shape[0], len(self._offsets)
        fxy = (cxy[:, :, None] + self._offsets).reshape(B, cxy.shape[1] * n, 2)
        return fxy, np.repeat(clp, n, axis=1)

    def _memory_shift(
        self, fine: _Beam, T: int, rows: np.ndarray, idx: np.ndarray | None = None
    ) -> np.ndarray:
        """``(B, T, 2)`` grid units: for the users ``rows``, the mean of a sub-cell beam's paths
        weighed by the memory less their plain mean (see
        :class:`~estimation.smoothing.memory.MotionMemory`); zero for the others. ``idx
        (len(rows), memory_paths, T)``: those paths where already drawn (default: drawn here)."""
        assert self.memory is not None
        xy = fine.points(T)
        out = np.zeros((xy.shape[0], T, 2))
        if len(rows):
            if idx is None:
                idx = fine.sample(T, self.memory_paths, rows)
            mem = self.memory
            # the tables as stored (float32, no copy): the kernel sums them in float64
            out[rows] = batch_map(
                memory_shift, 2, xy[rows], idx, mem.log_ratio.numpy(), mem.log_ratio_two.numpy(),
                mem.n_sub, mem.edges.numpy(), mem.reach,
            )  # fmt: skip
        return out

    def smooth(self, T: int | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """What the network reads for the first ``T`` steps (default all), given only those.

        Returns
        -------
        xy : (B, T, k, 2) float32, metres; the kept candidates (those of a vague step that the
            motion puts elsewhere moved with its estimate, see ``fine``)
        post : (B, T, k, 2 + len(STEP_SIGMAS)) float32
            Step-wise log posterior under a flat prior, the smoothed random-walk posteriors at
            each step scale, then the smoothed constant-velocity posterior (averaged over the
            motion models); clipped at -30.
        fine : (B, T, 2) float32, metres; smoothed positions (sub-cell posterior means, moved by
            the acceleration memory where there is one and ``T >= 4``). A step whose
            fingerprint says little and which lies farther than ``vague_gate`` metres (plus the
            track's step length per step) from the nearest informative step is put on the track
            of the informative steps around it.
        """
        return self.smooth_prefixes([self.steps if T is None else int(T)])[0]

    def smooth_prefixes(self, lengths: list[int]) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """:meth:`smooth` of the first ``T`` steps for each ``T`` in ``lengths`` (as evaluation
        runs every prefix): the same results, with the work the prefixes share done once."""
        lengths = [int(T) for T in lengths]
        for T in lengths:
            if not 1 <= T <= self.steps:
                raise ValueError(f"can smooth 1..{self.steps} steps, not {T}")
        weights = [self.model_weights(T) for T in lengths]
        per_model = [
            self._smooth_one(h, lengths, [w[:, i] for w in weights]) for i, h in enumerate(self._models)
        ]
        # the random walks read the candidates as the network does (float32)
        T_max = max(lengths)
        walks = batch_map(
            rw_smooth, 2, self.cells.points(T_max).astype(np.float32).astype(np.float64),
            self.cells.likelihoods(T_max).astype(np.float32).astype(np.float64), self._inv_two_s2,
            np.array(lengths, np.int64),
        ).astype(np.float32)  # fmt: skip
        starts = np.cumsum([0, *lengths])
        out = []
        for n, T in enumerate(lengths):
            xy = torch.from_numpy(self.cells.points(T)).float()
            lp = torch.from_numpy(self.cells.likelihoods(T)).float()
            w = torch.from_numpy(weights[n])[:, None, None]  # (B, 1, 1, n_models)
            p = torch.zeros(xy.shape[:3], dtype=torch.float64)
            fine = torch.zeros(xy.shape[0], T, 2, dtype=torch.float64)
            for i, one in enumerate(per_model):
                pi, fi = one[n]
                p += w[..., i] * pi
                fine += w[..., i] * fi
            cv = p.log().clamp(min=-1e300).float()
            walk = torch.from_numpy(walks[:, starts[n] : starts[n] + T])
            post = torch.cat([lp[..., None], walk, cv[..., None]], -1)
            if self.vague_gate is not None:
                shift = _vague_shift(fine.numpy(), np.stack(self.vague[:T], 1), self.vague_gate)
                xy, fine = xy + torch.from_numpy(shift)[:, :, None].float(), fine + torch.from_numpy(shift)
            out.append((xy, post.clamp(min=LOGP_FLOOR), fine.float()))
        return out

    def _smooth_one(
        self, h: _Hypothesis, lengths: list[int], weight: list[np.ndarray]
    ) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """One motion model's smoothed cell marginals ``(B, T, k)`` and positions ``(B, T, 2)``
        metres, float64, for each prefix length ``T`` in ``lengths``, given its posterior weight
        ``(B,)`` for each (the memory moves only the users it counts for)."""
        cells = h.cells.smooth(lengths)
        # the users whose paths the memory weighs (see _memory_shift), drawn with the smoothing
        remember = self.memory is not None and h.remembers
        draw = np.stack([w >= MEMORY_WEIGHT for w in weight], 1) & (remember & (np.array(lengths) >= 4))
        if h.fine is not None:
            fines, paths = h.fine.smooth_and_sample(lengths, draw if draw.any() else None, self.memory_paths)
        else:
            fines = None
        out = []
        for n, T in enumerate(lengths):
            xy = torch.from_numpy(h.cells.points(T)).float().double()  # as the network reads them
            p = torch.softmax(torch.from_numpy(cells[n]), -1)
            if fines is None:
                out.append((p, (p[..., None] * xy).sum(2)))
                continue
            # The sub-cells are the conditional mean given the cells split at each step, which
            # were chosen before the later steps were seen; the smoothed mass of the other cells
            # (an alias the first fingerprint preferred, say) keeps its cell-level mean.
            w = np.exp(fines[n])
            shift = np.zeros((len(w), T, 2))
            if remember and T >= 4:
                shift = self._memory_shift(h.fine, T, np.flatnonzero(draw[:, n]), paths[n])
            top = np.stack(h.top[:T], 1)
            inside = torch.zeros_like(p).scatter_(2, torch.from_numpy(top), 1.0)
            rest = ((p * (1 - inside))[..., None] * xy).sum(2)
            sub = ((w[..., None] * h.fine.points(T)).sum(2) + shift) * self.spacing
            whole = (p * inside).sum(-1, keepdim=True) * torch.from_numpy(sub) + rest
            # A sub-cell path must pass a split cell at every step: where one step's split left
            # out the cell of a mode the later steps favour, the sub-cell beam loses that mode
            # although the cells keep it. Its mass then stays with the mode, not with the other's
            # mean. Drivers (a median step longer than the place tables' speed) keep the sub-cell
            # beam's split between modes: their lanes make it the sharper.
            if math.isinf(self.mode_chain):
                out.append((p, whole))
                continue
            chain = self.mode_chain * self.spacing
            modes = torch.from_numpy(
                _mode_means(
                    p.numpy(), xy.numpy(), top, w, h.fine.points(T), shift, self.spacing, chain, MODE_SHARPEN
                )
            )
            # the median step: a driver that stops is still a driver, a walker whose mean jumps
            # between modes once is still a walker (one step: no driver); the place tables' speed
            # is the measured model's, metres per step
            steps = (whole[:, 1:] - whole[:, :-1]).norm(dim=-1)
            median = steps.median(-1).values if T > 1 else torch.zeros(len(whole), dtype=steps.dtype)
            fast = median > float(self.cells.m.place[0])
            out.append((p, torch.where(fast[:, None, None], whole, modes + rest)))
        return out


def _mode_means(
    p: np.ndarray,
    xy: np.ndarray,
    top: np.ndarray,
    w: np.ndarray,
    points: np.ndarray,
    shift: np.ndarray,
    spacing: float,
    chain: float,
    sharpen: float = 1.0,
) -> np.ndarray:
    """The smoothed mass of the split cells, each mode's at the sub-cell beam's mean within it.

    Parameters
    ----------
    p : (B, T, K) smoothed cell marginals.
    xy : (B, T, K, 2) the cells, metres.
    top : (B, T, F) the cells split at each step (indices into ``K``).
    w : (B, T, F n) smoothed sub-cell marginals, ``n`` lattice points per split cell in the order
        of ``top``.
    points : (B, T, F n, 2) those lattice points, grid units.
    shift : (B, T, 2) grid units added to every sub-cell mean (the acceleration memory's).
    spacing : the grid step, metres.
    chain : metres; split cells this close are one mode, and so are cells chained by such links.
    sharpen : each mode's share of the split cells' mass goes as its mass to this power (1: as
        it is).

    Returns
    -------
    (B, T, 2) metres: the sum over modes of the mode's share times its sub-cell mean; a mode
    where the sub-cell beam holds no mass stands at its cells' mean position.
    """
    p, xy, w, points, shift = (np.asarray(a, np.float64) for a in (p, xy, w, points, shift))
    top = np.asarray(top, np.int64)
    return _mode_means_kernel(
        p, xy, top, w, points, shift, float(spacing), float(chain) * (1 + 1e-6), float(sharpen)
    )


@njit(cache=True, nogil=True)
def _mode_means_kernel(p, xy, top, w, points, shift, spacing, chain, sharpen):
    B, T, F = top.shape
    n = w.shape[2] // F
    out = np.zeros((B, T, 2))
    label = np.empty(F, np.int64)
    acc = np.zeros((F, 6))
    for b in range(B):
        for t in range(T):
            # the smallest split cell each one reaches through links of at most `chain`
            for i in range(F):
                label[i] = i
            changed = True
            while changed:
                changed = False
                for i in range(F):
                    xi, yi = xy[b, t, top[b, t, i], 0], xy[b, t, top[b, t, i], 1]
                    for j in range(F):
                        if label[j] < label[i]:
                            dx, dy = xy[b, t, top[b, t, j], 0] - xi, xy[b, t, top[b, t, j], 1] - yi
                            if dx * dx + dy * dy <= chain * chain:
                                label[i] = label[j]
                                changed = True
            # per mode: cell mass, cells' mass-weighted x and y, sub-cell mass, its weighted x and y
            total = norm = 0.0
            for m in range(F):
                acc[m, :] = 0.0
                if label[m] != m:
                    continue
                for i in range(F):
                    if label[i] == m:
                        c = top[b, t, i]
                        acc[m, 0] += p[b, t, c]
                        acc[m, 1] += p[b, t, c] * xy[b, t, c, 0]
                        acc[m, 2] += p[b, t, c] * xy[b, t, c, 1]
                        for j in range(i * n, (i + 1) * n):
                            acc[m, 3] += w[b, t, j]
                            acc[m, 4] += w[b, t, j] * points[b, t, j, 0]
                            acc[m, 5] += w[b, t, j] * points[b, t, j, 1]
                total += acc[m, 0]
                norm += acc[m, 0] ** sharpen
            for m in range(F):
                mass = acc[m, 0]
                if label[m] != m or mass <= 0.0:
                    continue
                share = total * mass**sharpen / norm
                if acc[m, 3] > 1e-12:  # at the sub-cell mean
                    x = (acc[m, 4] / acc[m, 3] + shift[b, t, 0]) * spacing
                    y = (acc[m, 5] / acc[m, 3] + shift[b, t, 1]) * spacing
                else:  # a mode the sub-cell beam lost: at its cells' mean
                    x, y = acc[m, 1] / mass, acc[m, 2] / mass
                out[b, t, 0] += share * x
                out[b, t, 1] += share * y
    return out
