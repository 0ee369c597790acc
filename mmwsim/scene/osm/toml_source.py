"""The ``[osm]`` table of a TOML scene file: an OSM extract and an area as the scene's base.

Example::

    name = "helsinki"

    [osm]
    file = "helsinki.osm.pbf"        # relative to the TOML file, inside its folder
    center = [60.1675, 24.946]       # or bbox = [south, west, north, east], degrees
    size = [400.0, 400.0]            # metres
    # crs = "EPSG:3067"              # default: the area's UTM zone
    # roads = true                   # asphalt road strips

    [transmitter]
    position = [200.0, 200.0, 10.0]

Objects listed under ``[[objects]]`` are added to the OSM ones (ground, roads, building_NN).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field, Strict, StrictFloat

from ...config import StrictModel, Vec2
from ...errors import MmwsimError
from ..objects import ReceiverGrid, SceneObject, Transmitter
from .area import OsmArea
from .loader import OsmScene, _warn, osm_geometry, osm_objects

__all__ = ["OsmSource", "scene_with_osm"]

Vec4 = Annotated[tuple[StrictFloat, StrictFloat, StrictFloat, StrictFloat], Strict(False)]


class OsmSource(StrictModel):
    """Schema of the ``[osm]`` table."""

    file: str = Field(min_length=1)
    bbox: Vec4 | None = None
    center: Vec2 | None = None
    size: Vec2 | None = None
    crs: str | None = None
    roads: bool = False


def scene_with_osm(
    source: OsmSource,
    toml_path: Path,
    objects: list[SceneObject],
    transmitter: Transmitter | None,
    receivers: ReceiverGrid | None,
    frequency: float,
    name: str,
) -> OsmScene:
    """The scene of a TOML file with an ``[osm]`` table: the OSM objects, then ``objects``."""
    from ..loaders.meshes import resolve_inside

    where = f"{toml_path}: osm"
    path = resolve_inside(source.file, toml_path.parent, where)
    try:
        area = OsmArea.parse(source.bbox, source.center, source.size, source.crs)
    except MmwsimError as e:
        raise MmwsimError(f"{where}: {e}") from None
    geo = osm_geometry(path, area, source.roads)
    _warn(path, geo.stats)
    return OsmScene(
        osm_objects(geo) + objects,
        area=area,
        street_lines=geo.street_lines,
        osm_stats=geo.stats,
        transmitter=transmitter,
        receivers=receivers,
        frequency=frequency,
        name=name,
        source=str(toml_path),
    )
