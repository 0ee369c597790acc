"""Tracks of walkers who stop once: a line, one step standing still, a line on from there.

A walker who stops for a step leaves no straight line through its candidates, so the straight-line
pass (:mod:`~estimation.smoothing.line`) gives it up to the smoother, though both of its pieces
are lines at measured speeds that pin it down as well as a straight walk does. After a stop the
training users set off at a handful of speeds (the generator's own mean speed, for ours) in any
direction. :func:`stop_track` weighs, for each user whose track holds a short step, lines with a
stop at that step: the first piece ending where the user stands, at one of the measured walk
speeds (:func:`~estimation.smoothing.line.walk_speeds`); the second starting there, at one of
the measured restart speeds (:func:`walk_restarts`), in a heading of its own. Each family's
lines are drawn in stages around its posterior, as the straight lines are, over six coordinates
(where it stands, the two headings and the two speeds).

The straight-line family and every stop family are mixed by their evidence, a stop weighed by
the share of the training walkers' moving steps that a stop followed (:func:`walk_restarts`)
times ``exp(STOP_BIAS)``. The mixture's evidence takes the place of the straight lines' own
``delta`` (the same units: a user without a short step keeps both).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mmwsim._threads import batch_map

from ._positions import checked_positions
from .line import _MIN_STEP, LINE_BINS, LINE_LINES, LINE_REACH, LINE_SPEEDS, LINE_TURN, _offsets, fill_raster

__all__ = ["STOP_BIAS", "STOP_GATE", "stop_track", "walk_restarts"]

STOP_GATE = 1.0
"""Grid spacings: a step of the track shorter than this may be a stop, and is weighed as one."""
STOP_STAGES = 3
"""Stages of lines per stop family, each within the box of the previous one's posterior."""
STOP_BIAS = 1.4
"""Nats added to the log share of stops in a stop family's prior. Chosen on 1000 validation users
per kind of ``default.zarr`` (three draws; its stop share is 0.091): priors of -1.6 to 0 nats in
all were within 0.05 % of each other on the pedestrians, -2.2 (the share against the steps that
change nothing) 0.07 % behind."""
STOP_WINDOW = 0.8
"""Grid spacings per step: the walk speeds weighed for the first piece lie this near its fitted
line's."""
STOP_TURN = 0.5
"""Radians a piece's heading may differ from its fitted line's where it spans three steps or
fewer (:data:`~estimation.smoothing.line.LINE_TURN` where longer)."""
STOP_HALF = 5
"""Grid spacings either side of each step's tracked point that its raster of candidates spans."""
_OFFSETS6 = _offsets(LINE_LINES, 6)


def walk_restarts(positions: np.ndarray, max_step: float) -> tuple[np.ndarray, float]:
    """How the users who walk set off after a stop, and how often they stop.

    Parameters
    ----------
    positions : (n, L >= 2, 2) float
        Trajectories as they are (not snapped), in grid spacings.
    max_step : float
        The walkers' largest median step (the place tables' speed), grid spacings.

    Returns
    -------
    restarts : (V,) float64
        The share of the steps that follow a stop (one no longer than half a spacing), per length
        in bins of ``1 / LINE_BINS`` of a spacing, summing to 1 (empty where there is none).
    stop_share : float
        The share of the moving steps followed by a stop (0 where there is none).
    """
    p = checked_positions(positions)
    step = np.linalg.norm(np.diff(p, axis=1), axis=-1)
    s = step[np.median(step, axis=1) <= max_step]
    moving = s[:, :-1] > _MIN_STEP
    after = s[:, 1:][(s[:, :-1] <= _MIN_STEP) & (s[:, 1:] > _MIN_STEP)]
    if not after.size or not moving.any():
        return np.zeros(0), 0.0
    counts = np.bincount(np.rint(after * LINE_BINS).astype(np.int64))
    return counts / counts.sum(), float((moving & (s[:, 1:] <= _MIN_STEP)).sum() / moving.sum())


