"""Transformer over fingerprint-match candidates (``tn-match``): our model, beyond the paper.

The paper's transformer (``tn``) must learn the whole map from fingerprints to positions from the
training trajectories, so it cannot place a user in a region no training trajectory visited. This
model reads the data set's grid instead: for every step the exact fingerprint likelihood
(:class:`~estimation.matching.FingerprintMatcher`) proposes its ``K`` most likely grid points, and a
transformer encoder attends over all candidates of all steps to pick the ones that form a plausible
motion. Each step's estimate is a convex combination of that step's candidates, so the model only
sees relative geometry and likelihoods: the network is translation invariant and does not depend on
where the training trajectories ran. One prior does: the motion tables' place table, where training
users faster than :data:`~estimation.smoothing.motion.PLACE_SPEED` went (their lanes); elsewhere
(a region no training vehicle entered) it is flat and the smoother is as translation invariant.

Its features are the hidden-Markov posteriors (random walk, then constant velocity over the pruned
candidates) as the online candidate filter gives them
(:class:`~estimation.smoothing.online.CandidateFilter`, :meth:`Estimator.inputs`), with motion statistics
(:class:`~estimation.smoothing.motion.MotionTable`) measured on the training trajectories and saved
with the network. The sub-cell smoother's estimate (:func:`~estimation.smoothing.hmm.subcell_mean`)
is the network's starting point; the network moves it toward its own weighting of the candidates
where it learned to trust that.

For forecasting, the tracked positions of the observed steps are carried on at their last velocity
(:func:`~estimation.smoothing.forecast.extrapolate`); training then fits the tracker to what makes
good forecasts.
"""

from __future__ import annotations

import copy
import warnings

import numpy as np
import torch
from torch import nn

from mmwsim.trajectories.motion import KINDS

from ..smoothing.forecast import extrapolate
from ..smoothing.hmm import STEP_SIGMAS, cell_mean, subcell_mean
from ..smoothing.memory import MotionMemory
from ..smoothing.motion import (
    PLACE_SPEED,
    SUBCELLS,
    WALK_COPIES,
    WALK_SCALES,
    MotionTable,
    snap_to_lattice,
    speed_scaled,
)
from .embedding import sinusoidal_encoding
from .encoder import encode

__all__ = [
    "KIND_TABLE",
    "KIND_TABLE_MIN",
    "NET_REACH",
    "WALKER_KINDS",
    "CandidateTransformer",
    "grid_spacing",
]

_SCALE = 32.0  # metres; relative candidate offsets are divided by this
# The kind whose own motion tables the filter weighs as one more alternative: cyclists, whose
# stops, restarts and turns at 3.4 m/s the tables pooled over every kind drown among the
# pedestrians' and the vehicles' (docs/estimation.md: tables of the other kinds too gained them
# 0.5 to 1.6 % for two more hypotheses, each one more beam per stage).
KIND_TABLE = "hybrid"
KIND_TABLE_MIN = 20  # trajectories of that kind below which its tables are not measured
# The kinds whose trajectories at other speeds make the walkers' alternative tables
# (CandidateTransformer.fit_walker_speeds): people on foot keep their paths' shapes at other paces,
# which the tables measured at the training pedestrians' speeds (1.1 to 1.7 m/s) mark as speeding
# up or slowing down at every step. Not cyclists: scaled up to 6 m/s they explained a vehicle at
# 5.3 m per step by a track 8 m off it, and our own test vehicles' error rose by 3.7 %. Nor as a
# hypothesis of their own (scaled by 1.25 to 1.8, at a prior of 0.03 or 0.06, with or without the
# place table): our cyclists at 6 m/s 0.634 -> 0.551 to 0.559 m, but one of 300 of our test
# vehicles, driving at 5.3 m/s, went from 0.14 to 1.94 m (all of them +6 %); without the sub-cell
# table the cyclists kept a quarter of the gain, the vehicle its error.
WALKER_KINDS = ("pedestrian",)
NET_REACH = 10.0
"""Grid spacings the network may move a step of the classical estimate by. Its moves are local
corrections (on 34 356 steps of validation users of ``default.zarr``, 99.9 % under 1.22 m and 6
between 3 and 10 m); a move of more is its weighting of the candidates gone to an alias far away
(24 to 73 m, 3 of those steps), and there the classical estimate stands. At 3 spacings the
vehicles' error rose by up to 5 %."""


