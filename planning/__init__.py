"""Path determination over a scene: OMPL planners with FCL validity, guided by estimated trajectories.

- :class:`AgentSpace`: valid states and motions of a cylinder agent (FCL, exact swept volume),
  optionally restricted to a :class:`Corridor` around estimated trajectories.
- :func:`plan`: RRT, RRT*, Informed RRT*, BIT*, AORRTC (OMPL) under an iteration or time budget.
- :func:`shortest_path`: the exact optimum in the same free space (visibility graph).
- :func:`log_plan`: Rerun recording of tree growth, informed ellipse, best path and cost curve.
"""

from .corridor import QUAD_SEGS, Corridor, load_corridor, save_corridor
from .errors import PlanningError
from .optimal import ShortestPath, free_region, shortest_path
from .planners import PLANNERS, PlanResult, Snapshot, ompl_seed, plan, planner_label
from .record import informed_ellipse, log_plan
from .space import AgentSpace

__all__ = [
    "PLANNERS",
    "QUAD_SEGS",
    "Corridor",
    "AgentSpace",
    "PlanResult",
    "PlanningError",
    "ShortestPath",
    "Snapshot",
    "free_region",
    "informed_ellipse",
    "log_plan",
    "load_corridor",
    "ompl_seed",
    "plan",
    "planner_label",
    "save_corridor",
    "shortest_path",
]
