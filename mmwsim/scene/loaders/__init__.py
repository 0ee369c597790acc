"""Scene readers: TOML scene files, Mitsuba XML, bare mesh files, and catalogue names."""

from __future__ import annotations

from pathlib import Path

from ...errors import MmwsimError
from ...lazy import lazy_exports
from ..catalogue import load_named_scene
from ..osm.read import is_osm_path
from ..scene import Scene

# Each reader loads with the first file of its kind: a Mitsuba scene need not pay for the
# TOML schema (pydantic), nor a TOML scene for the XML parser.
_readers, __getattr__, __dir__ = lazy_exports(
    __name__,
    {".mesh_file": ("load_mesh_file",), ".mitsuba": ("load_mitsuba",), ".toml_file": ("load_toml",)},
)
__all__ = ["load_scene", *_readers]

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
            from .toml_file import load_toml

            return load_toml(path, transmitter)
        if suffix == ".xml":
            from .mitsuba import load_mitsuba

            return load_mitsuba(path, transmitter)
        if not path.exists():
            raise MmwsimError(f"{path}: file not found")
        from .mesh_file import load_mesh_file

        return load_mesh_file(path, transmitter=transmitter)
    return load_named_scene(text, transmitter=transmitter)
