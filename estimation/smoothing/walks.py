"""The walkers' tracks: straight lines, walks of two lines, and a second search for fast walkers.

:func:`walk_track` composes the passes of :mod:`~estimation.smoothing.line` and
:mod:`~estimation.smoothing.two_lines`, which search around the smoother's track. A fast walker
(a cyclist) whose track the smoother read too slow, or cut across a corner, lies outside what
they search: its true walk is likelier than the track, but a metre per step faster or metres
off the corner the track cut. So for each walker whose track's median step exceeds
:data:`WALK_FAST` spacings, both passes run again around a second centre, each step's likeliest
candidate within :data:`WALK_REACH` of the tracked point, where that centre lies more than
:data:`WALK_MOVE` from the track at some step. The two searches are mixed by their evidence, as
the families within each are.

The measured speeds are the training walkers' habits. A walker who keeps a speed of its own
(brisker, slower, a cyclist between our gears) finds no line at them, and the smoother, whose
tables hold our speeds' lattice patterns, reads it less well than it reads ours. So with
``free_prior`` every search runs once more with a flat speed prior (:func:`free_speeds`), for
the walkers whose walks at the measured speeds explain their steps less well than
:data:`WALK_FREE_BELOW`, and the two priors' walks are mixed by their evidence, the flat prior's
share of it ``free_prior`` (:data:`WALK_FREE_PRIOR` in :class:`~estimation.Estimator`).
"""

from __future__ import annotations

import numpy as np

from .line import _MIN_STEP, LINE_BINS, line_track
from .two_lines import FreeRaster, two_line_track

__all__ = [
    "WALK_FAST",
    "WALK_FREE_BELOW",
    "WALK_FREE_PRIOR",
    "WALK_MOVE",
    "WALK_REACH",
    "free_speeds",
    "near_best",
    "walk_track",
]

WALK_FAST = 2.0
"""Grid spacings per step: a walker whose track's median step is longer is searched around a
second centre too. On 1000 users per kind of ``default.zarr`` (`runs/tn-match-tracking` of the
README, three draws of each of validation, seen area and held out), cyclists -0.4 to -1.9 % on
all nine draws (validation -1.4 / -1.8 / -1.1 %), pedestrians within 0.2 %. Without this gate
the pedestrians' aliases lose what the cyclists gain: pedestrians -0.8 to +1.0 % (validation
+1.0 / -0.2 / -0.4 %)."""
WALK_REACH = 5.0
"""Grid spacings from each tracked point within which the second centre takes the likeliest
candidate. On the validation draws of :data:`WALK_FAST` (mean of the three), cyclists -1.4 % at 5
spacings; at 1.5 and 2 of the track's median steps (3 to 5 spacings for these walkers) -0.8 and
-1.2 %."""
WALK_MOVE = 1.0
"""Grid spacings: the second search runs only for walkers whose second centre lies farther than
this from the track at some step (a third to a half of the cyclists; at 0.5 the same gains)."""
WALK_FREE_PRIOR = 0.3
"""Prior share of the walks at a flat speed prior beside the measured one (see the module's text).
On the walkers' inputs of ``runs/tn-match-tracking`` of the README (500 each of our own walkers
at other mean speeds, 1000 each of our own and the foreign ones; priors 0.05 / 0.1 / 0.2 / 0.3 /
0.5): pedestrians at 2.2 m/s -2.4 / -3.0 / -3.6 / -4.1 / -4.7 %, cyclists at 2.2 m/s -2.5 /
-3.2 / -3.9 / -4.5 / -5.4 %, our own pedestrians within 0.1 %, our own cyclists +0.0 / +0.0 /
+0.1 / +0.1 / +0.2 %; the ``events`` cyclists -1.2 % at 0.1 to -1.9 % at 0.5."""
WALK_FREE_BELOW = -10.0
"""Nats: walkers whose walks at the measured speeds have at least this evidence are not searched
at the flat prior. On the inputs of :data:`WALK_FREE_PRIOR` (no gate / -8 / -10 / -12 / -14
nats): our own pedestrians searched 100 / 82 / 52 / 29 / 15 %, cyclists 100 / 91 / 74 / 66 / 52
%; pedestrians at 2.2 m/s -4.1 / -4.1 / -4.0 / -3.8 / -3.3 %, the ``events`` pedestrians -0.6 /
-0.6 / -0.5 / -0.4 / -0.2 %; our own within 0.02 % of no gate."""


