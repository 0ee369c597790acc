"""The scene catalogue: the embedded default scene, procedural cities and canonical test scenes.

Each entry is a factory that this package declares in the ``mmwsim.scenes`` entry-point group
(``pyproject.toml``), so ``mmwsim.load_scene("manhattan:seed=3")`` finds it through the registry
of :mod:`mmwsim.scene.catalogue` without mmwsim naming this package. A name may carry parameters,
e.g. ``manhattan:seed=3,median_height=30`` or ``ground_wall:distance=15``; an entry whose first
parameter is ``path`` takes it without a key (``osm:city.osm.pbf,bbox=...``).
"""

from __future__ import annotations

from importlib import resources
from typing import Any

from mmwsim.errors import MmwsimError
from mmwsim.scene import Scene, load_toml
from mmwsim.scene.catalogue import load_named_scene as load
from mmwsim.scene.catalogue import scene_names as names

from .canonical import corner_reflector, free_space, ground_only, ground_wall, street_canyon
from .downtown import downtown_buildings, write_default
from .manhattan import manhattan_city
from .osm import osm_scene

__all__ = [
    "corner_reflector",
    "default_scene",
    "default_scene_path",
    "downtown_buildings",
    "free_space",
    "ground_only",
    "ground_wall",
    "load",
    "manhattan_city",
    "names",
    "osm_scene",
    "street_canyon",
    "write_default",
]


def default_scene_path():
    """Path of the shipped ``scene.toml`` of the default scene."""
    return resources.files("scenes") / "default" / "scene.toml"


def default_scene(tx: tuple[float, float, float] | None = None, **kw: Any) -> Scene:
    """The embedded default scene (``scenes/default/scene.toml``), optionally with another transmitter."""
    if kw:
        raise MmwsimError(f"scene 'default' takes no parameters, got {', '.join(kw)}")
    return load_toml(default_scene_path(), transmitter=tx)
