"""Path determination over a scene: OMPL planners with FCL validity, guided by estimated trajectories.

- :class:`AgentSpace`: valid states and motions of a cylinder agent (FCL, exact swept volume) in
  the scene's free space (:class:`mmwsim.geometry.FreeSpace`'s obstacles), optionally restricted to
  a :class:`Corridor` around estimated trajectories.
- :func:`plan`: RRT, RRT*, Informed RRT*, BIT*, AORRTC (OMPL) under an iteration or time budget.
- :func:`shortest_path`: the exact optimum in the same space (visibility graph).
- :func:`log_plan`: Rerun recording of tree growth, informed ellipse, best path and cost curve.

Names load on first use: :mod:`.names` (the planners' names) is readable without OMPL, FCL or rerun.
"""

from __future__ import annotations

from mmwsim.lazy import lazy_exports

_EXPORTS = {
    ".corridor": ("QUAD_SEGS", "Corridor", "load_corridor", "save_corridor"),
    ".errors": ("PlanningError",),
    ".names": ("PLANNER_NAMES",),
    ".optimal": ("ShortestPath", "free_region", "shortest_path"),
    ".planners": ("PLANNERS", "PlanResult", "Snapshot", "ompl_seed", "plan", "planner_label"),
    ".record": ("informed_ellipse", "log_plan"),
    ".space": ("AgentSpace",),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
