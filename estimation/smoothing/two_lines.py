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
previous one's posterior. A stop's pieces are weighed apart (:func:`_weigh_stop`): given where
the user stands, the steps before it depend on the first piece alone and those after on the
second alone, so each of :data:`STOP_POINTS` places to stand is weighed with every pair of
:data:`STOP_PIECES` pieces, 21 times the walks of the lines for half their lookups. A family
whose first stage lies :data:`FAMILY_PRUNE` below the walks weighed before it is dropped there.

A walker whose track has two short steps is weighed stopping at both too
(:func:`_weigh_two_stops`): three pieces, the middle one between the two places it stands (none
where the stops follow each other) at a restart speed, the first and last weighed apart as a
single stop's are.

The straight lines and every family are mixed by their evidence, a stop weighed by the share of
the training walkers' moving steps a stop followed (:func:`walk_restarts`) times
``exp(STOP_BIAS)`` (two stops by its square), a change of speed by ``exp(PACE_BIAS)``. The
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
STOP_POINTS = 64
"""Points where the user stands per stage of a family of stops, each weighed with every pair of
:data:`STOP_PIECES` pieces before and after (:func:`_weigh_stop`): 65536 walks a stage for
the lookups of 1500 lines. With :data:`STOP_PIECES`, chosen on 1000 users per kind of ``default.zarr``
(`runs/tn-match-tracking` of the README, three draws of each of validation, seen area and held
out) against the 3072 lines of the other families: pedestrians -0.1 to -0.6 % on all nine draws
(validation -0.2 / -0.6 / -0.2 %), cyclists -0.2 to +0.2 % (held out +0.1 to +0.2 %), the walks of two
lines 0.80 s per 1445 seen walkers against 0.89 s; 96 and 32, 64 and 48, 48 and 32 alike. The
lines at 12288 per stage gained as much at 2.3 times the cost."""
STOP_PIECES = 32
"""Pieces (a heading and a speed) either side of each point per stage of a family of stops."""
_STOP_POINTS6 = _offsets(STOP_POINTS, 6)
_STOP_PIECES2 = _offsets(STOP_PIECES, 2)
TWO_STOP_POINTS = 256
"""First places to stand and middle pieces per stage of a family of two stops
(:func:`_weigh_two_stops`), each weighed with every pair of :data:`TWO_STOP_PIECES` first and
last pieces. Chosen on the draws of :data:`STOP_POINTS`: at 128 pedestrians 0.0 to 0.3 % behind;
32 pieces the same as 16 at about twice the families' cost."""
TWO_STOP_PIECES = 16
"""Pieces (a heading and a speed) before the first stop and after the second per stage of a
family of two stops."""
TWO_STOP_STEPS = 4
"""Two stops are weighed at pairs of the track's shortest steps, this many of them: a slow
walker's track has many steps shorter than :data:`STOP_GATE`, and pairs of all of them cost it
75 ms at 30 steps (12 ms before the two stops), 18 ms with these. On the draws of
:data:`STOP_POINTS` (7 steps) within 0.05 % of every pair; 3: pedestrians up to 0.05 % behind on
the README's draw."""
_TWO_STOP_POINTS8 = _offsets(TWO_STOP_POINTS, 8)
_TWO_STOP_PIECES2 = _offsets(TWO_STOP_PIECES, 2)

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
        _STOP_POINTS6, _STOP_PIECES2, _TWO_STOP_POINTS8, _TWO_STOP_PIECES2,
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
def _to_weights(ll, n):  # pragma: no cover - compiled
    """The log-likelihoods ``ll[:n]`` turned in place into weights that sum to one; returns the log
    of their sum of likelihoods."""
    big = -np.inf
    for k in range(n):
        big = max(big, ll[k])
    total = 0.0
    for k in range(n):
        ll[k] = np.exp(ll[k] - big)
        total += ll[k]
    for k in range(n):
        ll[k] /= total
    return big + np.log(total)


