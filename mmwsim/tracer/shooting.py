"""Candidate interaction sequences: shoot rays from the transmitter and bounce them specularly.

Rays leave the transmitter on a Fibonacci sphere (deterministic, nearly uniform) and
are reflected specularly by the planar reflectors up to ``max_reflections`` times.
Every distinct prefix of reflector ids a ray follows is a candidate sequence; its
exact geometry is solved later by the image method. Each ray's legs also tell
where in space the sequence can deliver energy, which prunes the receivers the
candidate is solved for (see :func:`sequence_cells`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from .._jit import njit
from .._threads import pieces, thread_map
from ..geometry import RayCaster
from .reflectors import Reflectors

__all__ = ["Shot", "Legs", "bounce", "fibonacci_directions", "sequence_ids", "shoot"]

# Offset of a bounced ray's origin off its plane, metres: Embree works in float32
# (about 3e-5 m resolution at 400 m), so a smaller offset could re-hit the plane.
_BOUNCE_OFFSET = 1e-3
_MIN_SPLIT = 1 << 16  # rays below which one thread does a numpy or compiled pass
_DENSE_KEYS = 1 << 24  # sequence keys looked up in a dense table up to this many (128 MB)


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
        if len(parts) == 1:
            return parts[0]
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
    hits : list of (n_k, 2) int64
        ``hits[k]``: distinct (sequence of order k, triangle) pairs such that some ray
        that followed the sequence next hit the triangle (``hits[0]``: triangles hit
        straight from the transmitter). Triangles outside ``hit_faces`` are left out.
    """

    n_rays: int
    spacing: float
    sequences: list[np.ndarray]
    legs: list[Legs | None]
    rays_cast: int
    sample: list[np.ndarray]
    hits: list[np.ndarray]


