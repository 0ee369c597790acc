"""Train / validation / test splits from disjoint trajectories, with an optional spatial hold-out.

With a hold-out rectangle, every trajectory that touches it (a sample inside, or a segment
crossing it) goes to the test split, and no training or validation trajectory enters it, so
the test split measures generalisation to an area never seen in training.
"""

from __future__ import annotations

import math

import numpy as np
import shapely

from .errors import TrajectoryError
from .trajectories import Trajectories

__all__ = ["SPLITS", "Region", "split", "touches_region"]

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