@njit(cache=True, nogil=True)
def _piece_at(base, shift, box, d, range_, n):  # pragma: no cover - compiled
    """A piece's heading (a fraction of ``box``'s coordinate ``d``) and speed bin (of the ``n``
    bins ``range_ (2,)`` spans) from its design point ``base (2,)`` rotated by ``shift (2,)``."""
    u = base[0] + shift[0]
    v = base[1] + shift[1]
    u, v = u - np.floor(u), v - np.floor(v)
    return box[2 * d] + u * (box[2 * d + 1] - box[2 * d]), range_[0] + min(int(v * n), n - 1)


@njit(cache=True, nogil=True)
def _weigh_stop(
    jv, at, head, turn, box, bins_a, lp_a, range_a, bins_b, lp_b, range_b, points, pieces, ox, oy, raster,
    spacing, la, lb, lm, last, mean, m1, m2, mass_a, mass_b
):  # pragma: no cover - compiled  # fmt: skip
    """One stage of a family of walks that stop at step ``jv``, its two pieces weighed apart.

    Given where the user stands, the steps before the stop depend on the first piece alone and
    those after it on the second alone, so each of ``points (M, 6)``'s places to stand (its
    coordinates 0 and 1) is weighed with every one of ``pieces (K, 2)``'s first pieces and every
    one of its second pieces (a heading and a speed, rotated by the point's coordinates 2, 3 and
    4, 5: Cranley and Patterson's shift): ``M K^2`` walks for the cost of ``M (2 + K (T - 2))``
    lookups, where lines of six coordinates (:func:`_weigh_two_lines`) draw each walk whole. The
    geometry is theirs (``box (12,)``, ``bins_*``, ``lp_*``, ``range_*``). Log-likelihoods per
    point and piece into ``la``, ``lb (M, K)``, ``lm (M,)``; the posterior's moments of ``box``'s
    coordinates into ``m1``, ``m2 (6,)`` and its weight per speed bin into ``mass_a``,
    ``mass_b`` (all normalised), or its mean into ``mean (T, 2)`` where ``last``. Returns the log
    of the mean likelihood over the stage's walks."""
    T = raster.shape[0]
    M, K = points.shape[0], pieces.shape[0]
    bin_w = spacing / LINE_BINS
    n_a, n_b = range_a[1] - range_a[0] + 1, range_b[1] - range_b[0] + 1
    ka_n = K if jv >= 1 else 1  # a piece with no steps of its own is one walk
    kb_n = K if jv + 2 <= T - 1 else 1
    for m in range(M):
        sx = at[0] + (2.0 * (box[0] + points[m, 0] * (box[1] - box[0])) - 1.0) * LINE_REACH * spacing
        sy = at[1] + (2.0 * (box[2] + points[m, 1] * (box[3] - box[2])) - 1.0) * LINE_REACH * spacing
        v = raster_at(raster, jv, sx, sy, ox, oy, spacing) + raster_at(
            raster, jv + 1, sx, sy, ox, oy, spacing
        )
        for side in range(2):
            l_, n_k = (la, ka_n) if side == 0 else (lb, kb_n)
            for k in range(n_k):
                if side == 0:
                    f, q = _piece_at(pieces[k], points[m, 2:4], box, 2, range_a, n_a)
                    s, lv = bins_a[q] * bin_w, lp_a[q]
                else:
                    f, q = _piece_at(pieces[k], points[m, 4:6], box, 4, range_b, n_b)
                    s, lv = bins_b[q] * bin_w, lp_b[q]
                h = head[side] + (2.0 * f - 1.0) * turn[side]
                dx, dy = s * np.cos(h), s * np.sin(h)
                if side == 0:
                    for t in range(jv):
                        lv += raster_at(raster, t, sx - (jv - t) * dx, sy - (jv - t) * dy, ox, oy, spacing)
                else:
                    for t in range(jv + 2, T):
                        lv += raster_at(
                            raster, t, sx + (t - jv - 1) * dx, sy + (t - jv - 1) * dy, ox, oy, spacing
                        )
                l_[m, k] = lv
            v += _to_weights(l_[m], n_k)  # from here on the pieces' weights given the point
        lm[m] = v
    log_total = _to_weights(lm, M)
    mean[:] = 0.0
    m1[:] = 0.0
    m2[:] = 0.0
    mass_a[:] = 0.0
    mass_b[:] = 0.0
    for m in range(M):
        w = lm[m]
        g0 = box[0] + points[m, 0] * (box[1] - box[0])
        g1 = box[2] + points[m, 1] * (box[3] - box[2])
        sx = at[0] + (2.0 * g0 - 1.0) * LINE_REACH * spacing
        sy = at[1] + (2.0 * g1 - 1.0) * LINE_REACH * spacing
        if last:
            for t in (jv, jv + 1):
                mean[t, 0] += w * sx
                mean[t, 1] += w * sy
        else:
            m1[0] += w * g0
            m2[0] += w * g0 * g0
            m1[1] += w * g1
            m2[1] += w * g1 * g1
        for side in range(2):
            n_k = ka_n if side == 0 else kb_n
            for k in range(n_k):
                if side == 0:
                    wk = w * la[m, k]
                    f, q = _piece_at(pieces[k], points[m, 2:4], box, 2, range_a, n_a)
                else:
                    wk = w * lb[m, k]
                    f, q = _piece_at(pieces[k], points[m, 4:6], box, 4, range_b, n_b)
                if not last:
                    m1[2 + 2 * side] += wk * f
                    m2[2 + 2 * side] += wk * f * f
                    if side == 0:
                        mass_a[q - range_a[0]] += wk
                    else:
                        mass_b[q - range_b[0]] += wk
                    continue
                s = (bins_a[q] if side == 0 else bins_b[q]) * bin_w
                h = head[side] + (2.0 * f - 1.0) * turn[side]
                dx, dy = s * np.cos(h), s * np.sin(h)
                if side == 0:
                    for t in range(jv):
                        mean[t, 0] += wk * (sx - (jv - t) * dx)
                        mean[t, 1] += wk * (sy - (jv - t) * dy)
                else:
                    for t in range(jv + 2, T):
                        mean[t, 0] += wk * (sx + (t - jv - 1) * dx)
                        mean[t, 1] += wk * (sy + (t - jv - 1) * dy)
    return log_total - np.log(M * ka_n * kb_n)


