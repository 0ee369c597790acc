"""Trajectories in a Rerun recording: trails over the building footprints on the ``step`` timeline."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from ..recording import Entity, Recording, Timeline, log_footprints
from .motion import KINDS
from .trajectories import Trajectories

if TYPE_CHECKING:
    from ..scene import Scene

__all__ = ["KIND_COLORS", "log_trajectories"]

KIND_COLORS: dict[str, tuple[int, int, int]] = {
    "static": (150, 150, 150),
    "pedestrian": (40, 170, 80),
    "hybrid": (230, 160, 20),
    "vehicle": (40, 110, 230),
}


def log_trajectories(
    rec: Recording,
    trajectories: Trajectories,
    scene: Scene | None = None,
    max_shown: int = 200,
    source: str = "true",
    labels: bool = True,
) -> int:
    """Log trajectories as growing trails with a head point, one entity per trajectory.

    Entity ``trajectories/<id>/<source>`` gets, at every step ``k`` of the ``step`` timeline,
    the trail ``positions[:k+1]`` and the current position. The building footprints go to
    ``map/footprints`` (static) when a scene is given.

    Parameters
    ----------
    rec : Recording
    trajectories : Trajectories
    scene : Scene, optional
    max_shown : int
        At most this many trajectories (the first ones) are logged.
    source : str
        Last entity-path part (``true`` for ground truth, a model name for estimates).

    Returns
    -------
    int
        Number of trajectories logged.
    """
    if scene is not None:
        log_footprints(rec, scene)
    n = min(len(trajectories), max_shown)
    for i in range(n):
        pos = trajectories.positions[i].astype(np.float32)
        kind = KINDS[int(trajectories.kind[i])]
        color = KIND_COLORS[kind]
        entity = Entity.trajectory(int(trajectories.ids[i]), source)
        label = [f"{kind} {int(trajectories.ids[i])}"] if labels else None
        steps = np.arange(len(pos))
        # One columnar call per trajectory: row k holds the trail up to step k and the head.
        columns = [
            *rr.LineStrips2D.columns(
                strips=[pos[: k + 1] for k in steps], colors=[color] * len(pos), radii=np.full(len(pos), 0.4)
            ),
            *rr.Points2D.columns(
                positions=pos,
                colors=[color] * len(pos),
                radii=np.full(len(pos), 1.5),
                labels=(label * len(pos)) if label else None,
            ),
        ]
        rec.stream.send_columns(
            entity, indexes=[rr.TimeColumn(Timeline.STEP, sequence=steps)], columns=columns
        )
    return n
