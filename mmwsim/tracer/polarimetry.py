"""Field bookkeeping along a path: reflection matrices, antenna bases, the path batch.

Every solver stage returns a :class:`PathBatch`; the orchestrator concatenates them
into :class:`~mmwsim.tracer.paths.Paths`. Fields are carried as 3x3 matrices acting
on transverse field vectors in global coordinates and projected on the antennas'
spherical bases at the end (see :mod:`mmwsim.tracer.paths`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import njit
from ..constants import SPEED_OF_LIGHT
from ._vec import dot, norm, row, scale, sub, unit
from .fresnel import (
    Surface,
    bounce_matrices,
    bounce_scalar,
    direction_angles,
    reflection_scalar,
    spherical_basis,
)
from .utd import diffraction_scalar

__all__ = [
    "PathBatch",
    "FaceMaterials",
    "path_fields",
    "spectral_norm",
    "unit_legs",
    "reflection_chain",
    "antenna_jones",
]


@dataclass
class PathBatch:
    """Paths of one kind and interaction count, to receivers of one trace call.

    Attributes
    ----------
    rx : (m,) int64
        Receiver of each path.
    length : (m,) float64
        Unfolded length, metres.
    points : (m, k, 3) float64
        Interaction points, metres.
    faces : (m, k) int64
        Triangle of each interaction (for a diffraction, a triangle of its 0-face).
    types : (m, k) int8
        :class:`~mmwsim.tracer.paths.Interaction` of each interaction.
    jones : (m, 2, 2) complex128
        Field transfer in the antennas' bases, spreading included.
    aod, aoa : (m, 2) float64
        Departure and arrival directions (zenith, azimuth), radians.
    wedge : (m,) int64, optional
        Wedge of each diffracted path.
    boundary : (m,) int8, optional
        Shadow boundary each diffracted path lies exactly on (:data:`~mmwsim.tracer.utd.BOUNDARIES`
        code; 0 for none).
    """

    rx: np.ndarray
    length: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    types: np.ndarray
    jones: np.ndarray
    aod: np.ndarray
    aoa: np.ndarray
    wedge: np.ndarray | None = None
    boundary: np.ndarray | None = None

    @property
    def k(self) -> int:
        return int(self.points.shape[1])

    def __len__(self) -> int:
        return int(len(self.rx))

    @staticmethod
    def empty(k: int) -> PathBatch:
        """No paths (of ``k`` interactions)."""
        z = np.zeros(0)
        return PathBatch(
            np.zeros(0, np.int64), z, np.zeros((0, k, 3)), np.zeros((0, k), np.int64), np.zeros((0, k), np.int8),
            np.zeros((0, 2, 2), np.complex128), np.zeros((0, 2)), np.zeros((0, 2)),
        )  # fmt: skip

    def select(self, mask: np.ndarray) -> PathBatch:
        """The paths where ``mask`` (m,) is true."""
        return PathBatch(
            *(
                None if getattr(self, f) is None else getattr(self, f)[mask]
                for f in PathBatch.__dataclass_fields__
            )
        )


@dataclass(frozen=True)
class FaceMaterials:
    """Reflection properties of every scene triangle.

    Attributes
    ----------
    objects : Surface
        One entry per scene object (its material at the carrier; roughness = S).
    owner : (n_faces,) int
        Object of each triangle.
    wavelength : float
        Metres.
    xpd : (n_objects,) float
        Cross-polarised fraction Kx of each object's diffuse scattering.
    pattern : (n_objects,) str
        Its scattering pattern, ``"lambertian"`` or ``"directive"``.
    alpha_r : (n_objects,) int
        Its directive lobe exponent.
    """

    objects: Surface
    owner: np.ndarray
    wavelength: float
    xpd: np.ndarray
    pattern: np.ndarray
    alpha_r: np.ndarray

    @classmethod
    def of(cls, scene) -> FaceMaterials:
        mats = [o.material for o in scene.objects]
        return cls(
            Surface.of(mats, scene.frequency),
            np.asarray(scene.face_object, np.int64),
            SPEED_OF_LIGHT / scene.frequency,
            np.array([m.xpd_coefficient for m in mats], np.float64),
            np.array([m.scattering_pattern for m in mats], dtype=object),
            np.array([m.alpha_r for m in mats], np.int64),
        )

    @property
    def rough_faces(self) -> np.ndarray:
        """(n_faces,) bool: triangles whose material scatters diffusely (S > 0)."""
        return self.objects.roughness[self.owner] > 0 if len(self.owner) else np.zeros(0, bool)

    def surface(self, faces: np.ndarray) -> Surface:
        """The surfaces of triangles ``faces`` (m,), one entry each."""
        return self.objects.take(self.owner[np.asarray(faces, np.int64)])

    def coefficients(self, faces: np.ndarray, cos_theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Specular TE and TM coefficients (m,) of triangles ``faces`` at incidence cosines (m,).

        :meth:`Surface.reflection`: slab or half-space, times ``sqrt(1 - S^2)`` on rough surfaces.
        """
        return self.surface(faces).reflection(np.minimum(cos_theta, 1.0), self.wavelength)