def grid_spacing(grid_xy: np.ndarray) -> float:
    """The spacing (metres) of the grid holding the points ``grid_xy (G, 2)`` metres: the
    frame :meth:`CandidateTransformer.fit_motion` measures its tables in (1 for a single column)."""
    steps = np.diff(np.unique(np.asarray(grid_xy, dtype=np.float64)[:, 0]))
    return float(steps.min()) if len(steps) else 1.0


def _place_frames(grid_xy: np.ndarray) -> tuple[np.ndarray, float, tuple, tuple]:
    """The first grid point ``(2,)`` metres and the spacing (metres) of the grid holding
    ``grid_xy (G, 2)``, and the place tables' frames ``(origin, res, shape)`` on it: the cell
    table's (metres, one cell per grid point) and the sub-cell lattice table's (grid units)."""
    spacing = grid_spacing(grid_xy)
    lo = grid_xy.min(0)
    cells = np.rint((grid_xy.max(0) - lo) / spacing).astype(int) + 1  # grid points per axis
    cell = (lo - spacing / 2, spacing, tuple(cells))
    fine = (lo / spacing - 0.5, 1.0 / SUBCELLS, tuple(cells * SUBCELLS))
    return lo, spacing, cell, fine


def _table_pair(u: np.ndarray, lo: np.ndarray, spacing: float) -> tuple[MotionTable, MotionTable]:
    """Both smoothers' tables, no place table, measured on trajectories ``u (n, L >= 3, 2)`` in
    grid units from the first grid point ``lo (2,)`` metres of a grid of ``spacing`` metres: the
    cell table on their nearest grid points, the sub-cell table on the lattice."""
    return MotionTable().fit(lo + np.rint(u) * spacing), MotionTable.lattice().fit(snap_to_lattice(u))


