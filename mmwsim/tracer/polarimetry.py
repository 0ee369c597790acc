"""Field bookkeeping along a path: reflection matrices, antenna bases, the path batch.

Every solver stage returns a :class:`PathBatch`; the orchestrator concatenates them
into :class:`~mmwsim.tracer.paths.Paths`. Fields are carried as 3x3 matrices acting
on transverse field vectors in global coordinates and projected on the antennas'
spherical bases at the end (see :mod:`mmwsim.tracer.paths`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import SPEED_OF_LIGHT
from .fresnel import Surface, bounce_matrices, direction_angles, spherical_basis

__all__ = ["PathBatch", "FaceMaterials", "spectral_norm", "unit_legs", "reflection_chain", "antenna_jones"]


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
    """

    rx: np.ndarray
    length: np.ndarray
    points: np.ndarray
    faces: np.ndarray
    types: np.ndarray
    jones: np.ndarray
    aod: np.ndarray
    aoa: np.ndarray

    @property
    def k(self) -> int:
        return int(self.points.shape[1])

    def __len__(self) -> int:
        return int(len(self.rx))

    def select(self, mask: np.ndarray) -> PathBatch:
        """The paths where ``mask`` (m,) is true."""
        return PathBatch(*(getattr(self, f)[mask] for f in PathBatch.__dataclass_fields__))


@dataclass(frozen=True)
class FaceMaterials:
    """Reflection properties of every scene triangle.

    Attributes
    ----------
    objects : Surface
        One entry per scene object (its material at the carrier).
    owner : (n_faces,) int
        Object of each triangle.
    wavelength : float
        Metres.
    """

    objects: Surface
    owner: np.ndarray
    wavelength: float

    @classmethod
    def of(cls, scene) -> FaceMaterials:
        surfaces = Surface.of([o.material for o in scene.objects], scene.frequency)
        return cls(surfaces, np.asarray(scene.face_object, np.int64), SPEED_OF_LIGHT / scene.frequency)

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
