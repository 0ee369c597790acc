"""Fresnel reflection (ITU-R P.2040) and the polarisation bookkeeping of specular paths.

Convention (time dependence ``exp(+j w t)``, lossy permittivity ``eps' - j eps''``):
at each bounce the s (TE) unit vector is ``e_s = k_in x n / |k_in x n|`` and the
p (TM) unit vectors are ``e_p = k x e_s`` for the incident and the reflected wave
alike. With this choice the reflected field is ``R_TE E_s e_s + R_TM E_p e_p_out``
with the coefficients of ITU-R P.2040 (equations 31a/b)::

    R_TE = (cos t - sqrt(eps - sin^2 t)) / (cos t + sqrt(eps - sin^2 t))
    R_TM = (eps cos t - sqrt(eps - sin^2 t)) / (eps cos t + sqrt(eps - sin^2 t))

(derived from the continuity of tangential E and H; a perfect conductor gives
R_TE = -1, R_TM = +1, and at normal incidence both describe the same field).

:class:`Surface` is the one reflection coefficient of the tracer: the specular paths, the
reflection terms inside the UTD diffraction coefficient and the diffuse-scattering model all
take their coefficients from it, so that the field is continuous across shadow and
reflection boundaries.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .._jit import njit
from ._vec import cross, norm, scale

if TYPE_CHECKING:
    from ..materials import Material

__all__ = [
    "Surface",
    "fresnel",
    "slab",
    "reflection",
    "spherical_basis",
    "bounce_matrices",
    "direction_angles",
]


def fresnel(eps: np.ndarray | complex, cos_theta: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Half-space reflection coefficients.

    Parameters
    ----------
    eps : (...) complex
        Complex relative permittivity of the reflecting medium (``eps' - j eps''``).
    cos_theta : (...) float
        Cosine of the incidence angle from the normal, in [0, 1].

    Returns
    -------
    r_te, r_tm : (...) complex128
    """
    eps = np.asarray(eps, dtype=np.complex128)
    c = np.asarray(cos_theta, dtype=np.float64)
    root = np.sqrt(eps - (1.0 - c * c))
    r_te = (c - root) / (c + root)
    r_tm = (eps * c - root) / (eps * c + root)
    return r_te, r_tm


