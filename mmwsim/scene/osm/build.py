"""From OSM features to scene geometry: footprints cleaned, clipped and merged, ground, roads, streets.

Everything here is in the scene's frame (x east, y north, metres, origin at the area's south-west
corner). Footprints are repaired with ``shapely.make_valid`` when invalid (self-intersections),
skipped when degenerate (under :data:`MIN_FOOTPRINT_AREA`, or a top not above the base), clipped to
the area, snapped to a 1 cm grid so that neighbours sharing OSM nodes share exact coordinates, and
merged with :func:`.extrude.merge_prisms_closed`. A building outline that holds ``building:part``
areas keeps only what its parts leave uncovered (Simple 3D Buildings), unless a part rises above
it (see :func:`_outlines_with_parts`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely

from .area import OsmArea
from .extrude import merge_prisms_closed
from .read import OsmFeatures
from .tags import building_heights, building_material, drivable, road_width

__all__ = ["MIN_FOOTPRINT_AREA", "SNAP", "OsmGeometry", "build_geometry"]

MIN_FOOTPRINT_AREA = 1.0  # square metres
SNAP = 0.01  # metres
# Raised bases are lowered this much so that a part starting exactly where its neighbour ends
# overlaps it instead of meeting it along an edge alone (which no closed manifold mesh can have).
BASE_OVERLAP = 0.001  # metres


@dataclass
class OsmGeometry:
    """Meshes of an OSM area, ready to become scene objects.

    Attributes
    ----------
    objects : list of (name, kind, material, vertices (v, 3) float64, faces (f, 3) int64)
    street_lines : list of (k, 2) float64
        Centre lines of the drivable highways in the area, metres.
    stats : dict
        Counts: ``buildings_read``, ``in_area``, ``clipped``, ``repaired``, ``skipped``,
        ``outlines_trimmed`` and ``outlines_dropped`` (by their parts), ``broken`` (building ways
        near the area left out: not closed, or cut by the extract's edge),
        ``tagged_material``, ``blocks``, ``streets``.
    """

    objects: list[tuple[str, str, str, np.ndarray, np.ndarray]]
    street_lines: list[np.ndarray]
    stats: dict[str, int] = field(default_factory=dict)


def _to_frame(geoms: np.ndarray, area: OsmArea) -> np.ndarray:
    origin = area.origin

    def fn(c: np.ndarray) -> np.ndarray:
        x, y = area.project(c[:, 0], c[:, 1])
        return np.column_stack([x - origin[0], y - origin[1]])

    return shapely.transform(geoms, fn)


def _snap(g):
    """Coordinates on the :data:`SNAP` grid; the grid is not kept, so later overlays run in full precision."""
    return shapely.set_precision(shapely.set_precision(g, SNAP), 0.0)


def _polygonal(g):
    """The polygons of a geometry (collections from make_valid keep only their areas)."""
    parts = [p for p in shapely.get_parts(g) if isinstance(p, shapely.Polygon) and not p.is_empty]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


def _triangles_up(polys) -> tuple[np.ndarray, np.ndarray]:
    """Flat triangulation at z = 0 with normals up; returns vertices, faces."""
    tris = shapely.get_parts(shapely.constrained_delaunay_triangles(shapely.get_parts(polys)))
    tc = shapely.get_coordinates(shapely.get_exterior_ring(tris)).reshape(-1, 4, 2)[:, :3]
    cross = (tc[:, 1, 0] - tc[:, 0, 0]) * (tc[:, 2, 1] - tc[:, 0, 1]) - (tc[:, 2, 0] - tc[:, 0, 0]) * (
        tc[:, 1, 1] - tc[:, 0, 1]
    )
    tc = np.where((cross < 0)[:, None, None], tc[:, ::-1], tc)[np.abs(cross) > 1e-12]
    xy, inv = np.unique(tc.reshape(-1, 2), axis=0, return_inverse=True)
    return np.column_stack([xy, np.zeros(len(xy))]), inv.reshape(-1, 3).astype(np.int64)


def _near(geoms: np.ndarray, area: OsmArea) -> np.ndarray:
    """Indices of the geometries whose lon/lat bounds meet the area's (grown a little)."""
    w, s, e, n = area.lon_lat_bounds()
    b = shapely.bounds(geoms).reshape(-1, 4)
    return np.flatnonzero((b[:, 0] <= e) & (b[:, 2] >= w) & (b[:, 1] <= n) & (b[:, 3] >= s))


def _outlines_with_parts(g: np.ndarray, heights: np.ndarray, tags: list[dict], stats: dict):
    """Outlines (``building``) that hold parts (``building:part``).

    Simple 3D Buildings draws such an outline by its parts only, the outline's height being the
    tallest part's: then only what the parts leave uncovered keeps the outline's prism. Many
    extracts instead tag the outline with its own lower floors and map only a setback or a tower
    as a part above them (a part rising above the outline's top): that outline stays whole.
    """
    is_part = np.array([t.get("building:part", "no") != "no" for t in tags], dtype=bool)
    stats["outlines_trimmed"] = stats["outlines_dropped"] = 0
    if not is_part.any() or is_part.all():
        return g, heights, tags
    outline_idx = np.flatnonzero(~is_part)
    part_idx = np.flatnonzero(is_part)
    part_at, outline_at = shapely.STRtree(g[outline_idx]).query(
        shapely.point_on_surface(g[part_idx]), predicate="within"
    )
    keep = np.ones(len(g), dtype=bool)
    for k in np.unique(outline_at):
        i = outline_idx[k]
        parts = part_idx[part_at[outline_at == k]]
        if heights[parts, 1].max() > heights[i, 1]:
            continue  # the outline is the lower floors
        rest = _polygonal(shapely.difference(g[i], shapely.union_all(g[parts])))
        if rest is None or rest.area < MIN_FOOTPRINT_AREA:
            keep[i] = False
            stats["outlines_dropped"] += 1
        else:
            g[i] = rest
            stats["outlines_trimmed"] += 1
    return g[keep], heights[keep], [t for t, k in zip(tags, keep, strict=True) if k]


def _buildings(feat: OsmFeatures, area: OsmArea, box: shapely.Polygon, stats: dict):
    """Footprints in the frame, clipped and snapped, with base, top and material of each."""
    stats["buildings_read"] = len(feat.buildings)
    idx = [i for i in _near(feat.buildings, area) if feat.building_tags[i].get("location") != "underground"]
    g = _to_frame(feat.buildings[idx], area) if idx else np.empty(0, object)
    tags = [feat.building_tags[i] for i in idx]
    # bounds first: GEOS predicates may refuse an invalid polygon, so repair before any other test
    b = shapely.bounds(g).reshape(-1, 4)
    w, h = area.extent
    meets = (b[:, 0] <= w) & (b[:, 2] >= 0) & (b[:, 1] <= h) & (b[:, 3] >= 0)
    invalid = meets & ~shapely.is_valid(g) if len(g) else np.zeros(0, bool)
    for i in np.flatnonzero(invalid):
        g[i] = _polygonal(shapely.make_valid(g[i]))
    heights = np.array([building_heights(t) for t in tags]).reshape(-1, 2)
    good = meets & np.array([x is not None for x in g], dtype=bool) & (heights[:, 1] > heights[:, 0])
    good[good] = shapely.area(g[good].astype(object)) >= MIN_FOOTPRINT_AREA
    stats["skipped"] = int((meets & ~good).sum())
    ok = good.copy()
    ok[ok] = shapely.intersects(g[ok].astype(object), box)
    stats["repaired"] = int((invalid & ok).sum())
    g, heights, tags = g[ok].astype(object), heights[ok], [t for t, k in zip(tags, ok, strict=True) if k]

    g, heights, tags = _outlines_with_parts(g, heights, tags, stats)

    inside = shapely.within(g, box) if len(g) else np.zeros(0, bool)
    stats["clipped"] = int((~inside).sum())
    if len(g):
        g[~inside] = shapely.intersection(g[~inside], box)
        g = np.array([_polygonal(x) for x in _snap(g)], dtype=object)
    ok = np.array([x is not None for x in g], dtype=bool)
    g, heights, tags = g[ok], heights[ok], [t for t, k in zip(tags, ok, strict=True) if k]
    stats["in_area"] = len(g)
    materials = [building_material(t) for t in tags]
    stats["tagged_material"] = sum(m[1] for m in materials)
    base = np.where(heights[:, 0] > 0, np.maximum(heights[:, 0] - BASE_OVERLAP, 0.0), 0.0)
    return g, base, heights[:, 1], [m[0] for m in materials]


def _building_objects(polys, z_min, z_max, materials, box) -> tuple[list, int]:
    solids, _ = merge_prisms_closed(polys, z_min, z_max, box)
    face_group = solids.group[solids.face_owner]
    face_mat = np.array(materials, dtype=object)[solids.face_owner]
    n_groups = int(solids.group.max()) + 1 if len(solids.group) else 0
    width = len(str(max(n_groups - 1, 0)))
    objects = []
    order = np.argsort(face_group, kind="stable")
    bounds = np.searchsorted(face_group[order], np.arange(n_groups + 1))
    for gi in range(n_groups):
        idx = order[bounds[gi] : bounds[gi + 1]]
        if len(idx) == 0:
            continue
        mats, counts = np.unique(face_mat[idx].astype(str), return_counts=True)
        ranked = sorted(zip(mats.tolist(), counts.tolist(), strict=True), key=lambda mc: (-mc[1], mc[0]))
        for rank, (mat, _) in enumerate(ranked):
            fi = idx[face_mat[idx] == mat]
            used, inv = np.unique(solids.faces[fi], return_inverse=True)
            name = f"building_{gi:0{width}d}" + ("" if rank == 0 else f"_{mat}")
            objects.append(
                (name, "building", mat, solids.vertices[used], inv.reshape(-1, 3).astype(np.int64))
            )
    return objects, n_groups


def _highways(feat: OsmFeatures, area: OsmArea, box: shapely.Polygon):
    """Drivable highway centre lines and road widths inside the area."""
    if len(feat.highways) == 0:
        return np.empty(0, object), np.zeros(0)
    idx = np.flatnonzero([drivable(t) for t in feat.highway_tags])
    if len(idx) == 0:
        return np.empty(0, object), np.zeros(0)
    w, s, e, n = area.lon_lat_bounds()
    idx = idx[shapely.intersects(feat.highways[idx], shapely.box(w, s, e, n))]
    lines = (
        shapely.intersection(_to_frame(feat.highways[idx], area), box) if len(idx) else np.empty(0, object)
    )
    keep = ~shapely.is_empty(lines) & (shapely.length(lines) > 0) if len(lines) else np.zeros(0, bool)
    widths = np.array([road_width(feat.highway_tags[i]) for i in idx[keep]])
    return lines[keep], widths


def build_geometry(feat: OsmFeatures, area: OsmArea, roads: bool = False) -> OsmGeometry:
    """Buildings, ground (and roads), and street centre lines of ``area``.

    Parameters
    ----------
    feat : OsmFeatures
        What :func:`.read.read_osm` read.
    area : OsmArea
    roads : bool
        Lay the drivable highways as asphalt strips (object ``roads``) cut out of the ground.

    Returns
    -------
    OsmGeometry
        Objects ``ground`` (concrete), optionally ``roads`` (asphalt), and ``building_NN``
        (one per group of touching buildings and material).
    """
    w, s, e, n = area.lon_lat_bounds()
    lon, lat = feat.broken.T
    stats: dict[str, int] = {"broken": int(((lon >= w) & (lon <= e) & (lat >= s) & (lat <= n)).sum())}
    width, height = area.extent
    box = shapely.box(0.0, 0.0, float(width), float(height))
    polys, z_min, z_max, materials = _buildings(feat, area, box, stats)
    objects, stats["blocks"] = (
        _building_objects(polys, z_min, z_max, materials, box) if len(polys) else ([], 0)
    )

    lines, road_widths = _highways(feat, area, box)
    pieces = [np.asarray(shapely.get_coordinates(p)) for p in shapely.get_parts(lines)] if len(lines) else []
    stats["streets"] = len(pieces)
    ground = box
    flat = []
    if roads and len(lines):
        strips = shapely.buffer(lines, road_widths / 2.0, cap_style="flat", join_style="mitre")
        road = _snap(shapely.intersection(shapely.union_all(strips), box))
        road = _polygonal(road)
        if road is not None:
            ground = _polygonal(_snap(shapely.difference(box, road))) or box
            flat.append(("roads", "ground", "asphalt", *_triangles_up(road)))
    flat.insert(0, ("ground", "ground", "concrete", *_triangles_up(ground)))
    return OsmGeometry(flat + objects, pieces, stats)