@njit(cache=True, nogil=True)
def _weigh_two_stops(
    j1, j2, at, head, turn, box, bins, lps, ranges, points, pieces, ox, oy, raster, spacing, la, lc, lm,
    last, mean, m1, m2, mass
):  # pragma: no cover - compiled  # fmt: skip
    """One stage of a family of walks that stop at steps ``j1 < j2``: the user stands at step
    ``j1 + 1`` where the first piece ends, walks a middle piece of ``j2 - j1 - 1`` steps (none
    where the stops follow each other), stands at step ``j2 + 1`` and walks a last piece. Each of
    ``points (M, 8)``'s first stands and middle pieces (coordinates 0..3) is weighed with every
    pair of ``pieces (K, 2)``'s first and last pieces (rotated by coordinates 4, 5 and 6, 7), as
    :func:`_weigh_stop` weighs one stop. Pieces ``p = 0, 1, 2`` (first, middle, last): heading
    ``head[p] +- turn[p]`` over ``box[4 + 4 p : 6 + 4 p]``, speed bins ``ranges[p]`` of
    ``bins[p]`` with log shares ``lps[p]``; the stand within ``box[0:4]``. Moments into ``m1``,
    ``m2 (8,)`` (coordinates 0, 1 and the pieces' headings at 2 + 2 p), weights per speed bin
    into ``mass[p]``, or the mean into ``mean (T, 2)``. Returns the log mean likelihood."""
    T = raster.shape[0]
    M, K = points.shape[0], pieces.shape[0]
    bin_w = spacing / LINE_BINS
    n_mid = j2 - j1 - 1
    n_k = np.array([K if j1 >= 1 else 1, 1, K if j2 + 2 <= T - 1 else 1])
    log_total = 0.0
    for rep in range(2):  # weigh; then the posterior's moments or mean
        for m in range(M):
            g0 = box[0] + points[m, 0] * (box[1] - box[0])
            g1 = box[2] + points[m, 1] * (box[3] - box[2])
            sx = at[0] + (2.0 * g0 - 1.0) * LINE_REACH * spacing
            sy = at[1] + (2.0 * g1 - 1.0) * LINE_REACH * spacing
            fb = box[8] + points[m, 2] * (box[9] - box[8])
            n = ranges[1, 1] - ranges[1, 0] + 1
            qb = ranges[1, 0] + min(int(points[m, 3] * n), n - 1)
            hb = head[1] + (2.0 * fb - 1.0) * turn[1]
            sb = bins[1, qb] * bin_w if n_mid > 0 else 0.0
            bx, by = sb * np.cos(hb), sb * np.sin(hb)
            ex, ey = sx + n_mid * bx, sy + n_mid * by  # the second stand
            w = 0.0
            if rep == 0:
                v = lps[1, qb] if n_mid > 0 else 0.0
                for t in range(j1, j2 + 1):
                    k = max(t - j1 - 1, 0)
                    v += raster_at(raster, t, sx + k * bx, sy + k * by, ox, oy, spacing)
                v += raster_at(raster, j2 + 1, ex, ey, ox, oy, spacing)
            else:
                w = lm[m]
                if last:
                    for t in range(j1, j2 + 2):
                        k = min(max(t - j1 - 1, 0), n_mid)
                        mean[t, 0] += w * (sx + k * bx)
                        mean[t, 1] += w * (sy + k * by)
                else:
                    m1[0] += w * g0
                    m2[0] += w * g0 * g0
                    m1[1] += w * g1
                    m2[1] += w * g1 * g1
                    if n_mid > 0:
                        m1[4] += w * fb
                        m2[4] += w * fb * fb
                        mass[1, qb - ranges[1, 0]] += w
            for p in (0, 2):
                l_ = la if p == 0 else lc
                for k in range(n_k[p]):
                    n = ranges[p, 1] - ranges[p, 0] + 1
                    f, kq = _piece_at(pieces[k], points[m, 4 + p : 6 + p], box, 2 + 2 * p, ranges[p], n)
                    dx, dy = 0.0, 0.0
                    if rep == 0 or last:
                        h = head[p] + (2.0 * f - 1.0) * turn[p]
                        dx, dy = bins[p, kq] * bin_w * np.cos(h), bins[p, kq] * bin_w * np.sin(h)
                    if rep == 0:
                        lv = lps[p, kq]
                        if p == 0:
                            for t in range(j1):
                                lv += raster_at(
                                    raster, t, sx - (j1 - t) * dx, sy - (j1 - t) * dy, ox, oy, spacing
                                )
                        else:
                            for t in range(j2 + 2, T):
                                lv += raster_at(
                                    raster, t, ex + (t - j2 - 1) * dx, ey + (t - j2 - 1) * dy, ox, oy, spacing
                                )
                        l_[m, k] = lv
                        continue
                    wk = w * l_[m, k]
                    if not last:
                        m1[2 + 2 * p] += wk * f
                        m2[2 + 2 * p] += wk * f * f
                        mass[p, kq - ranges[p, 0]] += wk
                    elif p == 0:
                        for t in range(j1):
                            mean[t, 0] += wk * (sx - (j1 - t) * dx)
                            mean[t, 1] += wk * (sy - (j1 - t) * dy)
                    else:
                        for t in range(j2 + 2, T):
                            mean[t, 0] += wk * (ex + (t - j2 - 1) * dx)
                            mean[t, 1] += wk * (ey + (t - j2 - 1) * dy)
                if rep == 0:
                    v += _to_weights(l_[m], n_k[p])
            if rep == 0:
                lm[m] = v
        if rep == 0:
            log_total = _to_weights(lm, M)
            mean[:] = 0.0
            m1[:] = 0.0
            m2[:] = 0.0
            mass[:] = 0.0
    return log_total - np.log(M * n_k[0] * n_k[2])


