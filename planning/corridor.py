"""Corridors around estimated trajectories: the free space "sampled from the estimated trajectories".

A corridor is the union of discs of radius ``width`` swept along trajectory polylines, as a
polygon (shapely buffer with round joins). Its arcs are polygons with vertices on the circle,
so the polygon lies inside the exact swept set and contains every point closer than
``width * cos(pi / (4 * QUAD_SEGS))`` to a polyline.

Corridor files (:func:`load_corridor`):

- ``.csv``: a header with columns ``x,y`` and optionally ``trajectory`` (any label); rows of one
  trajectory are consecutive, in order along it. Without a ``trajectory`` column the file holds
  one trajectory.
- ``.json``: ``{"trajectories": [[[x, y], ...], ...]}`` or the bare list of trajectories.
- ``.npy``: a float array of shape (n, L, 2) or (L, 2), read without unpickling.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely

from .errors import PlanningError

__all__ = ["Corridor", "load_corridor", "save_corridor", "QUAD_SEGS"]

QUAD_SEGS = 8


@dataclass(frozen=True)
class Corridor:
    """Trajectory polylines and the corridor width around them.

    Parameters
    ----------
    trajectories : list of (L_i, 2) float64 arrays
        Polylines, metres; each with at least one point.
    width : float
        Half-width of the corridor: how far from a polyline the agent's centre may be, metres.
    """

    trajectories: tuple[np.ndarray, ...]
    width: float
    polygon: shapely.Geometry = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if not (math.isfinite(self.width) and self.width > 0):
            raise PlanningError(f"corridor width must be a positive number of metres, got {self.width!r}")
        trajs = tuple(_check_polyline(t, i) for i, t in enumerate(self.trajectories))
        if not trajs:
            raise PlanningError("a corridor needs at least one trajectory")
        object.__setattr__(self, "trajectories", trajs)
        parts = [_polyline_geometry(t).buffer(self.width, quad_segs=QUAD_SEGS) for t in trajs]
        poly = shapely.union_all(parts)
        shapely.prepare(poly)
        object.__setattr__(self, "polygon", poly)

    @classmethod
    def from_array(cls, positions: np.ndarray, width: float) -> Corridor:
        """From an array of shape (n, L, 2) or (L, 2), metres."""
        a = np.asarray(positions, dtype=np.float64)
        if a.ndim == 2:
            a = a[None]
        if a.ndim != 3 or a.shape[2] != 2 or a.shape[1] < 1:
            raise PlanningError(f"trajectories must have shape (n, L, 2) or (L, 2), got {a.shape}")
        return cls(tuple(a), width)

    @property
    def inner_width(self) -> float:
        """Every point closer than this to a polyline lies in :attr:`polygon`, metres."""
        return self.width * math.cos(math.pi / (4 * QUAD_SEGS))

    @property
    def segments(self) -> np.ndarray:
        """(n_segments, 2, 2) float64 polyline segments; a one-point trajectory gives a zero-length one."""
        segs = [
            np.stack([t[:-1], t[1:]], axis=1) if len(t) > 1 else t[[0, 0]][None] for t in self.trajectories
        ]
        return np.concatenate(segs)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Whether each of (n, 2) points lies in the corridor polygon (boundary included); (n,) bool."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return shapely.intersects_xy(self.polygon, p[:, 0], p[:, 1])

    def covers_segment(self, a: tuple[float, float], b: tuple[float, float]) -> bool:
        """Whether the segment from ``a`` to ``b`` lies wholly in the corridor polygon."""
        return bool(shapely.covers(self.polygon, shapely.LineString([a, b])))


def _check_polyline(t, i: int) -> np.ndarray:
    a = np.asarray(t, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2 or len(a) == 0:
        raise PlanningError(f"trajectory {i}: expected (L, 2) points, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise PlanningError(f"trajectory {i}: contains NaN or infinite coordinates")
    keep = np.ones(len(a), dtype=bool)
    keep[1:] = np.any(np.diff(a, axis=0) != 0, axis=1)
    return a[keep]


def _polyline_geometry(t: np.ndarray) -> shapely.Geometry:
    return shapely.Point(t[0]) if len(t) == 1 else shapely.LineString(t)


def load_corridor(path: str | Path, width: float) -> Corridor:
    """Read trajectory polylines from a ``.csv``, ``.json`` or ``.npy`` file (see the module docstring).

    Parameters
    ----------
    path : path-like
    width : float
        Corridor half-width, metres.
    """
    path = Path(path)
    if not path.is_file():
        raise PlanningError(f"{path}: corridor file not found")
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            trajs = _read_csv(path)
        elif suffix == ".json":
            data = json.loads(path.read_text())
            if isinstance(data, dict):
                if "trajectories" not in data:
                    raise PlanningError(f"{path}: JSON object has no key 'trajectories'")
                data = data["trajectories"]
            if not isinstance(data, list):
                raise PlanningError(f"{path}: expected a list of trajectories")
            trajs = [np.asarray(t, dtype=np.float64) for t in data]
        elif suffix == ".npy":
            arr = np.load(path, allow_pickle=False)
            if arr.dtype.kind not in "fiu":
                raise PlanningError(f"{path}: expected a numeric array, got dtype {arr.dtype}")
            return Corridor.from_array(arr, width)
        else:
            raise PlanningError(f"{path}: unsupported corridor format {suffix!r} (use .csv, .json or .npy)")
    except PlanningError:
        raise
    except (ValueError, TypeError, OSError, UnicodeDecodeError) as e:
        raise PlanningError(f"{path}: cannot read corridor: {str(e).splitlines()[0]}") from None
    try:
        return Corridor(tuple(trajs), width)
    except PlanningError as e:
        raise PlanningError(f"{path}: {e}") from None


def _read_csv(path: Path) -> list[np.ndarray]:
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise PlanningError(f"{path}: empty corridor file")
    header = [c.strip().lower() for c in rows[0]]
    if "x" not in header or "y" not in header:
        raise PlanningError(f"{path}: header must name columns x and y (and optionally trajectory)")
    ix, iy = header.index("x"), header.index("y")
    it = header.index("trajectory") if "trajectory" in header else None
    trajs: list[list[tuple[float, float]]] = []
    last = object()
    for n, r in enumerate(rows[1:], start=2):
        if len(r) != len(header):
            raise PlanningError(f"{path}: line {n} has {len(r)} fields, the header {len(header)}")
        try:
            xy = (float(r[ix]), float(r[iy]))
        except ValueError:
            raise PlanningError(f"{path}: line {n}: x and y must be numbers") from None
        ident = r[it].strip() if it is not None else None
        if not trajs or ident != last:
            trajs.append([])
            last = ident
        trajs[-1].append(xy)
    if not trajs:
        raise PlanningError(f"{path}: no trajectory points")
    return [np.asarray(t) for t in trajs]


def save_corridor(path: str | Path, trajectories: np.ndarray | list[np.ndarray]) -> None:
    """Write trajectories as a corridor CSV (``trajectory,x,y``), atomically."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial")
    with tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["trajectory", "x", "y"])
        for i, t in enumerate(trajectories):
            for x, y in np.asarray(t, dtype=np.float64).reshape(-1, 2):
                w.writerow([i, repr(float(x)), repr(float(y))])
    tmp.replace(path)
