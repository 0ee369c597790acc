"""The trajectory container: positions of many users sampled at a fixed rate."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import TrajectoryError
from .motion import KINDS

__all__ = ["Trajectories"]


@dataclass
class Trajectories:
    """A batch of equally long trajectories.

    Parameters
    ----------
    positions : (n, L, 2) float64
        x, y of every sample, metres.
    kind : (n,) uint8
        Index into :data:`~mmwsim.trajectories.motion.KINDS`.
    ids : (n,) int64
        Trajectory ids, unique within one generation run (splits keep them).
    events : (n, L - 1) int8
        What happened in each step (:data:`~mmwsim.trajectories.motion.EVENT_NAMES`).
    rate_hz : float
        Samples per second.
    attrs : dict
        Provenance (seed, models, ...), JSON-serialisable.
    holdout : (n,) bool, optional
        Whether each trajectory touches the spatial hold-out region (test split only).
    """

    positions: np.ndarray
    kind: np.ndarray
    ids: np.ndarray
    events: np.ndarray
    rate_hz: float = 1.0
    attrs: dict = field(default_factory=dict)
    holdout: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float64)
        n = len(self.positions)
        if self.positions.ndim != 3 or self.positions.shape[2] != 2:
            raise TrajectoryError(f"positions must have shape (n, L, 2), got {self.positions.shape}")
        self.kind = np.asarray(self.kind, dtype=np.uint8).reshape(n)
        self.ids = np.asarray(self.ids, dtype=np.int64).reshape(n)
        self.events = np.asarray(self.events, dtype=np.int8).reshape(n, max(self.length - 1, 0))
        self.holdout = (
            np.zeros(n, dtype=bool) if self.holdout is None else np.asarray(self.holdout, bool).reshape(n)
        )

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    @property
    def length(self) -> int:
        """Samples per trajectory."""
        return int(self.positions.shape[1])

    @property
    def dt(self) -> float:
        """Seconds between samples."""
        return 1.0 / self.rate_hz

    @property
    def kind_names(self) -> np.ndarray:
        """(n,) str kind names."""
        return np.asarray(KINDS)[self.kind]

    def of_kind(self, kind: str) -> Trajectories:
        """The trajectories of one kind."""
        return self.subset(self.kind == KINDS.index(kind))

    def subset(self, index: np.ndarray) -> Trajectories:
        """Trajectories selected by a boolean mask or integer index array (order kept)."""
        return Trajectories(
            self.positions[index],
            self.kind[index],
            self.ids[index],
            self.events[index],
            self.rate_hz,
            dict(self.attrs),
            self.holdout[index],
        )

    def speeds(self) -> np.ndarray:
        """(n, L - 1) float64 mean speed of every step, m/s."""
        return np.linalg.norm(np.diff(self.positions, axis=1), axis=2) * self.rate_hz

    @staticmethod
    def concatenate(parts: list[Trajectories], attrs: dict | None = None) -> Trajectories:
        """Stack batches of equal length and rate."""
        if not parts:
            raise TrajectoryError("nothing to concatenate")
        if len({p.length for p in parts}) != 1 or len({p.rate_hz for p in parts}) != 1:
            raise TrajectoryError("trajectories of different lengths or rates cannot be stacked")
        return Trajectories(
            np.concatenate([p.positions for p in parts]),
            np.concatenate([p.kind for p in parts]),
            np.concatenate([p.ids for p in parts]),
            np.concatenate([p.events for p in parts]),
            parts[0].rate_hz,
            dict(attrs if attrs is not None else parts[0].attrs),
            np.concatenate([p.holdout for p in parts]),
        )