def stop_track(
    tracked: np.ndarray,
    xy: np.ndarray,
    lp: np.ndarray,
    speeds: np.ndarray,
    restarts: np.ndarray,
    stop_share: float,
    spacing: float,
    line: np.ndarray,
    delta: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The straight-line tracks ``line``, ``delta`` of
    :func:`~estimation.smoothing.line.line_track` mixed with lines that stop once (see the
    module's text).

    Parameters
    ----------
    tracked, xy, lp, speeds, spacing
        As :func:`~estimation.smoothing.line.line_track` took them.
    restarts : (V,) float
        The measured share of the steps after a stop per length bin (:func:`walk_restarts`).
    stop_share : float
        The measured share of moving steps followed by a stop.
    line : (B, T, 2) float, metres
        The straight lines' posterior mean.
    delta : (B,) float
        Their evidence, nats.

    Returns
    -------
    track : (B, T, 2) float64, metres
        The mixture's posterior mean; ``line`` where no stop is weighed.
    delta : (B,) float64
        The mixture's evidence, nats, in the units of the straight lines'.
    """
    line = np.ascontiguousarray(line, dtype=np.float64)
    delta = np.asarray(delta, dtype=np.float64)
    B, T = line.shape[:2]
    if B == 0 or T < 3 or not len(restarts) or not len(speeds) or stop_share <= 0:
        return line.copy(), delta.copy()
    return batch_map(
        _stop_kernel, 5, np.ascontiguousarray(tracked, np.float64), np.ascontiguousarray(xy, np.float64),
        np.ascontiguousarray(lp, np.float64), line, delta, np.asarray(speeds, np.float64),
        np.asarray(restarts, np.float64), float(np.log(stop_share) + STOP_BIAS), float(spacing), _OFFSETS6,
    )  # fmt: skip


@njit(cache=True, nogil=True)
def _fit(tr, a, b):  # pragma: no cover - compiled
    """Least-squares velocity per step ``(vx, vy)`` through the track's steps ``a..b``."""
    mid = (a + b) / 2.0
    tt, vx, vy = 0.0, 0.0, 0.0
    for t in range(a, b + 1):
        tt += (t - mid) ** 2
    for t in range(a, b + 1):
        vx += (t - mid) * tr[t, 0] / tt
        vy += (t - mid) * tr[t, 1] / tt
    return vx, vy


@njit(cache=True, nogil=True)
def _bins(prior, lo, hi):  # pragma: no cover - compiled
    """The bins ``lo..hi`` of ``prior`` that hold any share, and their log shares."""
    n = 0
    for j in range(lo, hi + 1):
        if prior[j] > 0.0:
            n += 1
    bins, log_prior = np.empty(n, np.int64), np.empty(n)
    k = 0
    for j in range(lo, hi + 1):
        if prior[j] > 0.0:
            bins[k], log_prior[k] = j, np.log(prior[j])
            k += 1
    return bins, log_prior


@njit(cache=True, nogil=True)
def _weigh_stops(
    jv,
    at,
    head,
    turn,
    box,
    bins_a,
    lp_a,
    range_a,
    bins_b,
    lp_b,
    range_b,
    offsets,
    ox,
    oy,
    raster,
    spacing,
    ll,
    px,
    py,
):  # pragma: no cover - compiled
    """One stage of the lines that stand at step ``jv`` and ``jv + 1``: where they stand within
    :data:`LINE_REACH` of ``at (2,)``, the two pieces' headings within ``turn (2,)`` of
    ``head (2,)``, their speeds in the bins ``range_a``, ``range_b`` (lowest, highest) of
    ``bins_a``, ``bins_b``; ``box (12,)`` the fractions of those ranges drawn in. Log-likelihoods
    into ``ll``, points into ``px``, ``py``; returns the largest."""
    T = raster.shape[0]
    side = raster.shape[1]
    bin_w = spacing / LINE_BINS
    n_a, n_b = range_a[1] - range_a[0] + 1, range_b[1] - range_b[0] + 1
    f = np.empty(6)
    top = -np.inf
    for n in range(offsets.shape[0]):
        for d in range(6):
            f[d] = box[2 * d] + offsets[n, d] * (box[2 * d + 1] - box[2 * d])
        sx = at[0] + (2.0 * f[0] - 1.0) * LINE_REACH * spacing
        sy = at[1] + (2.0 * f[1] - 1.0) * LINE_REACH * spacing
        ha = head[0] + (2.0 * f[2] - 1.0) * turn[0]
        hb = head[1] + (2.0 * f[4] - 1.0) * turn[1]
        ka = range_a[0] + min(int(f[3] * n_a), n_a - 1)
        kb = range_b[0] + min(int(f[5] * n_b), n_b - 1)
        sa, sb = bins_a[ka] * bin_w, bins_b[kb] * bin_w
        v = lp_a[ka] + lp_b[kb]
        for t in range(T):
            if t <= jv:
                x, y = sx - (jv - t) * sa * np.cos(ha), sy - (jv - t) * sa * np.sin(ha)
            else:
                x, y = sx + (t - jv - 1) * sb * np.cos(hb), sy + (t - jv - 1) * sb * np.sin(hb)
            px[n, t], py[n, t] = x, y
            i = min(max(int(np.rint((x - ox[t]) / spacing)), 0), side - 1)
            j = min(max(int(np.rint((y - oy[t]) / spacing)), 0), side - 1)
            v += raster[t, i, j]
        ll[n] = v
        top = max(top, v)
    return top


@njit(cache=True, nogil=True)
def _stop_family(
    tr, jv, speeds, restarts, spacing, offsets, ox, oy, raster, ll, px, py, mean
):  # pragma: no cover - compiled
    """Log evidence of the lines that stop at step ``jv`` (in the straight lines' measure: the
    first heading by the straight lines' density, the second by ``1 / 2 pi``); their posterior
    mean into ``mean (T, 2)``. ``-inf`` where no walk speed lies near the first piece's."""
    T = tr.shape[0]
    N = offsets.shape[0]
    bin_w = spacing / LINE_BINS
    before, after = jv >= 1, jv + 1 <= T - 2  # pieces of two or more steps
    at = np.array([0.5 * (tr[jv, 0] + tr[jv + 1, 0]), 0.5 * (tr[jv, 1] + tr[jv + 1, 1])])
    head = np.zeros(2)
    turn = np.array([STOP_TURN, STOP_TURN])
    one = np.ones(1, np.int64), np.zeros(1)  # a piece of one step: no speed, no heading
    bins_a, lp_a = one
    bins_b, lp_b = one
    if before:
        vx, vy = _fit(tr, 0, jv)
        head[0] = np.arctan2(vy, vx)
        s0 = np.hypot(vx, vy)
        lo = max(int(np.floor((s0 - STOP_WINDOW * spacing) / bin_w)), 0)
        hi = min(int(np.ceil((s0 + STOP_WINDOW * spacing) / bin_w)), len(speeds) - 1)
        bins_a, lp_a = _bins(speeds, lo, hi)
        if not len(bins_a):
            return -np.inf
        if jv >= 3:
            turn[0] = LINE_TURN
    if after:
        vx, vy = _fit(tr, jv + 1, T - 1)
        head[1] = np.arctan2(vy, vx)
        bins_b, lp_b = _bins(restarts, 0, len(restarts) - 1)
        if T - 2 - jv >= 3:
            turn[1] = LINE_TURN
    box = np.array([0.0, 1.0] * 6)
    range_a = np.array([0, len(bins_a) - 1])
    range_b = np.array([0, len(bins_b) - 1])
    lines_apart = 1.0 / N ** (1.0 / 6.0)  # of a box's side, for N quasi-random lines in six dimensions
    log_ev = -np.inf
    m1, m2 = np.zeros(6), np.zeros(6)
    for stage in range(STOP_STAGES):
        top = _weigh_stops(
            jv, at, head, turn, box, bins_a, lp_a, range_a, bins_b, lp_b, range_b, offsets, ox, oy,
            raster, spacing, ll, px, py,
        )  # fmt: skip
        total = 0.0
        mean[:] = 0.0
        m1[:] = 0.0
        m2[:] = 0.0
        for n in range(N):
            w = np.exp(ll[n] - top)
            total += w
            for t in range(T):
                mean[t, 0] += w * px[n, t]
                mean[t, 1] += w * py[n, t]
            for d in range(6):
                g = box[2 * d] + offsets[n, d] * (box[2 * d + 1] - box[2 * d])
                m1[d] += w * g
                m2[d] += w * g * g
        mean /= total
        share = (box[1] - box[0]) * (box[3] - box[2])
        log_ev = top + np.log(total / N)
        if before:
            share *= (box[5] - box[4]) * len(bins_a)
            log_ev += np.log(turn[0] / LINE_TURN)
        if after:
            share *= (box[9] - box[8]) * len(bins_b)
            log_ev += np.log(turn[1] / np.pi)
        log_ev += np.log(share)
        if stage + 1 == STOP_STAGES:
            break
        # the next stage's box: where it stands and the headings of the pieces that have one
        for d in range(5):
            if d == 3 or (d == 2 and not before) or (d == 4 and not after):
                continue
            mu = m1[d] / total
            sd = np.sqrt(max(m2[d] / total - mu * mu, 0.0))
            width = max(4.0 * sd, 1.5 * lines_apart * (box[2 * d + 1] - box[2 * d]))
            box[2 * d], box[2 * d + 1] = max(mu - width, box[2 * d]), min(mu + width, box[2 * d + 1])
    return log_ev


@njit(cache=True, nogil=True)
def _stop_kernel(
    tracked, xy, lp, line, delta, speeds, restarts, log_stop, spacing, offsets
):  # pragma: no cover - compiled
    B, T, K = lp.shape
    N = offsets.shape[0]
    out = line.copy()
    mixed = delta.copy()
    ll, px, py = np.empty(N), np.empty((N, T)), np.empty((N, T))
    mean = np.empty((T, 2))
    side = 2 * STOP_HALF + 1
    raster = np.empty((T, side, side))
    ox, oy = np.empty(T), np.empty(T)
    ts = np.arange(T) - (T - 1) / 2.0
    tt = (ts * ts).sum()
    bin_w = spacing / LINE_BINS
    for b in range(B):
        tr = tracked[b]
        short = np.zeros(T - 1, np.bool_)
        for t in range(T - 1):
            short[t] = np.hypot(tr[t + 1, 0] - tr[t, 0], tr[t + 1, 1] - tr[t, 1]) < STOP_GATE * spacing
        vx, vy = 0.0, 0.0
        for t in range(T):
            vx += ts[t] * tr[t, 0] / tt
            vy += ts[t] * tr[t, 1] / tt
        s0 = np.hypot(vx, vy)
        if not short.any() or short.all():  # no stop, or a user who never moves
            continue
        # the straight lines' evidence summed over their speed bins (line_track's is per bin)
        lo = max(int(np.floor((s0 - LINE_SPEEDS * spacing) / bin_w)), 0)
        hi = min(int(np.ceil((s0 + LINE_SPEEDS * spacing) / bin_w)), len(speeds) - 1)
        n_bins = max(len(_bins(speeds, lo, hi)[0]), 1)
        best = fill_raster(xy[b], lp[b], tr, spacing, raster, ox, oy)
        ev_line = delta[b] + best + np.log(n_bins)
        top = ev_line
        ev = np.full(T - 1, -np.inf)
        means = np.zeros((T - 1, T, 2))
        for jv in range(T - 1):
            if short[jv]:
                ev[jv] = _stop_family(
                    tr, jv, speeds, restarts, spacing, offsets, ox, oy, raster, ll, px, py, mean
                )
                ev[jv] += log_stop
                means[jv] = mean
                top = max(top, ev[jv])
        if top == -np.inf:
            continue
        total = 0.0
        acc = np.zeros((T, 2))
        if ev_line > -np.inf:
            w = np.exp(ev_line - top)
            total += w
            acc += w * line[b]
        for jv in range(T - 1):
            if ev[jv] > -np.inf:
                w = np.exp(ev[jv] - top)
                total += w
                acc += w * means[jv]
        out[b] = acc / total
        mixed[b] = top + np.log(total) - np.log(n_bins) - best
    return out, mixed
