"""Ray queries against a triangle soup with Embree (embreex).

Embree works in float32; callers that need exact geometry solve it in float64
themselves and use this module only to find what a ray hits first.
"""

from __future__ import annotations

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from .._threads import pieces, thread_map

__all__ = ["RayCaster"]

_CHUNK = 1 << 20  # rays per Embree call at most; bounds the float32 temporaries
_MIN_SPLIT = 1 << 15  # rays below which one call beats handing pieces to threads


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

        def run(sl: slice) -> None:
            o = np.ascontiguousarray(origins[sl], dtype=np.float32)
            d = np.ascontiguousarray(directions[sl], dtype=np.float32)
            dists = None if tmax is None else _dists(tmax, sl, len(o))
            res = self._scene.run(o, d, dists=dists, output=1)
            prim = res["primID"]
            face[sl] = prim
            t[sl] = np.where(prim >= 0, res["tfar"], np.inf)

        thread_map(run, _chunks(n))
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

        def run(sl: slice) -> None:
            o = np.ascontiguousarray(origins[sl], dtype=np.float32)
            d = np.ascontiguousarray(directions[sl], dtype=np.float32)
            res = self._scene.run(o, d, dists=_dists(tmax, sl, len(o)), query="OCCLUDED")
            out[sl] = np.asarray(res) >= 0

        thread_map(run, _chunks(n))
        return out


def _dists(tmax: np.ndarray | float, sl: slice, n: int) -> np.ndarray:
    """``tmax`` (scalar or one per ray) for the ``n`` rays of ``sl``, float32 and finite."""
    arr = np.asarray(tmax, dtype=np.float64)
    arr = np.broadcast_to(arr[sl] if arr.ndim else arr, (n,))
    return np.ascontiguousarray(np.minimum(arr, np.finfo(np.float32).max), dtype=np.float32)


def _chunks(n: int) -> list[slice]:
    """``n`` rays cut into contiguous pieces: at most ``_CHUNK`` each, one per thread at least.

    Embree answers each ray on its own, so the pieces (run on threads, each writing its own
    slice of the result) give the same answer as one call.
    """
    return pieces(n, _MIN_SPLIT, _CHUNK)
