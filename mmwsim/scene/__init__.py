"""Scene model and scene files."""

from .loaders import load_mesh_file, load_mitsuba, load_scene, load_toml
from .objects import ReceiverGrid, SceneObject, Transmitter
from .scene import Scene

__all__ = [
    "ReceiverGrid",
    "Scene",
    "SceneObject",
    "Transmitter",
    "load_mesh_file",
    "load_mitsuba",
    "load_scene",
    "load_toml",
]
