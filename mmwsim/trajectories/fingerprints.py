"""Fingerprint sequences of trajectories: per-step PDPs and noisy beamformed fingerprints.

A PDP source answers ``pdp_at(positions)`` with the per-beam power-delay profiles (dBm, -inf
where no signal) at continuous positions:

* :class:`GridPdp` looks them up on the data set's receiver grid, at the nearest grid point or
  interpolated bilinearly in dB between the four surrounding valid points;
* :class:`TracedPdp` computes them exactly at the positions with a user-supplied function
  (e.g. the ray tracer followed by the PDP stage).

:class:`SequenceLoader` turns trajectories into batches of (fingerprint sequence, positions)
with fresh noise at every draw: bit = 1 iff PDP + N(0, sigma^2) >= threshold, over the feature
bins (1..81 by default).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any, Protocol

import numpy as np

from ..fingerprints import BINS, SIGMA_DB, THRESHOLD_DBM, fingerprints
from ..scene import ReceiverGrid
from .errors import TrajectoryError
from .freespace import nearest_grid_index
from .trajectories import Trajectories

__all__ = [
    "FEATURE_BINS",
    "PdpSource",
    "GridPdp",
    "TracedPdp",
    "noisy_fingerprints",
    "pdp_sequences",
    "SequenceLoader",
]

FEATURE_BINS = slice(*BINS)
"""Bins 1..81 of the PDP form the fingerprint (N_s = 81)."""

_FLOOR_DBM = -300.0  # stands in for -inf while interpolating in dB


class PdpSource(Protocol):
    def pdp_at(self, positions: np.ndarray) -> np.ndarray: ...


def _take_rows(pdp: Any, index: np.ndarray, bins: slice) -> np.ndarray:
    """pdp[index, :, bins] for a numpy array or a zarr array (orthogonal read of unique rows)."""
    flat = index.reshape(-1)
    uniq, inverse = np.unique(flat, return_inverse=True)
    if isinstance(pdp, np.ndarray):
        rows = pdp[uniq][:, :, bins]
    elif hasattr(pdp, "get_orthogonal_selection"):
        rows = np.asarray(pdp.get_orthogonal_selection((uniq, slice(None), bins)))
    else:
        rows = np.asarray(pdp[uniq])[:, :, bins]
    return rows.astype(np.float32, copy=False)[inverse.reshape(-1)].reshape(index.shape + rows.shape[1:])


class GridPdp:
    """PDPs stored on a receiver grid, looked up at continuous positions.

    Parameters
    ----------
    grid : ReceiverGrid
        The data set's grid (index = ix + nx * iy).
    pdp : (grid.size, n_beams, n_bins) array-like, dBm
        numpy or zarr array; -inf where no signal.
    valid : (grid.size,) bool, optional
        Grid points with data; interpolation ignores the others.
    method : {"nearest", "linear"}
        Nearest grid point, or bilinear in dB over the valid surrounding points.
    bins : slice
        PDP bins to return (default all).
    """

    def __init__(
        self,
        grid: ReceiverGrid,
        pdp: Any,
        valid: np.ndarray | None = None,
        method: str = "nearest",
        bins: slice = slice(None),
    ):
        if method not in ("nearest", "linear"):
            raise TrajectoryError(f"PDP lookup method must be 'nearest' or 'linear', got {method!r}")
        if len(pdp.shape) != 3 or pdp.shape[0] != grid.size:
            raise TrajectoryError(
                f"PDP array of shape {tuple(pdp.shape)} does not fit a grid of {grid.size} points"
            )
        self.grid, self.pdp, self.method, self.bins = grid, pdp, method, bins
        self.valid = (
            np.ones(grid.size, dtype=bool) if valid is None else np.asarray(valid, dtype=bool).reshape(-1)
        )

    @classmethod
    def from_dataset(cls, dataset: Any, method: str = "nearest", bins: slice = slice(None)) -> GridPdp:
        """Adapter for an :class:`mmwsim.Dataset`-like object (``.grid``, ``.pdp``, ``.valid``)."""
        return cls(dataset.grid, dataset.pdp, getattr(dataset, "valid", None), method, bins)

    def pdp_at(self, positions: np.ndarray) -> np.ndarray:
        """PDPs at positions.

        Parameters
        ----------
        positions : (..., 2) float, metres

        Returns
        -------
        (..., n_beams, n_bins') float32, dBm (-inf where no signal)
        """
        p = np.asarray(positions, dtype=np.float64)
        if self.method == "nearest":
            return _take_rows(self.pdp, nearest_grid_index(self.grid, p), self.bins)
        g = self.grid
        nx, ny = g.shape
        u = (p[..., 0] - g.origin[0]) / g.spacing
        v = (p[..., 1] - g.origin[1]) / g.spacing
        i0 = np.clip(np.floor(u), 0, max(nx - 2, 0)).astype(np.int64)
        j0 = np.clip(np.floor(v), 0, max(ny - 2, 0)).astype(np.int64)
        fu = np.clip(u - i0, 0.0, 1.0)
        fv = np.clip(v - j0, 0.0, 1.0)
        i1 = np.minimum(i0 + 1, nx - 1)
        j1 = np.minimum(j0 + 1, ny - 1)
        corners = np.stack([i0 + nx * j0, i1 + nx * j0, i0 + nx * j1, i1 + nx * j1], axis=-1)
        w = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=-1)
        w = w * self.valid[corners]
        total = w.sum(axis=-1, keepdims=True)
        # No valid corner: fall back to the nearest point (the caller checked validity there).
        none = total[..., 0] <= 0
        w = np.where(none[..., None], 0.0, w / np.where(total > 0, total, 1.0))
        vals = _take_rows(self.pdp, corners, self.bins)  # (..., 4, beams, bins)
        vals = np.where(np.isfinite(vals), vals, _FLOOR_DBM)
        out = np.einsum("...c,...cbk->...bk", w.astype(np.float32), vals)
        if none.any():
            out[none] = _take_rows(self.pdp, nearest_grid_index(g, p[none]), self.bins)
        out[out <= _FLOOR_DBM + 1e-3] = -np.inf
        return out


class TracedPdp:
    """PDPs computed exactly at the continuous positions.

    Parameters
    ----------
    function : callable
        ``function(points)`` with points (m, 3) metres returning (m, n_beams, n_bins) dBm;
        e.g. the tracer followed by the PDP stage.
    height : float
        Receiver height, metres (z of every point).
    bins : slice
        PDP bins to return.
    """

    def __init__(
        self, function: Callable[[np.ndarray], np.ndarray], height: float, bins: slice = slice(None)
    ):
        self.function, self.height, self.bins = function, float(height), bins

    @classmethod
    def from_scene(
        cls,
        scene: Any,
        codebook: Any = None,
        max_reflections: int = 3,
        n_rays: int | None = None,
        bins: slice = slice(None),
        **pdp_options: Any,
    ) -> TracedPdp:
        """Trace exactly with :mod:`mmwsim.tracer` and :func:`mmwsim.fingerprints.power_delay_profile`.

        The candidate rays are shot once; every call solves the paths to the given positions.

        Parameters
        ----------
        scene : Scene
            With a transmitter; receivers at the scene's receiver-grid height.
        codebook : Codebook, optional
            Default: the 32-beam rotating horn at the scene's frequency.
        max_reflections : int
        n_rays : int, optional
            Candidate rays (tracer default if omitted).
        **pdp_options
            Passed to ``power_delay_profile`` (tx_power_dbm, n_bins, band_limited, ...).
        """
        from ..antennas import make_codebook
        from ..fingerprints import power_delay_profile
        from ..tracer import Tracer

        book = codebook if codebook is not None else make_codebook("rotating_horn", scene.frequency)
        kw = {} if n_rays is None else {"n_rays": n_rays}
        tracer = Tracer(scene, max_reflections=max_reflections, **kw)

        def function(points: np.ndarray) -> np.ndarray:
            return power_delay_profile(tracer.trace(points), book, **pdp_options)

        return cls(function, scene.receivers.height, bins)

    def pdp_at(self, positions: np.ndarray) -> np.ndarray:
        """(..., n_beams, n_bins') float32 PDPs at (..., 2) positions, dBm."""
        p = np.asarray(positions, dtype=np.float64)
        flat = p.reshape(-1, 2)
        pts = np.column_stack([flat, np.full(len(flat), self.height)])
        out = np.asarray(self.function(pts), dtype=np.float32)[:, :, self.bins]
        return out.reshape(p.shape[:-1] + out.shape[1:])


def pdp_sequences(source: PdpSource, trajectories: Trajectories | np.ndarray) -> np.ndarray:
    """Per-step PDPs of trajectories.

    Parameters
    ----------
    source : GridPdp or TracedPdp
    trajectories : Trajectories or (n, L, 2) positions

    Returns
    -------
    (n, L, n_beams, n_bins) float32, dBm
    """
    pos = trajectories.positions if isinstance(trajectories, Trajectories) else np.asarray(trajectories)
    return source.pdp_at(pos)


def noisy_fingerprints(
    pdp: np.ndarray, sigma_db: float, threshold_dbm: float, rng: np.random.Generator, dtype=np.uint8
) -> np.ndarray:
    """Beamformed fingerprints with fresh log-normal noise: 1 iff pdp + N(0, sigma^2) >= threshold.

    Delegates to :func:`mmwsim.fingerprints.fingerprints` over all bins given.

    Parameters
    ----------
    pdp : (..., n_beams, n_bins) float, dBm
    sigma_db : float
        Noise standard deviation, dB (0 for none).
    threshold_dbm : float
        Detection threshold, dBm.
    rng : numpy.random.Generator

    Returns
    -------
    (..., n_beams, n_bins) ``dtype`` (0/1)
    """
    pdp = np.asarray(pdp, dtype=np.float32)
    if not (np.isfinite(sigma_db) and sigma_db >= 0):
        raise TrajectoryError(f"noise sigma must be >= 0 dB, got {sigma_db!r}")
    # The PDPs arrive already cut to the wanted bins: use the whole window.
    bits = fingerprints(pdp, rng, sigma_db, threshold_dbm, bins=(0, pdp.shape[-1]))
    return bits if np.dtype(dtype) == np.uint8 else bits.astype(dtype)


class SequenceLoader:
    """Batches of (fingerprint sequence with fresh noise, true positions).

    Every pass draws new noise (and a new order when shuffling) from a stream seeded by
    ``(seed, pass number)``, so runs are reproducible and no two epochs see the same noise.

    Parameters
    ----------
    source : GridPdp or TracedPdp
        Where PDPs come from; give it ``bins=FEATURE_BINS`` to get the 81 feature bins.
    trajectories : Trajectories
    batch_size : int
    sigma_db, threshold_dbm : float
        Noise (dB) and detection threshold (dBm); defaults 6 dB and -115 dBm.
    shuffle : bool
    seed : int
    drop_last : bool
        Skip a final short batch.
    cache : bool
        Look the PDPs up once and keep them (float32); else look up every batch.
    dtype : numpy dtype
        Of the fingerprints (uint8 or float32).

    Yields
    ------
    fingerprints : (B, L, n_beams, n_bins) ``dtype``
    positions : (B, L, 2) float32, metres
    """

    def __init__(
        self,
        source: PdpSource,
        trajectories: Trajectories,
        batch_size: int = 64,
        sigma_db: float = SIGMA_DB,
        threshold_dbm: float = THRESHOLD_DBM,
        shuffle: bool = True,
        seed: int = 0,
        drop_last: bool = False,
        cache: bool = True,
        dtype=np.float32,
    ):
        if not (isinstance(batch_size, int) and batch_size > 0):
            raise TrajectoryError(f"batch size must be a positive integer, got {batch_size!r}")
        if not (np.isfinite(sigma_db) and sigma_db >= 0):
            raise TrajectoryError(f"noise sigma must be >= 0 dB, got {sigma_db!r}")
        self.source, self.trajectories = source, trajectories
        self.batch_size, self.sigma_db, self.threshold_dbm = batch_size, float(sigma_db), float(threshold_dbm)
        self.shuffle, self.seed, self.drop_last, self.dtype = shuffle, int(seed), drop_last, dtype
        self.epoch = 0
        self._cache = None
        if cache and len(trajectories):
            pdp = pdp_sequences(source, trajectories)
            self._cache = pdp

    def __len__(self) -> int:
        n = len(self.trajectories)
        return n // self.batch_size if self.drop_last else -(-n // self.batch_size)

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(self.epoch,)))
        self.epoch += 1
        n = len(self.trajectories)
        order = rng.permutation(n) if self.shuffle else np.arange(n)
        for b in range(len(self)):
            idx = order[b * self.batch_size : (b + 1) * self.batch_size]
            pos = self.trajectories.positions[idx]
            pdp = self._cache[idx] if self._cache is not None else self.source.pdp_at(pos)
            yield (
                noisy_fingerprints(pdp, self.sigma_db, self.threshold_dbm, rng, self.dtype),
                pos.astype(np.float32),
            )
