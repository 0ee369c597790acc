"""OSM scenes: :func:`load_osm`, the :class:`OsmScene` it returns, and the spec text that reloads it."""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import numpy as np
import trimesh

from ...errors import MmwsimError
from ...materials import get_material
from ..objects import SceneObject, Transmitter
from ..scene import Scene
from .area import OsmArea
from .build import OsmGeometry, build_geometry
from .cache import file_sha256, read_entry, write_entry
from .read import is_osm_path, read_osm

__all__ = ["BUILD_VERSION", "OsmScene", "OsmWarning", "load_osm", "osm_geometry", "osm_objects", "osm_spec"]

# Bump when the geometry built from the same file and area changes: old cache entries are ignored.
BUILD_VERSION = 1


class OsmWarning(UserWarning):
    """OSM input that was repaired or left out (counted in the message)."""


class OsmScene(Scene):
    """A :class:`Scene` built from an OpenStreetMap extract.

    Attributes (besides the Scene's)
    ---------------------------------
    area : OsmArea
        The area and its projected frame.
    crs : str
        The projected CRS with its name, e.g. ``EPSG:32635 (WGS 84 / UTM zone 35N)``.
    origin : (2,) float64
        Projected coordinates of the frame's origin (the area's south-west corner), metres.
    street_lines : list of (k, 2) float64
        Centre lines of the drivable highways in the area, in the scene's frame, metres; vehicles
        follow them (:meth:`mmwsim.trajectories.StreetNetwork.from_scene`).
    osm_stats : dict
        Counts of buildings read, in the area, clipped, repaired, skipped and merged.
    spec : str or None
        Catalogue text that reloads the scene (``osm:PATH,...``); None for a TOML scene.
    """

    def __init__(
        self,
        objects: list[SceneObject],
        *,
        area: OsmArea,
        street_lines: list[np.ndarray],
        osm_stats: dict[str, int],
        spec: str | None = None,
        **kw,
    ):
        self.area = area
        self.crs = area.crs_label
        self.origin = area.origin
        self.street_lines = street_lines
        self.osm_stats = dict(osm_stats)
        self.spec = spec
        super().__init__(objects, **kw)

    def summary(self) -> str:
        lines = super().summary().split("\n")
        s = self.osm_stats
        e, n = self.origin
        w, h = self.area.extent
        extra = [
            f"  crs          {self.crs}; x east, y north from the area's south-west corner"
            f" at E {e:.2f}, N {n:.2f} m",
            f"  osm area     {w:.1f} x {h:.1f} m ({self.area.spec(with_crs=False)})",
            f"  osm          {s.get('in_area', 0)} buildings in the area ({s.get('clipped', 0)} clipped at its edge,"
            f" {s.get('repaired', 0)} repaired, {s.get('skipped', 0)} skipped) merged into"
            f" {s.get('blocks', 0)} blocks; {s.get('streets', 0)} street pieces",
        ]
        return "\n".join(lines[:2] + extra + lines[2:])


def osm_spec(path: str | Path, area: OsmArea, roads: bool = False) -> str:
    """Catalogue text that reloads an OSM scene, e.g. ``osm:city.osm.pbf,center=60.17,24.94,size=400x400,crs=EPSG:32635``."""
    text = f"osm:{path},{area.spec()}"
    return text + ",roads=1" if roads else text


def _cache_key(digest: str, area: OsmArea, roads: bool) -> str:
    text = json.dumps([BUILD_VERSION, digest, area.key(), bool(roads)])
    return hashlib.sha256(text.encode()).hexdigest()


def _pack(geo: OsmGeometry) -> tuple[dict, dict[str, np.ndarray]]:
    meta = {"objects": [list(o[:3]) for o in geo.objects], "stats": geo.stats}
    arrays = {}
    for i, o in enumerate(geo.objects):
        arrays[f"v{i}"], arrays[f"f{i}"] = o[3], o[4]
    lines = geo.street_lines
    arrays["street_xy"] = np.concatenate(lines) if lines else np.zeros((0, 2))
    arrays["street_off"] = np.cumsum([0] + [len(p) for p in lines]).astype(np.int64)
    return meta, arrays


def _unpack(meta: dict, arrays: dict[str, np.ndarray]) -> OsmGeometry:
    objects = [
        (name, kind, mat, arrays[f"v{i}"], arrays[f"f{i}"])
        for i, (name, kind, mat) in enumerate(meta["objects"])
    ]
    off, xy = arrays["street_off"], arrays["street_xy"]
    lines = [xy[off[k] : off[k + 1]] for k in range(len(off) - 1)]
    return OsmGeometry(objects, lines, {k: int(v) for k, v in meta["stats"].items()})


