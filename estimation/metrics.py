"""Accuracy metrics: per-trajectory RMSE and its summaries (mean, 95th percentile), by kind."""

from __future__ import annotations

import numpy as np

from mmwsim.trajectories.motion import KINDS

__all__ = ["trajectory_rmse", "summarise", "summarise_by_kind"]


def trajectory_rmse(predicted: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Root-mean-square position error of each trajectory.

    ``RMSE_n = sqrt(mean_t ||y_hat_{n,t} - y_{n,t}||^2)``

    Parameters
    ----------
    predicted, true : (n, T, 2) float, metres

    Returns
    -------
    (n,) float64, metres
    """
    p, t = np.asarray(predicted, np.float64), np.asarray(true, np.float64)
    if p.shape != t.shape or p.ndim != 3 or p.shape[-1] != 2:
        raise ValueError(f"predicted {p.shape} and true {t.shape} must both be (n, T, 2)")
    return np.sqrt(((p - t) ** 2).sum(-1).mean(-1))


def summarise(rmse: np.ndarray) -> dict[str, float]:
    """``{"n", "mean", "median", "p95"}`` of per-trajectory RMSEs (metres); NaNs for an empty set.

    The 95th percentile is linear interpolation between order statistics (numpy's default).
    """
    r = np.asarray(rmse, np.float64)
    if r.size == 0:
        return {"n": 0, "mean": float("nan"), "median": float("nan"), "p95": float("nan")}
    return {
        "n": int(r.size),
        "mean": float(r.mean()),
        "median": float(np.median(r)),
        "p95": float(np.percentile(r, 95)),
    }


def summarise_by_kind(rmse: np.ndarray, kind: np.ndarray) -> dict[str, dict[str, float]]:
    """:func:`summarise` for all trajectories (``"all"``) and for each kind present.

    Parameters
    ----------
    rmse : (n,) float, metres
    kind : (n,) int, index into :data:`mmwsim.trajectories.KINDS`
    """
    out = {"all": summarise(rmse)}
    for code in np.unique(kind):
        out[KINDS[int(code)]] = summarise(np.asarray(rmse)[kind == code])
    return out
