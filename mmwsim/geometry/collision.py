"""Collision queries against building meshes with FCL (python-fcl).

Note: ``fcl.continuousCollide`` crashes with BVH mesh models; a motion is checked
as a static swept shape (box or capsule along the step) instead.
"""

from __future__ import annotations

import fcl
import numpy as np

__all__ = ["CollisionModel"]


class CollisionModel:
    """An FCL bounding-volume hierarchy (OBBRSS) over one triangle set.

    Parameters
    ----------
    vertices : (n_vertices, 3) float
        Vertex positions, metres.
    faces : (n_faces, 3) int
        Vertex indices per triangle.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.n_faces = int(len(faces))
        self.bvh: fcl.BVHModel | None = None
        self.object: fcl.CollisionObject | None = None
        if self.n_faces == 0:  # FCL complains about empty models; nothing can collide anyway
            return
        bvh = fcl.BVHModel()
        bvh.beginModel(len(vertices), len(faces))
        bvh.addSubModel(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int32))
        bvh.endModel()
        self.bvh = bvh
        self.object = fcl.CollisionObject(bvh, fcl.Transform())

    def collides(self, geometry: fcl.CollisionGeometry, transform: fcl.Transform) -> bool:
        """Whether ``geometry`` placed at ``transform`` touches any triangle."""
        if self.n_faces == 0:
            return False
        other = fcl.CollisionObject(geometry, transform)
        return fcl.collide(self.object, other, fcl.CollisionRequest(), fcl.CollisionResult()) > 0

    def distance(self, geometry: fcl.CollisionGeometry, transform: fcl.Transform) -> float:
        """Smallest distance from ``geometry`` at ``transform`` to the triangles (m), <= 0 on contact."""
        if self.n_faces == 0:
            return float("inf")
        other = fcl.CollisionObject(geometry, transform)
        result = fcl.DistanceResult()
        return float(fcl.distance(self.object, other, fcl.DistanceRequest(), result))
