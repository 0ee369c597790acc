"""Compiled kernels of the online candidate filter: one step forward, one pass back.

The constant-velocity smoother of :func:`~estimation.smoothing.hmm.velocity_posterior` keeps a
message over every pair of candidates ``(x_t-1, x_t)`` and sums over every triple, ``O(K^3)`` per
step. Almost all of that mass sits on a few pairs, so these kernels keep the ``M`` most likely
pairs of each step (a beam) and work in ``O(M K)`` per step: a forward step needs only the last
step's pairs, so a user's estimate is updated in constant time per fingerprint, and the stored
pairs give the smoothed marginals of any prefix by one backward pass (:func:`beam_smooth`, one call
for any set of prefixes, which bins the accelerations between consecutive steps' pairs once for all
of them). A step's kept pairs are stored in index order (by their candidate at the step
before, then at the step), so the backward pass finds the pairs that continue a pair without
sorting. With ``M >= K^2`` nothing is pruned and the result is the dense smoother's.

Motion models reach the kernels as the arrays of :func:`motion_arrays` (a
:class:`~estimation.smoothing.motion.MotionTable`'s tables); all kernels loop over sequences in
compiled code, in float64, and are deterministic (ties are broken by index order).
"""

from __future__ import annotations

import math
import weakref
from typing import NamedTuple

import numpy as np

from mmwsim._jit import njit

from .._stamps import same_stamp, stamp
from .motion import MixtureMotion, MotionTable

__all__ = [
    "MAX_CANDIDATES",
    "MotionArrays",
    "PAIR_INDEX",
    "beam_smooth",
    "motion_arrays",
    "pair_forward",
    "pair_start",
    "rw_smooth",
    "rw_step",
    "sample_paths",
]

_NEG = -1e300  # log of a pair that was pruned (or an impossible one)
# A term this far (log) below the largest of its sum changes it by less than float64 resolves
# (e^-40 = 4e-18), so its exponential is not computed.
_NEGLIGIBLE = -40.0
# Products of probabilities below this have lost precision to underflow (1e-308 is the smallest
# normal float64).
_TINY = 1e-290
# The kept pairs' candidate indices, stored for every step of every user until its backward
# passes: a quarter of the bytes of int64 indices, half of a pair's with its float64 message (a
# filter's stored state is mostly these, and touching fresh memory is much of a forward step's
# cost).
PAIR_INDEX = np.int16
MAX_CANDIDATES = int(np.iinfo(PAIR_INDEX).max)


class MotionArrays(NamedTuple):
    """A motion table as plain arrays for the kernels (see :class:`MotionTable`)."""

    step_table: np.ndarray  # (n_step,) log density of a displacement length bin
    speed_edges: np.ndarray  # (n_band - 1,) inner speed-band edges, units per step
    accel_table: np.ndarray  # (n_band, n_acc, n_acc) log density of (along, across) acceleration
    bin: float
    reach: float
    place: tuple  # (place_speed, log_place (H, W) float32, origin (2,), res); see MotionTable
    accel_prob: np.ndarray  # exp(accel_table), float32 to halve the cache it takes: the kernels multiply
    headings: int  # 0: the motion's frame; n: the lattice frame with n heading bins per quadrant
    heading_slopes: np.ndarray  # (max(headings - 1, 0),) inner heading bin edges, slopes v_y / v_x
    # the largest and smallest of accel_table: the kernels' pruning bounds, kept with the table
    # as the kernels run per slice of a batch and a sub-cell table's maximum alone takes 2-4 ms
    accel_max: float
    accel_min: float
    # (wall_classes, free (H, W) bool, origin (2,), res): the classes from wall_classes on are
    # read where the way straight ahead is blocked on the free-space raster (MotionTable.walls;
    # wall_classes 0: none). A tuple of its own: held in place, which the candidate loops read,
    # it made prediction 15 to 25 % slower, walls or none.
    walls: tuple


def motion_arrays(motion: MotionTable | MixtureMotion) -> MotionArrays:
    """The kernels' view of ``motion`` (read only); a hand-set :class:`MixtureMotion` is tabulated
    on a :class:`MotionTable`'s bins first (its densities at the bin centres).

    A table's arrays are made once and kept while the table lives and none of its buffers is
    replaced or changed in place: a filter is made per batch, and converting the sub-cell tables
    costs more than a batch's forward step."""
    if isinstance(motion, MixtureMotion):
        return _arrays(_tabulate(motion))
    key = stamp(float(motion.bin), float(motion.reach), motion, *(motion.walls or ()))
    kept = _KEPT.get(motion)
    if kept is not None and same_stamp(kept[0], key):
        return kept[1]
    arrays = _arrays(motion)
    _KEPT[motion] = (key, arrays)
    return arrays


# table -> (stamp, arrays)
_KEPT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _arrays(motion: MotionTable) -> MotionArrays:
    place = (
        float(motion.place_speed),
        motion.log_place.float().numpy().copy(),
        motion.place_origin.double().numpy().copy(),
        float(motion.place_res),
    )
    accel = motion.log_accel_table.double().numpy().copy()
    return MotionArrays(
        motion.log_step_table.double().numpy().copy(),
        motion.speed_edges.double().numpy().copy(),
        accel,
        float(motion.bin),
        float(motion.reach),
        place,
        np.exp(accel).astype(np.float32),
        int(motion.headings),
        motion.heading_slopes,
        float(accel.max()),
        float(accel.min()),
        _wall_arrays(motion),
    )


