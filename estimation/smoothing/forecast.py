"""Forecasting from tracked positions: the last displacement carried on, along the lanes where the
motion table knows them.

A tracker (``tn-match``, the smoothers) estimates where a user was at every observed step; the
positions after the last one follow from its last displacement (:func:`extrapolate`). Measured on
the demo's data set (2 m grid, 6 dB, ``benchmarks/forecast_tn_match.py``), the plain
constant-velocity forecast beat both the mean change of displacement per speed band that
:class:`~estimation.smoothing.motion.MotionTable` measures (2.21 against 2.09 m one second ahead:
the mean of a speed band mixes users who stop with users who cruise) and slopes fitted over more of
the track (3 steps 2.34 m, 4 steps 2.51 m: users turn). It is differentiable in the tracked
positions, so a network is trained through it.

Users fast enough for the table's place table (vehicles, which keep to lanes) are forecast by
:func:`carry` instead (:func:`forecast_tracks`): particles drawn through the measured accelerations
and weighed by the lanes, read by their geometric median, which, unlike their mean, stays with the
users who drive on rather than between them and the few who stop or turn.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from .motion import MotionTable

__all__ = ["carry", "extrapolate", "forecast_tracks"]

CARRY_PARTICLES = 1024
"""Particles per user of :func:`carry`; 4x as many moved the default data set's forecasts by under
1 % (1000 seen-area test trajectories)."""
_MEDIAN_ITERATIONS = 20  # Weiszfeld steps of the geometric median


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


def _geometric_median(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Weighted geometric median ``(B, 2)`` of points ``x (B, n, 2)`` with weights ``w (B, n)``
    summing to one (Weiszfeld's iteration from the mean)."""
    m = (w[..., None] * x).sum(1)
    for _ in range(_MEDIAN_ITERATIONS):
        inv = w / (x - m[:, None]).norm(dim=-1).clamp(min=1e-6)
        m = (inv[..., None] * x).sum(1) / inv.sum(1, keepdim=True)
    return m


@torch.no_grad()
def carry(
    table: MotionTable, prev: torch.Tensor, last: torch.Tensor, horizon: int, particles: int = CARRY_PARTICLES
) -> torch.Tensor:
    """Where users go after positions ``prev`` and ``last``, by the motion table.

    Every user's particles start at its last displacement; each step draws an acceleration per
    particle from the table (:meth:`MotionTable.accel_sampler`), weighs the new position by the
    place table (:meth:`MotionTable.log_place_ratio`: lanes, for fast users) and resamples. The
    uniform numbers are the same for every user, so a user's forecast does not depend on the
    others in its batch, and the same inputs give the same bytes.

    Parameters
    ----------
    table : MotionTable
        Measured tables, in their own units (the sub-cell table's: grid units).
    prev, last : (B, 2) float
        The last two tracked positions, in the table's units (the place table's frame).
    horizon : int
        Steps to forecast.
    particles : int

    Returns
    -------
    (B, horizon, 2) float64
        The weighted geometric median of the particles at every step, in the table's units.
    """
    prev, last = prev.double(), last.double()
    B, n = len(last), int(particles)
    gen = torch.Generator().manual_seed(0)
    # stratified: one number in each of n equal slices of [0, 1), in a fixed shuffled order per step
    draws = [
        (torch.randperm(n, generator=gen) + torch.rand(n, generator=gen, dtype=torch.float64)) / n
        for _ in range(int(horizon))
    ]
    spokes = (torch.arange(n, dtype=torch.float64) + 0.5) / n  # systematic resampling
    v = (last - prev)[:, None].expand(B, n, 2)
    x = last[:, None].expand(B, n, 2)
    draw = table.accel_sampler()
    out = []
    for h in range(int(horizon)):
        v = v + draw(v, draws[h].expand(B, n))
        # float noise must not take a user moving along an axis into the next quarter's frame
        v = torch.where(v.abs() < 1e-9, 0.0, v)
        x = x + v
        w = torch.softmax(table.log_place_ratio(v, x).double(), dim=1)
        out.append(_geometric_median(x, w))
        idx = torch.searchsorted(w.cumsum(1), spokes.expand(B, n).contiguous()).clamp(max=n - 1)[..., None]
        v, x = v.gather(1, idx.expand(B, n, 2)), x.gather(1, idx.expand(B, n, 2))
    return torch.stack(out, 1) if out else torch.zeros(B, 0, 2, dtype=torch.float64)


def forecast_tracks(tracked: torch.Tensor, horizon: int, table: MotionTable, spacing: float) -> torch.Tensor:
    """The forecast of tracked users: :func:`carry` through ``table`` for users faster than its
    place table's speed, :func:`extrapolate` for the others (and for all where the table has no
    place table, or only one step was tracked).

    Parameters
    ----------
    tracked : (B, T, 2) float, metres
    horizon : int
    table : MotionTable
        The sub-cell table (grid units), with the lanes the tracker uses.
    spacing : float
        The grid's spacing, metres (one grid unit).

    Returns
    -------
    (B, horizon, 2), ``tracked``'s dtype, metres
    """
    out = extrapolate(tracked, horizon)
    if tracked.shape[1] < 2 or not table.has_place:
        return out
    step = (tracked[:, -1] - tracked[:, -2]).double().norm(dim=-1) / spacing
    fast = step > float(table.place_speed)
    if fast.any():
        grid = tracked[fast].double() / spacing
        out[fast] = (carry(table, grid[:, -2], grid[:, -1], horizon) * spacing).to(out.dtype)
    return out