def slab(
    eps: np.ndarray | complex,
    cos_theta: np.ndarray | float,
    thickness: np.ndarray | float,
    wavelength: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Reflection coefficients of a single-layer slab in air (ITU-R P.2040 section 3.4).

    ``R = R' (1 - exp(-j 2q)) / (1 - R'^2 exp(-j 2q))`` with
    ``q = 2 pi d / lambda sqrt(eps - sin^2 t)``, summing the internal multiple reflections.

    Parameters
    ----------
    eps : (...) complex
        Complex relative permittivity.
    cos_theta : (...) float
        Cosine of the incidence angle.
    thickness : (...) float
        Slab thickness, metres.
    wavelength : float
        Free-space wavelength, metres.

    Returns
    -------
    r_te, r_tm : (...) complex128
    """
    eps = np.asarray(eps, dtype=np.complex128)
    c = np.asarray(cos_theta, dtype=np.float64)
    q = 2.0 * np.pi * np.asarray(thickness) / wavelength * np.sqrt(eps - (1.0 - c * c))
    ph = np.exp(-2j * q)
    r_te, r_tm = fresnel(eps, c)
    return (r_te * (1 - ph) / (1 - r_te**2 * ph), r_tm * (1 - ph) / (1 - r_tm**2 * ph))


def reflection(
    eps: np.ndarray, thickness: np.ndarray, cos_theta: np.ndarray, wavelength: float
) -> tuple[np.ndarray, np.ndarray]:
    """TE and TM coefficients, as a slab where ``thickness > 0`` and a half-space where it is 0.

    Parameters
    ----------
    eps : (n,) complex
    thickness : (n,) float, metres (0 for half-space)
    cos_theta : (n,) float
    wavelength : float, metres

    Returns
    -------
    r_te, r_tm : (n,) complex128
    """
    r_te, r_tm = fresnel(eps, cos_theta)
    thick = np.asarray(thickness) > 0
    if np.any(thick):
        s_te, s_tm = slab(eps[thick], cos_theta[thick], thickness[thick], wavelength)
        r_te[thick], r_tm[thick] = s_te, s_tm
    return r_te, r_tm


@dataclass(frozen=True, eq=False)
class Surface:
    """Reflecting surfaces, one per entry (faces, objects or interaction points).

    Parameters
    ----------
    eps : (n,) complex
        Complex relative permittivity ``eps' - j eps''``; an infinite value is a perfect
        conductor (``R_TE = -1``, ``R_TM = +1`` exactly).
    thickness : (n,) float
        Slab thickness, metres; 0 reflects as a half-space.
    roughness : (n,) float
        Scattering coefficient S in [0, 1] of the effective-roughness model: the specular
        field keeps ``sqrt(1 - S^2)`` of the smooth-surface reflection.
    """

    eps: np.ndarray
    thickness: np.ndarray
    roughness: np.ndarray

    def __post_init__(self) -> None:
        eps = np.atleast_1d(np.asarray(self.eps, dtype=np.complex128))
        thick = np.broadcast_to(np.asarray(self.thickness, dtype=np.float64), eps.shape).copy()
        rough = np.broadcast_to(np.asarray(self.roughness, dtype=np.float64), eps.shape).copy()
        if eps.ndim != 1:
            raise ValueError(f"Surface.eps must be one-dimensional, got shape {eps.shape}")
        if not np.all((rough >= 0.0) & (rough <= 1.0)):
            raise ValueError("Surface.roughness must lie in [0, 1]")
        object.__setattr__(self, "eps", eps)
        object.__setattr__(self, "thickness", thick)
        object.__setattr__(self, "roughness", rough)

    def __len__(self) -> int:
        return len(self.eps)

    @classmethod
    def of(cls, materials: Sequence[Material], frequency: float) -> Surface:
        """One entry per material, at ``frequency`` (Hz), S from each material."""
        return cls(
            np.array([m.complex_permittivity(frequency) for m in materials], dtype=np.complex128),
            np.array([m.thickness or 0.0 for m in materials], dtype=np.float64),
            np.array([m.scattering_coefficient for m in materials], dtype=np.float64),
        )

    @classmethod
    def perfect_conductor(cls, n: int = 1, roughness: float = 0.0) -> Surface:
        """``n`` perfectly conducting half-spaces."""
        return cls(np.full(n, complex(0.0, -np.inf)), np.zeros(n), np.full(n, float(roughness)))

    def take(self, index: np.ndarray | int | slice) -> Surface:
        """The entries at ``index`` (any numpy index; an int keeps one entry)."""
        index = np.atleast_1d(np.arange(len(self))[index])
        return Surface(self.eps[index], self.thickness[index], self.roughness[index])

    def smooth_reflection(self, cos_theta: np.ndarray, wavelength: float) -> tuple[np.ndarray, np.ndarray]:
        """TE and TM coefficients of the smooth surfaces (slab or half-space, no roughness factor).

        Parameters
        ----------
        cos_theta : (n,) float
            Cosine of the incidence angle from the normal, in [0, 1].
        wavelength : float
            Free-space wavelength, metres.

        Returns
        -------
        r_te, r_tm : (n,) complex128
        """
        c = np.broadcast_to(np.asarray(cos_theta, dtype=np.float64), self.eps.shape)
        r_te = np.full(c.shape, -1.0 + 0j)  # perfect conductors (infinite eps) keep these
        r_tm = np.full(c.shape, 1.0 + 0j)
        ok = np.isfinite(self.eps)
        if np.any(ok):
            r_te[ok], r_tm[ok] = reflection(self.eps[ok], self.thickness[ok], c[ok], wavelength)
        return r_te, r_tm

    def reflection(self, cos_theta: np.ndarray, wavelength: float) -> tuple[np.ndarray, np.ndarray]:
        """Specular TE and TM coefficients (n,): :meth:`smooth_reflection` times ``sqrt(1 - S^2)``.

        Same arguments as :meth:`smooth_reflection`; this is the coefficient of specular paths and
        of the reflection terms inside the UTD coefficient.
        """
        r_te, r_tm = self.smooth_reflection(cos_theta, wavelength)
        keep = np.sqrt(1.0 - self.roughness**2)
        return r_te * keep, r_tm * keep


@njit(cache=True)
def reflection_scalar(eps: complex, thickness: float, roughness: float, cos_theta: float, wavelength: float):
    """:meth:`Surface.reflection` for one surface and angle, for compiled kernels.

    Returns ``(r_te, r_tm)``: the half-space (``thickness == 0``) or slab coefficients, times
    ``sqrt(1 - S^2)``; an infinite permittivity is a perfect conductor (-1, +1).
    """
    if not (np.isfinite(eps.real) and np.isfinite(eps.imag)):
        r_te = -1.0 + 0.0j
        r_tm = 1.0 + 0.0j
    else:
        c = min(cos_theta, 1.0)
        root = np.sqrt(eps - (1.0 - c * c))
        r_te = (c - root) / (c + root)
        r_tm = (eps * c - root) / (eps * c + root)
        if thickness > 0.0:
            ph = np.exp(-2j * (2.0 * np.pi * thickness / wavelength * root))
            r_te = r_te * (1.0 - ph) / (1.0 - r_te * r_te * ph)
            r_tm = r_tm * (1.0 - ph) / (1.0 - r_tm * r_tm * ph)
    keep = np.sqrt(1.0 - roughness * roughness)
    return r_te * keep, r_tm * keep


@njit(cache=True)
def sp_basis(k_in, k_out, normal):  # pragma: no cover - compiled
    """Unit ``(e_s, e_p,in, e_p,out)`` 3-tuples of a bounce off a plane with unit ``normal``.

    ``e_s`` is perpendicular to the plane of incidence (TE), ``e_p = k x e_s`` on each side (TM).
    """
    e_s = cross(k_in, normal)
    ns = norm(e_s)
    if ns < 1e-9:
        # Normal incidence: any s direction will do, both coefficients describe one field.
        alt = (1.0, 0.0, 0.0) if abs(normal[0]) < 0.9 else (0.0, 1.0, 0.0)
        e_s = cross(alt, normal)
        ns = norm(e_s)
    e_s = scale(e_s, 1.0 / ns)
    return e_s, cross(k_in, e_s), cross(k_out, e_s)


@njit(cache=True)
def bounce_scalar(k_in, k_out, normal, r_te, r_tm, out):  # pragma: no cover - compiled
    """:func:`~bounce_matrices` of one bounce into ``out`` (3, 3) complex."""
    e_s, e_pi, e_po = sp_basis(k_in, k_out, normal)
    for a in range(3):
        for b in range(3):
            out[a, b] = r_te * e_s[a] * e_s[b] + r_tm * e_po[a] * e_pi[b]


def direction_angles(k: np.ndarray) -> np.ndarray:
    """(zenith, azimuth) in radians of unit vectors ``k`` (..., 3); returns (..., 2)."""
    theta = np.arccos(np.clip(k[..., 2], -1.0, 1.0))
    phi = np.arctan2(k[..., 1], k[..., 0])
    return np.stack([theta, phi], axis=-1)


def spherical_basis(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors theta_hat, phi_hat (..., 3) at directions (zenith, azimuth) (..., 2)."""
    t, p = angles[..., 0], angles[..., 1]
    ct, st, cp, sp = np.cos(t), np.sin(t), np.cos(p), np.sin(p)
    theta_hat = np.stack([ct * cp, ct * sp, -st], axis=-1)
    phi_hat = np.stack([-sp, cp, np.zeros_like(t)], axis=-1)
    return theta_hat, phi_hat


