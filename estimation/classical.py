"""Classical baseline: nearest-fingerprint matching on the grid, then a constant-velocity Kalman smoother.

Matching is maximum likelihood: with the noise model ``bit = 1 iff PDP + N(0, sigma^2) >= threshold``
every grid point g predicts bit (i, j) with probability ``p_gij = Phi((PDP_gij - threshold) / sigma)``,
and an observed fingerprint x scores ``sum_ij x_ij log p_gij + (1 - x_ij) log(1 - p_gij)``, i.e. one
matrix product ``x @ W.T + c`` with ``W = logit p`` and ``c = sum log(1 - p)``, done in chunks of grid
points with a running arg-max. The per-step matches are then smoothed by a Rauch-Tung-Striebel
smoother with a constant-velocity (white-acceleration) model, vectorised over trajectories; its noise
parameters are chosen on validation data. Forecasting extrapolates the filtered state.

:class:`MatchSmoother` (``match-cv``) is the stronger classical tracker that ``tn-match`` starts
from: instead of committing to each step's best match it keeps the most likely grid points of every
step and smooths over all of them with a hidden-Markov model of constant-velocity motion.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import torch

from .data import SequenceSet
from .errors import EstimationError
from .metrics import trajectory_rmse
from .models.candidates import candidate_features, cell_mean

__all__ = ["FingerprintMatcher", "rts_smoother", "kalman_forecast", "KnnKalman", "MatchSmoother"]


class FingerprintMatcher:
    """Maximum-likelihood grid points of noisy fingerprints.

    Parameters
    ----------
    grid_pdp : (G, M, N_s) tensor, dBm
    grid_xy : (G, 2) float, metres
    sigma : float, dB
        Noise level assumed by the likelihood (that of the observations).
    threshold : float, dBm
    eps : float
        Probabilities are clipped to ``[eps, 1 - eps]`` (in log space) so that a bit the model calls
        impossible costs a point ``log eps`` instead of vetoing it. The observations follow the
        model exactly, so a small floor is best: 1e-6 puts users standing still about 1.2 m closer on
        average than 1e-3 (13 on test/seen of the default data set at 6 dB).
    chunk : int
        Grid points per block when the weights are built.

    Notes
    -----
    The weights ``logit p`` are built once, ``(C, G)`` float32 for the ``C`` fingerprint entries in
    which any grid point has signal (about 200 MB for the default data set), so that scoring a
    fingerprint is a sum of the weight rows of its ones.
    """

    def __init__(
        self,
        grid_pdp: torch.Tensor,
        grid_xy: np.ndarray,
        sigma: float,
        threshold: float,
        eps: float = 1e-6,
        chunk: int = 16384,
    ):
        self.grid_pdp, self.grid_xy = grid_pdp, np.asarray(grid_xy, np.float64)
        self.sigma, self.threshold, self.eps, self.chunk = float(sigma), float(threshold), eps, chunk
        flat = grid_pdp.reshape(len(grid_pdp), -1)
        # Columns where no grid point has any signal can never read 1 and score all points alike.
        self.columns = torch.nonzero(torch.isfinite(flat).any(0)).flatten()
        self._w: torch.Tensor | None = None
        self._c: torch.Tensor | None = None

    def _weights(self, rows: slice) -> tuple[torch.Tensor, torch.Tensor]:
        pdp = self.grid_pdp[rows].reshape(-1, self.grid_pdp.shape[1] * self.grid_pdp.shape[2])
        pdp = pdp[:, self.columns].float()
        floor = math.log(self.eps)
        if self.sigma > 0:
            z = (pdp - self.threshold) / self.sigma
            log_p, log_q = torch.special.log_ndtr(z), torch.special.log_ndtr(-z)  # exact in both tails
        else:
            hit = pdp >= self.threshold
            log_p, log_q = torch.where(hit, 0.0, -math.inf), torch.where(hit, -math.inf, 0.0)
        log_p, log_q = log_p.clamp(min=floor), log_q.clamp(min=floor)
        return log_p - log_q, log_q.sum(1)

    def _tables(self) -> tuple[torch.Tensor, torch.Tensor]:
        if self._w is None:
            G = len(self.grid_pdp)
            w = torch.empty((len(self.columns), G), dtype=torch.float32)
            c = torch.empty(G, dtype=torch.float32)
            for k in range(0, G, self.chunk):
                wk, ck = self._weights(slice(k, k + self.chunk))
                w[:, k : k + len(ck)] = wk.T
                c[k : k + len(ck)] = ck
            self._w, self._c = w, c
        assert self._c is not None
        return self._w, self._c

    @torch.no_grad()
    def scores(self, bits: torch.Tensor) -> torch.Tensor:
        """Log-likelihood of every grid point: ``bits (N, M, N_s)`` -> ``(N, G)`` float32."""
        w, c = self._tables()
        x = bits.reshape(-1, bits.shape[-2] * bits.shape[-1])[:, self.columns]
        # Fingerprints are sparse (a few percent ones): x @ W as a sum of W's rows over the ones,
        # i.e. an embedding bag, is several times faster than the dense product.
        nz = torch.nonzero(x)
        offsets = torch.searchsorted(nz[:, 0].contiguous(), torch.arange(len(x)))
        return torch.nn.functional.embedding_bag(nz[:, 1], w, offsets, mode="sum") + c

    @torch.no_grad()
    def candidates(self, bits: torch.Tensor, k: int, block: int = 1024) -> tuple[torch.Tensor, torch.Tensor]:
        """The ``k`` most likely grid points of each fingerprint, best first.

        Parameters
        ----------
        bits : (..., M, N_s) tensor of 0/1
        k : int
        block : int
            Fingerprints scored at once (bounds the ``(block, G)`` score matrix).

        Returns
        -------
        scores : (..., k) float32 log-likelihoods
        rows : (..., k) int64 grid rows (indices into ``grid_xy``)
        """
        lead = bits.shape[:-2]
        flat = bits.reshape(-1, *bits.shape[-2:])
        k = min(int(k), len(self.grid_pdp))
        vals, rows = [], []
        for a in range(0, len(flat), block):
            v, i = self.scores(flat[a : a + block]).topk(k, dim=1)
            vals.append(v)
            rows.append(i)
        if not vals:
            return torch.zeros((*lead, k)), torch.zeros((*lead, k), dtype=torch.int64)
        return torch.cat(vals).reshape(*lead, k), torch.cat(rows).reshape(*lead, k)

    def candidate_points(self, bits: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`candidates` as positions: ``xy (..., k, 2)`` float32 metres and their
        log-likelihoods ``(..., k)``."""
        score, rows = self.candidates(bits, k)
        return torch.from_numpy(self.grid_xy[rows.numpy()]).float(), score

    def match(self, bits: torch.Tensor) -> np.ndarray:
        """Best grid point per fingerprint.

        Parameters
        ----------
        bits : (..., M, N_s) tensor of 0/1

        Returns
        -------
        (..., 2) float64 positions of the matched grid points, metres
        """
        _, rows = self.candidates(bits, 1)
        return self.grid_xy[rows[..., 0].numpy()]


