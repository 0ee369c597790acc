"""Scene readers: TOML scene files, Mitsuba XML, bare mesh files, and catalogue names."""

from __future__ import annotations

from pathlib import Path

from ...errors import MmwsimError
from ..catalogue import load_named_scene
from ..osm.read import is_osm_path
from ..scene import Scene
from .mesh_file import load_mesh_file
from .mitsuba import load_mitsuba
from .toml_file import load_toml

__all__ = ["load_scene", "load_toml", "load_mitsuba", "load_mesh_file"]

_MESH_SUFFIXES = {".obj", ".ply", ".glb", ".gltf", ".stl", ".off", ".dae", ".3mf"}


def load_scene(source: str | Path | Scene, transmitter: tuple[float, float, float] | None = None) -> Scene:
    """A scene from a catalogue name (``default``, ``manhattan:seed=3``, ...) or a file.

    Names are looked up in the scene registry (:mod:`mmwsim.scene.catalogue`).

    Files are read by suffix: ``.toml`` scene files, ``.xml`` Mitsuba scenes, any
    mesh format trimesh reads. An OpenStreetMap file needs an area, so it is named as a
    catalogue entry: ``osm:city.osm.pbf,bbox=S,W,N,E`` (or :func:`mmwsim.scene.osm.load_osm`).
    A :class:`Scene` is returned as it is.

    Parameters
    ----------
    source : str, path-like or Scene
    transmitter : (3,) float, optional
        Overrides the scene's transmitter position, metres.
    """
    if isinstance(source, Scene):
        return source
    text = str(source)
    path = Path(text)
    if not text.startswith("osm:") and is_osm_path(text):
        raise MmwsimError(
            f"{text}: an OSM file needs an area: --bbox S,W,N,E or --center LAT,LON --size WxH"
            f" (as a scene name: osm:{text},bbox=S,W,N,E)"
        )
    suffix = path.suffix.lower()
    if path.exists() or suffix in {".toml", ".xml"} | _MESH_SUFFIXES:
        if path.is_dir():
            candidates = sorted(path.glob("*.toml")) or sorted(path.glob("*.xml"))
            if not candidates:
                raise MmwsimError(f"{path}: folder holds no .toml or .xml scene file")
            path, suffix = candidates[0], candidates[0].suffix.lower()
        if suffix == ".toml":
            return load_toml(path, transmitter)
        if suffix == ".xml":
            return load_mitsuba(path, transmitter)
        if not path.exists():
            raise MmwsimError(f"{path}: file not found")
        return load_mesh_file(path, transmitter=transmitter)
    return load_named_scene(text, transmitter=transmitter)