class CandidateTransformer(nn.Module):
    """Candidates of every step in, positions ``(B, T, 2)`` in metres out (forecasting: the
    ``(B, horizon, 2)`` positions after the last step).

    Parameters
    ----------
    search : int
        Candidates per step proposed by the matcher and smoothed (:func:`candidate_features`).
    k : int
        Candidates per step the transformer attends over.
    d, heads, layers, ff : transformer width, heads, encoder layers, feed-forward width.
    dropout : float
    task : ``"tracking"`` or ``"forecasting"``
    horizon : int
        Forecasting: steps predicted after the last observed one.
    """

    def __init__(
        self,
        search: int = 256,
        k: int = 48,
        d: int = 64,
        heads: int = 2,
        layers: int = 2,
        ff: int = 128,
        dropout: float = 0.01,
        task: str = "tracking",
        horizon: int = 1,
    ):
        super().__init__()
        if not 1 <= k <= search:
            raise ValueError(f"need 1 <= k <= search (got k={k}, search={search})")
        self.task, self.horizon = task, int(horizon)
        self.search, self.k, self.d = int(search), int(k), int(d)
        n_post = 2 + len(STEP_SIGMAS)
        self.embed = nn.Sequential(nn.Linear(4 + n_post, d), nn.ReLU(), nn.Linear(d, d))
        self.rank = nn.Embedding(self.k, d)
        layer = nn.TransformerEncoderLayer(d, heads, ff, dropout, batch_first=True)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="enable_nested_tensor is True")
            self.encoder = nn.TransformerEncoder(layer, layers)
        # No dropout on the attention weights (the residual and feed-forward paths keep theirs):
        # with it, training's attention cannot run fused and materialises every batch's 336 x 336
        # weights per head, which doubled the time of a training step.
        for enc_layer in self.encoder.layers:
            enc_layer.self_attn.dropout = 0.0
        self.logit = nn.Linear(d, 1)
        self.offset = nn.Linear(d, 2)
        self.gate = nn.Linear(d, 1)
        # Measured on the training trajectories by estimation.train (fit_motion).
        self.motion = MotionTable()
        self.motion_fine = MotionTable.lattice()
        # The sub-cell table measured on the training trajectories at other speeds: the filter's
        # alternative for steady users at speeds the training users did not keep (unfitted in
        # models saved before it existed, which weigh the speed-pooled tables instead).
        self.motion_scaled = MotionTable.lattice()
        # Both tables measured on the training users of KIND_TABLE alone: the filter's alternative
        # for the kind the tables pooled over every kind drown (unfitted in models saved before
        # they existed, or trained without that kind).
        self.motion_kind = MotionTable()
        self.motion_kind_fine = MotionTable.lattice()
        # Both tables measured on the training pedestrians at other speeds (fit_walker_speeds): the
        # filter's alternative for users on foot at paces of their own (unfitted in models saved
        # before they existed, or trained without pedestrians).
        self.motion_walk = MotionTable()
        self.motion_walk_fine = MotionTable.lattice()
        # Measured on the network's own tracks of a population's unlabelled fingerprints
        # (Estimator.adapt_motion; fit_adapted): one more hypothesis of the filter.
        self.motion_adapted = MotionTable()
        self.motion_adapted_fine = MotionTable.lattice()
        # How an acceleration on the lattice depends on the one or two before it, measured on the same
        # trajectories (none in models saved before it existed).
        self.memory = MotionMemory()
        self.register_buffer("grid_step", torch.tensor(1.0))
        # Start as the classical smoother: unit weight on the constant-velocity posterior, the
        # learned terms at zero, the output the sub-cell smoother's, so training starts from it.
        self.prior = nn.Parameter(torch.tensor([0.0] * (n_post - 1) + [1.0]))
        for lin in (self.logit, self.offset, self.gate):
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)

    def fit_motion(
        self,
        positions: np.ndarray,
        grid_xy: np.ndarray,
        index: np.ndarray | None = None,
        places: bool = True,
        kind: np.ndarray | None = None,
    ) -> CandidateTransformer:
        """Measure both smoothers' motion (and, with ``places``, place) tables on training
        trajectories ``positions (n, L >= 3, 2)`` metres over the grid points ``grid_xy (G, 2)``
        metres: the cell smoother's on the grid points ``grid_xy[index]`` the fingerprints were
        drawn at (default the nearest grid point), the sub-cell smoother's on the positions snapped
        to the lattice of :func:`subcell_mean`, and its speed-scaled copy on
        :func:`~estimation.smoothing.motion.speed_scaled` copies of them (the same place table).
        With the trajectories' ``kind (n,)`` codes (``mmwsim.trajectories.KINDS``), both tables
        again on the users of :data:`KIND_TABLE` alone, without a place table, where there are at
        least :data:`KIND_TABLE_MIN` of them (else they stay unfitted), and the walkers' tables at
        other speeds (:meth:`fit_walker_speeds`). With ``L >= 4``, the acceleration memory
        (:class:`~estimation.smoothing.memory.MotionMemory`) on the lattice positions too. The
        tables adapted to a population (:meth:`fit_adapted`), made with the tables this
        replaces, are dropped. Returns ``self``."""
        grid_xy = np.asarray(grid_xy, dtype=np.float64)
        p = np.asarray(positions, dtype=np.float64)
        mine = None if kind is None else np.asarray(kind).reshape(-1) == KINDS.index(KIND_TABLE)
        if mine is not None and len(mine) != len(p):
            raise ValueError(f"kind holds {len(mine)} codes for {len(p)} trajectories")
        lo, spacing, cell, fine = _place_frames(grid_xy)
        on_grid = lo + np.rint((p - lo) / spacing) * spacing if index is None else grid_xy[index]
        self.motion.fit(on_grid)
        u = snap_to_lattice((p - lo) / spacing)  # grid units from the first grid point
        self.motion_fine.fit(u)
        self.motion_fine.fit_walks((p - lo) / spacing, PLACE_SPEED / spacing)
        self.memory = MotionMemory()
        if p.shape[1] >= 4:
            self.memory.fit(u)
        if places:
            self.motion.fit_place(on_grid, *cell)
            self.motion_fine.fit_place(u + lo / spacing, *fine, PLACE_SPEED / spacing)
            self.motion_fine.fit_drives((p - lo) / spacing, PLACE_SPEED / spacing)
        else:
            self.motion.drop_place()
            self.motion_fine.drop_place()
        self.motion_scaled = copy.deepcopy(self.motion_fine).fit(
            snap_to_lattice(speed_scaled((p - lo) / spacing))
        )
        self.motion_kind, self.motion_kind_fine = MotionTable(), MotionTable.lattice()
        if mine is not None and mine.sum() >= KIND_TABLE_MIN:
            self.motion_kind.fit(on_grid[mine])
            self.motion_kind_fine.fit(u[mine])
        if kind is None:
            self.motion_walk, self.motion_walk_fine = MotionTable(), MotionTable.lattice()
        else:
            self.fit_walker_speeds(p, grid_xy, kind)
        self.motion_adapted, self.motion_adapted_fine = MotionTable(), MotionTable.lattice()
        self.grid_step.fill_(spacing)
        return self

    def fit_walker_speeds(
        self, positions: np.ndarray, grid_xy: np.ndarray, kind: np.ndarray
    ) -> CandidateTransformer:
        """Measure the walkers' alternative tables: both smoothers' motion on the trajectories
        ``positions (n, L >= 3, 2)`` metres of the users of :data:`WALKER_KINDS` among ``kind
        (n,)`` codes, at other speeds (:func:`~estimation.smoothing.motion.speed_scaled` copies
        with factors from :data:`~estimation.smoothing.motion.WALK_SCALES`), over the grid points
        ``grid_xy (G, 2)`` metres; no place table (walkers go anywhere in the free space). Fewer
        than :data:`KIND_TABLE_MIN` walkers leave them unfitted. :meth:`fit_motion` calls it with
        the training trajectories; a model saved before these tables existed gets them by calling
        it with the same trajectories and saving again. Returns ``self``."""
        p = np.asarray(positions, dtype=np.float64)
        codes = np.asarray(kind).reshape(-1)
        if len(codes) != len(p):
            raise ValueError(f"kind holds {len(codes)} codes for {len(p)} trajectories")
        walkers = np.isin(codes, [KINDS.index(k) for k in WALKER_KINDS])
        self.motion_walk, self.motion_walk_fine = MotionTable(), MotionTable.lattice()
        if walkers.sum() < KIND_TABLE_MIN:
            return self
        lo, spacing, _, _ = _place_frames(np.asarray(grid_xy, dtype=np.float64))
        u = speed_scaled((p[walkers] - lo) / spacing, copies=WALK_COPIES, ranges=WALK_SCALES)
        self.motion_walk, self.motion_walk_fine = _table_pair(u, lo, spacing)
        return self

    def fit_adapted(self, tracks: np.ndarray, grid_xy: np.ndarray) -> CandidateTransformer:
        """Measure the adapted tables (cell and sub-cell, no place table) on ``tracks (n, L >= 3,
        2)`` metres, the network's own estimates of a population's positions, over the grid
        points ``grid_xy (G, 2)`` metres. The filter weighs them beside the measured tables
        rather than in their place: measured on estimates they are blurred where the measured
        ones are exact (our drivers' lattice patterns), so users who move as the training users
        did keep the measured ones by their evidence. Returns ``self``."""
        p = np.asarray(tracks, dtype=np.float64)
        if p.ndim != 3 or p.shape[1] < 3 or p.shape[2] != 2 or not np.isfinite(p).all():
            raise ValueError(f"tracks must be finite (n, L >= 3, 2) metres, got shape {p.shape}")
        lo, spacing, _, _ = _place_frames(np.asarray(grid_xy, dtype=np.float64))
        self.motion_adapted, self.motion_adapted_fine = _table_pair((p - lo) / spacing, lo, spacing)
        return self

    def lane_tables(
        self, lines: np.ndarray, grid_xy: np.ndarray, tables: tuple[MotionTable, MotionTable] | None = None
    ) -> tuple[MotionTable, MotionTable]:
        """Copies of both smoothers' motion tables (or of ``tables``, a cell-level and a sub-cell
        table made from them) whose place tables are a street map's lanes
        (:meth:`MotionTable.fit_place_lines`) instead of the measured ones: street centre lines
        ``lines (e, 2, 2)`` metres over the grid points ``grid_xy (G, 2)`` metres users can be
        at. The copies keep the motion; they are the tables' place part on the same
        grid, lattice and speeds as :meth:`fit_motion`'s."""
        grid_xy = np.asarray(grid_xy, dtype=np.float64)
        lines = np.asarray(lines, dtype=np.float64)
        _, spacing, cell_frame, fine_frame = _place_frames(grid_xy)
        cell, fine = copy.deepcopy(tables or (self.motion, self.motion_fine))
        cell.fit_place_lines(lines, *cell_frame, len(grid_xy))
        fine.fit_place_lines(lines / spacing, *fine_frame, len(grid_xy) * SUBCELLS**2, PLACE_SPEED / spacing)
        return cell, fine

    def smoothed(self, xy: torch.Tensor, post: torch.Tensor) -> torch.Tensor:
        """The classical estimate ``(B, T, 2)`` metres when features come without it (the online
        filter gives its own, :meth:`Estimator.inputs`): the dense sub-cell smoother's
        (:func:`subcell_mean`) once the motion tables are measured, else the cell-level
        constant-velocity posterior mean."""
        if not bool(self.motion_fine.fitted):
            return cell_mean(xy, post)
        return subcell_mean(xy, post[..., 0], post[..., -1], self.motion_fine, float(self.grid_step))

    def forward(self, xy: torch.Tensor, post: torch.Tensor, fine: torch.Tensor | None = None) -> torch.Tensor:
        """``xy (B, T, k, 2)`` metres and ``post (B, T, k, P)`` from :func:`candidate_features`, and
        the classical estimate ``fine (B, T, 2)`` metres (default :meth:`smoothed`) -> positions
        ``(B, T, 2)`` metres, or ``(B, horizon, 2)`` when forecasting."""
        tracked = self.track(xy, post, fine)
        if self.task != "forecasting":
            return tracked
        return extrapolate(tracked, self.horizon)

    def track(self, xy: torch.Tensor, post: torch.Tensor, fine: torch.Tensor | None = None) -> torch.Tensor:
        """Positions ``(B, T, 2)`` metres of the observed steps (see :meth:`forward`). Reads the
        first ``k`` candidates of each step where the filter carries more."""
        xy, post = xy[:, :, : self.k], post[:, :, : self.k]
        B, T, K, _ = xy.shape
        if fine is None:
            fine = self.smoothed(xy, post)
        # Anchor: coordinate-wise median of the steps' best candidates, robust to an alias far away.
        anchor = xy[:, :, 0].median(dim=1).values[:, None, None]
        near = (xy - fine[:, :, None]) / _SCALE
        feats = torch.cat([(xy - anchor) / _SCALE, near, post / 10.0], dim=-1)
        h = self.embed(feats) + self.rank.weight[:K] + sinusoidal_encoding(torch.arange(T), self.d)[:, None]
        h = encode(self.encoder, h.reshape(B, T * K, self.d)).reshape(B, T, K, self.d)
        logits = self.logit(h)[..., 0] + (post * self.prior).sum(-1)
        w = torch.softmax(logits, dim=-1)  # (B, T, K)
        cells = (w[..., None] * xy).sum(2)
        # The network moves the classical estimate toward its own weighting of the candidates as
        # far as it trusts that weighting (the gate), plus a small learned correction.
        pooled = (w[..., None] * h).sum(2)
        corr = torch.tanh((w[..., None] * self.offset(h)).sum(2))
        out = fine + self.gate(pooled) * (cells - fine) + corr
        far = (out - fine).norm(dim=-1, keepdim=True) > NET_REACH * self.grid_step
        return torch.where(far, fine, out)
