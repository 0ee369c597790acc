"""Catalogue entry ``osm``: a scene from an OpenStreetMap file the user names.

``osm:PATH,bbox=S,W,N,E`` or ``osm:PATH,center=LAT,LON,size=WxH`` (metres), optionally with
``crs=EPSG:...`` (default: the UTM zone of the area) and ``roads=1`` (asphalt road strips). Built
scenes are cached on disk by the file's content hash, so the second load is fast.
"""

from __future__ import annotations

from mmwsim.errors import MmwsimError
from mmwsim.scene import Scene
from mmwsim.scene.osm import load_osm

__all__ = ["osm_scene"]

_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


def osm_scene(
    path: str | None = None,
    bbox: str | None = None,
    center: str | None = None,
    size: str | float | None = None,
    crs: str | None = None,
    roads: int | str = 0,
    tx: tuple[float, float, float] | None = None,
) -> Scene:
    """The scene of an area of the OSM file ``path`` (see :func:`mmwsim.scene.osm.load_osm`)."""
    if path is None:
        raise MmwsimError(
            "scene 'osm' needs a file and an area: osm:PATH,bbox=S,W,N,E or osm:PATH,center=LAT,LON,size=WxH"
        )
    flag = str(roads).strip().lower()
    if flag not in _TRUE | _FALSE:
        raise MmwsimError(f"scene 'osm': roads must be 0 or 1, got {roads!r}")
    return load_osm(
        str(path), bbox=bbox, center=center, size=size, crs=crs, roads=flag in _TRUE, transmitter=tx
    )
