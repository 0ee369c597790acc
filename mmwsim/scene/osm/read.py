"""Reading buildings and highways from an OpenStreetMap file with pyosmium.

pyosmium reads ``.osm`` XML, ``.osm.pbf`` and compressed XML (``.osm.bz2``, ``.osm.gz``), and
assembles multipolygon relations into areas (holes kept). Closed building ways become polygons
here, as drawn, so that a self-intersecting one can be repaired later rather than dropped. Only the
tags the scene uses are kept. Geometries come back in degrees (WGS 84), as shapely objects.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely

from ...errors import MmwsimError

__all__ = ["OSM_SUFFIXES", "OsmFeatures", "is_osm_path", "read_osm"]

OSM_SUFFIXES = (".osm", ".osm.pbf", ".pbf", ".osm.bz2", ".osm.gz")

BUILDING_KEYS = (
    "building",
    "building:part",
    "height",
    "building:height",
    "min_height",
    "building:min_height",
    "building:levels",
    "building:min_level",
    "building:material",
    "building:facade:material",
    "location",
)
HIGHWAY_KEYS = ("highway", "width", "lanes", "tunnel", "covered", "area")


def is_osm_path(path: str | Path) -> bool:
    """Whether ``path`` is named like an OSM file (``.osm``, ``.osm.pbf``, ``.pbf``, ``.osm.bz2``, ``.osm.gz``)."""
    name = str(path).lower()
    return name.endswith(OSM_SUFFIXES)


@dataclass
class OsmFeatures:
    """What a scene uses from an OSM file, in degrees.

    Attributes
    ----------
    buildings : (n,) shapely geometries (Polygon / MultiPolygon), lon/lat
    building_tags : list of dict
        The :data:`BUILDING_KEYS` each building has.
    building_ids : list of str
        ``w<way id>`` or ``r<relation id>``.
    highways : (m,) shapely LineStrings, lon/lat
    highway_tags : list of dict
    broken : (k, 2) float64
        Longitude, latitude of a node of each building way left out because its outline is not
        closed or lacks nodes in the extract (NaN where no node of it is there). Multipolygons
        that pyosmium cannot assemble are not reported by it.
    """

    buildings: np.ndarray
    building_tags: list[dict[str, str]]
    building_ids: list[str]
    highways: np.ndarray
    highway_tags: list[dict[str, str]]
    broken: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    objects: int = 0


def _tags(tags, keys: tuple[str, ...]) -> dict[str, str]:
    return {k: tags[k] for k in keys if k in tags}


def read_osm(path: str | Path) -> OsmFeatures:
    """Buildings (areas tagged ``building`` or ``building:part``) and highway ways of an OSM file.

    Raises
    ------
    MmwsimError
        When the file is missing, not an OSM file, or malformed.
    """
    import osmium

    path = Path(path)
    if not path.is_file():
        raise MmwsimError(f"{path}: OSM file not found")
    wkb = osmium.geom.WKBFactory()
    ring_wkb: list[bytes] = []  # closed building ways, as their outline
    ring_tags: list[dict[str, str]] = []
    ring_ids: list[str] = []
    b_wkb: list[bytes] = []  # multipolygon relations, assembled by osmium
    b_tags: list[dict[str, str]] = []
    b_ids: list[str] = []
    h_wkb: list[bytes] = []
    h_tags: list[dict[str, str]] = []
    broken: list[tuple[float, float]] = []
    seen = 0
    try:
        fp = (
            osmium.FileProcessor(str(path))
            .with_areas()
            .with_filter(osmium.filter.KeyFilter("building", "building:part", "highway"))
        )
        for obj in fp:
            seen += 1
            tags = obj.tags
            building = tags.get("building", "no") != "no" or tags.get("building:part", "no") != "no"
            if obj.is_area():
                # Closed ways are read as ways below: osmium drops a self-intersecting ring, which
                # shapely can repair.
                if not building or obj.from_way():
                    continue
                try:
                    b_wkb.append(wkb.create_multipolygon(obj))
                except (RuntimeError, osmium.InvalidLocationError):  # an area osmium could not build
                    continue
                b_tags.append(_tags(tags, BUILDING_KEYS))
                b_ids.append(f"r{obj.orig_id()}")
            elif obj.is_way() and building:
                try:
                    line = wkb.create_linestring(obj)
                    closed = obj.is_closed() and len(obj.nodes) >= 4
                except (RuntimeError, osmium.InvalidLocationError):  # nodes missing from the extract
                    line, closed = None, False
                if not closed:
                    known = [(n.lon, n.lat) for n in obj.nodes if n.location.valid()]
                    broken.append(known[0] if known else (np.nan, np.nan))
                    continue
                ring_wkb.append(line)
                ring_tags.append(_tags(tags, BUILDING_KEYS))
                ring_ids.append(f"w{obj.id}")
            elif obj.is_way() and "highway" in tags:
                try:
                    h_wkb.append(wkb.create_linestring(obj))
                except (RuntimeError, osmium.InvalidLocationError):  # nodes missing from the extract
                    continue
                h_tags.append(_tags(tags, HIGHWAY_KEYS))
    except RuntimeError as e:
        text = " ".join(str(e).split())[:200]
        raise MmwsimError(f"{path}: not a readable OSM file ({text})") from None
    rings = shapely.from_wkb(ring_wkb) if ring_wkb else np.empty(0, dtype=object)
    if len(rings):
        coords, which = shapely.get_coordinates(rings, return_index=True)
        rings = shapely.polygons(shapely.linearrings(coords, indices=which))
    relations = shapely.from_wkb(b_wkb) if b_wkb else np.empty(0, dtype=object)
    buildings = np.concatenate([rings, relations]).astype(object)
    highways = shapely.from_wkb(h_wkb) if h_wkb else np.empty(0, dtype=object)
    return OsmFeatures(
        buildings,
        ring_tags + b_tags,
        ring_ids + b_ids,
        highways,
        h_tags,
        np.array(broken).reshape(-1, 2),
        seen,
    )