def near_best(tracked: np.ndarray, xy: np.ndarray, lp: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """Each step's likeliest candidate within ``reach`` of the tracked point.

    Parameters
    ----------
    tracked : (B, T, 2) float, metres
    xy : (B, T, K, 2) float, metres
        Every step's candidate grid points.
    lp : (B, T, K) float
        Their log-likelihoods.
    reach : (B,) float, metres

    Returns
    -------
    (B, T, 2) float64, metres
        The candidates; the tracked point where none lies within ``reach``.
    """
    tracked = np.asarray(tracked, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    near = np.linalg.norm(xy - tracked[:, :, None], axis=-1) <= np.asarray(reach, np.float64)[:, None, None]
    k = np.where(near, lp, -np.inf).argmax(-1)
    best = np.take_along_axis(xy, k[..., None, None], 2)[:, :, 0]
    return np.where(near.any(-1)[..., None], best, tracked)


def free_speeds(speeds: np.ndarray) -> np.ndarray:
    """A flat speed prior ``(V,)`` over the bins of ``speeds (V,)`` (as
    :func:`~estimation.smoothing.line.walk_speeds` gives them), from the slowest step a line is
    weighed at (half a spacing) to the fastest bin: every speed a walker may keep, alike."""
    p = np.zeros(len(speeds))
    p[int(np.ceil(_MIN_STEP * LINE_BINS)) :] = 1.0
    return p / p.sum() if p.any() else p


def _both_passes(tracked, xy, lp, speeds, spacing, restarts, stop_share, free):
    line, delta = line_track(tracked, xy, lp, speeds, spacing)
    return two_line_track(tracked, xy, lp, speeds, spacing, line, delta, restarts, stop_share, free)


def _mix(track, delta, other, d_other, rows):
    """``track (B, T, 2)`` and ``delta (B,)`` at ``rows`` mixed in place with another search's
    ``other`` and ``d_other`` there, by their evidence."""
    both = np.logaddexp(delta[rows], d_other)
    with np.errstate(invalid="ignore"):  # neither search weighs a line: -inf less -inf
        share = np.where(np.isfinite(both), np.exp(d_other - both), 0.0)
    track[rows] += share[:, None, None] * (other - track[rows])
    delta[rows] = both


def walk_track(
    tracked: np.ndarray,
    xy: np.ndarray,
    lp: np.ndarray,
    speeds: np.ndarray,
    spacing: float,
    restarts: np.ndarray | None = None,
    stop_share: float = 0.0,
    free: FreeRaster | None = None,
    free_prior: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The walkers' line tracks and their evidence (see the module's text).

    Parameters
    ----------
    tracked, xy, lp, speeds, spacing
        As :func:`~estimation.smoothing.line.line_track` takes them: ``tracked (B, T, 2)``
        metres, ``xy (B, T, K, 2)`` metres, ``lp (B, T, K)``.
    restarts, stop_share, free
        As :func:`~estimation.smoothing.two_lines.two_line_track` takes them.
    free_prior : float in [0, 1)
        Prior share of the walks at a flat speed prior (:func:`free_speeds`) beside ``speeds``,
        for the walkers below :data:`WALK_FREE_BELOW`; 0 searches ``speeds`` alone.

    Returns
    -------
    track : (B, T, 2) float64, metres
        The posterior mean over every search's lines.
    delta : (B,) float64
        Their evidence, nats, in the straight lines' units (``-inf`` where no line is weighed);
        the caller mixes the track with ``tracked`` by
        :func:`~estimation.smoothing.line.line_weight`.
    """
    tracked = np.ascontiguousarray(tracked, dtype=np.float64)
    rest = (spacing, restarts, stop_share, free)
    track, delta = _searched(tracked, xy, lp, speeds, *rest)
    # the walks at the measured speeds that explain a walker's steps hold it already
    rows = np.flatnonzero(~(delta >= WALK_FREE_BELOW)) if free_prior > 0.0 and len(speeds) else []
    if len(rows):
        other, d_other = _searched(tracked[rows], xy[rows], lp[rows], free_speeds(speeds), *rest)
        delta[rows] += np.log1p(-free_prior)
        _mix(track, delta, other, d_other + np.log(free_prior), rows)
    return track, delta


def _searched(tracked, xy, lp, speeds, spacing, restarts, stop_share, free):
    """:func:`walk_track` at one speed prior: both passes, and around a second centre for fast
    walkers."""
    args = (speeds, spacing, restarts, stop_share, free)
    track, delta = _both_passes(tracked, xy, lp, *args)
    if tracked.shape[0] == 0 or tracked.shape[1] < 2:
        return track, delta
    typical = np.median(np.linalg.norm(np.diff(tracked, axis=1), axis=-1), axis=1)
    fast = np.flatnonzero(typical > WALK_FAST * spacing)
    if not len(fast):
        return track, delta
    centre = near_best(tracked[fast], xy[fast], lp[fast], np.full(len(fast), WALK_REACH * spacing))
    far = np.linalg.norm(centre - tracked[fast], axis=-1).max(1) > WALK_MOVE * spacing
    if not far.any():
        return track, delta
    moved = fast[far]
    other, d_other = _both_passes(np.ascontiguousarray(centre[far]), xy[moved], lp[moved], *args)
    _mix(track, delta, other, d_other, moved)
    return track, delta
