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

from ..geometry import RayCaster
from .paths import Interaction
from .polarimetry import FaceMaterials, PathBatch, antenna_jones, reflection_chain, unit_legs
from .reflectors import Reflectors

__all__ = ["SpecularSolver", "mirror_chain", "EPS"]

EPS = 1e-3
"""Offset of leg origins off a reflecting plane, and clearance kept before a leg's end, metres."""
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
    """Unfolding and checking of specular reflection chains.

    Parameters
    ----------
    reflectors : Reflectors
    caster : RayCaster
        Embree queries over the scene's triangles (face ids index ``reflectors.face_reflector``).
    materials : FaceMaterials
    """

    def __init__(self, reflectors: Reflectors, caster: RayCaster, materials: FaceMaterials):
        self.reflectors = reflectors
        self.caster = caster
        self.materials = materials
        self.rays_cast = 0

    # ------------------------------------------------------------------ geometry
    def unfold(self, images: np.ndarray, refs: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reflection points of chains ending at ``end``, back through the source's images.

        Parameters
        ----------
        images : (m, k, 3) float64
            Images of each chain's source after each prefix of its reflections.
        refs : (m, k) int
            Reflectors of each chain.
        end : (m, 3) float64
            Where each chain ends (a receiver, or a diffraction point), metres.

        Returns
        -------
        alive : (m',) int64
            Chains whose reflection points lie inside their segments and reflectors' bounds.
        points : (m', k, 3) float64
            Their reflection points.
        """
        refl = self.reflectors
        m, k = refs.shape
        alive = np.arange(m)
        pts = np.empty((m, k, 3))
        nxt = end
        # The leg towards image j crosses plane j at the reflection point.
        for j in range(k - 1, -1, -1):
            r = refs[alive, j]
            img = images[alive, j]
            n = refl.normal[r]
            den = np.einsum("ij,ij->i", n, img - nxt)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (refl.offset[r] - np.einsum("ij,ij->i", n, nxt)) / den
                p = nxt + t[:, None] * (img - nxt)
            ok = (t > 1e-12) & (t < 1.0 - 1e-12)
            ok &= np.all((p >= refl.lo[r] - _BOX_TOL) & (p <= refl.hi[r] + _BOX_TOL), axis=1)
            alive, nxt = alive[ok], p[ok]
            pts[alive, j] = nxt
        return alive, pts[alive]

    def check(
        self, start: np.ndarray, points: np.ndarray, refs: np.ndarray, end: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Whether each chain's legs are clear: every reflection lands on its reflector, the end is reached.

        Parameters
        ----------
        start : (m, 3) float64
            Where each chain starts (the transmitter, or just off a diffraction point).
        points : (m, k, 3) float64
            Reflection points.
        refs : (m, k) int
        end : (m, 3) float64
            Where each chain ends; the last leg stops :data:`EPS` short of it.

        Returns
        -------
        good : (m,) bool
        faces : (m, k) int64
            Triangle hit at each reflection (-1 where none was).
        """
        refl = self.reflectors
        m, k = refs.shape
        good = np.ones(m, bool)
        faces = np.full((m, k), -1, np.int64)
        if k:
            origins = np.empty((m, k, 3))
            origins[:, 0] = start
            if k > 1:
                prev = points[:, :-1]
                n = refl.normal[refs[:, :-1]]
                side = np.sign(np.einsum("mki,mki->mk", points[:, 1:] - prev, n))
                origins[:, 1:] = prev + (side * EPS)[..., None] * n
            v = points - origins
            dist = np.linalg.norm(v, axis=2)
            _, f = self.caster.intersect(origins.reshape(-1, 3), (v / dist[..., None]).reshape(-1, 3))
            self.rays_cast += m * k
            f = f.reshape(m, k)
            hit_ref = np.where(f >= 0, refl.face_reflector[np.maximum(f, 0)], -1)
            good &= np.all(hit_ref == refs, axis=1)
            faces[:] = f
            last = points[:, -1]
            n = refl.normal[refs[:, -1]]
            side = np.sign(np.einsum("mi,mi->m", end - last, n))
            o = last + (side * EPS)[:, None] * n
        else:
            o = start
        v = end - o
        dist = np.linalg.norm(v, axis=1)
        sel = np.flatnonzero(good & (dist > EPS))
        blocked = self.caster.occluded(o[sel], v[sel] / dist[sel, None], dist[sel] - EPS)
        self.rays_cast += len(sel)
        good[sel[blocked]] = False
        good &= dist > EPS
        return good, faces

    # ------------------------------------------------------------------ paths
    def solve(
        self, tx: np.ndarray, seqs: np.ndarray, images: np.ndarray, seq_p: np.ndarray, rx_p: np.ndarray, rx
    ) -> PathBatch:
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
        refs = seqs[seq_p]
        alive, pts = self.unfold(images[seq_p], refs, rx[rx_p])
        seq_p, rx_p, refs = seq_p[alive], rx_p[alive], refs[alive]
        good, faces = self.check(np.broadcast_to(tx, (len(alive), 3)), pts, refs, rx[rx_p])
        seq_p, rx_p, refs, pts, faces = seq_p[good], rx_p[good], refs[good], pts[good], faces[good]
        nodes = np.concatenate([np.broadcast_to(tx, (len(rx_p), 1, 3)), pts, rx[rx_p][:, None]], axis=1)
        k_legs, _ = unit_legs(nodes)
        field = reflection_chain(k_legs, self.reflectors.normal[refs], faces, self.materials)
        length = np.linalg.norm(rx[rx_p] - images[seq_p, k - 1], axis=1)
        jones, aod, aoa = antenna_jones(field, k_legs[:, 0], k_legs[:, -1])
        jones *= (self.materials.wavelength / (4.0 * np.pi * length))[:, None, None]
        return PathBatch(
            rx_p, length, pts, faces, np.full(faces.shape, Interaction.REFLECTION, np.int8), jones, aod, aoa
        )

    def line_of_sight(self, tx: np.ndarray, rx: np.ndarray) -> PathBatch:
        """Unblocked direct paths from ``tx`` to receivers ``rx`` (n, 3)."""
        v = rx - tx
        dist = np.linalg.norm(v, axis=1)
        ok = dist > EPS
        d = np.zeros_like(v)
        d[ok] = v[ok] / dist[ok, None]
        blocked = self.caster.occluded(np.broadcast_to(tx, v.shape)[ok], d[ok], dist[ok] - EPS)
        self.rays_cast += int(ok.sum())
        idx = np.flatnonzero(ok)[~blocked]
        m = len(idx)
        field = np.broadcast_to(np.eye(3, dtype=complex), (m, 3, 3))
        jones, aod, aoa = antenna_jones(field, d[idx], d[idx])
        jones = jones * (self.materials.wavelength / (4.0 * np.pi * dist[idx]))[:, None, None]
        return PathBatch(
            idx,
            dist[idx],
            np.zeros((m, 0, 3)),
            np.zeros((m, 0), np.int64),
            np.zeros((m, 0), np.int8),
            jones,
            aod,
            aoa,
        )
