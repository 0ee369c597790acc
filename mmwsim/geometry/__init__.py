"""Geometry back-ends built from one set of triangles (Embree for rays, FCL for collision) and the
free space of the plane that trajectories and the planner share."""

from .collision import CollisionModel
from .freespace import CoverageMask, FreeSpace, scene_obstacles
from .raycast import RayCaster

__all__ = ["CollisionModel", "CoverageMask", "FreeSpace", "RayCaster", "scene_obstacles"]
