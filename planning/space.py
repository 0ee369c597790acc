"""The space of a disc-shaped agent in the plane of a scene, and its exact and fast tests.

The agent is a vertical cylinder of radius ``radius`` and height ``height`` standing ``lift``
above the scene's lowest point. A state (x, y) is valid when it lies in the planning region
(the scene's extent, cut to the corridor's bounds when there is one), inside the corridor
polygon when there is one, outside every building footprint, and the cylinder there touches
no building or other non-ground triangle (FCL). A motion is valid when the volume the
cylinder sweeps along the straight step, a box of the step's length and width ``2 radius``
plus a cylinder at each end, touches no triangle (FCL), stays in the region and the corridor,
and does not end inside a footprint.

Those exact tests cost microseconds each through Python, so a conservative certificate
answers first: a raster of lower bounds on the clearance margin

    m(p) = min(d_obstacles(p) - radius, distance to the corridor's outside, distance to the region's edge)

sampled at nodes ``resolution`` apart. ``m`` is 1-Lipschitz, so ``m(p) >= M[node] - |p - node|``
and a disc of that radius around ``p`` is valid; a motion is walked in such safe strides and
is certified in one or two look-ups in open streets. Only where the bound cannot prove
validity (within about a raster step of an obstacle or corridor edge) is the exact FCL test
run. The obstacles of the 2D map are those of the scene's free space
(:func:`mmwsim.geometry.scene_obstacles`, the same the trajectories avoid): the building footprints
(solid prisms) and the parts of other non-ground triangles within the agent's height range, so the
certificate never passes what FCL would reject. What is the planner's own: the agent radius, the
clearance raster and the FCL tests.
"""

from __future__ import annotations

import math
from array import array

import fcl
import numpy as np
import shapely

from mmwsim.geometry.freespace import AGENT_HEIGHT, AGENT_LIFT, scene_obstacles
from mmwsim.scene import Scene

from .corridor import Corridor
from .errors import PlanningError

__all__ = ["AgentSpace"]

# Margins below this (metres) are left to the exact test rather than walked in tiny strides.
_MIN_STRIDE = 1e-3
_MAX_STRIDES = 64
_MAX_NODES = 1 << 23


