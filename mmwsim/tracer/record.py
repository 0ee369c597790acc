"""Rerun views of traced paths and of the shot candidate rays."""

from __future__ import annotations

import numpy as np
import rerun as rr

from ..recording import Entity, Recording
from .paths import Paths
from .tracer import Tracer

__all__ = ["log_paths", "log_candidates", "ORDER_COLORS"]

# Line of sight, then 1st, 2nd, 3rd and higher reflections.
ORDER_COLORS = np.array(
    [[255, 255, 255], [60, 200, 80], [250, 200, 40], [240, 90, 40], [200, 60, 200]], dtype=np.uint8
)


def log_paths(rec: Recording, paths: Paths, receivers: np.ndarray | None = None) -> int:
    """Paths of chosen receivers as line strips coloured by reflection order (one batched call).

    Parameters
    ----------
    rec : Recording
    paths : Paths
    receivers : (n,) int, optional
        Receiver indices to show; all by default.

    Returns
    -------
    int
        Number of strips logged.
    """
    sel = np.ones(paths.n_paths, bool) if receivers is None else np.isin(paths.rx_index, receivers)
    idx = np.flatnonzero(sel)
    strips = []
    for i in idx:
        k = int(paths.order[i])
        strips.append(np.vstack([paths.tx, paths.points[i, :k], paths.rx[paths.rx_index[i]]]))
    if strips:
        gain = paths.gain_db()[idx]
        rec.log(
            Entity.RAY_PATHS,
            rr.LineStrips3D(
                strips,
                colors=ORDER_COLORS[np.minimum(paths.order[idx], len(ORDER_COLORS) - 1)],
                radii=0.15,
                labels=[
                    f"rx {r}: {1e9 * d:.2f} ns, {g:.1f} dB"
                    for r, d, g in zip(paths.rx_index[idx], paths.delay[idx], gain, strict=True)
                ],
            ),
            static=True,
        )
    return len(strips)


def log_candidates(rec: Recording, tracer: Tracer) -> int:
    """An evenly spread sample of the rays shot from the transmitter, as line strips."""
    strips = [p.astype(np.float32) for p in tracer.shot.sample]
    if strips:
        rec.log(
            Entity.RAY_CANDIDATES,
            rr.LineStrips3D(strips, colors=[(120, 160, 255, 90)], radii=0.05),
            static=True,
        )
    return len(strips)