def _wall_arrays(motion: MotionTable) -> tuple:
    """:attr:`MotionArrays.walls` of ``motion``. The raster is read only whether there are walls
    or none: a writeable default beside :meth:`MotionTable.with_walls`' read-only raster is
    another type to numba, and every kernel was compiled twice."""
    if motion.walls is None:
        n, free, origin, res = 0, np.zeros((1, 1), np.bool_), np.zeros(2), 1.0
    else:
        n, (free, origin, res) = motion.wall_classes, motion.walls
    free = np.array(free, np.bool_)
    free.flags.writeable = False
    return int(n), free, np.array(origin, np.float64), float(res)


def _tabulate(mix: MixtureMotion) -> MotionTable:
    import torch

    table = MotionTable(speed_edges=(), bin=0.25, reach=24.0, max_step=60.0)
    n_acc = table.log_accel_table.shape[1]
    c = -table.reach + (torch.arange(n_acc, dtype=torch.float64) + 0.5) * table.bin
    a = torch.stack(torch.meshgrid(c, c, indexing="ij"), -1)
    table.log_accel_table[0] = mix.log_accel(torch.zeros(2, dtype=torch.float64), a).float()
    r = (torch.arange(len(table.log_step_table), dtype=torch.float64) + 0.5) * table.bin
    table.log_step_table.copy_(mix.log_first(torch.stack([r, torch.zeros_like(r)], -1)).float())
    table.fitted.fill_(True)
    return table


@njit(cache=True, inline="always")
def _log_first(vx, vy, step_table, bin_):
    i = min(int(math.sqrt(vx * vx + vy * vy) / bin_), len(step_table) - 1)
    return step_table[i]


@njit(cache=True, inline="always")
def _count_below(edges, x):
    # how many of the ascending edges lie below x (torch.bucketize's bin), by bisection
    lo, hi = 0, len(edges)
    while lo < hi:
        mid = (lo + hi) >> 1
        if edges[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, inline="always")
def _frame(vx, vy, speed_edges, headings, slopes):
    """MotionTable._classify after the displacement ``v``: the map ``(f00, f01, f10, f11)`` of an
    acceleration to the table's frame and the class of ``v`` (speed band, and heading bin)."""
    n = math.sqrt(vx * vx + vy * vy)
    band = _count_below(speed_edges, n)
    if headings == 0:
        ux, uy = (vx / n, vy / n) if n > 0 else (1.0, 0.0)
        return ux, uy, -uy, ux, band
    # the quarter turn (cos, sin) that brings v into the quadrant x > 0, y >= 0 (none for v = 0)
    if vx > 0 and vy >= 0:
        c, s = 1.0, 0.0
    elif vx <= 0 and vy > 0:
        c, s = 0.0, -1.0
    elif vx < 0 and vy <= 0:
        c, s = -1.0, 0.0
    elif vx == 0 and vy == 0:
        c, s = 1.0, 0.0
    else:
        c, s = 0.0, 1.0
    cx, cy = c * vx - s * vy, s * vx + c * vy
    # the number of bin edges below the slope, as MotionTable._classify counts them
    k = _count_below(slopes, cy / cx if cx > 0 else 0.0)
    return c, -s, s, c, band * headings + k


@njit(cache=True, inline="always")
def _accel_scale(f00, f01, f10, f11, bin_, reach):
    """The frame map of :func:`_frame` scaled to bins, and the offset of the table's first bin:
    what :func:`_accel_index` reads a class's table with."""
    inv = 1.0 / bin_
    return f00 * inv, f01 * inv, f10 * inv, f11 * inv, reach * inv


@njit(cache=True, inline="always")
def _accel_index(wx, wy, vx, vy, g00, g01, g10, g11, c, n, idx):
    """MotionTable.log_accel's bins: the flat indices ``idx (len(wx),)`` into a class's ``n x n``
    table of the accelerations ``(wx - vx, wy - vy)`` in the table's frame (scaled by
    :func:`_accel_scale`; the tensor code's bins exactly where the bin is a power of two or the
    accelerations lie at bin centres, as a lattice's do). Forward and backward passes both read a
    table through this loop, so they read the same bins; indices first, then the table, so that
    both loops vectorise."""
    hi = n - 1
    for r in range(len(wx)):
        ax, ay = wx[r] - vx, wy[r] - vy
        i = min(max(int(g00 * ax + g01 * ay + c), 0), hi)
        j = min(max(int(g10 * ax + g11 * ay + c), 0), hi)
        idx[r] = i * n + j


@njit(cache=True, inline="always")
def _place_at(x, y, place):
    # MotionTable.log_place_ratio of a fast user at x: the place table at the cell holding x.
    _, table, origin, res = place
    i = min(max(int(math.floor((x - origin[0]) / res)), 0), table.shape[0] - 1)
    j = min(max(int(math.floor((y - origin[1]) / res)), 0), table.shape[1] - 1)
    return table[i, j]


@njit(cache=True, inline="always")
def _blocked(x, y, walls):
    # whether the free-space raster has no free point nearest x (or x lies off it)
    _, free, origin, res = walls
    i = int(math.floor((x - origin[0]) / res + 0.5))
    j = int(math.floor((y - origin[1]) / res + 0.5))
    if i < 0 or j < 0 or i >= free.shape[0] or j >= free.shape[1]:
        return True
    return not free[i, j]


