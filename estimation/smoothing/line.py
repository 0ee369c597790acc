"""Tracks of users who walk a straight line at one of the measured speeds.

A walker or cyclist who keeps its heading and speed over a sequence crosses cell boundaries at
times that pin down where along the line it is, as a vernier does, to far below the grid
spacing, but only for a model that knows the speed: the training users keep a handful of exact
speeds (the generator's, or any population's habits), which a lattice of a third of a cell
blurs. :func:`line_track` weighs, for each user, straight lines at constant speed around a
least-squares line through its track: every line by the measured prior of its speed (in bins of
1 / :data:`LINE_BINS` of the grid spacing) times the fingerprint likelihood of the candidate
grid points it passes at each step. The lines' posterior mean is the straight-line track.

The lines are drawn in :data:`LINE_STAGES` stages of :data:`LINE_LINES` each: the first spread over
the whole range of centres, headings and speeds; each later one over the box that holds the
previous stage's posterior (:data:`LINE_SPREAD` of its standard deviations either side, in each
of the four), where most of the first stage's lines had next to no weight. The last stage gives
the track and the evidence (its mean likelihood times its box's share of the range).

How far to believe it is the evidence: ``delta``, the log of the lines' mean likelihood less the
best candidates' at every step (how much the straight line costs against following the best
candidate each step). A user who turns or changes speed within the sequence finds no line
through its candidates and ``delta`` drops by tens of nats. The caller mixes the two tracks by
``sigmoid((delta - LINE_SHIFT) / LINE_SCALE)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mmwsim._threads import batch_map

from ._positions import checked_positions

__all__ = ["LINE_BINS", "LINE_MIN_STEPS", "LINE_STAGES", "line_track", "line_weight", "walk_speeds"]

LINE_BINS = 20
"""Bins of the measured speeds per grid spacing per step (5 cm on a 1 m grid)."""
LINE_MIN_STEPS = 4
"""Sequences shorter than this are left as they are: three cells leave a line too free."""
LINE_LINES = 4096
"""Lines weighed per user and stage (a fixed quasi-random set of offsets: the same for every
user)."""
LINE_STAGES = 2
"""Stages of lines per user, each within the box of the previous one's posterior. A second stage
took the pedestrians of ``default.zarr``'s test set 0.8 % lower, as 65 536 lines in one stage do
(docs/estimation.md); a third moved nothing."""
LINE_SPREAD = 4.0
"""Posterior standard deviations either side of its mean that a later stage's box spans, at least
one and a half of the previous stage's spacing of lines."""
LINE_REACH = 0.75
"""Grid spacings the lines' centre (the track's middle step) may lie from the fitted line's."""
LINE_TURN = 0.3
"""Radians the lines' heading may differ from the fitted line's."""
LINE_SPEEDS = 0.6
"""Grid spacings per step: the measured speeds weighed lie this near the fitted line's."""
LINE_SHIFT = -14.0
"""Nats of ``delta`` at which the straight-line track takes half the weight (see the module).
With :data:`LINE_SCALE`, chosen on 1000 validation users per kind of ``default.zarr`` (three
draws, 7 steps; shifts -18 to -8 nats, scales 2 to 6) with the walks of two lines mixed in
(:mod:`~estimation.smoothing.two_lines`), and checked on sequences of 5 and 15 steps (one
draw): the best of -4 to -14 at 5 steps, 0.5 % behind -20 (the best of -46 to -10) at 15.
Before those walks, -10 and 3 were the best for 4 to 7 steps."""
LINE_SCALE = 4.0
"""Nats of ``delta`` per unit of the logistic: the weight goes from a quarter to three quarters
over ``2 ln 3`` times this (8.8 nats)."""
_MIN_STEP = 0.5  # grid spacings per step: a slower user (a static one, or a stop) is left alone


def walk_speeds(positions: np.ndarray, max_step: float) -> np.ndarray:
    """The share of the steps of users who walk, per length in bins of ``1 / LINE_BINS`` of the
    positions' unit: ``(V,)`` float64 over bins ``0..V-1``, summing to 1 (empty where no such
    step).

    Measured on trajectories ``positions (n, L >= 2, 2)`` as they are (not snapped), in grid
    spacings: the steps longer than half a spacing of users whose median step is at most
    ``max_step`` (the place tables' speed: the drivers are the route pass's)."""
    s = walker_steps(positions, max_step)
    return length_shares(s[s > _MIN_STEP])


