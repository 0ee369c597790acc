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
"""

from __future__ import annotations

import numpy as np

__all__ = ["fresnel", "slab", "reflection", "spherical_basis", "bounce_matrices", "direction_angles"]


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
    return r_te[:, None, None] * np.einsum("ni,nj->nij", e_s, e_s) + r_tm[:, None, None] * np.einsum(
        "ni,nj->nij", e_po, e_pi
    )
