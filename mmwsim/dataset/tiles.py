"""One tile of a data set: trace a block of receivers and turn the paths into PDPs.

:func:`compute_tile` is a plain function of (config JSON, tile number), so any
executor can run it: this process, a process pool or a Dask cluster. Each process
builds the scene, tracer and codebook once per configuration and keeps them.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from ..antennas import Codebook, make_codebook
from ..fingerprints import power_delay_profile, receive_pattern
from ..stages import STAGES
from ..tracer.paths import Paths
from .config import GenerateConfig

__all__ = ["TileResult", "compute_tile", "make_codebook_from", "build_plan", "install_plan"]

_CONTEXT: dict[str, tuple] = {}
_PLANS: dict = {}  # content hash -> TracerPlan handed over by the executor
_LOCK = threading.Lock()  # executors may run tiles on threads of one process; the tracer is not shared


@dataclass
class TileResult:
    """What one tile contributes to the store (receivers ``start:stop``).

    Attributes
    ----------
    tile : int
    outdoors, valid : (n,) bool
    pdp : (n, n_beams, n_bins) float16, dBm
    count : (n,) int32 paths per receiver
    paths : dict of str to ndarray
        Flat path arrays in receiver order: delay (m,) float64 s, jones (m, 2, 2) complex64,
        aod / aoa (m, 2) float32 rad, order (m,) int8, objects / faces (m, K) int32,
        points (m, K, 3) float32 m, types (m, K) int8, with K = max(max_reflections, 1).
    stages : dict of str to float
        Seconds this tile's process spent per stage since its last tile (for benchmarks).
    """

    tile: int
    outdoors: np.ndarray
    valid: np.ndarray
    pdp: np.ndarray
    count: np.ndarray
    paths: dict[str, np.ndarray]
    stages: dict[str, float]


def make_codebook_from(cfg: GenerateConfig) -> Codebook:
    c = cfg.codebook
    if c.kind == "rotating_horn":
        return make_codebook(
            c.kind,
            cfg.frequency,
            n_beams=c.n_beams,
            gain_dbi=c.gain_dbi,
            elevation_deg=c.elevation_deg,
            azimuth0_deg=c.azimuth0_deg,
        )
    return make_codebook(
        c.kind,
        cfg.frequency,
        n_horizontal=c.n_horizontal,
        n_vertical=c.n_vertical,
        azimuth_deg=c.azimuth0_deg,
    )


def _context(cfg: GenerateConfig, config_json: str):
    key = cfg.hash()
    ctx = _CONTEXT.get(key)
    if ctx is None:
        from ..scene import ReceiverGrid
        from ..tracer import Tracer

        scene = cfg.load_scene()
        if cfg.diffuse is not None:
            scene = scene.with_scattering(cfg.diffuse)
        grid = ReceiverGrid(cfg.grid_origin, cfg.grid_spacing, cfg.grid_shape, cfg.grid_height)
        if key in _PLANS:
            tracer = Tracer.from_plan(scene, _PLANS[key])
        else:
            tracer = Tracer(
                scene,
                np.asarray(cfg.transmitter),
                cfg.max_reflections,
                cfg.n_rays,
                diffraction=cfg.diffraction,
                min_gain_db=cfg.min_path_gain_db,
            )
        ctx = (scene, grid, tracer, make_codebook_from(cfg), receive_pattern(cfg.rx_gain_dbi))
        _CONTEXT.clear()  # one configuration per process at a time
        _CONTEXT[key] = ctx
    return ctx


def build_plan(cfg: GenerateConfig):
    """The tracer's candidates for the whole grid of ``cfg`` (a :class:`~mmwsim.tracer.TracerPlan`).

    Built once by the process that hands out tiles, so that workers shoot no rays.
    """
    with _LOCK:
        _, grid, tracer, _, _ = _context(cfg, cfg.model_dump_json())
        plan = tracer.plan(grid.positions())
        _CONTEXT.clear()  # this process computes no tiles: drop the rays
    return plan


def install_plan(key: str, plan) -> None:
    """Make this process build its tracer for configuration ``key`` from ``plan`` (executor initializer)."""
    _PLANS.clear()
    _PLANS[key] = plan


def compute_tile(config_json: str, tile: int, plan=None) -> TileResult:
    """Trace and profile the receivers of ``tile``; deterministic in (config, tile).

    ``plan`` (from :func:`build_plan`) spares this process the candidate search; the
    result is the same with or without it.
    """
    cfg = GenerateConfig.model_validate_json(config_json)
    if plan is not None and cfg.hash() not in _PLANS:
        install_plan(cfg.hash(), plan)
    with _LOCK:
        scene, grid, tracer, codebook, rx_pattern = _context(cfg, config_json)
        start, stop = cfg.tile_range(tile)
        rx = grid.positions()[start:stop]
        outdoors = scene.outdoors(rx)
        inside = np.flatnonzero(outdoors)
        traced = tracer.trace(rx[inside]) if len(inside) else None
    n = stop - start
    k = max(cfg.max_reflections, 1)
    if traced is None or traced.n_paths == 0:
        paths = _empty_paths(cfg, rx)
    else:
        paths = _widen(traced, rx, inside[traced.rx_index], k)
    with STAGES("PDP"):
        pdp = power_delay_profile(
            paths, codebook, rx_pattern, cfg.tx_power_dbm, cfg.sample_rate, cfg.n_bins, cfg.band_limited
        )
    lo, hi = cfg.bins
    valid = outdoors & np.any(pdp[:, :, lo:hi] >= cfg.threshold_dbm, axis=(1, 2))
    # The profiles above used every diffuse patch; the store keeps them merged per surface and bin.
    paths = paths.merge_diffuse(1.0 / cfg.sample_rate)
    arrays = {
        "delay": paths.delay.astype(np.float64),
        "jones": paths.jones.astype(np.complex64),
        "aod": paths.aod.astype(np.float32),
        "aoa": paths.aoa.astype(np.float32),
        "order": paths.order.astype(np.int8),
        "objects": paths.objects.astype(np.int32),
        "faces": paths.faces.astype(np.int32),
        "points": paths.points.astype(np.float32),
        "types": paths.types.astype(np.int8),
    }
    count = np.bincount(paths.rx_index, minlength=n).astype(np.int32)
    return TileResult(tile, outdoors, valid, pdp.astype(np.float16), count, arrays, STAGES.take())


def _empty_paths(cfg: GenerateConfig, rx: np.ndarray) -> Paths:
    k = max(cfg.max_reflections, 1)
    return Paths(
        tx=np.asarray(cfg.transmitter, dtype=np.float64),
        rx=rx,
        frequency=cfg.frequency,
        rx_index=np.zeros(0, np.int64),
        length=np.zeros(0),
        jones=np.zeros((0, 2, 2), np.complex128),
        aod=np.zeros((0, 2)),
        aoa=np.zeros((0, 2)),
        order=np.zeros(0, np.int8),
        faces=np.full((0, k), -1, np.int64),
        objects=np.full((0, k), -1, np.int32),
        points=np.full((0, k, 3), np.nan),
        types=np.zeros((0, k), np.int8),
    )


def _widen(p: Paths, rx: np.ndarray, rx_index: np.ndarray, k: int) -> Paths:
    """Paths re-indexed to all receivers of the tile, interaction arrays padded to ``k`` columns."""
    m, kk = p.faces.shape

    def pad(a: np.ndarray, fill) -> np.ndarray:
        if kk == k:
            return a
        out = np.full((m, k) + a.shape[2:], fill, dtype=a.dtype)
        out[:, :kk] = a[:, :k]
        return out

    return Paths(
        tx=p.tx,
        rx=rx,
        frequency=p.frequency,
        rx_index=rx_index.astype(np.int64),
        length=p.length,
        jones=p.jones,
        aod=p.aod,
        aoa=p.aoa,
        order=p.order,
        faces=pad(p.faces, -1),
        objects=pad(p.objects, -1),
        points=pad(p.points, np.nan),
        types=pad(p.types, 0),
    )