def as_point(point, what: str) -> tuple[float, float]:
    """``point`` as ``(x, y)`` metres, or a one-line :class:`PlanningError` naming ``what`` where it
    is not two finite numbers."""
    try:
        p = np.asarray(point, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        p = np.zeros(0)
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        raise PlanningError(f"{what} must be two finite numbers X,Y, got {point!r}")
    return float(p[0]), float(p[1])


class AgentSpace:
    """Valid states and motions of a cylinder agent among a scene's buildings.

    Parameters
    ----------
    scene : Scene
    radius : float
        Agent radius, metres (default 0.5).
    corridor : Corridor, optional
        Restricts the agent's centre to the corridor polygon.
    resolution : float
        Node spacing of the clearance raster, metres; finer means fewer exact tests and a
        longer set-up. Coarsened so that the raster holds at most 2^23 nodes.
    height, lift : float
        Agent height and its clearance above the scene's lowest point, metres.
    reach : float
        Largest margin stored in the raster, metres; longer than a planner step is enough.

    Attributes
    ----------
    bounds : (2, 2) float64
        Planning region [[xmin, ymin], [xmax, ymax]], metres.
    obstacles : list of shapely geometries
        The 2D obstacle map: footprints and projected slab cuts of other triangles.
    """

    def __init__(
        self,
        scene: Scene,
        radius: float = 0.5,
        corridor: Corridor | None = None,
        resolution: float = 0.25,
        height: float = AGENT_HEIGHT,
        lift: float = AGENT_LIFT,
        reach: float = 10.0,
    ):
        for name, v in (("radius", radius), ("resolution", resolution), ("height", height), ("reach", reach)):
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise PlanningError(f"agent {name} must be a positive number of metres, got {v!r}")
        if not (math.isfinite(lift) and lift >= 0):
            raise PlanningError(f"agent lift must be a non-negative number of metres, got {lift!r}")
        self.scene = scene
        self.radius = float(radius)
        self.corridor = corridor
        self.resolution = float(resolution)
        self.height = float(height)
        lo, hi = scene.extent
        self.z0 = float(lo[2]) + float(lift)
        self.z1 = self.z0 + self.height
        box = np.array([lo[:2], hi[:2]], dtype=np.float64)
        if corridor is not None:
            cx0, cy0, cx1, cy1 = corridor.polygon.bounds
            box = np.array([np.maximum(box[0], (cx0, cy0)), np.minimum(box[1], (cx1, cy1))])
            if np.any(box[1] <= box[0]):
                raise PlanningError("the corridor lies outside the scene")
        if np.any(box[1] <= box[0]):
            raise PlanningError(f"scene {scene.name!r} has no extent in the plane")
        self.bounds = box
        footprints = list(scene.footprints)
        self._footprints = shapely.union_all(footprints) if footprints else None
        if self._footprints is not None:
            shapely.prepare(self._footprints)
        self.obstacles = scene_obstacles(scene, lift, self.height)
        self._reach = float(reach)
        self._build_raster()
        solid = any(o.kind != "ground" and len(o.mesh.faces) for o in scene.objects)
        self._collision = scene.collision_model if solid and scene.collision_model.n_faces else None
        self._zc = 0.5 * (self.z0 + self.z1)
        self._cylinder = fcl.CollisionObject(fcl.Cylinder(self.radius, self.height), fcl.Transform())
        self._request = fcl.CollisionRequest()
        self.stats = {"states": 0, "states_exact": 0, "motions": 0, "motions_exact": 0}

    # ------------------------------------------------------------------ raster
    def _build_raster(self) -> None:
        (x0, y0), (x1, y1) = self.bounds
        # Large regions get a coarser raster rather than an unbounded one (the bound stays exact).
        h = max(self.resolution, math.sqrt((x1 - x0) * (y1 - y0) / _MAX_NODES))
        self.resolution = h
        nx = int(math.floor((x1 - x0) / h)) + 1
        ny = int(math.floor((y1 - y0) / h)) + 1
        xs = x0 + h * np.arange(nx)
        ys = y0 + h * np.arange(ny)
        cap = self._reach + self.radius
        d_obs = _distance_to_segments(_boundary_segments(self.obstacles), xs, ys, cap)
        # Depth inside a footprint proves a point is inside a building (an invalid end of a step).
        depth = np.full(d_obs.shape, -1.0)
        if self._footprints is not None:
            inside = _inside_mask(self._footprints, xs, ys)
            depth[inside] = d_obs[inside]
        polys = [g for g in self.obstacles if isinstance(g, shapely.Polygon | shapely.MultiPolygon)]
        if polys:
            d_obs[_inside_mask(shapely.union_all(polys), xs, ys)] = 0.0
        margin = d_obs - self.radius
        np.minimum(margin, self._reach, out=margin)
        edge = np.minimum.outer(np.minimum(xs - x0, x1 - xs), np.minimum(ys - y0, y1 - ys))
        np.minimum(margin, edge, out=margin)
        if self.corridor is not None:
            w = self.corridor.inner_width
            d_traj = _distance_to_segments(self.corridor.segments, xs, ys, w + h)
            np.minimum(margin, w - d_traj, out=margin)
        # float32 storage rounds; shave a little so that the bound stays a bound.
        self.margin = (margin - 1e-5).astype(np.float32)
        self._flat = array("f", self.margin.ravel().tobytes())
        self._depth = array("f", (depth - 1e-5).astype(np.float32).ravel().tobytes())
        self._grid = (float(x0), float(y0), h, 1.0 / h, nx, ny)

    # ------------------------------------------------------------------ queries
    def margin_at(self, x: float, y: float) -> float:
        """A lower bound (m) on how far the agent at (x, y) is from invalid; <= 0: no proof."""
        x0, y0, h, inv, nx, ny = self._grid
        i = int((x - x0) * inv + 0.5)
        j = int((y - y0) * inv + 0.5)
        if i < 0 or j < 0 or i >= nx or j >= ny:
            return -1.0
        return self._flat[i * ny + j] - math.hypot(x - (x0 + i * h), y - (y0 + j * h))

    def state_valid(self, x: float, y: float) -> bool:
        """Whether the agent at (x, y) is valid (certificate first, then the exact FCL test)."""
        self.stats["states"] += 1
        x0, y0, h, inv, nx, ny = self._grid
        i = int((x - x0) * inv + 0.5)
        j = int((y - y0) * inv + 0.5)
        if 0 <= i < nx and 0 <= j < ny:
            off = math.hypot(x - (x0 + i * h), y - (y0 + j * h))
            if self._flat[i * ny + j] - off > 0.0:
                return True
            if self._depth[i * ny + j] - off > 0.0:
                return False
        self.stats["states_exact"] += 1
        return self.exact_state_valid(x, y)

    def motion_valid(self, ax: float, ay: float, bx: float, by: float) -> bool:
        """Whether the straight motion from (ax, ay) to (bx, by) is valid, end points included."""
        self.stats["motions"] += 1
        x0, y0, h, inv, nx, ny = self._grid
        flat = self._flat
        dx, dy = bx - ax, by - ay
        length = math.hypot(dx, dy)
        t = 0.0
        for _ in range(_MAX_STRIDES):
            f = t / length if length > 0.0 else 0.0
            x, y = ax + dx * f, ay + dy * f
            i = int((x - x0) * inv + 0.5)
            j = int((y - y0) * inv + 0.5)
            if i < 0 or j < 0 or i >= nx or j >= ny:
                break
            m = flat[i * ny + j] - math.hypot(x - (x0 + i * h), y - (y0 + j * h))
            if m < _MIN_STRIDE:
                break
            t += m
            if t >= length:
                return True
        i = int((bx - x0) * inv + 0.5)
        j = int((by - y0) * inv + 0.5)
        if 0 <= i < nx and 0 <= j < ny:
            if self._depth[i * ny + j] - math.hypot(bx - (x0 + i * h), by - (y0 + j * h)) > 0.0:
                return False
        self.stats["motions_exact"] += 1
        return self.exact_motion_valid(ax, ay, bx, by)

    # ------------------------------------------------------------------ exact tests
    def in_region(self, x: float, y: float) -> bool:
        (x0, y0), (x1, y1) = self.bounds
        return x0 <= x <= x1 and y0 <= y <= y1

    def in_building(self, x: float, y: float) -> bool:
        """Whether (x, y) lies inside a building footprint."""
        return self._footprints is not None and bool(shapely.contains_xy(self._footprints, x, y))

    def in_corridor(self, x: float, y: float) -> bool:
        return self.corridor is None or bool(self.corridor.contains(np.array([[x, y]]))[0])

    def collides_at(self, x: float, y: float) -> bool:
        """FCL: whether the agent's cylinder at (x, y) touches a building or other triangle."""
        if self._collision is None:
            return False
        self._cylinder.setTransform(fcl.Transform(np.array([x, y, self._zc])))
        return fcl.collide(self._collision.object, self._cylinder, self._request, fcl.CollisionResult()) > 0

    def sweep_collides(self, ax: float, ay: float, bx: float, by: float) -> bool:
        """FCL: whether the volume swept by the cylinder from (ax, ay) to (bx, by) touches a triangle.

        The swept volume of a translated vertical cylinder is exactly a box of the step's length,
        ``2 radius`` wide, oriented along the step, plus the cylinder at both ends.
        """
        if self._collision is None:
            return False
        if self.collides_at(ax, ay) or self.collides_at(bx, by):
            return True
        dx, dy = bx - ax, by - ay
        length = math.hypot(dx, dy)
        if length == 0.0:
            return False
        half = 0.5 * math.atan2(dy, dx)
        quat = np.array([math.cos(half), 0.0, 0.0, math.sin(half)])
        centre = np.array([0.5 * (ax + bx), 0.5 * (ay + by), self._zc])
        box = fcl.CollisionObject(
            fcl.Box(length, 2.0 * self.radius, self.height), fcl.Transform(quat, centre)
        )
        return fcl.collide(self._collision.object, box, self._request, fcl.CollisionResult()) > 0

    def exact_state_valid(self, x: float, y: float) -> bool:
        """The authoritative state test: region, corridor, footprints, FCL."""
        return (
            self.in_region(x, y)
            and self.in_corridor(x, y)
            and not self.in_building(x, y)
            and not self.collides_at(x, y)
        )

    def exact_motion_valid(self, ax: float, ay: float, bx: float, by: float) -> bool:
        """The authoritative motion test: region (convex), corridor, footprints, FCL swept volume."""
        if not (self.in_region(ax, ay) and self.in_region(bx, by)):
            return False
        if self.corridor is not None and not self.corridor.covers_segment((ax, ay), (bx, by)):
            return False
        # FCL sees surfaces, not solids: a step wholly inside a building touches nothing.
        if self.in_building(bx, by) or self.in_building(ax, ay):
            return False
        return not self.sweep_collides(ax, ay, bx, by)

    def check_endpoint(self, point, what: str) -> tuple[float, float]:
        """Validate a start or goal position; a one-line :class:`PlanningError` names the problem.

        Returns
        -------
        (x, y) float, metres
        """
        x, y = as_point(point, what)
        at = f"{what} ({x:g}, {y:g})"
        lo, hi = self.scene.extent
        if not (lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1]):
            raise PlanningError(f"{at} is outside the scene (x {lo[0]:g}..{hi[0]:g}, y {lo[1]:g}..{hi[1]:g})")
        if self.in_building(x, y):
            raise PlanningError(f"{at} is inside a building")
        if not self.in_corridor(x, y) or not self.in_region(x, y):
            raise PlanningError(f"{at} is outside the corridor (width {self.corridor.width:g} m)")
        if not self.exact_state_valid(x, y):
            raise PlanningError(
                f"{at} is in collision: closer than the agent radius {self.radius:g} m to an obstacle"
            )
        return x, y

    def clear_nodes(self) -> np.ndarray:
        """(k, 2) float64 nodes of the clearance raster where the agent certainly fits (a margin of
        at least a tenth of its radius), metres."""
        clear = np.argwhere(self.margin > 0.1 * self.radius)  # raster node indices, x first
        return self.bounds[0] + self.resolution * clear

    def nearest_free_point(self, point) -> np.ndarray | None:
        """Where a planner can start or end closest to ``point``.

        Parameters
        ----------
        point : (2,) float, metres

        Returns
        -------
        (2,) float64 or None
            ``point`` itself when the agent may stand there (inside the corridor, clear of every
            obstacle), else the nearest of :meth:`clear_nodes`, else None (no free point in the
            region).
        """
        try:
            return np.array(self.check_endpoint(point, "point"), dtype=np.float64)
        except PlanningError:
            pass
        return self._extreme_node(point, nearest=True)

    def farthest_free_point(self, point) -> np.ndarray | None:
        """The one of :meth:`clear_nodes` farthest (straight-line) from ``point`` (2,) metres, or None."""
        return self._extreme_node(point, nearest=False)

    def _extreme_node(self, point, nearest: bool) -> np.ndarray | None:
        nodes = self.clear_nodes()
        if not len(nodes):
            return None
        d2 = ((nodes - np.asarray(point, dtype=np.float64)) ** 2).sum(axis=1)
        return nodes[int(np.argmin(d2) if nearest else np.argmax(d2))]

    def summary(self) -> str:
        """One line: region, raster and agent."""
        (x0, y0), (x1, y1) = self.bounds
        free = float(np.mean(self.margin > 0)) * 100
        c = self.corridor
        extra = f", corridor {c.width:g} m around {len(c.trajectories)} trajectories" if c is not None else ""
        return (
            f"free space x {x0:g}..{x1:g} y {y0:g}..{y1:g} m, agent radius {self.radius:g} m, "
            f"{len(self.obstacles)} obstacles, raster {self.margin.shape[0]} x {self.margin.shape[1]} at "
            f"{self.resolution:g} m ({free:.0f} % certified free){extra}"
        )