@njit(cache=True, nogil=True)
def _two_stop_family(
    tr, j1, j2, speeds, restarts, spacing, points, pieces, ox, oy, raster, buffers, mean, floor
):  # pragma: no cover - compiled
    """Log evidence of the family of walks that stop at steps ``j1 < j2`` (:func:`_weigh_two_stops`)
    in the straight lines' measure (the first heading by their density, the others by ``1 / 2
    pi`` each); its posterior mean into ``mean (T, 2)``."""
    T = tr.shape[0]
    la, lc, lm = buffers
    n_mid = j2 - j1 - 1
    before, after = j1 >= 1, j2 + 2 <= T - 1
    at = np.array([0.5 * (tr[j1, 0] + tr[j1 + 1, 0]), 0.5 * (tr[j1, 1] + tr[j1 + 1, 1])])
    head = np.zeros(3)
    turn = np.full(3, TWO_LINE_TURN)
    V = max(len(speeds), len(restarts))
    bins, lps = np.ones((3, V), np.int64), np.zeros((3, V))
    ranges = np.zeros((3, 2), np.int64)
    if before:
        vx, vy = fit_line(tr, 0, j1)[2:]
        head[0] = np.arctan2(vy, vx)
        b_, l_ = speed_bins(speeds, np.hypot(vx, vy), TWO_LINE_WINDOW, spacing)
        if not len(b_):
            return -np.inf
        bins[0, : len(b_)], lps[0, : len(b_)], ranges[0, 1] = b_, l_, len(b_) - 1
        if j1 >= 3:
            turn[0] = LINE_TURN
    for p, lo, hi, on in ((1, j1 + 1, j2, n_mid > 0), (2, j2 + 1, T - 1, after)):
        if not on:
            continue
        vx, vy = fit_line(tr, lo, hi)[2:]
        head[p] = np.arctan2(vy, vx)
        b_, l_ = prior_bins(restarts, 0, len(restarts) - 1)
        bins[p, : len(b_)], lps[p, : len(b_)], ranges[p, 1] = b_, l_, len(b_) - 1
        if hi - lo >= 3:
            turn[p] = LINE_TURN
    box = np.array([0.0, 1.0] * 8)
    # the stage's spacing of points (two or four coordinates) and of pieces, as a share of a side
    apart = np.array([points.shape[0] ** (-0.25 if n_mid > 0 else -0.5), pieces.shape[0] ** -0.5])
    m1, m2, mass = np.zeros(8), np.zeros(8), np.zeros((3, V))
    log_ev = -np.inf
    for stage in range(TWO_LINE_STAGES):
        last = stage + 1 == TWO_LINE_STAGES
        log_ev = _weigh_two_stops(
            j1, j2, at, head, turn, box, bins, lps, ranges, points, pieces, ox, oy, raster, spacing,
            la, lc, lm, last, mean, m1, m2, mass,
        )  # fmt: skip
        share = (box[1] - box[0]) * (box[3] - box[2])
        if before:
            share *= (box[5] - box[4]) * (ranges[0, 1] - ranges[0, 0] + 1)
            log_ev += np.log(turn[0] / LINE_TURN)
        for p, on in ((1, n_mid > 0), (2, after)):
            if on:
                share *= (box[5 + 4 * p] - box[4 + 4 * p]) * (ranges[p, 1] - ranges[p, 0] + 1)
                log_ev += np.log(turn[p] / np.pi)
        log_ev += np.log(share)
        if last:
            break
        if log_ev < floor:
            return -np.inf
        for d in (0, 1):
            narrow_box(box, d, m1[d], m2[d], 1.0, LINE_SPREAD, apart[0])
        for p, on in ((0, before), (1, n_mid > 0), (2, after)):
            if on:
                d = 2 + 2 * p
                narrow_box(box, d, m1[d], m2[d], 1.0, LINE_SPREAD, apart[0] if p == 1 else apart[1])
                ranges[p, 0], ranges[p, 1] = narrow_bins(mass[p], ranges[p, 0], ranges[p, 1], 1.0)
    return log_ev