@njit(cache=True, inline="always")
def _wall_class(cls, x, y, vx, vy, walls):
    # MotionArrays.walls: after displacement v to x, the class among the wall classes where
    # the way straight ahead (its end or its middle) is blocked
    if walls[0] == 0:
        return cls
    if _blocked(x + vx, y + vy, walls) or _blocked(x + 0.5 * vx, y + 0.5 * vy, walls):
        return cls + walls[0]
    return cls


@njit(cache=True, inline="always")
def _log_place(x, y, vx, vy, place):
    # MotionTable.log_place_ratio: the place table at the cell holding x if v is fast, else 0.
    if vx * vx + vy * vy <= place[0] * place[0]:
        return 0.0
    return _place_at(x, y, place)


@njit(cache=True, nogil=True)
def rw_step(prev_xy, prev_f, xy, lp, inv_two_s2):
    """One forward step of the random-walk filters over a step's candidates.

    Parameters
    ----------
    prev_xy : (B, Kp, 2) float64, metres; the previous step's kept candidates
    prev_f : (B, Kp, n_s) float64; their filtered log posteriors, one per step scale
    xy : (B, S, 2) float64, metres; this step's candidates
    lp : (B, S) float64; their log likelihoods
    inv_two_s2 : (n_s,) float64; ``1 / (2 s^2)`` per step scale ``s`` (metres)

    Returns
    -------
    (B, S, n_s) float64 filtered log posteriors, normalised per sequence and scale
    """
    B, S = lp.shape
    Kp, ns = prev_f.shape[1], prev_f.shape[2]
    out = np.empty((B, S, ns))
    for b in range(B):
        for s in range(ns):
            m = -np.inf
            for i in range(Kp):
                m = max(m, prev_f[b, i, s])
            top = -np.inf
            for j in range(S):
                acc = 0.0
                for i in range(Kp):
                    dx = xy[b, j, 0] - prev_xy[b, i, 0]
                    dy = xy[b, j, 1] - prev_xy[b, i, 1]
                    e = prev_f[b, i, s] - m - (dx * dx + dy * dy) * inv_two_s2[s]
                    if e > _NEGLIGIBLE:
                        acc += math.exp(e)
                v = (math.log(acc) + m if acc > 0 else -690.0 + m) + lp[b, j]
                out[b, j, s] = v
                top = max(top, v)
            tot = 0.0
            for j in range(S):
                tot += math.exp(out[b, j, s] - top)
            norm = top + math.log(tot)
            for j in range(S):
                out[b, j, s] -= norm
    return out


@njit(cache=True, nogil=True)
def rw_smooth(xy, lp, inv_two_s2, lengths):
    """The random-walk smoothers (:func:`~estimation.smoothing.hmm.motion_posterior`) of the
    prefixes ``lengths`` of kept candidates, every step scale at once.

    The transition weights and the forward messages are worked out once, to the longest prefix,
    and a backward pass runs per prefix; a sum over candidates is a product with the step's
    transition weights in linear space, each message rescaled by its largest log value, as
    :func:`~estimation.smoothing.hmm.motion_posterior` does in torch for one prefix (and one
    scale): the same to float64 rounding.

    Parameters
    ----------
    xy : (B, T, K, 2) float64, metres; the steps' candidates
    lp : (B, T, K) float64; their log likelihoods
    inv_two_s2 : (n_s,) float64; ``1 / (2 s^2)`` per step scale ``s`` (metres)
    lengths : (P,) int64; prefix lengths, each 1..T

    Returns
    -------
    (B, sum(lengths), K, n_s) float64 smoothed log posteriors, normalised per step and scale:
    the prefixes' steps one prefix after another
    """
    B, T, K = lp.shape
    ns = len(inv_two_s2)
    P = len(lengths)
    T_max = 1
    for p in range(P):
        if lengths[p] < 1 or lengths[p] > T:
            raise ValueError("prefix lengths must lie in 1..T")
        T_max = max(T_max, lengths[p])
    out = np.empty((B, lengths.sum(), K, ns))
    trans = np.empty((max(T_max - 1, 1), ns, K, K))
    fwd = np.empty((T_max, K))
    bwd = np.empty((T_max, K))
    u = np.empty(K)
    d2 = np.empty(K)
    sums = np.empty(K)
    for b in range(B):
        for t in range(T_max - 1):
            for i in range(K):
                for j in range(K):
                    dx = xy[b, t, i, 0] - xy[b, t + 1, j, 0]
                    dy = xy[b, t, i, 1] - xy[b, t + 1, j, 1]
                    d2[j] = dx * dx + dy * dy
                for s in range(ns):
                    for j in range(K):
                        # below e^-746 the weight is 0 in float64 whether or not it is worked out
                        e = -d2[j] * inv_two_s2[s]
                        trans[t, s, i, j] = math.exp(e) if e > -746.0 else 0.0
        for s in range(ns):
            for k in range(K):
                fwd[0, k] = lp[b, 0, k]
            for t in range(1, T_max):
                m = -np.inf
                for i in range(K):
                    m = max(m, fwd[t - 1, i])
                for j in range(K):
                    sums[j] = 0.0
                for i in range(K):
                    ui = math.exp(fwd[t - 1, i] - m)
                    for j in range(K):
                        sums[j] += trans[t - 1, s, i, j] * ui
                for j in range(K):
                    fwd[t, j] = math.log(max(sums[j], 1e-300)) + m + lp[b, t, j]
            start = 0
            for p in range(P):
                L = lengths[p]
                for k in range(K):
                    bwd[L - 1, k] = 0.0
                for t in range(L - 2, -1, -1):
                    m = -np.inf
                    for j in range(K):
                        u[j] = lp[b, t + 1, j] + bwd[t + 1, j]
                        m = max(m, u[j])
                    for j in range(K):
                        u[j] = math.exp(u[j] - m)
                    for i in range(K):
                        acc = 0.0
                        for j in range(K):
                            acc += trans[t, s, i, j] * u[j]
                        bwd[t, i] = math.log(max(acc, 1e-300)) + m
                for t in range(L):
                    top = -np.inf
                    for k in range(K):
                        top = max(top, fwd[t, k] + bwd[t, k])
                    tot = 0.0
                    for k in range(K):
                        tot += math.exp(fwd[t, k] + bwd[t, k] - top)
                    norm = top + math.log(tot)
                    for k in range(K):
                        out[b, start + t, k, s] = fwd[t, k] + bwd[t, k] - norm
                start += L
    return out


