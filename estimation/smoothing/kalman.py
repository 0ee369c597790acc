"""Kalman smoothing of per-step position matches: a constant-velocity (white-acceleration) model,
vectorised over trajectories. Tracking runs the Rauch-Tung-Striebel smoother; forecasting
extrapolates the filtered state.
"""

from __future__ import annotations

import numpy as np

__all__ = ["kalman_forecast", "rts_smoother"]


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
