"""Fingerprint sequences of trajectories: per-step PDPs and noisy beamformed fingerprints.

A PDP source answers ``pdp_at(positions)`` with the per-beam power-delay profiles (dBm, -inf
where no signal) at continuous positions:

* :class:`GridPdp` looks them up on the data set's receiver grid, at the nearest grid point or
  interpolated bilinearly in dB between the four surrounding valid points
  (:meth:`GridPdp.from_dataset`);
* :class:`TracedPdp` computes them exactly at the positions with the ray tracer and the PDP
  stage (:meth:`TracedPdp.from_dataset` uses the data set's own configuration), or any
  user-supplied function.

:class:`SequenceLoader` turns trajectories into batches of (fingerprint sequence, positions)
with fresh noise at every draw: bit = 1 iff PDP + N(0, sigma^2) >= threshold, over the feature
bins (1..81 by default). With the nearest-point lookup the bits are drawn by the data set's
:class:`~mmwsim.fingerprints.FingerprintSampler` (exact Bernoulli draws of the same
probabilities, many times faster than Gaussian noise on every entry); otherwise the noise is
added to the looked-up or traced PDPs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import zarr

from ..fingerprints import BINS, SIGMA_DB, THRESHOLD_DBM, FingerprintSampler, fingerprints
from ..scene import ReceiverGrid
from .errors import TrajectoryError
from .freespace import nearest_grid_index
from .trajectories import Trajectories

if TYPE_CHECKING:
    from ..dataset import Dataset
    from ..scene import Scene

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

SamplerFactory = Callable[[float, float, tuple[int, int]], FingerprintSampler]
"""``(sigma_db, threshold_dbm, (start, stop)) -> FingerprintSampler`` over all grid points."""


class PdpSource(Protocol):
    def pdp_at(self, positions: np.ndarray) -> np.ndarray: ...


def _take_rows(pdp: np.ndarray | zarr.Array, index: np.ndarray, bins: slice) -> np.ndarray:
    """pdp[index, :, bins] as float32, reading each distinct row once (orthogonal read from zarr)."""
    flat = index.reshape(-1)
    uniq, inverse = np.unique(flat, return_inverse=True)
    if isinstance(pdp, zarr.Array):
        rows = np.asarray(pdp.get_orthogonal_selection((uniq, slice(None), bins)))
    else:
        rows = np.asarray(pdp)[uniq][:, :, bins]
    return rows.astype(np.float32, copy=False)[inverse.reshape(-1)].reshape(index.shape + rows.shape[1:])


class GridPdp:
    """PDPs stored on a receiver grid, looked up at continuous positions.

    Parameters
    ----------
    grid : ReceiverGrid
        The data set's grid (index = ix + nx * iy).
    pdp : (grid.size, n_beams, n_bins) numpy or zarr array, dBm
        -inf where no signal.
    valid : (grid.size,) bool, optional
        Grid points with data; interpolation ignores the others.
    method : {"nearest", "linear"}
        Nearest grid point, or bilinear in dB over the valid surrounding points.
    bins : slice
        PDP bins to return (default all).
    sampler : callable, optional
        ``(sigma_db, threshold_dbm, (start, stop)) -> FingerprintSampler`` over all grid points
        (a data set's cached :meth:`~mmwsim.dataset.Dataset.sampler`); default: built here from
        ``pdp`` on first use.
    """

    def __init__(
        self,
        grid: ReceiverGrid,
        pdp: np.ndarray | zarr.Array,
        valid: np.ndarray | None = None,
        method: str = "nearest",
        bins: slice = slice(None),
        sampler: SamplerFactory | None = None,
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
        self._sampler_factory = sampler
        self._samplers: dict[tuple, FingerprintSampler] = {}

    @classmethod
    def from_dataset(cls, dataset: Dataset, method: str = "nearest", bins: slice | None = None) -> GridPdp:
        """The PDPs of a data set (read lazily from its store) on its grid.

        Parameters
        ----------
        dataset : Dataset
        method : {"nearest", "linear"}
        bins : slice, optional
            Default: the data set's fingerprint window (``config["bins"]``, bins 1..81).
        """
        if bins is None:
            bins = slice(*dataset.config["bins"])
        return cls(dataset.grid, dataset.pdp, dataset.valid, method, bins, sampler=dataset.sampler)

    @property
    def window(self) -> tuple[int, int] | None:
        """The bins as a contiguous window ``(start, stop)``, or None (strided or empty)."""
        start, stop, step = self.bins.indices(self.pdp.shape[2])
        return (start, stop) if step == 1 and stop > start else None

    def index_at(self, positions: np.ndarray) -> np.ndarray:
        """(...,) int64 index of the grid point nearest to each (..., 2) position."""
        return nearest_grid_index(self.grid, positions)

    def sampler(self, sigma_db: float, threshold_dbm: float) -> FingerprintSampler | None:
        """Fast exact sampler of the fingerprints at grid points, or None where it does not apply.

        It draws each bit with probability P(PDP + N(0, sigma^2) >= threshold), the
        distribution of noise added to :meth:`pdp_at`, for the nearest-point lookup over a
        contiguous bin window; interpolated PDPs lie between grid points and have no row.

        Returns
        -------
        FingerprintSampler or None
            Rows are grid indices (:meth:`index_at`); fingerprints (n_beams, stop - start).
        """
        window = self.window
        if self.method != "nearest" or window is None:
            return None
        if self._sampler_factory is not None:
            return self._sampler_factory(float(sigma_db), float(threshold_dbm), window)
        key = (float(sigma_db), float(threshold_dbm), window)
        if key not in self._samplers:
            self._samplers[key] = FingerprintSampler(self.pdp, *key)
        return self._samplers[key]

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
            return _take_rows(self.pdp, self.index_at(p), self.bins)
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
            out[none] = _take_rows(self.pdp, self.index_at(p[none]), self.bins)
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
        scene: Scene,
        codebook: Any = None,
        max_reflections: int = 3,
        n_rays: int | None = None,
        bins: slice = slice(None),
        height: float | None = None,
        **pdp_options: Any,
    ) -> TracedPdp:
        """Trace exactly with :mod:`mmwsim.tracer` and :func:`mmwsim.fingerprints.power_delay_profile`.

        The candidate rays are shot once; every call solves the paths to the given positions.

        Parameters
        ----------
        scene : Scene
            With a transmitter.
        codebook : Codebook, optional
            Default: the 32-beam rotating horn at the scene's frequency.
        max_reflections : int
        n_rays : int, optional
            Candidate rays (tracer default if omitted).
        bins : slice
        height : float, optional
            Receiver height, metres (default the scene's receiver-grid height).
        **pdp_options
            Passed to ``power_delay_profile`` (rx_pattern, tx_power_dbm, n_bins, band_limited, ...).
        """
        from ..antennas import make_codebook
        from ..fingerprints import power_delay_profile
        from ..tracer import Tracer

        book = codebook if codebook is not None else make_codebook("rotating_horn", scene.frequency)
        kw = {} if n_rays is None else {"n_rays": n_rays}
        tracer = Tracer(scene, max_reflections=max_reflections, **kw)

        def function(points: np.ndarray) -> np.ndarray:
            return power_delay_profile(tracer.trace(points), book, **pdp_options)

        return cls(function, scene.receivers.height if height is None else height, bins)

    @classmethod
    def from_dataset(
        cls, dataset: Dataset, bins: slice | None = None, scene: Scene | None = None
    ) -> TracedPdp:
        """Trace exactly with the data set's own configuration.

        Scene and transmitter, reflections, candidate rays, codebook, receive gain, transmit
        power, sampling and receiver height are the ones the data set was generated with, so
        at grid points the result is its stored PDPs (before their float16 rounding).

        Parameters
        ----------
        dataset : Dataset
        bins : slice, optional
            Default: the data set's fingerprint window.
        scene : Scene, optional
            The data set's scene if already loaded.
        """
        from ..dataset import GenerateConfig
        from ..dataset.tiles import make_codebook_from
        from ..fingerprints import receive_pattern

        cfg = GenerateConfig.model_validate(dataset.config)
        return cls.from_scene(
            dataset.scene() if scene is None else scene,
            make_codebook_from(cfg),
            cfg.max_reflections,
            cfg.n_rays,
            slice(*cfg.bins) if bins is None else bins,
            height=cfg.grid_height,
            rx_pattern=receive_pattern(cfg.rx_gain_dbi),
            tx_power_dbm=cfg.tx_power_dbm,
            sample_rate=cfg.sample_rate,
            n_bins=cfg.n_bins,
            band_limited=cfg.band_limited,
        )

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
        Where PDPs come from; give it ``bins=FEATURE_BINS`` to get the 81 feature bins
        (:meth:`from_dataset` does).
    trajectories : Trajectories
    batch_size : int
    sigma_db, threshold_dbm : float
        Noise (dB) and detection threshold (dBm); defaults 6 dB and -115 dBm.
    shuffle : bool
    seed : int
    drop_last : bool
        Skip a final short batch.
    cache : bool
        Look the PDPs up once and keep them (float32); else look up every batch. (With the
        fast sampler only the grid indices are kept, whatever this says.)
    dtype : numpy dtype
        Of the fingerprints (uint8 or float32).
    fast : bool
        Draw the bits with the source's :meth:`GridPdp.sampler` where there is one (nearest
        lookup); False adds Gaussian noise to the looked-up PDPs (same distribution, slower).

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
        fast: bool = True,
    ):
        if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size <= 0:
            raise TrajectoryError(f"batch size must be a positive integer, got {batch_size!r}")
        if not (np.isfinite(sigma_db) and sigma_db >= 0):
            raise TrajectoryError(f"noise sigma must be >= 0 dB, got {sigma_db!r}")
        self.source, self.trajectories = source, trajectories
        self.batch_size, self.sigma_db, self.threshold_dbm = batch_size, float(sigma_db), float(threshold_dbm)
        self.shuffle, self.seed, self.drop_last, self.dtype = shuffle, int(seed), drop_last, dtype
        self.epoch = 0
        self.sampler: FingerprintSampler | None = None
        self._index: np.ndarray | None = None
        self._cache: np.ndarray | None = None
        if fast and isinstance(source, GridPdp):
            self.sampler = source.sampler(self.sigma_db, self.threshold_dbm)
        if self.sampler is not None:
            self._index = source.index_at(trajectories.positions)  # (n, L) grid rows
        elif cache and len(trajectories):
            self._cache = pdp_sequences(source, trajectories)

    @classmethod
    def from_dataset(
        cls,
        dataset: Dataset,
        trajectories: Trajectories | str,
        method: str = "nearest",
        bins: slice | None = None,
        sigma_db: float | None = None,
        threshold_dbm: float | None = None,
        **options: Any,
    ) -> SequenceLoader:
        """Batches over a data set's grid PDPs.

        Parameters
        ----------
        dataset : Dataset
        trajectories : Trajectories or str
            Trajectories, or the name of a split stored in the data set.
        method : {"nearest", "linear"}
            Grid lookup (:class:`GridPdp`); nearest uses the data set's fast sampler.
        bins : slice, optional
            Default: the data set's fingerprint window (bins 1..81).
        sigma_db, threshold_dbm : float, optional
            Default: the data set's configuration.
        **options
            batch_size, shuffle, seed, drop_last, cache, dtype, fast.
        """
        t = dataset.trajectories(trajectories) if isinstance(trajectories, str) else trajectories
        cfg = dataset.config
        return cls(
            GridPdp.from_dataset(dataset, method, bins),
            t,
            sigma_db=cfg["sigma_db"] if sigma_db is None else sigma_db,
            threshold_dbm=cfg["threshold_dbm"] if threshold_dbm is None else threshold_dbm,
            **options,
        )

    def __len__(self) -> int:
        n = len(self.trajectories)
        return n // self.batch_size if self.drop_last else -(-n // self.batch_size)

    def _fingerprints(self, idx: np.ndarray, pos: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self.sampler is not None:
            rows = self._index[idx]
            bits = self.sampler.sample(rows.reshape(-1), rng).reshape(rows.shape + self.sampler.shape)
            return bits if np.dtype(self.dtype) == np.uint8 else bits.astype(self.dtype)
        pdp = self._cache[idx] if self._cache is not None else self.source.pdp_at(pos)
        return noisy_fingerprints(pdp, self.sigma_db, self.threshold_dbm, rng, self.dtype)

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(self.epoch,)))
        self.epoch += 1
        n = len(self.trajectories)
        order = rng.permutation(n) if self.shuffle else np.arange(n)
        for b in range(len(self)):
            idx = order[b * self.batch_size : (b + 1) * self.batch_size]
            pos = self.trajectories.positions[idx]
            yield self._fingerprints(idx, pos, rng), pos.astype(np.float32)
