"""Where a user may be and move: outside the (clearance-grown) building footprints, inside the
receiver-grid bounds and, when a data set is given, at points with coverage.

All queries are vectorised: points and segments go to shapely's STRtree in one call.
"""

from __future__ import annotations

from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
import shapely

from ..dataset.store import nearest_index
from .errors import TrajectoryError

if TYPE_CHECKING:
    from ..dataset import Dataset
    from ..scene import ReceiverGrid, Scene

__all__ = ["FreeSpace", "CoverageMask", "nearest_grid_index"]

nearest_grid_index = nearest_index
"""(...,) int64 flat index (ix + nx iy) of the grid point nearest to each (..., 2) position
(the data set's own lookup, :meth:`mmwsim.dataset.Dataset.nearest`)."""


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
            raise TrajectoryError(f"validity mask has {valid.size} entries, the grid {grid.size}")
        self.grid = grid
        self.valid = valid

    @classmethod
    def from_dataset(cls, dataset: Dataset) -> CoverageMask:
        """The data set's validity mask (outdoors and detected) on its grid."""
        return cls(dataset.grid, dataset.valid)

    def nearest_index(self, points: np.ndarray) -> np.ndarray:
        """(n,) int64 index of the nearest grid point of each (n, 2) position (clipped to the grid)."""
        return nearest_grid_index(self.grid, points)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: whether the nearest grid point of each (n, 2) position is valid."""
        return self.valid[self.nearest_index(points)]


class FreeSpace:
    """The 2D area users may occupy.

    Parameters
    ----------
    footprints : list of shapely.Polygon
        Building footprints (``Scene.footprints``).
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
        footprints: list[shapely.Polygon],
        bounds: np.ndarray,
        clearance: float = 0.0,
        coverage: CoverageMask | None = None,
        name: str = "scene",
    ):
        b = np.asarray(bounds, dtype=np.float64).reshape(2, 2)
        if not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
            raise TrajectoryError(f"{name}: the area bounds {b.tolist()} are empty")
        if not (np.isfinite(clearance) and clearance >= 0):
            raise TrajectoryError(f"clearance must be >= 0 m, got {clearance!r}")
        self.bounds = b
        self.clearance = float(clearance)
        self.coverage = coverage
        self.name = name
        polys = list(footprints)
        if clearance > 0 and polys:
            # Square joins/caps: the grown footprint contains every point within `clearance`
            # (a round buffer is polygonised and would cut corners slightly).
            polys = list(shapely.buffer(np.array(polys, dtype=object), clearance, join_style="mitre"))
        self.obstacles = polys
        self.tree = shapely.STRtree(polys)

    @classmethod
    def from_scene(
        cls, scene: Scene, clearance: float = 0.0, coverage: CoverageMask | None = None
    ) -> FreeSpace:
        """Free space of ``scene`` within its receiver-grid bounds."""
        return cls(
            scene.footprints, scene.receivers.bounds, clearance, coverage, name=f"scene {scene.name!r}"
        )

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
            raise TrajectoryError(f"{self.name}: no free area to place users in (everything is built up)")
        if self.coverage is not None and not self.coverage.valid.any():
            raise TrajectoryError(f"{self.name}: the data set has no valid (covered) receiver point")
        frac = self.area / float(np.prod(self.bounds[1] - self.bounds[0]))
        for _ in range(max_rounds):
            m = int(min(4 * n, (n - have) / max(frac, 1e-3) * 1.3 + 16))
            p = rng.uniform(self.bounds[0], self.bounds[1], size=(m, 2))
            p = p[self.points_ok(p)][: n - have]
            out[have : have + len(p)] = p
            have += len(p)
            if have == n:
                return out
        raise TrajectoryError(
            f"{self.name}: could not find {n} valid start points (too little free, covered area)"
        )
