"""The floor: an oracle tracker that knows how the data were made.

Every trajectory of a data set comes from mmwsim's generator (:mod:`mmwsim.trajectories.generate`):
a kind drawn in the stored proportions, a start uniform over the free, covered area (a vehicle on
the street network: uniform along the centre lines), then per step a stop, a turn, a speed change
or nothing, with the generator's speed limits, obstacle-avoidance retries, street routes, and the
rejection of trajectories that leave the free space; each step's fingerprint is the noisy bits of
the nearest valid grid point's PDP. :class:`Oracle` is a particle smoother on the continuous plane
that uses exactly that model: per kind a particle filter whose transition *is* the generator's step
(same events and probabilities, avoidance, routes and validity checks, on the same free space),
weighted by the exact fingerprint likelihood of the nearest valid grid point (the matcher's noise
model at the observations' noise, without its robustness floor); its estimate is the posterior
mean of the particles' ancestral paths, averaged over the kinds by their posterior probabilities.

What it leaves to chance is only Monte-Carlo error, which falls with the particle count (measured in
``benchmarks/oracle_floor.py``), so its error is the floor of what any tracker can reach on data of
our generator: the posterior mean minimises the expected squared error of every step. (The tables
report the mean per-trajectory RMSE, whose exact minimiser differs from the posterior mean only
by the spread of the squared errors within a trajectory; the difference is far below the gaps
between methods.) It is evaluated as the ``oracle`` method (:class:`OracleMethod`), on the same
noise draws as every other method. The floor includes knowing the generator's constants exactly,
which no tracker is told; :meth:`Oracle.with_model` changes one of them (an oracle told it wrong),
and :meth:`Oracle.with_speed_spread` makes the oracle read every user's speeds from its fingerprints
instead of knowing them, to measure what that knowledge is worth (docs/estimation.md).
"""

from __future__ import annotations

import copy
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import shapely
import torch
from scipy import ndimage

from mmwsim.geometry.freespace import CoverageMask, FreeSpace

# The generator's avoidance tries per step: a blocked step is retried with a heading deviating by up
# to pi * t / _MAX_AVOID on try t, then the trajectory is dropped. The oracle must retry as it does.
from mmwsim.trajectories.generate import _MAX_AVOID
from mmwsim.trajectories.motion import KINDS, SPEED, STOP, TURN, MotionModel
from mmwsim.trajectories.streets import StreetNetwork

from .data import SequenceSet
from .errors import EstimationError
from .matching import FingerprintMatcher

__all__ = ["Oracle", "OracleMethod", "ORACLE_PARTICLES"]

ORACLE_PARTICLES = {"pedestrian": 8192, "hybrid": 16384, "vehicle": 4096}
"""Default particles per trajectory of each moving kind (others: the largest), chosen by measuring
error against particles on the demo data set (``benchmarks/oracle_floor.py --convergence``):
four times as many move a kind's mean error by at most 1.2 %. Hybrids need the most (fast users whose
heading the 2 m cells pin down slowly), vehicles on the streets the fewest (one dimension)."""

_PARTICLES_PER_BATCH = 1 << 19  # trajectories x particles held at once (about 150 MB of state and history)
_RING, _RING_MIX = 64, 0.9  # sectors of a restart's heading proposal, and its share against the uniform
_ACCEPTANCE_PARTICLES = 1 << 16  # at most this many prior draws (8 x the particles) estimate how often
# the generator keeps a trajectory
_ESS = 0.5  # resample a trajectory's particles when their effective number falls below this share


