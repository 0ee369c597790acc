"""Geometry back-ends built from one set of triangles: Embree for rays, FCL for collision."""

from .collision import CollisionModel
from .raycast import RayCaster

__all__ = ["CollisionModel", "RayCaster"]
