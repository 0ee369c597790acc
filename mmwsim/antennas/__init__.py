"""Antenna patterns, polarisation directions and transmit codebooks."""

from .codebooks import Codebook, PlanarArrayCodebook, RotatingHorn, make_codebook
from .patterns import Isotropic, Pattern, PyramidalHorn, ShortDipole, integrate_gain
from .spherical import POLARISATIONS, angles_of, phi_hat, spherical_basis, theta_hat, unit_vector

__all__ = [
    "Codebook",
    "Isotropic",
    "POLARISATIONS",
    "Pattern",
    "PlanarArrayCodebook",
    "PyramidalHorn",
    "RotatingHorn",
    "ShortDipole",
    "angles_of",
    "integrate_gain",
    "make_codebook",
    "phi_hat",
    "spherical_basis",
    "theta_hat",
    "unit_vector",
]