@njit(cache=True, nogil=True)
def _lines_posterior(
    box, offsets, ll, px, py, top, n_a, n_b, last, mean, m1, m2, mass_a, mass_b
):  # pragma: no cover - compiled
    """What :func:`_weigh_stop` leaves of a stage of :func:`_weigh_two_lines`'s lines (``ll``,
    ``px``, ``py``, the largest log-likelihood ``top``; ``n_a``, ``n_b`` speed bins drawn). Returns
    the log of their mean likelihood."""
    N, T = px.shape
    total = 0.0
    mean[:] = 0.0
    m1[:] = 0.0
    m2[:] = 0.0
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
    m1 /= total
    m2 /= total
    mass_a /= total
    mass_b /= total
    return top + np.log(total / N)


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
    kind, tr, jv, speeds, restarts, spacing, offsets, points, pieces, ox, oy, raster, free, origin, res,
    buffers, stop_buffers, mean, floor
):  # pragma: no cover - compiled  # fmt: skip
    """Log evidence of the family of walks that stop, turn or change speed (``kind``) at step
    ``jv``, in the straight lines' measure (the first heading by their density, the second by
    ``1 / 2 pi``); its posterior mean into ``mean (T, 2)``. A stop's stages weigh ``points`` with
    ``pieces`` (:func:`_weigh_stop`, scratch ``stop_buffers``: ``la``, ``lb (M, K)``, ``lm
    (M,)``), the others' ``offsets``' lines (:func:`_weigh_two_lines`, scratch ``buffers``:
    ``ll (N,)``, ``px``, ``py (N, T)``). ``-inf`` where no walk speed lies near the first
    piece's (or the second's, for a change of speed), or where the first stage's evidence lies
    below ``floor``."""
    T = tr.shape[0]
    N = offsets.shape[0]
    ll, px, py = buffers
    la, lb, lm = stop_buffers
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
    # a stage's spacing of lines or points as a share of the box's side, per coordinate
    apart = np.full(6, 1.0 / N ** (1.0 / 6.0))  # N quasi-random lines in six dimensions
    if kind == _STOP:
        apart[:2] = 1.0 / np.sqrt(points.shape[0])
        apart[2:] = 1.0 / np.sqrt(pieces.shape[0])
    log_ev = -np.inf
    m1, m2 = np.zeros(6), np.zeros(6)
    mass_a, mass_b = np.zeros(len(bins_a)), np.zeros(len(bins_b))  # a stage's weight per speed bin
    for stage in range(TWO_LINE_STAGES):
        last = stage + 1 == TWO_LINE_STAGES
        if kind == _STOP:
            log_ev = _weigh_stop(
                jv, at, head, turn, box, bins_a, lp_a, range_a, bins_b, lp_b, range_b, points, pieces,
                ox, oy, raster, spacing, la, lb, lm, last, mean, m1, m2, mass_a, mass_b,
            )  # fmt: skip
        else:
            top = _weigh_two_lines(
                kind, jv, at, head, turn, box, bins_a, lp_a, range_a, bins_b, lp_b, range_b, offsets,
                ox, oy, raster, spacing, free, origin, res, ll, px, py,
            )  # fmt: skip
            log_ev = _lines_posterior(
                box, offsets, ll, px, py, top, range_a[1] - range_a[0] + 1, range_b[1] - range_b[0] + 1,
                last, mean, m1, m2, mass_a, mass_b,
            )  # fmt: skip
        share = (box[1] - box[0]) * (box[3] - box[2])
        if before:
            share *= (box[5] - box[4]) * (range_a[1] - range_a[0] + 1)
            log_ev += np.log(turn[0] / LINE_TURN)
        if pace:
            share *= range_b[1] - range_b[0] + 1
        elif after:
            share *= (box[9] - box[8]) * (range_b[1] - range_b[0] + 1)
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
            narrow_box(box, d, m1[d], m2[d], 1.0, LINE_SPREAD, apart[d])
        range_a[0], range_a[1] = narrow_bins(mass_a, range_a[0], range_a[1], 1.0)
        range_b[0], range_b[1] = narrow_bins(mass_b, range_b[0], range_b[1], 1.0)
    return log_ev


