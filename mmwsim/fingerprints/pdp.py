"""Per-beam power-delay profiles from traced paths.

For receiver r, beam b and path p (Paths' polarisation convention)::

    a[b, p] = rx_field(aoa_p)^T . jones_p . F_b(aod_p) * exp(-j 2 pi f_c tau_p)

where ``F_b`` is the beam's field pattern and ``rx_field`` the receive antenna's,
both with ``|F|^2`` the linear gain, so that ``P_tx |a|^2`` is the Friis received
power. The sampled channel of bin k (width 1 / Fs) is the coherent sum of the paths
whose delay falls in [k / Fs, (k + 1) / Fs), or, band-limited, the sum of
``a sinc(Fs (t_k - tau))`` sampled at the bin centres t_k = (k + 1/2) / Fs.
Delays are absolute (time of flight), as in the reference data set.
"""

from __future__ import annotations

import numpy as np

from ..antennas import Codebook, Isotropic, Pattern
from ..antennas.spherical import spherical_basis
from ..errors import MmwsimError
from ..tracer.paths import Paths

__all__ = [
    "SAMPLE_RATE",
    "N_BINS",
    "TX_POWER_DBM",
    "RX_GAIN_DBI",
    "receive_pattern",
    "beam_amplitudes",
    "channel_taps",
    "power_delay_profile",
]

SAMPLE_RATE = 20e6
"""Hz: 50 ns bins."""
N_BINS = 120
"""Bins per profile: 6 us at 20 MHz."""
TX_POWER_DBM = 30.0
RX_GAIN_DBI = 10.0
SINC_TAPS = 16
"""Bins either side of a path that a band-limited path contributes to (sinc^2 tail below -40 dB)."""


def receive_pattern(gain_dbi: float = RX_GAIN_DBI) -> Pattern:
    """The reference receive antenna: V polarised, ``gain_dbi`` in every direction."""
    return Isotropic(gain_dbi, "V")


def beam_amplitudes(paths: Paths, codebook: Codebook, rx_pattern: Pattern | None = None) -> np.ndarray:
    """Complex amplitude of every path for every beam, propagation phase included.

    Parameters
    ----------
    paths : Paths
        n_paths paths.
    codebook : Codebook
        Transmit beams; its frequency must match the paths'.
    rx_pattern : Pattern, optional
        Receive antenna; :func:`receive_pattern` (10 dBi, V) by default.

    Returns
    -------
    (n_beams, n_paths) complex128
        Square root of the power ratio P_rx / P_tx, with phase.
    """
    freq = getattr(codebook, "frequency", paths.frequency)
    if abs(freq - paths.frequency) > 1e-9 * paths.frequency:
        raise MmwsimError(
            f"codebook is for {freq / 1e9:g} GHz but the paths were traced at {paths.frequency / 1e9:g} GHz"
        )
    rx_pattern = rx_pattern if rx_pattern is not None else receive_pattern()
    if paths.n_paths == 0:
        return np.zeros((codebook.n_beams, 0), dtype=np.complex128)
    rx_field = rx_pattern.field(paths.aoa[:, 0], paths.aoa[:, 1])  # (n, 2)
    v = np.einsum("pi,pij->pj", rx_field, paths.jones)  # rx^T J, (n, 2)
    v *= np.exp(-2j * np.pi * paths.frequency * paths.delay)[:, None]
    tx_field = codebook.field_basis(*spherical_basis(paths.aod[:, 0], paths.aod[:, 1]))  # (n_beams, n, 2)
    return tx_field[..., 0] * v[:, 0] + tx_field[..., 1] * v[:, 1]


def channel_taps(
    paths: Paths,
    amplitudes: np.ndarray,
    sample_rate: float = SAMPLE_RATE,
    n_bins: int = N_BINS,
    band_limited: bool = False,
) -> np.ndarray:
    """Sampled complex channel per receiver and beam.

    Parameters
    ----------
    paths : Paths
    amplitudes : (n_beams, n_paths) complex
        From :func:`beam_amplitudes`.
    sample_rate : float
        Hz; bin width 1 / sample_rate.
    n_bins : int
        Bins kept; later paths are dropped.
    band_limited : bool
        Sinc interpolation (bandwidth = sample_rate) instead of plain binning.

    Returns
    -------
    (n_rx, n_beams, n_bins) complex128
    """
    if not sample_rate > 0 or n_bins < 1:
        raise MmwsimError(f"need a positive sample rate and bin count, got {sample_rate!r}, {n_bins!r}")
    n_beams = amplitudes.shape[0]
    n_rx = paths.n_rx
    size = n_beams * n_rx * n_bins
    x = paths.delay * sample_rate  # delay in bins
    base = np.floor(x).astype(np.int64)
    shifts = range(-SINC_TAPS, SINC_TAPS + 1) if band_limited else (0,)
    re = np.zeros(size)
    im = np.zeros(size)
    beam_off = (np.arange(n_beams, dtype=np.int64) * n_rx)[:, None]
    for s in shifts:
        k = base + s
        keep = (k >= 0) & (k < n_bins)
        if not keep.any():
            continue
        a = amplitudes[:, keep]
        if band_limited:
            a = a * np.sinc(k[keep] + 0.5 - x[keep])
        idx = ((beam_off + paths.rx_index[keep]) * n_bins + k[keep]).ravel()
        re += np.bincount(idx, weights=a.real.ravel(), minlength=size)
        im += np.bincount(idx, weights=a.imag.ravel(), minlength=size)
    h = (re + 1j * im).reshape(n_beams, n_rx, n_bins)
    return h.transpose(1, 0, 2)


def power_delay_profile(
    paths: Paths,
    codebook: Codebook,
    rx_pattern: Pattern | None = None,
    tx_power_dbm: float = TX_POWER_DBM,
    sample_rate: float = SAMPLE_RATE,
    n_bins: int = N_BINS,
    band_limited: bool = False,
) -> np.ndarray:
    """Per-beam power-delay profiles, dBm.

    Parameters
    ----------
    paths : Paths
        Paths to n_rx receivers.
    codebook : Codebook
        n_beams transmit beams.
    rx_pattern : Pattern, optional
        Receive antenna, 10 dBi V by default.
    tx_power_dbm : float
        Transmit power, dBm.
    sample_rate : float
        Hz (20 MHz: 50 ns bins).
    n_bins : int
        Bins per profile (120: 6 us).
    band_limited : bool
        Sinc-interpolated samples instead of coherent sums per bin.

    Returns
    -------
    (n_rx, n_beams, n_bins) float32
        Received power per bin, dBm; ``-inf`` where no path arrives (no signal).
    """
    amps = beam_amplitudes(paths, codebook, rx_pattern)
    h = channel_taps(paths, amps, sample_rate, n_bins, band_limited)
    power = h.real**2 + h.imag**2
    with np.errstate(divide="ignore"):
        return (tx_power_dbm + 10.0 * np.log10(power)).astype(np.float32)
