"""Scenes from OpenStreetMap extracts: buildings as closed extrusions, ground, roads and streets.

``load_osm("city.osm.pbf", center="60.17,24.94", size="400x400")`` or, as a catalogue name,
``load_scene("osm:city.osm.pbf,center=60.17,24.94,size=400x400")``.
"""

from .area import OsmArea
from .loader import OsmScene, OsmWarning, load_osm, osm_spec
from .read import OSM_SUFFIXES, is_osm_path
from .tags import DEFAULT_HEIGHT, DEFAULT_MATERIAL, LEVEL_HEIGHT

__all__ = [
    "DEFAULT_HEIGHT",
    "DEFAULT_MATERIAL",
    "LEVEL_HEIGHT",
    "OSM_SUFFIXES",
    "OsmArea",
    "OsmScene",
    "OsmWarning",
    "is_osm_path",
    "load_osm",
    "osm_spec",
]
