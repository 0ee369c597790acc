"""Where a candidate can deliver energy: ray legs binned into cells around the receivers.

Every candidate (a reflector sequence, or a diffraction sequence) is represented by
the legs of the rays that followed it. A receiver lies within about ``gap`` of one
of those legs if the candidate can reach it, where ``gap`` grows with the distance
travelled (rays spread apart). Legs are clipped to the receivers' box widened by
the gap, and every cell that the leg's capsule of radius ``gap`` overlaps (in plan)
is marked for the leg's candidate. The result is a sparse (cell -> candidates) table
from which (candidate, receiver) pairs are drawn for the exact solve.

The marking runs in a compiled kernel: legs are counting-sorted by candidate, each
leg's capsule is rasterised column by column, and a stamp per cell (the last
candidate that marked it) removes duplicates without hashing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import njit
from .._threads import thread_map, threads

__all__ = ["CellLattice", "CandidateCells", "LegSet", "mark_cells"]


@dataclass(frozen=True)
class CellLattice:
    """A horizontal lattice of square cells over a slab of heights.

    Attributes
    ----------
    origin : (2,) float
        x, y of the corner of cell (0, 0), metres; a multiple of ``size``, so lattices
        of different extents bin the same point alike.
    size : float
        Cell side, metres.
    shape : (2,) int
        Cells along x and y.
    z_range : (2,) float
        Heights of the receivers, metres.
    """

    origin: tuple[float, float]
    size: float
    shape: tuple[int, int]
    z_range: tuple[float, float]

    @classmethod
    def covering(
        cls, lo: np.ndarray, hi: np.ndarray, size: float, z_range: tuple[float, float]
    ) -> CellLattice:
        """The lattice of ``size`` cells aligned to multiples of ``size`` that covers ``lo..hi`` (x, y)."""
        o = np.floor(np.asarray(lo, float)[:2] / size) * size
        shape = np.floor((np.asarray(hi, float)[:2] - o) / size).astype(np.int64) + 1
        return cls((float(o[0]), float(o[1])), float(size), (int(shape[0]), int(shape[1])), z_range)

    @property
    def n_cells(self) -> int:
        return int(self.shape[0] * self.shape[1])

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """(n,) int64 linear cell index of points (n, 2+); -1 outside the lattice."""
        ij = np.floor((np.asarray(xy)[:, :2] - np.asarray(self.origin)) / self.size).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.shape[0]) & (ij[:, 1] < self.shape[1])
        return np.where(inside, ij[:, 0] + self.shape[0] * ij[:, 1], -1)


@dataclass
class LegSet:
    """Ray legs of many candidates, with the tolerance each one is marked with.

    Attributes
    ----------
    cand : (m,) int64
        Candidate of each leg.
    start, direction : (m, 3) float32
        Origin and unit direction, metres.
    length : (m,) float32
        Distance to the next hit, ``inf`` for a ray that leaves the scene, metres.
    gap0, slope : (m,) float32
        Cells within ``gap0 + slope * t`` of the point at parameter ``t`` are marked, metres.
    """

    cand: np.ndarray
    start: np.ndarray
    direction: np.ndarray
    length: np.ndarray
    gap0: np.ndarray
    slope: np.ndarray

    def __len__(self) -> int:
        return int(len(self.cand))

    @staticmethod
    def concatenate(parts: list[LegSet]) -> LegSet:
        if not parts:
            return LegSet.empty()
        names = LegSet.__dataclass_fields__
        return LegSet(*(np.concatenate([getattr(p, f) for p in parts]) for f in names))

    @staticmethod
    def empty() -> LegSet:
        f = np.zeros(0, np.float32)
        v = np.zeros((0, 3), np.float32)
        return LegSet(np.zeros(0, np.int64), v, v, f, f, f)


@dataclass
class CandidateCells:
    """Sparse table of the cells each candidate may reach, grouped by cell.

    Attributes
    ----------
    lattice : CellLattice
    cell_start : (n_cells + 1,) int64
        Candidates of cell ``c`` are ``cand[cell_start[c]:cell_start[c + 1]]``, ascending.
    cand : (nnz,) int64
    """

    lattice: CellLattice
    cell_start: np.ndarray
    cand: np.ndarray

    @property
    def nnz(self) -> int:
        return int(len(self.cand))

    def pairs(self, rx: np.ndarray, batch: int = 1 << 20):
        """(candidate, receiver) index pairs for receivers ``rx`` (n, 3), in batches.

        Yields
        ------
        cand, rx_index : (b,) int64
            Sorted by candidate, then receiver, within each batch.
        """
        cell = self.lattice.cell_of(rx)
        ok = cell >= 0
        idx = np.flatnonzero(ok)
        counts = self.cell_start[cell[idx] + 1] - self.cell_start[cell[idx]]
        keep = counts > 0
        idx, counts = idx[keep], counts[keep]
        if not len(idx):
            return
        cum = np.cumsum(counts)
        start = 0
        while start < len(idx):
            done = cum[start - 1] if start else 0
            stop = max(int(np.searchsorted(cum, done + batch, side="right")), start + 1)
            c = counts[start:stop]
            rep = np.repeat(np.arange(stop - start), c)
            within = np.arange(len(rep)) - (np.cumsum(c) - c)[rep]
            r = idx[start:stop][rep]
            k = self.cand[self.cell_start[cell[r]] + within]
            order = np.lexsort((r, k))
            yield k[order], r[order]
            start = stop


def mark_cells(legs: LegSet, n_cand: int, lattice: CellLattice) -> CandidateCells:
    """The cells each candidate's legs pass within their gap of, at the receivers' heights.

    Parameters
    ----------
    legs : LegSet
    n_cand : int
        Candidates are ``0 .. n_cand - 1``.
    lattice : CellLattice

    Returns
    -------
    CandidateCells
    """
    nx, ny = lattice.shape
    empty = CandidateCells(lattice, np.zeros(lattice.n_cells + 1, np.int64), np.zeros(0, np.int64))
    if len(legs) == 0 or n_cand == 0:
        return empty
    cand = legs.cand.astype(np.int64)
    order = _counting_order(cand, n_cand)
    args = (
        cand, n_cand, np.ascontiguousarray(legs.start), np.ascontiguousarray(legs.direction), legs.length,
        legs.gap0, legs.slope, lattice.origin[0], lattice.origin[1], lattice.size, nx, ny, *lattice.z_range,
    )  # fmt: skip
    # Candidates split in two halves marked on two threads (the kernel runs without the GIL);
    # each candidate's legs stay in one half, so the halves mark disjoint keys.
    parts = _halves(order, cand) if len(order) > _THREADED and threads() > 1 else [order]
    keys = np.concatenate(thread_map(lambda o: _mark(o, *args), parts))
    # keys = cell * n_cand + cand: one sort groups them by cell with candidates ascending.
    keys.sort()
    cell = keys // n_cand
    cell_start = np.searchsorted(cell, np.arange(lattice.n_cells + 1)).astype(np.int64)
    return CandidateCells(lattice, cell_start, keys % n_cand)


_THREADED = 1 << 18  # legs above which the marking is split over two threads


def _halves(order: np.ndarray, cand: np.ndarray) -> list[np.ndarray]:
    """``order`` (legs sorted by candidate) cut in two near its middle, at a change of candidate."""
    c = cand[order]
    m = int(np.searchsorted(c, c[len(c) // 2], side="left"))
    if m == 0:
        m = int(np.searchsorted(c, c[len(c) // 2], side="right"))
    return [order[:m], order[m:]] if 0 < m < len(order) else [order]


@njit(cache=True)
def _counting_order(cand, n_cand):  # pragma: no cover - compiled
    count = np.zeros(n_cand + 1, np.int64)
    for k in cand:
        count[k + 1] += 1
    for i in range(n_cand):
        count[i + 1] += count[i]
    order = np.empty(len(cand), np.int64)
    for i in range(len(cand)):
        k = cand[i]
        order[count[k]] = i
        count[k] += 1
    return order


@njit(cache=True)
def _mark(
    order, cand, n_cand, start, direc, length, gap0, slope, x0, y0, c, nx, ny, z0, z1
):  # pragma: no cover
    """Keys ``cell * n_cand + cand`` of the cells each leg's capsule (radius gap) overlaps, once each.

    Each leg is clipped to the receivers' box widened by its largest gap, then rasterised
    column by column along its major horizontal axis: in every column of cells, the cells
    within the gap of the leg's stretch over that column are marked.
    """
    stamp = np.full(nx * ny, -1, np.int64)
    out = np.empty(1 << 16, np.int64)
    n_out = 0
    x1 = x0 + nx * c
    y1 = y0 + ny * c
    lo_b = (x0, y0, z0)
    hi_b = (x1, y1, z1)
    for ii in range(len(order)):
        i = order[ii]
        k = cand[i]
        s3 = (float(start[i, 0]), float(start[i, 1]), float(start[i, 2]))
        d3 = (float(direc[i, 0]), float(direc[i, 1]), float(direc[i, 2]))
        # Farthest the leg can travel inside the box: bounds the gap of endless legs.
        ex = max(abs(s3[0] - x0), abs(s3[0] - x1))
        ey = max(abs(s3[1] - y0), abs(s3[1] - y1))
        ez = max(abs(s3[2] - z0), abs(s3[2] - z1))
        far = min(float(length[i]), np.sqrt(ex * ex + ey * ey + ez * ez) + 1.0)
        g_a = float(gap0[i])
        g_s = float(slope[i])
        gmax = g_a + g_s * far
        lo = 0.0
        hi = far
        for a in range(3):
            sa = s3[a]
            da = d3[a]
            a0 = lo_b[a] - gmax
            a1 = hi_b[a] + gmax
            if abs(da) < 1e-12:
                if sa < a0 or sa > a1:
                    hi = -1.0
                continue
            ta = (a0 - sa) / da
            tb = (a1 - sa) / da
            if ta > tb:
                ta, tb = tb, ta
            lo = max(lo, ta)
            hi = min(hi, tb)
        if hi < lo:
            continue
        # Major axis u (larger horizontal direction component), minor axis v.
        if abs(d3[0]) >= abs(d3[1]):
            su, sv, du, dv, ou, ov, nu, nv, swap = s3[0], s3[1], d3[0], d3[1], x0, y0, nx, ny, False
        else:
            su, sv, du, dv, ou, ov, nu, nv, swap = s3[1], s3[0], d3[1], d3[0], y0, x0, ny, nx, True
        ua = su + lo * du
        ub = su + hi * du
        g_hi = g_a + g_s * hi
        i0 = max(int(np.floor((min(ua, ub) - g_hi - ou) / c)), 0)
        i1 = min(int(np.floor((max(ua, ub) + g_hi - ou) / c)), nu - 1)
        for col in range(i0, i1 + 1):
            ca = ou + col * c - g_hi
            cb = ou + (col + 1) * c + g_hi
            # Parameter range of the leg over this column (widened by the gap).
            if abs(du) > 1e-12:
                ta = (ca - su) / du
                tb = (cb - su) / du
                if ta > tb:
                    ta, tb = tb, ta
                ta = max(ta, lo)
                tb = min(tb, hi)
            else:
                ta = lo
                tb = hi
            if tb < ta:
                continue
            g = g_a + g_s * tb
            va = sv + ta * dv
            vb = sv + tb * dv
            j0 = max(int(np.floor((min(va, vb) - g - ov) / c)), 0)
            j1 = min(int(np.floor((max(va, vb) + g - ov) / c)), nv - 1)
            for row in range(j0, j1 + 1):
                if swap:
                    cell = row + nx * col
                else:
                    cell = col + nx * row
                if stamp[cell] != k:
                    stamp[cell] = k
                    if n_out == len(out):
                        grown = np.empty(2 * len(out), np.int64)
                        grown[:n_out] = out[:n_out]
                        out = grown
                    out[n_out] = cell * n_cand + k
                    n_out += 1
    return out[:n_out].copy()
