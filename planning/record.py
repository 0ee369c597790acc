"""Rerun logging of a planner run: tree growth, informed ellipse, best path and cost on the iteration timeline."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr
import shapely

from mmwsim.recording import Entity, Recording, Timeline, log_footprints

from .freespace import FreeSpace
from .optimal import ShortestPath
from .planners import PLANNERS, PlanResult

__all__ = ["log_plan", "informed_ellipse"]

_TREE = (60, 170, 90)
_PATH = (220, 40, 40)
_OPTIMUM = (40, 90, 230)
_ELLIPSE = (230, 160, 30)
_CORRIDOR = (150, 110, 200)


def informed_ellipse(start, goal, cost: float, n: int = 96) -> np.ndarray | None:
    """The informed set's boundary: points whose distances to start and goal sum to ``cost``.

    Returns
    -------
    (n + 1, 2) float64 closed outline, metres; None when ``cost`` is not finite.
    """
    s, g = np.asarray(start, dtype=np.float64), np.asarray(goal, dtype=np.float64)
    c_min = float(np.linalg.norm(g - s))
    if not math.isfinite(cost) or cost < c_min:
        return None
    a, b = 0.5 * cost, 0.5 * math.sqrt(max(cost * cost - c_min * c_min, 0.0))
    t = np.linspace(0.0, 2 * math.pi, n + 1)
    u = (g - s) / c_min
    v = np.array([-u[1], u[0]])
    return 0.5 * (s + g) + np.outer(a * np.cos(t), u) + np.outer(b * np.sin(t), v)


def log_plan(
    rec: Recording, space: FreeSpace, result: PlanResult, optimum: ShortestPath | None = None
) -> None:
    """Log a run: static context (footprints, corridor, start/goal, optimum), then per snapshot
    the tree, best path and informed ellipse, and the cost curve, on the ``iteration`` timeline."""
    log_footprints(rec, space.scene)
    if space.corridor is not None:
        rings = [np.asarray(r.coords) for p in shapely.get_parts(space.corridor.polygon) for r in _rings(p)]
        rec.log(
            Entity.PLANNER_CORRIDOR,
            rr.LineStrips2D(
                rings, colors=[_CORRIDOR], radii=0.25, labels=[f"corridor {space.corridor.width:g} m"]
            ),
            static=True,
        )
        rec.log(
            f"{Entity.PLANNER_CORRIDOR}/trajectories",
            rr.LineStrips2D(list(space.corridor.trajectories), colors=[_CORRIDOR], radii=0.4),
            static=True,
        )
    rec.log(
        Entity.PLANNER_ENDPOINTS,
        rr.Points2D([result.start, result.goal], radii=2.0, colors=[(20, 20, 20)], labels=["start", "goal"]),
        static=True,
    )
    if optimum is not None:
        rec.log(
            Entity.PLANNER_OPTIMUM,
            rr.LineStrips2D(
                [optimum.path], colors=[_OPTIMUM], radii=0.5, labels=[f"optimum {optimum.length:.2f} m"]
            ),
            static=True,
        )
    informed = PLANNERS[result.planner][2]
    for snap in result.snapshots:
        rec.set_time(Timeline.ITERATION, snap.iteration)
        rec.log(Entity.PLANNER_TREE, rr.LineStrips2D(snap.edges, colors=[_TREE], radii=0.15))
        if snap.path is not None:
            rec.log(Entity.PLANNER_PATH, rr.LineStrips2D([snap.path], colors=[_PATH], radii=0.6))
        ell = informed_ellipse(result.start, result.goal, snap.cost) if informed else None
        if ell is not None:
            rec.log(Entity.PLANNER_ELLIPSE, rr.LineStrips2D([ell], colors=[_ELLIPSE], radii=0.3))
    if result.solved:
        rec.set_time(Timeline.ITERATION, result.iterations)
        rec.log(
            Entity.PLANNER_PATH,
            rr.LineStrips2D(
                [result.path], colors=[_PATH], radii=0.6, labels=[f"{result.label} {result.length:.2f} m"]
            ),
        )
    for it, _, cost in result.cost_curve:
        rec.set_time(Timeline.ITERATION, int(it))
        rec.log(f"{Entity.PLANNER_COST}/best", rr.Scalars(float(cost)))
    if optimum is not None:
        for it in (0, result.iterations):
            rec.set_time(Timeline.ITERATION, it)
            rec.log(f"{Entity.PLANNER_COST}/optimum", rr.Scalars(optimum.length))


def _rings(poly: shapely.Polygon):
    return [poly.exterior, *poly.interiors]
