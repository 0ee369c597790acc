"""OSM tags to building heights, materials and road widths.

Heights (metres) follow the Simple 3D Buildings conventions:

* top: ``height``, else ``building:height``, else ``building:levels`` x :data:`LEVEL_HEIGHT`,
  else :data:`DEFAULT_HEIGHT`;
* base: ``min_height``, else ``building:min_height``, else ``building:min_level`` x
  :data:`LEVEL_HEIGHT`, else 0; a roof-only structure (``building=roof``) without a base is
  :data:`ROOF_THICKNESS` thick under its top, so streets pass under it.

Lengths may carry units (``12 m``, ``40'``, ``40 ft``) or a decimal comma; the first of several
values (``12;15``) is used.

Materials: ``building:facade:material``, else ``building:material``, mapped to the ITU-R P.2040
name that fits (:data:`MATERIALS`), else :data:`DEFAULT_MATERIAL`.
"""

from __future__ import annotations

import math
import re

__all__ = [
    "DEFAULT_HEIGHT",
    "DEFAULT_MATERIAL",
    "LEVEL_HEIGHT",
    "MATERIALS",
    "ROOF_THICKNESS",
    "building_heights",
    "building_material",
    "parse_length",
    "road_width",
]

LEVEL_HEIGHT = 3.0  # metres per storey
DEFAULT_HEIGHT = 10.0  # metres, a building with no height or level tag
ROOF_THICKNESS = 1.0  # metres, building=roof without a base
DEFAULT_MATERIAL = "concrete"

# OSM values (building:material, building:facade:material) -> ITU-R P.2040 material
MATERIALS = {
    "concrete": "concrete",
    "reinforced_concrete": "concrete",
    "cement_block": "concrete",
    "plaster": "concrete",  # render over masonry or concrete
    "stucco": "concrete",
    "brick": "brick",
    "masonry": "brick",
    "clay": "brick",
    "glass": "glass",
    "mirror": "glass",
    "metal": "metal",
    "steel": "metal",
    "aluminium": "metal",
    "aluminum": "metal",
    "metal_plates": "metal",
    "copper": "metal",
    "wood": "wood",
    "timber_framing": "wood",
    "log": "wood",
    "bamboo": "wood",
    "stone": "marble",
    "marble": "marble",
    "granite": "marble",
    "limestone": "marble",
    "sandstone": "marble",
}

# Typical carriageway widths (metres) by highway class, used when a way has no width or lanes.
ROAD_WIDTHS = {
    "motorway": 14.0,
    "trunk": 12.0,
    "primary": 10.0,
    "secondary": 9.0,
    "tertiary": 8.0,
    "unclassified": 6.0,
    "residential": 6.0,
    "living_street": 5.0,
    "service": 4.0,
    "pedestrian": 6.0,
}
LANE_WIDTH = 3.25  # metres
# Highway classes vehicles drive on (links included by their class name).
DRIVABLE = frozenset(
    {
        "motorway",
        "trunk",
        "primary",
        "secondary",
        "tertiary",
        "unclassified",
        "residential",
        "living_street",
        "service",
    }
)

_NUMBER = re.compile(r"^\s*([-+]?\d+(?:[.,]\d+)?)\s*(m|metres|meters|ft|feet|'|)\s*$", re.IGNORECASE)


def parse_length(text: str | None) -> float | None:
    """``"12"``, ``"12.5 m"``, ``"12,5"``, ``"40'"``, ``"40 ft"``, ``"12;15"`` -> metres; None if unreadable."""
    if text is None:
        return None
    m = _NUMBER.match(text.split(";")[0])
    if m is None:
        return None
    value = float(m.group(1).replace(",", "."))
    if m.group(2).lower() in ("ft", "feet", "'"):
        value *= 0.3048
    return value if math.isfinite(value) else None


def _levels(text: str | None) -> float | None:
    v = parse_length(text)
    return v * LEVEL_HEIGHT if v is not None and v >= 0 else None


def building_heights(tags: dict[str, str]) -> tuple[float, float]:
    """(base, top) of a building or building part in metres above the ground (see the module doc)."""
    top = parse_length(tags.get("height"))
    if top is None or top <= 0:
        top = parse_length(tags.get("building:height"))
    if top is None or top <= 0:
        top = _levels(tags.get("building:levels"))
        if top is not None and top <= 0:
            top = None
    base = parse_length(tags.get("min_height"))
    if base is None:
        base = parse_length(tags.get("building:min_height"))
    if base is None:
        base = _levels(tags.get("building:min_level"))
    if top is None:
        top = max(DEFAULT_HEIGHT, (base or 0.0) + LEVEL_HEIGHT)
    if base is None:
        roof = tags.get("building") == "roof" or tags.get("building:part") == "roof"
        base = max(top - ROOF_THICKNESS, 0.0) if roof else 0.0
    return max(base, 0.0), top


def building_material(tags: dict[str, str]) -> tuple[str, bool]:
    """ITU-R P.2040 material name of a building and whether a material tag was recognised."""
    for key in ("building:facade:material", "building:material"):
        value = tags.get(key)
        if value:
            name = MATERIALS.get(value.strip().lower().split(";")[0])
            if name is not None:
                return name, True
    return DEFAULT_MATERIAL, False


def road_width(tags: dict[str, str]) -> float:
    """Carriageway width of a highway way, metres: ``width``, else ``lanes`` x 3.25 m, else by class."""
    w = parse_length(tags.get("width"))
    if w is not None and w > 0:
        return w
    lanes = parse_length(tags.get("lanes"))
    if lanes is not None and lanes >= 1:
        return lanes * LANE_WIDTH
    return ROAD_WIDTHS.get(tags.get("highway", "").removesuffix("_link"), 5.0)


def drivable(tags: dict[str, str]) -> bool:
    """Whether vehicles drive on a highway way at ground level (no tunnels, covered ways or areas)."""
    if tags.get("highway", "").removesuffix("_link") not in DRIVABLE:
        return False
    if tags.get("area") == "yes":
        return False
    return tags.get("tunnel", "no") == "no" and tags.get("covered", "no") == "no"