@njit(cache=True, nogil=True)
def _keep_best(dense, M, pi, ci, la, lowest=_NEG):
    """The ``M`` largest entries above ``lowest`` of ``dense (Kp, K)`` into ``pi, ci, la`` in
    index order (row-major: ``pi`` ascending), ties at the cut taken in index order too; padded
    with ``_NEG``. Returns how many."""
    K = dense.shape[1]
    flat = dense.ravel()
    N = len(flat)
    n_ok = 0
    for q in range(N):
        if flat[q] > lowest:
            n_ok += 1
    cut, ties = lowest, 0
    if n_ok > M:
        # A selection, not a sort: the kept pairs' order is the index order. The M-th largest
        # lies above lowest, so it is selected among those alone (most pairs are pruned).
        above = np.empty(n_ok)
        n = 0
        for q in range(N):
            if flat[q] > lowest:
                above[n] = flat[q]
                n += 1
        cut = np.partition(above, n_ok - M)[n_ok - M]
        ties = M
        for q in range(n_ok):
            if above[q] > cut:
                ties -= 1
    n = 0
    for q in range(N):
        v = flat[q]
        if v > cut or (v == cut and ties > 0 and v > lowest):
            if v == cut:
                ties -= 1
            pi[n], ci[n], la[n] = q // K, q % K, v
            n += 1
    for q in range(n, M):
        pi[q], ci[q], la[q] = 0, 0, _NEG
    return n


@njit(cache=True, nogil=True)
def _marginal(la, group, K, out):
    """Normalised log-sum-exp of ``la (M,)`` grouped by ``group (M,)`` into ``out (K,)``."""
    m = -np.inf
    for q in range(len(la)):
        if la[q] > _NEG:
            m = max(m, la[q])
    acc = np.zeros(K)
    for q in range(len(la)):
        if la[q] > _NEG:
            acc[group[q]] += math.exp(la[q] - m)
    tot = acc.sum()
    for k in range(K):
        out[k] = math.log(acc[k] / tot) if acc[k] > 0 else _NEG


@njit(cache=True, nogil=True)
def pair_start(x0, x1, lp0, lp1, M, step_table, bin_, place):
    """The first pair message: every ``(x_0, x_1)`` scored by both likelihoods, the first
    displacement's density and both places given that displacement, the ``M`` best kept.

    Parameters
    ----------
    x0, x1 : (B, K0, 2), (B, K1, 2) float64; candidates of steps 0 and 1
    lp0, lp1 : (B, K0), (B, K1) float64 log likelihoods
    M : int, beam width
    step_table, bin_, place : the motion's displacement and place tables (:class:`MotionArrays`)

    Returns
    -------
    pi, ci : (B, M) :data:`PAIR_INDEX`; indices of the pairs' candidates at steps 0 and 1
    la : (B, M) float64; forward log messages (``_NEG`` past the kept pairs)
    marg : (B, K1) float64; filtered log marginal of step 1
    """
    B, K0, K1 = x0.shape[0], x0.shape[1], x1.shape[1]
    if max(K0, K1) > MAX_CANDIDATES:
        raise ValueError("a beam step holds at most 32767 candidates (MAX_CANDIDATES)")
    pi = np.empty((B, M), PAIR_INDEX)
    ci = np.empty((B, M), PAIR_INDEX)
    la = np.empty((B, M))
    marg = np.empty((B, K1))
    dense = np.empty((K0, K1))
    for b in range(B):
        for i in range(K0):
            for j in range(K1):
                vx, vy = x1[b, j, 0] - x0[b, i, 0], x1[b, j, 1] - x0[b, i, 1]
                dense[i, j] = (
                    lp0[b, i]
                    + lp1[b, j]
                    + _log_first(vx, vy, step_table, bin_)
                    + _log_place(x0[b, i, 0], x0[b, i, 1], vx, vy, place)
                    + _log_place(x1[b, j, 0], x1[b, j, 1], vx, vy, place)
                )
        _keep_best(dense, M, pi[b], ci[b], la[b])
        _marginal(la[b], ci[b], K1, marg[b])
    return pi, ci, la, marg