def _cv_model(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    G = np.array([[dt**2 / 2, 0], [0, dt**2 / 2], [dt, 0], [0, dt]])
    return F, q**2 * G @ G.T


def _kalman_filter(z: np.ndarray, dt: float, q: float, r: float, gate: float | None, v0: float):
    """Forward pass; returns filtered and predicted means/covariances, (n, T, 4) and (n, T, 4, 4)."""
    n, T, _ = z.shape
    F, Q = _cv_model(dt, q)
    H = np.zeros((2, 4))
    H[0, 0] = H[1, 1] = 1
    R = r**2 * np.eye(2)
    x = np.zeros((n, 4))
    x[:, :2] = z[:, 0]
    P = np.broadcast_to(np.diag([r**2, r**2, v0**2, v0**2]), (n, 4, 4)).copy()
    xf, Pf = np.empty((n, T, 4)), np.empty((n, T, 4, 4))
    xp, Pp = np.empty((n, T, 4)), np.empty((n, T, 4, 4))
    for t in range(T):
        if t > 0:
            x = x @ F.T
            P = F @ P @ F.T + Q
        xp[:, t], Pp[:, t] = x, P
        S = P[:, :2, :2] + R
        Sinv = np.linalg.inv(S)
        innov = z[:, t] - x[:, :2]
        use = np.ones(n, dtype=bool)
        if gate is not None and t > 0:  # drop matches far outside the prediction (fingerprint aliasing)
            d2 = np.einsum("ni,nij,nj->n", innov, Sinv, innov)
            use = d2 <= gate**2
        K = P[:, :, :2] @ Sinv * use[:, None, None]
        x = x + np.einsum("nij,nj->ni", K, innov)
        P = P - K @ P[:, :2, :]
        xf[:, t], Pf[:, t] = x, P
    return xf, Pf, xp, Pp, F


def rts_smoother(
    z: np.ndarray,
    dt: float = 1.0,
    q: float = 1.0,
    r: float = 3.0,
    gate: float | None = None,
    v0: float = 10.0,
) -> np.ndarray:
    """Rauch-Tung-Striebel smoothing of 2D position measurements under a constant-velocity model.

    Parameters
    ----------
    z : (n, T, 2) float, metres
        Measured positions.
    dt : float, seconds between steps
    q : float, m/s^2
        Standard deviation of the white acceleration noise.
    r : float, metres
        Standard deviation of each measurement coordinate.
    gate : float, optional
        Measurements whose Mahalanobis distance from the prediction exceeds ``gate`` are ignored.
    v0 : float, m/s
        Prior standard deviation of the initial velocity.

    Returns
    -------
    (n, T, 2) float64 smoothed positions, metres
    """
    z = np.asarray(z, np.float64)
    xf, Pf, xp, Pp, F = _kalman_filter(z, dt, q, r, gate, v0)
    xs = xf.copy()
    Ps = Pf[:, -1]
    for t in range(z.shape[1] - 2, -1, -1):
        C = Pf[:, t] @ F.T @ np.linalg.inv(Pp[:, t + 1])
        xs[:, t] = xf[:, t] + np.einsum("nij,nj->ni", C, xs[:, t + 1] - xp[:, t + 1])
        Ps = Pf[:, t] + C @ (Ps - Pp[:, t + 1]) @ np.swapaxes(C, 1, 2)
    return xs[..., :2]


def kalman_forecast(
    z: np.ndarray,
    horizon: int,
    dt: float = 1.0,
    q: float = 1.0,
    r: float = 3.0,
    gate: float | None = None,
    v0: float = 10.0,
) -> np.ndarray:
    """Filter the observed ``z (n, T_obs, 2)`` and extrapolate ``horizon`` steps: ``(n, horizon, 2)``."""
    xf, _, _, _, F = _kalman_filter(np.asarray(z, np.float64), dt, q, r, gate, v0)
    x, out = xf[:, -1], []
    for _ in range(horizon):
        x = x @ F.T
        out.append(x[:, :2])
    return np.stack(out, 1)


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
        self.matcher = FingerprintMatcher(data.grid_pdp, data.grid_xy, sigma, data.threshold)
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

    Every step keeps its ``search`` most likely grid points; a random walk prunes them to ``k`` and
    the constant-velocity model's posterior mean over those is the estimate
    (:func:`~estimation.models.candidates.candidate_features`). It has no parameters to fit: this is
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
        self.matcher = FingerprintMatcher(data.grid_pdp, data.grid_xy, sigma, data.threshold)
        self.n_search, self.k = int(search), int(k)

    def search(self, bits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``bits (n, T, M, N_s)`` -> candidates ``xy (n, T, search, 2)`` metres and their
        log-likelihoods ``(n, T, search)``."""
        return self.matcher.candidate_points(bits, self.n_search)

    def smooth(self, xy: torch.Tensor, score: torch.Tensor) -> np.ndarray:
        """Posterior-mean positions ``(n, T, 2)`` metres of :meth:`search`'s candidates."""
        return cell_mean(*candidate_features(xy, score, self.k)).numpy().astype(np.float64)

    def predict(self, bits: torch.Tensor) -> np.ndarray:
        """``bits (n, T, M, N_s)`` -> ``(n, T, 2)`` metres."""
        return self.smooth(*self.search(bits))
