"""A street network derived from a scene's free space: the medial axis of the open area between
the buildings, kept where the street is wide enough for a vehicle, as a graph of centre lines
(or, for a scene that carries its streets, e.g. an OpenStreetMap extract, those centre lines).

The medial axis comes from the Voronoi diagram of points spaced along the footprint outlines
(its edges are equidistant from two outline points); edges closer than ``half_width`` to a
building are dropped, short dead-end spurs (towards recesses between buildings) are pruned, and
the largest connected part is kept. Vehicles then drive along the centre lines (see
:func:`mmwsim.trajectories.generate`), choosing a random onward street at every junction.
"""

from __future__ import annotations

from collections import OrderedDict
from functools import cached_property

import numpy as np
import shapely
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from .errors import TrajectoryError

__all__ = ["STREET_HALF_WIDTH", "StreetNetwork", "segment_feet"]

STREET_HALF_WIDTH = 4.0  # metres of clearance a centre line keeps from the buildings, by default
_POINTS = 4096  # points per nearest-edge search (points x edges float64 arrays)
# Bytes of ways_from's results kept per network: a route smoother asks for the same few nodes for
# every driver near them, and scipy's search costs 0.4 ms a call however near the limit is.
_WAYS_KEPT_BYTES = 64 << 20


def segment_feet(points: np.ndarray, a: np.ndarray, ab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where every point's foot lies on every segment ``a + [0, 1] ab``.

    Parameters
    ----------
    points : (n, 2) float
        Metres.
    a, ab : (e, 2) float
        The segments' first ends and their vectors to the second, metres.

    Returns
    -------
    share : (n, e) float64
        The foot's share along the segment, in [0, 1].
    distance : (n, e) float64
        Metres from the point to its foot.
    """
    share = np.clip(((points[:, None] - a) * ab).sum(-1) / np.maximum((ab**2).sum(-1), 1e-18), 0.0, 1.0)
    return share, np.linalg.norm(points[:, None] - (a + share[..., None] * ab), axis=-1)


class StreetNetwork:
    """Street centre lines as an undirected graph.

    Parameters
    ----------
    nodes : (m, 2) float64
        Node positions, metres.
    edges : (e, 2) int64
        Node index pairs of the straight centre-line pieces.
    """

    def __init__(self, nodes: np.ndarray, edges: np.ndarray):
        self.nodes = np.asarray(nodes, dtype=np.float64).reshape(-1, 2)
        self.edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        if len(self.edges) == 0:
            raise TrajectoryError("the street network is empty: no street is wide enough for vehicles")
        self.edge_length = np.linalg.norm(self.nodes[self.edges[:, 1]] - self.nodes[self.edges[:, 0]], axis=1)
        deg = np.bincount(self.edges.ravel(), minlength=len(self.nodes))
        self.degree = deg
        # Padded neighbour table for vectorised walks: row i lists i's neighbours, -1 after.
        nbr = np.full((len(self.nodes), max(int(deg.max()), 1)), -1, dtype=np.int64)
        both = np.concatenate([self.edges, self.edges[:, ::-1]])
        both = both[np.lexsort((both[:, 1], both[:, 0]))]
        first = np.searchsorted(both[:, 0], both[:, 0])
        nbr[both[:, 0], np.arange(len(both)) - first] = both[:, 1]
        self.neighbours = nbr
        self._ways: OrderedDict[tuple[int, float], tuple[np.ndarray, np.ndarray]] = OrderedDict()

    @property
    def total_length(self) -> float:
        """Summed length of the centre lines, metres."""
        return float(self.edge_length.sum())

    def nearest_edges(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The edge nearest to every ``points (..., 2)`` (metres) and the distance to it, both
        ``(...)``; searched in chunks, so a city's thousands of edges cost no points x edges
        array of all points at once."""
        flat = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        edge, dist = np.empty(len(flat), np.int64), np.empty(len(flat))
        a = self.nodes[self.edges[:, 0]]
        ab = self.nodes[self.edges[:, 1]] - a
        for lo in range(0, len(flat), _POINTS):
            d = segment_feet(flat[lo : lo + _POINTS], a, ab)[1]
            edge[lo : lo + _POINTS] = d.argmin(1)
            dist[lo : lo + _POINTS] = d[np.arange(len(d)), edge[lo : lo + _POINTS]]
        shape = np.shape(points)[:-1]
        return edge.reshape(shape), dist.reshape(shape)

    def lines(self) -> np.ndarray:
        """(e, 2, 2) float64 end points of every edge (for drawing and tests)."""
        return self.nodes[self.edges]

    @classmethod
    def from_footprints(
        cls,
        footprints: list[shapely.Polygon],
        bounds: np.ndarray,
        half_width: float = STREET_HALF_WIDTH,
        spacing: float = 2.0,
        spur_length: float = 20.0,
        simplify: float = 0.3,
    ) -> StreetNetwork:
        """Derive the network from building footprints.

        Parameters
        ----------
        footprints : list of shapely.Polygon
            Building footprints.
        bounds : (2, 2) float
            Area [[xmin, ymin], [xmax, ymax]], metres.
        half_width : float
            Minimum distance of a centre line from any building, metres.
        spacing : float
            Spacing of the outline points of the Voronoi diagram, metres.
        spur_length : float
            Dead ends shorter than this (and not at the area's edge) are pruned, metres.
        simplify : float
            Tolerance for straightening the centre lines, metres.
        """
        b = np.asarray(bounds, dtype=np.float64).reshape(2, 2)
        if not footprints:
            raise TrajectoryError("no buildings, hence no streets: drive off-network instead")
        if not (half_width > 0 and spacing > 0 and spur_length >= 0 and simplify >= 0):
            raise TrajectoryError("street network: half_width and spacing must be > 0")
        box = shapely.box(*b.ravel())
        union = shapely.union_all(footprints)
        pts = shapely.get_coordinates(shapely.segmentize(union.boundary, spacing))
        edges = shapely.get_parts(
            shapely.voronoi_polygons(shapely.multipoints(pts), only_edges=True, extend_to=box)
        )
        edges = shapely.intersection(edges, box)
        edges = edges[(shapely.get_type_id(edges) == 1) & (shapely.length(edges) > 1e-9)]
        edges = edges[shapely.distance(edges, union) >= half_width]
        if len(edges) == 0:
            raise TrajectoryError(f"no street is wider than {2 * half_width:g} m: no network for vehicles")
        lines = shapely.get_parts(shapely.line_merge(shapely.multilinestrings(edges)))
        lines = _prune_spurs(lines, box, spur_length)
        if simplify > 0:
            lines = shapely.simplify(lines, simplify, preserve_topology=True)
        return cls._from_lines(lines)

    @classmethod
    def from_scene(
        cls, scene, half_width: float = STREET_HALF_WIDTH, bounds: np.ndarray | None = None, **kw
    ) -> StreetNetwork:
        """Network of ``scene`` within ``bounds`` (default its receiver-grid bounds).

        A scene that carries street centre lines (``street_lines``, e.g. the highways of an
        OpenStreetMap extract) uses them (:meth:`from_lines`); others derive them from the free
        space (:meth:`from_footprints`).
        """
        bounds = scene.receivers.bounds if bounds is None else bounds
        lines = getattr(scene, "street_lines", None)
        if lines is not None:
            return cls.from_lines(lines, scene.footprints, bounds, half_width)
        return cls.from_footprints(scene.footprints, bounds, half_width, **kw)

    @classmethod
    def from_lines(
        cls,
        lines: list[np.ndarray],
        footprints: list[shapely.Polygon],
        bounds: np.ndarray,
        half_width: float = STREET_HALF_WIDTH,
    ) -> StreetNetwork:
        """Network of given centre lines (ways meeting at shared vertices connect there).

        Parameters
        ----------
        lines : list of (k, 2) float
            Polylines, metres.
        footprints : list of shapely.Polygon
            Buildings; centre lines closer than ``half_width`` to one are cut away.
        bounds : (2, 2) float
            Area [[xmin, ymin], [xmax, ymax]], metres.
        half_width : float
            Minimum distance of a centre line from any building, metres.
        """
        if not half_width > 0:
            raise TrajectoryError("street network: half_width must be > 0")
        geoms = [shapely.LineString(p) for p in lines if len(p) >= 2]
        if not geoms:
            raise TrajectoryError("the scene has no street centre lines for vehicles")
        free = shapely.box(*np.asarray(bounds, dtype=np.float64).ravel())
        if footprints:
            free = free.difference(shapely.union_all(footprints).buffer(half_width))
        cut = shapely.get_parts(shapely.intersection(np.array(geoms, dtype=object), free))
        cut = cut[(shapely.get_type_id(cut) == 1) & (shapely.length(cut) > 1e-9)]
        if len(cut) == 0:
            raise TrajectoryError(f"no street centre line is {half_width:g} m clear of the buildings")
        return cls._from_lines(cut)

    @classmethod
    def from_segments(cls, segments: np.ndarray) -> StreetNetwork:
        """Network of straight centre-line pieces ``segments (e, 2, 2)`` metres, as :meth:`lines`
        gives them: pieces meeting at an end point (to 1e-6 m) connect there, and the largest
        connected part is kept, so ``from_segments(net.lines())`` is ``net`` again."""
        s = np.asarray(segments, dtype=np.float64)
        if s.ndim != 3 or s.shape[1:] != (2, 2) or len(s) == 0:
            raise TrajectoryError(f"street segments must have shape (e >= 1, 2, 2), got {s.shape}")
        if not np.isfinite(s).all():
            raise TrajectoryError("street segments hold NaN or infinite coordinates")
        return cls._from_lines(shapely.linestrings(s))

    @classmethod
    def _from_lines(cls, lines: np.ndarray) -> StreetNetwork:
        coords, which = shapely.get_coordinates(lines, return_index=True)
        key = np.round(coords, 6)
        nodes, inverse = np.unique(key, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        same = which[1:] == which[:-1]
        e = np.column_stack([inverse[:-1][same], inverse[1:][same]])
        e = e[e[:, 0] != e[:, 1]]
        e = np.unique(np.sort(e, axis=1), axis=0)
        if len(e) == 0:
            raise TrajectoryError("the street network is empty: no street is wide enough for vehicles")
        adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(nodes), len(nodes)))
        _, label = connected_components(adj, directed=False)
        sizes = np.bincount(label[e[:, 0]], minlength=label.max() + 1)
        keep_nodes = np.flatnonzero(label == np.argmax(sizes))
        remap = np.full(len(nodes), -1)
        remap[keep_nodes] = np.arange(len(keep_nodes))
        e = remap[e]
        e = e[(e >= 0).all(axis=1)]
        return cls(nodes[keep_nodes], e)

    # ------------------------------------------------------------------ routes
    @cached_property
    def _graph(self) -> csr_matrix:
        n = len(self.nodes)
        return coo_matrix((self.edge_length, (self.edges[:, 0], self.edges[:, 1])), shape=(n, n)).tocsr()

    def ways_from(self, node: int, limit: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Shortest ways along the streets from ``node`` to every node.

        Searched only within ``limit`` metres, so that a large city's graph costs no all-pairs
        table; the results of the last calls are kept (read-only arrays).

        Returns
        -------
        length : (m,) float64
            Metres to every node; infinite beyond ``limit`` or where no way leads.
        predecessor : (m,) int32
            The node before each on its way from ``node`` (negative where none).
        """
        key = (int(node), float(limit))
        found = self._ways.get(key)
        if found is not None:
            self._ways.move_to_end(key)
            return found
        length, pred = dijkstra(
            self._graph, directed=False, indices=key[0], return_predecessors=True, limit=limit
        )
        length.flags.writeable = pred.flags.writeable = False  # shared by every caller
        self._ways[key] = (length, pred)
        while len(self._ways) > max(1, _WAYS_KEPT_BYTES // (12 * len(self.nodes))):  # least recent first
            self._ways.popitem(last=False)
        return length, pred

    def onward(self, cur: np.ndarray, prev: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The node after ``cur (n,)`` for drivers coming from ``prev (n,)``: of ``cur``'s
        neighbours other than ``prev``, the one ``u (n,)`` (uniform numbers in [0, 1)) picks, each
        with equal probability; ``prev`` at a dead end."""
        cand = self.neighbours[cur]
        ok = (cand >= 0) & (cand != prev[:, None])
        count = ok.sum(axis=1)
        pick = np.floor(u * np.maximum(count, 1)).astype(np.int64)
        col = np.argmax(np.cumsum(ok, axis=1) > pick[:, None], axis=1)
        return np.where(count > 0, cand[np.arange(len(cur)), col], prev)

    def random_routes(
        self, n: int, distance: np.ndarray, rng: np.random.Generator, max_pieces: int = 10_000
    ) -> tuple[np.ndarray, np.ndarray]:
        """Random drives: start anywhere on the network (uniform by length), then at every node take
        a random onward edge (never straight back unless at a dead end).

        Parameters
        ----------
        n : int
            Number of routes.
        distance : (n,) float
            Length each route must reach, metres.
        rng : numpy.random.Generator

        Returns
        -------
        points : (n, R, 2) float64
            Route vertices, metres; the first is the start.
        arc : (n, R) float64
            Arc length at every vertex, metres (non-decreasing, starts at 0).
        """
        need = np.broadcast_to(np.asarray(distance, dtype=np.float64), (n,))
        e = rng.choice(len(self.edges), size=n, p=self.edge_length / self.edge_length.sum())
        flip = rng.random(n) < 0.5
        prev = np.where(flip, self.edges[e, 1], self.edges[e, 0])
        cur = np.where(flip, self.edges[e, 0], self.edges[e, 1])
        t = rng.random(n)
        start = self.nodes[prev] + t[:, None] * (self.nodes[cur] - self.nodes[prev])
        pts = [start, self.nodes[cur]]
        arcs = [np.zeros(n), (1.0 - t) * self.edge_length[e]]
        for _ in range(max_pieces):
            if np.all(arcs[-1] >= need):
                break
            nxt = self.onward(cur, prev, rng.random(n))
            step = np.linalg.norm(self.nodes[nxt] - self.nodes[cur], axis=1)
            pts.append(self.nodes[nxt])
            arcs.append(arcs[-1] + step)
            prev, cur = cur, nxt
        return np.stack(pts, axis=1), np.stack(arcs, axis=1)


def _prune_spurs(lines: np.ndarray, box: shapely.Polygon, spur_length: float) -> np.ndarray:
    """Drop short dead-end chains that do not end at the area's edge, until none is left."""
    edge = box.exterior
    for _ in range(20):
        if len(lines) <= 1:
            return lines
        ends = np.stack([shapely.get_coordinates(shapely.get_point(lines, i)) for i in (0, -1)], axis=1)
        key = np.round(ends.reshape(-1, 2), 6)
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        leaf = (counts[inv.reshape(-1)] == 1).reshape(-1, 2)
        at_edge = (shapely.distance(shapely.points(ends.reshape(-1, 2)), edge) < 1.0).reshape(-1, 2)
        dead = (leaf & ~at_edge).any(axis=1)
        drop = (
            dead & (shapely.length(lines) < spur_length) & ~(leaf.all(axis=1) & (shapely.length(lines) > 0))
        )
        # An isolated piece (both ends leaves) is left to the largest-component filter.
        if not drop.any():
            return lines
        lines = shapely.get_parts(shapely.line_merge(shapely.multilinestrings(lines[~drop])))
    return lines