@njit(cache=True, nogil=True)
def _two_line_kernel(
    tracked, xy, lp, line, delta, speeds, restarts, log_stop, spacing, offsets, points, pieces, points2,
    pieces2, free, origin, res
):  # pragma: no cover - compiled  # fmt: skip
    B, T = lp.shape[:2]
    N = offsets.shape[0]
    out = line.copy()
    mixed = delta.copy()
    mean = np.empty((T, 2))
    buffers = np.empty(N), np.empty((N, T)), np.empty((N, T))
    M, K = points.shape[0], pieces.shape[0]
    stop_buffers = np.empty((M, K)), np.empty((M, K)), np.empty(M)
    M2 = points2.shape[0]
    two_buffers = np.empty((M2, pieces2.shape[0])), np.empty((M2, pieces2.shape[0])), np.empty(M2)
    ev, ev2 = np.empty((3, T - 1)), np.empty((T - 1, T - 1))  # the families' evidence and means
    means, means2 = np.empty((3, T - 1, T, 2)), np.empty((T - 1, T - 1, T, 2))
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
        ev[:] = -np.inf
        for kind in (_STOP, _TURN, _PACE):
            bias = log_stop if kind == _STOP else PACE_BIAS if kind == _PACE else 0.0
            for jv in range(T - 1):
                if stop_at[jv] if kind == _STOP else turn_at[jv] if kind == _TURN else jv == pace_at:
                    e = _family(
                        kind, tr, jv, speeds, restarts, spacing, offsets, points, pieces, ox, oy,
                        raster, free, origin, res, buffers, stop_buffers, mean, top - FAMILY_PRUNE - bias,
                    )  # fmt: skip
                    ev[kind, jv] = e + bias
                    means[kind, jv] = mean
                    top = max(top, ev[kind, jv])
        ev2[:] = -np.inf
        if stops:
            shortest = np.argsort(step, kind="mergesort")[:TWO_STOP_STEPS]
            for j1 in range(T - 1):
                for j2 in range(j1 + 1, T - 1):
                    near = (shortest == j1).any() and (shortest == j2).any()
                    if near and stop_at[j1] and stop_at[j2]:
                        bias = 2.0 * log_stop
                        e = _two_stop_family(
                            tr, j1, j2, speeds, restarts, spacing, points2, pieces2, ox, oy, raster,
                            two_buffers, mean, top - FAMILY_PRUNE - bias,
                        )  # fmt: skip
                        ev2[j1, j2] = e + bias
                        means2[j1, j2] = mean
                        top = max(top, ev2[j1, j2])
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
        for j1 in range(T - 1):
            for j2 in range(T - 1):
                if ev2[j1, j2] > -np.inf:
                    w = np.exp(ev2[j1, j2] - top)
                    total += w
                    acc += w * means2[j1, j2]
        out[b] = acc / total
        mixed[b] = top + np.log(total) - np.log(n_bins) - best
    return out, mixed