def walker_steps(positions: np.ndarray, max_step: float) -> np.ndarray:
    """The step lengths ``(n_walkers, L - 1)`` of the trajectories ``positions (n, L >= 2, 2)``
    whose median step is at most ``max_step`` (the same unit)."""
    step = np.linalg.norm(np.diff(checked_positions(positions), axis=1), axis=-1)
    return step[np.median(step, axis=1) <= max_step]


def length_shares(lengths: np.ndarray) -> np.ndarray:
    """The share of ``lengths`` (any shape) per bin of ``1 / LINE_BINS``: ``(V,)`` float64 summing
    to 1, empty where there are none."""
    if not lengths.size:
        return np.zeros(0)
    counts = np.bincount(np.rint(lengths.ravel() * LINE_BINS).astype(np.int64))
    return counts / counts.sum()


def line_weight(delta: np.ndarray) -> np.ndarray:
    """The straight-line track's weight ``(B,)`` in ``[0, 1]`` for its ``delta (B,)`` nats."""
    z = (np.asarray(delta, dtype=np.float64) - LINE_SHIFT) / LINE_SCALE
    return 0.5 * (1.0 + np.tanh(0.5 * np.clip(z, -60.0, 60.0)))


def _offsets(n: int, dims: int = 4) -> np.ndarray:
    """``(n, dims)`` points of the additive recurrence in ``[0, 1)^dims`` (Roberts' sequence):
    spread evenly, and the same on every call."""
    g = 1.0
    for _ in range(80):  # the root of x^(dims + 1) = x + 1 that generalises the golden ratio
        g = (1.0 + g) ** (1.0 / (dims + 1))
    alpha = np.array([g ** -(i + 1) for i in range(dims)])
    return np.mod(0.5 + np.arange(1, n + 1)[:, None] * alpha, 1.0)


_OFFSETS = _offsets(LINE_LINES)


def line_track(
    tracked: np.ndarray, xy: np.ndarray, lp: np.ndarray, speeds: np.ndarray, spacing: float
) -> tuple[np.ndarray, np.ndarray]:
    """Straight-line tracks of every user and their evidence (see the module's text).

    Parameters
    ----------
    tracked : (B, T, 2) float, metres
        The smoother's (or network's) track; the lines lie around its least-squares line.
    xy : (B, T, K, 2) float, metres
        Every step's candidate grid points.
    lp : (B, T, K) float
        Their log-likelihoods, each step's normalised alike (a grid point that is no candidate
        gets its step's lowest).
    speeds : (V,) float
        The measured share of steps per length bin (:func:`walk_speeds`).
    spacing : float
        The grid's spacing, metres.

    Returns
    -------
    track : (B, T, 2) float64, metres
        The lines' posterior mean; ``tracked`` where no line is weighed (a user slower than half a
        grid spacing per step, or no measured speed near its own).
    delta : (B,) float64
        Nats (``-inf`` where no line is weighed).
    """
    tracked = np.ascontiguousarray(tracked, dtype=np.float64)
    B, T = tracked.shape[:2]
    if B == 0 or T < 2 or not len(speeds):
        return tracked.copy(), np.full(B, -np.inf)
    return batch_map(
        _line_kernel, 3, tracked, np.ascontiguousarray(xy, np.float64), np.ascontiguousarray(lp, np.float64),
        np.asarray(speeds, np.float64), float(spacing), _OFFSETS, LINE_REACH, LINE_TURN, LINE_SPEEDS,
        LINE_STAGES, LINE_SPREAD,
    )  # fmt: skip


@njit(cache=True, nogil=True)
def fit_line(tr, a, b):  # pragma: no cover - compiled
    """The least-squares line through the points ``tr[a..b]`` ``(T, 2)``: their mean ``(cx, cy)``
    (the line's point at their middle step) and its velocity per step ``(vx, vy)``."""
    n = b - a + 1
    mid = (a + b) / 2.0
    tt = 0.0
    for t in range(a, b + 1):
        tt += (t - mid) ** 2
    cx, cy, vx, vy = 0.0, 0.0, 0.0, 0.0
    for t in range(a, b + 1):
        cx += tr[t, 0] / n
        cy += tr[t, 1] / n
        vx += (t - mid) * tr[t, 0] / tt
        vy += (t - mid) * tr[t, 1] / tt
    return cx, cy, vx, vy


@njit(cache=True, nogil=True)
def prior_bins(prior, lo, hi):  # pragma: no cover - compiled
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
def speed_bins(speeds, s0, window, spacing):  # pragma: no cover - compiled
    """:func:`prior_bins` of the measured ``speeds`` within ``window`` spacings of ``s0`` metres
    per step."""
    bin_w = spacing / LINE_BINS
    lo = max(int(np.floor((s0 - window * spacing) / bin_w)), 0)
    hi = min(int(np.ceil((s0 + window * spacing) / bin_w)), len(speeds) - 1)
    return prior_bins(speeds, lo, hi)


