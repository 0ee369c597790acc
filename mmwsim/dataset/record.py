"""Rerun views of a data set: per-beam power maps, the best-beam map, PDPs and fingerprints."""

from __future__ import annotations

import os

import numpy as np
import rerun as rr

from ..recording import Entity, Recording, Timeline, log_scene
from .store import Dataset

__all__ = ["record_dataset", "log_dataset", "beam_power_dbm", "default_receivers"]

POWER_RANGE_DBM = (-140.0, -40.0)
NO_SIGNAL_DBM = -200.0


def beam_power_dbm(pdp: np.ndarray) -> np.ndarray:
    """Total received power per beam, (n, n_beams) float64 dBm, from PDPs (n, n_beams, n_bins) dBm."""
    mw = np.power(10.0, np.asarray(pdp, dtype=np.float64) / 10.0).sum(axis=-1)
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(mw)


def _colour(values: np.ndarray, cmap: str, lo: float, hi: float, mask: np.ndarray) -> np.ndarray:
    import matplotlib

    rgba = matplotlib.colormaps[cmap](np.clip((values - lo) / (hi - lo), 0.0, 1.0), bytes=True)
    rgba[~mask] = (40, 40, 40, 255)
    return rgba[..., :3]


def default_receivers(ds: Dataset, n: int = 3) -> np.ndarray:
    """``n`` valid receivers spread through the valid set (deterministic)."""
    valid = np.flatnonzero(ds.valid)
    if len(valid) == 0:
        return valid
    return valid[np.unique(np.linspace(0, len(valid) - 1, n + 2).round().astype(int)[1:-1])]


def record_dataset(
    ds: Dataset,
    path: str | os.PathLike,
    receivers: np.ndarray | None = None,
    scene=None,
    seed: int = 0,
) -> None:
    """Write a recording of ``ds`` to ``path`` (.rrd).

    Logs ``world/coverage/beam_power`` (one image per beam on the ``beam`` timeline),
    ``world/coverage/best_beam`` and, for each chosen receiver r, ``bff/rx_<r>/pdp``
    (beam x bin tensor, dBm), ``bff/rx_<r>/fingerprint`` (one noisy draw) and
    ``bff/rx_<r>/beam_power`` (a scalar per beam on the ``beam`` timeline).
    """
    families = ("world", "coverage", "bff") if scene is not None else ("coverage", "bff")
    with Recording(path, "dataset", families=families, config=ds.config) as rec:
        log_dataset(rec, ds, receivers, scene, seed)


def log_dataset(
    rec: Recording,
    ds: Dataset,
    receivers: np.ndarray | None = None,
    scene=None,
    seed: int = 0,
) -> None:
    """Log the entities of :func:`record_dataset` into an open :class:`~mmwsim.recording.Recording`."""
    nx, ny = ds.grid.shape
    n_beams = ds.n_beams
    rx = default_receivers(ds) if receivers is None else np.asarray(receivers, dtype=np.int64)
    if scene is not None:
        log_scene(rec, scene)
    power = np.empty((ds.n_rx, n_beams), dtype=np.float32)
    step = 8192
    for s in range(0, ds.n_rx, step):
        power[s : s + step] = beam_power_dbm(ds.pdp[s : s + step])
    signal = np.isfinite(power) & ds.valid[:, None]

    def image(values: np.ndarray) -> np.ndarray:  # (n_rx, ...) -> (ny, nx, ...) with north up
        return values.reshape((ny, nx) + values.shape[1:])[::-1]

    lo, hi = POWER_RANGE_DBM
    for b in range(n_beams):
        rec.set_time(Timeline.BEAM, b)
        rgb = _colour(power[:, b], "viridis", lo, hi, signal[:, b])
        rec.log(Entity.coverage("beam_power"), rr.Image(image(rgb)))
    best = np.argmax(np.where(signal, power, -np.inf), axis=1)
    rgb = _colour(best.astype(float), "twilight", 0.0, float(n_beams), signal.any(axis=1))
    rec.log(Entity.coverage("best_beam"), rr.Image(image(rgb)), static=True)

    rng = np.random.default_rng(seed)
    for r in rx:
        name = f"rx_{int(r)}"
        pdp = np.asarray(ds.pdp[int(r)], dtype=np.float32)
        shown = np.where(np.isfinite(pdp), pdp, NO_SIGNAL_DBM)
        rec.log(Entity.bff(name, "pdp"), rr.Tensor(shown, dim_names=["beam", "bin"]), static=True)
        bits = ds.fingerprints(np.array([r]), rng)[0]
        rec.log(Entity.bff(name, "fingerprint"), rr.Tensor(bits, dim_names=["beam", "bin"]), static=True)
        x, y, _ = ds.positions[int(r)]
        rec.log(
            Entity.bff(name, "position"),
            rr.TextDocument(f"receiver {int(r)} at ({x:g}, {y:g}) m"),
            static=True,
        )
        for b in range(n_beams):
            rec.set_time(Timeline.BEAM, b)
            value = float(power[int(r), b]) if np.isfinite(power[int(r), b]) else NO_SIGNAL_DBM
            rec.log(Entity.bff(name, "beam_power"), rr.Scalars(value))
