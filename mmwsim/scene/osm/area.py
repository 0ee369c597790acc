"""The area of an OpenStreetMap extract to build a scene of, and the projected frame of that scene.

An area is a latitude/longitude box (``bbox``) or a centre with a size in metres. It is projected
with pyproj to a metric CRS, by default the WGS 84 UTM zone of the area's centre (standard 6 degree
zones). The scene's frame is that CRS shifted so that the area's south-west corner is the origin:
x east, y north, metres.

* ``center`` + ``size``: the rectangle ``size`` metres wide and high centred on the projected centre,
  so a 400 x 400 m area spans exactly 0..400 in x and y.
* ``bbox``: the smallest rectangle of the projected frame that holds the whole latitude/longitude box
  (grid convergence turns such a box by a degree or two, so the rectangle is a little larger),
  its sides rounded up to whole centimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ...errors import MmwsimError

__all__ = ["OsmArea", "MAX_AREA_SIZE"]

MAX_AREA_SIZE = 20_000.0  # metres per side; larger areas belong in tiles of their own
_LAT_LIMITS = (-80.0, 84.0)  # where UTM is defined


def _numbers(value, n: int, what: str) -> tuple[float, ...]:
    if isinstance(value, str):
        parts = [p for p in value.replace(" ", "").split(",")]
        try:
            values = tuple(float(p) for p in parts)
        except ValueError:
            raise MmwsimError(f"{what} {value!r}: expected {n} comma-separated numbers") from None
    else:
        try:
            values = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            raise MmwsimError(f"{what} {value!r}: expected {n} numbers") from None
    if len(values) != n:
        raise MmwsimError(f"{what} {value!r}: expected {n} numbers, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise MmwsimError(f"{what} {value!r}: numbers must be finite")
    return values


def _size(value) -> tuple[float, float]:
    """``"400x300"``, ``"400"``, ``400`` or ``(400, 300)`` -> (width, height) in metres."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        w = h = float(value)
    elif isinstance(value, str):
        parts = value.lower().replace(" ", "").split("x")
        try:
            w, h = (float(parts[0]),) * 2 if len(parts) == 1 else (float(parts[0]), float(parts[1]))
        except (ValueError, IndexError):
            raise MmwsimError(f"size {value!r}: expected WIDTHxHEIGHT in metres, e.g. 400x400") from None
        if len(parts) > 2:
            raise MmwsimError(f"size {value!r}: expected WIDTHxHEIGHT in metres, e.g. 400x400")
    else:
        w, h = _numbers(value, 2, "size")
    if not (math.isfinite(w) and math.isfinite(h) and w > 0 and h > 0):
        raise MmwsimError(f"size {value!r}: the area is empty (width and height must be positive metres)")
    if max(w, h) > MAX_AREA_SIZE:
        raise MmwsimError(f"size {value!r}: at most {MAX_AREA_SIZE:g} m per side")
    return w, h


def _check_lat_lon(lat: float, lon: float, what: str) -> None:
    if not _LAT_LIMITS[0] <= lat <= _LAT_LIMITS[1]:
        raise MmwsimError(f"{what}: latitude {lat:g} outside {_LAT_LIMITS[0]:g}..{_LAT_LIMITS[1]:g} (UTM)")
    if not -180.0 <= lon <= 180.0:
        raise MmwsimError(f"{what}: longitude {lon:g} outside -180..180")


def _fmt(v: float) -> str:
    """Shortest text that reads back as the same float (``400`` rather than ``400.0``)."""
    text = repr(float(v))
    return text[:-2] if text.endswith(".0") else text


