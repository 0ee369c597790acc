"""Directions and polarisation directions on the unit sphere.

A direction is (zenith theta from +z, azimuth phi from +x towards +y), radians.
Fields are written in the local spherical basis (theta_hat, phi_hat) of that
direction; V polarisation is theta_hat, H is phi_hat.
"""

from __future__ import annotations

import numpy as np

# One definition for antennas and paths: the tracer's Jones matrices act on these same vectors.
from ..tracer.paths import POLARISATIONS

__all__ = ["unit_vector", "theta_hat", "phi_hat", "spherical_basis", "angles_of", "POLARISATIONS"]


def unit_vector(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(..., 3) float64 unit direction of zenith ``theta`` and azimuth ``phi`` (radians, broadcast)."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, dtype=np.float64), np.asarray(phi, dtype=np.float64))
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def theta_hat(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(..., 3) float64 unit vector of increasing zenith (points down at the horizon)."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, dtype=np.float64), np.asarray(phi, dtype=np.float64))
    ct = np.cos(theta)
    return np.stack([ct * np.cos(phi), ct * np.sin(phi), -np.sin(theta)], axis=-1)


def phi_hat(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(..., 3) float64 unit vector of increasing azimuth (horizontal)."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, dtype=np.float64), np.asarray(phi, dtype=np.float64))
    return np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)], axis=-1)


def spherical_basis(theta: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(r_hat, theta_hat, phi_hat)``, each (..., 3) float64, for directions (theta, phi) in radians."""
    return unit_vector(theta, phi), theta_hat(theta, phi), phi_hat(theta, phi)


def angles_of(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zenith and azimuth (radians) of vectors ``v`` (..., 3); azimuth in (-pi, pi]."""
    v = np.asarray(v, dtype=np.float64)
    r = np.linalg.norm(v, axis=-1)
    theta = np.arccos(np.clip(v[..., 2] / np.where(r > 0, r, 1.0), -1.0, 1.0))
    return theta, np.arctan2(v[..., 1], v[..., 0])


class FieldFromBasis:
    """``field``, ``gain`` and ``gain_dbi`` by angles, from a subclass's ``field_basis(r, th, ph)``.

    The trailing axis of a field is (E_theta, E_phi) with ``|F|^2`` the linear gain;
    leading axes (e.g. one per beam) pass through.
    """

    def field_basis(self, r: np.ndarray, th: np.ndarray, ph: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def field(self, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """(..., 2) complex128 field (E_theta, E_phi) towards (theta, phi), radians."""
        return self.field_basis(*spherical_basis(theta, phi))

    def gain(self, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """(...) float64 linear gain towards (theta, phi), radians."""
        f = self.field(theta, phi)
        return np.sum(f.real**2 + f.imag**2, axis=-1)

    def gain_dbi(self, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """(...) float64 gain in dBi (-inf in exact nulls)."""
        with np.errstate(divide="ignore"):
            return 10.0 * np.log10(self.gain(theta, phi))
