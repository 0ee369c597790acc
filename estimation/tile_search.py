"""Exact top-k grid matching by branch and bound over tiles of the grid.

Scoring a fingerprint against every grid point (:meth:`FingerprintMatcher.scores
<estimation.matching.FingerprintMatcher.scores>`) reads the weight rows of all its ones over the
whole grid: about 26 MB per fingerprint on the default data set, bound by memory bandwidth. Its
``k`` best points are a few hundred of the grid's 79,000, clustered where the fingerprint fits.

:class:`TileIndex` groups the grid's points into square tiles of at most :data:`TILE_POINTS`
points and keeps, per tile, the largest weight of each fingerprint entry over its points. A
fingerprint's score summed with those maxima bounds every point of the tile from above. The tiles
with the highest bounds are scored point by point first; that fixes a ``k``-th best score, and only
the tiles whose bound reaches it are scored after. The result is the exact top ``k`` (scores equal
to the dense product's up to float32 summation order) for about a twentieth of the memory traffic.

What is left is reading the weights of the tiles scored: one cache line per tile and fingerprint
entry, scattered over 515 MB, at about the memory's latency each (some 90 ns on our machines).
Fingerprints of users near one another, and a user's steps above all, score the same tiles, so
a batch of them (each thread's share of :data:`_BATCH`) is searched stage by stage, each stage's
(tile, fingerprint) pairs scored tile by tile: a tile's lines are read from memory once and then
from cache, about twice as fast overall. A fingerprint's second stage scores every tile whose
bound reaches the ``k``-th best score of its seed tiles (a few percent more tiles than raising
that score tile by tile would); the result is the same.

The same bound serves the guided selection of :meth:`FingerprintMatcher.track_candidates
<estimation.matching.FingerprintMatcher.track_candidates>`: a point's key is its score plus a bonus
``log(1 + A exp(-d^2 / 2 s^2))`` falling with its distance ``d`` to a predicted position, which the
bonus at the tile's nearest point bounds.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from mmwsim._jit import njit
from mmwsim._threads import pieces, thread_map

__all__ = ["TILE", "TILE_POINTS", "TileIndex"]

TILE = 4  # tile side in grid steps: 4 x 4 points (1,578 points scored per fingerprint on the
# default data set against 596 for 2 x 2 tiles, whose 20,601 bounds cost more than they save)
TILE_POINTS = 16  # points per tile at most (a tile of an irregular grid is cut into such pieces)
# Relative margin on a tile's bound: the bound and the points' scores add the same terms in the
# same order, so rounding keeps the bound above them; the guided bonus goes through exp and log1p.
_SLACK = 1e-5
# Fingerprints searched together (their bounds on every tile held at once: 45 MB on the default
# data set).
_BATCH = 2048


def _grid_spacing(xy: np.ndarray) -> float:
    """The grid's typical spacing: the median distance from a point to its nearest other point
    (1 if there is none)."""
    from scipy.spatial import cKDTree

    if len(xy) < 2:
        return 1.0
    d = cKDTree(xy).query(xy, k=2)[0][:, 1]
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 1.0


class TileIndex:
    """The grid's points in tiles, with the matcher's weights laid out tile by tile.

    Parameters
    ----------
    grid_xy : (G, 2) float, metres
    weights : callable
        ``weights(rows) -> (w (n, C) float32, c (n,) float32)``: the matcher's per-entry weights
        ``logit p`` and constant ``sum log(1 - p)`` of grid points ``rows (n,)`` int64.
    n_columns : int
        ``C``, the fingerprint entries the weights cover.
    tile : int
        Tile side in grid steps.

    Notes
    -----
    The weights are stored as ``(n_tiles, C, TILE_POINTS)`` float32, padded with ``-inf``: one
    fingerprint entry of one tile is one 64-byte cache line. On the default data set (79,097
    points, 1,472 entries) that is 515 MB, beside 32 MB of tile bounds.
    """

    def __init__(
        self,
        grid_xy: np.ndarray,
        weights: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
        n_columns: int,
        tile: int = TILE,
    ):
        xy = np.asarray(grid_xy, np.float64)
        cell = np.floor(xy / (tile * _grid_spacing(xy))).astype(np.int64)
        order = np.lexsort((np.arange(len(xy)), cell[:, 1], cell[:, 0]))
        key = cell[order]
        start = np.r_[True, (np.diff(key, axis=0) != 0).any(1)] if len(key) else np.zeros(0, bool)
        # a tile of more than TILE_POINTS points (an irregular grid) is cut into pieces
        rank = np.arange(len(order)) - np.maximum.accumulate(np.where(start, np.arange(len(order)), 0))
        start |= rank % TILE_POINTS == 0
        tile_of = np.cumsum(start) - 1
        n_tiles = int(tile_of[-1]) + 1 if len(tile_of) else 0
        slot = np.arange(len(order)) - np.flatnonzero(start)[tile_of]
        self.n_tiles = n_tiles
        self.rows = np.full((n_tiles, TILE_POINTS), -1, np.int64)  # grid row of every slot
        self.rows[tile_of, slot] = order
        self.n_points = len(order)
        self.count = np.bincount(tile_of, minlength=n_tiles).astype(np.int64)
        self.xy = np.zeros((n_tiles, TILE_POINTS, 2))
        self.xy[tile_of, slot] = xy[order]
        self.lo = np.full((n_tiles, 2), np.inf)
        self.hi = np.full((n_tiles, 2), -np.inf)
        np.minimum.at(self.lo, tile_of, xy[order])
        np.maximum.at(self.hi, tile_of, xy[order])
        self.w = np.full((n_tiles, n_columns, TILE_POINTS), -np.inf, np.float32)
        self.c = np.full((n_tiles, TILE_POINTS), -np.inf, np.float32)
        for a in range(0, n_tiles, 256):  # bounded temporaries (about 24 MB each on the default data set)
            sl = slice(a, min(a + 256, n_tiles))
            ok = self.rows[sl] >= 0
            w, c = weights(self.rows[sl][ok])
            block = np.full((*ok.shape, n_columns), -np.inf, np.float32)
            block[ok] = w
            self.w[sl] = block.transpose(0, 2, 1)
            self.c[sl][ok] = c
        self.w_max = np.ascontiguousarray(self.w.max(-1).T)  # (C, n_tiles)
        self.c_max = self.c.max(-1)
        self.scored = 0  # tile slots scored point by point by the last topk

    def topk(
        self,
        indptr: np.ndarray,
        ones: np.ndarray,
        k: int,
        guide: tuple[np.ndarray, np.ndarray, float] | None = None,
        seed: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` best grid points of ``N`` fingerprints given as the entries of their ones.

        Parameters
        ----------
        indptr : (N + 1,) int64
            Fingerprint ``n``'s ones are ``ones[indptr[n]:indptr[n + 1]]``.
        ones : (nnz,) int64
            Column indices (into the weights' ``C`` entries), ascending per fingerprint.
        k : int
            At most the number of grid points.
        guide : (pred (N, 2) metres, spread (N,) metres, A), optional
            Rank by score plus ``log(1 + A exp(-d^2 / 2 s^2))`` for the distance ``d`` to
            ``pred`` instead of by score.
        seed : int, optional
            Tiles of highest bound scored before any is pruned (default about three times the
            tiles ``k`` points fill, at least 8); the result does not depend on it.

        Returns
        -------
        score : (N, k) float32 log-likelihoods (without the bonus)
        row : (N, k) int64 grid rows, best first (ties: lower row first)

        The tile slots scored point by point (``TILE_POINTS`` per tile) are left in
        :attr:`scored`.
        """
        N = len(indptr) - 1
        score = np.empty((N, k), np.float32)
        row = np.empty((N, k), np.int64)
        self.scored = 0
        if k < 1 or N == 0:
            return score, row
        if k > self.n_points:
            raise ValueError(f"{k} best of a grid of {self.n_points} points")
        if guide is None:
            pred, inv2s2, bonus = np.zeros((N, 2)), np.zeros(N), 0.0
        else:
            pred = np.asarray(guide[0], np.float64)
            inv2s2 = 0.5 / np.square(np.asarray(guide[1], np.float64))
            bonus = float(guide[2])
        seed = min(self.n_tiles - 1, max(8, 3 * k // TILE_POINTS) if seed is None else max(int(seed), 0))

        def run(s: slice) -> int:
            return _topk_batch(
                indptr[s.start : s.stop + 1] - indptr[s.start], ones[indptr[s.start] : indptr[s.stop]],
                self.w, self.c, self.w_max, self.c_max, self.rows, self.xy, self.lo, self.hi, k, seed,
                pred[s], inv2s2[s], bonus, score[s], row[s],
            )  # fmt: skip

        # the threads' batches in turn, so that at most _BATCH fingerprints' bounds are held
        parts = [
            slice(a + p.start, a + p.stop)
            for a in range(0, N, _BATCH)
            for p in pieces(min(_BATCH, N - a), 16)
        ]
        self.scored = int(sum(thread_map(run, parts)))
        return score, row


@njit(cache=True, inline="always")
def _worse(ka, ra, kb, rb):
    return ka < kb or (ka == kb and ra > rb)


@njit(cache=True, inline="always")
def _swap(hk, hs, hr, i, j):
    hk[i], hk[j] = hk[j], hk[i]
    hs[i], hs[j] = hs[j], hs[i]
    hr[i], hr[j] = hr[j], hr[i]


@njit(cache=True, inline="always")
def _sift_down(hk, hs, hr, i, n):
    # min-heap on (key, -row): the root is the worst point kept
    while True:
        m = 2 * i + 1
        if m >= n:
            return
        if m + 1 < n and _worse(hk[m + 1], hr[m + 1], hk[m], hr[m]):
            m += 1
        if not _worse(hk[m], hr[m], hk[i], hr[i]):
            return
        _swap(hk, hs, hr, i, m)
        i = m


@njit(cache=True, inline="always")
def _sift_up(hk, hs, hr, i):
    while i > 0:
        p = (i - 1) // 2
        if not _worse(hk[i], hr[i], hk[p], hr[p]):
            return
        _swap(hk, hs, hr, i, p)
        i = p


@njit(cache=True, nogil=True)
def _topk_batch(
    indptr, ones, w, c, w_max, c_max, rows, xy, lo, hi, k, seed, pred, inv2s2, bonus, out_score, out_row
):
    """TileIndex.topk of a batch of fingerprints: the seed tiles, then every other tile that can
    still enter, each stage's (tile, fingerprint) pairs scored tile by tile. Returns the tile
    slots scored."""
    N, n_tiles, P = len(indptr) - 1, len(c_max), c.shape[1]
    ub = np.empty((N, n_tiles), np.float32)
    _tile_bounds(indptr, ones, w_max, c_max, lo, hi, pred, inv2s2, bonus, seed, ub)
    hk = np.empty((N, k), np.float32)  # each fingerprint's k best so far: keys, scores, rows
    hs = np.empty((N, k), np.float32)
    hr = np.empty((N, k), np.int64)
    size = np.zeros(N, np.int64)
    tau = np.empty(N, np.float32)
    scored = 0
    for stage in range(2):
        for n in range(N):
            tau[n] = hk[n, 0] if size[n] == k else -np.inf
        start, tile, fp = _select_tiles(ub, tau, stage == 0)
        scores = np.empty((start[N], P), np.float32)
        _score_pairs(np.argsort(tile, kind="mergesort"), tile, fp, indptr, ones, w, c, scores)
        _push(start, tile, scores, rows, xy, pred, inv2s2, bonus, hk, hs, hr, size)
        scored += start[N] * P
    _heap_sort(hk, hs, hr, size, out_score, out_row)
    return scored


@njit(cache=True, nogil=True)
def _tile_bounds(indptr, ones, w_max, c_max, lo, hi, pred, inv2s2, bonus, seed, ub):
    # ub (N, n_tiles): each fingerprint's bound on every tile, +inf on its seed tiles
    n_tiles = len(c_max)
    for n in range(len(indptr) - 1):
        u = ub[n]
        u[:] = c_max
        for q in range(indptr[n], indptr[n + 1]):
            wq = w_max[ones[q]]
            for b in range(n_tiles):
                u[b] += wq[b]
        if bonus > 0:
            px, py, f = pred[n, 0], pred[n, 1], inv2s2[n]
            for b in range(n_tiles):
                dx = max(lo[b, 0] - px, 0.0, px - hi[b, 0])
                dy = max(lo[b, 1] - py, 0.0, py - hi[b, 1])
                u[b] += math.log1p(bonus * math.exp(-(dx * dx + dy * dy) * f))
        cut = -np.inf
        if seed < n_tiles:
            cut = -np.partition(-u, seed)[seed]
        for b in range(n_tiles):
            if u[b] > cut:
                u[b] = np.inf


@njit(cache=True, inline="always")
def _takes(u, tau, seeds):
    # a seed tile (its bound set to +inf), or another whose bound reaches the k-th best key tau
    if seeds:
        return u == np.inf
    return u != np.inf and not u + _SLACK * (1.0 + abs(u)) < tau


@njit(cache=True, nogil=True)
def _select_tiles(ub, tau, seeds):
    # The (tile, fingerprint) pairs to score, fingerprint by fingerprint: fingerprint n's are
    # tile[start[n]:start[n + 1]].
    N, n_tiles = ub.shape
    start = np.zeros(N + 1, np.int64)
    for n in range(N):
        j = 0
        for b in range(n_tiles):
            j += _takes(ub[n, b], tau[n], seeds)
        start[n + 1] = start[n] + j
    tile, fp = np.empty(start[N], np.int64), np.empty(start[N], np.int64)
    for n in range(N):
        j = start[n]
        for b in range(n_tiles):
            if _takes(ub[n, b], tau[n], seeds):
                tile[j], fp[j] = b, n
                j += 1
    return start, tile, fp


@njit(cache=True, nogil=True)
def _score_pairs(order, tile, fp, indptr, ones, w, c, out):
    P = c.shape[1]
    acc = np.empty(P, np.float32)
    for j in order:
        b, n = tile[j], fp[j]
        acc[:] = c[b]
        wb = w[b]
        for q in range(indptr[n], indptr[n + 1]):
            wq = wb[ones[q]]
            for i in range(P):
                acc[i] += wq[i]
        out[j] = acc


@njit(cache=True, nogil=True)
def _push(start, tile, scores, rows, xy, pred, inv2s2, bonus, hk, hs, hr, size):
    # fingerprint n's scored pairs start[n]..start[n + 1] into its heap (n of this slice)
    k = hk.shape[1]
    for n in range(len(start) - 1):
        px, py, f = pred[n, 0], pred[n, 1], inv2s2[n]
        K, S, R = hk[n], hs[n], hr[n]
        m = size[n]
        for j in range(start[n], start[n + 1]):
            b = tile[j]
            for i in range(rows.shape[1]):
                g = rows[b, i]
                if g < 0:
                    break
                sc = scores[j, i]
                key = sc
                if bonus > 0:
                    dx, dy = xy[b, i, 0] - px, xy[b, i, 1] - py
                    key = sc + math.log1p(bonus * math.exp(-(dx * dx + dy * dy) * f))
                if m < k:
                    K[m], S[m], R[m] = key, sc, g
                    _sift_up(K, S, R, m)
                    m += 1
                elif _worse(K[0], R[0], key, g):
                    K[0], S[0], R[0] = key, sc, g
                    _sift_down(K, S, R, 0, k)
        size[n] = m


@njit(cache=True, nogil=True)
def _heap_sort(hk, hs, hr, size, out_score, out_row):
    for n in range(hk.shape[0]):  # the worst to the end
        K, S, R = hk[n], hs[n], hr[n]
        for j in range(size[n] - 1, -1, -1):
            out_score[n, j], out_row[n, j] = S[0], R[0]
            _swap(K, S, R, 0, j)
            _sift_down(K, S, R, 0, j)
