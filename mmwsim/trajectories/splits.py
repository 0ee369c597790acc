"""Train / validation / test splits from disjoint trajectories, with an optional spatial hold-out.

With a hold-out rectangle, every trajectory that touches it (a sample inside, or a segment
crossing it) goes to the test split, and no training or validation trajectory enters it, so
the test split measures generalisation to an area never seen in training.

One rectangle is one place, easy or hard by chance. :func:`block_folds` cuts the whole area into
square blocks and deals them to ``k`` folds in a Latin pattern (no two blocks that share an edge
in one fold), so that each fold holds blocks from all over the area, and holding each fold out in
turn tests every trajectory once, in a model that never saw its blocks (spatial block
cross-validation): the held-out error then covers the whole area's streets, in line of sight and
shadowed, in their own proportions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from .errors import TrajectoryError
from .trajectories import Trajectories

__all__ = ["SPLITS", "BlockFolds", "Region", "block_folds", "split", "touches_region"]

SPLITS: tuple[str, ...] = ("train", "validation", "test")

Region = tuple[float, float, float, float]
"""Axis-aligned rectangle (x0, y0, x1, y1), metres."""


def check_region(region: Region) -> Region:
    """Validate a hold-out rectangle."""
    try:
        x0, y0, x1, y1 = (float(v) for v in region)
    except (TypeError, ValueError):
        raise TrajectoryError(f"hold-out region must be four numbers X0,Y0,X1,Y1, got {region!r}") from None
    if not all(math.isfinite(v) for v in (x0, y0, x1, y1)) or x1 <= x0 or y1 <= y0:
        raise TrajectoryError(f"hold-out region {region!r} must be finite with X0 < X1 and Y0 < Y1")
    return (x0, y0, x1, y1)


def check_fractions(fractions) -> np.ndarray:
    """Validate train / validation / test shares: three numbers >= 0 summing to 1 (within 1e-6).

    Returns
    -------
    (3,) float64, scaled to sum exactly 1.
    """
    try:
        f = np.asarray(fractions, dtype=np.float64)
    except (TypeError, ValueError):
        f = np.zeros(0)
    if f.shape != (3,) or not np.all(np.isfinite(f)) or np.any(f < 0) or abs(f.sum() - 1) > 1e-6:
        raise TrajectoryError(f"split fractions must be three numbers >= 0 that sum to 1, got {fractions!r}")
    return f / f.sum()


def touches_region(positions: np.ndarray, region: Region) -> np.ndarray:
    """Whether any sample or any segment of each trajectory meets the closed rectangle.

    Parameters
    ----------
    positions : (n, L, 2) float, metres
    region : (x0, y0, x1, y1)

    Returns
    -------
    (n,) bool
    """
    p = np.asarray(positions, dtype=np.float64)
    n, length = p.shape[:2]
    box = shapely.box(*check_region(region))
    a = p[:, :-1].reshape(-1, 2)
    b = p[:, 1:].reshape(-1, 2)
    hit = shapely.intersects(shapely.linestrings(np.stack([a, b], axis=1)), box).reshape(n, length - 1)
    return hit.any(axis=1)


def split(
    trajectories: Trajectories,
    fractions: tuple[float, float, float] = (0.8, 0.1, 0.1),
    seed: int = 0,
    holdout_region: Region | None = None,
) -> dict[str, Trajectories]:
    """Split trajectories into disjoint train / validation / test sets.

    Parameters
    ----------
    trajectories : Trajectories
    fractions : (3,) float
        Shares of train, validation and test among the trajectories outside the hold-out
        region; each in [0, 1], summing to 1 (within 1e-6).
    seed : int
        Seeds the shuffle (numpy Generator).
    holdout_region : (x0, y0, x1, y1), optional
        Trajectories touching it go to the test split only.

    Returns
    -------
    dict
        ``{"train": ..., "validation": ..., "test": ...}``; ``.holdout`` marks the trajectories
        that touch the region (all in the test split).
    """
    f = check_fractions(fractions)
    n = len(trajectories)
    held = np.zeros(n, dtype=bool)
    if holdout_region is not None:
        held = touches_region(trajectories.positions, holdout_region)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(101,)))
    free = rng.permutation(np.flatnonzero(~held))
    cuts = np.rint(np.cumsum(f)[:2] * len(free)).astype(int)
    parts = np.split(free, cuts)
    parts[2] = np.concatenate([parts[2], np.flatnonzero(held)])
    out = {}
    for name, idx in zip(SPLITS, parts, strict=True):
        idx = np.sort(idx)
        sub = trajectories.subset(idx)
        sub.holdout = held[idx]
        sub.attrs.update(
            split=name,
            split_fractions=f.tolist(),
            split_seed=int(seed),
            holdout_region=None if holdout_region is None else list(check_region(holdout_region)),
        )
        out[name] = sub
    return out


@dataclass(frozen=True)
class BlockFolds:
    """Trajectories dealt to spatial folds by the square blocks they lie in (see :func:`block_folds`).

    Attributes
    ----------
    bounds : (x0, y0, x1, y1)
        The area cut into blocks, metres.
    block : float
        Block side, metres (the last row and column are cut short where the area is not a
        multiple of it).
    block_fold : (n_y, n_x) int64
        Fold of each block; row ``j`` covers ``y0 + j * block`` onwards, column ``i`` likewise in x.
    fold : (n,) int64
        Each trajectory's fold: that of the block holding its middle sample (index ``L // 2``).
    touches : (n, k) bool
        Whether any sample or segment of each trajectory meets fold ``f``'s blocks (closed squares).
    """

    bounds: Region
    block: float
    block_fold: np.ndarray
    fold: np.ndarray
    touches: np.ndarray

    @property
    def n_folds(self) -> int:
        return int(self.touches.shape[1])

    @property
    def inside(self) -> np.ndarray:
        """(n,) bool: the trajectory meets no block but its own fold's (it crosses no fold border)."""
        return self.touches.sum(axis=1) == 1

    def test(self, fold: int, strict: bool = False) -> np.ndarray:
        """Indices of fold ``fold``'s test trajectories: those assigned to it (every trajectory is in
        exactly one fold's), or with ``strict`` only those of them wholly inside its blocks."""
        keep = self.fold == self._check(fold)
        return np.flatnonzero(keep & self.inside if strict else keep)

    def train(self, fold: int) -> np.ndarray:
        """Indices of the trajectories that may train a model tested on fold ``fold``: those that
        never touch its blocks (no test trajectory of the fold is among them)."""
        return np.flatnonzero(~self.touches[:, self._check(fold)])

    def blocks(self, fold: int) -> list[Region]:
        """The rectangles ``(x0, y0, x1, y1)`` of fold ``fold``'s blocks, metres."""
        js, is_ = np.nonzero(self.block_fold == self._check(fold))
        return [_block_box(self.bounds, self.block, i, j) for j, i in zip(js, is_, strict=True)]

    def fold_at(self, xy: np.ndarray) -> np.ndarray:
        """Fold of the block holding each point of ``xy (..., 2)`` metres -> ``(...)`` int64 (blocks
        are half-open ``[x0, x0 + block)``, the last row and column closed; points outside the area
        count in the nearest block)."""
        return _fold_at(np.asarray(xy, dtype=np.float64), self.bounds, self.block, self.block_fold)

    def _check(self, fold: int) -> int:
        if not 0 <= int(fold) < self.n_folds or int(fold) != fold:
            raise TrajectoryError(f"fold must be an integer in 0..{self.n_folds - 1}, got {fold!r}")
        return int(fold)


