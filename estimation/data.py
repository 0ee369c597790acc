"""The internal data interface of the torch pipeline: grid PDPs, trajectories indexing them, fresh noise.

A :class:`SequenceSet` is what every model, trainer and evaluator works on; adapters (see
:mod:`estimation.adapter`) build it from a data set on disk, :mod:`estimation.synthetic` builds toy ones.
Fingerprints are never stored: every use draws the bits afresh from the grid PDP,
``bit = 1 iff PDP_dBm + N(0, sigma^2) >= threshold``, in torch with a seeded generator.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from .errors import EstimationError
from .noise import fingerprint_bits

__all__ = ["SequenceSet", "Normaliser", "Batch", "BatchSampler"]


@dataclass
class Normaliser:
    """Maps positions in metres to roughly [-1, 1] and back, using the grid extent.

    Parameters
    ----------
    centre : (2,) float, metres
    half_span : float, metres
        Half of the larger side of the grid extent.
    """

    centre: tuple[float, float]
    half_span: float

    @classmethod
    def from_extent(cls, lo: np.ndarray, hi: np.ndarray) -> Normaliser:
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        return cls(
            centre=(float((lo[0] + hi[0]) / 2), float((lo[1] + hi[1]) / 2)),
            half_span=float(max(np.max(hi - lo) / 2, 1e-9)),
        )

    def to_unit(self, xy: torch.Tensor) -> torch.Tensor:
        c = torch.tensor(self.centre, dtype=xy.dtype, device=xy.device)
        return (xy - c) / self.half_span

    def to_metres(self, u: torch.Tensor) -> torch.Tensor:
        c = torch.tensor(self.centre, dtype=u.dtype, device=u.device)
        return u * self.half_span + c

    def as_dict(self) -> dict:
        return {"centre": list(self.centre), "half_span": self.half_span}


@dataclass
class SequenceSet:
    """Trajectories over a grid of PDPs.

    Attributes
    ----------
    grid_pdp : (G, M, N_s) float16 or float32 tensor, dBm
        Per-beam power-delay profiles of the G grid points the trajectories use, already cut to the
        fingerprint bin window; ``-inf`` marks a bin without signal.
    grid_xy : (G, 2) float64 ndarray, metres
        Positions of those grid points.
    index : (n, L) int64 ndarray
        Row of ``grid_pdp`` looked up at each step (the grid point nearest to the true position).
    positions : (n, L, 2) float32 ndarray, metres
        True (continuous) positions.
    kind : (n,) int8 ndarray
        Index into :data:`mmwsim.trajectories.KINDS`.
    threshold : float, dBm
        Detection threshold of the fingerprint bits.
    extent : (2, 2) float ndarray, metres
        ``[[x_min, y_min], [x_max, y_max]]`` of the whole grid, used to normalise positions.
    streets : (e, 2, 2) float64 ndarray, metres, optional
        Street centre lines of the scene (segment end points), where it has any: the map whose
        lanes ``tn-match`` prefers for fast users (:meth:`Estimator.attach`).
    """

    grid_pdp: torch.Tensor
    grid_xy: np.ndarray
    index: np.ndarray
    positions: np.ndarray
    kind: np.ndarray
    threshold: float
    extent: np.ndarray
    streets: np.ndarray | None = None

    def __post_init__(self) -> None:
        n, L = self.index.shape
        if self.positions.shape != (n, L, 2):
            raise EstimationError(
                f"positions shape {self.positions.shape} does not match index {self.index.shape}"
            )
        if self.kind.shape != (n,):
            raise EstimationError(f"kind shape {self.kind.shape} does not match {n} trajectories")
        if self.grid_pdp.ndim != 3 or self.grid_xy.shape != (self.grid_pdp.shape[0], 2):
            raise EstimationError(
                f"grid_pdp {tuple(self.grid_pdp.shape)} / grid_xy {self.grid_xy.shape} mismatch"
            )
        if n and (self.index.min() < 0 or self.index.max() >= self.grid_pdp.shape[0]):
            raise EstimationError("trajectory index points outside the grid PDP")

    @property
    def n(self) -> int:
        return self.index.shape[0]

    @property
    def length(self) -> int:
        return self.index.shape[1]

    @property
    def n_beams(self) -> int:
        return int(self.grid_pdp.shape[1])

    @property
    def n_bins(self) -> int:
        return int(self.grid_pdp.shape[2])

    def subset(self, rows: np.ndarray) -> SequenceSet:
        """The trajectories ``rows`` (indices or boolean mask) over the same grid."""
        return SequenceSet(
            self.grid_pdp,
            self.grid_xy,
            self.index[rows],
            self.positions[rows],
            self.kind[rows],
            self.threshold,
            self.extent,
            self.streets,
        )

    def crop(self, start: int, length: int) -> SequenceSet:
        """Steps ``start .. start + length - 1`` of every trajectory."""
        if start < 0 or length < 1 or start + length > self.length:
            raise EstimationError(
                f"cannot crop steps {start}..{start + length - 1} of {self.length}-step trajectories"
            )
        s = slice(start, start + length)
        return SequenceSet(
            self.grid_pdp,
            self.grid_xy,
            self.index[:, s],
            self.positions[:, s],
            self.kind,
            self.threshold,
            self.extent,
            self.streets,
        )

    def normaliser(self) -> Normaliser:
        return Normaliser.from_extent(self.extent[0], self.extent[1])


@dataclass
class Batch:
    """One mini-batch: ``bits (B, T_in, M, N_s)``, targets ``y (B, T_out, 2)`` metres, rows ``(B,)``,
    and optionally what the network reads of the bits (``Estimator.inputs``), prepared ahead."""

    bits: torch.Tensor
    y: torch.Tensor
    rows: np.ndarray
    inputs: Any = None


class BatchSampler:
    """Mini-batches of fresh-noise fingerprint sequences for the tracking or forecasting task.

    Parameters
    ----------
    data : SequenceSet
    task : ``"tracking"`` or ``"forecasting"``
    sigma : float, dB
    batch_size : int
    lengths : (int, int)
        Tracking: the range of sequence lengths T a batch is cropped to (one T per batch, drawn
        uniformly). Forecasting: ``(T_obs, horizon)``.
    seed : int
        With ``epoch``, seeds the generator of every draw (order, crops, noise) so that an epoch is
        reproducible on its own, which is what makes resuming bitwise exact.
    shuffle : bool
    epoch_size : int
        Trajectories per epoch, a fresh random subset each epoch; 0 = all.
    """

    def __init__(
        self,
        data: SequenceSet,
        task: str,
        sigma: float,
        batch_size: int,
        lengths: tuple[int, int],
        seed: int,
        shuffle: bool = True,
        epoch_size: int = 0,
    ):
        if task not in ("tracking", "forecasting"):
            raise EstimationError(f"unknown task {task!r} (tracking, forecasting)")
        a, b = lengths
        need = b if task == "tracking" else a + b
        if a < 1 or b < 1 or (task == "tracking" and a > b) or need > data.length:
            raise EstimationError(f"lengths {lengths} do not fit {task} on {data.length}-step trajectories")
        self.data, self.task, self.sigma = data, task, float(sigma)
        self.batch_size, self.lengths, self.seed, self.shuffle = int(batch_size), (a, b), int(seed), shuffle
        self.per_epoch = min(int(epoch_size), data.n) if epoch_size > 0 else data.n

    def __len__(self) -> int:
        return -(-self.per_epoch // self.batch_size)

    def epoch(self, epoch: int):
        """Yield the :class:`Batch` es of ``epoch``."""
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        n = self.data.n
        order = torch.randperm(n, generator=g).numpy() if self.shuffle else np.arange(n)
        order = order[: self.per_epoch]
        for k in range(0, len(order), self.batch_size):
            rows = order[k : k + self.batch_size]
            yield self.make(rows, g)

    def singles(self, epoch: int, batch_size: int):
        """Yield the batches of single fingerprints of ``epoch`` (tracking, one step each): every step
        of the epoch's trajectories on its own, shuffled across trajectories, ``batch_size`` a batch;
        ``bits (B, 1, M, N_s)``, ``y (B, 1, 2)`` and ``rows`` the trajectory of each."""
        if self.task != "tracking":
            raise EstimationError("single fingerprints are for tracking")
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        d, n = self.data, self.data.n
        order = torch.randperm(n, generator=g).numpy() if self.shuffle else np.arange(n)
        order = order[: self.per_epoch]
        flat = (order[:, None] * d.length + np.arange(d.length)[None, :]).ravel()
        flat = flat[torch.randperm(len(flat), generator=g).numpy()] if self.shuffle else flat
        for k in range(0, len(flat), batch_size):
            rows, steps = np.divmod(flat[k : k + batch_size], d.length)
            bits = fingerprint_bits(
                d.grid_pdp[torch.from_numpy(d.index[rows, steps])], self.sigma, d.threshold, g
            )
            y = torch.from_numpy(np.ascontiguousarray(d.positions[rows, steps])).float()
            yield Batch(bits[:, None], y[:, None], rows)

    def make(self, rows: np.ndarray, g: torch.Generator) -> Batch:
        """One batch of trajectories ``rows`` with crops and noise drawn from ``g``."""
        d, L = self.data, self.data.length
        if self.task == "tracking":
            lo, hi = self.lengths
            T = int(torch.randint(lo, hi + 1, (1,), generator=g)) if hi > lo else lo
            t_in = t_out = T
        else:
            t_in, h = self.lengths
            T = t_in + h
        starts = (
            torch.randint(0, L - T + 1, (len(rows),), generator=g).numpy()
            if L > T
            else np.zeros(len(rows), int)
        )
        steps = starts[:, None] + np.arange(T)[None, :]
        idx = d.index[rows[:, None], steps]
        pos = d.positions[rows[:, None], steps]
        pdp = d.grid_pdp[torch.from_numpy(idx[:, :t_in])]
        bits = fingerprint_bits(pdp, self.sigma, d.threshold, g)
        y = torch.from_numpy(
            np.ascontiguousarray(pos[:, T - t_out :] if self.task == "tracking" else pos[:, t_in:])
        )
        return Batch(bits, y.float(), rows)
