"""Rerun logging of a planner run: tree growth, informed ellipse, best path and cost on the iteration timeline."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr
import shapely

from mmwsim.recording import (
    Entity,
    Recording,
    Timeline,
    log_footprints,
    log_legend,
    log_map_context,
    north_up,
)

from .optimal import ShortestPath
from .planners import PLANNERS, PlanResult
from .space import AgentSpace

__all__ = ["log_plan", "informed_ellipse"]

_TREE = (70, 190, 100)
_TREE_FINAL = (70, 190, 100, 70)
_PATH = (245, 70, 60)
_OPTIMUM = (80, 150, 255)
_ELLIPSE = (240, 170, 40)
_CORRIDOR = (170, 130, 220)
_ENDPOINTS = (245, 245, 245)


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
    rec: Recording, space: AgentSpace, result: PlanResult, optimum: ShortestPath | None = None
) -> None:
    """Log a run: static context (footprints, corridor, start/goal, optimum), the end of the
    search (final tree faint, path found, a summary, the best cost as bars), then per snapshot
    the tree, best path and informed ellipse, and the cost curve, on the ``iteration`` timeline.

    The static end state lets the Planner tab show the result whatever timeline is active; on
    the ``iteration`` timeline the growing search is drawn over it.
    """
    log_footprints(rec, space.scene)
    north_up(rec, Entity.PLANNER)
    log_map_context(rec, Entity.PLANNER, space.scene.footprints, _extent_points(space, result, optimum))
    if space.corridor is not None:
        rings = [np.asarray(r.coords) for p in shapely.get_parts(space.corridor.polygon) for r in _rings(p)]
        rec.log(
            Entity.PLANNER_CORRIDOR,
            rr.LineStrips2D(
                rings,
                colors=[_CORRIDOR],
                radii=0.25,
                labels=[f"corridor {space.corridor.width:g} m"],
                show_labels=False,
            ),
            static=True,
        )
        rec.log(
            f"{Entity.PLANNER_CORRIDOR}/trajectories",
            rr.LineStrips2D(
                list(space.corridor.trajectories), colors=[_CORRIDOR], radii=0.4, draw_order=10.0
            ),
            static=True,
        )
    rec.log(
        Entity.PLANNER_ENDPOINTS,
        rr.Points2D([result.start, result.goal], radii=1.5, colors=[_ENDPOINTS], labels=["start", "goal"]),
        static=True,
    )
    if optimum is not None:
        rec.log(
            Entity.PLANNER_OPTIMUM,
            _labelled_path(optimum.path, _OPTIMUM, 0.5, f"optimum {optimum.length:.2f} m", 20.0),
            static=True,
        )
    _log_result(rec, result, optimum)
    informed = PLANNERS[result.planner][2]
    for snap in result.snapshots:
        rec.set_time(Timeline.ITERATION, snap.iteration)
        rec.log(Entity.PLANNER_TREE, rr.LineStrips2D(snap.edges, colors=[_TREE], radii=0.15))
        if snap.path is not None:
            rec.log(
                Entity.PLANNER_PATH, rr.LineStrips2D([snap.path], colors=[_PATH], radii=0.6, draw_order=30.0)
            )
        ell = informed_ellipse(result.start, result.goal, snap.cost) if informed else None
        if ell is not None:
            rec.log(Entity.PLANNER_ELLIPSE, rr.LineStrips2D([ell], colors=[_ELLIPSE], radii=0.3))
    if result.solved:
        rec.set_time(Timeline.ITERATION, result.iterations)
        rec.log(
            Entity.PLANNER_PATH,
            _labelled_path(result.path, _PATH, 0.6, f"{result.label} {result.length:.2f} m", 30.0),
        )
    for it, _, cost in result.cost_curve:
        rec.set_time(Timeline.ITERATION, int(it))
        rec.log(f"{Entity.PLANNER_COST}/best", rr.Scalars(float(cost)))
    if optimum is not None:
        for it in (0, result.iterations):
            rec.set_time(Timeline.ITERATION, it)
            rec.log(f"{Entity.PLANNER_COST}/optimum", rr.Scalars(optimum.length))
    entries = [("start and goal", _ENDPOINTS), (f"{result.label} path", _PATH), ("tree", _TREE)]
    if informed:
        entries.append(("informed ellipse", _ELLIPSE))
    if optimum is not None:
        entries.append(("exact optimum", _OPTIMUM))
    if space.corridor is not None:
        entries.append(("corridor, its trajectories", _CORRIDOR))
    log_legend(rec, "planner", "planner", "planner (iteration timeline: search)", entries)


def _log_result(rec: Recording, result: PlanResult, optimum: ShortestPath | None) -> None:
    """The end of the search (static): final tree, path found, summary text, cost bars."""
    if result.snapshots:
        rec.log(
            f"{Entity.PLANNER_RESULT}/tree",
            rr.LineStrips2D(result.snapshots[-1].edges, colors=[_TREE_FINAL], radii=0.1),
            static=True,
        )
    if result.solved:
        rec.log(
            f"{Entity.PLANNER_RESULT}/path",
            _labelled_path(result.path, _PATH, 0.45, f"{result.label} {result.length:.2f} m", 30.0),
            static=True,
        )
    found = f"path of {result.length:.2f} m" if result.solved else "no path"
    lines = [
        f"**{result.label}**: {found} after {result.iterations} iterations ({result.run_time:.2f} s).",
        f"From ({result.start[0]:.1f}, {result.start[1]:.1f}) to ({result.goal[0]:.1f}, {result.goal[1]:.1f}) m.",
    ]
    if optimum is not None:
        ratio = f", ratio {result.length / optimum.length:.3f}" if result.solved else ""
        lines.append(f"Exact shortest path: {optimum.length:.2f} m{ratio}.")
    if result.problem:
        lines.append(f"Stopped: {result.problem}.")
    rec.log(
        Entity.PLANNER_SUMMARY, rr.TextDocument("\n\n".join(lines), media_type="text/markdown"), static=True
    )
    curve = np.asarray(result.cost_curve, dtype=np.float64).reshape(-1, 3)
    curve = curve[np.isfinite(curve[:, 2])]  # no bar before the first solution
    if len(curve):
        # One bar per improvement, as wide as it lasted: a step plot of the best cost.
        it = curve[:, 0]
        widths = np.diff(np.append(it, max(result.iterations, it[-1] + 1)))
        base = optimum.length if optimum is not None else 0.0
        rec.log(
            f"{Entity.PLANNER_COST}/excess" if optimum is not None else f"{Entity.PLANNER_COST}/length",
            rr.BarChart(
                curve[:, 2] - base, abscissa=it, widths=widths, color=_PATH
            ),  # bars start at abscissa
            static=True,
        )


def _labelled_path(path, colour, radius: float, label: str, draw_order: float) -> rr.LineStrips2D:
    """One path as a 2D strip, its label on hover, drawn above lines of lower ``draw_order``."""
    return rr.LineStrips2D(
        [path], colors=[colour], radii=radius, labels=[label], show_labels=False, draw_order=draw_order
    )


def _extent_points(space: AgentSpace, result: PlanResult, optimum: ShortestPath | None) -> np.ndarray:
    """(n, 2) points spanning what the planner view shows: ends, paths, final tree, corridor."""
    parts = [np.asarray([result.start, result.goal], dtype=np.float64)]
    if result.solved:
        parts.append(np.asarray(result.path, dtype=np.float64))
    if optimum is not None:
        parts.append(np.asarray(optimum.path, dtype=np.float64))
    if result.snapshots and len(result.snapshots[-1].edges):
        parts.append(np.asarray(result.snapshots[-1].edges, dtype=np.float64).reshape(-1, 2))
    if space.corridor is not None:
        x0, y0, x1, y1 = space.corridor.polygon.bounds
        parts.append(np.array([[x0, y0], [x1, y1]]))
    return np.concatenate(parts)


def _rings(poly: shapely.Polygon):
    return [poly.exterior, *poly.interiors]