@njit(cache=True, nogil=True)
def pair_forward(
    xpp, xp, xc, pi, ci, la, lp, M, speed_edges, headings, slopes, accel_table, bin_, reach, place, accel_prob,
    a_max, walls,
):  # fmt: skip
    """One forward step of the beam: pairs ``(x_t-2, x_t-1)`` to pairs ``(x_t-1, x_t)``.

    Parameters
    ----------
    xpp, xp, xc : (B, K, 2) float64; candidates of steps t-2, t-1 and t
    pi, ci, la : (B, M') the kept pairs of step t-1 (see :func:`pair_start`)
    lp : (B, K) float64; log likelihoods of step t
    M : int, beam width
    speed_edges, headings, slopes, accel_table, bin_, reach, place, accel_prob : the motion's
        acceleration and place tables (:class:`MotionArrays`)
    a_max : float, the largest entry of ``accel_table`` (``MotionArrays.accel_max``)
    walls : the free space the table's wall classes are read by (``MotionArrays.walls``)

    Returns
    -------
    pi, ci, la, marg : as :func:`pair_start`, for step t
    """
    B, Kp, K, Mp = xp.shape[0], xp.shape[1], xc.shape[1], pi.shape[1]
    if max(Kp, K) > MAX_CANDIDATES:
        raise ValueError("a beam step holds at most 32767 candidates (MAX_CANDIDATES)")
    n_acc = accel_table.shape[1]
    npi = np.empty((B, M), PAIR_INDEX)
    nci = np.empty((B, M), PAIR_INDEX)
    nla = np.empty((B, M))
    marg = np.empty((B, K))
    dense, key = np.empty((Kp, K)), np.empty((Kp, K))
    wx, wy = np.empty((Kp, K)), np.empty((Kp, K))
    idx = np.empty(K, np.int64)
    weight = np.empty((2, K))
    flat_prob = accel_prob.reshape(accel_prob.shape[0], -1)
    speed2 = place[0] * place[0]
    for b in range(B):
        for i in range(Kp):
            for j in range(K):
                wx[i, j], wy[i, j] = xc[b, j, 0] - xp[b, i, 0], xc[b, j, 1] - xp[b, i, 1]
        # Sums of exp(la_q + a_qj) are kept relative to the best pair's message (one exponential
        # per pair, the accelerations' densities multiplied in). The best pair goes first: once a
        # pair's message plus the likeliest acceleration lies _NEGLIGIBLE below the largest term
        # so far, its terms change no sum and are not computed.
        best_q, ref = 0, -np.inf
        for q in range(Mp):
            if la[b, q] > ref:
                best_q, ref = q, la[b, q]
        dense[:, :] = 0.0
        big, top = 0.0, -np.inf
        for r in range(Mp + 1):
            q = best_q if r == 0 else r - 1
            if (r > 0 and q == best_q) or la[b, q] <= _NEG or la[b, q] + a_max - top < _NEGLIGIBLE:
                continue
            a0, a1 = pi[b, q], ci[b, q]
            vx, vy = xp[b, a1, 0] - xpp[b, a0, 0], xp[b, a1, 1] - xpp[b, a0, 1]
            f00, f01, f10, f11, cls = _frame(vx, vy, speed_edges, headings, slopes)
            cls = _wall_class(cls, xp[b, a1, 0], xp[b, a1, 1], vx, vy, walls)
            g00, g01, g10, g11, c = _accel_scale(f00, f01, f10, f11, bin_, reach)
            _accel_index(wx[a1], wy[a1], vx, vy, g00, g01, g10, g11, c, n_acc, idx)
            scale = math.exp(la[b, q] - ref)
            prob = flat_prob[cls]
            row = dense[a1]
            p_big = np.float32(0.0)
            for j in range(K):
                pv = prob[idx[j]]
                row[j] += scale * pv
                p_big = max(p_big, pv)
            big = max(big, scale * p_big)
            top = ref + math.log(big) if big > 0 else top
        # The new pairs' messages are log(dense) + ref + lp + place. The beam keeps the M largest;
        # those are the M largest of dense * exp(lp + place - h) (h: the largest lp + place), so
        # only the kept pairs need a logarithm. A product below _TINY has lost precision (or
        # underflowed): with fewer than M above it, every message is computed in logs.
        h = -np.inf
        for j in range(K):
            # lp alone, and with the place term of a fast user (see _log_place)
            weight[0, j], weight[1, j] = lp[b, j], lp[b, j] + _place_at(xc[b, j, 0], xc[b, j, 1], place)
            h = max(h, weight[0, j], weight[1, j])
        for j in range(K):
            weight[0, j], weight[1, j] = math.exp(weight[0, j] - h), math.exp(weight[1, j] - h)
        n_good = 0
        for i in range(Kp):
            for j in range(K):
                k = dense[i, j] * weight[int(wx[i, j] * wx[i, j] + wy[i, j] * wy[i, j] > speed2), j]
                key[i, j] = k
                n_good += k > _TINY
        if n_good >= M:
            n = _keep_best(key, M, npi[b], nci[b], nla[b], 0.0)
            for q in range(n):
                nla[b, q] = math.log(nla[b, q]) + ref + h
        else:
            for i in range(Kp):
                for j in range(K):
                    d = dense[i, j]
                    place_ij = _log_place(xc[b, j, 0], xc[b, j, 1], wx[i, j], wy[i, j], place)
                    dense[i, j] = math.log(d) + ref + lp[b, j] + place_ij if d > 0 else _NEG
            _keep_best(dense, M, npi[b], nci[b], nla[b])
        _marginal(nla[b], nci[b], K, marg[b])
    return npi, nci, nla, marg


@njit(cache=True, nogil=True)
def _group(pi, n, Kp, start):
    """The first ``n`` kept pairs of a step by their candidate at the step before: the beam keeps
    them in index order, so candidate ``i``'s are the pairs ``start[i]:start[i + 1]``."""
    start[:] = 0
    for q in range(n):
        if q and pi[q] < pi[q - 1]:
            raise ValueError("a beam's kept pairs must be in index order")
        start[pi[q] + 1] += 1
    for i in range(Kp):
        start[i + 1] += start[i]


