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
"""

from __future__ import annotations

import numpy as np

from .line import line_track
from .two_lines import FreeRaster, two_line_track

__all__ = ["WALK_FAST", "WALK_MOVE", "WALK_REACH", "near_best", "walk_track"]

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


def _both_passes(tracked, xy, lp, speeds, spacing, restarts, stop_share, free):
    line, delta = line_track(tracked, xy, lp, speeds, spacing)
    return two_line_track(tracked, xy, lp, speeds, spacing, line, delta, restarts, stop_share, free)


def walk_track(
    tracked: np.ndarray,
    xy: np.ndarray,
    lp: np.ndarray,
    speeds: np.ndarray,
    spacing: float,
    restarts: np.ndarray | None = None,
    stop_share: float = 0.0,
    free: FreeRaster | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The walkers' line tracks and their evidence (see the module's text).

    Parameters
    ----------
    tracked, xy, lp, speeds, spacing
        As :func:`~estimation.smoothing.line.line_track` takes them: ``tracked (B, T, 2)``
        metres, ``xy (B, T, K, 2)`` metres, ``lp (B, T, K)``.
    restarts, stop_share, free
        As :func:`~estimation.smoothing.two_lines.two_line_track` takes them.

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
    # the two searches mixed by their evidence: the second's share of it
    both = np.logaddexp(delta[moved], d_other)
    with np.errstate(invalid="ignore"):  # neither search weighs a line: -inf less -inf
        share = np.where(np.isfinite(both), np.exp(d_other - both), 0.0)
    track[moved] += share[:, None, None] * (other - track[moved])
    delta[moved] = both
    return track, delta
