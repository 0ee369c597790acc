"""Scene model, scene files and the registry of named scenes.

Names load on first use, so the registry (:mod:`.catalogue`) can list the catalogue without
importing trimesh.
"""

from __future__ import annotations

from ..lazy import lazy_exports

_EXPORTS = {
    ".catalogue": ("load_named_scene", "register_scene", "scene_names"),
    ".loaders": ("load_mesh_file", "load_mitsuba", "load_scene", "load_toml"),
    ".objects": ("ReceiverGrid", "SceneObject", "Transmitter"),
    ".osm": ("OsmArea", "OsmScene", "OsmWarning", "load_osm"),
    ".scene": ("Scene",),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