@njit(cache=True, nogil=True)
def narrow_box(box, d, m1, m2, total, spread, apart):  # pragma: no cover - compiled
    """Narrow coordinate ``d`` of a stage's ``box`` (fractions, lowest and highest per coordinate)
    to ``spread`` standard deviations either side of the posterior's mean (from its weighted
    moments ``m1``, ``m2`` and weight ``total``), at least 1.5 times ``apart``, the stage's
    spacing of lines as a share of the box's side."""
    mu = m1 / total
    sd = np.sqrt(max(m2 / total - mu * mu, 0.0))
    width = max(spread * sd, 1.5 * apart * (box[2 * d + 1] - box[2 * d]))
    box[2 * d], box[2 * d + 1] = max(mu - width, box[2 * d]), min(mu + width, box[2 * d + 1])


@njit(cache=True, nogil=True)
def narrow_bins(mass, lo, hi, total):  # pragma: no cover - compiled
    """The next stage's speed bins: of a stage's bins ``lo..hi`` (``mass[q]`` the posterior
    weight of bin ``lo + q``, ``total`` all of it), those from the first to the last holding more
    than ``1e-4`` of it, with one more either side within ``lo..hi``. Returns ``(lo, hi)``."""
    first, last = hi - lo + 1, -1
    for q in range(hi - lo + 1):
        if mass[q] > 1e-4 * total:
            first, last = min(first, q), max(last, q)
    return max(lo + first - 1, lo), min(lo + last + 1, hi)


@njit(cache=True, nogil=True)
def fill_raster(xy, lp, centres, spacing, raster, ox, oy):  # pragma: no cover - compiled
    """Each step's candidates ``xy (T, K, 2)``, ``lp (T, K)`` on a square raster ``(T, S, S)``
    around the grid point nearest ``centres (T, 2)``, each cell the best candidate on it and the
    step's lowest elsewhere; the rasters' corners into ``ox``, ``oy (T,)`` (cell ``(i, j)`` is
    the corner plus ``(i, j)`` spacings). Returns the sum of the steps' best log-likelihoods."""
    T, K = lp.shape
    side = raster.shape[1]
    half = side // 2
    best = 0.0
    for t in range(T):
        floor, top = np.inf, -np.inf
        for c in range(K):
            floor = min(floor, lp[t, c])
            top = max(top, lp[t, c])
        best += top
        raster[t] = floor
        gx = xy[t, 0, 0] + np.rint((centres[t, 0] - xy[t, 0, 0]) / spacing) * spacing
        gy = xy[t, 0, 1] + np.rint((centres[t, 1] - xy[t, 0, 1]) / spacing) * spacing
        ox[t], oy[t] = gx - half * spacing, gy - half * spacing
        for c in range(K):
            i = int(np.rint((xy[t, c, 0] - ox[t]) / spacing))
            j = int(np.rint((xy[t, c, 1] - oy[t]) / spacing))
            if 0 <= i < side and 0 <= j < side:
                raster[t, i, j] = max(raster[t, i, j], lp[t, c])
    return best


@njit(cache=True, nogil=True)
def raster_at(raster, t, x, y, ox, oy, spacing):  # pragma: no cover - compiled
    """Step ``t``'s log-likelihood on :func:`fill_raster`'s raster at ``(x, y)`` metres (its edge
    beyond it)."""
    side = raster.shape[1]
    i = min(max(int(np.rint((x - ox[t]) / spacing)), 0), side - 1)
    j = min(max(int(np.rint((y - oy[t]) / spacing)), 0), side - 1)
    return raster[t, i, j]


@njit(cache=True, nogil=True)
def _weigh_lines(
    cx,
    cy,
    h0,
    box,
    bins,
    log_prior,
    kb_lo,
    kb_hi,
    offsets,
    reach,
    turn,
    ts,
    ox,
    oy,
    raster,
    spacing,
    bin_w,
    ll,
    px,
    py,
):  # pragma: no cover - compiled
    """One stage: the lines of ``offsets`` within ``box`` (fractions of the range of the centre's x
    and y and of the heading, lowest and highest) and the speed bins ``kb_lo..kb_hi``; their
    log-likelihoods into ``ll``, their points into ``px``, ``py``. Returns the largest."""
    T = ts.shape[0]
    n_kb = kb_hi - kb_lo + 1
    top = -np.inf
    for n in range(offsets.shape[0]):
        ax = cx + (2.0 * (box[0] + offsets[n, 0] * (box[1] - box[0])) - 1.0) * reach * spacing
        ay = cy + (2.0 * (box[2] + offsets[n, 1] * (box[3] - box[2])) - 1.0) * reach * spacing
        h = h0 + (2.0 * (box[4] + offsets[n, 2] * (box[5] - box[4])) - 1.0) * turn
        kb = kb_lo + min(int(offsets[n, 3] * n_kb), n_kb - 1)
        s = bins[kb] * bin_w
        ux, uy = s * np.cos(h), s * np.sin(h)
        v = log_prior[kb]
        for t in range(T):
            x, y = ax + ts[t] * ux, ay + ts[t] * uy
            px[n, t], py[n, t] = x, y
            v += raster_at(raster, t, x, y, ox, oy, spacing)
        ll[n] = v
        top = max(top, v)
    return top


