"""The planners' names, importable without OMPL, FCL or rerun (the CLI offers them)."""

from __future__ import annotations

from typing import Literal, get_args

__all__ = ["PLANNER_NAMES", "PlannerName"]

PlannerName = Literal["rrt", "rrtstar", "irrtstar", "bitstar", "aorrtc"]
"""RRT, RRT*, Informed RRT*, BIT*, AORRTC (:data:`planning.PLANNERS` holds their OMPL classes)."""
PLANNER_NAMES: tuple[PlannerName, ...] = get_args(PlannerName)
