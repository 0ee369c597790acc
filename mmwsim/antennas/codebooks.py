"""Transmit codebooks: the field pattern of every beam.

A codebook maps (beam, departure direction) to a complex field in the
(theta_hat, phi_hat) basis with ``|F|^2`` the linear gain. Two kinds:
a horn rotated through M azimuth steps (the reference data set's transmitter)
and a planar array steered by a DFT codebook (the true MIMO alternative).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from .._jit import njit
from ..constants import DEFAULT_FREQUENCY, SPEED_OF_LIGHT
from ..errors import MmwsimError
from .patterns import Isotropic, Pattern, PyramidalHorn, _cosine_aperture, _uniform_aperture, horn_fields
from .spherical import FieldFromBasis

__all__ = ["Codebook", "RotatingHorn", "PlanarArrayCodebook", "make_codebook"]


class Codebook(FieldFromBasis, ABC):
    """A set of ``n_beams`` transmit patterns."""

    n_beams: int

    @abstractmethod
    def field_basis(self, r: np.ndarray, th: np.ndarray, ph: np.ndarray) -> np.ndarray:
        """(n_beams, ..., 2) complex128 fields for unit directions ``r`` and their bases ``th``, ``ph``."""

    @abstractmethod
    def describe(self) -> dict[str, Any]:
        """JSON-able parameters (stored in data-set configs)."""


class RotatingHorn(Codebook):
    """One horn turned through ``n_beams`` azimuth orientations.

    Beam i points at azimuth ``azimuth0 + i * 2 pi / n_beams`` and elevation ``elevation``.

    Parameters
    ----------
    n_beams : int
        Number of orientations M.
    gain_dbi : float
        Peak gain of the horn, dBi.
    frequency : float
        Hz.
    elevation : float
        Boresight elevation above the horizon, radians (negative tilts down).
    azimuth0 : float
        Azimuth of beam 0, radians.
    """

    def __init__(
        self,
        n_beams: int = 32,
        gain_dbi: float = 24.5,
        frequency: float = DEFAULT_FREQUENCY,
        elevation: float = 0.0,
        azimuth0: float = 0.0,
    ):
        if int(n_beams) != n_beams or n_beams < 1:
            raise MmwsimError(f"number of beams must be a positive integer, got {n_beams!r}")
        if not -np.pi / 2 <= elevation <= np.pi / 2:
            raise MmwsimError(f"horn elevation {np.degrees(elevation):g} deg is outside -90..90 deg")
        self.n_beams = int(n_beams)
        self.gain_dbi_value = float(gain_dbi)
        self.frequency = float(frequency)
        self.elevation = float(elevation)
        self.azimuth0 = float(azimuth0)
        self.step = 2.0 * np.pi / self.n_beams
        base = PyramidalHorn(gain_dbi, frequency, azimuth0, elevation)
        self.horns = [base.rotated(azimuth0 + i * self.step, elevation) for i in range(self.n_beams)]

    @property
    def azimuths(self) -> np.ndarray:
        """(n_beams,) float64 boresight azimuths, radians."""
        return self.azimuth0 + self.step * np.arange(self.n_beams)

    def field_basis(self, r, th, ph):
        return horn_fields(self.horns, r, th, ph)

    def field(self, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """(n_beams, ..., 2) complex128 fields of every beam towards (theta, phi), radians.

        The beams are one horn turned in azimuth: its pattern in terms of the angle
        ``phi - azimuth`` (and the common elevation), with the next beam's angle reached by an
        angle-addition step instead of new trigonometry (the same pattern as
        :meth:`field_basis`, to rounding).
        """
        theta, phi = np.broadcast_arrays(np.asarray(theta, np.float64), np.asarray(phi, np.float64))
        h = self.horns[0]
        out = np.empty((self.n_beams, theta.size, 2), np.complex128)
        _rotating_fields_into(
            np.ascontiguousarray(theta).reshape(-1), np.ascontiguousarray(phi).reshape(-1), self.azimuth0,
            self.step, h._amp, 0.5 * h.k * h.width, 0.5 * h.k * h.height, self.elevation, out,
        )  # fmt: skip
        return out.reshape((self.n_beams,) + theta.shape + (2,))

    def describe(self) -> dict[str, Any]:
        h = self.horns[0]
        return {
            "kind": "rotating_horn",
            "n_beams": self.n_beams,
            "gain_dbi": self.gain_dbi_value,
            "elevation_deg": float(np.degrees(self.elevation)),
            "azimuth0_deg": float(np.degrees(self.azimuth0)),
            "aperture_m": [h.width, h.height],
        }


@njit(cache=True)
def _rotating_fields_into(theta, phi, az0, step, amp0, half_kw, half_kh, elev, out):  # pragma: no cover
    # With c, s = cos, sin(phi - azimuth) of a beam and the horn's E- and H-plane axes e, h:
    # r.h = st s, r.e = se st c - ce ct, th.e = se ct c + ce st, th.h = ct s, ph.e = -se s, ph.h = c.
    se, ce = np.sin(elev), np.cos(elev)
    cs, sn = np.cos(step), np.sin(step)
    for i in range(len(theta)):
        st, ct = np.sin(theta[i]), np.cos(theta[i])
        c, s = np.cos(phi[i] - az0), np.sin(phi[i] - az0)
        uf = _uniform_aperture(-half_kh * ct) if se == 0.0 else 0.0
        for b in range(out.shape[0]):
            if se != 0.0:
                uf = _uniform_aperture(half_kh * (se * st * c - ce * ct))
            amp = amp0 * _cosine_aperture(half_kw * st * s) * uf
            e_th = 0.5 * (se * ct * c + ce * st + c)
            e_ph = 0.5 * (-se * s - ct * s)
            out[b, i, 0] = amp * e_th
            out[b, i, 1] = amp * e_ph
            c, s = c * cs + s * sn, s * cs - c * sn  # next beam: the angle phi - azimuth falls by a step


class PlanarArrayCodebook(Codebook):
    """A vertical uniform planar array steered by the 2D DFT codebook.

    ``n_horizontal x n_vertical`` elements at ``spacing`` in the plane that faces
    azimuth ``azimuth``. Beam (p, q) has weights ``exp(-j pi (m u_p + n v_q)) / sqrt(N)``
    (for half-wavelength spacing) with u_p, v_q the DFT grid of direction cosines
    along the array's horizontal and vertical axes; the weights of all beams form a
    unitary matrix, so in every direction the beam gains sum to N times the element gain.
    Mutual coupling is ignored.

    Parameters
    ----------
    n_horizontal, n_vertical : int
        Elements along the horizontal and vertical array axes.
    frequency : float
        Hz.
    spacing : float, optional
        Element spacing, metres; half a wavelength by default.
    azimuth : float
        Azimuth the array faces, radians.
    element : Pattern, optional
        Element pattern; isotropic V polarisation (0 dBi) by default.
    """

    def __init__(
        self,
        n_horizontal: int = 8,
        n_vertical: int = 4,
        frequency: float = DEFAULT_FREQUENCY,
        spacing: float | None = None,
        azimuth: float = 0.0,
        element: Pattern | None = None,
    ):
        if n_horizontal < 1 or n_vertical < 1:
            raise MmwsimError(f"array size must be positive, got {n_horizontal} x {n_vertical}")
        self.n_horizontal, self.n_vertical = int(n_horizontal), int(n_vertical)
        self.n_beams = self.n_horizontal * self.n_vertical
        self.frequency = float(frequency)
        lam = SPEED_OF_LIGHT / self.frequency
        self.spacing = lam / 2.0 if spacing is None else float(spacing)
        if not self.spacing > 0:
            raise MmwsimError(f"element spacing must be positive, got {spacing!r}")
        self.azimuth = float(azimuth)
        self.element = element if element is not None else Isotropic(0.0, "V")
        self.k = 2.0 * np.pi / lam
        self.h_axis = np.array([-np.sin(azimuth), np.cos(azimuth), 0.0])
        self.v_axis = np.array([0.0, 0.0, 1.0])
        m, n = np.meshgrid(np.arange(self.n_horizontal), np.arange(self.n_vertical), indexing="xy")
        self.element_index = np.column_stack([m.ravel(), n.ravel()])  # (N, 2)
        self.positions = self.spacing * (
            self.element_index[:, :1] * self.h_axis + self.element_index[:, 1:] * self.v_axis
        )
        # DFT grid of spatial frequencies (cycles per element), beam b = p + n_horizontal * q.
        fp = np.fft.fftfreq(self.n_horizontal)
        fq = np.fft.fftfreq(self.n_vertical)
        p, q = np.meshgrid(fp, fq, indexing="xy")
        self.spatial_frequency = np.column_stack([p.ravel(), q.ravel()])  # (n_beams, 2)
        phase = -2.0 * np.pi * self.spatial_frequency @ self.element_index.T
        self.weights = np.exp(1j * phase) / np.sqrt(self.n_beams)  # (n_beams, N)

    def steering(self, r: np.ndarray) -> np.ndarray:
        """(..., N) complex128 steering vectors exp(j k p_n . r) for unit directions r (..., 3)."""
        return np.exp(1j * self.k * (r @ self.positions.T))

    def beam_directions(self) -> np.ndarray:
        """(n_beams, 2) direction cosines (along the horizontal, vertical axes) of the beam peaks."""
        lam = 2.0 * np.pi / self.k
        return self.spatial_frequency * lam / self.spacing

    def field_basis(self, r, th, ph):
        af = self.steering(r) @ self.weights.T  # (..., n_beams)
        elem = self.element.field_basis(r, th, ph)  # (..., 2)
        return np.moveaxis(af, -1, 0)[..., None] * elem[None]

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "planar_array",
            "n_horizontal": self.n_horizontal,
            "n_vertical": self.n_vertical,
            "spacing_m": self.spacing,
            "azimuth_deg": float(np.degrees(self.azimuth)),
        }


def make_codebook(kind: str, frequency: float = DEFAULT_FREQUENCY, **kw: Any) -> Codebook:
    """A codebook by name: ``rotating_horn`` or ``planar_array``, degrees for angles.

    Parameters
    ----------
    kind : str
    frequency : float
        Hz.
    **kw
        ``rotating_horn``: n_beams, gain_dbi, elevation_deg, azimuth0_deg;
        ``planar_array``: n_horizontal, n_vertical, spacing_m, azimuth_deg.
    """
    if kind == "rotating_horn":
        return RotatingHorn(
            n_beams=kw.get("n_beams", 32),
            gain_dbi=kw.get("gain_dbi", 24.5),
            frequency=frequency,
            elevation=np.radians(kw.get("elevation_deg", 0.0)),
            azimuth0=np.radians(kw.get("azimuth0_deg", 0.0)),
        )
    if kind == "planar_array":
        return PlanarArrayCodebook(
            n_horizontal=kw.get("n_horizontal", 8),
            n_vertical=kw.get("n_vertical", 4),
            frequency=frequency,
            spacing=kw.get("spacing_m"),
            azimuth=np.radians(kw.get("azimuth_deg", 0.0)),
        )
    raise MmwsimError(f"unknown codebook {kind!r} (use rotating_horn or planar_array)")
