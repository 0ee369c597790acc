"""Classical trackers: fingerprint matching on the grid followed by a smoother, nothing learned.

* :class:`KnnKalman` (``knn-kalman``), the paper's baseline: the maximum-likelihood grid point of
  every step (:class:`~estimation.matching.FingerprintMatcher`), smoothed by a Rauch-Tung-Striebel
  smoother (:mod:`estimation.smoothing.kalman`) whose noise parameters are chosen on validation data.
* :class:`MatchSmoother` (``match-cv``), the stronger tracker that ``tn-match`` starts from: instead
  of committing to each step's best match it keeps the most likely grid points of every step and
  smooths over all of them with a hidden-Markov model of constant-velocity motion
  (:mod:`estimation.smoothing.hmm`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import torch

from .data import SequenceSet
from .errors import EstimationError
from .matching import FingerprintMatcher
from .metrics import trajectory_rmse
from .smoothing.kalman import kalman_forecast, rts_smoother
from .smoothing.motion import MixtureMotion
from .smoothing.online import CandidateFilter

__all__ = ["KnnKalman", "MatchSmoother"]


class KnnKalman:
    """The classical method: :class:`FingerprintMatcher` on every step, then :func:`rts_smoother`
    (tracking) or :func:`kalman_forecast` (forecasting).

    Parameters
    ----------
    data : SequenceSet
        Supplies the grid (all valid points) and the threshold.
    sigma : float, dB
        Noise level of the observations the likelihood assumes.
    task : ``tracking`` or ``forecasting``
    horizon : int
        Forecast steps.
    q, r, gate : Kalman parameters (see :func:`rts_smoother`); :meth:`fit` picks them on validation data.
    """

    name = "knn-kalman"
    n_parameters = 0
    train_seconds = 0.0

    def __init__(
        self,
        data: SequenceSet,
        sigma: float,
        task: str = "tracking",
        horizon: int = 1,
        q: float = 1.0,
        r: float = 3.0,
        gate: float | None = 4.0,
    ):
        if task not in ("tracking", "forecasting"):
            raise EstimationError(f"unknown task {task!r}")
        self.matcher = FingerprintMatcher.shared(data.grid_pdp, data.grid_xy, sigma, data.threshold)
        self.matcher.tile_index()  # built now (or shared), so that prediction times are prediction
        self.task, self.horizon, self.q, self.r, self.gate = task, horizon, q, r, gate

    def smooth(self, z: np.ndarray) -> np.ndarray:
        if self.task == "tracking":
            return rts_smoother(z, q=self.q, r=self.r, gate=self.gate)
        return kalman_forecast(z, self.horizon, q=self.q, r=self.r, gate=self.gate)

    def predict(self, bits: torch.Tensor) -> np.ndarray:
        """``bits (n, T, M, N_s)`` -> ``(n, T_out, 2)`` metres."""
        return self.smooth(self.matcher.match(bits))

    def fit(
        self,
        bits: torch.Tensor,
        true: np.ndarray,
        qs=(0.3, 1.0, 3.0),
        rs=(1.0, 2.0, 4.0, 8.0),
        gates=(None, 3.0, 5.0),
    ) -> dict[str, float]:
        """Choose ``q, r, gate`` minimising the mean RMSE on validation fingerprints ``bits`` and
        targets ``true (n, T_out, 2)``; matching runs once, the grid search only re-smooths."""
        z = self.matcher.match(bits)
        best = (math.inf, None)
        for q, r, g in itertools.product(qs, rs, gates):
            self.q, self.r, self.gate = q, r, g
            err = float(trajectory_rmse(self.smooth(z), true).mean())
            if err < best[0]:
                best = (err, (q, r, g))
        self.q, self.r, self.gate = best[1]
        return {"q": self.q, "r": self.r, "gate": self.gate, "val_rmse": best[0]}


class MatchSmoother:
    """Fingerprint matching with a hidden-Markov constant-velocity smoother over candidates (tracking).

    Every step keeps its ``search`` most likely grid points; random-walk filters prune them to
    ``k`` and the constant-velocity model's smoothed posterior mean over those is the estimate
    (:class:`~estimation.smoothing.online.CandidateFilter` without its sub-cell stage). It has no parameters to fit: this is
    ``tn-match`` before training without its measured motion tables (and its sub-cell stage).

    Parameters
    ----------
    data : SequenceSet
        Supplies the grid (all valid points) and the threshold.
    sigma : float, dB
        Noise level of the observations the likelihood assumes.
    search, k : int
        Candidates per step searched and smoothed.
    """

    name = "match-cv"

    def __init__(self, data: SequenceSet, sigma: float, search: int = 256, k: int = 48):
        self.matcher = FingerprintMatcher.shared(data.grid_pdp, data.grid_xy, sigma, data.threshold)
        self.matcher.tile_index()  # built now (or shared), so that prediction times are prediction
        self.n_search, self.k = int(search), int(k)

    def search(self, bits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``bits (n, T, M, N_s)`` -> candidates ``xy (n, T, search, 2)`` metres and their
        log-likelihoods ``(n, T, search)`` (:meth:`FingerprintMatcher.track_candidates`)."""
        return self.matcher.track_candidates(bits, self.n_search)[:2]

    def filter(self, xy: torch.Tensor, score: torch.Tensor) -> CandidateFilter:
        """The candidate filter run forward over :meth:`search`'s candidates ``xy (n, T, search,
        2)`` metres and ``score (n, T, search)``: its :meth:`~CandidateFilter.smooth` gives any
        prefix's estimate."""
        return CandidateFilter(MixtureMotion(), None, k=self.k).run(xy, score)

    def smooth(self, xy: torch.Tensor, score: torch.Tensor) -> np.ndarray:
        """Posterior-mean positions ``(n, T, 2)`` metres of :meth:`search`'s candidates."""
        return self.filter(xy, score).smooth()[2].numpy().astype(np.float64)

    def predict(self, bits: torch.Tensor) -> np.ndarray:
        """``bits (n, T, M, N_s)`` -> ``(n, T, 2)`` metres."""
        return self.smooth(*self.search(bits))