def osm_geometry(path: str | Path, area: OsmArea, roads: bool = False, cache: bool = True) -> OsmGeometry:
    """The geometry of ``area`` from the OSM file ``path``, from the cache when it holds it.

    The cache key is the file's SHA-256, the area with its CRS, the options and
    :data:`BUILD_VERSION`: an edited file or a new area is rebuilt.
    """
    path = Path(path)
    if not path.is_file():
        raise MmwsimError(f"{path}: OSM file not found")
    key = _cache_key(file_sha256(path), area, roads) if cache else None
    entry = read_entry(key) if key else None
    if entry is not None:
        try:
            return _unpack(*entry)
        except (KeyError, ValueError, TypeError, IndexError):
            pass  # a stale or foreign entry: rebuild it
    feat = read_osm(path)
    geo = build_geometry(feat, area, roads)
    if geo.stats.get("in_area", 0) == 0:
        where = ""
        if len(feat.buildings):
            import shapely

            w, s, e, n = shapely.total_bounds(feat.buildings)
            where = (
                f"; its {len(feat.buildings)} buildings lie within lat {s:.5f}..{n:.5f}, lon {w:.5f}..{e:.5f}"
            )
        elif feat.objects == 0:
            where = "; it holds no buildings or highways at all"
        raise MmwsimError(f"{path}: no buildings in the area {area.spec(with_crs=False)}{where}")
    if key:
        write_entry(key, *_pack(geo))
    return geo


def _warn(path: Path, stats: dict[str, int]) -> None:
    parts = []
    if stats.get("repaired"):
        parts.append(f"{stats['repaired']} building footprints repaired (self-intersecting or invalid)")
    if stats.get("skipped"):
        parts.append(f"{stats['skipped']} skipped (degenerate: under 1 m2, or top not above base)")
    if stats.get("broken"):
        parts.append(
            f"{stats['broken']} building outlines near the area left out (not closed, or cut by the extract's edge)"
        )
    if parts:
        warnings.warn(f"{path}: " + "; ".join(parts), OsmWarning, stacklevel=3)


def osm_objects(geo: OsmGeometry) -> list[SceneObject]:
    """Scene objects of built OSM geometry (meshes kept exactly as built)."""
    return [
        SceneObject(name, trimesh.Trimesh(v, f, process=False), get_material(mat), kind)
        for name, kind, mat, v, f in geo.objects
    ]


def load_osm(
    path: str | Path,
    bbox=None,
    center=None,
    size=None,
    crs: str | None = None,
    roads: bool = False,
    transmitter: tuple[float, float, float] | None = None,
    cache: bool = True,
) -> OsmScene:
    """A scene of an area of an OpenStreetMap extract.

    Parameters
    ----------
    path : path-like
        ``.osm``, ``.osm.pbf`` or ``.osm.bz2`` file.
    bbox : (4,) float or str, optional
        South, west, north, east, degrees; or give ``center`` and ``size``.
    center : (2,) float or str, optional
        Latitude, longitude of the area's centre, degrees.
    size : (2,) float, float or str, optional
        Width and height of the area, metres (``"400x400"``).
    crs : str, optional
        Projected CRS in metres; default the UTM zone of the area's centre.
    roads : bool
        Lay drivable highways as asphalt strips in the ground.
    transmitter : (3,) float, optional
        Transmitter position in the scene's frame, metres.
    cache : bool
        Use the on-disk cache (see :mod:`.cache`).

    Returns
    -------
    OsmScene
        Ground (concrete) over the area, buildings ``building_NN``, the receiver grid over the
        area at 1 m, 1.5 m above the ground; frame x east, y north from the south-west corner.
    """
    if not is_osm_path(path):
        raise MmwsimError(f"{path}: not an OSM file name (.osm, .osm.pbf, .osm.bz2, .osm.gz)")
    area = OsmArea.parse(bbox=bbox, center=center, size=size, crs=crs)
    path = Path(path)
    geo = osm_geometry(path, area, roads, cache)
    _warn(path, geo.stats)
    tx = Transmitter(tuple(float(v) for v in transmitter)) if transmitter is not None else None
    spec = osm_spec(path, area, roads)
    name = path.name.split(".")[0] or "osm"
    try:
        return OsmScene(
            osm_objects(geo),
            area=area,
            street_lines=geo.street_lines,
            osm_stats=geo.stats,
            spec=spec,
            transmitter=tx,
            name=name,
            source=spec,
        )
    except MmwsimError as e:
        raise MmwsimError(f"{path}: {e}") from None
