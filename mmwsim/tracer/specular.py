"""Exact specular paths by the image method, checked against the real triangles with Embree.

For a reflector sequence and an end point, the reflection points are found back
from the end point through the images of the source; a path is kept only if every
reflection point lies between its neighbours and on the reflector's triangles, and
no leg is blocked. The last two conditions are checked at once: the first hit of a
ray cast from one interaction towards the next must be a triangle of the expected
reflector (a ray meets a plane at most once, so that hit is the reflection point),
and the last leg must reach the end point unoccluded.

The same unfolding serves the parts of a diffracted path before and after the
diffraction point (:mod:`.diffraction`).
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ..geometry import RayCaster
from ._vec import add, dot, norm, row, scale, sub
from .paths import Interaction
from .polarimetry import FaceMaterials, PathBatch, path_fields, spectral_norm
from .reflectors import Reflectors
from .visibility import EPS, check_paths

__all__ = ["SpecularSolver", "mirror_chain", "plane_point", "inside_box", "EPS"]
# Reflection points may sit this far outside a reflector's bounds (float64 noise) before
# Embree decides on the exact face.
_BOX_TOL = 1e-6


def mirror_chain(reflectors: Reflectors, source: np.ndarray, seqs: np.ndarray) -> np.ndarray:
    """Images of ``source`` after each prefix of each reflector sequence.

    Parameters
    ----------
    reflectors : Reflectors
    source : (3,) or (n, 3) float
        Point to mirror, metres (one per sequence, or one for all).
    seqs : (n, k) int
        Reflector sequences.

    Returns
    -------
    (n, k, 3) float64
        ``[:, j]`` is the image after reflections ``seqs[:, :j + 1]``.
    """
    n, k = seqs.shape
    imgs = np.empty((n, k, 3))
    cur = np.broadcast_to(np.asarray(source, dtype=np.float64), (n, 3))
    for j in range(k):
        cur = reflectors.mirror(cur, seqs[:, j])
        imgs[:, j] = cur
    return imgs


class SpecularSolver:
    """Exact specular paths: unfolding by images, leg checks, fields.

    Parameters
    ----------
    reflectors : Reflectors
    caster : RayCaster
        Embree queries over the scene's triangles (face ids index ``reflectors.face_reflector``).
    materials : FaceMaterials
    floor : float
        Paths whose amplitude (largest singular value of the Jones matrix) is below this
        are dropped (0 keeps all).
    """

    def __init__(
        self, reflectors: Reflectors, caster: RayCaster, materials: FaceMaterials, floor: float = 0.0
    ):
        self.reflectors = reflectors
        self.caster = caster
        self.materials = materials
        self.floor = float(floor)
        self.rays_cast = 0

    def check(
        self, tx: np.ndarray, rx: np.ndarray, points: np.ndarray, order: np.ndarray, types: np.ndarray,
        refs: np.ndarray, offsets: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """:func:`.visibility.check_paths` with this scene's Embree back-end; counts the rays."""
        good, faces, n = check_paths(
            self.caster, self.reflectors.face_reflector, self.reflectors.normal, tx, rx, points, order, types,
            refs, offsets,
        )  # fmt: skip
        self.rays_cast += n
        return good, faces

    def finish(
        self, tx: np.ndarray, rx: np.ndarray, rx_p: np.ndarray, length: np.ndarray, points: np.ndarray,
        order: np.ndarray, types: np.ndarray, faces: np.ndarray, wedge: np.ndarray, wedges=None,
        boundary: np.ndarray | None = None,
    ) -> list[PathBatch]:  # fmt: skip
        """Fields of valid paths, the gain floor, and one batch per interaction count.

        Diffracted paths (``wedges`` given) keep their ``wedge`` and ``boundary`` codes.
        """
        refl = self.reflectors
        refs = np.where(faces >= 0, refl.face_reflector[np.maximum(faces, 0)], 0)
        jones, aod, aoa = path_fields(
            tx, rx[rx_p], points, order, types, faces, refl.normal[refs], wedge, wedges, self.materials
        )
        keep = spectral_norm(jones) >= self.floor if self.floor > 0 else np.ones(len(order), bool)
        out = []
        for k in np.unique(order[keep]):
            m = keep & (order == k)
            out.append(
                PathBatch(
                    rx_p[m], length[m], points[m, :k], faces[m, :k], types[m, :k], jones[m], aod[m], aoa[m],
                    wedge[m] if wedges is not None else None, boundary[m] if boundary is not None else None,
                )
            )  # fmt: skip
        return out

    # ------------------------------------------------------------------ paths
    def solve(
        self, tx: np.ndarray, seqs: np.ndarray, images: np.ndarray, seq_p: np.ndarray, rx_p: np.ndarray, rx
    ) -> list[PathBatch]:
        """Exact specular paths for (sequence, receiver) pairs; returns the valid ones.

        Parameters
        ----------
        tx : (3,) float64
            Transmitter, metres.
        seqs : (n, k) int
            Candidate reflector sequences, k >= 1.
        images : (n, k, 3) float64
            :func:`mirror_chain` of ``tx`` through ``seqs``.
        seq_p, rx_p : (m,) int
            Pairs to solve.
        rx : (n_rx, 3) float64
            Receivers, metres.
        """
        k = seqs.shape[1]
        refl = self.reflectors
        m = len(seq_p)
        ok = np.zeros(m, bool)
        points = np.zeros((m, k, 3))
        length = np.zeros(m)
        _geometry(
            seq_p, rx_p, rx, seqs, images, refl.normal, refl.offset, refl.lo, refl.hi, ok, points, length
        )
        idx = np.flatnonzero(ok)
        seq_p, rx_p, points, length = seq_p[idx], rx_p[idx], points[idx], length[idx]
        refs = seqs[seq_p]
        order = np.full(len(idx), k, np.int64)
        types = np.full((len(idx), k), Interaction.REFLECTION, np.int8)
        good, faces = self.check(tx, rx[rx_p], points, order, types, refs, np.zeros((len(idx), 3)))
        g = np.flatnonzero(good)
        return self.finish(
            tx, rx, rx_p[g], length[g], points[g], order[g], types[g], faces[g], np.full(len(g), -1, np.int64)
        )

    def reach(
        self,
        tx: np.ndarray,
        seqs: np.ndarray,
        images: np.ndarray,
        seq_p: np.ndarray,
        ends: np.ndarray,
        with_points: bool = False,
    ):
        """Whether each point ``ends`` (m, 3) is reached from ``tx`` through sequence ``seqs[seq_p]``.

        The exact specular chain is unfolded and its legs checked, as for a receiver; ``seqs``
        may have zero columns (line of sight). With ``with_points``, also returns the
        reflection points (m, k, 3).
        """
        m, k = len(seq_p), seqs.shape[1]
        ok = np.zeros(m, bool)
        points = np.zeros((m, k, 3))
        if k:
            refl = self.reflectors
            _geometry(
                seq_p, np.arange(m), ends, seqs, images, refl.normal, refl.offset, refl.lo, refl.hi, ok, points,
                np.zeros(m),
            )  # fmt: skip
        else:
            ok[:] = True
        idx = np.flatnonzero(ok)
        good, _ = self.check(
            tx, ends[idx], points[idx], np.full(len(idx), k, np.int64),
            np.full((len(idx), k), Interaction.REFLECTION, np.int8), seqs[seq_p[idx]], np.zeros((len(idx), 3)),
        )  # fmt: skip
        ok[idx] = good
        return (ok, points) if with_points else ok

    def line_of_sight(self, tx: np.ndarray, rx: np.ndarray) -> list[PathBatch]:
        """Unblocked direct paths from ``tx`` to receivers ``rx`` (n, 3)."""
        m = len(rx)
        order = np.zeros(m, np.int64)
        empty = np.zeros((m, 0), np.int64)
        good, _ = self.check(
            tx, rx, np.zeros((m, 0, 3)), order, empty.astype(np.int8), empty, np.zeros((m, 3))
        )
        g = np.flatnonzero(good)
        length = np.linalg.norm(rx[g] - tx, axis=1)
        return self.finish(
            tx, rx, g, length, np.zeros((len(g), 0, 3)), order[g], empty[g].astype(np.int8), empty[g],
            np.full(len(g), -1, np.int64),
        )  # fmt: skip


