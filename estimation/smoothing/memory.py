"""Acceleration memory: how a step's change of displacement depends on the change before it.

The sub-cell smoother scores every step's acceleration alone (:class:`~estimation.smoothing.motion.MotionTable`),
a Markov chain of one order over pairs of lattice points. A user snapped to the lattice crosses
lattice points in a pattern set by its exact speed and heading: a pedestrian at 1.8 m/s (5.4
lattice steps of 1/3 m per step) goes 5, 6, 5, 5, 6, ... steps, so one acceleration of +1 is
followed by -1 or 0, never by another +1, which a table of single accelerations cannot tell from a
user who speeds up. :class:`MotionMemory` measures, on the training trajectories, the log ratio

    log p(a_t | a_t-1, band) - log p(a_t | band)

for small accelerations (lattice steps within +-:data:`MEMORY_REACH` per axis) in the quarter
turn of the displacement between them, per speed band, and one order further,

    log p(a_t | a_t-1, a_t-2, band) - log p(a_t | a_t-1, band)

(a walker at 1.75 m/s goes 5, 5, 5, 6, ... lattice steps, accelerations 0, 0, +1, -1: after 0
comes 0 or +1, but after -1, 0 only 0, and after 0, 0 only +1).
:class:`~estimation.smoothing.online.CandidateFilter` weighs paths drawn from the smoothed pair posterior (:func:`~estimation.smoothing.beam.sample_paths`)
by the sum of these ratios along them: importance sampling of the smoother one order higher.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from mmwsim._jit import njit

from ._positions import checked_positions
from .beam import _frame
from .motion import SUBCELLS

__all__ = [
    "MEMORY_BACKOFF",
    "MEMORY_EDGES",
    "MEMORY_PATHS",
    "MEMORY_REACH",
    "MEMORY_WEIGHT",
    "MotionMemory",
    "memory_shift",
]

MEMORY_REACH = 2  # lattice steps per axis of the accelerations told apart; larger ones share a code
# Inner speed-band edges, lattice steps per step (1/3 m on a 1 m grid): standing, walking,
# cycling, slow, steady and fast driving.
MEMORY_EDGES = (1.5, 4.5, 9.0, 15.0, 21.0, 30.0)
# Paths drawn per user, prefix and motion model. 128, 512 and 2048 took 300 seen-area users per
# kind of the default data set to 0.372, 0.371 and 0.371 m (0.378 without memory; 512 cost 10 %
# more prediction time, docs/estimation.md).
MEMORY_PATHS = 512
# Weight of the density given the acceleration before in the one given the two before
# (MotionMemory.fit): 2, 5 and 20 tracked 300 seen-area users per kind of the default data set
# within 0.0001 m of each other (docs/estimation.md).
MEMORY_BACKOFF = 5.0
# A motion model's posterior weight below which the filter does not weigh its paths for a user:
# its share of the user's track is too small for the memory's move (centimetres) to show.
MEMORY_WEIGHT = 1e-3


@njit(cache=True, inline="always")
def _code(ax, ay, reach):
    """An acceleration's code: ``(ax + reach) (2 reach + 1) + ay + reach`` within ``+-reach``
    lattice steps per axis, else the one code of the large ones, ``(2 reach + 1)^2``."""
    w = 2 * reach + 1
    if abs(ax) > reach or abs(ay) > reach:
        return w * w
    return (ax + reach) * w + ay + reach


@njit(cache=True, inline="always")
def _window(px, py, t, n_sub, edges, reach, no_slopes):
    """Speed band and acceleration codes at points ``t .. t+3`` of a lattice path ``px, py (L,)``
    (grid units), turned by the quarter turn that brings the middle displacement (``t+1`` to
    ``t+2``) into ``x > 0, y >= 0``: :func:`~estimation.smoothing.beam._frame`'s lattice frame with
    one heading bin (``no_slopes``: an empty array), whose class is then the speed band.

    Returns ``band, before, c0, c1``: the codes of the accelerations into and out of the middle
    displacement (``c0``, ``c1``) and of the one before those (``before``, -1 for ``t = 0``).
    """
    # the displacements in lattice steps: before (into t+1), middle (d) and next (out of t+2)
    bx, by = round((px[t + 1] - px[t]) * n_sub), round((py[t + 1] - py[t]) * n_sub)
    dx, dy = round((px[t + 2] - px[t + 1]) * n_sub), round((py[t + 2] - py[t + 1]) * n_sub)
    nx, ny = round((px[t + 3] - px[t + 2]) * n_sub), round((py[t + 3] - py[t + 2]) * n_sub)
    a0x, a0y, a1x, a1y = dx - bx, dy - by, nx - dx, ny - dy
    f00, f01, f10, f11, band = _frame(float(dx), float(dy), edges, 1, no_slopes)
    c0 = _code(round(f00 * a0x + f01 * a0y), round(f10 * a0x + f11 * a0y), reach)
    c1 = _code(round(f00 * a1x + f01 * a1y), round(f10 * a1x + f11 * a1y), reach)
    before = -1
    if t >= 1:
        ax = bx - round((px[t] - px[t - 1]) * n_sub)
        ay = by - round((py[t] - py[t - 1]) * n_sub)
        before = _code(round(f00 * ax + f01 * ay), round(f10 * ax + f11 * ay), reach)
    return band, before, c0, c1


@njit(cache=True)
def _codes(u, n_sub, edges, reach):
    """Flat indices of every window of four consecutive points of lattice paths ``u (n, L, 2)``
    grid units: ``(n, L - 3)`` into the ratio table ``(band, code before, code after)`` and
    ``(n, L - 3)`` into the table of two before ``(band, code two back, code before, code after)``,
    -1 for the first window (no acceleration before it)."""
    n, L = u.shape[0], u.shape[1]
    w = 2 * reach + 1
    n_code = w * w + 1
    one = np.empty((n, max(L - 3, 0)), np.int64)
    two = np.full((n, max(L - 3, 0)), -1, np.int64)
    no_slopes = np.empty(0)
    for i in range(n):
        px, py = u[i, :, 0].copy(), u[i, :, 1].copy()
        for t in range(L - 3):
            band, before, c0, c1 = _window(px, py, t, n_sub, edges, reach, no_slopes)
            one[i, t] = (band * n_code + c0) * n_code + c1
            if before >= 0:
                two[i, t] = ((band * n_code + before) * n_code + c0) * n_code + c1
    return one, two


@njit(cache=True, nogil=True)
def memory_shift(xy, idx, log_ratio, log_ratio_two, n_sub, edges, reach):
    """The mean of paths weighed by the memory less their plain mean: ``(B, T, 2)`` grid units.

    Parameters
    ----------
    xy : (B, T', K, 2) float64; the steps' lattice points, grid units
    idx : (B, n, T) int64; the paths' point indices (:func:`~estimation.smoothing.beam.sample_paths`)
    log_ratio, log_ratio_two : float32 or float64; :attr:`MotionMemory.log_ratio` ``(n_band, n_code, n_code)``
        and :attr:`MotionMemory.log_ratio_two` ``(n_band, n_code, n_code, n_code)``
    n_sub, edges, reach : the lattice and the memory's bands and reach
    """
    B, n, T = idx.shape
    out = np.zeros((B, T, 2))
    lw = np.empty(n)
    px, py = np.empty(T), np.empty(T)
    no_slopes = np.empty(0)
    for b in range(B):
        top = -np.inf
        for j in range(n):
            for t in range(T):
                p = idx[b, j, t]
                px[t], py[t] = xy[b, t, p, 0], xy[b, t, p, 1]
            acc = 0.0
            for t in range(T - 3):
                band, before, c0, c1 = _window(px, py, t, n_sub, edges, reach, no_slopes)
                acc += log_ratio[band, c0, c1]
                if before >= 0:
                    acc += log_ratio_two[band, before, c0, c1]
            lw[j] = acc
            top = max(top, acc)
        tot = 0.0
        for j in range(n):
            lw[j] = math.exp(lw[j] - top)
            tot += lw[j]
        for j in range(n):
            w = lw[j] / tot - 1.0 / n
            for t in range(T):
                p = idx[b, j, t]
                out[b, t, 0] += w * xy[b, t, p, 0]
                out[b, t, 1] += w * xy[b, t, p, 1]
    return out


class MotionMemory(nn.Module):
    """The measured log ratios of an acceleration's density given the one before it to its density
    alone, and given the two before it to its density given the one, on the sub-cell lattice (see
    the module docstring). Buffers, so they travel with the network's ``state_dict``; zero (no
    memory) until :meth:`fit`.

    Parameters
    ----------
    reach : int
        Accelerations within ``+-reach`` lattice steps per axis are told apart.
    edges : sequence of float
        Inner speed-band edges, lattice steps per step.
    n_sub : int
        Lattice points per grid spacing and axis.
    """

    def __init__(
        self, reach: int = MEMORY_REACH, edges: tuple[float, ...] = MEMORY_EDGES, n_sub: int = SUBCELLS
    ):
        super().__init__()
        self.reach, self.n_sub = int(reach), int(n_sub)
        n_code = (2 * self.reach + 1) ** 2 + 1
        self.register_buffer("edges", torch.tensor(edges, dtype=torch.float64))
        self.register_buffer("log_ratio", torch.zeros(len(edges) + 1, n_code, n_code))
        self.register_buffer("log_ratio_two", torch.zeros(len(edges) + 1, n_code, n_code, n_code))
        self.register_buffer("fitted", torch.tensor(False))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        if prefix + "fitted" not in state_dict:
            # a model saved before it had a memory keeps none
            for name, buf in self._buffers.items():
                state_dict[prefix + name] = buf
        # the saved table's reach and bands are its own
        ratio, edges = state_dict.get(prefix + "log_ratio"), state_dict.get(prefix + "edges")
        if ratio is not None and edges is not None and ratio.ndim == 3:
            self.log_ratio, self.edges = torch.empty_like(ratio), torch.empty_like(edges)
            self.reach = (math.isqrt(ratio.shape[1] - 1) - 1) // 2
            # a memory saved before it looked two accelerations back looks one back only
            two = state_dict.setdefault(
                prefix + "log_ratio_two", ratio.new_zeros((*ratio.shape, ratio.shape[-1]))
            )
            self.log_ratio_two = torch.empty_like(two)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def flat_codes(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices of every four consecutive points of lattice paths ``u (..., L, 2)`` grid
        units: ``(..., L - 3)`` into :attr:`log_ratio` and ``(..., L - 3)`` into
        :attr:`log_ratio_two` (-1 for the first four points, which have no acceleration before)."""
        u = np.asarray(u, dtype=np.float64)
        flat = np.ascontiguousarray(u.reshape(-1, *u.shape[-2:]))
        one, two = _codes(flat, self.n_sub, self.edges.numpy(), self.reach)
        shape = (*u.shape[:-2], max(u.shape[-2] - 3, 0))
        return one.reshape(shape), two.reshape(shape)

    def fit(self, u: np.ndarray, prior: float = 0.5, backoff: float = MEMORY_BACKOFF) -> MotionMemory:
        """Measure the ratios on trajectories ``u (n, L >= 4, 2)`` grid units snapped to the
        lattice (as the sub-cell table is): counts plus ``prior`` per cell given the acceleration
        before, and given the two before the counts plus ``backoff`` times the density given
        the one (so an acceleration seen rarely after a pair keeps its density given the last
        one). Returns ``self``."""
        u = checked_positions(u, 4, nonempty=True, what="lattice positions")
        if not backoff > 0:
            raise ValueError(f"backoff must be > 0, got {backoff}")
        n_band, n_code = self.log_ratio.shape[:2]
        one, two = self.flat_codes(u)
        h = np.bincount(one.ravel(), minlength=n_band * n_code * n_code)
        h = h.reshape(n_band, n_code, n_code).astype(np.float64) + prior
        given = h / h.sum(2, keepdims=True)
        alone = h.sum(1) / h.sum((1, 2))[:, None]
        ratio = np.log(given) - np.log(alone)[:, None, :]
        h2 = np.bincount(two[two >= 0], minlength=n_band * n_code**3).reshape(n_band, n_code, n_code, n_code)
        given_two = (h2 + backoff * given[:, None]) / (h2.sum(3, keepdims=True) + backoff)
        ratio_two = np.log(given_two) - np.log(given)[:, None]
        # the large accelerations (turns, stops) keep their single-step density
        ratio[:, -1, :] = ratio[:, :, -1] = 0.0
        ratio_two[:, -1] = ratio_two[:, :, -1] = ratio_two[:, :, :, -1] = 0.0
        self.log_ratio.copy_(torch.from_numpy(ratio).float())
        self.log_ratio_two.copy_(torch.from_numpy(ratio_two).float())
        self.fitted.fill_(True)
        return self

    def log_weight(self, u: np.ndarray) -> np.ndarray:
        """Sum of the log ratios along lattice paths ``u (..., L, 2)`` grid units: ``(...)``
        (zeros for ``L < 4``)."""
        one, two = self.flat_codes(u)
        w = self.log_ratio.double().numpy().ravel()[one].sum(-1)
        return w + np.where(
            two >= 0, self.log_ratio_two.double().numpy().ravel()[np.maximum(two, 0)], 0.0
        ).sum(-1)
