"""Manhattan-style city layouts: street plans, lots and extruded buildings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

__all__ = ["StreetPlan", "Building", "plan_buildings", "building_mesh", "ground_mesh"]


@dataclass(frozen=True)
class StreetPlan:
    """Free strips of a rectangular street grid.

    Parameters
    ----------
    size : (2,) float
        Extent in x and y from the origin, metres.
    avenues : list of (x0, x1)
        Streets running along y (constant x), metres.
    streets : list of (y0, y1)
        Streets running along x (constant y), metres.
    """

    size: tuple[float, float]
    avenues: tuple[tuple[float, float], ...]
    streets: tuple[tuple[float, float], ...]

    def blocks(self) -> list[tuple[float, float, float, float]]:
        """Rectangles (x0, y0, x1, y1) between the streets, row by row."""
        xs = _complement(self.avenues, self.size[0])
        ys = _complement(self.streets, self.size[1])
        return [(x0, y0, x1, y1) for (y0, y1) in ys for (x0, x1) in xs]


@dataclass(frozen=True)
class Building:
    """An extruded rectangle: (x0, y0, x1, y1) footprint and its height, metres."""

    x0: float
    y0: float
    x1: float
    y1: float
    height: float


def _complement(strips, length: float) -> list[tuple[float, float]]:
    out, cur = [], 0.0
    for a, b in sorted(strips):
        if a > cur:
            out.append((cur, a))
        cur = max(cur, b)
    if cur < length:
        out.append((cur, length))
    return [(a, b) for a, b in out if b - a >= 4.0]


def draw_height(rng: np.random.Generator, median: float, spread: float, lo: float, hi: float) -> float:
    """A building height from a log-normal distribution (median, log-spread), clipped, to 0.5 m."""
    return float(np.round(np.clip(median * np.exp(spread * rng.standard_normal()), lo, hi) * 2) / 2)


def plan_buildings(
    block: tuple[float, float, float, float],
    rng: np.random.Generator,
    median_height: float = 24.0,
    height_spread: float = 0.55,
    height_range: tuple[float, float] = (6.0, 150.0),
    lot_width: tuple[float, float] = (14.0, 36.0),
    gap_probability: float = 0.3,
    empty_probability: float = 0.08,
) -> list[Building]:
    """Fill one block with buildings on lots along its long side.

    Lots are drawn with widths in ``lot_width``; between some lots an alley of
    2-5 m is left, some lots stay empty, deep blocks are split into a front and a
    back row. Rectangles are rounded to 0.5 m so that the geometry is exact.
    """
    x0, y0, x1, y1 = block
    along_x = (x1 - x0) >= (y1 - y0)
    a0, a1, b0, b1 = (x0, x1, y0, y1) if along_x else (y0, y1, x0, x1)
    rows = [(b0, b1)]
    if b1 - b0 > 50.0 and rng.random() < 0.5:
        mid = np.round(rng.uniform(b0 + 0.4 * (b1 - b0), b0 + 0.6 * (b1 - b0)) * 2) / 2
        gap = float(np.round(rng.uniform(0.0, 6.0) * 2) / 2)
        rows = [(b0, mid - gap / 2), (mid + gap / 2, b1)]
    out: list[Building] = []
    for r0, r1 in rows:
        cur = a0
        while a1 - cur >= 6.0:
            width = float(np.round(rng.uniform(*lot_width) * 2) / 2)
            end = a1 if a1 - (cur + width) < lot_width[0] / 2 else cur + width
            if rng.random() >= empty_probability:
                h = draw_height(rng, median_height, height_spread, *height_range)
                if along_x:
                    out.append(Building(cur, r0, end, r1, h))
                else:
                    out.append(Building(r0, cur, r1, end, h))
            cur = end
            if rng.random() < gap_probability:
                cur += float(np.round(rng.uniform(2.0, 5.0) * 2) / 2)
    return [b for b in out if b.x1 - b.x0 >= 3.0 and b.y1 - b.y0 >= 3.0]


def building_mesh(buildings: list[Building]) -> trimesh.Trimesh:
    """Closed boxes with outward normals, one connected part per building."""
    boxes = []
    for b in buildings:
        extents = (b.x1 - b.x0, b.y1 - b.y0, b.height)
        center = ((b.x0 + b.x1) / 2, (b.y0 + b.y1) / 2, b.height / 2)
        boxes.append(trimesh.creation.box(extents, trimesh.transformations.translation_matrix(center)))
    return trimesh.util.concatenate(boxes)


def ground_mesh(x0: float, y0: float, x1: float, y1: float, z: float = 0.0) -> trimesh.Trimesh:
    """A horizontal rectangle of two triangles, normal up."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=np.float64)
    return trimesh.Trimesh(v, np.array([[0, 1, 2], [0, 2, 3]]), process=False)