def check_blocks(block: float, folds: int, bounds: Region) -> tuple[int, int]:
    """Validate a block side and fold count for ``bounds``; the number of block columns and rows."""
    x0, y0, x1, y1 = check_region(bounds)
    try:
        block = float(block)
    except (TypeError, ValueError):
        raise TrajectoryError(f"block side must be a number of metres, got {block!r}") from None
    if not (math.isfinite(block) and block > 0):
        raise TrajectoryError(f"block side must be a finite number of metres > 0, got {block!r}")
    nx, ny = (max(1, math.ceil((hi - lo) / block - 1e-9)) for lo, hi in ((x0, x1), (y0, y1)))
    if isinstance(folds, bool) or int(folds) != folds or not 2 <= folds <= nx * ny:
        raise TrajectoryError(
            f"folds must be an integer from 2 to the number of blocks ({nx} x {ny} = {nx * ny} of "
            f"{block:g} m), got {folds!r}"
        )
    return nx, ny


def latin_folds(nx: int, ny: int, folds: int) -> np.ndarray:
    """Folds of an ``nx x ny`` array of blocks: block (i, j) goes to ``(i + s j) mod k``, so blocks
    that share an edge are in different folds and each row deals its blocks round the folds in
    turn (for 4 folds of 4 x 4 blocks: one of the four central blocks each). ``s = k // 2``, or
    the smallest ``s`` in 1..k-1 for which no fold is left without a block.

    Returns
    -------
    (ny, nx) int64
    """
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    for s in dict.fromkeys([max(folds // 2, 1), *range(1, folds)]):
        table = (i + s * j) % folds
        if len(np.unique(table)) == folds:
            return table
    raise TrajectoryError(
        f"cannot deal {nx} x {ny} blocks to {folds} folds; use smaller blocks or fewer folds"
    )


def block_folds(
    trajectories: Trajectories | np.ndarray,
    block: float = 100.0,
    folds: int = 4,
    bounds: Region | None = None,
) -> BlockFolds:
    """Spatial block cross-validation folds: every trajectory dealt to one fold by where it lies.

    The area is cut into squares of side ``block`` from its lower-left corner, dealt to the folds
    by :func:`latin_folds`. Rule for a trajectory that crosses a fold border: it is *tested* in the
    fold of the block holding its middle sample (so every trajectory is tested exactly once, and
    the folds together keep the whole area's mix of streets and users), and it *trains* only the
    models of folds whose blocks it never touches (no sample and no segment meets them, blocks
    taken closed). So no model is trained on a trajectory that enters the blocks it is tested
    on; :meth:`BlockFolds.test` with ``strict=True`` keeps only the trajectories wholly inside
    their fold's blocks, a stricter test that under-represents fast users (they cross borders
    more often).

    Parameters
    ----------
    trajectories : Trajectories or (n, L, 2) float array, metres
    block : float
        Block side, metres (default 100).
    folds : int
        Number of folds k, 2 .. number of blocks (default 4).
    bounds : (x0, y0, x1, y1), optional
        The area, metres; default the trajectories' ``attrs["bounds"]`` (``[[x0, y0], [x1, y1]]``,
        as generation stores it). Positions outside it are moved onto its edge first.

    Returns
    -------
    BlockFolds
        Deterministic: no random draw is involved.
    """
    positions = trajectories.positions if isinstance(trajectories, Trajectories) else trajectories
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 2 or p.shape[1] < 1:
        raise TrajectoryError(f"positions must have shape (n, L, 2) with L >= 1, got {p.shape}")
    if bounds is None:
        stored = trajectories.attrs.get("bounds") if isinstance(trajectories, Trajectories) else None
        if stored is None:
            raise TrajectoryError("block folds need the area's bounds (X0, Y0, X1, Y1)")
        bounds = (*stored[0], *stored[1])
    bounds = check_region(bounds)
    nx, ny = check_blocks(block, folds, bounds)
    block = float(block)
    table = latin_folds(nx, ny, int(folds))
    x0, y0, x1, y1 = bounds
    p = np.stack([np.clip(p[..., 0], x0, x1), np.clip(p[..., 1], y0, y1)], axis=-1)
    n, length = p.shape[:2]
    touches = np.zeros((n, int(folds)), dtype=bool)
    if n:
        a, b = (p, p) if length == 1 else (p[:, :-1], p[:, 1:])
        lines = shapely.linestrings(np.stack([a.reshape(-1, 2), b.reshape(-1, 2)], axis=1))
        for f in range(int(folds)):
            cells = zip(*np.nonzero(table == f), strict=True)
            area = shapely.union_all([shapely.box(*_block_box(bounds, block, i, j)) for j, i in cells])
            shapely.prepare(area)
            touches[:, f] = shapely.intersects(lines, area).reshape(n, -1).any(axis=1)
    fold = _fold_at(p[:, length // 2], bounds, block, table)
    return BlockFolds(bounds, block, table, fold, touches)


def _block_box(bounds: Region, block: float, i: int, j: int) -> Region:
    x0, y0, x1, y1 = bounds
    return (
        x0 + i * block,
        y0 + j * block,
        min(x0 + (i + 1) * block, x1),
        min(y0 + (j + 1) * block, y1),
    )


def _fold_at(xy: np.ndarray, bounds: Region, block: float, table: np.ndarray) -> np.ndarray:
    ny, nx = table.shape
    i = np.clip(np.floor((xy[..., 0] - bounds[0]) / block), 0, nx - 1).astype(np.int64)
    j = np.clip(np.floor((xy[..., 1] - bounds[1]) / block), 0, ny - 1).astype(np.int64)
    return table[j, i]