@njit(cache=True)
def _geometry(seq_p, rx_p, rx, seqs, images, normal, offset, lo, hi, ok, points, length):  # pragma: no cover
    """Reflection points of (sequence, receiver) pairs, back from the receiver through the images.

    Sets ``ok`` where every point lies strictly inside its segment and inside its
    reflector's bounds (Embree then decides on the exact triangle).
    """
    k = seqs.shape[1]
    for i in range(len(seq_p)):
        s = seq_p[i]
        end = row(rx, rx_p[i])
        nxt = end
        good = True
        for j in range(k - 1, -1, -1):
            r = seqs[s, j]
            p = plane_point(nxt, row(images[s], j), row(normal, r), offset[r])
            if not inside_box(p, lo, hi, r):
                good = False
                break
            points[i, j, 0], points[i, j, 1], points[i, j, 2] = p
            nxt = p
        if good:
            ok[i] = True
            length[i] = norm(sub(end, row(images[s], k - 1)))


@njit(cache=True, inline="always")
def plane_point(p, img, n, d):  # pragma: no cover - compiled
    """Where the segment p -> img crosses the plane n . x = d (NaN if not strictly inside it)."""
    den = dot(n, sub(img, p))
    if den == 0.0:
        return (np.nan, np.nan, np.nan)
    t = (d - dot(n, p)) / den
    if not (1e-12 < t < 1.0 - 1e-12):
        return (np.nan, np.nan, np.nan)
    return add(p, scale(sub(img, p), t))


@njit(cache=True, inline="always")
def inside_box(p, lo, hi, r):  # pragma: no cover - compiled
    """Whether point p lies within reflector r's bounds, with float64 slack (NaN is outside)."""
    for a in range(3):
        if not (lo[r, a] - _BOX_TOL <= p[a] <= hi[r, a] + _BOX_TOL):
            return False
    return True
