"""Antenna field patterns: isotropic, short dipole and a pyramidal horn from aperture theory.

A pattern gives the far field radiated towards direction (theta, phi) as its
(theta_hat, phi_hat) components, normalised so that ``|F|^2`` is the linear gain
(lossless antennas: gain = directivity). Fields carry a sign and phase, so they
can be combined coherently with the Jones matrices of :class:`mmwsim.tracer.Paths`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from .._jit import njit
from ..constants import DEFAULT_FREQUENCY, SPEED_OF_LIGHT
from ..errors import MmwsimError
from .spherical import POLARISATIONS, FieldFromBasis

__all__ = ["Pattern", "Isotropic", "ShortDipole", "PyramidalHorn", "integrate_gain"]


class Pattern(FieldFromBasis, ABC):
    """A far-field pattern; subclasses implement :meth:`field_basis`."""

    @abstractmethod
    def field_basis(self, r: np.ndarray, th: np.ndarray, ph: np.ndarray) -> np.ndarray:
        """Field towards unit directions ``r`` given the spherical basis there.

        Parameters
        ----------
        r, th, ph : (..., 3) float64
            Direction and its theta_hat, phi_hat unit vectors.

        Returns
        -------
        (..., 2) complex128
            (E_theta, E_phi), ``|.|^2`` = linear gain.
        """


def _polarisation(p: str | np.ndarray) -> np.ndarray:
    if isinstance(p, str):
        if p not in POLARISATIONS:
            raise MmwsimError(f"unknown polarisation {p!r} (use 'V', 'H' or a 2-vector)")
        v = POLARISATIONS[p].astype(np.complex128)
    else:
        v = np.asarray(p, dtype=np.complex128).reshape(2)
    n = np.linalg.norm(v)
    if not n > 0:
        raise MmwsimError("polarisation vector must be non-zero")
    return v / n


class Isotropic(Pattern):
    """The same gain and polarisation in every direction.

    Not realisable by a physical antenna, but the usual model of a receiver whose
    pattern is not of interest; with ``gain_dbi=10`` it is the receive model of the
    reference experiments.

    Parameters
    ----------
    gain_dbi : float
        Gain in every direction, dBi.
    polarisation : {"V", "H"} or (2,) complex
        Field direction in the (theta_hat, phi_hat) basis; normalised.
    """

    def __init__(self, gain_dbi: float = 0.0, polarisation: str | np.ndarray = "V"):
        self.gain_dbi_value = float(gain_dbi)
        self.polarisation = _polarisation(polarisation)

    @property
    def directivity_dbi(self) -> float:
        return self.gain_dbi_value

    def field_basis(self, r, th, ph):
        amp = np.sqrt(10.0 ** (self.gain_dbi_value / 10.0))
        return np.broadcast_to(amp * self.polarisation, r.shape[:-1] + (2,)).astype(np.complex128)


class ShortDipole(Pattern):
    """A short (Hertzian) dipole along ``axis``: gain 1.5 sin^2 of the angle to the axis.

    Parameters
    ----------
    axis : (3,) float
        Dipole direction; the default, +z, radiates V polarisation (+theta_hat at the horizon).
    """

    def __init__(self, axis: tuple[float, float, float] = (0.0, 0.0, 1.0)):
        a = np.asarray(axis, dtype=np.float64)
        if a.shape != (3,) or not np.linalg.norm(a) > 0:
            raise MmwsimError(f"dipole axis must be a non-zero 3-vector, got {axis!r}")
        self.axis = a / np.linalg.norm(a)

    @property
    def directivity_dbi(self) -> float:
        return float(10.0 * np.log10(1.5))

    def field_basis(self, r, th, ph):
        # The far field is the axis' component across the direction of propagation; the minus
        # sign makes a vertical dipole radiate +theta_hat at the horizon.
        s = -np.sqrt(1.5)
        return np.stack([s * (th @ self.axis), s * (ph @ self.axis)], axis=-1).astype(np.complex128)


# ----------------------------------------------------------------------------- pyramidal horn


@njit(cache=True, inline="always")
def _cosine_aperture(x):  # pragma: no cover - compiled
    """Normalised transform of a cosine aperture: pi^2 cos(x) / (pi^2 - 4 x^2), x = k a u / 2."""
    den = np.pi * np.pi - 4.0 * x * x
    return np.pi / 4.0 if abs(den) < 1e-9 else np.pi * np.pi * np.cos(x) / den


@njit(cache=True, inline="always")
def _uniform_aperture(y):  # pragma: no cover - compiled
    """Normalised transform of a uniform aperture: sin(y) / y."""
    return 1.0 if y == 0.0 else np.sin(y) / y


@njit(cache=True)
def _factors(x, y):  # pragma: no cover - compiled
    out = np.empty(x.shape)
    xf, yf, of = x.ravel(), y.ravel(), out.ravel()
    for i in range(len(xf)):
        of[i] = _cosine_aperture(xf[i]) * _uniform_aperture(yf[i])
    return out


def _aperture_factor(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Cosine-aperture factor of ``x`` times uniform-aperture factor of ``y`` (broadcast arrays)."""
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    return _factors(np.ascontiguousarray(x), np.ascontiguousarray(y))