@njit(cache=True, nogil=True)
def _transitions(xpp, xp, xc, ppi, pci, pla, ci, start, tables, row, val, idx, gwx, gwy):
    """The acceleration densities from each kept pair of step t-1 to the kept pairs of step t
    that continue it: pair ``q``'s are ``val[row[q]:row[q + 1]]``, one per pair of its candidate
    at t-1's group (``start``, see :func:`_group`), in the group's order. They do not depend on
    the steps after t, so every prefix's backward pass reads them. ``idx, gwx, gwy``: scratch
    of at least the step's number of pairs."""
    speed_edges, headings, slopes, accel_table, bin_, reach, place, accel_prob, walls = tables
    n_acc = accel_table.shape[1]
    flat_prob = accel_prob.reshape(accel_prob.shape[0], -1)
    for i in range(xp.shape[0]):
        for m in range(start[i], start[i + 1]):
            gwx[m], gwy[m] = xc[ci[m], 0] - xp[i, 0], xc[ci[m], 1] - xp[i, 1]
    row[0] = 0
    for q in range(len(ppi)):
        a1 = pci[q]
        lo, n_r = start[a1], start[a1 + 1] - start[a1]
        row[q + 1] = row[q]
        if pla[q] <= _NEG or n_r == 0:
            continue
        vx, vy = xp[a1, 0] - xpp[ppi[q], 0], xp[a1, 1] - xpp[ppi[q], 1]
        f00, f01, f10, f11, cls = _frame(vx, vy, speed_edges, headings, slopes)
        cls = _wall_class(cls, xp[a1, 0], xp[a1, 1], vx, vy, walls)
        g00, g01, g10, g11, c = _accel_scale(f00, f01, f10, f11, bin_, reach)
        _accel_index(gwx[lo : lo + n_r], gwy[lo : lo + n_r], vx, vy, g00, g01, g10, g11, c, n_acc, idx)
        prob = flat_prob[cls]
        o = row[q]
        for r in range(n_r):
            val[o + r] = prob[idx[r]]
        row[q + 1] = o + n_r


@njit(cache=True, nogil=True)
def _backward_step(pci, pla, start, base, beta, row, val, floor, scale, head, out):
    """One sequence's backward messages ``out (Mp,)`` of the kept pairs of step t-1 from those
    of step t (``beta``, over its kept pairs grouped by ``start``, see :func:`_group`), through
    :func:`_transitions`' densities ``row, val``. ``base``: each pair of t's place and likelihood
    at t. A term whose rest lies ``floor`` below its group's largest is left out (its scale is
    zero). ``scale, head``: scratch."""
    for i in range(len(start) - 1):
        h = -np.inf
        for m in range(start[i], start[i + 1]):
            if beta[m] > _NEG:
                h = max(h, base[m] + beta[m])
        head[i] = h
        for m in range(start[i], start[i + 1]):
            rest = base[m] + beta[m] - h
            scale[m] = math.exp(rest) if beta[m] > _NEG and rest > floor else 0.0
    for q in range(len(pci)):
        out[q] = _NEG
        if pla[q] <= _NEG:
            continue
        lo, o = start[pci[q]], row[q]
        acc = 0.0
        for r in range(row[q + 1] - o):
            acc += val[o + r] * scale[lo + r]
        if acc > 0.0:
            out[q] = math.log(acc) + head[pci[q]]


@njit(cache=True, nogil=True)
def _prepare_step(b, t, work, start, base, row, val):
    """What the backward passes read at step t of sequence ``b``: the kept pairs ``(t-1, t)``
    grouped by their candidate at t-1 (``start``), each one's place and likelihood at t
    (``base``), and the densities from the kept pairs of t-1 (``row, val``, see
    :func:`_transitions`)."""
    xy, lp, pi, ci, la, place, tables, idx, gwx, gwy = work
    M, K = pi.shape[2], lp.shape[2]
    s = t - 1  # the pairs (t-1, t)
    n = 0
    while n < M and la[b, s, n] > _NEG:
        n += 1
    _group(pi[b, s], n, K, start)
    xp, xc = xy[b, t - 1], xy[b, t]
    for m in range(M):
        i, j = pi[b, s, m], ci[b, s, m]
        wx, wy = xc[j, 0] - xp[i, 0], xc[j, 1] - xp[i, 1]
        base[m] = _log_place(xc[j, 0], xc[j, 1], wx, wy, place) + lp[b, t, j]
    _transitions(
        xy[b, t - 2],
        xp,
        xc,
        pi[b, s - 1],
        ci[b, s - 1],
        la[b, s - 1],
        ci[b, s, :n],
        start,
        tables,
        row,
        val,
        idx,
        gwx,
        gwy,
    )