@njit(cache=True, nogil=True)
def _line_kernel(
    tracked, xy, lp, speeds, spacing, offsets, reach, turn, window, stages, spread
):  # pragma: no cover - compiled
    B, T, K = lp.shape
    N = offsets.shape[0]
    out = tracked.copy()
    delta = np.full(B, -np.inf)
    mid = (T - 1) / 2.0
    ts = np.arange(T) - mid
    bin_w = spacing / LINE_BINS
    ll = np.empty(N)
    px = np.empty((N, T))
    py = np.empty((N, T))
    spacing_of_lines = 1.0 / N**0.25  # of a box's side, for N quasi-random lines in four dimensions
    for b in range(B):
        # least-squares line through the track: centre at the middle step, velocity per step
        cx, cy, vx, vy = fit_line(tracked[b], 0, T - 1)
        s0 = np.hypot(vx, vy)
        if s0 < _MIN_STEP * spacing:
            continue
        h0 = np.arctan2(vy, vx)
        # the measured speed bins near the fitted line's, each read by every line at its speed
        bins, log_prior = speed_bins(speeds, s0, window, spacing)
        n_bins = len(bins)
        if n_bins == 0:
            continue
        # each step's candidates on a raster around the fitted line's point (its lowest elsewhere),
        # as far out as a line's point at the first or last step can lie from the fitted line's
        far = reach * spacing + abs(ts[0]) * (window * spacing + (s0 + window * spacing) * turn)
        half = int(np.ceil(far / spacing)) + 1
        side = 2 * half + 1
        raster = np.empty((T, side, side))
        ox, oy = np.empty(T), np.empty(T)
        centres = np.empty((T, 2))
        for t in range(T):
            centres[t, 0], centres[t, 1] = cx + ts[t] * vx, cy + ts[t] * vy
        best = fill_raster(xy[b], lp[b], centres, spacing, raster, ox, oy)
        box = np.array([0.0, 1.0, 0.0, 1.0, 0.0, 1.0])
        kb_lo, kb_hi = 0, n_bins - 1
        for stage in range(stages):
            top_ll = _weigh_lines(
                cx, cy, h0, box, bins, log_prior, kb_lo, kb_hi, offsets, reach, turn, ts, ox, oy,
                raster, spacing, bin_w, ll, px, py,
            )  # fmt: skip
            n_kb = kb_hi - kb_lo + 1
            last = stage + 1 == stages
            total = 0.0
            mx = np.zeros(T)  # the last stage's posterior mean
            my = np.zeros(T)
            m1 = np.zeros(3)  # an earlier stage's moments of the box's three continuous coordinates
            m2 = np.zeros(3)
            kb_mass = np.zeros(n_kb)
            for n in range(N):
                w = np.exp(ll[n] - top_ll)
                total += w
                if last:
                    for t in range(T):
                        mx[t] += w * px[n, t]
                        my[t] += w * py[n, t]
                    continue
                for d in range(3):
                    f = box[2 * d] + offsets[n, d] * (box[2 * d + 1] - box[2 * d])
                    m1[d] += w * f
                    m2[d] += w * f * f
                kb_mass[min(int(offsets[n, 3] * n_kb), n_kb - 1)] += w
            if last:
                for t in range(T):
                    out[b, t, 0] = mx[t] / total
                    out[b, t, 1] = my[t] / total
                share = (box[1] - box[0]) * (box[3] - box[2]) * (box[5] - box[4]) * n_kb / n_bins
                delta[b] = top_ll + np.log(total / N * share) - best
                break
            # the next stage's box: the posterior's spread either side of its mean, and the speed
            # bins that hold any of its mass with one more either side
            for d in range(3):
                narrow_box(box, d, m1[d], m2[d], total, spread, spacing_of_lines)
            kb_lo, kb_hi = narrow_bins(kb_mass, kb_lo, kb_hi, total)
    return out, delta
