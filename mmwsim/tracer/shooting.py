"""Candidate interaction sequences: shoot rays from the transmitter and bounce them specularly.

Rays leave the transmitter on a Fibonacci sphere (deterministic, nearly uniform) and
are reflected specularly by the planar reflectors up to ``max_reflections`` times.
Every distinct prefix of reflector ids a ray follows is a candidate sequence; its
exact geometry is solved later by the image method. Each ray's legs also tell
where in space the sequence can deliver energy, which prunes the receivers the
candidate is solved for (see :func:`sequence_cells`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import RayCaster
from .reflectors import Reflectors

__all__ = ["Shot", "fibonacci_directions", "shoot", "sequence_cells", "CellGrid"]

# Offset of a bounced ray's origin off its plane, metres: Embree works in float32
# (about 3e-5 m resolution at 400 m), so a smaller offset could re-hit the plane.
_BOUNCE_OFFSET = 1e-3
# Receiver cells are marked within this many ray spacings (times the unfolded length) of a
# sequence's rays: twice the mean spacing, since along a thin beam rays lie one spacing apart.
_GAP_FACTOR = 2.0


def fibonacci_directions(n: int) -> np.ndarray:
    """(n, 3) float64 unit vectors on a Fibonacci spiral covering the sphere evenly."""
    return _fib_slice(n, 0, n)


@dataclass
class Legs:
    """The legs of order ``k`` (after the k-th bounce) of the rays that made k bounces.

    Stored in float32: they only decide which receiver cells a sequence may reach.

    Attributes
    ----------
    seq : (m,) int32
        Candidate sequence (index into ``Shot.sequences[k]``) of each leg.
    start : (m, 3) float32
        Leg origin (the k-th bounce point), metres.
    direction : (m, 3) float32
        Unit direction.
    length : (m,) float32
        Distance to the next hit, ``inf`` when the ray leaves the scene, metres.
    unfolded : (m,) float32
        Path length from the transmitter to ``start``, metres.
    """

    seq: np.ndarray
    start: np.ndarray
    direction: np.ndarray
    length: np.ndarray
    unfolded: np.ndarray

    @staticmethod
    def concatenate(parts: list[Legs]) -> Legs:
        return Legs(*(np.concatenate([getattr(p, f) for p in parts]) for f in Legs.__dataclass_fields__))


@dataclass
class Shot:
    """Result of the ray shooting.

    Attributes
    ----------
    n_rays : int
        Rays launched.
    spacing : float
        Mean angular spacing of the launched rays, radians.
    sequences : list of (n_k, k) int64
        ``sequences[k]`` holds the distinct reflector sequences of order k
        (``sequences[0]`` is the empty sequence of line of sight).
    legs : list of Legs
        ``legs[k]`` for k = 1 .. max_reflections (``legs[0]`` is None).
    rays_cast : int
        Embree queries issued.
    sample : list of (n_points, 3) float64
        Polylines of an evenly spread sample of the shot rays (transmitter, bounce
        points, last hit or a point 1 km out), for display.
    """

    n_rays: int
    spacing: float
    sequences: list[np.ndarray]
    legs: list[Legs | None]
    rays_cast: int
    sample: list[np.ndarray]


def shoot(
    caster: RayCaster,
    reflectors: Reflectors,
    tx: np.ndarray,
    max_reflections: int,
    n_rays: int,
    batch: int = 1 << 20,
    n_sample: int = 500,
) -> Shot:
    """Shoot ``n_rays`` rays from ``tx`` and bounce them ``max_reflections`` times.

    Parameters
    ----------
    caster : RayCaster
        Embree scene whose face ids index ``reflectors.face_reflector``.
    reflectors : Reflectors
    tx : (3,) float64
        Transmitter, metres.
    max_reflections : int
    n_rays : int
    batch : int
        Rays traced together (memory bound; the result does not depend on it).
    n_sample : int
        Rays kept as polylines in ``Shot.sample``.

    Returns
    -------
    Shot
    """
    tx = np.asarray(tx, dtype=np.float64)
    n_ref = max(reflectors.n, 1)
    # Per order: key (parent id * n_ref + reflector) -> id, in order of discovery (deterministic).
    tables: list[dict[int, int]] = [{} for _ in range(max_reflections + 1)]
    parents: list[list[int]] = [[] for _ in range(max_reflections + 1)]
    legs: list[list[Legs]] = [[] for _ in range(max_reflections + 1)]
    stride = max(1, n_rays // n_sample)
    sample: dict[int, list[np.ndarray]] = {}
    rays_cast = 0
    for b0 in range(0, n_rays, batch):
        dirs = _fib_slice(n_rays, b0, batch)
        ray_id = np.arange(b0, b0 + len(dirs), dtype=np.int64)
        origin = np.broadcast_to(tx, dirs.shape).copy()
        unfolded = np.zeros(len(dirs))
        seq_id = np.zeros(len(dirs), dtype=np.int64)
        last_ref = np.full(len(dirs), -1, dtype=np.int64)
        for i in ray_id[ray_id % stride == 0]:
            sample[int(i)] = [tx]
        for k in range(max_reflections + 1):
            t, face = caster.intersect(origin, dirs)
            rays_cast += len(origin)
            if k:
                legs[k].append(
                    Legs(
                        seq_id.astype(np.int32),
                        origin.astype(np.float32),
                        dirs.astype(np.float32),
                        t.astype(np.float32),
                        unfolded.astype(np.float32),
                    )
                )
            smp = np.flatnonzero(ray_id % stride == 0)
            for i in smp:
                tt = t[i] if np.isfinite(t[i]) else 1e3
                sample[int(ray_id[i])].append(origin[i] + tt * dirs[i])
            if k == max_reflections:
                break
            ref = np.where(face >= 0, reflectors.face_reflector[np.maximum(face, 0)], -1)
            # A ray cannot physically meet the plane it just left; such hits are float32 noise.
            keep = (ref >= 0) & (ref != last_ref)
            t, ref, origin, dirs = t[keep], ref[keep], origin[keep], dirs[keep]
            unfolded, seq_id, ray_id = unfolded[keep] + t, seq_id[keep], ray_id[keep]
            n = reflectors.normal[ref]
            point = origin + t[:, None] * dirs
            dn = np.einsum("ij,ij->i", dirs, n)
            dirs = dirs - 2.0 * dn[:, None] * n
            origin = point - np.sign(dn)[:, None] * _BOUNCE_OFFSET * n
            uniq, inv = np.unique(seq_id * n_ref + ref, return_inverse=True)
            table = tables[k + 1]
            ids = np.empty(len(uniq), dtype=np.int64)
            for j, key in enumerate(uniq.tolist()):
                if key not in table:
                    table[key] = len(table)
                    parents[k + 1].append(key)
                ids[j] = table[key]
            seq_id = ids[inv.ravel()]
            last_ref = ref
    sequences: list[np.ndarray] = [np.zeros((1, 0), dtype=np.int64)]
    for k in range(1, max_reflections + 1):
        keys = np.asarray(parents[k], dtype=np.int64)
        prev = sequences[k - 1][keys // n_ref]
        sequences.append(np.column_stack([prev, keys % n_ref]).astype(np.int64))
    all_legs: list[Legs | None] = [None] + [
        Legs.concatenate(legs[k]) if legs[k] else _empty_legs() for k in range(1, max_reflections + 1)
    ]
    polylines = [np.asarray(sample[i]) for i in sorted(sample)]
    return Shot(n_rays, float(np.sqrt(4.0 * np.pi / n_rays)), sequences, all_legs, rays_cast, polylines)


def _fib_slice(n: int, start: int, count: int) -> np.ndarray:
    """Rays ``start:start+count`` of :func:`fibonacci_directions` (n) without building them all."""
    i = np.arange(start, min(n, start + count), dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * (np.pi * (3.0 - np.sqrt(5.0)))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _empty_legs() -> Legs:
    f = np.zeros(0, np.float32)
    return Legs(np.zeros(0, np.int32), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32), f, f)


@dataclass(frozen=True)
class CellGrid:
    """A horizontal grid of square cells that bins receivers and ray legs.

    Attributes
    ----------
    origin : (2,) float64
        x, y of the corner of cell (0, 0), metres.
    size : float
        Cell side, metres.
    shape : (2,) int
        Cells along x and y.
    z_range : (2,) float64
        Heights spanned by the receivers, metres.
    """

    origin: tuple[float, float]
    size: float
    shape: tuple[int, int]
    z_range: tuple[float, float]

    @property
    def n_cells(self) -> int:
        return int(self.shape[0] * self.shape[1])

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """(n,) int64 linear cell index of points (n, 2); -1 outside the grid."""
        ij = np.floor((xy - np.asarray(self.origin)) / self.size).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.shape[0]) & (ij[:, 1] < self.shape[1])
        return np.where(inside, ij[:, 0] + self.shape[0] * ij[:, 1], -1)


def sequence_cells(legs: Legs, grid: CellGrid, spacing: float, chunk: int = 1 << 20) -> np.ndarray:
    """The cells where each candidate sequence of one order may reach a receiver.

    A sequence's rays sample the beam it illuminates, spread by ``spacing`` radians
    around its image source; a receiver inside the beam lies within about
    ``spacing x unfolded length`` of one of those rays. Each leg is clipped to the
    receivers' height range widened by that gap, sampled every half cell, and the
    cells around the samples (radius gap + half a step) are marked.

    Parameters
    ----------
    legs : Legs
    grid : CellGrid
    spacing : float
        Angular spacing of the shot rays, radians.
    chunk : int
        Legs processed together (memory bound; the result does not depend on it).

    Returns
    -------
    (n_pairs,) int64
        Sorted unique keys ``seq * grid.n_cells + cell``.
    """
    parts = [
        _leg_cells(Legs(*(getattr(legs, f)[a : a + chunk] for f in Legs.__dataclass_fields__)), grid, spacing)
        for a in range(0, len(legs.seq), chunk)
    ]
    return np.unique(np.concatenate(parts)) if parts else np.zeros(0, dtype=np.int64)


def _leg_cells(legs: Legs, grid: CellGrid, spacing: float, max_samples: int = 1 << 22) -> np.ndarray:
    if len(legs.seq) == 0:
        return np.zeros(0, dtype=np.int64)
    c = grid.size
    x0, y0 = grid.origin
    x1, y1 = x0 + grid.shape[0] * c, y0 + grid.shape[1] * c
    z0, z1 = grid.z_range
    s, d = legs.start.astype(np.float64), legs.direction.astype(np.float64)
    length = legs.length.astype(np.float64)
    # Farthest a leg can travel inside the receivers' box: bounds the gap of long or endless legs.
    box_lo, box_hi = np.array([x0, y0, z0]), np.array([x1, y1, z1])
    reach = np.sqrt(np.sum(np.maximum(np.abs(s - box_lo), np.abs(s - box_hi)) ** 2, axis=1))
    far = np.minimum(length, reach + 1.0)
    # Gap to the nearest ray of the same sequence, at the farthest useful point of the leg.
    gap = _GAP_FACTOR * spacing * (legs.unfolded.astype(np.float64) + far) + 0.05
    lo = np.zeros(len(s))
    hi = far.copy()
    for axis, a0, a1 in ((0, x0, x1), (1, y0, y1), (2, z0, z1)):
        # Slab clip with the per-leg margin: parameter range where the coordinate is in [a0 - g, a1 + g].
        da = d[:, axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (a0 - gap - s[:, axis]) / da
            tb = (a1 + gap - s[:, axis]) / da
        flat = np.abs(da) < 1e-12
        inside = (s[:, axis] >= a0 - gap) & (s[:, axis] <= a1 + gap)
        tmin = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
        tmax = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
        lo = np.maximum(lo, tmin)
        hi = np.minimum(hi, tmax)
    ok = hi >= lo
    idx = np.flatnonzero(ok)
    step = c / 2.0
    n_samp = np.floor((hi[idx] - lo[idx]) / step).astype(np.int64) + 2
    radius = np.ceil((gap[idx] + step / 2.0) / c).astype(np.int64)
    keys = []
    cum = np.cumsum(n_samp)
    start = 0
    while start < len(idx):
        done = cum[start - 1] if start else 0
        stop = max(int(np.searchsorted(cum, done + max_samples, side="right")), start + 1)
        sel = idx[start:stop]
        ns = n_samp[start:stop]
        rad = radius[start:stop]
        leg_of = np.repeat(np.arange(len(sel)), ns)
        first = np.cumsum(ns) - ns
        j = np.arange(len(leg_of)) - first[leg_of]
        tt = np.minimum(lo[sel][leg_of] + j * step, hi[sel][leg_of])
        pts = s[sel][leg_of, :2] + tt[:, None] * d[sel][leg_of, :2]
        ij = np.floor((pts - np.asarray(grid.origin)) / c).astype(np.int64)
        seq = legs.seq[sel].astype(np.int64)[leg_of]
        r = rad[leg_of]
        for rr in np.unique(r):
            m = r == rr
            off = np.arange(-rr, rr + 1)
            ox, oy = np.meshgrid(off, off, indexing="ij")
            ci = ij[m, 0:1] + ox.ravel()[None, :]
            cj = ij[m, 1:2] + oy.ravel()[None, :]
            valid = (ci >= 0) & (cj >= 0) & (ci < grid.shape[0]) & (cj < grid.shape[1])
            key = seq[m][:, None] * grid.n_cells + ci + grid.shape[0] * cj
            keys.append(np.unique(key[valid]))
        start = stop
    if not keys:
        return np.zeros(0, dtype=np.int64)
    return np.unique(np.concatenate(keys))