def spectral_norm(jones: np.ndarray) -> np.ndarray:
    """(m,) largest singular value of 2x2 matrices (m, 2, 2): the path's amplitude for the best
    pair of transmit and receive polarisations."""
    fro2 = np.sum(np.abs(jones) ** 2, axis=(1, 2))
    det = np.abs(jones[:, 0, 0] * jones[:, 1, 1] - jones[:, 0, 1] * jones[:, 1, 0])
    return np.sqrt(0.5 * (fro2 + np.sqrt(np.maximum(fro2**2 - 4.0 * det**2, 0.0))))


def unit_legs(nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (m, j, 3) and lengths (m, j) of the legs between consecutive nodes (m, j + 1, 3)."""
    legs = np.diff(nodes, axis=1)
    length = np.linalg.norm(legs, axis=2)
    return legs / np.maximum(length, 1e-300)[..., None], length


def reflection_chain(
    k_legs: np.ndarray, normals: np.ndarray, faces: np.ndarray, materials: FaceMaterials
) -> np.ndarray:
    """Product of the reflection matrices of consecutive bounces.

    Parameters
    ----------
    k_legs : (m, j + 1, 3) float64
        Unit directions of the legs around j reflections.
    normals : (m, j, 3) float64
        Plane normals at the reflections (either sign).
    faces : (m, j) int64
        Triangles reflected off.
    materials : FaceMaterials

    Returns
    -------
    (m, 3, 3) complex128
        Maps the transverse field on the first leg to the one on the last.
    """
    m, j = faces.shape
    t = np.broadcast_to(np.eye(3, dtype=complex), (m, 3, 3)).copy()
    for i in range(j):
        cos = np.abs(np.einsum("mi,mi->m", k_legs[:, i], normals[:, i]))
        r_te, r_tm = materials.coefficients(faces[:, i], cos)
        t = bounce_matrices(k_legs[:, i], k_legs[:, i + 1], normals[:, i], r_te, r_tm) @ t
    return t


def antenna_jones(
    field: np.ndarray, k_first: np.ndarray, k_last: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A global 3x3 field map in the antennas' spherical bases.

    Parameters
    ----------
    field : (m, 3, 3) complex
        Transverse field on the last leg = ``field @`` transverse field on the first.
    k_first, k_last : (m, 3) float
        Unit directions of the first (departure) and last (arrival) legs.

    Returns
    -------
    jones : (m, 2, 2) complex128
    aod, aoa : (m, 2) float64
        Departure direction and arrival direction (towards where the wave comes from).
    """
    aod = direction_angles(k_first)
    aoa = direction_angles(-k_last)
    th_t, ph_t = spherical_basis(aod)
    th_r, ph_r = spherical_basis(aoa)
    w = np.stack([th_t, ph_t], axis=2)  # (m, 3, 2): columns are the TX basis
    u = np.stack([th_r, ph_r], axis=1)  # (m, 2, 3): rows are the RX basis
    return u @ field @ w, aod, aoa


def path_fields(
    tx: np.ndarray,
    rx: np.ndarray,
    points: np.ndarray,
    order: np.ndarray,
    types: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    wedge: np.ndarray,
    wedges,
    materials: FaceMaterials,
    nudge: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Field of every path from its interaction points, in the antennas' bases.

    One compiled loop for every kind of path: each reflection multiplies the field by
    its bounce matrix (:meth:`Surface.reflection` of its triangle), the diffraction by
    the UTD coefficient (:func:`~mmwsim.tracer.utd.diffraction_matrices`); the spreading
    is ``lambda / (4 pi L)`` for specular paths and ``lambda / (4 pi sqrt(s s' (s + s')))``
    for a diffracted one.

    Parameters
    ----------
    tx : (3,) float64
    rx : (m, 3) float64
        Each path's receiver, metres.
    points : (m, k, 3) float64
        Interaction points (the first ``order`` of each row), metres.
    order : (m,) int
    types : (m, k) int8
        :class:`~mmwsim.tracer.paths.Interaction` of each interaction.
    faces : (m, k) int64
        Triangle of each reflection (its material).
    normals : (m, k, 3) float64
        Plane normal at each reflection.
    wedge : (m,) int64
        Wedge of the path's diffraction (-1 for none).
    wedges : Wedges or None
    materials : FaceMaterials
    nudge : (m,) float, optional
        Radians added to each diffraction angle (a side of an exact shadow boundary).

    Returns
    -------
    jones : (m, 2, 2) complex128
    aod, aoa : (m, 2) float64
    """
    m = len(order)
    jones = np.empty((m, 2, 2), np.complex128)
    angles = np.empty((m, 4))
    if wedges is None or not wedges.count:
        w = np.zeros((1, 3))
        wa = (w, w, w, w, w, w, np.ones(1), np.zeros(1, np.int64), np.zeros(1, np.int64))
    else:
        wa = (
            wedges.edge,
            wedges.t0,
            wedges.n0,
            wedges.tn,
            wedges.nn,
            wedges.origin,
            wedges.n,
            wedges.face0,
            wedges.facen,
        )
    surf = materials.objects
    path_fields_into(
        np.asarray(tx, np.float64),
        np.ascontiguousarray(rx, np.float64),
        np.ascontiguousarray(points, np.float64),
        np.asarray(order, np.int64),
        np.asarray(types, np.int8),
        np.asarray(faces, np.int64),
        np.ascontiguousarray(normals, np.float64),
        np.asarray(wedge, np.int64),
        np.zeros(m) if nudge is None else np.asarray(nudge, np.float64),
        *wa,
        materials.owner,
        surf.eps,
        surf.thickness,
        surf.roughness,
        materials.wavelength,
        jones,
        angles,
    )
    return jones, angles[:, :2], angles[:, 2:]


@njit(cache=True)
def _spherical_rows(theta, phi):  # pragma: no cover - compiled
    ct, st, cp, sp = np.cos(theta), np.sin(theta), np.cos(phi), np.sin(phi)
    return (ct * cp, ct * sp, -st), (-sp, cp, 0.0)


@njit(cache=True)
def path_fields_into(
    tx, rx, points, order, types, faces, normals, wedge, nudge,
    w_edge, w_t0, w_n0, w_tn, w_nn, w_origin, w_n, w_face0, w_facen,
    owner, eps, thick, rough, wavelength, jones, angles,
):  # pragma: no cover - compiled  # fmt: skip
    """Kernel of :func:`path_fields` (see there)."""
    field = np.empty((3, 3), np.complex128)
    step = np.empty((3, 3), np.complex128)
    tmp = np.empty((3, 3), np.complex128)
    r0 = np.empty((2, 2), np.complex128)
    rn = np.empty((2, 2), np.complex128)
    t = (float(tx[0]), float(tx[1]), float(tx[2]))
    for i in range(len(order)):
        k = order[i]
        end = row(rx, i)
        # Unfolded lengths before each node, and the total.
        total = 0.0
        prev = t
        for j in range(k + 1):
            nxt = end if j == k else row(points[i], j)
            total += norm(sub(nxt, prev))
            prev = nxt
        for a in range(3):
            for b in range(3):
                field[a, b] = 1.0 if a == b else 0.0
        prev = t
        walked = 0.0
        spread = wavelength / (4.0 * np.pi * total)
        first = unit(sub(end if k == 0 else row(points[i], 0), t))
        for j in range(k):
            p = row(points[i], j)
            nxt = end if j == k - 1 else row(points[i], j + 1)
            leg = norm(sub(p, prev))
            k_in = scale(sub(p, prev), 1.0 / leg)
            k_out = unit(sub(nxt, p))
            walked += leg
            if types[i, j] == 2:
                w = wedge[i]
                s_in = walked
                s_out = total - walked
                o0 = owner[w_face0[w]]
                on = owner[w_facen[w]]
                diffraction_scalar(
                    k_in, k_out, row(w_edge, w), row(w_t0, w), row(w_n0, w), row(w_tn, w), row(w_nn, w),
                    s_in, s_out, wavelength, eps[o0], thick[o0], rough[o0], eps[on], thick[on], rough[on],
                    r0, rn, step, nudge[i],
                )  # fmt: skip
                spread = wavelength / (4.0 * np.pi * np.sqrt(s_in * s_out * (s_in + s_out)))
            else:
                nrm = row(normals[i], j)
                o = owner[faces[i, j]]
                r_te, r_tm = reflection_scalar(
                    eps[o], thick[o], rough[o], min(abs(dot(k_in, nrm)), 1.0), wavelength
                )
                bounce_scalar(k_in, k_out, nrm, r_te, r_tm, step)
            for a in range(3):
                for b in range(3):
                    acc = 0.0j
                    for c in range(3):
                        acc += step[a, c] * field[c, b]
                    tmp[a, b] = acc
            field[:, :] = tmp
            prev = p
        last = unit(sub(end, prev)) if k else first
        th_d = np.arccos(min(max(first[2], -1.0), 1.0))
        ph_d = np.arctan2(first[1], first[0])
        th_a = np.arccos(min(max(-last[2], -1.0), 1.0))
        ph_a = np.arctan2(-last[1], -last[0])
        wt, wp = _spherical_rows(th_d, ph_d)
        ut, up = _spherical_rows(th_a, ph_a)
        for a in range(2):
            ua = ut if a == 0 else up
            for b in range(2):
                wb = wt if b == 0 else wp
                acc = 0.0j
                for c in range(3):
                    for d in range(3):
                        acc += ua[c] * field[c, d] * wb[d]
                jones[i, a, b] = acc * spread
        angles[i, 0] = th_d
        angles[i, 1] = ph_d
        angles[i, 2] = th_a
        angles[i, 3] = ph_a
