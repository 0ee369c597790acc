"""Diffracting wedges of a scene: convex edges shared by two exposed faces.

A wedge is an edge shared by exactly two triangles (after welding the vertices of
all objects) whose planes meet at an exterior angle differing from flat by more
than :data:`MIN_ANGLE`, with the solid on the inside (a convex edge). Left out:

- coplanar diagonals (flat), free boundaries such as the ground's rim (one face),
  non-manifold edges (three or more faces) and concave edges (exterior angle < 180 deg);
- edges buried in other geometry: the bottom edges of a closed building standing on
  the ground, the edges of a part stacked on another, walls shared by touching
  buildings. Each face of the edge must have free space just in front of it near the
  edge, and so must the bisector of the exterior region.

Collinear pieces of one edge between the same two planes and materials are merged into
one wedge (across objects: touching buildings form one edge), so a diffraction point on
a joint between triangles is neither lost nor counted twice.

Frame of each wedge (Kouyoumjian-Pathak): ``t0`` lies in the 0-face, perpendicular
to the edge and pointing into the face; ``n0`` is that face's outward normal; the edge
direction is ``e = t0 x n0`` so that ``t0 = n0 x e``. A direction perpendicular to the
edge at angle ``phi`` from the 0-face is ``cos(phi) t0 + sin(phi) n0``; the exterior
region is ``0 < phi < n pi`` and ``phi = n pi`` lies along ``tn``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..scene import Scene
from .reflectors import group_reflectors

__all__ = ["Wedges", "find_wedges", "MIN_ANGLE", "solid_inside"]

MIN_ANGLE = np.radians(1.0)
"""Edges whose faces' normals differ by less than this are flat (not wedges), radians."""

_WELD = 1e-5  # vertex welding quantum, metres
_PROBE = 0.01  # how far in front of a face free space is checked, metres
_PROBE_STEP = 0.5  # spacing of the exposure probes along an edge, metres
_LINE_ANGLE = 1e-7  # collinear pieces: directions within this many radians
_LINE_DIST = 1e-5  # ... and lines within this distance, metres


@dataclass(frozen=True)
class Wedges:
    """The diffracting wedges of a scene.

    Attributes
    ----------
    origin : (w, 3) float64
        Start of each edge, metres.
    edge : (w, 3) float64
        Unit edge direction ``e = t0 x n0``.
    length : (w,) float64
        Edge length, metres; the edge is ``origin + x edge`` for ``0 <= x <= length``.
    t0, n0, tn, nn : (w, 3) float64
        In-face directions (from the edge into the face) and outward normals of the
        0-face and the n-face.
    n : (w,) float64
        Exterior angle over pi, in (1, 2).
    face0, facen : (w,) int64
        A triangle of each face (for its material and object).
    facet_start, facet_wedge : (n_facets + 1,) int64, (nnz,) int64
        Wedges bordering each facet (connected coplanar triangles), as CSR.
    face_facet : (n_faces,) int64
        Facet of every scene triangle (-1 for degenerate ones).
    """

    origin: np.ndarray
    edge: np.ndarray
    length: np.ndarray
    t0: np.ndarray
    n0: np.ndarray
    tn: np.ndarray
    nn: np.ndarray
    n: np.ndarray
    face0: np.ndarray
    facen: np.ndarray
    facet_start: np.ndarray
    facet_wedge: np.ndarray
    face_facet: np.ndarray

    @property
    def count(self) -> int:
        return int(len(self.length))

    def segments(self) -> np.ndarray:
        """(w, 2, 3) float64 end points of every wedge, metres."""
        return np.stack([self.origin, self.origin + self.length[:, None] * self.edge], axis=1)

    def point(self, wedge: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(m, 3) points at distance ``x`` (m,) along wedges ``wedge`` (m,), metres."""
        return self.origin[wedge] + x[:, None] * self.edge[wedge]

    @cached_property
    def bisectors(self) -> np.ndarray:
        """(w, 3) unit vectors into the middle of each wedge's exterior region."""
        b = self.n0 + self.nn
        return b / np.linalg.norm(b, axis=1, keepdims=True)

    def bisector(self, wedge: np.ndarray) -> np.ndarray:
        """(m, 3) unit vectors into the middle of the exterior region of wedges ``wedge``."""
        return self.bisectors[wedge]

    def locate(self, points: np.ndarray, tol: float = 1e-6) -> np.ndarray:
        """(m,) index of the wedge each point (m, 3) lies on (within ``tol`` metres), -1 if none."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.full(len(p), -1, np.int64)
        for a in range(0, len(p), 256):  # bounded (points x wedges) temporaries
            q = p[a : a + 256, None, :] - self.origin[None]
            x = np.clip(np.einsum("mwi,wi->mw", q, self.edge), 0.0, self.length[None])
            d = np.linalg.norm(q - x[..., None] * self.edge[None], axis=2)
            best = np.argmin(d, axis=1) if self.count else np.zeros(len(q), np.int64)
            hit = d[np.arange(len(q)), best] <= tol if self.count else np.zeros(len(q), bool)
            out[a : a + 256] = np.where(hit, best, -1)
        return out

    def wedges_of_facets(self, facets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(index into ``facets``, wedge) pairs of the wedges bordering each facet (m,)."""
        facets = np.asarray(facets, np.int64)
        ok = facets >= 0
        f = facets[ok]
        cnt = self.facet_start[f + 1] - self.facet_start[f]
        src = np.repeat(np.flatnonzero(ok), cnt)
        within = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        return src, self.facet_wedge[np.repeat(self.facet_start[f], cnt) + within]


def solid_inside(scene: Scene, points: np.ndarray) -> np.ndarray:
    """Whether each point (n, 3) lies inside a closed object or under the ground.

    A ray cast straight up from a point inside a closed, outward-oriented mesh first
    meets a face from behind (a face whose normal points up); from free space it meets
    nothing, a downward-facing face, or a vertical one.

    Returns
    -------
    (n,) bool
    """
    p = np.asarray(points, dtype=np.float64)
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), p.shape)
    _, face = scene.ray_caster.intersect(p, up)
    hit = face >= 0
    out = np.zeros(len(p), bool)
    out[hit] = scene.face_normals[face[hit], 2] > 1e-9
    return out


