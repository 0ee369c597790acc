"""The exact shortest path in a :class:`AgentSpace`: a visibility graph over the inflated obstacles.

The agent's centre moves in F = region ∩ corridor − (obstacles ⊕ disc(radius)). A shortest
path in a polygonal domain is a polyline whose inner vertices are reflex vertices of F (convex
corners of the inflated obstacles, concave corners of the corridor), joined by segments that
lie in F and are tangent to the boundary at both ends. The disc's arcs are polygons with
their vertices on the circle (``quad_segs`` per quadrant), so F contains the true free space
and the length found is a lower bound on the true optimum, within r (theta - 2 sin(theta / 2))
per corner turned by theta (< 0.3 mm per right-angle corner at r = 0.5 m, quad_segs = 16).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import shapely
from shapely.geometry.polygon import orient

from .space import AgentSpace, as_point

__all__ = ["ShortestPath", "shortest_path", "free_region"]

_PAIR_BLOCK = 1 << 22


@dataclass(frozen=True)
class ShortestPath:
    """A shortest collision-free path.

    Attributes
    ----------
    path : (n, 2) float64
        Vertices from start to goal, metres.
    length : float
        Metres.
    n_nodes, n_edges : int
        Size of the visibility graph.
    """

    path: np.ndarray
    length: float
    n_nodes: int
    n_edges: int


def free_region(space: AgentSpace, quad_segs: int = 16) -> shapely.Geometry:
    """F: the planning region, cut to the corridor, minus the obstacles grown by the agent radius."""
    (x0, y0), (x1, y1) = space.bounds
    region = shapely.box(x0, y0, x1, y1)
    if space.corridor is not None:
        region = region.intersection(space.corridor.polygon)
    if space.obstacles:
        grown = shapely.buffer(np.array(space.obstacles, dtype=object), space.radius, quad_segs=quad_segs)
        region = region.difference(shapely.union_all(grown))
    return region


def shortest_path(space: AgentSpace, start, goal, quad_segs: int = 16) -> ShortestPath | None:
    """The shortest path from ``start`` to ``goal`` in the free space, or None if none exists.

    Parameters
    ----------
    space : AgentSpace
    start, goal : (2,) float
        Metres.
    quad_segs : int
        Vertices per quarter circle of the inflated corners.

    Raises
    ------
    PlanningError
        Where ``start`` or ``goal`` is not two finite numbers (one that lies in no free space has
        no path: None).
    """
    s, g = np.array(as_point(start, "start")), np.array(as_point(goal, "goal"))
    region = free_region(space, quad_segs)
    shapely.prepare(region)
    if not (shapely.intersects_xy(region, *s) and shapely.intersects_xy(region, *g)):
        return None
    if shapely.covers(region, shapely.LineString([s, g])):
        return ShortestPath(np.stack([s, g]), float(np.linalg.norm(g - s)), 2, 1)
    v, prev, nxt = _reflex_vertices(region)
    pts = np.concatenate([v, s[None], g[None]])
    n = len(pts)
    # start and goal take any direction: their "neighbours" are themselves (zero cross products).
    prev = np.concatenate([prev, s[None], g[None]])
    nxt = np.concatenate([nxt, s[None], g[None]])
    rows, cols = [], []
    ii, jj = np.triu_indices(n, k=1)
    for k in range(0, len(ii), _PAIR_BLOCK):
        i, j = ii[k : k + _PAIR_BLOCK], jj[k : k + _PAIR_BLOCK]
        d = pts[j] - pts[i]
        ok = _tangent(d, pts[i], prev[i], nxt[i]) & _tangent(d, pts[j], prev[j], nxt[j])
        rows.append(i[ok])
        cols.append(j[ok])
    i, j = np.concatenate(rows), np.concatenate(cols)
    lines = shapely.linestrings(np.stack([pts[i], pts[j]], axis=1))
    seen = shapely.covers(region, lines)
    i, j = i[seen], j[seen]
    w = np.linalg.norm(pts[j] - pts[i], axis=1)
    graph = scipy.sparse.coo_matrix((w, (i, j)), shape=(n, n)).tocsr()
    dist, pred = scipy.sparse.csgraph.dijkstra(graph, directed=False, indices=n - 2, return_predecessors=True)
    if not np.isfinite(dist[n - 1]):
        return None
    order = [n - 1]
    while order[-1] != n - 2:
        order.append(int(pred[order[-1]]))
    path = pts[order[::-1]]
    return ShortestPath(path, float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1))), n, int(len(i)))


def _tangent(d: np.ndarray, p: np.ndarray, prev: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    """Whether the line through p along d leaves both ring neighbours of p on one side."""
    a = d[:, 0] * (prev[:, 1] - p[:, 1]) - d[:, 1] * (prev[:, 0] - p[:, 0])
    b = d[:, 0] * (nxt[:, 1] - p[:, 1]) - d[:, 1] * (nxt[:, 0] - p[:, 0])
    return a * b >= -1e-12


def _reflex_vertices(region: shapely.Geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices of the region's rings where the free side turns by more than 180 degrees.

    Returns
    -------
    v, prev, next : (m, 2) float64
        The vertices and their neighbours along the ring.
    """
    out_v, out_p, out_n = [np.zeros((0, 2))], [np.zeros((0, 2))], [np.zeros((0, 2))]
    for poly in shapely.get_parts(region):
        if not isinstance(poly, shapely.Polygon) or poly.is_empty:
            continue
        poly = orient(poly, sign=1.0)  # free side on the left of every ring
        for ring in [poly.exterior, *poly.interiors]:
            c = np.asarray(ring.coords)[:-1]
            if len(c) < 3:
                continue
            p, q = np.roll(c, 1, axis=0), np.roll(c, -1, axis=0)
            turn = (c[:, 0] - p[:, 0]) * (q[:, 1] - c[:, 1]) - (c[:, 1] - p[:, 1]) * (q[:, 0] - c[:, 0])
            r = turn < -1e-12
            out_v.append(c[r])
            out_p.append(p[r])
            out_n.append(q[r])
    return np.concatenate(out_v), np.concatenate(out_p), np.concatenate(out_n)
