"""Compiled kernels of the online candidate filter: one step forward, one step back.

The constant-velocity smoother of :func:`~estimation.smoothing.hmm.velocity_posterior` keeps a
message over every pair of candidates ``(x_t-1, x_t)`` and sums over every triple, ``O(K^3)`` per
step. Almost all of that mass sits on a few pairs, so these kernels keep the ``M`` most likely
pairs of each step (a beam) and work in ``O(M K)`` per step: a forward step needs only the last
step's pairs, so a user's estimate is updated in constant time per fingerprint, and the stored
pairs give the smoothed marginals of any prefix by one backward pass. With ``M >= K^2`` nothing is
pruned and the result is the dense smoother's.

Motion models reach the kernels as the arrays of :func:`motion_arrays` (a
:class:`~estimation.smoothing.motion.MotionTable`'s tables); all kernels loop over sequences in
compiled code, in float64, and are deterministic (ties are broken by a stable sort).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from mmwsim._jit import njit

from .motion import MixtureMotion, MotionTable

__all__ = ["MotionArrays", "motion_arrays", "pair_backward", "pair_forward", "pair_start", "rw_step"]

_NEG = -1e300  # log of a pair that was pruned (or an impossible one)
# A term this far (log) below the largest of its sum changes it by less than float64 resolves
# (e^-40 = 4e-18), so its exponential is not computed.
_NEGLIGIBLE = -40.0


class MotionArrays(NamedTuple):
    """A motion table as plain arrays for the kernels (see :class:`MotionTable`)."""

    step_table: np.ndarray  # (n_step,) log density of a displacement length bin
    speed_edges: np.ndarray  # (n_band - 1,) inner speed-band edges, units per step
    accel_table: np.ndarray  # (n_band, n_acc, n_acc) log density of (along, across) acceleration
    bin: float
    reach: float
    place: tuple  # (place_speed, log_place (H, W) float32, origin (2,), res); see MotionTable
    accel_prob: np.ndarray  # exp(accel_table): the kernels' sums multiply instead of exponentiate


def motion_arrays(motion: MotionTable | MixtureMotion) -> MotionArrays:
    """The kernels' view of ``motion``; a hand-set :class:`MixtureMotion` is tabulated on a
    :class:`MotionTable`'s bins first (its densities at the bin centres)."""
    if isinstance(motion, MixtureMotion):
        motion = _tabulate(motion)
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
        np.exp(accel),
    )


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
def _frame(vx, vy, speed_edges):
    """Unit vector of the displacement ``v`` (x where ``v = 0``) and its speed band."""
    n = math.sqrt(vx * vx + vy * vy)
    ux, uy = (vx / n, vy / n) if n > 0 else (1.0, 0.0)
    band = 0
    for e in speed_edges:
        if e < n:
            band += 1
    return ux, uy, band


@njit(cache=True, inline="always")
def _accel_bin(ux, uy, ax, ay, n, bin_, reach):
    # MotionTable.log_accel: the acceleration in the frame of the motion, in a speed band's
    # n x n table.
    i = min(max(int((ax * ux + ay * uy + reach) / bin_), 0), n - 1)
    j = min(max(int((ay * ux - ax * uy + reach) / bin_), 0), n - 1)
    return i, j


