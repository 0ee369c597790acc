"""Tracks of walkers whose walk is two lines: a stop between them, a turn away from a wall, or a
change of speed.

A walker who stops for a step, or turns because a building blocks the way ahead, leaves no
straight line through its candidates, so the straight-line pass (:mod:`~estimation.smoothing.line`)
gives it up to the smoother, though both pieces of its walk are lines at measured speeds that
pin it down as well as a straight walk does. :func:`two_line_track` weighs, for each walker, three
kinds of families of such walks, each a family per step where the track allows one:

* **a stop** at a step where the track moves less than :data:`STOP_GATE` spacings: the first
  piece ending where the user stands, at one of the measured walk speeds
  (:func:`~estimation.smoothing.line.walk_speeds`); the user standing there one step; the second
  piece setting off from there at one of the measured restart speeds (:func:`walk_restarts`: the
  training users set off after a stop at a handful of speeds, the generator's own mean speed for
  ours) in a heading of its own;
* **a turn at a wall** at a step where the way straight ahead of the track meets a grid point
  outside the free space within a spacing either side: the two pieces meeting at that step, at
  one speed, the second in a heading of its own. Each line is weighed by whether its own way
  straight ahead is blocked (:data:`TURN_BLOCKED`) or free (:data:`TURN_FREE`): people turn where
  a wall is ahead, and almost nowhere else at that angle;
* **a change of speed** for a walker faster than :data:`PACE_FAST` (a cyclist, whose speed
  changes by a quarter at a time), at the one step where a walk along the track's line that
  changes speed there fits the track best, if the change exceeds :data:`PACE_GATE`: the two
  pieces meeting at that step in one heading, each at one of the measured walk speeds.

Each family's lines are drawn in :data:`TWO_LINE_STAGES` stages of :data:`TWO_LINE_LINES`
around its posterior, as the straight lines are, over six coordinates (where the pieces meet, the
two headings and the two speeds): each stage within the box and the speed bins that hold the
previous one's posterior. A family whose first stage lies :data:`FAMILY_PRUNE` below the walks
weighed before it is dropped there. The straight lines and every family are mixed by their
evidence, a stop weighed by the share of the training walkers' moving steps a stop followed
(:func:`walk_restarts`) times ``exp(STOP_BIAS)``, a change of speed by ``exp(PACE_BIAS)``. The
mixture's evidence takes the place of the straight lines' own ``delta`` (the same units: a user
no family applies to keeps both).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mmwsim._threads import batch_map

from .line import (
    _MIN_STEP,
    LINE_BINS,
    LINE_REACH,
    LINE_SPEEDS,
    LINE_SPREAD,
    LINE_TURN,
    _offsets,
    fill_raster,
    fit_line,
    length_shares,
    narrow_bins,
    narrow_box,
    prior_bins,
    raster_at,
    speed_bins,
    walker_steps,
)

__all__ = [
    "STOP_BIAS",
    "STOP_GATE",
    "TURN_BLOCKED",
    "TURN_FREE",
    "FreeRaster",
    "free_raster",
    "two_line_track",
    "walk_restarts",
]

STOP_GATE = 1.0
"""Grid spacings: a step of the track shorter than this may be a stop, and is weighed as one."""
TWO_LINE_STAGES = 4
"""Stages of lines per family, each within the box of the previous one's posterior and its speed
bins. With :data:`TWO_LINE_LINES`, chosen on 1000 users per kind of ``default.zarr`` (three draws
of each of validation, seen area and held out, `runs/tn-match-tracking` of the README): against
three stages of 4096 lines whose speeds stayed in the whole window, pedestrians -0.1 to -0.5 %
on all nine draws (validation -0.4 / -0.2 / -0.2 %), cyclists -0.4 to +0.1 %, at the same cost.
Speed bins narrowed with three stages of 4096: pedestrians 0 to -0.5 %; four stages of 4096:
-0.2 to -0.7 % at 4 / 3 the cost; five of 2458: alike."""
STOP_BIAS = 1.4
"""Nats added to the log share of stops in a stop family's prior. Chosen on 1000 validation users
per kind of ``default.zarr`` (three draws; its stop share is 0.091): priors of -1.6 to 0 nats in
all were within 0.05 % of each other on the pedestrians, -2.2 (the share against the steps that
change nothing) 0.07 % behind."""
TURN_BLOCKED = 4.0
"""Nats by which a line that turns where its way straight ahead is blocked is weighed up."""
TURN_FREE = -12.0
"""Nats by which a line that turns where its way straight ahead is free is weighed down. With
:data:`TURN_BLOCKED`, chosen on 1000 validation users per kind of ``default.zarr`` (three
draws; blocked 2 to 8 nats, free -8 to -16: pedestrians -0.06 to -0.35 %, cyclists -0.5 to
-0.7 %)."""
PACE_FAST = 2.0
"""Grid spacings per step: a walker whose track's median step is longer (our cyclists, not our
pedestrians, whose speed changes by a fifth at a time) is weighed changing its speed too. On
1000 users per kind of ``default.zarr`` (`runs/tn-match-tracking` of the README, three draws of
each of validation, seen area and held out): cyclists -0.1 to -1.3 % on all nine draws
(validation -0.8 / -1.3 / -0.7 %), pedestrians unchanged; the walks of two lines took 0.89 s
per 1445 seen walkers against 0.94 s before (with :data:`FAMILY_PRUNE`)."""
PACE_GATE = 0.3
"""Grid spacings per step: the least change of speed weighed (the fitted walk's). On the
validation draws of :data:`PACE_FAST`, with two free lines for the fit: 0.15 / 0.3 / 0.5 gave
-0.8 / -0.8 / -0.6 % on the cyclists; families at every step instead of the best one alike at
three times the cost, and at the best step's neighbours too no better."""
PACE_BIAS = -2.0
"""Nats added to the evidence of a family of walks that change speed (-1 to -3: within 0.1 %)."""
FAMILY_PRUNE = 40.0
"""Nats: a family whose first stage's evidence lies this far below the likeliest walk weighed
before it is dropped (its weight ``exp(-40)`` of that walk's) instead of narrowed: the tracks
move by 3e-9 m, for 7 % of the pass's time (at 25 nats they move by up to 0.2 m)."""
TWO_LINE_WINDOW = 0.8
"""Grid spacings per step: the walk speeds weighed for the first piece lie this near its fitted
line's."""
TWO_LINE_TURN = 0.5
"""Radians a piece's heading may differ from its fitted line's where it spans three steps or
fewer (:data:`~estimation.smoothing.line.LINE_TURN` where longer)."""
TWO_LINE_HALF = 5
"""Grid spacings either side of each step's tracked point that its raster of candidates spans."""
TWO_LINE_LINES = 3072
"""Lines per stage of a family: :data:`TWO_LINE_STAGES` stages of them cost what three stages of
:data:`~estimation.smoothing.line.LINE_LINES` did."""
_OFFSETS6 = _offsets(TWO_LINE_LINES, 6)

_STOP, _TURN, _PACE = 0, 1, 2  # the kinds of family

FreeRaster = tuple[np.ndarray, np.ndarray, float]
"""The free space on the grid: ``(free (nx, ny) bool, origin (2,) metres, spacing metres)``, cell
``(i, j)`` the grid point at ``origin + (i, j) * spacing``."""


def free_raster(grid_xy: np.ndarray, spacing: float) -> FreeRaster:
    """The free space of a grid whose free points are ``grid_xy (G, 2)`` metres (the points a data
    set holds fingerprints at: outside the buildings), every other grid point blocked."""
    xy = np.asarray(grid_xy, dtype=np.float64).reshape(-1, 2)
    if not len(xy):
        return np.zeros((1, 1), bool), np.zeros(2), float(spacing)
    origin = xy.min(axis=0)
    ij = np.rint((xy - origin) / spacing).astype(np.int64)
    free = np.zeros(tuple(ij.max(axis=0) + 1), dtype=bool)
    free[ij[:, 0], ij[:, 1]] = True
    return free, origin, float(spacing)


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
    s = walker_steps(positions, max_step)
    moving = s[:, :-1] > _MIN_STEP
    after = s[:, 1:][(s[:, :-1] <= _MIN_STEP) & (s[:, 1:] > _MIN_STEP)]
    if not after.size or not moving.any():
        return np.zeros(0), 0.0
    return length_shares(after), float((moving & (s[:, 1:] <= _MIN_STEP)).sum() / moving.sum())


def two_line_track(
    tracked: np.ndarray,
    xy: np.ndarray,
    lp: np.ndarray,
    speeds: np.ndarray,
    spacing: float,
    line: np.ndarray,
    delta: np.ndarray,
    restarts: np.ndarray | None = None,
    stop_share: float = 0.0,
    free: FreeRaster | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The straight-line tracks ``line``, ``delta`` of
    :func:`~estimation.smoothing.line.line_track` mixed with walks of two lines (see the
    module's text).

    Parameters
    ----------
    tracked, xy, lp, speeds, spacing
        As :func:`~estimation.smoothing.line.line_track` took them.
    line : (B, T, 2) float, metres
        The straight lines' posterior mean.
    delta : (B,) float
        Their evidence, nats.
    restarts : (V,) float, optional
        The measured share of the steps after a stop per length bin (:func:`walk_restarts`);
        no stops are weighed without them.
    stop_share : float
        The measured share of moving steps followed by a stop (no stops are weighed at 0).
    free : FreeRaster, optional
        The grid's free space (:func:`free_raster`); no turns at walls are weighed without it.

    Returns
    -------
    track : (B, T, 2) float64, metres
        The mixture's posterior mean; ``line`` where no family applies.
    delta : (B,) float64
        The mixture's evidence, nats, in the units of the straight lines'.
    """
    line = np.ascontiguousarray(line, dtype=np.float64)
    delta = np.asarray(delta, dtype=np.float64)
    B, T = line.shape[:2]
    stops = restarts is not None and len(restarts) > 0 and stop_share > 0
    if B == 0 or T < 3 or not len(speeds):
        return line.copy(), delta.copy()
    mask, origin, res = free if free is not None else (np.zeros((0, 0), bool), np.zeros(2), 1.0)
    return batch_map(
        _two_line_kernel, 5, np.ascontiguousarray(tracked, np.float64), np.ascontiguousarray(xy, np.float64),
        np.ascontiguousarray(lp, np.float64), line, delta, np.asarray(speeds, np.float64),
        np.asarray(restarts if stops else np.zeros(0), np.float64),
        float(np.log(stop_share) + STOP_BIAS) if stops else -np.inf, float(spacing), _OFFSETS6,
        np.ascontiguousarray(mask), np.asarray(origin, np.float64), float(res),
    )  # fmt: skip


@njit(cache=True, nogil=True)
def _blocked(x, y, hx, hy, free, origin, res):  # pragma: no cover - compiled
    """Whether the step from ``(x, y)`` by ``(hx, hy)`` metres meets a blocked grid point at a
    quarter, a half, three quarters or all of its length (off the raster counts as free)."""
    for q in range(1, 5):
        i = int(np.rint((x + 0.25 * q * hx - origin[0]) / res))
        j = int(np.rint((y + 0.25 * q * hy - origin[1]) / res))
        if 0 <= i < free.shape[0] and 0 <= j < free.shape[1] and not free[i, j]:
            return True
    return False


@njit(cache=True, nogil=True)
def _wall_ahead(tr, jv, free, origin, res, spacing):  # pragma: no cover - compiled
    """Whether the way straight ahead of the track at step ``jv`` (its last step carried on for
    one and a half steps) meets a blocked grid point within a spacing either side."""
    dx, dy = tr[jv, 0] - tr[jv - 1, 0], tr[jv, 1] - tr[jv - 1, 1]
    n = np.hypot(dx, dy)
    nx, ny = -dy / n * spacing, dx / n * spacing
    for side in (-1.0, 0.0, 1.0):
        x, y = tr[jv, 0] + side * nx, tr[jv, 1] + side * ny
        if _blocked(x, y, dx, dy, free, origin, res) or _blocked(x, y, 1.5 * dx, 1.5 * dy, free, origin, res):
            return True
    return False


@njit(cache=True, nogil=True)
def _weigh_two_lines(
    kind,
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
    free,
    origin,
    res,
    ll,
    px,
    py,
):  # pragma: no cover - compiled
    """One stage of a family of walks of two lines that meet at step ``jv``: within
    :data:`LINE_REACH` of ``at (2,)``, the two pieces' headings within ``turn (2,)`` of
    ``head (2,)``, their speeds in the bins ``range_a``, ``range_b`` (lowest, highest) of
    ``bins_a``, ``bins_b``; ``box (12,)`` the fractions of those ranges drawn in. With ``kind``
    :data:`_STOP` the user stands at step ``jv + 1`` too; with :data:`_TURN` the second piece
    keeps the first's speed and each line is weighed by whether its way straight ahead at ``jv``
    is blocked on ``free`` (a turn at a wall); with :data:`_PACE` it keeps the first's heading (a
    change of speed). Log-likelihoods into ``ll``, points into ``px``, ``py``; returns the
    largest."""
    T = raster.shape[0]
    N = offsets.shape[0]
    bin_w = spacing / LINE_BINS
    n_a, n_b = range_a[1] - range_a[0] + 1, range_b[1] - range_b[0] + 1
    f = np.empty(6)
    gap = 1 if kind == _STOP else 0
    top = -np.inf
    for n in range(N):
        for d in range(6):
            f[d] = box[2 * d] + offsets[n, d] * (box[2 * d + 1] - box[2 * d])
        sx = at[0] + (2.0 * f[0] - 1.0) * LINE_REACH * spacing
        sy = at[1] + (2.0 * f[1] - 1.0) * LINE_REACH * spacing
        ha = head[0] + (2.0 * f[2] - 1.0) * turn[0]
        hb = ha if kind == _PACE else head[1] + (2.0 * f[4] - 1.0) * turn[1]
        ka = range_a[0] + min(int(f[3] * n_a), n_a - 1)
        kb = range_b[0] + min(int(f[5] * n_b), n_b - 1)
        sa = bins_a[ka] * bin_w
        sb = sa if kind == _TURN else bins_b[kb] * bin_w
        v = lp_a[ka] + (0.0 if kind == _TURN else lp_b[kb])
        ax, ay = sa * np.cos(ha), sa * np.sin(ha)  # the pieces' steps
        bx, by = sb * np.cos(hb), sb * np.sin(hb)
        if kind == _TURN:
            v += TURN_BLOCKED if _blocked(sx, sy, ax, ay, free, origin, res) else TURN_FREE
        for t in range(T):
            if t <= jv:
                x, y = sx - (jv - t) * ax, sy - (jv - t) * ay
            else:
                x, y = sx + (t - jv - gap) * bx, sy + (t - jv - gap) * by
            px[n, t], py[n, t] = x, y
            v += raster_at(raster, t, x, y, ox, oy, spacing)
        ll[n] = v
        top = max(top, v)
    return top


@njit(cache=True, nogil=True)
def _pace_step(tr):  # pragma: no cover - compiled
    """The step ``1..T-2`` at which a walk along the track's least-squares line that changes
    speed there fits the track best (by least squares along that line), and the change (its
    speed after less before, the track's unit per step)."""
    T = tr.shape[0]
    vx, vy = fit_line(tr, 0, T - 1)[2:]
    n = np.hypot(vx, vy)
    along = ((tr[:, 0] - tr[0, 0]) * vx + (tr[:, 1] - tr[0, 1]) * vy) / max(n, 1e-12)
    best, at, change = np.inf, -1, 0.0
    a = np.empty((T, 3))
    m, r = np.empty((3, 3)), np.empty(3)
    for jv in range(1, T - 1):
        for t in range(T):  # where the walk is at jv, its speed before and its speed after
            a[t, 0], a[t, 1], a[t, 2] = 1.0, min(t - jv, 0), max(t - jv, 0)
        for i in range(3):
            r[i] = (a[:, i] * along).sum()
            for k in range(3):
                m[i, k] = (a[:, i] * a[:, k]).sum()
        p = np.linalg.solve(m, r)
        sse = ((a @ p - along) ** 2).sum()
        if sse < best:
            best, at, change = sse, jv, p[2] - p[1]
    return at, change


@njit(cache=True, nogil=True)
def _family(
    kind, tr, jv, speeds, restarts, spacing, offsets, ox, oy, raster, free, origin, res, buffers, mean, floor
):  # pragma: no cover - compiled
    """Log evidence of the family of walks that stop, turn or change speed (``kind``) at step
    ``jv``, in the straight lines' measure (the first heading by their density, the second by
    ``1 / 2 pi``); its posterior mean into ``mean (T, 2)``, the lines of a stage into ``buffers``
    (``ll (N,)``, ``px``, ``py (N, T)``). ``-inf`` where no walk speed lies near the first
    piece's (or the second's, for a change of speed), or where the first stage's evidence lies
    below ``floor``."""
    T = tr.shape[0]
    N = offsets.shape[0]
    ll, px, py = buffers
    pace = kind == _PACE
    gap = 1 if kind == _STOP else 0
    before, after = jv >= 1, jv + gap <= T - 2  # pieces of two or more steps
    if kind == _STOP:
        at = np.array([0.5 * (tr[jv, 0] + tr[jv + 1, 0]), 0.5 * (tr[jv, 1] + tr[jv + 1, 1])])
    else:
        at = np.array([tr[jv, 0], tr[jv, 1]])
    head = np.zeros(2)
    turn = np.array([TWO_LINE_TURN, TWO_LINE_TURN])
    bins_a, lp_a = np.ones(1, np.int64), np.zeros(1)  # a piece of one step: no speed, no heading
    bins_b, lp_b = np.ones(1, np.int64), np.zeros(1)
    if before:
        vx, vy = fit_line(tr, 0, jv)[2:]
        head[0] = np.arctan2(vy, vx)
        bins_a, lp_a = speed_bins(speeds, np.hypot(vx, vy), TWO_LINE_WINDOW, spacing)
        if not len(bins_a):
            return -np.inf
        if jv >= 3:
            turn[0] = LINE_TURN
    if after:
        vx, vy = fit_line(tr, jv + gap, T - 1)[2:]
        head[1] = np.arctan2(vy, vx)
        if kind == _STOP:
            bins_b, lp_b = prior_bins(restarts, 0, len(restarts) - 1)
        elif pace:
            bins_b, lp_b = speed_bins(speeds, np.hypot(vx, vy), TWO_LINE_WINDOW, spacing)
            if not len(bins_b):
                return -np.inf
        if T - 1 - jv - gap >= 3:
            turn[1] = LINE_TURN
    if pace:  # one heading, about the whole track's
        vx, vy = fit_line(tr, 0, T - 1)[2:]
        head[0] = np.arctan2(vy, vx)
        turn[0] = LINE_TURN
    box = np.array([0.0, 1.0] * 6)
    range_a = np.array([0, len(bins_a) - 1])
    range_b = np.array([0, len(bins_b) - 1])
    lines_apart = 1.0 / N ** (1.0 / 6.0)  # of a box's side, for N quasi-random lines in six dimensions
    log_ev = -np.inf
    m1, m2 = np.zeros(6), np.zeros(6)
    mass_a, mass_b = np.zeros(len(bins_a)), np.zeros(len(bins_b))  # a stage's weight per speed bin
    for stage in range(TWO_LINE_STAGES):
        top = _weigh_two_lines(
            kind, jv, at, head, turn, box, bins_a, lp_a, range_a, bins_b, lp_b, range_b, offsets, ox,
            oy, raster, spacing, free, origin, res, ll, px, py,
        )  # fmt: skip
        last = stage + 1 == TWO_LINE_STAGES
        total = 0.0
        mean[:] = 0.0  # the last stage's posterior mean
        m1[:] = 0.0  # an earlier stage's moments of the box's coordinates
        m2[:] = 0.0
        n_a, n_b = range_a[1] - range_a[0] + 1, range_b[1] - range_b[0] + 1
        mass_a[:] = 0.0
        mass_b[:] = 0.0
        for n in range(N):
            w = np.exp(ll[n] - top)
            total += w
            if last:
                for t in range(T):
                    mean[t, 0] += w * px[n, t]
                    mean[t, 1] += w * py[n, t]
                continue
            for d in range(6):
                g = box[2 * d] + offsets[n, d] * (box[2 * d + 1] - box[2 * d])
                m1[d] += w * g
                m2[d] += w * g * g
            mass_a[min(int(offsets[n, 3] * n_a), n_a - 1)] += w
            mass_b[min(int(offsets[n, 5] * n_b), n_b - 1)] += w
        mean /= total
        share = (box[1] - box[0]) * (box[3] - box[2])
        log_ev = top + np.log(total / N)
        if before:
            share *= (box[5] - box[4]) * n_a
            log_ev += np.log(turn[0] / LINE_TURN)
        if pace:
            share *= n_b
        elif after:
            share *= (box[9] - box[8]) * n_b
            log_ev += np.log(turn[1] / np.pi)
        log_ev += np.log(share)
        if last:
            break
        if log_ev < floor:
            return -np.inf
        # the next stage's box: where the pieces meet and the headings of the pieces that have one,
        # and the speed bins that hold the posterior (as the straight lines' stages narrow theirs)
        for d in range(5):
            if d == 3 or (d == 2 and not before) or (d == 4 and (pace or not after)):
                continue
            narrow_box(box, d, m1[d], m2[d], total, LINE_SPREAD, lines_apart)
        range_a[0], range_a[1] = narrow_bins(mass_a, range_a[0], range_a[1], total)
        range_b[0], range_b[1] = narrow_bins(mass_b, range_b[0], range_b[1], total)
    return log_ev


@njit(cache=True, nogil=True)
def _two_line_kernel(
    tracked, xy, lp, line, delta, speeds, restarts, log_stop, spacing, offsets, free, origin, res
):  # pragma: no cover - compiled
    B, T = lp.shape[:2]
    N = offsets.shape[0]
    out = line.copy()
    mixed = delta.copy()
    mean = np.empty((T, 2))
    buffers = np.empty(N), np.empty((N, T)), np.empty((N, T))
    side = 2 * TWO_LINE_HALF + 1
    raster = np.empty((T, side, side))
    ox, oy = np.empty(T), np.empty(T)
    stops, turns = len(restarts) > 0, free.shape[0] > 0
    for b in range(B):
        tr = tracked[b]
        step = np.empty(T - 1)
        for t in range(T - 1):
            step[t] = np.hypot(tr[t + 1, 0] - tr[t, 0], tr[t + 1, 1] - tr[t, 1])
        stop_at = np.zeros(T - 1, np.bool_)
        turn_at = np.zeros(T - 1, np.bool_)
        moving = False
        for t in range(T - 1):
            moving |= step[t] >= STOP_GATE * spacing
            stop_at[t] = stops and step[t] < STOP_GATE * spacing
            if turns and 1 <= t and step[t - 1] >= _MIN_STEP * spacing:
                turn_at[t] = _wall_ahead(tr, t, free, origin, res, spacing)
        pace_at = -1  # where a fast walker's track changes speed, if it does
        if np.median(step) > PACE_FAST * spacing:
            at, change = _pace_step(tr)
            if abs(change) > PACE_GATE * spacing:
                pace_at = at
        if not moving or not (stop_at.any() or turn_at.any() or pace_at >= 0):  # never moves, or no family
            continue
        # the straight lines' evidence summed over their speed bins (line_track's is per bin)
        vx, vy = fit_line(tr, 0, T - 1)[2:]
        n_bins = max(len(speed_bins(speeds, np.hypot(vx, vy), LINE_SPEEDS, spacing)[0]), 1)
        best = fill_raster(xy[b], lp[b], tr, spacing, raster, ox, oy)
        ev_line = delta[b] + best + np.log(n_bins)
        top = ev_line
        ev = np.full((3, T - 1), -np.inf)
        means = np.zeros((3, T - 1, T, 2))
        for kind in (_STOP, _TURN, _PACE):
            bias = log_stop if kind == _STOP else PACE_BIAS if kind == _PACE else 0.0
            for jv in range(T - 1):
                if stop_at[jv] if kind == _STOP else turn_at[jv] if kind == _TURN else jv == pace_at:
                    e = _family(
                        kind, tr, jv, speeds, restarts, spacing, offsets, ox, oy, raster, free,
                        origin, res, buffers, mean, top - FAMILY_PRUNE - bias,
                    )  # fmt: skip
                    ev[kind, jv] = e + bias
                    means[kind, jv] = mean
                    top = max(top, ev[kind, jv])
        if top == -np.inf:
            continue
        total = 0.0
        acc = np.zeros((T, 2))
        if ev_line > -np.inf:
            w = np.exp(ev_line - top)
            total += w
            acc += w * line[b]
        for kind in (_STOP, _TURN, _PACE):
            for jv in range(T - 1):
                if ev[kind, jv] > -np.inf:
                    w = np.exp(ev[kind, jv] - top)
                    total += w
                    acc += w * means[kind, jv]
        out[b] = acc / total
        mixed[b] = top + np.log(total) - np.log(n_bins) - best
    return out, mixed
