"""The registry of named scenes: catalogue entries are found by name, never imported by name.

A scene factory is a callable returning a :class:`~mmwsim.scene.Scene`; its keyword parameters
are the name's parameters (``manhattan:seed=3,median_height=30``) and ``tx``, the transmitter
position. Factories come from two places:

* the ``mmwsim.scenes`` entry-point group of installed distributions (the ``scenes`` package
  declares its catalogue there in ``pyproject.toml``), loaded only when their name is asked for;
* :func:`register_scene`, for factories defined at run time.

So the scene model below the catalogue never imports it, and any package can add scenes.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any

from ..errors import MmwsimError

if TYPE_CHECKING:
    from .scene import Scene

__all__ = [
    "ENTRY_POINT_GROUP",
    "SceneFactory",
    "load_named_scene",
    "register_scene",
    "scene_factory",
    "scene_names",
]

ENTRY_POINT_GROUP = "mmwsim.scenes"
SceneFactory = Callable[..., "Scene"]
"""``factory(**parameters, tx=(x, y, z)) -> Scene``; a first parameter named ``path`` takes a
value without a key (``osm:city.osm.pbf,bbox=...``)."""

_REGISTERED: dict[str, SceneFactory] = {}


def register_scene(name: str, factory: SceneFactory) -> None:
    """Make ``factory`` loadable as ``name`` (replacing an entry point of the same name)."""
    if not name or any(c in name for c in ":,="):
        raise MmwsimError(f"scene name {name!r} must be non-empty and hold no ':', ',' or '='")
    _REGISTERED[name] = factory


def _entry_points() -> dict[str, Any]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def scene_names() -> list[str]:
    """Names of every registered scene: the installed catalogue's first, then run-time ones."""
    return list(dict.fromkeys([*_entry_points(), *_REGISTERED]))


def scene_factory(name: str) -> SceneFactory:
    """The factory registered as ``name``, or a one-line :class:`MmwsimError`."""
    if name in _REGISTERED:
        return _REGISTERED[name]
    ep = _entry_points().get(name)
    if ep is None:
        known = ", ".join(scene_names()) or "none: is mmwsim installed (pip install -e .)?"
        raise MmwsimError(f"unknown scene {name!r}: not a file, and not in the catalogue ({known})")
    return ep.load()


def _parse_value(text: str) -> Any:
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def load_named_scene(name: str, transmitter: tuple[float, float, float] | None = None) -> Scene:
    """A registered scene by name, with optional ``:key=value,...`` parameters.

    A value may hold commas (``bbox=60.16,24.93,60.17,24.95``): an item without ``=`` continues
    the value before it.

    Parameters
    ----------
    name : str
        e.g. ``default``, ``manhattan:seed=3``.
    transmitter : (3,) float, optional
        Overrides the scene's transmitter position, metres.
    """
    base, _, params = name.partition(":")
    factory = scene_factory(base)
    kwargs: dict[str, Any] = {}
    raw: dict[str, str] = {}
    last = None
    takes_path = next(iter(inspect.signature(factory).parameters), None) == "path"
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
        return factory(**kwargs)
    except TypeError as e:
        raise MmwsimError(f"scene {name!r}: {e}") from None