def shoot(
    caster: RayCaster,
    reflectors: Reflectors,
    tx: np.ndarray,
    max_reflections: int,
    n_rays: int,
    batch: int = 1 << 22,
    n_sample: int = 500,
    hit_faces: np.ndarray | None = None,
    hit_orders: int = 0,
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
    hit_faces : (n_faces,) bool, optional
        Triangles whose hits are recorded in ``Shot.hits`` (none by default).
    hit_orders : int
        Hits are recorded after sequences of order ``0 .. hit_orders - 1``.

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
    hits: list[list[np.ndarray]] = [[] for _ in range(max_reflections + 1)]
    n_faces = caster.n_faces
    sample: dict[int, list[np.ndarray]] = {}
    rays_cast = 0
    warm = _warm_up(reflectors) if max_reflections else None
    for b0 in range(0, n_rays, batch):
        dirs = _fib_slice(n_rays, b0, batch)
        # Sampled rays: their position in this order's arrays and their ray number.
        smp = np.arange((-b0) % stride, len(dirs), stride)
        smp_id = smp + b0
        origin = np.broadcast_to(tx, dirs.shape).copy()
        unfolded = np.zeros(len(dirs))
        seq_id = np.zeros(len(dirs), dtype=np.int64)
        last_ref = np.full(len(dirs), -1, dtype=np.int64)
        for i in smp_id.tolist():
            sample[i] = [tx]
        for k in range(max_reflections + 1):
            t, face = caster.intersect(origin, dirs)
            rays_cast += len(origin)
            if k < hit_orders and hit_faces is not None:
                sel = face >= 0
                sel[sel] = hit_faces[face[sel]]
                hits[k].append(np.unique(seq_id[sel] * n_faces + face[sel]))
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
            for i, r in zip(smp.tolist(), smp_id.tolist(), strict=True):
                tt = t[i] if np.isfinite(t[i]) else 1e3
                sample[r].append(origin[i] + tt * dirs[i])
            if k == max_reflections:
                break
            if warm is not None:
                warm.join()
                warm = None
            keep, ref, origin, dirs, unfolded = bounce(
                origin, dirs, t, face, reflectors.face_reflector, reflectors.normal, last_ref, unfolded
            )
            seq_id = seq_id[keep]
            at = np.minimum(np.searchsorted(keep, smp), max(len(keep) - 1, 0))
            alive = keep[at] == smp if len(keep) else np.zeros(len(smp), bool)
            smp, smp_id = at[alive], smp_id[alive]
            seq_id = sequence_ids(tables[k + 1], parents[k + 1], seq_id * n_ref + ref)
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
    hit_pairs = []
    for h in hits:
        keys = np.unique(np.concatenate(h)) if h else np.zeros(0, np.int64)
        hit_pairs.append(np.column_stack([keys // max(n_faces, 1), keys % max(n_faces, 1)]))
    spacing = float(np.sqrt(4.0 * np.pi / n_rays))
    return Shot(n_rays, spacing, sequences, all_legs, rays_cast, polylines, hit_pairs)


def bounce(origin, dirs, t, face, face_reflector, normal, last_ref, unfolded):
    """Reflect the rays that hit a reflector specularly; returns (kept index, reflector, origin, dirs, unfolded).

    A ray cannot physically meet the plane it just left: such hits are float32 noise and
    end the ray, as do misses. New origins sit :data:`_BOUNCE_OFFSET` off the plane.
    """
    ref = face_reflector[np.maximum(face, 0)].astype(np.int64)
    keep = np.flatnonzero((face >= 0) & (ref >= 0) & (ref != last_ref))
    ref = ref[keep]
    n = len(keep)
    o2, d2, u2 = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    thread_map(
        lambda s: _reflect(keep[s], ref[s], origin, dirs, t, normal, unfolded, o2[s], d2[s], u2[s]),
        pieces(n, _MIN_SPLIT),
    )
    return keep, ref, o2, d2, u2


@njit(cache=True)
def _reflect(keep, ref, origin, dirs, t, normal, unfolded, o2, d2, u2):  # pragma: no cover
    """Mirror rays ``keep`` in the planes ``ref`` at their hits, into ``o2``, ``d2``, ``u2``."""
    for j in range(len(keep)):
        i = keep[j]
        r = ref[j]
        nx, ny, nz = normal[r, 0], normal[r, 1], normal[r, 2]
        dn = dirs[i, 0] * nx + dirs[i, 1] * ny + dirs[i, 2] * nz
        side = _BOUNCE_OFFSET if dn > 0 else (-_BOUNCE_OFFSET if dn < 0 else 0.0)
        for a, na in enumerate((nx, ny, nz)):
            o2[j, a] = origin[i, a] + t[i] * dirs[i, a] - side * na
            d2[j, a] = dirs[i, a] - 2.0 * dn * na
        u2[j] = unfolded[i] + t[i]


def _warm_up(reflectors: Reflectors) -> threading.Thread:
    """Load the compiled kernel in the background; numba's first load takes a third of a second
    of Python work, which overlaps the first Embree pass (that releases the GIL)."""
    i, f, v = np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3))
    normal = np.ascontiguousarray(reflectors.normal, dtype=np.float64)
    job = threading.Thread(target=_reflect, args=(i, i, v, v, f, normal, f, v, v, f), daemon=True)
    job.start()
    return job


def sequence_ids(table: dict, parents: list[int], keys: np.ndarray) -> np.ndarray:
    """Ids of sequence keys (parent id * n_ref + reflector), new keys numbered in sorted order.

    ``table`` maps keys to ids; while the key space is small it also holds a dense array
    (``table["dense"]``) so that known keys are looked up without sorting.
    """
    top = int(keys.max()) + 1 if len(keys) else 0
    dense = table.get("dense")
    if top <= _DENSE_KEYS:
        if dense is None or len(dense) < top:
            grown = np.full(max(top, 1024), -1, np.int64)
            if dense is not None:
                grown[: len(dense)] = dense
            table["dense"] = dense = grown
        ids = dense[keys]
        new = np.unique(keys[ids < 0])
        if len(new):
            dense[new] = len(parents) + np.arange(len(new))
            parents.extend(new.tolist())
            ids = dense[keys]
        return ids
    if dense is not None:  # the key space outgrew the dense table: move to the sorted path
        for key in np.flatnonzero(dense >= 0).tolist():
            table[key] = int(dense[key])
        del table["dense"]
    uniq, inv = np.unique(keys, return_inverse=True)
    ids = np.empty(len(uniq), dtype=np.int64)
    for j, key in enumerate(uniq.tolist()):
        if key not in table:
            table[key] = len(parents)
            parents.append(key)
        ids[j] = table[key]
    return ids[inv.ravel()]


def _fib_slice(n: int, start: int, count: int) -> np.ndarray:
    """Rays ``start:start+count`` of :func:`fibonacci_directions` (n) without building them all."""
    out = np.empty((max(0, min(n, start + count) - start), 3))

    def fill(s: slice) -> None:  # numpy releases the GIL in these loops: pieces run on threads
        i = np.arange(start + s.start, start + s.stop, dtype=np.float64)
        z = 1.0 - (2.0 * i + 1.0) / n
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        phi = i * (np.pi * (3.0 - np.sqrt(5.0)))
        out[s, 0] = r * np.cos(phi)
        out[s, 1] = r * np.sin(phi)
        out[s, 2] = z

    thread_map(fill, pieces(len(out), _MIN_SPLIT))
    return out


def _empty_legs() -> Legs:
    f = np.zeros(0, np.float32)
    return Legs(np.zeros(0, np.int32), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32), f, f)