def _gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.polynomial.legendre.leggauss(n)


@lru_cache(maxsize=64)
def _aperture_directivity(ka: float, kb: float, n_mu: int = 150, n_chi: int = 256) -> float:
    """Directivity (linear) of the Huygens aperture, by quadrature of its power pattern.

    The sphere is parametrised around the boresight: mu = cos(angle off boresight)
    with Gauss-Legendre nodes on three pieces (the main lobe gets its own), and the
    roll angle chi with the trapezoid rule, spectrally accurate for a periodic integrand.
    """
    x, w = _gauss_legendre(n_mu)
    width = min(0.5, 40.0 / max(ka, kb) ** 2)  # about ten main-lobe widths in mu
    edges = [-1.0, 0.0, 1.0 - width, 1.0]
    mus, ws = [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        mus.append(0.5 * (hi - lo) * x + 0.5 * (hi + lo))
        ws.append(0.5 * (hi - lo) * w)
    mu, wmu = np.concatenate(mus), np.concatenate(ws)
    chi = np.linspace(0.0, 2.0 * np.pi, n_chi, endpoint=False)
    s = np.sqrt(1.0 - mu * mu)[:, None]
    u_h, u_e = s * np.cos(chi), s * np.sin(chi)
    p = _aperture_factor(0.5 * ka * u_h, 0.5 * kb * u_e) ** 2
    p *= ((1.0 + mu[:, None]) / 2.0) ** 2
    total = float(wmu @ p.sum(axis=1)) * (2.0 * np.pi / n_chi)
    return 4.0 * np.pi / total


class PyramidalHorn(Pattern):
    """A pyramidal horn modelled by its aperture: cosine H-plane and uniform E-plane distribution.

    The aperture field is a Huygens source (E and H in the ratio of a plane wave,
    the obliquity factor (1 + cos psi)/2) without the flare's phase error, i.e. an
    optimum-gain horn in the limit of a long flare. The far field is the Fourier
    transform of the aperture distribution; its peak is set to the directivity
    obtained by integrating the power pattern over the sphere, so the pattern
    integrates to 4 pi exactly. By default the aperture is sized for ``gain_dbi``
    with the E-plane height chosen for equal E- and H-plane half-power beamwidths.

    Parameters
    ----------
    gain_dbi : float
        Peak gain the aperture is sized for, dBi (ignored when ``width`` and ``height`` are given).
    frequency : float
        Hz.
    azimuth, elevation : float
        Boresight direction, radians (elevation above the horizon; negative tilts down).
    width, height : float, optional
        Aperture dimensions (H-plane, horizontal at zero elevation; E-plane), metres.
    aspect : float, optional
        height / width when sizing; default 50.8 / 68.8 (equal beamwidths).

    Notes
    -----
    The E-field on the aperture points along -z' (the local vertical, tilted with the
    boresight), so the horn radiates +theta_hat (V polarisation) on boresight.
    """

    HPBW_UNIFORM_DEG = 50.8
    """Half-power beamwidth of a uniform aperture of height b, degrees times lambda / b."""
    HPBW_COSINE_DEG = 68.8
    """Half-power beamwidth of a cosine aperture of width a, degrees times lambda / a."""

    def __init__(
        self,
        gain_dbi: float = 24.5,
        frequency: float = DEFAULT_FREQUENCY,
        azimuth: float = 0.0,
        elevation: float = 0.0,
        width: float | None = None,
        height: float | None = None,
        aspect: float | None = None,
    ):
        if not frequency > 0:
            raise MmwsimError(f"horn frequency must be positive, got {frequency!r}")
        self.frequency = float(frequency)
        self.k = 2.0 * np.pi * self.frequency / SPEED_OF_LIGHT
        if (width is None) != (height is None):
            raise MmwsimError("give both horn width and height, or neither")
        if width is None:
            aspect = self.HPBW_UNIFORM_DEG / self.HPBW_COSINE_DEG if aspect is None else float(aspect)
            if not aspect > 0:
                raise MmwsimError(f"horn aspect must be positive, got {aspect!r}")
            if not 3.0 <= gain_dbi <= 50.0:
                raise MmwsimError(f"horn gain {gain_dbi!r} dBi is outside 3..50 dBi")
            width, height = _size_for_gain(float(gain_dbi), self.k, aspect)
        if not (width > 0 and height > 0):
            raise MmwsimError(f"horn aperture must be positive, got {width!r} x {height!r} m")
        self.width, self.height = float(width), float(height)
        self.azimuth, self.elevation = float(azimuth), float(elevation)
        ca, sa, ce, se = np.cos(azimuth), np.sin(azimuth), np.cos(elevation), np.sin(elevation)
        self.boresight = np.array([ce * ca, ce * sa, se])
        self.e_dir = np.array([se * ca, se * sa, -ce])  # E-plane axis, down at zero elevation
        self.h_dir = np.cross(self.boresight, self.e_dir)  # H-plane axis, horizontal
        self.directivity = _aperture_directivity(self.k * self.width, self.k * self.height)
        self._amp = float(np.sqrt(self.directivity))

    @property
    def directivity_dbi(self) -> float:
        """Peak directivity = peak gain, dBi."""
        return float(10.0 * np.log10(self.directivity))

    def rotated(self, azimuth: float, elevation: float | None = None) -> PyramidalHorn:
        """The same aperture pointing elsewhere (radians; elevation kept if not given)."""
        return PyramidalHorn(
            frequency=self.frequency,
            azimuth=azimuth,
            elevation=self.elevation if elevation is None else elevation,
            width=self.width,
            height=self.height,
        )

    def aperture_directivity_dbi(self) -> float:
        """Large-aperture closed form 4 pi a b / lambda^2 * 8 / pi^2 (aperture efficiency 0.81), dBi."""
        lam = 2.0 * np.pi / self.k
        return float(10.0 * np.log10(4.0 * np.pi * self.width * self.height / lam**2 * 8.0 / np.pi**2))

    def beamwidth_formulas(self) -> tuple[float, float]:
        """Aperture-theory half-power beamwidths (E-plane, H-plane), radians."""
        lam = 2.0 * np.pi / self.k
        return (
            np.radians(self.HPBW_UNIFORM_DEG * lam / self.height),
            np.radians(self.HPBW_COSINE_DEG * lam / self.width),
        )

    def half_power_beamwidths(self) -> tuple[float, float]:
        """Half-power beamwidths of this pattern (E-plane, H-plane), radians, found by root search."""

        def plane(axis: np.ndarray) -> float:
            def excess(psi: float) -> float:
                d = np.cos(psi) * self.boresight + np.sin(psi) * axis
                return float(self._power(d[None])[0]) - 0.5

            return 2.0 * brentq(excess, 0.0, np.pi / 2, xtol=1e-12)

        return plane(self.e_dir), plane(self.h_dir)

    def _power(self, r: np.ndarray) -> np.ndarray:
        """Power pattern normalised to 1 on boresight, for unit vectors r (..., 3)."""
        x = 0.5 * self.k * self.width * (r @ self.h_dir)
        y = 0.5 * self.k * self.height * (r @ self.e_dir)
        return (_aperture_factor(x, y) * (1.0 + r @ self.boresight) / 2.0) ** 2

    def field_basis(self, r, th, ph):
        return horn_fields([self], r, th, ph)[0]


def horn_fields(horns: list[PyramidalHorn], r: np.ndarray, th: np.ndarray, ph: np.ndarray) -> np.ndarray:
    """Fields of several horns at once: (n_horns, ..., 2) complex128 for directions ``r`` (..., 3).

    The aperture model of :class:`PyramidalHorn`, evaluated for every horn and direction in
    one compiled pass (a rotating codebook's 32 beams cost about one numpy evaluation).
    ``th``, ``ph`` are the spherical basis vectors at ``r``.
    """
    shape = r.shape[:-1]
    rr, tt, pp = (np.ascontiguousarray(np.asarray(v, np.float64).reshape(-1, 3)) for v in (r, th, ph))
    params = np.array([[h._amp, 0.5 * h.k * h.width, 0.5 * h.k * h.height] for h in horns])
    e_dir = np.array([h.e_dir for h in horns], dtype=np.float64)
    h_dir = np.array([h.h_dir for h in horns], dtype=np.float64)
    out = np.empty((len(horns), len(rr), 2), np.complex128)
    _horn_fields_into(rr, tt, pp, params, e_dir, h_dir, out)
    return out.reshape((len(horns),) + shape + (2,))


@njit(cache=True)
def _horn_fields_into(r, th, ph, params, e_dir, h_dir, out):  # pragma: no cover - compiled
    for b in range(len(params)):
        amp0, half_kw, half_kh = params[b, 0], params[b, 1], params[b, 2]
        ex, ey, ez = e_dir[b, 0], e_dir[b, 1], e_dir[b, 2]
        hx, hy, hz = h_dir[b, 0], h_dir[b, 1], h_dir[b, 2]
        for i in range(len(r)):
            x = half_kw * (r[i, 0] * hx + r[i, 1] * hy + r[i, 2] * hz)
            y = half_kh * (r[i, 0] * ex + r[i, 1] * ey + r[i, 2] * ez)
            amp = amp0 * _cosine_aperture(x) * _uniform_aperture(y)
            # Huygens source: equivalent electric and magnetic currents combine into
            # ((e . th + h . ph), (e . ph - h . th)) / 2, i.e. (1 + cos psi) / 2 on the E and H planes.
            e_th = 0.5 * (
                th[i, 0] * ex + th[i, 1] * ey + th[i, 2] * ez + ph[i, 0] * hx + ph[i, 1] * hy + ph[i, 2] * hz
            )
            e_ph = 0.5 * (
                ph[i, 0] * ex + ph[i, 1] * ey + ph[i, 2] * ez - th[i, 0] * hx - th[i, 1] * hy - th[i, 2] * hz
            )
            out[b, i, 0] = amp * e_th
            out[b, i, 1] = amp * e_ph


@lru_cache(maxsize=64)
def _size_for_gain(gain_dbi: float, k: float, aspect: float) -> tuple[float, float]:
    """Aperture (width, height), metres, whose integrated directivity is ``gain_dbi``."""
    target = 10.0 ** (gain_dbi / 10.0)
    # Start from the closed form; directivity grows almost like the area, so a few
    # multiplicative corrections converge.
    area = target * (2 * np.pi / k) ** 2 / (4 * np.pi * 8 / np.pi**2)
    width = np.sqrt(area / aspect)
    for _ in range(30):
        d = _aperture_directivity(k * width, k * width * aspect)
        if abs(10 * np.log10(d / target)) < 1e-7:
            break
        width *= np.sqrt(target / d)
    return float(width), float(width * aspect)


def integrate_gain(pattern: Pattern, n_theta: int = 721, n_phi: int = 1440) -> float:
    """(1 / 4 pi) times the gain integrated over the sphere on a plain (theta, phi) grid.

    Equals 1 for a lossless pattern whose peak is its directivity. Midpoint rule in
    theta, periodic trapezoid in phi.
    """
    theta = (np.arange(n_theta) + 0.5) * np.pi / n_theta
    phi = np.arange(n_phi) * 2 * np.pi / n_phi
    g = pattern.gain(theta[:, None], phi[None, :])
    return float(
        (g.sum(axis=1) * np.sin(theta)).sum() * (np.pi / n_theta) * (2 * np.pi / n_phi) / (4 * np.pi)
    )
