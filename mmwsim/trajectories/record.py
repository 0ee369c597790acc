"""Trajectories in a Rerun recording: trails over the building footprints on the ``step`` timeline."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..recording import Entity, Recording, log_footprints, log_legend, log_map_context, log_track, north_up
from .motion import KINDS
from .trajectories import Trajectories

if TYPE_CHECKING:
    from ..scene import Scene

__all__ = ["KIND_COLORS", "log_trajectories"]

KIND_COLORS: dict[str, tuple[int, int, int]] = {
    "static": (170, 170, 170),
    "pedestrian": (70, 200, 100),
    "hybrid": (240, 170, 40),
    "vehicle": (80, 150, 255),
}


def log_trajectories(
    rec: Recording,
    trajectories: Trajectories,
    scene: Scene | None = None,
    max_shown: int = 200,
    source: str = "true",
    labels: bool = True,
) -> int:
    """Log trajectories: each whole track (static, faint), and a growing trail with a head point
    on the ``step`` timeline; one entity per trajectory.

    Entity ``trajectories/<id>/<source>`` holds the whole track, so a 2D view shows every
    trajectory whatever timeline is active; ``trajectories/<id>/<source>/now`` gets, at every step
    ``k``, the trail ``positions[:k+1]`` and the current position. Labels (kind and id) show on
    hover. The building footprints go to ``map/footprints`` (static) when a scene is given.

    Parameters
    ----------
    rec : Recording
    trajectories : Trajectories
    scene : Scene, optional
    max_shown : int
        At most this many trajectories (the first ones) are logged.
    source : str
        Last entity-path part (``true`` for ground truth, a model name for estimates).
    labels : bool
        Attach hover labels.

    Returns
    -------
    int
        Number of trajectories logged.
    """
    n = min(len(trajectories), max_shown)
    north_up(rec, Entity.TRAJECTORIES)
    if scene is not None:
        log_footprints(rec, scene)
        log_map_context(rec, Entity.TRAJECTORIES, scene.footprints, trajectories.positions[:n].reshape(-1, 2))
    for i in range(n):
        kind = KINDS[int(trajectories.kind[i])]
        ident = int(trajectories.ids[i])
        label = f"{kind} {ident}" if labels else None
        log_track(
            rec,
            Entity.trajectory(ident, source),
            trajectories.positions[i],
            KIND_COLORS[kind],
            label,
            alpha=110,
        )
    shown = sorted({KINDS[int(k)] for k in trajectories.kind[:n]}, key=list(KIND_COLORS).index)
    log_legend(
        rec,
        "trajectories",
        "kinds",
        "kinds (step timeline: trails)",
        [(kind, KIND_COLORS[kind]) for kind in shown],
    )
    return n