def bounce_matrices(
    k_in: np.ndarray, k_out: np.ndarray, normal: np.ndarray, r_te: np.ndarray, r_tm: np.ndarray
) -> np.ndarray:
    """3x3 field maps of specular bounces: ``E_out = M @ E_in`` for transverse fields.

    Parameters
    ----------
    k_in, k_out : (n, 3) float
        Unit propagation directions before and after the bounce.
    normal : (n, 3) float
        Unit plane normals (either sign).
    r_te, r_tm : (n,) complex

    Returns
    -------
    (n, 3, 3) complex128
    """
    e_s = np.cross(k_in, normal)
    norm = np.linalg.norm(e_s, axis=-1)
    normal_inc = norm < 1e-9
    if np.any(normal_inc):
        # Normal incidence: any s direction will do, both coefficients describe one field.
        alt = np.where(np.abs(normal[normal_inc, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        e_s[normal_inc] = np.cross(alt, normal[normal_inc])
        norm = np.linalg.norm(e_s, axis=-1)
    e_s /= norm[:, None]
    e_pi = np.cross(k_in, e_s)
    e_po = np.cross(k_out, e_s)
    return (r_te[:, None, None] * e_s[:, :, None]) * e_s[:, None, :] + (
        r_tm[:, None, None] * e_po[:, :, None]
    ) * e_pi[:, None, :]
