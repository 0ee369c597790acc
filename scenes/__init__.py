"""The scene catalogue: the embedded default scene, procedural cities and canonical test scenes.

Load by name with :func:`load`; a name may carry parameters, e.g.
``manhattan:seed=3,median_height=30`` or ``ground_wall:distance=15``. An entry whose first
parameter is ``path`` takes it without a key (``osm:city.osm.pbf,bbox=...``), and a value may hold
commas (``bbox=60.16,24.93,60.17,24.95``): an item without ``=`` continues the value before it.
"""

from __future__ import annotations

import inspect
from importlib import resources
from typing import Any

from mmwsim.errors import MmwsimError
from mmwsim.scene import Scene, load_toml

from .canonical import corner_reflector, free_space, ground_only, ground_wall, street_canyon
from .downtown import downtown_buildings, write_default
from .manhattan import manhattan_city
from .osm import osm_scene

__all__ = [
    "CATALOGUE",
    "corner_reflector",
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


def _default(tx: tuple[float, float, float] | None = None, **kw: Any) -> Scene:
    if kw:
        raise MmwsimError(f"scene 'default' takes no parameters, got {', '.join(kw)}")
    return load_toml(default_scene_path(), transmitter=tx)


CATALOGUE = {
    "default": _default,
    "manhattan": manhattan_city,
    "free_space": free_space,
    "ground_only": ground_only,
    "ground_wall": ground_wall,
    "street_canyon": street_canyon,
    "corner_reflector": corner_reflector,
    "osm": osm_scene,
}


def names() -> list[str]:
    """Names of the catalogue's scenes."""
    return list(CATALOGUE)


def _parse_value(text: str) -> Any:
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def load(name: str, transmitter: tuple[float, float, float] | None = None) -> Scene:
    """A catalogue scene by name, with optional ``:key=value,...`` parameters.

    Parameters
    ----------
    name : str
        e.g. ``default``, ``manhattan:seed=3``.
    transmitter : (3,) float, optional
        Overrides the scene's transmitter position, metres.
    """
    base, _, params = name.partition(":")
    if base not in CATALOGUE:
        raise MmwsimError(
            f"unknown scene {name!r}: not a file, and not in the catalogue ({', '.join(names())})"
        )
    kwargs: dict[str, Any] = {}
    raw: dict[str, str] = {}
    last = None
    takes_path = next(iter(inspect.signature(CATALOGUE[base]).parameters), None) == "path"
    for i, item in enumerate(filter(None, params.split(","))):
        key, eq, value = item.partition("=")
        if not eq and i == 0 and takes_path:
            key, value = "path", item
        elif not eq and last is not None:
            key, value = last, f"{raw[last]},{item}"
        elif not eq:
            raise MmwsimError(f"scene {name!r}: parameter {item!r} is not key=value")
        last = key = key.strip()
        raw[key] = value.strip()
        kwargs[key] = raw[key] if key == "path" else _parse_value(raw[key])
    if transmitter is not None:
        kwargs["tx"] = tuple(float(v) for v in transmitter)
    try:
        return CATALOGUE[base](**kwargs)
    except TypeError as e:
        raise MmwsimError(f"scene {name!r}: {e}") from None
