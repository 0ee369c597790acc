"""Forecasting from tracked positions: the last displacement carried on.

A tracker (``tn-match``, the smoothers) estimates where a user was at every observed step; the
positions after the last one follow from its last displacement. Measured on the demo's data set
(2 m grid, 6 dB, ``benchmarks/forecast_tn_match.py``), the plain constant-velocity forecast beat
both the mean change of displacement per speed band that :class:`~estimation.smoothing.motion.MotionTable`
measures (2.21 against 2.09 m one second ahead: the mean of a speed band mixes users who stop with
users who cruise) and slopes fitted over more of the track (3 steps 2.34 m, 4 steps 2.51 m: users
turn). It is differentiable in the tracked positions, so a network is trained through it.
"""

from __future__ import annotations

import torch

__all__ = ["extrapolate"]


def extrapolate(positions: torch.Tensor, horizon: int) -> torch.Tensor:
    """Positions ``horizon`` steps past the last of ``positions``, at its last velocity.

    Parameters
    ----------
    positions : (B, T, 2) float, metres
        Tracked positions of the observed steps (one step apart); with ``T = 1`` the user is
        taken to stand.
    horizon : int
        Steps to forecast.

    Returns
    -------
    (B, horizon, 2) float, metres
        Step ``h`` is the position ``h`` steps after the last observed one.
    """
    if positions.ndim != 3 or positions.shape[-1] != 2 or positions.shape[1] < 1:
        raise ValueError(f"need positions of shape (B, T >= 1, 2), got {tuple(positions.shape)}")
    last = positions[:, -1:]
    v = last - positions[:, -2:-1] if positions.shape[1] > 1 else torch.zeros_like(last)
    steps = torch.arange(1, int(horizon) + 1, dtype=positions.dtype)[None, :, None]
    return last + steps * v
