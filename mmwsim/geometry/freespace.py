"""Where a user or an agent may be and move, in the plane of a scene: one model for the
trajectories, the demo and the planner.

The obstacles are the building footprints (solid prisms) and, of every other non-ground object,
the parts between ``lift`` and ``lift + height`` above the scene's lowest point projected onto the
plane (a wall without a roof, a fin): what a person-sized body standing on the ground would touch.
:class:`FreeSpace` keeps a clearance from them, stays within bounds and, given a data set's
coverage, at covered points. All queries are vectorised: points and segments go to shapely's
STRtree in one call. The planner adds its own agent radius, clearance raster and FCL tests on top
(:class:`planning.AgentSpace`).
"""

from __future__ import annotations

from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
import shapely

from ..errors import MmwsimError

if TYPE_CHECKING:
    from ..scene import ReceiverGrid, Scene

__all__ = ["AGENT_HEIGHT", "AGENT_LIFT", "CoverageMask", "FreeSpace", "scene_obstacles", "slab_cuts"]

AGENT_LIFT = 0.2
"""Clearance of a body above the scene's lowest point, metres: kerbs and ground steps below it."""
AGENT_HEIGHT = 1.8
"""Height of the body whose obstacles count, metres."""


def scene_obstacles(
    scene: Scene, lift: float = AGENT_LIFT, height: float = AGENT_HEIGHT
) -> list[shapely.Geometry]:
    """The 2D obstacles of ``scene``: its building footprints, then the projections of the parts of
    other non-ground triangles between ``lift`` and ``lift + height`` above its lowest point that
    the footprints do not already cover."""
    footprints = list(scene.footprints)
    z0 = float(scene.extent[0][2]) + float(lift)
    union = shapely.union_all(footprints) if footprints else None
    return footprints + slab_cuts(scene, z0, z0 + float(height), union)


def slab_cuts(scene: Scene, z0: float, z1: float, footprints) -> list[shapely.Geometry]:
    """Projections of the parts of non-ground triangles between heights z0 and z1.

    Buildings enter the map as their footprints (solid prisms); pieces already inside a
    footprint are dropped, so building triangles only add what the footprints miss (walls
    without a roof, fins).
    """
    idx = [i for i, o in enumerate(scene.objects) if o.kind != "ground"]
    sel = np.flatnonzero(np.isin(scene.face_object, idx))
    if len(sel) == 0:
        return []
    tri = scene.vertices[scene.faces[sel]]
    z = tri[:, :, 2]
    tri = tri[(z.max(axis=1) >= z0) & (z.min(axis=1) <= z1)]
    out = []
    covered = footprints.buffer(1e-6) if footprints is not None else None
    for t in tri:
        poly = _clip_z(_clip_z(list(t), z0, keep_above=True), z1, keep_above=False)
        if not poly:
            continue
        xy = np.array(poly)[:, :2]
        area2 = abs(np.dot(xy[:, 0], np.roll(xy[:, 1], -1)) - np.dot(xy[:, 1], np.roll(xy[:, 0], -1)))
        if area2 > 1e-9 and len(xy) >= 3:
            g = shapely.Polygon(xy)
        else:  # a vertical piece projects to a segment: keep its two farthest points
            d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
            a, b = np.unravel_index(np.argmax(d), d.shape)
            g = shapely.Point(xy[a]) if d[a, b] == 0 else shapely.LineString([xy[a], xy[b]])
        if covered is None or not covered.covers(g):
            out.append(g)
    return out


def _clip_z(poly: list, level: float, keep_above: bool) -> list:
    """Sutherland-Hodgman clip of a 3D polygon by the plane z = level."""
    out = []
    n = len(poly)
    for k in range(n):
        p, q = poly[k], poly[(k + 1) % n]
        pin = p[2] >= level if keep_above else p[2] <= level
        qin = q[2] >= level if keep_above else q[2] <= level
        if pin:
            out.append(p)
        if pin != qin:
            s = (level - p[2]) / (q[2] - p[2])
            out.append(p + s * (q - p))
    return out


