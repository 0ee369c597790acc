"""Scene model and scene files."""

from .loaders import load_mesh_file, load_mitsuba, load_scene, load_toml
from .objects import ReceiverGrid, SceneObject, Transmitter
from .osm import OsmArea, OsmScene, OsmWarning, load_osm
from .scene import Scene

__all__ = [
    "OsmArea",
    "OsmScene",
    "OsmWarning",
    "ReceiverGrid",
    "Scene",
    "SceneObject",
    "Transmitter",
    "load_mesh_file",
    "load_mitsuba",
    "load_osm",
    "load_scene",
    "load_toml",
]
