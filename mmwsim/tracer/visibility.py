"""Whether the legs of exact paths are clear, checked with Embree against the real triangles.

A path is a chain of nodes: the transmitter, its interaction points, the receiver. Each
leg is cast as one ray from its start node towards its end node:

- towards a reflection point, the ray's first hit must be a triangle of the expected
  reflector (a ray meets a plane at most once, so that hit *is* the reflection point:
  this checks at once that the point lies on a real triangle and that the leg is clear);
- towards a diffraction point or the receiver, nothing may be hit before the end.

Rays leave a reflection point :data:`EPS` off its plane, on the side of the next node,
and a diffraction point :data:`EPS` along its wedge's exterior bisector; they stop
:data:`EPS` short of a diffraction point (its offset twin) or of the receiver. The rays of
a batch are built in one compiled pass and cast in two Embree calls.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ..geometry import RayCaster
from ._vec import add, dot, norm, row, scale, sub

__all__ = ["EPS", "check_paths"]

EPS = 1e-3
"""Offset of leg origins off a reflecting plane or a diffracting edge, and clearance kept before
a leg's end, metres."""


def check_paths(
    caster: RayCaster,
    face_reflector: np.ndarray,
    ref_normal: np.ndarray,
    tx: np.ndarray,
    rx: np.ndarray,
    points: np.ndarray,
    order: np.ndarray,
    types: np.ndarray,
    refs: np.ndarray,
    offsets: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Which paths have every leg clear.

    Parameters
    ----------
    caster : RayCaster
    face_reflector : (n_faces,) int64
        Reflector of every triangle.
    ref_normal : (n_ref, 3) float64
        Reflector plane normals.
    tx : (3,) float64
    rx : (m, 3) float64
        Each path's receiver.
    points : (m, k, 3) float64
        Interaction points (first ``order`` of each row).
    order : (m,) int
    types : (m, k) int8
        1 reflection, 2 diffraction (:class:`~mmwsim.tracer.paths.Interaction`).
    refs : (m, k) int64
        Reflector of each reflection.
    offsets : (m, 3) float64
        Unit exterior bisector of each path's diffraction point (ignored without one).

    Returns
    -------
    good : (m,) bool
    faces : (m, k) int64
        Triangle hit at each reflection (-1 where none was, and at diffractions).
    rays : int
        Embree queries issued.
    """
    m, k = types.shape
    n_legs = int(np.sum(order)) + m
    o = np.empty((n_legs, 3))
    d = np.empty((n_legs, 3))
    tmax = np.empty(n_legs)
    expect = np.empty(n_legs, np.int64)  # reflector the leg must hit, -1: must be clear
    path = np.empty(n_legs, np.int64)
    slot = np.empty(n_legs, np.int64)
    _build_rays(tx, rx, points, order, types, refs, offsets, ref_normal, o, d, tmax, expect, path, slot)
    good = np.ones(m, bool)
    faces = np.full((m, k), -1, np.int64)
    hit_leg = np.flatnonzero(expect >= 0)
    if len(hit_leg):
        _, f = caster.intersect(o[hit_leg], d[hit_leg])
        got = np.where(f >= 0, face_reflector[np.maximum(f, 0)], -1)
        bad = got != expect[hit_leg]
        good[path[hit_leg[bad]]] = False
        faces[path[hit_leg], slot[hit_leg]] = f
    clear_leg = np.flatnonzero((expect < 0) & good[path])
    if len(clear_leg):
        blocked = caster.occluded(o[clear_leg], d[clear_leg], tmax[clear_leg])
        good[path[clear_leg[blocked]]] = False
    good[path[tmax <= 0]] = False
    return good, faces, len(hit_leg) + len(clear_leg)


@njit(cache=True)
def _build_rays(tx, rx, points, order, types, refs, offsets, ref_normal, o, d, tmax, expect, path, slot):
    # pragma: no cover - compiled
    leg = 0
    for i in range(len(order)):
        k = order[i]
        start = (float(tx[0]), float(tx[1]), float(tx[2]))
        for j in range(k + 1):
            end = row(rx, i) if j == k else row(points[i], j)
            kind_end = 0 if j == k else types[i, j]
            if kind_end == 2:  # stop at the offset twin of the diffraction point
                end = add(end, scale(row(offsets, i), EPS))
            v = sub(end, start)
            dist = norm(v)
            o[leg, 0], o[leg, 1], o[leg, 2] = start
            if dist > 0.0:
                d[leg, 0], d[leg, 1], d[leg, 2] = scale(v, 1.0 / dist)
            else:
                d[leg, 0], d[leg, 1], d[leg, 2] = 0.0, 0.0, 1.0
            path[leg] = i
            slot[leg] = j
            if kind_end == 1:
                expect[leg] = refs[i, j]
                tmax[leg] = np.inf
            else:
                expect[leg] = -1
                tmax[leg] = dist - EPS
            leg += 1
            if j < k:
                p = row(points[i], j)
                if types[i, j] == 2:
                    start = add(p, scale(row(offsets, i), EPS))
                else:
                    n = row(ref_normal, refs[i, j])
                    nxt = row(rx, i) if j == k - 1 else row(points[i], j + 1)
                    side = 1.0 if dot(sub(nxt, p), n) >= 0.0 else -1.0
                    start = add(p, scale(n, side * EPS))