@dataclass(frozen=True)
class OsmArea:
    """An area of the globe and its projected frame.

    Give either ``bbox`` or ``center`` and ``size``.

    Parameters
    ----------
    bbox : (4,) float or str, optional
        South latitude, west longitude, north latitude, east longitude, degrees (WGS 84);
        ``"60.16,24.93,60.17,24.95"`` as text.
    center : (2,) float or str, optional
        Latitude, longitude of the centre, degrees.
    size : (2,) float, float or str, optional
        Width (east) and height (north) in metres; ``"400x400"`` or ``400`` as text.
    crs : str, optional
        Projected CRS in metres (anything pyproj reads, e.g. ``EPSG:3067``); default the UTM zone
        of the area's centre.
    """

    bbox: tuple[float, float, float, float] | None = None
    center: tuple[float, float] | None = None
    size: tuple[float, float] | None = None
    crs: str | None = None

    @classmethod
    def parse(cls, bbox=None, center=None, size=None, crs: str | None = None) -> OsmArea:
        """Validate and normalise user input (text or numbers); one-line errors."""
        if bbox is not None and (center is not None or size is not None):
            raise MmwsimError("give an area as a bbox or as a center with a size, not both")
        if bbox is not None:
            s, w, n, e = _numbers(bbox, 4, "bbox")
            _check_lat_lon(s, w, f"bbox {bbox!r}")
            _check_lat_lon(n, e, f"bbox {bbox!r}")
            if s > n:
                raise MmwsimError(f"bbox {bbox!r}: south {s:g} is north of north {n:g} (order: S,W,N,E)")
            if w > e:
                raise MmwsimError(f"bbox {bbox!r}: west {w:g} is east of east {e:g} (order: S,W,N,E)")
            if s == n or w == e:
                raise MmwsimError(f"bbox {bbox!r}: the area is empty")
            area = cls(bbox=(s, w, n, e), crs=crs)
        elif center is not None:
            if size is None:
                raise MmwsimError("an area given by its center also needs a size, e.g. 400x400 (metres)")
            lat, lon = _numbers(center, 2, "center")
            _check_lat_lon(lat, lon, f"center {center!r}")
            area = cls(center=(lat, lon), size=_size(size), crs=crs)
        else:
            if size is not None:
                raise MmwsimError("a size needs a center (LAT,LON) too")
            raise MmwsimError("an OSM file needs an area: a bbox S,W,N,E or a center LAT,LON with a size WxH")
        area.frame  # noqa: B018 - resolves the CRS now, so a bad one fails here
        return area

    # ------------------------------------------------------------------ projection
    @property
    def center_lat_lon(self) -> tuple[float, float]:
        """(lat, lon) of the area's centre, degrees."""
        if self.center is not None:
            return self.center
        s, w, n, e = self.bbox
        return (0.5 * (s + n), 0.5 * (w + e))

    @cached_property
    def frame(self) -> tuple:
        """(pyproj.CRS, forward Transformer lon/lat -> metres, inverse Transformer)."""
        import pyproj

        if self.crs is None:
            lat, lon = self.center_lat_lon
            zone = min(int((lon + 180.0) // 6.0) + 1, 60)
            crs = pyproj.CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)
        else:
            try:
                crs = pyproj.CRS.from_user_input(self.crs)
            except pyproj.exceptions.CRSError as e:
                raise MmwsimError(f"crs {self.crs!r}: not a CRS pyproj knows ({e})") from None
            units = {a.unit_name for a in crs.axis_info}
            if not crs.is_projected or units - {"metre"}:
                raise MmwsimError(f"crs {self.crs!r}: must be a projected CRS in metres")
        fwd = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        inv = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
        return crs, fwd, inv

    @property
    def crs_name(self) -> str:
        """``EPSG:32635`` or the CRS as given."""
        crs = self.frame[0]
        code = crs.to_epsg()
        return f"EPSG:{code}" if code is not None else (self.crs or crs.to_string())

    @property
    def crs_label(self) -> str:
        """The CRS code with its name, e.g. ``EPSG:32635 (WGS 84 / UTM zone 35N)``."""
        return f"{self.crs_name} ({self.frame[0].name})"

    def project(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Degrees to projected metres (not shifted to the scene's origin)."""
        x, y = self.frame[1].transform(np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64))
        return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)

    @cached_property
    def rectangle(self) -> np.ndarray:
        """(2, 2) float64 [[xmin, ymin], [xmax, ymax]] of the area in projected metres."""
        if self.center is not None:
            cx, cy = self.project(self.center[1], self.center[0])
            half = 0.5 * np.asarray(self.size)
            lo = np.array([float(cx), float(cy)]) - half
            return np.stack([lo, lo + 2 * half])
        s, w, n, e = self.bbox
        t = np.linspace(0.0, 1.0, 33)
        lat = np.concatenate([np.full_like(t, s), n + 0 * t, s + (n - s) * t, s + (n - s) * t])
        lon = np.concatenate([w + (e - w) * t, w + (e - w) * t, np.full_like(t, w), np.full_like(t, e)])
        x, y = self.project(lon, lat)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise MmwsimError(f"bbox {self.spec()}: cannot be projected to {self.crs_name}")
        lo = np.array([x.min(), y.min()])
        # whole centimetres, so the area's edges lie on the grid footprints are snapped to
        span = np.ceil(np.array([x.max(), y.max()]) * 100.0 - lo * 100.0 - 1e-6) / 100.0
        rect = np.stack([lo, lo + span])
        if np.max(rect[1] - rect[0]) > MAX_AREA_SIZE:
            raise MmwsimError(f"bbox {self.spec()}: at most {MAX_AREA_SIZE:g} m per side")
        return rect

    @property
    def origin(self) -> np.ndarray:
        """(2,) float64 projected coordinates of the scene's origin (the south-west corner), metres."""
        return self.rectangle[0].copy()

    @property
    def extent(self) -> np.ndarray:
        """(2,) float64 width and height of the area in the scene's frame, metres."""
        if self.size is not None:
            return np.asarray(self.size, dtype=np.float64)
        return np.round((self.rectangle[1] - self.rectangle[0]) * 100.0) / 100.0

    def lon_lat_bounds(self, margin: float = 50.0) -> tuple[float, float, float, float]:
        """(west, south, east, north) degrees of the rectangle grown by ``margin`` metres."""
        (x0, y0), (x1, y1) = self.rectangle
        t = np.linspace(0.0, 1.0, 33)
        xs = np.concatenate(
            [x0 + (x1 - x0) * t, x0 + (x1 - x0) * t, np.full_like(t, x0), np.full_like(t, x1)]
        )
        ys = np.concatenate(
            [np.full_like(t, y0), np.full_like(t, y1), y0 + (y1 - y0) * t, y0 + (y1 - y0) * t]
        )
        xs = xs + margin * np.sign(xs - 0.5 * (x0 + x1))
        ys = ys + margin * np.sign(ys - 0.5 * (y0 + y1))
        lon, lat = self.frame[2].transform(xs, ys)
        return float(np.min(lon)), float(np.min(lat)), float(np.max(lon)), float(np.max(lat))

    # ------------------------------------------------------------------ text
    def spec(self, with_crs: bool = True) -> str:
        """The area as catalogue parameters, e.g. ``center=60.17,24.94,size=400x400,crs=EPSG:32635``."""
        if self.bbox is not None:
            text = "bbox=" + ",".join(_fmt(v) for v in self.bbox)
        else:
            text = f"center={_fmt(self.center[0])},{_fmt(self.center[1])},size={_fmt(self.size[0])}x{_fmt(self.size[1])}"
        return f"{text},crs={self.crs_name}" if with_crs else text

    def key(self) -> str:
        """Text that identifies the area and its frame exactly (for cache keys)."""
        return f"{self.spec()}|{self.frame[0].to_wkt()}"