@njit(cache=True, inline="always")
def _log_place(x, y, vx, vy, place):
    # MotionTable.log_place_ratio: the place table at the cell holding x if v is fast, else 0.
    speed, table, origin, res = place
    if vx * vx + vy * vy <= speed * speed:
        return 0.0
    i = min(max(int(math.floor((x - origin[0]) / res)), 0), table.shape[0] - 1)
    j = min(max(int(math.floor((y - origin[1]) / res)), 0), table.shape[1] - 1)
    return table[i, j]


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
def _keep_best(dense, M, pi, ci, la):
    """The ``M`` largest finite entries of ``dense (Kp, K)`` into ``pi, ci, la``, largest first
    and ties in index order (padded with ``_NEG``); returns how many."""
    K = dense.shape[1]
    flat = dense.ravel()
    N = len(flat)
    if N > M:
        # Only the entries from the M-th largest value up are sorted.
        cut = np.partition(flat, N - M)[N - M]
        idx = np.flatnonzero(flat >= cut)
    else:
        idx = np.arange(N)
    order = idx[np.argsort(-flat[idx], kind="mergesort")]
    n = 0
    for q in order[:M]:
        if flat[q] <= _NEG:
            break
        pi[n], ci[n], la[n] = q // K, q % K, flat[q]
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
    pi, ci : (B, M) int64; indices of the pairs' candidates at steps 0 and 1
    la : (B, M) float64; forward log messages (``_NEG`` past the kept pairs)
    marg : (B, K1) float64; filtered log marginal of step 1
    """
    B, K0, K1 = x0.shape[0], x0.shape[1], x1.shape[1]
    pi = np.empty((B, M), np.int64)
    ci = np.empty((B, M), np.int64)
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
def pair_forward(xpp, xp, xc, pi, ci, la, lp, M, speed_edges, accel_table, bin_, reach, place, accel_prob):
    """One forward step of the beam: pairs ``(x_t-2, x_t-1)`` to pairs ``(x_t-1, x_t)``.

    Parameters
    ----------
    xpp, xp, xc : (B, K, 2) float64; candidates of steps t-2, t-1 and t
    pi, ci, la : (B, M') the kept pairs of step t-1 (see :func:`pair_start`)
    lp : (B, K) float64; log likelihoods of step t
    M : int, beam width
    speed_edges, accel_table, bin_, reach, place, accel_prob : the motion's acceleration and
        place tables (:class:`MotionArrays`)

    Returns
    -------
    pi, ci, la, marg : as :func:`pair_start`, for step t
    """
    B, Kp, K, Mp = xp.shape[0], xp.shape[1], xc.shape[1], pi.shape[1]
    n_acc = accel_table.shape[1]
    npi = np.empty((B, M), np.int64)
    nci = np.empty((B, M), np.int64)
    nla = np.empty((B, M))
    marg = np.empty((B, K))
    sc = np.empty((Mp, K))
    cell = np.empty((Mp, K), np.int64)  # the acceleration's entry in the flattened table
    prob = accel_prob.ravel()
    dense = np.empty((Kp, K))
    # The beam is sorted by message, largest first: once a pair's message plus the likeliest
    # acceleration lies _NEGLIGIBLE below the best term so far, its terms and those of every
    # pair after it would be skipped below; they are not computed.
    a_max = accel_table.max()
    for b in range(B):
        top = -np.inf
        used = Mp
        for q in range(Mp):
            if la[b, q] <= _NEG or la[b, q] + a_max - top < _NEGLIGIBLE:
                used = q
                break
            a0, a1 = pi[b, q], ci[b, q]
            vx, vy = xp[b, a1, 0] - xpp[b, a0, 0], xp[b, a1, 1] - xpp[b, a0, 1]
            ux, uy, band = _frame(vx, vy, speed_edges)
            for j in range(K):
                ax = xc[b, j, 0] - xp[b, a1, 0] - vx
                ay = xc[b, j, 1] - xp[b, a1, 1] - vy
                u, w = _accel_bin(ux, uy, ax, ay, n_acc, bin_, reach)
                v = la[b, q] + accel_table[band, u, w]
                sc[q, j] = v
                cell[q, j] = (band * n_acc + u) * n_acc + w
                top = max(top, v)
        # sum_q exp(la_q + a_qj - top) as exp(la_q - top) exp(a_qj): one exponential per pair
        dense[:, :] = 0.0
        for q in range(used):
            a1 = ci[b, q]
            scale = math.exp(la[b, q] - top)
            for j in range(K):
                if sc[q, j] - top > _NEGLIGIBLE:
                    dense[a1, j] += scale * prob[cell[q, j]]
        for i in range(Kp):
            for j in range(K):
                d = dense[i, j]
                if d > 0:
                    vx, vy = xc[b, j, 0] - xp[b, i, 0], xc[b, j, 1] - xp[b, i, 1]
                    dense[i, j] = (
                        math.log(d) + top + lp[b, j] + _log_place(xc[b, j, 0], xc[b, j, 1], vx, vy, place)
                    )
                else:
                    dense[i, j] = _NEG
        _keep_best(dense, M, npi[b], nci[b], nla[b])
        _marginal(nla[b], nci[b], K, marg[b])
    return npi, nci, nla, marg


@njit(cache=True, nogil=True)
def group_pairs(pi, la, Kp):
    """The kept pairs of a step grouped by their candidate at the step before, so that a backward
    step visits from each pair of the step before only the pairs it continues into.

    Parameters
    ----------
    pi, la : (B, M) a step's kept pairs (see :func:`pair_start`)
    Kp : int, candidates of the step before

    Returns
    -------
    order : (B, M) int64; the kept pairs by their candidate at the step before (stable)
    start : (B, Kp + 1) int64; candidate ``i``'s pairs are ``order[start[i]:start[i + 1]]``
    """
    B, M = pi.shape
    order = np.zeros((B, M), np.int64)
    start = np.zeros((B, Kp + 1), np.int64)
    for b in range(B):
        n = 0
        while n < M and la[b, n] > _NEG:
            n += 1
        order[b, :n] = np.argsort(pi[b, :n], kind="mergesort")
        for q in range(n):
            start[b, pi[b, q] + 1] += 1
        for i in range(Kp):
            start[b, i + 1] += start[b, i]
    return order, start


# fmt: off
@njit(cache=True, nogil=True)
def pair_backward(
    xpp, xp, xc, ppi, pci, pla, order, start, ci, beta, lp,
    speed_edges, accel_table, bin_, reach, place, accel_prob,
):
    # fmt: on
    """One backward step: the backward messages of the kept pairs of step t-1 from those of step t.

    Parameters
    ----------
    xpp, xp, xc : (B, K, 2) float64; candidates of steps t-2, t-1 and t
    ppi, pci, pla : (B, Mp) kept pairs of step t-1 and their forward messages
    order, start : the kept pairs of step t grouped by their candidate at t-1 (:func:`group_pairs`)
    ci : (B, M) their candidates at step t
    beta : (B, M) float64; their backward log messages (0 at the last step)
    lp : (B, K) float64; log likelihoods of step t
    speed_edges, accel_table, bin_, reach, place, accel_prob : the motion's tables

    Returns
    -------
    (B, Mp) float64 backward log messages of step t-1 (``_NEG`` for padding)
    """
    B, M, Mp = ci.shape[0], ci.shape[1], ppi.shape[1]
    Kp = xp.shape[1]
    n_acc = accel_table.shape[1]
    # a term whose rest lies this far below its group's largest stays _NEGLIGIBLE below the sum
    # whatever the accelerations
    floor = _NEGLIGIBLE - (accel_table.max() - accel_table.min())
    out = np.full((B, Mp), _NEG)
    # per pair of step t, what does not depend on the pair of t-1 it continues: its place,
    # likelihood and backward message, and the largest of them over its candidate's group
    rest = np.empty(M)
    scale = np.empty(M)
    head = np.empty(Kp)
    for b in range(B):
        head[:] = -np.inf
        for i in range(Kp):
            for r in range(start[b, i], start[b, i + 1]):
                m = order[b, r]
                if beta[b, m] <= _NEG:
                    rest[m] = -np.inf
                    continue
                j = ci[b, m]
                wx, wy = xc[b, j, 0] - xp[b, i, 0], xc[b, j, 1] - xp[b, i, 1]
                rest[m] = _log_place(xc[b, j, 0], xc[b, j, 1], wx, wy, place) + lp[b, j] + beta[b, m]
                head[i] = max(head[i], rest[m])
            for r in range(start[b, i], start[b, i + 1]):
                m = order[b, r]
                scale[m] = math.exp(rest[m] - head[i]) if rest[m] - head[i] > floor else 0.0
        for q in range(Mp):
            if pla[b, q] <= _NEG:
                continue
            a0, a1 = ppi[b, q], pci[b, q]
            if head[a1] == -np.inf:
                continue
            vx, vy = xp[b, a1, 0] - xpp[b, a0, 0], xp[b, a1, 1] - xpp[b, a0, 1]
            ux, uy, band = _frame(vx, vy, speed_edges)
            acc = 0.0
            for r in range(start[b, a1], start[b, a1 + 1]):
                m = order[b, r]
                if scale[m] > 0.0:
                    j = ci[b, m]
                    wx, wy = xc[b, j, 0] - xp[b, a1, 0], xc[b, j, 1] - xp[b, a1, 1]
                    u, w = _accel_bin(ux, uy, wx - vx, wy - vy, n_acc, bin_, reach)
                    acc += accel_prob[band, u, w] * scale[m]
            if acc > 0.0:
                out[b, q] = math.log(acc) + head[a1]
    return out
