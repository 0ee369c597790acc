"""Motion models of the candidate smoother: how far users move per step and how that changes.

:func:`~estimation.smoothing.hmm.velocity_posterior` scores a path of grid candidates by the
density of its first displacement and of every change of displacement ("acceleration", metres per
step squared). Two models give those densities:

* :class:`MixtureMotion`, set by hand: a wide Gaussian for the first displacement and a two-part
  Gaussian mixture for the acceleration, the same for every user. ``match-cv`` uses it.
* :class:`MotionTable`, measured: histograms of the training trajectories' displacements (snapped to
  the grid, as the candidates are) and of their accelerations in the frame of the motion, one per
  speed band. Speed tells a pedestrian from a vehicle, and the frame tells a speed change (along
  the motion) from a turn (across it), which a single isotropic mixture mixes up. On the sub-cell
  lattice the table is kept in the lattice's own frame instead, one per speed band and heading
  (``MotionTable(headings=...)``), where the pattern in which a steady user crosses lattice points
  is not blurred by rotation. ``tn-match`` fits one on its training split; it is saved with the
  network's weights. Its optional place table (:meth:`MotionTable.fit_place`) adds where fast
  users were, a density ratio against the flat one over the visited area, so vehicles stay in
  their lanes. Its :meth:`MotionTable.broadened` copy is the alternative the online filter weighs
  it against, for users who do not move like the training users; one measured on the training
  trajectories at other speeds (:func:`speed_scaled`) is the alternative for users as steady as
  they are at speeds they did not keep.

Both take ``v`` and ``a`` as ``(..., 2)`` tensors in metres per step that broadcast against each
other and return log densities per square metre of the same broadcast shape without the last axis.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from ._positions import checked_positions
from .line import walk_speeds
from .route import ROUTE_BINS
from .two_lines import walk_restarts

__all__ = [
    "MixtureMotion",
    "MotionTable",
    "ACCELERATION",
    "BLEND",
    "FIRST_STEP_SIGMA",
    "HEADINGS",
    "PLACE_FLOOR",
    "PLACE_SPEED",
    "BROADENED_BLOCKED",
    "BROADENED_OPEN",
    "POOLED_SPEED",
    "SCALED_COPIES",
    "SPEED_SCALE",
    "SUBCELLS",
    "WALK_COPIES",
    "WALK_SCALES",
    "snap_to_lattice",
    "speed_scaled",
]

# Change of displacement between consecutive steps (m/step^2), as (weight, sigma) of a Gaussian
# mixture: mostly steady motion with the grid's quantisation, sometimes a turn, stop or start.
# Chosen by comparing a few mixtures on 1000 test trajectories of the default data set at 6 dB.
ACCELERATION = ((0.9, 0.7), (0.1, 5.0))
FIRST_STEP_SIGMA = 15.0  # metres; prior scale of the first displacement (up to vehicle speeds)
SUBCELLS = 3  # lattice points per grid spacing and axis of the sub-cell smoother
# Heading bins per quadrant of the lattice frame of tn-match's tables (MotionTable(headings=...)).
# A steady user snapped to the lattice accelerates by whole lattice steps in a pattern set by its
# heading against the lattice axes. 24 bins (3.75 degrees) tracked best of 12, 24 and 36 on the
# default data set (docs/estimation.md).
HEADINGS = 24
# Weight of a speed band's blurred density in each class of a lattice-frame table (MotionTable.fit).
BLEND = 0.2
# Users faster than this (metres per step) get a place table: vehicles keep to lanes. Slower ones
# go anywhere, and a measured table of where they were made pedestrians' and hybrids' error worse
# (sampling noise and turns in, on the default data set), so they have none.
PLACE_SPEED = 5.0
# The broadened copy's (turn, steer) weights (MotionTable.broadened) where the free space is known
# (MotionTable.with_walls): a user whose way straight ahead is blocked turns, one on open ground
# seldom does. On 300 of benchmarks/foreign_motion.py's users per set, against (0.2, 0.75)
# everywhere: `events` vehicles 0.798 -> 0.752 m, `smooth` vehicles 0.804 -> 0.770 m, `lanes`
# 0.611 -> 0.624 m (lane drivers beside a wall go straight), our own users within 0.3 %; more
# steering where blocked, (0.75, 0.2), gives 0.759 / 0.782 / 0.620 m (docs/estimation.md).
BROADENED_OPEN = (0.05, 0.9)
BROADENED_BLOCKED = (0.9, 0.1)
# Weight of the flat density mixed into the measured one: a place no fast training user visited is
# this much (relative) less likely than the average place, never impossible.
PLACE_FLOOR = 3.0
# A fast user (over the place table's speed) whose next step is under this share of that speed has
# stopped; what such users do the step after is measured with the place table (restart_step), from
# at least RESTART_MIN such stops.
RESTART_SHARE = 0.4
RESTART_MIN = 20
# Users from this speed (metres per step) up share one acceleration table in the speed-pooled
# alternative (MotionTable.speed_pooled): the generator's vehicles drive at 5.3, 8.3 or 11.3 m per
# step, and steady vehicles at other speeds were tracked 30 to 90 % worse by the per-band tables.
POOLED_SPEED = 6.0
# The speed-scaled copies of the training trajectories (speed_scaled): each scaled by a factor in
# [1 - SPEED_SCALE, 1 + SPEED_SCALE], SCALED_COPIES of each. A table measured on the lattice
# learns the exact pattern in which a user at one of the generator's speeds crosses lattice points
# (at 8.3 m per step nearly always 25 lattice steps, at 9.5 an alternation of 28 and 29), and
# marks steady users at other speeds as accelerating; measured on these copies it sees every
# phase. 0.2 and 3 tracked vehicles at 7.5 to 9.5 m/s best of 0.08, 0.15, 0.2, 0.25 and 0.4 with
# 2 or 3 copies on the default data set (docs/estimation.md).
SPEED_SCALE = 0.2
SCALED_COPIES = 3
# The walkers' copies at speeds of their own (CandidateTransformer.fit_walker_speeds): each scaled
# by a factor from one of these ranges (either, evenly), WALK_COPIES of each, so that the tables
# see paces from half to nearly twice the training pedestrians' (1.1 to 1.7 m/s). One range from
# 0.5 to 1.7 helped walkers at other speeds less (ours at 0.8 m/s 2.8 % closer, not 4.1 %) and
# cost ours as much; copies scaled to speeds away from ours (0.45 to 0.95 and 1.9 to 2.8 m/s)
# cost ours more (+0.6 to +1.8 % against +0.6 to +1.5 %): what they pay for is the broader model
# following an alias, not their speeds (docs/estimation.md).
WALK_SCALES = ((0.5, 0.8), (1.25, 1.8))
WALK_COPIES = 2
# fit_drives: a step shorter than this (the table's units) stands still; two steps whose headings
# differ by less than this (radians) drive straight on, not round a corner.
_STILL = 1e-6
_STRAIGHT = math.radians(1.0)


def speed_scaled(
    positions: np.ndarray,
    spread: float = SPEED_SCALE,
    copies: int = SCALED_COPIES,
    seed: int = 0,
    ranges: tuple[tuple[float, float], ...] | None = None,
) -> np.ndarray:
    """The same paths at other speeds: ``copies`` copies of trajectories ``positions (n, L, 2)``
    in grid units, each scaled about its first point by its own factor drawn uniformly from
    ``[1 - spread, 1 + spread]`` (or, with ``ranges``, from one of those ``(low, high)`` ranges
    chosen evenly at random) and moved by up to one grid unit along each axis, so that its
    lattice points fall at any phase. Deterministic for a ``seed``.

    Returns
    -------
    (copies n, L, 2) float64, grid units.
    """
    if not (math.isfinite(spread) and 0.0 <= spread < 1.0):
        raise ValueError(f"spread must lie in [0, 1), got {spread}")
    if copies < 1:
        raise ValueError(f"copies must be >= 1, got {copies}")
    if ranges is not None:
        r = np.asarray(ranges, dtype=np.float64)
        if r.ndim != 2 or r.shape[1] != 2 or not len(r) or not (np.isfinite(r).all() and (0 < r[:, 0]).all()):
            raise ValueError(f"ranges must be (low, high) pairs of positive factors, got {ranges!r}")
        if not (r[:, 0] <= r[:, 1]).all():
            raise ValueError(f"each range must have low <= high, got {ranges!r}")
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 2:
        raise ValueError(f"need positions of shape (n, L, 2), got {p.shape}")
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(copies):
        if ranges is None:
            scale = rng.uniform(1.0 - spread, 1.0 + spread, len(p))[:, None, None]
        else:
            low, high = r[rng.integers(len(r), size=len(p))].T
            scale = rng.uniform(low, high)[:, None, None]
        shift = rng.uniform(0.0, 1.0, (len(p), 1, 2))
        out.append(p[:, :1] + scale * (p - p[:, :1]) + shift)
    return np.concatenate(out)


def snap_to_lattice(u: np.ndarray, n_sub: int = SUBCELLS) -> np.ndarray:
    """Nearest point of the lattice ``n_sub`` times finer than the grid whose points are the grid
    points plus the sub-cell offsets ``(j - (n_sub - 1) / 2) / n_sub``, ``j = 0..n_sub-1``.

    ``u (..., 2)`` and the result are in grid units (metres / grid spacing) from a grid point.
    """
    u = np.asarray(u, dtype=np.float64)
    return np.round(u * n_sub) / n_sub if n_sub % 2 else (np.floor(u * n_sub) + 0.5) / n_sub


def heading_slopes(headings: int) -> np.ndarray:
    """Slopes ``tan(k pi / (2 headings))``, ``k = 1..headings-1``: the inner edges of ``headings``
    equal heading bins in the first quadrant (:class:`MotionTable`'s lattice frame)."""
    h = max(int(headings), 1)
    return np.tan(np.arange(1, h) * np.pi / (2 * h))


def _check_place(shape: tuple[int, int], res: float, floor: float, speed: float, visited: int = 1) -> None:
    if min(int(v) for v in shape) < 1 or not res > 0 or not floor > 0 or not speed >= 0 or visited < 1:
        raise ValueError(
            f"need a positive table shape, resolution, floor and visited count and a speed >= 0, got "
            f"{shape}, {res}, {floor}, {visited}, {speed}"
        )


def _table_cells(points: np.ndarray, origin: np.ndarray, res: float, shape: tuple[int, int]):
    """Table cell ``(n, 2)`` int64 of every point ``(n, 2)`` of a table of ``shape`` cells of
    ``res`` from ``origin``, and whether it lies in the table ``(n,)`` bool."""
    ij = np.floor((points - np.asarray(origin, dtype=np.float64)) / res).astype(np.int64)
    return ij, ((ij >= 0) & (ij < np.asarray(shape, dtype=np.int64))).all(1)


class MixtureMotion:
    """Hand-set motion model: first displacement ``N(0, first_step_sigma^2 I)``, acceleration the
    isotropic Gaussian mixture ``acceleration`` ((weight, sigma) pairs, m/step^2), independent of
    the speed."""

    def __init__(
        self,
        acceleration: tuple[tuple[float, float], ...] = ACCELERATION,
        first_step_sigma: float = FIRST_STEP_SIGMA,
    ):
        self.acceleration = tuple((float(w), float(s)) for w, s in acceleration)
        self.first_step_sigma = float(first_step_sigma)

    def log_first(self, v: torch.Tensor) -> torch.Tensor:
        """Log density of the first displacement ``v (..., 2)`` m -> ``(...)``, up to a constant."""
        return -v.square().sum(-1) / (2 * self.first_step_sigma**2)

    def log_accel(self, v: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """Log density of acceleration ``a (..., 2)`` after displacement ``v`` (ignored) -> ``(...)``."""
        w = torch.tensor([w for w, _ in self.acceleration], dtype=a.dtype)
        s = torch.tensor([s for _, s in self.acceleration], dtype=a.dtype)
        a2 = a.square().sum(-1)[..., None]
        return torch.logsumexp((w / (2 * math.pi * s**2)).log() - a2 / (2 * s**2), dim=-1)


class MotionTable(nn.Module):
    """Motion statistics measured on training trajectories (see :meth:`fit`).

    The tables are buffers, so they travel with the network's ``state_dict``. Before :meth:`fit`
    the table is flat and ``fitted`` is False.

    Parameters
    ----------
    speed_edges : sequence of float
        Inner edges of the speed bands, metres per step; one acceleration histogram per band.
    bin : float
        Histogram bin width, metres per step (squared for accelerations).
    reach : float
        Accelerations are tabulated over ``[-reach, reach]`` along and across the motion; larger
        ones count as the edge bin.
    max_step : float
        Displacements are tabulated up to this length, metres per step.
    headings : int
        0: accelerations in the frame of the motion (along and across it), one histogram per speed
        band. ``n > 0``: in the lattice's own frame, the displacement turned by quarter turns into
        the first quadrant (``v_x > 0, v_y >= 0``), and one histogram per speed band and each of
        ``n`` heading bins within the quadrant. Quarter turns keep lattice points on lattice
        points, so a table on a lattice (:meth:`lattice`) sees the exact quantisation pattern of
        every heading instead of its blur by rotation; unlike mirror images they keep left and
        right turns apart.
    """

    def __init__(
        self,
        speed_edges: tuple[float, ...] = (0.5, 1.2, 1.6, 2.2, 2.7, 3.5, 4.5, 6.0, 7.5, 9.0, 11.0),
        bin: float = 0.5,
        reach: float = 16.0,
        max_step: float = 40.0,
        headings: int = 0,
    ):
        super().__init__()
        if headings < 0:
            raise ValueError(f"headings must be >= 0, got {headings}")
        self.bin, self.reach = float(bin), float(reach)
        n_acc, n_step = round(2 * reach / bin), round(max_step / bin)
        self.register_buffer("speed_edges", torch.tensor(speed_edges, dtype=torch.float32))
        self.register_buffer("headings", torch.tensor(int(headings), dtype=torch.int64))
        n_class = (len(speed_edges) + 1) * max(int(headings), 1)
        flat_acc = -math.log((2 * reach) ** 2)
        self.register_buffer("log_accel_table", torch.full((n_class, n_acc, n_acc), flat_acc))
        r = (torch.arange(n_step) + 0.5) * bin
        self.register_buffer("log_step_table", -torch.log(2 * math.pi * r * max_step))
        self.register_buffer("fitted", torch.tensor(False))
        # Samples per class (speed band, and heading bin) in the fit (speed_pooled weighs the bands
        # by them); zeros: unknown, as in a model saved before they were kept.
        self.register_buffer("band_count", torch.zeros(n_class, dtype=torch.float64))
        # Place table (fit_place): log density ratio of fast users per table cell, float16 to keep
        # the saved model small; a single zero cell until measured, i.e. no place preference.
        self.register_buffer("place_speed", torch.tensor(math.inf, dtype=torch.float64))
        self.register_buffer("log_place", torch.zeros(1, 1, dtype=torch.float16))
        self.register_buffer("place_origin", torch.zeros(2, dtype=torch.float64))
        self.register_buffer("place_res", torch.tensor(1.0, dtype=torch.float64))
        # What fast users do the step after they stop (fit_place): the median length of that
        # step, the table's units; zero until measured, i.e. a stopped user stays.
        self.register_buffer("restart_step", torch.tensor(0.0, dtype=torch.float64))
        # How users faster than the place speed drive (fit_drives), for the smoother along their
        # street routes: the share of their steps per length, in bins of 1 / ROUTE_BINS of the
        # table's unit, and how often their step length changes; none until measured (no such
        # smoothing).
        self.register_buffer("route_speeds", torch.zeros(0, dtype=torch.float64))
        self.register_buffer("route_change", torch.tensor(0.0, dtype=torch.float64))
        # How fast the other moving users walk (fit_walks), for the straight-line pass: the share
        # of their steps per length, in bins of 1 / LINE_BINS of the table's unit; none until
        # measured (no such pass).
        self.register_buffer("walk_speeds", torch.zeros(0, dtype=torch.float64))
        # How they set off after a stop (fit_walks), for the walks of two lines that stop: the share of
        # those steps per length (the same bins), and the share of moving steps a stop follows.
        self.register_buffer("walk_restarts", torch.zeros(0, dtype=torch.float64))
        self.register_buffer("walk_stop", torch.tensor(0.0, dtype=torch.float64))
        # Walls (broadened(blocked=...), with_walls): the acceleration table's classes from
        # wall_classes on are those of steps whose way straight ahead is blocked on the free-space
        # raster walls = (free (H, W) bool, origin (2,), res), table units. Only the kernels of
        # estimation.smoothing.beam read them (log_accel reads the first wall_classes classes);
        # never saved: the copies that have them are made from the measured tables at run time.
        self.wall_classes = 0
        self.walls: tuple[np.ndarray, np.ndarray, float] | None = None

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        if prefix + "fitted" not in state_dict:
            # a table the model was saved without (it did not have it yet) stays as it is: unfitted
            for name, buf in self._buffers.items():
                state_dict[prefix + name] = buf
        # The place table's shape depends on the area it was measured on; a model saved before
        # place tables existed has none (no place preference).
        for name in (
            "place_speed", "log_place", "place_origin", "place_res", "restart_step", "route_speeds", "route_change",
            "walk_speeds", "walk_restarts", "walk_stop",
        ):  # fmt: skip
            key = prefix + name
            if key in state_dict:
                setattr(self, name, torch.empty_like(state_dict[key]))
            else:
                state_dict[key] = getattr(self, name)
        # The acceleration table's classes depend on its frame; a model saved before frames were
        # kept has the motion frame. Its bins' reach follows from their number (the bin width is
        # the table kind's: metres on the grid, lattice steps on the lattice).
        table = state_dict.get(prefix + "log_accel_table")
        if table is not None:
            self.log_accel_table = torch.empty_like(table)
            self.band_count = torch.zeros(len(table), dtype=torch.float64)
            self.reach = table.shape[1] * self.bin / 2
        state_dict.setdefault(prefix + "headings", torch.tensor(0, dtype=torch.int64))
        if prefix + "band_count" not in state_dict:  # saved before the counts were kept
            state_dict[prefix + "band_count"] = torch.zeros_like(self.band_count)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def drop_place(self) -> MotionTable:
        """Forget the place table (no place preference). Returns ``self``."""
        self.place_speed = torch.tensor(math.inf, dtype=torch.float64)
        self.log_place = torch.zeros(1, 1, dtype=torch.float16)
        return self

    @property
    def has_place(self) -> bool:
        """Whether :meth:`fit_place` measured a place table."""
        return bool(torch.isfinite(self.place_speed))

    def log_place_ratio(self, v: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Log density ratio of being at ``x (..., 2)`` after (or before) displacement ``v (..., 2)``
        (same units as the table) -> ``(...)``: the place table's where ``v`` is faster than its
        speed, else (and where none was measured) zero."""
        shape = torch.broadcast_shapes(v.shape, x.shape)[:-1]
        if not self.has_place:
            return torch.zeros(shape, dtype=x.dtype)
        ij = ((x - self.place_origin.to(x.dtype)) / self.place_res.to(x.dtype)).floor().long()
        i = ij[..., 0].clamp(0, self.log_place.shape[0] - 1)
        j = ij[..., 1].clamp(0, self.log_place.shape[1] - 1)
        fast = v.norm(dim=-1) > self.place_speed.to(v.dtype)
        return torch.where(fast, self.log_place[i, j].to(x.dtype), torch.zeros((), dtype=x.dtype)).expand(
            shape
        )

    @torch.no_grad()
    def fit_drives(self, positions: np.ndarray, speed: float) -> MotionTable:
        """Measure how users faster than ``speed`` (their median step, the table's units) drive,
        on trajectories ``positions (n, L >= 2, 2)`` as they are (not snapped): ``route_speeds``,
        the share of their steps per length in bins of ``1 / ROUTE_BINS`` of the table's unit,
        and ``route_change``, the share of their consecutive steps whose lengths differ by more
        than a bin (what :func:`~estimation.smoothing.route.route_track` drives them by). Both
        are cleared where there is no such user.

        Both are measured along the streets, where that smoother moves its drivers: a step that
        turns a corner is its chord, shorter than the way driven, so the speeds are those of the
        steps that head as a neighbour does (or stand still) and the changes those between two
        steps that head alike (or where one stands still). On ``default.zarr`` the chords had made
        a third of the speeds and two in five of the changes (0.376 against 0.224). Returns
        ``self``."""
        p = checked_positions(positions)
        move = np.diff(p, axis=1)
        step = np.linalg.norm(move, axis=-1)
        drivers = np.median(step, axis=1) > speed
        move, step = move[drivers], step[drivers]
        drives = np.rint(step * ROUTE_BINS).astype(np.int64)
        if not drives.size:
            self.route_speeds = torch.zeros(0, dtype=torch.float64)
            self.route_change = torch.tensor(0.0, dtype=torch.float64)
            return self
        moving = step > _STILL
        both = moving[:, 1:] & moving[:, :-1]
        heading = np.arctan2(move[..., 1], move[..., 0])
        turn = np.abs(np.angle(np.exp(1j * np.diff(heading, axis=1))))
        alike = both & (turn < _STRAIGHT)
        straight = ~moving
        straight[:, 1:] |= alike
        straight[:, :-1] |= alike
        if not straight.any():  # nothing but corners: their chords are all there is
            straight[:] = True
        self.route_speeds = torch.from_numpy(np.bincount(drives[straight]) / straight.sum())
        pair = alike | ~both
        changed = (np.abs(np.diff(drives, axis=1)) > 1)[pair]
        self.route_change = torch.tensor(float(changed.mean()) if changed.size else 0.0, dtype=torch.float64)
        return self

    @torch.no_grad()
    def fit_walks(self, positions: np.ndarray, speed: float) -> MotionTable:
        """Measure how fast the users who walk move, on trajectories ``positions (n, L >= 2, 2)``
        as they are (not snapped), in the table's units: ``walk_speeds``, the share of the steps
        longer than half a unit of users whose median step is at most ``speed`` (the drivers are
        :meth:`fit_drives`'s), per length in bins of ``1 / LINE_BINS`` of the unit (what
        :func:`~estimation.smoothing.line.line_track` weighs its lines by), and how they set off
        after a stop: ``walk_restarts`` and ``walk_stop``
        (:func:`~estimation.smoothing.two_lines.walk_restarts`). Empty where there is no such step.
        Returns ``self``."""
        self.walk_speeds = torch.from_numpy(walk_speeds(positions, speed))
        restarts, stop = walk_restarts(positions, speed)
        self.walk_restarts = torch.from_numpy(restarts)
        self.walk_stop = torch.tensor(stop, dtype=torch.float64)
        return self

    @torch.no_grad()
    def fit_place(
        self,
        positions: np.ndarray,
        origin: np.ndarray,
        res: float,
        shape: tuple[int, int],
        speed: float = PLACE_SPEED,
        floor: float = PLACE_FLOOR,
        smooth: float = 0.5,
    ) -> MotionTable:
        """Measure where users faster than ``speed`` (per step, the table's units) are, on
        trajectories ``positions (n, L >= 2, 2)`` snapped as the candidates are.

        The table cells are ``[origin + i res, origin + (i + 1) res)`` per axis, ``shape`` of them.
        A position's speed is that of its step in (the first one's, of its step out). The fast
        users' histogram, smoothed by a Gaussian of ``smooth`` cells, becomes the density ratio
        ``(h + floor u) / ((1 + floor) u)`` against their flat density ``u`` over the cells any
        user visited: above 1 in lanes, ``floor / (1 + floor)`` where none went. With it,
        ``restart_step``: the median length of the step after a fast user's step falls under
        :data:`RESTART_SHARE` of ``speed`` (it stopped), zero (it stays) with fewer than
        :data:`RESTART_MIN` such stops. Returns ``self``.
        """
        p = checked_positions(positions, nonempty=True)
        _check_place(shape, res, floor, speed)
        step = np.linalg.norm(np.diff(p, axis=1), axis=-1)  # (n, L-1)
        stopped = (step[:, :-2] > speed) & (step[:, 1:-1] < RESTART_SHARE * speed)
        after = step[:, 2:][stopped]
        restart = float(np.median(after)) if len(after) >= RESTART_MIN else 0.0
        self.restart_step = torch.tensor(restart, dtype=torch.float64)
        fast = np.concatenate([step[:, :1], step], axis=1).ravel() > speed
        ij, ok = _table_cells(p.reshape(-1, 2), origin, res, shape)
        visited = max(len(np.unique(ij[ok, 0] * int(shape[1]) + ij[ok, 1])), 1)
        return self._set_place(ij[ok & fast], visited, origin, res, shape, speed, floor, smooth)

    @torch.no_grad()
    def fit_place_lines(
        self,
        lines: np.ndarray,
        origin: np.ndarray,
        res: float,
        shape: tuple[int, int],
        visited: int,
        speed: float = PLACE_SPEED,
        floor: float = PLACE_FLOOR,
        smooth: float = 0.5,
    ) -> MotionTable:
        """The place table of users faster than ``speed`` who drive along street centre lines
        ``lines (e, 2, 2)`` (segment end points, the table's units) uniformly: a map's lanes in
        place of measured ones, so they hold where no training user went (:meth:`fit_place`,
        with the fast users' histogram the length of centre line per table cell). ``visited`` is
        the number of table cells users can be in (the flat density's support). Returns ``self``.
        """
        seg = np.asarray(lines, dtype=np.float64)
        if seg.ndim != 3 or seg.shape[1:] != (2, 2) or not len(seg):
            raise ValueError(f"need street lines of shape (e >= 1, 2, 2), got {seg.shape}")
        if not np.isfinite(seg).all():
            raise ValueError("street lines hold NaN or infinite values")
        _check_place(shape, res, floor, speed, visited)
        # Points every tenth of a cell along every segment: each cell's count is its length of line.
        length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
        n = np.maximum(np.ceil(length / (0.1 * res)).astype(np.int64), 1)
        which = np.repeat(np.arange(len(seg)), n)
        t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / n[which]
        ij, ok = _table_cells(
            seg[which, 0] + t[:, None] * (seg[which, 1] - seg[which, 0]), origin, res, shape
        )
        return self._set_place(ij[ok], visited, origin, res, shape, speed, floor, smooth)

    def _set_place(
        self,
        f: np.ndarray,
        visited: int,
        origin: np.ndarray,
        res: float,
        shape: tuple[int, int],
        speed: float,
        floor: float,
        smooth: float,
    ) -> MotionTable:
        """The place table from the table cells ``f (n, 2)`` int of fast users (see
        :meth:`fit_place`) over ``visited`` cells."""
        from scipy.ndimage import gaussian_filter

        H, W = (int(v) for v in shape)
        # Histogram and smoothing over the fast users' box (and the smoothing's reach) only, and the
        # table kept over the cells they reach plus a border where none went, which lookups outside
        # clamp to: a city's lanes need not cost arrays of the whole area.
        reach = int(np.ceil(4 * smooth)) + 1
        r0, c0 = np.maximum(f.min(0) - reach, 0) if len(f) else (0, 0)
        r1, c1 = np.minimum(f.max(0) + reach + 1, (H, W)) if len(f) else (1, 1)
        counts = np.bincount((f[:, 0] - r0) * (c1 - c0) + f[:, 1] - c0, minlength=(r1 - r0) * (c1 - c0))
        h = gaussian_filter(counts.reshape(r1 - r0, c1 - c0).astype(np.float64), smooth)
        u = max(h.sum() / visited, 1e-12)
        rows, cols = np.flatnonzero((h > 1e-9 * u).any(1)), np.flatnonzero((h > 1e-9 * u).any(0))
        i0, j0 = (rows[0] - 1, cols[0] - 1) if len(rows) else (0, 0)
        i1, j1 = (rows[-1] + 2, cols[-1] + 2) if len(rows) else (1, 1)
        box = np.zeros((i1 - i0, j1 - j0))
        inner = h[max(i0, 0) : i1, max(j0, 0) : j1]
        box[max(-i0, 0) : max(-i0, 0) + inner.shape[0], max(-j0, 0) : max(-j0, 0) + inner.shape[1]] = inner
        box[[0, -1]], box[:, [0, -1]] = 0.0, 0.0
        i0, j0 = i0 + r0, j0 + c0
        self.place_speed = torch.tensor(float(speed), dtype=torch.float64)
        self.log_place = torch.from_numpy(np.log((box + floor * u) / ((1 + floor) * u))).to(torch.float16)
        origin = np.asarray(origin, dtype=np.float64) + np.array([i0, j0]) * res
        self.place_origin = torch.tensor(origin)
        self.place_res = torch.tensor(float(res), dtype=torch.float64)
        return self

    @torch.no_grad()
    def broadened(
        self,
        unit: float = 1.0,
        turn: float = 0.2,
        steer: float = 0.75,
        steer_sigma: tuple[float, float] = (0.7, 0.1),
        flat_step: float = 0.3,
        blocked: tuple[float, float] | None = None,
    ) -> MotionTable:
        """A copy whose motion is far less sure than the measured one, and which has no place
        table: the alternative hypothesis for a user that does not move like the training users.

        Every speed band's acceleration density becomes the mixture of a turn to a uniformly
        random heading at the band's mid speed ``s`` (weight ``turn``; a ring of radius ``s``
        around ``-v``, blurred by ``0.5 + 0.15 s``), isotropic steering noise
        ``N(0, (steer_sigma[0] + steer_sigma[1] s)^2 I)`` (weight ``steer``) and the measured
        density (the rest); the first displacement's density mixes the measured one with a flat
        density over the table's reach (weight ``flat_step``). ``unit`` is the length of one table
        unit in metres (the grid spacing for :meth:`lattice` tables), as ``steer_sigma`` and the
        ring's blur are in metres. The defaults were chosen on the trajectories of
        benchmarks/foreign_motion.py's generators, keeping our own test set's error (docs/estimation.md).

        ``blocked``: weights ``(turn, steer)`` of a second set of classes, for the steps whose way
        straight ahead is blocked (``wall_classes``; :meth:`with_walls` gives the free space): a
        user who drives into a wall turns, one on open ground seldom does.
        """
        weights = [(turn, steer)] + ([] if blocked is None else [tuple(blocked)])
        if not (
            all(t >= 0 and s >= 0 and t + s <= 1 for t, s in weights) and 0 <= flat_step <= 1 and unit > 0
        ):
            raise ValueError(
                f"need weights turn, steer >= 0 with turn + steer <= 1 (and so for blocked), flat_step in "
                f"[0, 1] and unit > 0, got {turn}, {steer}, {blocked}, {flat_step}, {unit}"
            )
        if self.wall_classes:
            raise ValueError("the table has wall classes already: broaden the measured table")
        out = copy.deepcopy(self)
        out.drop_place()
        n_class = len(self.log_accel_table)
        if blocked is not None:
            out.log_accel_table = self.log_accel_table.repeat(2, 1, 1)
            out.band_count = self.band_count.repeat(2)
            out.wall_classes = n_class
        n_acc = self.log_accel_table.shape[1]
        c = -self.reach + (np.arange(n_acc) + 0.5) * self.bin
        p, q = np.meshgrid(c, c, indexing="ij")
        edges = self.speed_edges.double().numpy()
        top = 1.4 * edges[-1] if len(edges) else self.reach / 2
        lo, hi = np.concatenate([[0.0], edges]), np.concatenate([edges, [top]])
        theta = np.linspace(0.0, 2 * np.pi, 72, endpoint=False)[:, None, None]
        h = int(self.headings)
        for k in range(len(out.log_accel_table)):
            turn, steer = weights[k // n_class]
            s = 0.5 * (lo + hi)[(k % n_class) // max(h, 1)]
            # the table's components along and across the motion: in the lattice frame the
            # motion heads at the middle of its heading bin
            phi = (k % h + 0.5) * np.pi / (2 * h) if h else 0.0
            along, across = p * np.cos(phi) + q * np.sin(phi), q * np.cos(phi) - p * np.sin(phi)
            blur = (0.5 + 0.15 * s * unit) / unit
            d2 = (along - s * (np.cos(theta) - 1)) ** 2 + (across - s * np.sin(theta)) ** 2
            ring = np.exp(-d2 / (2 * blur**2)).mean(0) / (2 * np.pi * blur**2)
            sd = (steer_sigma[0] + steer_sigma[1] * s * unit) / unit
            noise = np.exp(-(along**2 + across**2) / (2 * sd**2)) / (2 * np.pi * sd**2)
            measured = np.exp(self.log_accel_table[k % n_class].double().numpy())
            mix = (1 - turn - steer) * measured + turn * ring + steer * noise
            out.log_accel_table[k] = torch.from_numpy(np.log(np.maximum(mix, 1e-300)))
        n_step = len(self.log_step_table)
        r = (np.arange(n_step) + 0.5) * self.bin
        flat = 1.0 / (2 * np.pi * r * n_step * self.bin)  # uniform in length up to the reach, per unit^2
        step = (1 - flat_step) * np.exp(self.log_step_table.double().numpy()) + flat_step * flat
        out.log_step_table.copy_(torch.from_numpy(np.log(step)))
        return out

    def with_walls(self, free: np.ndarray, origin: np.ndarray, res: float) -> MotionTable:
        """Give a table with wall classes (:meth:`broadened` with ``blocked``) the free space
        its steps are read against: ``free (H, W)`` bool, whether the raster point nearest a
        position (``origin (2,)`` plus ``res`` times its index, table units) is free. A step
        after displacement ``v`` to ``x`` reads the wall classes where ``x + v`` or ``x + v / 2``
        is not free (or off the raster). Returns ``self``."""
        free = np.array(free, dtype=bool)
        origin = np.array(origin, dtype=np.float64).reshape(-1)
        if not self.wall_classes:
            raise ValueError("the table has no wall classes: make it with broadened(blocked=...)")
        if free.ndim != 2 or not free.size or origin.shape != (2,) or not np.isfinite(origin).all():
            raise ValueError(
                f"need free (H, W) and a finite origin (2,), got {free.shape} and {origin.shape}"
            )
        if not (math.isfinite(res) and res > 0):
            raise ValueError(f"res must be finite and > 0, got {res}")
        free.flags.writeable = origin.flags.writeable = False  # kept in the kernels' stamp
        self.walls = (free, origin, float(res))
        return self

    @torch.no_grad()
    def speed_pooled(self, above: float = POOLED_SPEED) -> MotionTable | None:
        """A copy in which every speed band from ``above`` up (same units as the table) has one
        acceleration density: the mixture of those bands' densities weighted by their samples in
        the fit. The alternative hypothesis for users as steady as the training users at speeds
        they did not drive at: the generator's vehicles keep three exact speeds, and a band
        between them holds what those do there (corner chords), not steady driving. The cell-level
        part of that hypothesis; its sub-cell part is measured on :func:`speed_scaled` copies of
        the training trajectories (models saved before that pool their sub-cell table too).

        Returns None where there is nothing to pool: the table was not fitted, was saved without
        its band counts, or has fewer than two bands from ``above`` up with samples. The place
        table is kept.
        """
        h = max(int(self.headings), 1)
        lower = np.concatenate([[0.0], self.speed_edges.double().numpy()])
        fast = np.flatnonzero(lower >= above)
        counts = self.band_count.double().numpy().reshape(-1, h)
        if not bool(self.fitted) or (counts[fast].sum(1) > 0).sum() < 2:
            return None
        out = copy.deepcopy(self)
        for k in range(h):  # each heading bin pools its own
            used = fast[counts[fast, k] > 0]
            if not len(used):
                continue
            log_w = torch.from_numpy(np.log(counts[used, k] / counts[used, k].sum()))
            mix = torch.logsumexp(self.log_accel_table[used * h + k].double() + log_w[:, None, None], 0)
            out.log_accel_table[fast * h + k] = mix.to(out.log_accel_table.dtype)
        return out

    @classmethod
    def lattice(cls, n_sub: int = SUBCELLS) -> MotionTable:
        """An unfitted table for positions on the lattice of :func:`snap_to_lattice`, in grid units:
        one bin per lattice step, centred on the lattice's accelerations so that rounding cannot
        move one to the next bin, in the lattice's frame (``headings``)."""
        return cls(bin=1.0 / n_sub, reach=16.0 + 0.5 / n_sub, headings=HEADINGS)

    @property
    def heading_slopes(self) -> np.ndarray:
        """Inner edges ``(headings - 1,)`` of the heading bins as slopes ``v_y / v_x`` within the
        first quadrant (empty in the motion frame); the compiled kernels compare with the same
        numbers."""
        return heading_slopes(int(self.headings))

    def _classify(self, v: torch.Tensor, a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``a``'s two components in the table's frame after displacement ``v`` (broadcast) and
        ``v``'s class (its speed band, and its heading bin in the lattice frame; ``v``'s shape):
        what depends on ``v`` alone is computed once per ``v``."""
        n = v.norm(dim=-1)
        band = torch.bucketize(n, self.speed_edges.to(n.dtype))
        h = int(self.headings)
        if h == 0:
            u = torch.where(
                (n > 0)[..., None], v / n.clamp(min=1e-9)[..., None], torch.tensor([1.0, 0.0], dtype=v.dtype)
            )
            along = (a * u).sum(-1)
            across = a[..., 1] * u[..., 0] - a[..., 0] * u[..., 1]
            return along, across, band
        # the quarter turn that brings v into the quadrant x > 0, y >= 0 (none for v = 0)
        vx, vy = v[..., 0], v[..., 1]
        turn = torch.where(
            (vx > 0) & (vy >= 0),
            0,
            torch.where((vx <= 0) & (vy > 0), 1, torch.where((vx < 0) & (vy <= 0), 2, 3)),
        )
        turn = torch.where((vx == 0) & (vy == 0), 0, turn)
        # rotations by 0, -90, 180 and +90 degrees
        cos = torch.tensor([1.0, 0.0, -1.0, 0.0], dtype=v.dtype)[turn]
        sin = torch.tensor([0.0, -1.0, 0.0, 1.0], dtype=v.dtype)[turn]
        cx, cy = cos * vx - sin * vy, sin * vx + cos * vy
        one = torch.ones((), dtype=v.dtype)
        slope = torch.where(cx > 0, cy / torch.where(cx > 0, cx, one), torch.zeros((), dtype=v.dtype))
        heading = torch.searchsorted(torch.from_numpy(self.heading_slopes).to(v.dtype), slope)
        return cos * a[..., 0] - sin * a[..., 1], sin * a[..., 0] + cos * a[..., 1], band * h + heading

    def _acc_index(self, x: torch.Tensor) -> torch.Tensor:
        return ((x + self.reach) / self.bin).long().clamp(0, self.log_accel_table.shape[1] - 1)

    def log_first(self, v: torch.Tensor) -> torch.Tensor:
        """Log density (per m^2) of a displacement ``v (..., 2)`` m -> ``(...)``."""
        i = (v.norm(dim=-1) / self.bin).long().clamp(max=len(self.log_step_table) - 1)
        return self.log_step_table[i]

    def log_accel(self, v: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """Log density (per m^2) of acceleration ``a (..., 2)`` after displacement ``v (..., 2)``."""
        along, across, cls = self._classify(v, a)
        return self.log_accel_table[cls, self._acc_index(along), self._acc_index(across)]

    @torch.no_grad()
    def sample_accel(self, v: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Accelerations ``(..., 2)`` drawn from the table after displacements ``v (..., 2)``: bin
        centres chosen by the inverse distribution function of the uniform numbers ``u (...)`` in
        ``[0, 1)`` (the same ``u`` and ``v`` draw the same acceleration), turned from the table's
        frame back to the plane's. Edge bins stand for everything beyond them, and are drawn at
        their centres. To draw repeatedly, take :meth:`accel_sampler` once."""
        return self.accel_sampler()(v, u)

    @torch.no_grad()
    def accel_sampler(self) -> Callable[[torch.Tensor, torch.Tensor], torch.Tensor]:
        """:meth:`sample_accel` with the table's distribution functions built once (13 ms for the
        sub-cell table), for as many draws as the table stays unchanged."""
        table = self.log_accel_table.double()
        n_class, n_acc = table.shape[:2]
        cdf = torch.softmax(table.reshape(n_class, -1), dim=-1).cumsum(-1)
        cdf[:, -1] = 1.0
        # every class's distribution function, class c shifted to [c, c + 1]: one sorted array,
        # searched once for all draws instead of gathering a row per draw
        flat = (cdf + torch.arange(n_class, dtype=torch.float64)[:, None]).reshape(-1)
        # bin centres symmetric about zero, so that the middle one is exactly no acceleration
        centre = (torch.arange(n_acc, dtype=torch.float64) - (n_acc - 1) / 2) * self.bin

        def draw(v: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
            e1, e2, cls = self._frame(v.double())
            k = torch.searchsorted(flat, cls + u.double().clamp(0.0, 1.0 - 1e-12)) - cls * n_acc * n_acc
            k = k.clamp(0, n_acc * n_acc - 1)
            # along / across, or the lattice frame's x / y: the table reads a as (a . e1, a . e2)
            return centre[k // n_acc, None] * e1 + centre[k % n_acc, None] * e2

        return draw

    def _frame(self, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The unit vectors ``(..., 2)`` along which :meth:`_classify` reads an acceleration's two
        components after displacement ``v`` (it reads them linearly, so the plane's unit vectors
        give them), and ``v``'s class."""
        one, zero = torch.ones_like(v[..., 0]), torch.zeros_like(v[..., 0])
        first_x, second_x, cls = self._classify(v, torch.stack([one, zero], -1))
        first_y, second_y, _ = self._classify(v, torch.stack([zero, one], -1))
        return torch.stack([first_x, first_y], -1), torch.stack([second_x, second_y], -1), cls

    @torch.no_grad()
    def fit(
        self,
        positions: np.ndarray,
        smooth: float | None = None,
        min_count: int = 200,
        blend: float | None = None,
    ) -> MotionTable:
        """Measure the tables on trajectories ``positions (n, L, 2)`` metres, ``L >= 3``.

        Pass the positions the candidates take, i.e. snapped to the grid. Histograms are smoothed
        by a Gaussian of ``smooth`` bins (default 0.6 in the motion frame; none in the lattice
        frame, whose accelerations are the lattice's own and a blur would smear their pattern) and
        floored so that no motion is impossible; a class with fewer than ``min_count`` samples
        uses the histogram of its speed band (all headings), then that of all speeds. In the
        lattice frame every class's density is mixed with its speed band's blurred by 0.6 bins,
        weight ``blend`` (default :data:`BLEND`), so that motion a little off the training users'
        exact patterns stays likely, and the slowest band (no heading to speak of) has one density
        for all headings, symmetric under quarter turns. Returns ``self``.
        """
        lattice = int(self.headings) > 0
        smooth = (0.0 if lattice else 0.6) if smooth is None else smooth
        blend = (BLEND if lattice else 0.0) if blend is None else blend
        if not 0.0 <= blend <= 1.0:
            raise ValueError(f"blend must lie in [0, 1], got {blend}")
        from scipy.ndimage import gaussian_filter

        p = checked_positions(positions, 3, nonempty=True)
        d = np.diff(p, axis=1)  # displacements; their differences are the accelerations
        step = torch.from_numpy(d.reshape(-1, 2))
        v = torch.from_numpy(d[:, :-1].reshape(-1, 2))
        a = torch.from_numpy(np.diff(d, axis=1).reshape(-1, 2))

        n_step = len(self.log_step_table)
        h = np.bincount(
            np.minimum((step.norm(dim=-1) / self.bin).long().numpy(), n_step - 1), minlength=n_step
        )
        h = np.convolve(h + 1e-3 * len(step) / n_step, [0.25, 0.5, 0.25], mode="same")
        r = (np.arange(n_step) + 0.5) * self.bin
        self.log_step_table.copy_(torch.from_numpy(np.log(h / h.sum() / self.bin / (2 * np.pi * r))))

        along, across, cls = self._classify(v, a)
        ia, ic, cls = self._acc_index(along).numpy(), self._acc_index(across).numpy(), cls.numpy()
        n_acc = self.log_accel_table.shape[1]
        h = max(int(self.headings), 1)

        n_class = len(self.log_accel_table)
        # every class's histogram in one pass; a band's is the sum of its heading bins'
        hist = np.bincount((cls * n_acc + ia) * n_acc + ic, minlength=n_class * n_acc * n_acc)
        hist = hist.reshape(n_class, n_acc, n_acc).astype(np.float64)
        bands = hist.reshape(-1, h, n_acc, n_acc).sum(1)

        def density(counts: np.ndarray, blur: float) -> np.ndarray:
            n = counts.sum()
            d = (gaussian_filter(counts, blur) if blur > 0 else counts) + 5e-3 * max(n, 1) / counts.size
            return d / d.sum() / self.bin**2

        pooled, pooled_wide = density(bands.sum(0), smooth), density(bands.sum(0), 0.6)
        for b, band in enumerate(bands):
            # a class with too few samples takes its speed band's histogram, then all speeds'
            enough = band.sum() >= min_count
            shared = density(band, smooth) if enough else pooled
            wide = (density(band, 0.6) if enough else pooled_wide) if blend > 0 else 0.0
            for c in range(b * h, (b + 1) * h):
                dens = density(hist[c], smooth) if hist[c].sum() >= min_count else shared
                self.log_accel_table[c] = torch.from_numpy(np.log((1 - blend) * dens + blend * wide))
        if lattice:
            # Below the first speed edge a user (mostly one standing still) has no heading to turn
            # its table by: one density for all those headings, the same under quarter turns, so
            # that the table is the same however the lattice is turned.
            slow = self.log_accel_table[:h].double().exp().mean(0).numpy()
            slow = sum(np.rot90(slow, k) for k in range(4)) / 4
            self.log_accel_table[:h] = torch.from_numpy(np.log(slow))
        self.band_count.copy_(
            torch.from_numpy(np.bincount(cls, minlength=len(self.band_count)).astype(np.float64))
        )
        self.fitted.fill_(True)
        return self
