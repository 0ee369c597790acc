"""Per-step match candidates of known tracks on a 1 m grid, as a fingerprint would rank them."""

from __future__ import annotations

import numpy as np


def grid_candidates(true: np.ndarray, radius: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every step's grid points (1 m grid) within ``radius`` of the cell of ``true (..., T, 2)``
    metres, the cell itself the most likely by 10 nats: ``(candidates (..., T, K, 2),
    log-likelihoods (..., T, K), cells (..., T, 2))``, the cells being the per-step best match."""
    cell = np.rint(true)
    d = np.arange(-radius, radius + 1.0)
    around = np.stack(np.meshgrid(d, d, indexing="ij"), -1).reshape(-1, 2)
    xy = cell[..., None, :] + around
    lp = np.where(np.abs(around).sum(-1) == 0, 0.0, -10.0) * np.ones(xy.shape[:-1])
    return xy, lp, cell