def find_wedges(scene: Scene, min_angle: float = MIN_ANGLE) -> Wedges:
    """Extract the diffracting wedges of ``scene``.

    Parameters
    ----------
    scene : Scene
    min_angle : float
        Smallest angle between the two faces' normals for an edge to diffract, radians.

    Returns
    -------
    Wedges
    """
    verts = scene.vertices
    faces = scene.faces
    normals = scene.face_normals
    n_faces = len(faces)
    good = np.linalg.norm(normals, axis=1) > 0.5
    refl = group_reflectors(scene).face_reflector
    key = np.round(verts / _WELD).astype(np.int64)
    if len(key):
        _, vid = np.unique(key, axis=0, return_inverse=True)
        vid = vid.ravel()
    else:
        vid = np.zeros(0, np.int64)
    # Half-edges: corner j -> corner j + 1 of each face, with the opposite corner.
    corners = np.arange(3)
    he_face = np.repeat(np.arange(n_faces), 3)
    he_p0 = faces[:, corners].reshape(-1)
    he_p1 = faces[:, (corners + 1) % 3].reshape(-1)
    he_opp = faces[:, (corners + 2) % 3].reshape(-1)
    a, b = vid[he_p0], vid[he_p1]
    ok = good[he_face] & (a != b)
    he = np.flatnonzero(ok)
    lo, hi = np.minimum(a[he], b[he]), np.maximum(a[he], b[he])
    ekey = lo * (int(vid.max(initial=0)) + 1) + hi
    order = np.argsort(ekey, kind="stable")
    he, ekey = he[order], ekey[order]
    _, first, count = np.unique(ekey, return_index=True, return_counts=True)
    pair = count == 2
    h0, h1 = he[first[pair]], he[first[pair] + 1]
    fa, fb = he_face[h0], he_face[h1]
    face_facet = _facets(n_faces, good, refl, fa, fb)
    # Consistently wound neighbours run the shared edge in opposite directions.
    consistent = a[h0] == b[h1]
    h0, h1, fa, fb = h0[consistent], h1[consistent], fa[consistent], fb[consistent]
    # Canonical 0-face: the one on the lower reflector (then lower face index).
    swap = (refl[fa] > refl[fb]) | ((refl[fa] == refl[fb]) & (fa > fb))
    h0, h1 = np.where(swap, h1, h0), np.where(swap, h0, h1)
    fa, fb = he_face[h0], he_face[h1]
    na, nb = normals[fa], normals[fb]
    ang = np.arccos(np.clip(np.einsum("ij,ij->i", na, nb), -1.0, 1.0))
    p0, p1 = verts[he_p0[h0]], verts[he_p1[h0]]
    # Convex: face b's opposite corner lies behind face a's plane.
    convex = np.einsum("ij,ij->i", na, verts[he_opp[h1]] - p0) < -1e-9
    keep = (ang > min_angle) & convex
    h0, fa, fb, na, nb, ang, p0, p1 = (x[keep] for x in (h0, fa, fb, na, nb, ang, p0, p1))
    e = p1 - p0
    length = np.linalg.norm(e, axis=1)
    e /= length[:, None]
    # Orient e so that t0 = n0 x e points into the 0-face.
    flip = np.einsum("ij,ij->i", np.cross(na, e), verts[he_opp[h0]] - p0) < 0
    e[flip] *= -1.0
    p0 = np.where(flip[:, None], p1, p0)
    t0 = np.cross(na, e)
    tn = np.cross(e, nb)
    p0, length = _exposed(scene, p0, length, e, t0, tn, na, nb)
    keep = length > 0
    fa, fb, na, nb, ang, p0, length, e, t0, tn = (
        x[keep] for x in (fa, fb, na, nb, ang, p0, length, e, t0, tn)
    )
    # Pieces of one line between the same planes and materials merge, across objects too
    # (touching buildings of one material form one straight edge).
    kinds = [repr(o.material) for o in scene.objects]
    material = (
        np.unique(kinds, return_inverse=True)[1].ravel()[scene.face_object] if kinds else scene.face_object
    )
    group = (
        np.unique(
            np.column_stack([refl[fa], refl[fb], material[fa], material[fb]]),
            axis=0,
            return_inverse=True,
        )[1].ravel()
        if len(fa)
        else np.zeros(0, np.int64)
    )
    s0 = np.einsum("ij,ij->i", p0, e)
    # Pieces of one line between the same planes share e exactly up to rounding: use the
    # group's first direction to measure positions along it.
    order = np.lexsort((s0, group))
    group, s0 = group[order], s0[order]
    fa, fb, na, nb, ang, p0, length, e, t0, tn = (
        x[order] for x in (fa, fb, na, nb, ang, p0, length, e, t0, tn)
    )
    s1 = s0 + length
    # Merge touching pieces: a new wedge starts where a group starts or a piece begins
    # beyond every earlier piece of its group.
    span = 4.0 * (np.abs(np.concatenate([s0, s1])).max(initial=1.0) + 1.0)
    reach = np.maximum.accumulate(s1 + group * span) - group * span
    new = np.ones(len(s0), bool)
    new[1:] = (group[1:] != group[:-1]) | (s0[1:] > reach[:-1] + _WELD)
    wid = np.cumsum(new) - 1
    heads = np.flatnonzero(new)
    n_w = len(heads)
    end = np.full(n_w, -np.inf)
    np.maximum.at(end, wid, s1)
    lengths = end - s0[heads]
    # Facet -> wedge table from every piece, so a wedge is found from any facet along it.
    fac = np.concatenate([face_facet[fa], face_facet[fb]])
    wfac = np.concatenate([wid, wid])
    pairs = np.unique(np.column_stack([fac, wfac]), axis=0) if len(fac) else np.zeros((0, 2), np.int64)
    n_facets = int(face_facet.max(initial=-1)) + 1
    facet_start = np.searchsorted(pairs[:, 0], np.arange(n_facets + 1)).astype(np.int64)
    return Wedges(
        origin=p0[heads],
        edge=e[heads],
        length=lengths,
        t0=t0[heads],
        n0=na[heads],
        tn=tn[heads],
        nn=nb[heads],
        n=1.0 + ang[heads] / np.pi,
        face0=fa[heads].astype(np.int64),
        facen=fb[heads].astype(np.int64),
        facet_start=facet_start,
        facet_wedge=pairs[:, 1].astype(np.int64),
        face_facet=face_facet,
    )