class CoverageMask:
    """Validity of positions by their nearest point of a receiver grid.

    Parameters
    ----------
    grid : ReceiverGrid
        The data set's grid.
    valid : (grid.size,) bool
        Whether each grid point has coverage (index = ix + nx * iy).
    """

    def __init__(self, grid: ReceiverGrid, valid: np.ndarray):
        valid = np.asarray(valid, dtype=bool).reshape(-1)
        if valid.size != grid.size:
            raise MmwsimError(f"validity mask has {valid.size} entries, the grid {grid.size}")
        self.grid = grid
        self.valid = valid

    @classmethod
    def from_dataset(cls, dataset: Any) -> CoverageMask:
        """The validity mask (outdoors and detected) of a :class:`~mmwsim.dataset.Dataset` on its grid."""
        return cls(dataset.grid, dataset.valid)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: whether the nearest grid point of each (n, 2) position is valid."""
        return self.valid[self.grid.nearest_index(points)]


class FreeSpace:
    """The 2D area users and agents may occupy.

    Parameters
    ----------
    obstacles : list of shapely geometries
        What blocks the plane: building footprints and the parts of other objects within reach
        (:func:`scene_obstacles`).
    bounds : (2, 2) float
        [[xmin, ymin], [xmax, ymax]] the users stay within, metres.
    clearance : float
        Distance kept from every footprint, metres.
    coverage : CoverageMask, optional
        Positions must also have coverage (data-set validity).
    name : str
        Used in messages.
    """

    def __init__(
        self,
        obstacles: list[shapely.Geometry],
        bounds: np.ndarray,
        clearance: float = 0.0,
        coverage: CoverageMask | None = None,
        name: str = "scene",
    ):
        b = np.asarray(bounds, dtype=np.float64).reshape(2, 2)
        if not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
            raise MmwsimError(f"{name}: the area bounds {b.tolist()} are empty")
        if not (np.isfinite(clearance) and clearance >= 0):
            raise MmwsimError(f"clearance must be >= 0 m, got {clearance!r}")
        self.bounds = b
        self.clearance = float(clearance)
        self.coverage = coverage
        self.name = name
        polys = list(obstacles)
        if clearance > 0 and polys:
            # Square joins/caps: the grown footprint contains every point within `clearance`
            # (a round buffer is polygonised and would cut corners slightly).
            polys = list(shapely.buffer(np.array(polys, dtype=object), clearance, join_style="mitre"))
        self.obstacles = polys
        self.tree = shapely.STRtree(polys)

    @classmethod
    def from_scene(
        cls,
        scene: Scene,
        clearance: float = 0.0,
        coverage: CoverageMask | None = None,
        bounds: np.ndarray | None = None,
    ) -> FreeSpace:
        """Free space of ``scene`` (:func:`scene_obstacles`) within ``bounds``, by default its
        receiver-grid bounds."""
        area = scene.receivers.bounds if bounds is None else bounds
        return cls(scene_obstacles(scene), area, clearance, coverage, name=f"scene {scene.name!r}")

    @cached_property
    def area(self) -> float:
        """Free area (outside the grown footprints, within bounds), m^2; coverage not counted."""
        box = shapely.box(*self.bounds.ravel())
        if not self.obstacles:
            return float(box.area)
        return float(box.difference(shapely.union_all(self.obstacles)).area)

    # ------------------------------------------------------------------ queries
    def in_bounds(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        return np.all((p >= self.bounds[0]) & (p <= self.bounds[1]), axis=-1)

    def points_ok(self, points: np.ndarray) -> np.ndarray:
        """Whether each position may be occupied.

        Parameters
        ----------
        points : (n, 2) float, metres

        Returns
        -------
        (n,) bool
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        ok = self.in_bounds(p) & np.all(np.isfinite(p), axis=1)
        if self.obstacles and ok.any():
            idx = np.flatnonzero(ok)
            hit = self.tree.query(shapely.points(p[idx]), predicate="intersects")[0]
            ok[idx[hit]] = False
        if self.coverage is not None and ok.any():
            idx = np.flatnonzero(ok)
            ok[idx] = self.coverage(p[idx])
        return ok

    def segments_ok(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Whether each straight segment stays clear of every grown footprint and within bounds.

        Only the end points are checked for coverage (between two samples a user
        may cross a shadow; the bounds are convex, so the end points decide them).

        Parameters
        ----------
        start, end : (n, 2) float, metres

        Returns
        -------
        (n,) bool
        """
        a = np.asarray(start, dtype=np.float64).reshape(-1, 2)
        b = np.asarray(end, dtype=np.float64).reshape(-1, 2)
        ok = self.points_ok(a) & self.points_ok(b)
        if self.obstacles and ok.any():
            idx = np.flatnonzero(ok)
            moving = np.any(a[idx] != b[idx], axis=1)
            idx = idx[moving]  # a zero-length segment is its end point, already checked
            if len(idx):
                lines = shapely.linestrings(np.stack([a[idx], b[idx]], axis=1))
                hit = self.tree.query(lines, predicate="intersects")[0]
                ok[idx[hit]] = False
        return ok

    def sample(self, n: int, rng: np.random.Generator, max_rounds: int = 200) -> np.ndarray:
        """``n`` positions drawn uniformly from the free space (rejection sampling).

        Returns
        -------
        (n, 2) float64, metres
        """
        out = np.empty((n, 2))
        have = 0
        if n == 0:
            return out
        if self.area <= 0.0:
            raise MmwsimError(f"{self.name}: no free area to place users in (everything is built up)")
        if self.coverage is not None and not self.coverage.valid.any():
            raise MmwsimError(f"{self.name}: the data set has no valid (covered) receiver point")
        frac = self.area / float(np.prod(self.bounds[1] - self.bounds[0]))
        for _ in range(max_rounds):
            m = int(min(4 * n, (n - have) / max(frac, 1e-3) * 1.3 + 16))
            p = rng.uniform(self.bounds[0], self.bounds[1], size=(m, 2))
            p = p[self.points_ok(p)][: n - have]
            out[have : have + len(p)] = p
            have += len(p)
            if have == n:
                return out
        raise MmwsimError(
            f"{self.name}: could not find {n} valid start points (too little free, covered area)"
        )
