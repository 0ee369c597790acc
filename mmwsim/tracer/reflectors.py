"""Planar reflectors: the scene's triangles grouped by the plane they lie in.

A wall made of several triangles is one reflector, so that a specular path whose
reflection point falls on a shared triangle edge is solved (and counted) once.
Grouping is by unoriented plane: both sides of a thin wall, and coincident
back-to-back triangles, belong to the same reflector.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import Scene

__all__ = ["Reflectors", "group_reflectors"]

# Quantisation of plane keys: normals to 1e-6 (about 0.2 arc seconds), offsets to 0.1 mm.
_NORMAL_STEP = 1e-6
_OFFSET_STEP = 1e-4


@dataclass(frozen=True)
class Reflectors:
    """Planar reflectors of a scene.

    Parameters
    ----------
    normal : (n_ref, 3) float64
        Unit normal of each plane (sign canonical, not meaningful).
    offset : (n_ref,) float64
        Plane offset ``d`` in ``normal . x = d``, metres.
    lo, hi : (n_ref, 3) float64
        Axis-aligned bounds of each reflector's triangles, metres.
    face_reflector : (n_faces,) int64
        Reflector of each scene triangle; -1 for degenerate triangles.
    """

    normal: np.ndarray
    offset: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    face_reflector: np.ndarray

    @property
    def n(self) -> int:
        return int(len(self.offset))

    def mirror(self, points: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """Mirror images of ``points`` (..., 3) in the planes ``ref`` (...), metres."""
        n = self.normal[ref]
        s = np.einsum("...i,...i->...", points, n) - self.offset[ref]
        return points - 2.0 * s[..., None] * n


def group_reflectors(scene: Scene) -> Reflectors:
    """Group the scene's triangles into planar reflectors.

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    Reflectors
    """
    nrm = scene.face_normals.copy()
    n_faces = len(nrm)
    valid = np.linalg.norm(nrm, axis=1) > 0.5
    # Canonical sign: first clearly non-zero component positive.
    first = np.argmax(np.abs(nrm) > 1e-9, axis=1)
    sign = np.sign(nrm[np.arange(n_faces), first])
    sign[sign == 0] = 1.0
    nrm *= sign[:, None]
    tri = scene.vertices[scene.faces] if n_faces else np.zeros((0, 3, 3))
    d = np.einsum("ij,ij->i", nrm, tri.mean(axis=1)) if n_faces else np.zeros(0)
    key = np.column_stack([np.round(nrm / _NORMAL_STEP), np.round(d / _OFFSET_STEP)]).astype(np.int64)
    face_ref = np.full(n_faces, -1, dtype=np.int64)
    if valid.any():
        _, inv = np.unique(key[valid], axis=0, return_inverse=True)
        face_ref[valid] = inv.ravel()
    n_ref = int(face_ref.max()) + 1 if n_faces else 0
    normal = np.zeros((n_ref, 3))
    offset = np.zeros(n_ref)
    lo = np.full((n_ref, 3), np.inf)
    hi = np.full((n_ref, 3), -np.inf)
    if n_ref:
        idx = face_ref[valid]
        # Area-weighted mean plane of each group, renormalised.
        area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)[valid]
        np.add.at(normal, idx, nrm[valid] * area[:, None])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        cen = tri.mean(axis=1)[valid]
        wsum = np.bincount(idx, weights=area, minlength=n_ref)
        centre = np.stack([np.bincount(idx, weights=cen[:, k] * area, minlength=n_ref) for k in range(3)], 1)
        offset = np.einsum("ij,ij->i", normal, centre / wsum[:, None])
        np.minimum.at(lo, idx, tri[valid].min(axis=1))
        np.maximum.at(hi, idx, tri[valid].max(axis=1))
    return Reflectors(normal, offset, lo, hi, face_ref)
