"""``--bbox`` / ``--center`` / ``--size`` / ``--roads``: the area of an OpenStreetMap file given as SCENE.

The commands that take a scene call :func:`add_area_arguments` on their parser and
:func:`scene_spec` on the parsed arguments; an OSM file with an area becomes the catalogue text
``osm:PATH,<area>,crs=...`` that any later step (the data set's workers, ``Dataset.scene``)
reloads the same scene from.
"""

from __future__ import annotations

import re

from ..errors import MmwsimError

__all__ = ["add_area_arguments", "scene_spec"]


def add_area_arguments(parser) -> None:
    """Add the area options to ``parser`` (and let their values start with a minus sign)."""
    g = parser.add_argument_group("area of an OpenStreetMap file (SCENE ending in .osm, .osm.pbf, .osm.bz2)")
    g.add_argument("--bbox", metavar="S,W,N,E", help="south, west, north, east in degrees")
    g.add_argument("--center", metavar="LAT,LON", help="centre of the area in degrees (with --size)")
    g.add_argument("--size", metavar="WxH", help="width x height of the area in metres, e.g. 400x400")
    g.add_argument("--roads", action="store_true", help="lay the drivable highways as asphalt strips")
    # "--bbox -33.93,18.41,..." is a value, not an option
    parser._negative_number_matcher = re.compile(r"^-\.?\d[\d.,eE+-]*$")


def scene_spec(args) -> str:
    """The scene text to load: SCENE as given, or ``osm:PATH,<area>`` for an OSM file with an area."""
    from ..scene.osm import OsmArea, is_osm_path, osm_spec

    area_given = args.bbox is not None or args.center is not None or args.size is not None
    if not is_osm_path(args.scene):
        if area_given or args.roads:
            raise MmwsimError(
                f"--bbox, --center, --size and --roads apply to OSM files (.osm, .osm.pbf, .osm.bz2),"
                f" not to {args.scene!r}"
            )
        return args.scene
    if not area_given:
        raise MmwsimError(
            f"{args.scene}: an OSM file needs an area: --bbox S,W,N,E or --center LAT,LON --size WxH"
        )
    area = OsmArea.parse(bbox=args.bbox, center=args.center, size=args.size)  # errors name the value
    return osm_spec(args.scene, area, roads=args.roads)
