"""The check every fit on training trajectories makes of the positions it is given."""

from __future__ import annotations

import numpy as np

__all__ = ["checked_positions"]


def checked_positions(
    positions: np.ndarray, min_length: int = 2, nonempty: bool = False, what: str = "positions"
) -> np.ndarray:
    """``positions (n, L, 2)`` as float64, with ``L >= min_length`` (and ``n >= 1`` where
    ``nonempty``); a ``ValueError`` naming the problem otherwise (``what`` names them)."""
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 2 or p.shape[1] < min_length or (nonempty and not len(p)):
        raise ValueError(f"need {what} of shape (n, L >= {min_length}, 2), got {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("positions hold NaN or infinite values")
    return p