@njit(cache=True, nogil=True)
def beam_smooth(
    xy, lp, pi, ci, la, draw, lengths, n_paths, seed, speed_edges, headings, slopes, accel_table, bin_, reach,
    place, accel_prob, a_span, walls,
):  # fmt: skip
    """Smoothed log marginals of the first ``L`` steps given those ``L`` steps, for every ``L`` in
    ``lengths``, from a beam's stored forward messages: one backward pass over the kept pairs per
    prefix; and, where ``draw`` asks, paths drawn from the same posteriors (as
    :func:`sample_paths` draws them). The acceleration densities between the kept pairs of
    consecutive steps are worked out once for all the prefixes and paths.

    Parameters
    ----------
    xy : (B, T, K, 2) float64; the steps' candidates (T >= 2)
    lp : (B, T, K) float64; their log likelihoods
    pi, ci, la : (B, T - 1, M) the kept pairs of steps 1..T-1 (see :func:`pair_start`), index
        order
    draw : (B, n) bool; for which sequences and prefixes to draw paths (``(B, 0)``: none)
    lengths : (n,) int64, each in 2..T
    n_paths, seed : int; paths per sequence and prefix drawn, and their seed (see
        :func:`sample_paths`)
    speed_edges, headings, slopes, accel_table, bin_, reach, place, accel_prob : the motion's
        tables (:class:`MotionArrays`)
    a_span : float, the largest less the smallest entry of ``accel_table``
    walls : the free space the table's wall classes are read by (``MotionArrays.walls``)

    Returns
    -------
    marginals : (B, sum(lengths), K) float64 normalised log marginals: prefix ``i``'s steps are
        the rows from ``sum(lengths[:i])`` on (``_NEG`` for none)
    paths : (P,) int64; for each sequence in turn, for each prefix ``i`` drawn for it, its
        ``(n_paths, lengths[i])`` point indices (:func:`sample_paths`' rows), flattened
    """
    B, T, K = lp.shape
    M = pi.shape[2]
    T_max = 0
    for L in lengths:
        if L < 2 or L > T:
            raise ValueError("prefix lengths must lie in 2..T")
        T_max = max(T_max, L)
    if draw.shape[1] and draw.shape[1] != len(lengths):
        raise ValueError("draw must have a column per prefix length")
    tables = (speed_edges, headings, slopes, accel_table, bin_, reach, place, accel_prob, walls)
    # a term whose rest lies this far below its group's largest stays _NEGLIGIBLE below the sum
    # whatever the accelerations
    floor = _NEGLIGIBLE - a_span
    out = np.empty((B, lengths.sum(), K))
    n_drawn = 0
    for b in range(B):
        for i in range(draw.shape[1]):
            n_drawn += draw[b, i] * n_paths * lengths[i]
    paths = np.empty(n_drawn, np.int64)
    beta = np.empty(M)
    prev = np.empty(M)
    joint = np.empty(M)
    scale, head, idx = np.empty(M), np.empty(K), np.empty(M, np.int64)
    # per step t in 2..T_max-1: the pairs of t grouped, their place and likelihood, the densities;
    # kept for every step where several prefixes (or paths) share them, else made as the one
    # pass needs them (scratch of one step, whatever the length)
    shared = len(lengths) > 1 or n_drawn > 0
    slots = T_max if shared else 1
    start = np.zeros((slots, K + 1), np.int64)
    base = np.empty((slots, M))
    row = np.empty((slots, M + 1), np.int64)
    val = np.empty((slots, M * K))
    work = (xy, lp, pi, ci, la, place, tables, idx, np.empty(M), np.empty(M))
    scratch = _draw_scratch(n_paths, M, K)
    o_path = 0
    for b in range(B):
        if shared:
            for t in range(2, T_max):
                _prepare_step(b, t, work, start[t], base[t], row[t], val[t])
        o = 0
        for L in lengths:
            for m in range(M):
                beta[m] = 0.0 if la[b, L - 2, m] > _NEG else _NEG
            for t in range(L - 1, 0, -1):
                s = t - 1
                for m in range(M):
                    joint[m] = la[b, s, m] + beta[m]
                _marginal(joint, ci[b, s], K, out[b, o + t])
                if t == 1:
                    _marginal(joint, pi[b, s], K, out[b, o])
                    break
                u = t if shared else 0
                if not shared:
                    _prepare_step(b, t, work, start[u], base[u], row[u], val[u])
                _backward_step(
                    ci[b, s - 1],
                    la[b, s - 1],
                    start[u],
                    base[u],
                    beta,
                    row[u],
                    val[u],
                    floor,
                    scale,
                    head,
                    prev,
                )
                beta[:] = prev
            o += L
        for i in range(draw.shape[1]):
            if draw[b, i]:
                L = lengths[i]
                one = paths[o_path : o_path + n_paths * L].reshape(n_paths, L)
                _draw_paths(b, L, n_paths, seed, work, start, base, row, val, True, one, scratch)
                o_path += n_paths * L
    return out, paths


@njit(cache=True, nogil=True)
def _draw_scratch(n, M, K):
    """Scratch arrays of :func:`_draw_paths` for ``n`` paths through a beam of ``M`` pairs over
    ``K`` points."""
    # cw: the last pairs' cumulative weights (M), then every drawn pair's predecessors' (at most
    # M drawn pairs, each group at most K: one per point two steps back)
    return (
        np.empty(n, np.int64),
        np.empty(M, np.int64),
        np.empty(K + 1, np.int64),
        np.empty(K, np.int64),
        np.empty(M * K),
        np.empty(M),
        np.empty(M, np.int64),
        np.empty(M),
    )