class _Grid:
    """The data set's receiver grid and its valid points (the rows of the likelihood).

    Parameters
    ----------
    grid : ReceiverGrid
    valid : (grid.size,) bool
        Row ``r`` of every likelihood is the ``r``-th valid point in flat order (``ix + nx iy``), as in
        :class:`estimation.adapter.GridTable`.
    """

    def __init__(self, grid: Any, valid: np.ndarray):
        valid = np.asarray(valid, dtype=bool).reshape(-1)
        if valid.size != grid.size or not valid.any():
            raise EstimationError(
                f"oracle: the validity mask has {valid.size} entries ({int(valid.sum())} valid), "
                f"the grid {grid.size} points"
            )
        self.grid, self.valid, self.spacing = grid, valid, float(grid.spacing)
        flat = np.flatnonzero(valid)
        self.flat = flat
        self.row_of_flat = np.full(grid.size, -1, dtype=np.int64)
        self.row_of_flat[flat] = np.arange(len(flat))
        nx = grid.shape[0]
        self.xy = np.column_stack([grid.xs[flat % nx], grid.ys[flat // nx]])
        self.size = len(flat)

    def rows(self, p: np.ndarray) -> np.ndarray:
        """Likelihood row of the nearest grid point of each ``(..., 2)`` position (metres), -1 where
        that point is not valid (the generator never puts a user there)."""
        return self.row_of_flat[self.grid.nearest_index(p)]


class _Space:
    """The generator's free space of one clearance (:class:`mmwsim.geometry.FreeSpace` with the
    data set's coverage), with a fast path.

    Most particles are far from every building, where shapely's exact test is wasted: a raster of
    the signed distance to the grown obstacles (resolution ``res``, error below ``2.2 res``)
    decides those, and only the particles within that margin of an obstacle go to the exact test.
    The answers are the exact ones except inside free slivers narrower than ``res`` between two
    obstacles.

    Attributes
    ----------
    area : float, m^2
        Free, covered area within the bounds (the start prior's support).
    cell_fraction : (G,) float
        Free, covered share of each valid grid point's cell.
    centroid : (G, 2) float, metres
        Centre of that share (a static user's mean position given its cell).
    """

    def __init__(self, obstacles: list, bounds: np.ndarray, clearance: float, grid: _Grid, res: float):
        self.fs = FreeSpace(obstacles, bounds, clearance, CoverageMask(grid.grid, grid.valid), name="oracle")
        self.grid, self.res, self.margin = grid, float(res), 2.2 * float(res)
        b = self.fs.bounds
        self.lo = b[0]
        n = np.floor((b[1] - b[0]) / res + 1e-9).astype(np.int64) + 1
        self.shape = (int(n[1]), int(n[0]))
        X, Y = np.meshgrid(b[0, 0] + res * np.arange(n[0]), b[0, 1] + res * np.arange(n[1]))
        self.union = None
        if self.fs.obstacles:
            # The grown obstacles as one prepared geometry: point tests without point objects.
            self.union = shapely.union_all(self.fs.obstacles)
            shapely.prepare(self.union)
            blocked = shapely.intersects_xy(self.union, X, Y)
        else:
            blocked = np.zeros(X.shape, dtype=bool)
        if not blocked.any():
            self.dist = np.full(X.shape, np.inf)
        elif blocked.all():
            self.dist = np.full(X.shape, -np.inf)
        else:
            self.dist = res * np.where(
                blocked, -ndimage.distance_transform_edt(blocked), ndimage.distance_transform_edt(~blocked)
            )
        rows = grid.rows(np.stack([X, Y], axis=-1))
        keep = ~blocked & (rows >= 0)
        count = np.bincount(rows[keep], minlength=grid.size).astype(np.float64)
        self.area = float(keep.sum()) * res * res
        if self.area <= 0:
            raise EstimationError(f"oracle: no free, covered area for a clearance of {clearance:g} m")
        # Cells the raster sees as closed may still hold a sliver of free space: keep them proposable.
        self.cell_fraction = np.maximum(
            count * res * res / grid.spacing**2, 0.25 * res * res / grid.spacing**2
        )
        safe = np.maximum(count, 1.0)
        cx = np.bincount(rows[keep], weights=X[keep], minlength=grid.size) / safe
        cy = np.bincount(rows[keep], weights=Y[keep], minlength=grid.size) / safe
        self.centroid = np.where(count[:, None] > 0, np.column_stack([cx, cy]), grid.xy)

    def _distance(self, p: np.ndarray) -> np.ndarray:
        """Raster signed distance (metres, > 0 outside the grown obstacles) at ``(..., 2)`` positions."""
        q = (p - self.lo) * (1.0 / self.res) + 0.5
        ix = np.clip(q[..., 0], 0, self.shape[1] - 1).astype(np.intp)
        iy = np.clip(q[..., 1], 0, self.shape[0] - 1).astype(np.intp)
        return self.dist[iy, ix]

    def in_bounds(self, p: np.ndarray) -> np.ndarray:
        b = self.fs.bounds
        return (p[:, 0] >= b[0, 0]) & (p[:, 0] <= b[1, 0]) & (p[:, 1] >= b[0, 1]) & (p[:, 1] <= b[1, 1])

    def points_ok(self, p: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """``FreeSpace.points_ok``: ``(n, 2)`` metres -> ``(n,)`` bool (in bounds, covered, clear);
        ``rows``: their likelihood rows if already known."""
        ok = self.in_bounds(p) & ((self.grid.rows(p) if rows is None else rows) >= 0)
        d = self._distance(p)
        ok &= d > -self.margin
        unsure = np.flatnonzero(ok & (d <= self.margin))
        if len(unsure) and self.union is not None:
            ok[unsure] = ~shapely.intersects_xy(self.union, p[unsure, 0], p[unsure, 1])
        return ok

    def clear(self, a: np.ndarray, b: np.ndarray, pieces: int) -> np.ndarray:
        """Whether the straight segments from ``a`` to ``b`` (``(n, 2)`` metres, end points free)
        stay clear of the grown obstacles: ``(n,)`` bool.

        A segment is surely clear when the disc around its midpoint through its ends is, else when
        each of ``pieces`` equal parts is (the disc around its centre), surely blocked when a
        part's centre lies deep inside an obstacle, and tested exactly otherwise.
        """
        ok = np.ones(len(a), dtype=bool)
        if self.union is None or not len(a):
            return ok
        half = 0.5 * np.linalg.norm(b - a, axis=1)
        idx = np.flatnonzero(self._distance(0.5 * (a + b)) < half + self.margin)
        if not len(idx) or pieces < 2:
            unsure = idx
        else:
            aa, bb = a[idx], b[idx]
            f = (np.arange(pieces) + 0.5) / pieces
            d = self._distance(aa[:, None] + f[None, :, None] * (bb - aa)[:, None])
            sure = np.all(d >= (half[idx] / pieces)[:, None] + self.margin, axis=1)
            blocked = np.any(d < -self.margin, axis=1)
            ok[idx[blocked]] = False
            unsure = idx[~sure & ~blocked]
        if len(unsure):
            ok[unsure] = ~shapely.intersects(
                self.union, shapely.linestrings(np.stack([a[unsure], b[unsure]], axis=1))
            )
        return ok

    def segments_ok(
        self, a: np.ndarray, b: np.ndarray, pieces: int, rows: np.ndarray | None = None
    ) -> np.ndarray:
        """``FreeSpace.segments_ok`` for steps from valid positions ``a`` to ``b`` (both ``(n, 2)``
        metres): ``b`` valid (``rows``: its likelihood rows if known) and the segment clear."""
        ok = self.points_ok(b, rows)
        idx = np.flatnonzero(ok & np.any(a != b, axis=1))
        ok[idx] = self.clear(a[idx], b[idx], pieces)
        return ok


def _logsumexp(x: np.ndarray, axis: int) -> np.ndarray:
    """``log(sum(exp(x)))`` along ``axis`` (-inf where all are -inf); several times faster than
    ``np.logaddexp.reduce``."""
    top = np.max(x, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.log(np.sum(np.exp(x - top), axis=axis)) + np.squeeze(top, axis=axis)


def _speed_step(
    model: MotionModel,
    dt: float,
    speed: np.ndarray,
    restart: np.ndarray,
    rng: np.random.Generator,
    scale: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One step of the generator's speed process (``generate._speed_process``) for every particle.

    ``scale (P,)``, where given, multiplies each particle's speeds (restart speed, speed step and
    limits): a user whose speeds the filter reads instead of knowing (:meth:`Oracle.with_speed_spread`).

    Returns
    -------
    events : (P,) int8, the step's event (NONE, STOP, TURN or SPEED)
    speed : (P,) float64, m/s after the step
    step : (P,) float64, metres travelled in the step
    sign : (P,) float64, +-1, the direction of a turn
    """
    P = len(speed)
    u = rng.random(P)
    sign = (rng.integers(0, 2, size=P) * 2 - 1).astype(np.float64)
    cut = np.cumsum([model.p_stop, model.p_turn, model.p_speed]) * dt
    events = np.where(u < cut[0], STOP, np.where(u < cut[1], TURN, np.where(u < cut[2], SPEED, 0))).astype(
        np.int8
    )
    # After a stop the user restarts at the mean speed; a speed change always changes the speed,
    # its sign forced where the other would leave the speed range.
    f = 1.0 if scale is None else scale
    speed = np.where(restart, model.mean_speed * f, speed)
    dv = model.speed_change * dt * f
    s = np.where(
        speed + dv > model.max_speed * f + 1e-12,
        -1.0,
        np.where(speed - dv < model.speed_floor * f - 1e-12, 1.0, sign),
    )
    speed = np.where(events == SPEED, speed + s * dv, speed)
    step = np.where(events == STOP, 0.0, speed * dt)
    return events, speed, step, sign


def _speed_scales(spread: float, P: int, rng: np.random.Generator) -> np.ndarray | None:
    """Every particle's factor on its kind's speeds, uniform in ``[1 - spread, 1 + spread]``
    (None, and no draw, where the speeds are known: ``spread`` 0)."""
    return None if spread == 0 else 1.0 + spread * (2.0 * rng.random(P) - 1.0)


def _start_speeds(model: MotionModel, scale: np.ndarray | None, P: int) -> np.ndarray:
    return np.full(P, model.mean_speed) if scale is None else model.mean_speed * scale


def _sample_rows(logp: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` independent draws per row of the categorical ``softmax(logp)``: ``(B, K)`` -> ``(B, n)``."""
    p = np.exp(logp - logp.max(axis=1, keepdims=True))
    c = np.cumsum(p, axis=1)
    c /= c[:, -1:]
    B, K = c.shape
    off = np.arange(B)[:, None]
    # One searchsorted over all rows: row b's cumulative sums are shifted into (b, b + 1].
    k = np.searchsorted((c + off).ravel(), (rng.random((B, n)) + off).ravel(), side="right")
    return np.minimum(k.reshape(B, n) - off * K, K - 1)


@dataclass
class _State:
    """Particle states, flattened over (trajectory, particle): every array has ``P = B N`` rows."""

    pos: np.ndarray  # (P, 2) metres
    speed: np.ndarray  # (P,) m/s
    restart: np.ndarray  # (P,) bool: the last step was a stop
    heading: np.ndarray | None = None  # (P,) radians (free motion)
    prev: np.ndarray | None = None  # (P,) int64 node the vehicle comes from (streets)
    cur: np.ndarray | None = None  # (P,) int64 node it drives to (streets)
    off: np.ndarray | None = None  # (P,) metres driven from ``prev`` (streets)
    scale: np.ndarray | None = None  # (P,) factor on every speed of the kind (speed spread)

    def take(self, idx: np.ndarray) -> _State:
        return _State(*(None if v is None else v[idx] for v in self.__dict__.values()))


class _Transition:
    """What the free and the street transitions share: a kind's motion model over a free space,
    and the spread of the speeds the particles read (:meth:`Oracle.with_speed_spread`)."""

    def __init__(self, model: MotionModel, space: _Space, dt: float, spread: float = 0.0):
        self.model, self.space, self.dt, self.spread = model, space, dt, spread

    @property
    def pieces(self) -> int:
        """Segment pieces for the fast clearance test: about 1 m each at the top speed."""
        return max(1, math.ceil(self.model.max_speed * (1.0 + self.spread) * self.dt))

    def replaced(self, model: MotionModel, spread: float) -> _Transition:
        """The same transition (its free space and precomputed tables shared) with another model
        and spread."""
        other = copy.copy(self)
        other.model, other.spread = model, spread
        return other


class _FreeMotion(_Transition):
    """The generator's free motion (``generate._attempt_free``) as a particle transition."""

    def start(self, lik: np.ndarray, n: int, rng: np.random.Generator) -> tuple[_State, np.ndarray]:
        """Particles of the first step and their log importance weights ``(B, n)``.

        The prior is uniform over the free, covered area; the proposal picks a grid cell by its
        likelihood times its free share, then a point uniformly in the cell, so that the weight
        ``prior x likelihood / proposal`` is a constant over the free share (zero off it).
        """
        sp, g = self.space, self.space.grid
        B = len(lik)
        logq = lik + np.log(sp.cell_fraction)
        log_s = _logsumexp(logq, axis=1)
        rows = _sample_rows(logq, n, rng)
        pos = g.xy[rows] + (rng.random((B, n, 2)) - 0.5) * g.spacing
        flat = pos.reshape(-1, 2)
        ok = (sp.points_ok(flat) & (g.rows(flat) == rows.ravel())).reshape(B, n)
        logw = log_s[:, None] + math.log(g.spacing**2 / sp.area) - np.log(sp.cell_fraction[rows])
        # The first heading is drawn in the first step, as after a stop (a restart at the mean speed
        # in a uniformly random direction is exactly the generator's start).
        P = B * n
        scale = _speed_scales(self.spread, P, rng)
        state = _State(
            flat,
            _start_speeds(self.model, scale, P),
            np.ones(P, dtype=bool),
            heading=np.zeros(P),
            scale=scale,
        )
        return state, np.where(ok, logw, -np.inf)

    def _fresh_headings(
        self, pos: np.ndarray, step: np.ndarray, lik: np.ndarray, owner: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """Headings of users (re)starting, proposed from this step's likelihood, and the log
        importance weights ``log(prior / proposal)`` that undo the proposal.

        The generator draws a restart's heading uniformly; most directions lead out of the
        fingerprint's likely cells, so the proposal picks one of ``_RING`` sectors by the likelihood
        at the point the step would reach in its middle (a mixture with the uniform, to keep the
        weights bounded), then a heading uniformly within the sector.
        """
        K, g = _RING, self.space.grid.grid
        nx, ny = int(g.shape[0]), int(g.shape[1])
        # Each trajectory's likelihood relative to its best cell as an image of the whole grid (0 off
        # the valid points): one gather per ring point. A proposal needs no exactness, so the ring
        # is computed in float32 grid units.
        img = np.zeros((len(lik), g.size), dtype=np.float32)
        img[:, self.space.grid.flat] = np.exp(lik - lik.max(axis=1, keepdims=True))
        mid = 2.0 * np.pi * (np.arange(K) + 0.5) / K
        inv = 1.0 / float(g.spacing)
        reach = (step * inv).astype(np.float32)[:, None]
        fx = ((pos[:, 0] - g.origin[0]) * inv + 0.5).astype(np.float32)[:, None] + reach * np.cos(mid).astype(
            np.float32
        )
        fy = ((pos[:, 1] - g.origin[1]) * inv + 0.5).astype(np.float32)[:, None] + reach * np.sin(mid).astype(
            np.float32
        )
        itype = np.int32 if img.size < 2**31 else np.int64
        flat = np.clip(fx, 0, nx - 1).astype(itype) + nx * np.clip(fy, 0, ny - 1).astype(itype)
        p = img.ravel()[flat + (owner.astype(itype) * g.size)[:, None]]
        total = p.sum(axis=1, keepdims=True)
        p = np.where(total > 0, p / np.maximum(total, 1e-30), np.float32(1.0 / K))  # nothing likely: uniform
        q = np.float32((1.0 - _RING_MIX) / K) + np.float32(_RING_MIX) * p
        c = np.cumsum(q, axis=1)
        k = np.minimum((c < rng.random(len(q), dtype=np.float32)[:, None] * c[:, -1:]).sum(axis=1), K - 1)
        heading = (k + rng.random(len(k))) * (2.0 * np.pi / K)
        # The weight uses q normalised in float64 (its float32 sum is 1 within 1e-6).
        qk = q[np.arange(len(k)), k].astype(np.float64) / c[:, -1].astype(np.float64)
        return heading, -np.log(K * qk)

    def step(
        self, s: _State, rng: np.random.Generator, lik: np.ndarray, n: int
    ) -> tuple[_State, np.ndarray, np.ndarray, np.ndarray]:
        """Every particle one step on.

        Parameters
        ----------
        s : _State
        rng : numpy.random.Generator
        lik : (B, G) float, log-likelihoods of this step's fingerprints (for the restarts' headings)
        n : int, particles per trajectory

        Returns
        -------
        state : _State
        ok : (P,) bool, whether the generator could take each step
        rows : (P,) int64, likelihood rows of the new positions
        log_correction : (P,) float, log importance weight of the proposal
        """
        m, dt, grid = self.model, self.dt, self.space.grid
        events, speed, step, sign = _speed_step(m, dt, s.speed, s.restart, rng, s.scale)
        P = len(speed)
        fresh = rng.uniform(0.0, 2.0 * np.pi, P)
        correction = np.zeros(P)
        sel = np.flatnonzero(s.restart & (step > 0))  # a restart's heading matters once it moves
        if len(sel):
            fresh[sel], correction[sel] = self._fresh_headings(s.pos[sel], step[sel], lik, sel // n, rng)
        heading = np.where(s.restart, fresh, s.heading) + np.where(
            events == TURN, sign * math.radians(m.turn_rate) * dt, 0.0
        )
        nxt = s.pos + step[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        rows = grid.rows(nxt)
        bad = ~self.space.segments_ok(s.pos, nxt, self.pieces, rows)
        for t in range(1, _MAX_AVOID + 1):  # the generator's retries, the deviation widening each time
            idx = np.flatnonzero(bad)
            if not len(idx):
                break
            h = heading[idx] + rng.uniform(-1.0, 1.0, len(idx)) * np.pi * t / _MAX_AVOID
            cand = s.pos[idx] + step[idx, None] * np.column_stack([np.cos(h), np.sin(h)])
            cand_rows = grid.rows(cand)
            good = self.space.segments_ok(s.pos[idx], cand, self.pieces, cand_rows)
            gi = idx[good]
            heading[gi], nxt[gi], rows[gi], bad[gi] = h[good], cand[good], cand_rows[good], False
        return _State(nxt, speed, events == STOP, heading=heading, scale=s.scale), ~bad, rows, correction


class _StreetMotion(_Transition):
    """The generator's vehicles on the street network (``generate._attempt_streets``): a random
    start along the centre lines, a random onward street at every node (never straight back unless
    at a dead end), every chord checked against the free space."""

    def __init__(self, model: MotionModel, space: _Space, dt: float, net: StreetNetwork, piece: float = 0.5):
        super().__init__(model, space, dt)
        self.net = net
        # The first step's proposal picks a piece of centre line (about `piece` metres) by its
        # cell's likelihood times its length, then a point uniformly along it.
        n_p = np.maximum(np.ceil(net.edge_length / piece).astype(np.int64), 1)
        self.p_edge = np.repeat(np.arange(len(net.edges)), n_p)
        k = np.arange(n_p.sum()) - np.repeat(np.cumsum(n_p) - n_p, n_p)
        self.p_from = k / n_p[self.p_edge]  # start of the piece, as a share of its edge
        self.p_share = 1.0 / n_p[self.p_edge]
        self.p_len = net.edge_length[self.p_edge] * self.p_share
        a, b = net.nodes[net.edges[self.p_edge, 0]], net.nodes[net.edges[self.p_edge, 1]]
        self.p_rows = space.grid.rows(a + ((k + 0.5) / n_p[self.p_edge])[:, None] * (b - a))
        # A chord within one edge lies on its centre line: where the whole edge is clear of the
        # grown obstacles (tested exactly once here), only its end points' bounds and coverage remain.
        e = net.edges
        if space.fs.obstacles:
            hit = space.fs.tree.query(shapely.linestrings(net.nodes[e]), predicate="intersects")[0]
        else:
            hit = np.zeros(0, dtype=np.int64)
        clear = np.ones(len(e), dtype=bool)
        clear[hit] = False
        m = len(net.nodes)
        keys = np.concatenate([e[:, 0] * m + e[:, 1], e[:, 1] * m + e[:, 0]])
        order = np.argsort(keys)
        self.edge_keys, self.edge_clear = keys[order], np.concatenate([clear, clear])[order]

    def _position(self, prev: np.ndarray, cur: np.ndarray, off: np.ndarray) -> np.ndarray:
        a, b = self.net.nodes[prev], self.net.nodes[cur]
        return a + (off / np.linalg.norm(b - a, axis=1))[:, None] * (b - a)

    def start(self, lik: np.ndarray, n: int, rng: np.random.Generator) -> tuple[_State, np.ndarray]:
        """Particles of the first step and their log importance weights ``(B, n)`` (prior: uniform
        along the centre lines, either direction)."""
        B = len(lik)
        lp = np.take(lik, np.maximum(self.p_rows, 0), axis=1)
        # A piece whose centre has no valid cell may still reach into one: keep it proposable.
        lp = np.where(self.p_rows >= 0, lp, lik.min(axis=1, keepdims=True) - 10.0)
        logq = lp + np.log(self.p_len)
        log_s = _logsumexp(logq, axis=1)
        piece = _sample_rows(logq, n, rng)
        edge = self.p_edge[piece]
        share = self.p_from[piece] + rng.random((B, n)) * self.p_share[piece]
        flip = rng.random((B, n)) < 0.5
        e = self.net.edges[edge]
        prev = np.where(flip, e[..., 1], e[..., 0]).ravel()
        cur = np.where(flip, e[..., 0], e[..., 1]).ravel()
        off = (np.where(flip, 1.0 - share, share) * self.net.edge_length[edge]).ravel()
        pos = self._position(prev, cur, off)
        rows = self.space.grid.rows(pos).reshape(B, n)
        ok = self.space.points_ok(pos).reshape(B, n)
        lx = np.take_along_axis(lik, np.maximum(rows, 0), axis=1)
        logw = lx - np.take_along_axis(lp, piece, axis=1) + log_s[:, None] - math.log(self.net.total_length)
        P = B * n
        scale = _speed_scales(self.spread, P, rng)
        state = _State(
            pos,
            _start_speeds(self.model, scale, P),
            np.zeros(P, dtype=bool),
            prev=prev,
            cur=cur,
            off=off,
            scale=scale,
        )
        return state, np.where(ok, logw, -np.inf)

    def step(
        self, s: _State, rng: np.random.Generator, lik: np.ndarray, n: int
    ) -> tuple[_State, np.ndarray, np.ndarray, float]:
        """Every particle one step along its route; as :meth:`_FreeMotion.step` (the transition
        itself is the proposal: no correction)."""
        events, speed, step, _ = _speed_step(self.model, self.dt, s.speed, s.restart, rng, s.scale)
        nodes = self.net.nodes
        prev, cur, off = s.prev.copy(), s.cur.copy(), s.off + step
        length = np.linalg.norm(nodes[cur] - nodes[prev], axis=1)
        idx = np.flatnonzero(off > length)
        passed = np.zeros(len(off), dtype=bool)
        passed[idx] = True
        while len(idx):  # past the node: on to a random next street (back only at a dead end)
            c = cur[idx]
            nxt = self.net.onward(c, prev[idx], rng.random(len(idx)))
            off[idx] -= length[idx]
            prev[idx], cur[idx] = c, nxt
            length[idx] = np.linalg.norm(nodes[nxt] - nodes[c], axis=1)
            idx = idx[off[idx] > length[idx]]
        pos = self._position(prev, cur, off)
        rows = self.space.grid.rows(pos)
        on_edge = ~passed & self.edge_clear[np.searchsorted(self.edge_keys, prev * len(nodes) + cur)]
        ok = self.space.in_bounds(pos) & (rows >= 0)
        rest = np.flatnonzero(~on_edge)
        ok[rest] = self.space.segments_ok(s.pos[rest], pos[rest], self.pieces, rows[rest])
        state = _State(pos, speed, events == STOP, prev=prev, cur=cur, off=off, scale=s.scale)
        return state, ok, rows, 0.0


def _resample(logw: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Systematic resampling of the trajectories whose effective particle number fell below
    ``_ESS`` (resampling only then keeps the ancestral paths, hence the smoothed early steps,
    diverse).

    Returns
    -------
    ancestors : (B, N) int64, each particle's parent (itself where nothing was resampled)
    logw : (B, N) float64, the weights after resampling (their sum per trajectory unchanged)
    """
    B, N = logw.shape
    anc = np.broadcast_to(np.arange(N), (B, N)).copy()
    top = logw.max(axis=1, keepdims=True)
    alive = np.isfinite(top[:, 0])
    w = np.exp(logw - np.where(alive[:, None], top, 0.0))
    W = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    do = np.flatnonzero(alive & (1.0 / np.maximum((W**2).sum(axis=1), 1e-300) < _ESS * N))
    if not len(do):
        return anc, logw
    c = np.cumsum(W[do], axis=1)
    c[:, -1] = 1.0
    off = np.arange(len(do))[:, None]
    u = (rng.random((len(do), 1)) + np.arange(N)) / N
    k = np.searchsorted((c + off).ravel(), (u + off).ravel(), side="right").reshape(len(do), N) - off * N
    anc[do] = np.minimum(k, N - 1)
    logw = logw.copy()
    logw[do] = (_logsumexp(logw[do], axis=1) - math.log(N))[:, None]
    return anc, logw


def _particle_counts(n_particles: int | dict[str, int]) -> dict[str, int]:
    """Particles per trajectory of every kind, from one count or counts by kind (kinds not named:
    the largest given)."""
    given = dict(n_particles) if isinstance(n_particles, dict) else {k: n_particles for k in KINDS}
    if not given or any(
        isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1 for v in given.values()
    ):
        raise EstimationError(f"oracle: n_particles must be integers >= 1, got {n_particles!r}")
    top = max(int(v) for v in given.values())
    return {k: int(given.get(k, top)) for k in KINDS}


class Oracle:
    """Particle smoother with the generator's true motion model and the exact fingerprint likelihood.

    Parameters
    ----------
    grid : ReceiverGrid
        The data set's receiver grid.
    valid : (grid.size,) bool
        Valid (outdoors, covered) grid points; likelihood rows are the valid points in flat order.
    obstacles : list of shapely geometries
        What blocks users (:func:`mmwsim.geometry.scene_obstacles` of the data set's scene).
    bounds : (2, 2) float, metres
        Area the users stay within (the trajectories' ``attrs["bounds"]``).
    models : dict kind -> MotionModel
        Motion model of every kind.
    counts : dict kind -> int
        Trajectories generated per kind: the prior probability of each kind.
    streets : StreetNetwork, optional
        Vehicles (kind ``vehicle``) drive on it; None: they move freely like the others.
    rate_hz : float
        Samples per second.
    n_particles : int or dict kind -> int
        Particles per trajectory, for every kind or by kind (kinds not named: the largest given).
    seed : int
        Seeds every draw: the same inputs and batch size give the same estimates.
    resolution : float
        Raster resolution of the fast free-space test, metres.

    Notes
    -----
    For each kind a particle filter runs over all steps at once for a batch of trajectories
    (arrays of trajectories x particles, no per-trajectory loop). The first step is proposed from its
    own likelihood (grid cells by likelihood, or centre-line pieces for vehicles), the others by the
    generator's transition (a bootstrap filter); a particle whose step the generator would reject
    gets weight zero, which conditions on the trajectory being one the generator keeps. The
    estimate of a prefix of ``L`` steps uses only its ``L`` fingerprints: the weights at step ``L``
    applied to the particles' ancestral paths. Static users are smoothed exactly on the grid.
    """

    def __init__(
        self,
        grid: Any,
        valid: np.ndarray,
        obstacles: list,
        bounds: np.ndarray,
        models: dict[str, MotionModel],
        counts: dict[str, int],
        streets: StreetNetwork | None = None,
        rate_hz: float = 1.0,
        n_particles: int | dict[str, int] = ORACLE_PARTICLES,
        seed: int = 0,
        resolution: float = 0.25,
    ):
        self.n_particles = _particle_counts(n_particles)
        if not (math.isfinite(rate_hz) and rate_hz > 0) or not (math.isfinite(resolution) and resolution > 0):
            raise EstimationError(f"oracle: rate {rate_hz!r} Hz and resolution {resolution!r} m must be > 0")
        kinds = [k for k in KINDS if counts.get(k, 0) > 0]
        if not kinds or any(k not in models for k in kinds) or any(c < 0 for c in counts.values()):
            raise EstimationError(
                f"oracle: counts {counts} need a kind with trajectories and its motion model"
            )
        self.grid = _Grid(grid, valid)
        self.seed, self.dt = int(seed), 1.0 / float(rate_hz)
        total = sum(counts[k] for k in kinds)
        self.log_prior = {k: math.log(counts[k] / total) for k in kinds}
        spaces: dict[float, _Space] = {}
        self.motion: dict[str, _Transition] = {}
        self.static_space: dict[str, _Space] = {}
        for k in kinds:
            m = models[k]
            m.check_rate(rate_hz)
            c = float(m.clearance)
            if c not in spaces:
                spaces[c] = _Space(obstacles, np.asarray(bounds, dtype=np.float64), c, self.grid, resolution)
            if not m.moving:
                self.static_space[k] = spaces[c]
            elif k == "vehicle" and streets is not None:
                self.motion[k] = _StreetMotion(m, spaces[c], self.dt, streets)
            else:
                self.motion[k] = _FreeMotion(m, spaces[c], self.dt)
        self.kinds = kinds
        self.dead = 0  # trajectories no kind could explain (estimated from the fingerprints alone)
        self._acceptance: dict[tuple[str, int], np.ndarray] = {}

    def with_particles(self, n_particles: int | dict[str, int]) -> Oracle:
        """The same oracle (its free space and streets not rebuilt) with other particle counts."""
        other = copy.copy(self)
        other.n_particles, other.dead, other._acceptance = _particle_counts(n_particles), 0, {}
        return other

    def with_particle_factor(self, factor: float) -> Oracle:
        """The same oracle with every kind's particle count times ``factor`` (at least one)."""
        if not (math.isfinite(factor) and factor > 0):
            raise EstimationError(f"oracle: particle factor {factor!r} must be > 0")
        return self.with_particles({k: max(1, round(n * factor)) for k, n in self.n_particles.items()})

    def with_model(self, kind: str, **changes: float) -> Oracle:
        """The same oracle with one moving kind's motion model changed: a misspecified oracle.

        It measures how much of the floor rests on knowing the generator's constants exactly
        (``benchmarks/oracle_floor.py --misspecify``): the vehicles' speeds, for one, take only
        ``mean_speed + k speed_change`` within their range, which the true model pins them to.

        Parameters
        ----------
        kind : str
            A moving kind of the oracle (``pedestrian``, ``hybrid`` or ``vehicle``).
        **changes : float
            :class:`~mmwsim.trajectories.motion.MotionModel` fields and their new values, e.g.
            ``mean_speed=8.35``: speeds, speed change, turn rate and event probabilities (not
            ``kind``, nor ``clearance``, which would need another free space).

        Returns
        -------
        Oracle
            A copy sharing this one's free space, streets and other kinds; this one is unchanged.
        """
        from mmwsim.errors import MmwsimError

        old = self.motion.get(kind)
        if old is None:
            raise EstimationError(f"oracle: no moving kind {kind!r} to change (has {', '.join(self.motion)})")
        allowed = {f.name for f in fields(MotionModel)} - {"kind", "clearance"}
        unknown = sorted(set(changes) - allowed)
        if unknown:
            raise EstimationError(
                f"oracle: {kind}: cannot change {', '.join(unknown)} (can: {', '.join(sorted(allowed))})"
            )
        try:
            model = old.model.replace(**changes)
            model.check_rate(1.0 / self.dt)
        except MmwsimError as e:
            raise EstimationError(f"oracle: {e}") from None
        other = self.with_particles(self.n_particles)
        other.motion = dict(self.motion)
        other.motion[kind] = old.replaced(model, old.spread)
        return other

    def with_speed_spread(self, spread: float, kinds: Sequence[str] | None = None) -> Oracle:
        """The same oracle knowing its users' speeds only to within ``+-spread`` (a share).

        Every particle of a moving kind scales all of that kind's speeds (its start and restart
        speed, its speed step and limits) by its own factor, drawn uniformly from
        ``[1 - spread, 1 + spread]`` and kept along its path, so the filter reads each user's
        speeds from its fingerprints as a tracker must, and knows the rest of the generator (stops,
        turns, streets, that speeds change in steps). Its error against the floor says how much of
        the floor is knowing the speeds a priori (``benchmarks/oracle_floor.py --speed-spread``).

        Parameters
        ----------
        spread : float
            Half-width of the factor's range, in ``[0, 0.5]``; 0 gives the oracle itself.
        kinds : sequence of str, optional
            Moving kinds whose speeds are read (default every moving kind).

        Returns
        -------
        Oracle
            A copy sharing this one's free space and streets; this one is unchanged.
        """
        if not (math.isfinite(spread) and 0.0 <= spread <= 0.5):
            raise EstimationError(f"oracle: speed spread {spread!r} must be within [0, 0.5]")
        chosen = list(self.motion) if kinds is None else list(kinds)
        unknown = [k for k in chosen if k not in self.motion]
        if unknown:
            raise EstimationError(
                f"oracle: no moving kind {', '.join(map(repr, unknown))} (has {', '.join(self.motion)})"
            )
        other = self.with_particles(self.n_particles)
        other.motion = dict(self.motion)
        for k in chosen:
            other.motion[k] = self.motion[k].replaced(self.motion[k].model, float(spread))
        return other

    @classmethod
    def from_dataset(cls, dataset: Any, split: str | None = None, **options: Any) -> Oracle:
        """The oracle of a data set's stored trajectories.

        Parameters
        ----------
        dataset : path or mmwsim.Dataset
            A data set with trajectories generated for it (``mmwsim trajectories``).
        split : str, optional
            Split whose generation attributes are read (default the first stored; all splits of
            one generation share them).
        **options
            ``n_particles``, ``seed``, ``resolution`` of :class:`Oracle`.
        """
        from mmwsim.errors import MmwsimError
        from mmwsim.trajectories import list_splits, read_trajectories

        from .adapter import open_dataset

        ds = open_dataset(dataset) if isinstance(dataset, (str, os.PathLike)) else dataset
        try:
            names = list_splits(ds.path)
            if not names:
                raise EstimationError(f"{ds.path}: the oracle needs the data set's generated trajectories")
            attrs = read_trajectories(ds.path, split or names[0]).attrs
        except MmwsimError as e:
            if isinstance(e, EstimationError):
                raise
            raise EstimationError(str(e)) from None
        return cls.from_trajectories(ds, attrs, **options)

    @classmethod
    def from_trajectories(cls, dataset: Any, trajectories: Any, **options: Any) -> Oracle:
        """The oracle of trajectories made by mmwsim's generator for ``dataset``, stored or not.

        Trajectories of other habits than the data set's own (``generate_for_dataset(...,
        models=...)``, e.g. faster pedestrians, or vehicles off the streets) have a floor of
        their own: this oracle knows their generator as :meth:`from_dataset` knows the data
        set's (``benchmarks/foreign_motion.py --oracle``).

        Parameters
        ----------
        dataset : mmwsim.Dataset
            The data set they were generated for: its grid, validity mask and scene.
        trajectories : Trajectories or dict
            The trajectories, or their ``attrs`` (what :func:`mmwsim.trajectories.generate`
            records: motion models, counts per kind, bounds, rate, vehicles on streets).
        **options
            ``n_particles``, ``seed``, ``resolution`` of :class:`Oracle`.
        """
        from mmwsim.errors import MmwsimError
        from mmwsim.geometry.freespace import scene_obstacles

        attrs = trajectories if isinstance(trajectories, dict) else getattr(trajectories, "attrs", None)
        if not isinstance(attrs, dict):
            raise EstimationError("oracle: give trajectories made by mmwsim's generator, or their attrs")
        try:
            made_for = attrs.get("dataset")
            if made_for is not None and made_for != dataset.content_hash:
                raise EstimationError(f"{dataset.path}: its trajectories were generated for another data set")
            try:
                models = {k: MotionModel(**v) for k, v in attrs["models"].items()}
                counts = {k: int(v) for k, v in attrs["counts"].items()}
                area = attrs.get("bounds") or dataset.grid.bounds
                bounds = np.asarray(area, dtype=np.float64).reshape(2, 2)
                rate = float(attrs.get("rate_hz", 1.0))
            except (KeyError, TypeError, ValueError) as e:
                raise EstimationError(
                    f"{dataset.path}: the trajectories do not say how they were generated ({e}); the "
                    "oracle needs mmwsim's generator attributes"
                ) from None
            scene = dataset.scene()
            streets = None
            if attrs.get("vehicles_on_streets") and counts.get("vehicle", 0) > 0:
                streets = StreetNetwork.from_scene(
                    scene, float(attrs.get("street_half_width", 4.0)), bounds=bounds
                )
            obstacles = scene_obstacles(scene)
            return cls(
                dataset.grid, dataset.valid, obstacles, bounds, models, counts, streets, rate, **options
            )
        except MmwsimError as e:
            if isinstance(e, EstimationError):
                raise
            raise EstimationError(str(e)) from None

    # ------------------------------------------------------------------ smoothing
    def _particles(
        self, kind: str, lik: np.ndarray, lengths: list[int], rng: np.random.Generator, horizon: int = 0
    ) -> tuple[dict[int, np.ndarray], np.ndarray]:
        """One kind's particle smoother over ``lik (B, T, G)``: estimates ``{L: (B, L, 2)}`` and the
        log evidence of every prefix ``(B, T)``; with ``horizon`` > 0 the estimate of ``L = T`` is
        followed by its forecast, ``(B, T + horizon, 2)`` (:meth:`_ahead`)."""
        motion, N = self.motion[kind], self.n_particles[kind]
        B, T, _ = lik.shape
        state, logw = motion.start(lik[:, 0], N, rng)
        pos, anc, logws = [state.pos.reshape(B, N, 2)], [], [logw]
        rows_of = np.arange(B)[:, None] * N
        for t in range(1, T):
            a, logw = _resample(logw, rng)
            state = state.take((a + rows_of).ravel())
            state, ok, rows, correction = motion.step(state, rng, lik[:, t], N)
            rows = rows.reshape(B, N)
            ll = np.take_along_axis(lik[:, t], np.maximum(rows, 0), axis=1)
            ll += np.reshape(correction, (B, N)) if np.ndim(correction) else correction
            logw = logw + np.where(ok.reshape(B, N) & (rows >= 0), ll, -np.inf)
            pos.append(state.pos.reshape(B, N, 2))
            anc.append(a)
            logws.append(logw)
        evidence = np.stack([_logsumexp(w, axis=1) - math.log(N) for w in logws], axis=1)
        out = {}
        for L in lengths:
            w = logws[L - 1]
            top = w.max(axis=1, keepdims=True)
            W = np.exp(w - np.where(np.isfinite(top), top, 0.0))
            W /= np.maximum(W.sum(axis=1, keepdims=True), 1e-300)
            idx = np.broadcast_to(np.arange(N), (B, N))
            est = np.empty((B, L, 2))
            for t in range(L - 1, -1, -1):  # back along the ancestral paths of step L's particles
                p = np.take_along_axis(pos[t], idx[..., None], axis=1)
                est[:, t] = np.einsum("bn,bnc->bc", W, p)
                if t:
                    idx = np.take_along_axis(anc[t - 1], idx, axis=1)
            out[L] = est
        if horizon > 0:
            ahead = self._ahead(motion, state, logw, out[T][:, -1], horizon, rng)
            out[T] = np.concatenate([out[T], ahead], axis=1)
        return out, evidence

    def _ahead(
        self,
        motion: _Transition,
        state: _State,
        logw: np.ndarray,
        last: np.ndarray,
        horizon: int,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """The filter's particles at the last observed step carried ``horizon`` steps on by the
        generator's transition, no fingerprint to weigh them: the posterior-mean position of every
        future step ``(B, horizon, 2)``.

        A particle whose step the generator would reject drops out; where none is left (too few
        particles for that trajectory) the forecast stays at the previous step's (``last``, the
        filtered position, before the first)."""
        B, N = logw.shape
        rows_of = np.arange(B)[:, None] * N
        none = np.zeros((B, self.grid.size))  # no fingerprint: a restart's heading is uniform
        out = np.empty((B, horizon, 2))
        prev = last
        for h in range(horizon):
            a, logw = _resample(logw, rng)
            state = state.take((a + rows_of).ravel())
            state, ok, rows, correction = motion.step(state, rng, none, N)
            keep = ok.reshape(B, N) & (rows.reshape(B, N) >= 0)
            logw = logw + np.where(
                keep, np.reshape(correction, (B, N)) if np.ndim(correction) else 0.0, -np.inf
            )
            top = logw.max(axis=1, keepdims=True)
            alive = np.isfinite(top[:, 0])
            W = np.exp(logw - np.where(alive[:, None], top, 0.0))
            W /= np.maximum(W.sum(axis=1, keepdims=True), 1e-300)
            est = np.einsum("bn,bnc->bc", W, state.pos.reshape(B, N, 2))
            out[:, h] = np.where(alive[:, None], est, prev)
            prev = out[:, h]
        return out

    def _log_acceptance(self, kind: str, T: int) -> np.ndarray:
        """``(T,)`` log probability that the generator keeps a trajectory of ``kind`` of each
        length (a vehicle route cutting a corner or leaving the coverage, a walker stuck behind a
        building are drawn again), estimated once by the filter without fingerprints.

        The kind's evidence divided by it is that of the trajectories the generator keeps, so the
        kinds' posterior probabilities are exact, not biased against kinds rejected more often."""
        key = (kind, T)
        if key not in self._acceptance:
            rng = np.random.default_rng(
                np.random.SeedSequence(self.seed, spawn_key=(2**31, KINDS.index(kind)))
            )
            counts = self.n_particles
            self.n_particles = {**counts, kind: min(_ACCEPTANCE_PARTICLES, 8 * counts[kind])}
            try:
                _, evidence = self._particles(kind, np.zeros((1, T, self.grid.size)), [1], rng)
            finally:
                self.n_particles = counts
            self._acceptance[key] = np.minimum(evidence[0], 0.0)
        return self._acceptance[key]

    def _static(
        self, kind: str, lik: np.ndarray, lengths: list[int], horizon: int = 0
    ) -> tuple[dict[int, np.ndarray], np.ndarray]:
        """A user standing still, exactly: its cell's posterior from all steps' likelihoods times the
        cell's free share; the estimate is the posterior mean of the cells' free centroids."""
        sp = self.static_space[kind]
        cum = np.cumsum(lik, axis=1) + np.log(sp.cell_fraction)
        top = cum.max(axis=2, keepdims=True)
        w = np.exp(cum - top)
        z = w.sum(axis=2)
        evidence = np.log(z) + top[..., 0] + math.log(self.grid.spacing**2 / sp.area)
        mean = np.einsum("btg,gc->btc", w, sp.centroid) / z[..., None]
        T = lik.shape[1]
        return {
            L: np.repeat(mean[:, L - 1 : L], L + (horizon if L == T else 0), axis=1) for L in lengths
        }, evidence

    def smooth(
        self, loglik: np.ndarray | torch.Tensor, lengths: list[int], batch_index: int = 0, horizon: int = 0
    ) -> dict:
        """Smoothed positions of one batch of trajectories for several prefix lengths.

        Parameters
        ----------
        loglik : (B, T, G) float
            Log-likelihood of every valid grid point (row order of the data set's valid points)
            for each step's fingerprint, e.g. ``FingerprintMatcher.scores``.
        lengths : list of int
            Prefix lengths in ``1..T``; the estimate of prefix ``L`` uses its first ``L`` steps only.
        batch_index : int
            Mixed into the seed, so that batches draw different particles.
        horizon : int
            Steps to forecast past the last one: the estimate of ``L = T`` then has ``T + horizon``
            steps, the last ``horizon`` the posterior mean of where the generator takes the user
            next given all ``T`` fingerprints.

        Returns
        -------
        dict L -> (B, L, 2) float64, metres (``L = T``: ``(B, T + horizon, 2)``)
        """
        lik = np.asarray(loglik.numpy() if isinstance(loglik, torch.Tensor) else loglik, dtype=np.float64)
        if lik.ndim != 3 or lik.shape[2] != self.grid.size or lik.shape[1] < 1:
            raise EstimationError(
                f"oracle: log-likelihoods must be (B, T, {self.grid.size}) for this grid, got {lik.shape}"
            )
        T = lik.shape[1]
        lengths = sorted({int(v) for v in lengths})
        if not lengths or lengths[0] < 1 or lengths[-1] > T:
            raise EstimationError(f"oracle: prefix lengths {lengths} must lie within 1..{T}")
        if np.isnan(lik).any():
            raise EstimationError("oracle: log-likelihoods contain NaN")
        if horizon < 0 or (horizon and lengths[-1] != T):
            raise EstimationError(
                f"oracle: horizon {horizon} must be >= 0, and a forecast needs the whole prefix {T} "
                "among the lengths"
            )
        ests, evid = {}, {}
        for code, kind in enumerate(KINDS):
            if kind not in self.kinds:
                continue
            if kind in self.static_space:
                ests[kind], evid[kind] = self._static(kind, lik, lengths, horizon)
            else:
                rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(batch_index, code)))
                ests[kind], evid[kind] = self._particles(kind, lik, lengths, rng, horizon)
                evid[kind] = evid[kind] - self._log_acceptance(kind, T)
        out = {}
        for L in lengths:
            # The kinds by their posterior probability: evidence of the prefix times the prior share.
            logp = np.stack([evid[k][:, L - 1] + self.log_prior[k] for k in self.kinds], axis=1)
            top = logp.max(axis=1, keepdims=True)
            dead = ~np.isfinite(top[:, 0])
            p = np.exp(logp - np.where(dead[:, None], 0.0, top))
            p = np.nan_to_num(p / np.maximum(p.sum(axis=1, keepdims=True), 1e-300))
            out[L] = sum(p[:, i, None, None] * np.nan_to_num(ests[k][L]) for i, k in enumerate(self.kinds))
            if dead.any():
                # No particle of any kind survived (the particle count was too small for this
                # trajectory): fall back on each step's own likelihood-weighted mean.
                w = np.exp(lik[dead, :L] - lik[dead, :L].max(axis=2, keepdims=True))
                own = np.einsum("btg,gc->btc", w, self.grid.xy) / w.sum(axis=2)[..., None]
                extra = out[L].shape[1] - L  # a forecast: stay at the last step's
                out[L][dead] = np.concatenate([own, np.repeat(own[:, -1:], extra, axis=1)], axis=1)
                if L == lengths[-1]:
                    self.dead += int(dead.sum())
        return out

    def track(
        self,
        bits: torch.Tensor,
        matcher: FingerprintMatcher,
        lengths: list[int],
        batch: int | None = None,
        horizon: int = 0,
    ) -> dict[int, np.ndarray]:
        """Smoothed positions of fingerprint sequences.

        Parameters
        ----------
        bits : (n, T, M, N_s) tensor of 0/1
        matcher : FingerprintMatcher
            The likelihood of every valid grid point (same grid rows as the oracle's).
        lengths : list of int
            Prefix lengths in ``1..T``.
        batch : int, optional
            Trajectories smoothed at once (default: as many as keep about half a million
            particles per kind).
        horizon : int
            Steps forecast past the last fingerprint (see :meth:`smooth`).

        Returns
        -------
        dict L -> (n, L, 2) float64, metres (``L = T``: ``(n, T + horizon, 2)``)
        """
        if bits.ndim != 4 or bits.shape[1] < 1:
            raise EstimationError(f"oracle: bits must be (n, T, M, N_s), got {tuple(bits.shape)}")
        if len(matcher.grid_xy) != self.grid.size or not np.allclose(matcher.grid_xy, self.grid.xy):
            raise EstimationError("oracle: the matcher's grid is not the oracle's (another data set?)")
        n, T = bits.shape[:2]
        batch = batch or max(
            1, _PARTICLES_PER_BATCH // max(self.n_particles[k] for k in self.motion or KINDS)
        )
        parts: dict[int, list[np.ndarray]] = {L: [] for L in sorted(set(lengths))}
        for i, a in enumerate(range(0, n, batch)):
            b = bits[a : a + batch]
            lik = matcher.scores(b.reshape(-1, *b.shape[2:]).float()).reshape(len(b), T, -1)
            for L, est in self.smooth(lik, lengths, batch_index=i, horizon=horizon).items():
                parts[L].append(est)
        if n == 0:
            return {L: np.zeros((0, L + (horizon if L == T else 0), 2)) for L in parts}
        return {L: np.concatenate(v) for L, v in parts.items()}


class OracleMethod:
    """The oracle as an evaluation method (``oracle``; tracking or forecasting, nothing to fit).

    It needs what the generator knew: the data set's scene, street network, validity mask and the
    trajectories' generation attributes (motion models, counts, bounds, rate).

    Parameters
    ----------
    dataset : path, mmwsim.Dataset or Oracle, optional
        The data set the evaluated trajectories were generated for (or a ready oracle); may be
        given later with :meth:`use_dataset` (``mmwsim evaluate`` does so).
    n_particles : int or dict kind -> int
        Particles per trajectory (see :class:`Oracle`).
    seed : int
    eps : float
        Floor of the bit probabilities of the likelihood; the matcher's default (1e-6) is a
        robustness floor, the oracle's tiny one makes the likelihood the exact one.
    task, t_obs, horizon : str, int, int
        ``"forecasting"``: the ``horizon`` positions after the first ``t_obs`` steps, the filter's
        particles carried on by the generator's own transition (the forecasting floor).
    """

    name = "oracle"
    n_parameters = 0
    train_seconds = 0.0
    epochs = 0
    fitted: dict[float, dict[str, Any]] = {}  # nothing is fitted

    def __init__(
        self,
        dataset: Any = None,
        n_particles: int | dict[str, int] = ORACLE_PARTICLES,
        seed: int = 0,
        eps: float = 1e-30,
        task: str = "tracking",
        t_obs: int = 0,
        horizon: int = 0,
    ):
        if task not in ("tracking", "forecasting") or (task == "forecasting" and (t_obs < 1 or horizon < 1)):
            raise EstimationError(
                f"oracle: task {task!r} (tracking, or forecasting with t_obs and horizon >= 1; got "
                f"{t_obs}, {horizon})"
            )
        self.n_particles, self.seed, self.eps = n_particles, seed, eps
        self.task = task
        self.t_obs, self.horizon = (t_obs, horizon) if task == "forecasting" else (0, 0)
        self.source: Any = None
        self.oracle: Oracle | None = None
        self.matcher: FingerprintMatcher | None = None
        if dataset is not None:
            self.use_dataset(dataset)

    def use_dataset(self, dataset: Any) -> OracleMethod:
        """Build the oracle of ``dataset`` (path, ``mmwsim.Dataset`` or :class:`Oracle`); a toy
        data set has no generator to know, and is refused."""
        if isinstance(dataset, Oracle):
            self.source, self.oracle = "oracle", dataset
            return self
        if str(dataset).startswith("toy"):
            raise EstimationError(
                "oracle: the toy data sets' random walks are not mmwsim's generator; evaluate it on a "
                "data set with generated trajectories"
            )
        if self.oracle is None or self.source != str(dataset):
            self.oracle = Oracle.from_dataset(dataset, n_particles=self.n_particles, seed=self.seed)
            self.source = str(dataset)
        return self

    def for_sigma(self, sigma: float, validation: SequenceSet | None) -> OracleMethod:
        """The oracle with the exact likelihood at noise ``sigma`` (dB) on the grid of
        ``validation`` (any split of the data set: only its grid is read)."""
        if self.oracle is None:
            raise EstimationError(
                "oracle needs the data set its trajectories were generated for (use_dataset)"
            )
        if validation is None:
            raise EstimationError("oracle needs the data set's grid (pass validation trajectories)")
        m = OracleMethod(None, self.n_particles, self.seed, self.eps, self.task, self.t_obs, self.horizon)
        # A relabelled oracle (another particle count beside the default) keeps its label.
        m.name, m.source, m.oracle = self.name, self.source, self.oracle
        m.matcher = FingerprintMatcher(
            validation.grid_pdp, validation.grid_xy, sigma, validation.threshold, eps=self.eps
        )
        return m

    def predict_lengths(self, bits: torch.Tensor, lengths: list[int]) -> dict[int, tuple[np.ndarray, float]]:
        """Predictions for inputs cropped to each length: ``{L: (pred (n, L, 2) metres, seconds)}``;
        the one pass over the longest prefix serves all (a prefix's estimate sees only its own
        steps), each length charged its share of the time. Forecasting: ``{L: (pred (n, horizon,
        2), seconds)}``, the positions after the first ``L`` steps (``L`` is ``t_obs`` in
        evaluation)."""
        if self.oracle is None or self.matcher is None:
            raise EstimationError("oracle: call for_sigma(sigma, validation) before predicting")
        T = max(lengths)
        if T > bits.shape[1]:
            raise EstimationError(f"oracle: length {T} exceeds the {bits.shape[1]} steps given")
        if self.task == "forecasting":
            out = {}
            for L in lengths:
                t0 = time.perf_counter()
                pred = self.oracle.track(bits[:, :L], self.matcher, [L], horizon=self.horizon)[L]
                out[L] = (pred[:, L:], time.perf_counter() - t0)
            return out
        t0 = time.perf_counter()
        out = self.oracle.track(bits[:, :T], self.matcher, list(lengths))
        seconds = time.perf_counter() - t0
        return {L: (out[L], seconds * L / T) for L in lengths}