def _exposed(scene, p0, length, e, t0, tn, n0, nn) -> tuple[np.ndarray, np.ndarray]:
    """Trim each edge to its exposed part: free space in front of both faces and on the bisector.

    Probes every ``_PROBE_STEP`` along the edge (at least three per edge); an edge keeps
    the span from its first to its last exposed probe (widened by half a step, within
    the edge), or length 0 when none is exposed. A partly covered edge (a corner of a
    tall building whose lower part touches a lower one) keeps its free part; any covered
    stretch left inside that span is rejected later by the path's blocked legs.
    """
    if not len(length):
        return p0, length
    k = np.clip(np.ceil(length / _PROBE_STEP).astype(np.int64), 3, 256)
    piece = np.repeat(np.arange(len(length)), k)
    j = np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
    frac = (j + 0.5) / k[piece]
    x = frac * length[piece]
    mid = p0[piece] + x[:, None] * e[piece]
    bis = n0[piece] + nn[piece]
    bis /= np.linalg.norm(bis, axis=1, keepdims=True)
    probes = np.concatenate(
        [mid + _PROBE * (t0[piece] + n0[piece]), mid + _PROBE * (tn[piece] + nn[piece]), mid + _PROBE * bis]
    )
    free = ~solid_inside(scene, probes).reshape(3, -1).any(axis=0)
    half = 0.5 * length[piece] / k[piece]
    lo = np.full(len(length), np.inf)
    hi = np.full(len(length), -np.inf)
    np.minimum.at(lo, piece[free], np.maximum(x[free] - half[free], 0.0))
    np.maximum.at(hi, piece[free], np.minimum(x[free] + half[free], length[piece][free]))
    exposed = hi > lo
    lo = np.where(exposed, lo, 0.0)
    # Ends within half a step of the true end are the true end (no trimming by rounding).
    lo = np.where(lo <= half[np.cumsum(k) - 1] + 1e-9, 0.0, lo)
    hi = np.where(hi >= length - half[np.cumsum(k) - 1] - 1e-9, length, hi)
    return p0 + lo[:, None] * e, np.where(exposed, hi - lo, 0.0)


def _facets(n_faces: int, good: np.ndarray, refl: np.ndarray, fa: np.ndarray, fb: np.ndarray) -> np.ndarray:
    """Facet id per face: triangles of one plane connected through shared edges."""
    same = refl[fa] == refl[fb]
    graph = coo_matrix((np.ones(int(same.sum())), (fa[same], fb[same])), shape=(n_faces, n_faces))
    _, label = connected_components(graph, directed=False)
    label = label.astype(np.int64)
    label[~good] = -1
    return label