@njit(cache=True, nogil=True)
def _draw_paths(b, T, n, seed, work, start, base, row, val, prepared, out, scratch):
    """Sequence ``b``'s ``n`` paths ``out (n, T)`` (point indices) drawn from the smoothed
    posterior of its first ``T`` steps (see :func:`sample_paths`). ``start, base, row, val``:
    :func:`_prepare_step`'s slots, filled for every step ``t`` (slot ``t``) where ``prepared``,
    else made here one step at a time (slot 0)."""
    xy, pi, ci, la = work[0], work[2], work[3], work[4]
    M, K = la.shape[2], xy.shape[2]
    cur, order, gstart, fill, cw, wq, mark, total = scratch
    # numba's generator has one state per thread, and a sequence runs on one thread from its
    # own seed: the legacy API is the one compiled code has
    np.random.seed(seed)  # noqa: NPY002
    s = T - 2
    top = -np.inf
    for q in range(M):
        top = max(top, la[b, s, q])
    acc = 0.0
    for q in range(M):
        acc += math.exp(la[b, s, q] - top) if la[b, s, q] > _NEG else 0.0
        cw[q] = acc
    u0 = np.random.random()  # noqa: NPY002
    q = 0
    for j in range(n):
        target = (j + u0) / n * acc
        while q < M - 1 and (cw[q] < target or la[b, s, q] <= _NEG):
            q += 1
        cur[j] = q
        out[j, T - 1], out[j, T - 2] = ci[b, s, q], pi[b, s, q]
    for t in range(T - 1, 1, -1):
        s = t - 1  # the paths' pairs (t-1, t); their predecessors are pairs (t-2, t-1)
        u = t if prepared else 0
        if not prepared:
            _prepare_step(b, t, work, start[0], base[0], row[0], val[0])
        st, rw, vl = start[u], row[u], val[u]
        # the predecessors grouped by their point at t-1 (a counting sort), and their messages
        gstart[:] = 0
        top = -np.inf
        for q in range(M):
            if la[b, s - 1, q] > _NEG:
                gstart[ci[b, s - 1, q] + 1] += 1
                top = max(top, la[b, s - 1, q])
        for k in range(K):
            gstart[k + 1] += gstart[k]
            fill[k] = gstart[k]
        for q in range(M):
            if la[b, s - 1, q] > _NEG:
                order[fill[ci[b, s - 1, q]]] = q
                fill[ci[b, s - 1, q]] += 1
                wq[q] = math.exp(la[b, s - 1, q] - top)
        # Paths at the same pair draw from the same predecessors: their cumulative weights are
        # summed once per pair and step (most of the n paths share a few pairs).
        mark[:] = -1
        used, likeliest = 0, -1
        for j in range(n):
            p = cur[j]
            a = pi[b, s, p]
            lo, hi = gstart[a], gstart[a + 1]
            if mark[p] < 0:
                mark[p] = used
                r = p - st[a]  # the pair's place among those leaving a (see _transitions)
                tot = 0.0
                for g in range(lo, hi):
                    q = order[g]
                    if rw[q + 1] - rw[q] > r:
                        tot += wq[q] * vl[rw[q] + r]
                    cw[used + g - lo] = tot
                total[p] = tot
                used += hi - lo
            o, tot = mark[p], total[p]
            if tot <= 0.0:  # no kept predecessor leads there: the likeliest one
                if likeliest < 0:
                    ref = -np.inf
                    for q in range(M):
                        if la[b, s - 1, q] > ref:
                            likeliest, ref = q, la[b, s - 1, q]
                    likeliest = max(likeliest, 0)
                cur[j] = likeliest
            else:
                target = np.random.random() * tot  # noqa: NPY002
                g = 0
                while g < hi - lo - 1 and cw[o + g] < target:
                    g += 1
                cur[j] = order[lo + g]
            out[j, t - 2] = pi[b, s - 1, cur[j]]


@njit(cache=True, nogil=True)
def sample_paths(
    xy, lp, pi, ci, la, T, n, seed, speed_edges, headings, slopes, accel_table, bin_, reach, place, accel_prob,
    walls,
):  # fmt: skip
    """Paths drawn from the smoothed posterior of the first ``T`` steps given those steps, from a
    beam's stored forward messages (forward filtering, backward sampling): the last pair by its
    message, then each pair before by its message times the acceleration density to the pair
    drawn after it (:func:`_transitions`' densities, worked out once per step for all paths).

    Parameters
    ----------
    xy : (B, T', K, 2) float64; the steps' points (T' >= T >= 2)
    lp : (B, T', K) float64; their log likelihoods
    pi, ci, la : (B, T' - 1, M) the kept pairs of steps 1.. (see :func:`pair_start`), index order
    T : int, the prefix
    n : int, paths per sequence
    seed : int; every sequence draws from its own generator seeded with it, so a sequence's paths
        do not depend on the others in its batch
    speed_edges, headings, slopes, accel_table, bin_, reach, place, accel_prob, walls : the motion's
        tables (:class:`MotionArrays`)

    Returns
    -------
    (B, n, T) int64; each path's point index at every step. The last pairs are drawn
    systematically (one uniform for all ``n``), so a pair of posterior mass ``m`` is drawn
    ``n m`` times rounded either way.
    """
    B, M, K = la.shape[0], la.shape[2], xy.shape[2]
    tables = (speed_edges, headings, slopes, accel_table, bin_, reach, place, accel_prob, walls)
    work = (xy, lp, pi, ci, la, place, tables, np.empty(M, np.int64), np.empty(M), np.empty(M))
    out = np.zeros((B, n, T), np.int64)
    start, base = np.zeros((1, K + 1), np.int64), np.empty((1, M))
    row, val = np.empty((1, M + 1), np.int64), np.empty((1, M * K))
    scratch = _draw_scratch(n, M, K)
    for b in range(B):
        _draw_paths(b, T, n, seed, work, start, base, row, val, False, out[b], scratch)
    return out
