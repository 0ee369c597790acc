"""Ray queries against a triangle soup with Embree (embreex).

Embree works in float32; callers that need exact geometry solve it in float64
themselves and use this module only to find what a ray hits first.
"""

from __future__ import annotations

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

__all__ = ["RayCaster"]

_CHUNK = 1 << 20  # rays per Embree call; bounds the float32 temporaries


class RayCaster:
    """Nearest-hit and occlusion queries over one triangle set.

    Parameters
    ----------
    vertices : (n_vertices, 3) float
        Vertex positions, metres.
    faces : (n_faces, 3) int
        Vertex indices per triangle.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.n_faces = int(len(faces))
        self._scene = rtcore_scene.EmbreeScene()
        triangles = np.asarray(vertices, dtype=np.float32)[np.asarray(faces)]
        if self.n_faces:
            TriangleMesh(self._scene, triangles)

    def intersect(
        self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """First hit along each ray.

        Parameters
        ----------
        origins, directions : (n, 3) float
            Ray origins (m) and directions (need not be unit length; distances are in
            units of the direction's length).
        tmax : (n,) float or float, optional
            Farthest parameter considered.

        Returns
        -------
        t : (n,) float64
            Ray parameter of the hit, ``inf`` where nothing is hit.
        face : (n,) int64
            Index of the triangle hit, -1 where nothing is hit.
        """
        n = len(origins)
        t = np.full(n, np.inf)
        face = np.full(n, -1, dtype=np.int64)
        if n == 0 or self.n_faces == 0:
            return t, face
        for s in range(0, n, _CHUNK):
            sl = slice(s, min(n, s + _CHUNK))
            o = np.ascontiguousarray(origins[sl], dtype=np.float32)
            d = np.ascontiguousarray(directions[sl], dtype=np.float32)
            dists = None if tmax is None else _dists(tmax, sl, len(o))
            res = self._scene.run(o, d, dists=dists, output=1)
            prim = res["primID"].astype(np.int64)
            hit = prim >= 0
            face[sl] = prim
            tt = np.full(len(o), np.inf)
            tt[hit] = res["tfar"][hit]
            t[sl] = tt
        return t, face

    def occluded(
        self, origins: np.ndarray, directions: np.ndarray, tmax: np.ndarray | float = np.inf
    ) -> np.ndarray:
        """Whether anything lies along each ray before ``tmax``.

        Returns
        -------
        (n,) bool
        """
        n = len(origins)
        out = np.zeros(n, dtype=bool)
        if n == 0 or self.n_faces == 0:
            return out
        for s in range(0, n, _CHUNK):
            sl = slice(s, min(n, s + _CHUNK))
            o = np.ascontiguousarray(origins[sl], dtype=np.float32)
            d = np.ascontiguousarray(directions[sl], dtype=np.float32)
            res = self._scene.run(o, d, dists=_dists(tmax, sl, len(o)), query="OCCLUDED")
            out[sl] = np.asarray(res) >= 0
        return out


def _dists(tmax: np.ndarray | float, sl: slice, n: int) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (sl.stop,) if np.ndim(tmax) else (n,))
    arr = arr[sl] if np.ndim(tmax) else arr
    return np.ascontiguousarray(np.minimum(arr, np.finfo(np.float32).max), dtype=np.float32)
