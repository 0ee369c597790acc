"""The resolved configuration of a generated data set (stored in it, with its content hash)."""

from __future__ import annotations

import hashlib
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from ..config import Int2, StrictModel, Vec2, Vec3, content_hash, validate
from ..constants import BINS, DEFAULT_RAYS, N_BINS, RX_GAIN_DBI, SAMPLE_RATE, SIGMA_DB, THRESHOLD_DBM
from ..errors import MmwsimError
from ..limits import check_fits

__all__ = ["CodebookConfig", "GenerateConfig", "check_tile_memory", "resolve_config", "scene_fingerprint"]

DEFAULT_TILE = 4096
DEFAULT_PATH_CHUNK = 32768
PDP_CHUNK = 1024


class CodebookConfig(StrictModel):
    """Transmit codebook; angles in degrees."""

    kind: Literal["rotating_horn", "planar_array"] = "rotating_horn"
    n_beams: int = Field(default=32, ge=1)
    gain_dbi: float = 24.5
    elevation_deg: float = Field(default=0.0, ge=-90.0, le=90.0)
    azimuth0_deg: float = 0.0
    n_horizontal: int = Field(default=8, ge=1)
    n_vertical: int = Field(default=4, ge=1)


class GenerateConfig(StrictModel):
    """Everything that determines the bytes of a data set.

    Lengths in metres, powers in dBm / dBi, frequencies in Hz. ``max_reflections`` bounds
    all interactions of a path (reflections, the diffraction, the diffuse scattering);
    ``diffuse`` is a scattering coefficient S set on every material for this run (None:
    the scene's own); paths weaker than ``min_path_gain_db`` are dropped (None: none are).
    """

    scene: str
    scene_sha256: str
    frequency: float = Field(gt=0)
    transmitter: Vec3
    tx_power_dbm: float = 30.0
    grid_origin: Vec2
    grid_spacing: float = Field(gt=0)
    grid_shape: Int2
    grid_height: float
    max_reflections: int = Field(default=3, ge=0, le=6)
    n_rays: int = Field(ge=1)
    diffraction: bool = True
    diffuse: float | None = Field(default=None, ge=0.0, le=1.0)
    min_path_gain_db: float | None = -180.0
    codebook: CodebookConfig = CodebookConfig()
    rx_gain_dbi: float = RX_GAIN_DBI
    sample_rate: float = Field(default=SAMPLE_RATE, gt=0)
    n_bins: int = Field(default=N_BINS, ge=1)
    band_limited: bool = False
    sigma_db: float = Field(default=SIGMA_DB, ge=0)
    threshold_dbm: float = THRESHOLD_DBM
    bins: Int2 = BINS
    tile_size: int = Field(default=DEFAULT_TILE, ge=1)
    path_chunk: int = Field(default=DEFAULT_PATH_CHUNK, ge=1)

    @model_validator(mode="after")
    def _consistent(self) -> GenerateConfig:
        if min(self.grid_shape) < 1:
            raise ValueError(f"grid_shape must be positive, got {list(self.grid_shape)}")
        lo, hi = self.bins
        if not 0 <= lo < hi <= self.n_bins:
            raise ValueError(f"bins must satisfy 0 <= first < last <= n_bins ({self.n_bins}), got {[lo, hi]}")
        return self

    @property
    def n_beams(self) -> int:
        c = self.codebook
        return c.n_beams if c.kind == "rotating_horn" else c.n_horizontal * c.n_vertical

    @property
    def n_rx(self) -> int:
        return int(self.grid_shape[0] * self.grid_shape[1])

    @property
    def n_tiles(self) -> int:
        return -(-self.n_rx // self.tile_size)

    @property
    def pdp_chunk(self) -> int:
        return min(self.tile_size, PDP_CHUNK)

    def tile_range(self, tile: int) -> tuple[int, int]:
        """Receivers [start, stop) of ``tile``."""
        return tile * self.tile_size, min((tile + 1) * self.tile_size, self.n_rx)

    def hash(self) -> str:
        return content_hash(self)

    def load_scene(self, spec: str | None = None):
        """The scene this configuration was resolved from, with its transmitter.

        Parameters
        ----------
        spec : str, optional
            Catalogue name or scene file to load instead of the stored ``scene`` (e.g. a file
            that has moved); it must hold the same scene.

        Raises
        ------
        MmwsimError
            If the scene's triangles, objects, materials or frequency differ from the ones
            the configuration was resolved from (``scene_sha256``).
        """
        from ..scene import load_scene

        name = self.scene if spec is None else str(spec)
        scene = load_scene(name, transmitter=self.transmitter)
        if scene_fingerprint(scene) != self.scene_sha256:
            raise MmwsimError(
                f"scene {name!r} is not the one this data set was generated from (or has changed since)"
            )
        return scene


# Peak bytes of a tile per (receiver, beam, bin): the complex taps as two float64 arrays, the power
# in float64 and its dBm conversion (the paths of a tile are small beside them).
_TILE_BYTES_PER_SAMPLE = 48
# What a worker process holds besides its tile: interpreter, libraries, scene and ray tracer.
_WORKER_BASE_BYTES = 256 << 20


def check_tile_memory(cfg: GenerateConfig, workers: int = 1) -> None:
    """Refuse a tile size (times the workers computing tiles at once) that cannot fit in memory."""
    n = min(cfg.tile_size, cfg.n_rx)
    per_worker = n * cfg.n_beams * cfg.n_bins * _TILE_BYTES_PER_SAMPLE + _WORKER_BASE_BYTES
    what = f"a tile of {n} receivers" + (f" in each of {workers} workers" if workers > 1 else "")
    check_fits(per_worker * workers, what)


def scene_fingerprint(scene) -> str:
    """SHA-256 of a scene's triangles, objects and materials (detects an edited scene file)."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(scene.vertices, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(scene.faces, dtype="<i8").tobytes())
    h.update(np.ascontiguousarray(scene.face_object, dtype="<i4").tobytes())
    for o in scene.objects:
        h.update(f"{o.name}|{o.kind}|{o.material!r}".encode())
    h.update(repr(float(scene.frequency)).encode())
    return h.hexdigest()


def resolve_config(
    scene_spec: str,
    scene,
    spacing: float | None = None,
    max_reflections: int = 3,
    n_rays: int | None = None,
    codebook: CodebookConfig | None = None,
    tile_size: int = DEFAULT_TILE,
    path_chunk: int = DEFAULT_PATH_CHUNK,
    band_limited: bool = False,
    diffraction: bool = True,
    diffuse: float | None = None,
    min_path_gain_db: float | None = -180.0,
) -> GenerateConfig:
    """The full configuration of a data set of ``scene`` (loaded from ``scene_spec``)."""
    if scene.transmitter is None:
        raise MmwsimError(f"scene {scene_spec!r} has no transmitter")
    grid = scene.receivers
    if spacing is not None:
        if not (spacing > 0 and np.isfinite(spacing)):
            raise MmwsimError(f"--spacing must be a positive number of metres, got {spacing!r}")
        grid = grid.with_spacing(float(spacing))
    if int(max_reflections) != max_reflections or not 0 <= max_reflections <= 6:
        raise MmwsimError(f"--max-reflections must be an integer from 0 to 6, got {max_reflections!r}")
    if diffuse is not None and not (np.isfinite(diffuse) and 0.0 <= diffuse <= 1.0):
        raise MmwsimError(f"--diffuse must be a scattering coefficient from 0 to 1, got {diffuse!r}")
    if min_path_gain_db is not None and not np.isfinite(min_path_gain_db):
        raise MmwsimError(f"the path gain floor must be a finite number of dB, got {min_path_gain_db!r}")
    if n_rays is not None and (int(n_rays) != n_rays or n_rays < 1):
        raise MmwsimError(f"--rays must be a positive whole number, got {n_rays!r}")
    if tile_size < 1 or path_chunk < 1:
        raise MmwsimError(f"tile size and path chunk must be positive, got {tile_size} and {path_chunk}")
    tile_size = int(tile_size)
    if tile_size > PDP_CHUNK and tile_size % PDP_CHUNK:
        raise MmwsimError(f"tile size above {PDP_CHUNK} must be a multiple of {PDP_CHUNK}, got {tile_size}")
    fields = dict(
        # a scene that knows its full spec (an OSM area with its CRS) is stored by it
        scene=str(getattr(scene, "spec", None) or scene_spec),
        scene_sha256=scene_fingerprint(scene),
        frequency=float(scene.frequency),
        transmitter=tuple(float(v) for v in scene.transmitter.position),
        tx_power_dbm=float(scene.transmitter.power_dbm),
        grid_origin=tuple(float(v) for v in grid.origin),
        grid_spacing=float(grid.spacing),
        grid_shape=tuple(int(v) for v in grid.shape),
        grid_height=float(grid.height),
        max_reflections=int(max_reflections),
        n_rays=int(DEFAULT_RAYS if n_rays is None else n_rays),
        diffraction=bool(diffraction),
        diffuse=None if diffuse is None else float(diffuse),
        min_path_gain_db=None if min_path_gain_db is None else float(min_path_gain_db),
        codebook=codebook or CodebookConfig(),
        band_limited=bool(band_limited),
        tile_size=tile_size,
        path_chunk=int(path_chunk),
    )
    return validate(GenerateConfig, fields, f"scene {scene_spec!r}")