# ---------------------------------------------------------------------- helpers
def _boundary_segments(geoms: list) -> np.ndarray:
    """(n, 2, 2) float64 edges of the geometries' boundaries (a point gives a zero-length edge)."""
    segs = [np.zeros((0, 2, 2))]
    for g in geoms:
        if isinstance(g, shapely.Point):
            c = np.asarray(g.coords)
            segs.append(np.stack([c, c], axis=1))
            continue
        lines = (
            shapely.get_parts(g.boundary) if isinstance(g, shapely.Polygon | shapely.MultiPolygon) else [g]
        )
        for line in shapely.get_parts(np.asarray(lines, dtype=object)):
            c = np.asarray(line.coords)
            if len(c) >= 2:
                segs.append(np.stack([c[:-1], c[1:]], axis=1))
    return np.concatenate(segs)


def _distance_to_segments(segs: np.ndarray, xs: np.ndarray, ys: np.ndarray, cap: float) -> np.ndarray:
    """Euclidean distance from grid nodes to the nearest segment, capped at ``cap``.

    Parameters
    ----------
    segs : (n, 2, 2) float
    xs, ys : (nx,), (ny,) float
        Node coordinates (evenly spaced), metres.

    Returns
    -------
    (nx, ny) float64
    """
    d = np.full((len(xs), len(ys)), cap, dtype=np.float64)
    if len(segs) == 0:
        return d
    h = xs[1] - xs[0] if len(xs) > 1 else 1.0
    # Long segments are cut so that each one only touches a window of nodes near it.
    pieces = []
    for a, b in segs:
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / (4 * cap))))
        f = np.linspace(0.0, 1.0, n + 1)[:, None]
        pts = a + f * (b - a)
        pieces.append(np.stack([pts[:-1], pts[1:]], axis=1))
    for (ax, ay), (bx, by) in np.concatenate(pieces):
        i0 = max(0, int(math.floor((min(ax, bx) - cap - xs[0]) / h)))
        i1 = min(len(xs), int(math.ceil((max(ax, bx) + cap - xs[0]) / h)) + 1)
        j0 = max(0, int(math.floor((min(ay, by) - cap - ys[0]) / h)))
        j1 = min(len(ys), int(math.ceil((max(ay, by) + cap - ys[0]) / h)) + 1)
        if i0 >= i1 or j0 >= j1:
            continue
        px = xs[i0:i1, None] - ax
        py = ys[None, j0:j1] - ay
        ux, uy = bx - ax, by - ay
        ll = ux * ux + uy * uy
        t = np.clip((px * ux + py * uy) / ll, 0.0, 1.0) if ll > 0 else 0.0
        dist = np.hypot(px - t * ux, py - t * uy)
        np.minimum(d[i0:i1, j0:j1], dist, out=d[i0:i1, j0:j1])
    return d


def _inside_mask(region: shapely.Geometry, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """(nx, ny) bool: nodes strictly inside ``region``, tested only within each part's bounds."""
    mask = np.zeros((len(xs), len(ys)), dtype=bool)
    h = xs[1] - xs[0] if len(xs) > 1 else 1.0
    for part in shapely.get_parts(region):
        bx0, by0, bx1, by1 = part.bounds
        i0, i1 = np.searchsorted(xs, [bx0 - h, bx1 + h])
        j0, j1 = np.searchsorted(ys, [by0 - h, by1 + h])
        if i0 >= i1 or j0 >= j1:
            continue
        X, Y = np.meshgrid(xs[i0:i1], ys[j0:j1], indexing="ij")
        shapely.prepare(part)
        mask[i0:i1, j0:j1] |= shapely.contains_xy(part, X, Y)
    return mask
