"""Scene model, scene files and the registry of named scenes.

Names load on first use, so the registry (:mod:`.catalogue`) can list the catalogue without
importing trimesh.
"""

from __future__ import annotations

from ..lazy import lazy_exports

_EXPORTS = {
    "load_named_scene": ".catalogue",
    "register_scene": ".catalogue",
    "scene_names": ".catalogue",
    "load_mesh_file": ".loaders",
    "load_mitsuba": ".loaders",
    "load_scene": ".loaders",
    "load_toml": ".loaders",
    "ReceiverGrid": ".objects",
    "SceneObject": ".objects",
    "Transmitter": ".objects",
    "OsmArea": ".osm",
    "OsmScene": ".osm",
    "OsmWarning": ".osm",
    "load_osm": ".osm",
    "Scene": ".scene",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
