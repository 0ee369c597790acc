"""Fingerprint sequences of trajectories: per-step PDPs from a fingerprint field and batches of
noisy fingerprints with fresh noise at every draw.

The PDPs come from any :class:`~mmwsim.fingerprints.FingerprintField` (a data set's grid, or
exact tracing); the bits from the one noise model (:class:`~mmwsim.fingerprints.NoiseModel`):
``bit = 1 iff PDP + N(0, sigma^2) >= threshold``. With a grid field's nearest-point lookup the bits
are drawn by the data set's :class:`~mmwsim.fingerprints.FingerprintSampler` (exact Bernoulli draws
of the same probabilities, many times faster than Gaussian noise on every entry).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from ..constants import SIGMA_DB, THRESHOLD_DBM
from ..fingerprints import FingerprintField, FingerprintSampler, GridField, NoiseModel
from .errors import TrajectoryError
from .store import read_trajectories
from .trajectories import Trajectories

if TYPE_CHECKING:
    from ..dataset import Dataset

__all__ = ["SequenceLoader", "pdp_sequences"]


def pdp_sequences(source: FingerprintField, trajectories: Trajectories | np.ndarray) -> np.ndarray:
    """Per-step PDPs of trajectories.

    Parameters
    ----------
    source : GridField or TracedField
    trajectories : Trajectories or (n, L, 2) positions

    Returns
    -------
    (n, L, n_beams, n_bins) float32, dBm
    """
    pos = trajectories.positions if isinstance(trajectories, Trajectories) else np.asarray(trajectories)
    return source.pdp_at(pos)


class SequenceLoader:
    """Batches of (fingerprint sequence with fresh noise, true positions).

    Every pass draws new noise (and a new order when shuffling) from a stream seeded by
    ``(seed, pass number)``, so runs are reproducible and no two epochs see the same noise.

    Parameters
    ----------
    source : GridField or TracedField
        Where PDPs come from; give it ``bins=slice(*BINS)`` to get the 81 fingerprint bins
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
        Draw the bits with the source's :meth:`GridField.sampler` where there is one (nearest
        lookup); False adds Gaussian noise to the looked-up PDPs (same distribution, slower).

    Yields
    ------
    fingerprints : (B, L, n_beams, n_bins) ``dtype``
    positions : (B, L, 2) float32, metres
    """

    def __init__(
        self,
        source: FingerprintField,
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
        self.noise = NoiseModel(sigma_db, threshold_dbm)  # the window: the source's bins
        self.source, self.trajectories = source, trajectories
        self.batch_size, self.sigma_db, self.threshold_dbm = (
            batch_size,
            self.noise.sigma_db,
            self.noise.threshold_dbm,
        )
        self.shuffle, self.seed, self.drop_last, self.dtype = shuffle, int(seed), drop_last, dtype
        self.epoch = 0
        self.sampler: FingerprintSampler | None = None
        self._index: np.ndarray | None = None
        self._cache: np.ndarray | None = None
        if fast and isinstance(source, GridField):
            self.sampler = source.sampler(self.noise)
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
            Grid lookup (:class:`~mmwsim.fingerprints.GridField`); nearest uses the data set's fast sampler.
        bins : slice, optional
            Default: the data set's fingerprint window (bins 1..81).
        sigma_db, threshold_dbm : float, optional
            Default: the data set's configuration.
        **options
            batch_size, shuffle, seed, drop_last, cache, dtype, fast.
        """
        t = read_trajectories(dataset, trajectories) if isinstance(trajectories, str) else trajectories
        cfg = dataset.config
        return cls(
            dataset.field(method, bins),
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
        bits = self.noise.whole(pdp.shape[-1]).bits(pdp, rng)  # the PDPs arrive cut to the window
        return bits if np.dtype(self.dtype) == np.uint8 else bits.astype(self.dtype)

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(self.epoch,)))
        self.epoch += 1
        n = len(self.trajectories)
        order = rng.permutation(n) if self.shuffle else np.arange(n)
        for b in range(len(self)):
            idx = order[b * self.batch_size : (b + 1) * self.batch_size]
            pos = self.trajectories.positions[idx]
            yield self._fingerprints(idx, pos, rng), pos.astype(np.float32)
