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

from .._jit import njit
from ..antennas import Codebook, Isotropic, Pattern
from ..constants import N_BINS, RX_GAIN_DBI, SAMPLE_RATE, TX_POWER_DBM
from ..errors import MmwsimError
from ..tracer.paths import PathKind, Paths

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
    tx_field, v = _factors(paths, codebook, rx_pattern)
    return tx_field[..., 0] * v[:, 0] + tx_field[..., 1] * v[:, 1]


def _factors(paths: Paths, codebook: Codebook, rx_pattern: Pattern | None) -> tuple[np.ndarray, np.ndarray]:
    """The two factors of :func:`beam_amplitudes`: transmit fields (n_beams, n, 2) and ``rx^T J`` with
    the propagation phase (n, 2); the amplitude is their product summed over the last axis."""
    freq = getattr(codebook, "frequency", paths.frequency)
    if abs(freq - paths.frequency) > 1e-9 * paths.frequency:
        raise MmwsimError(
            f"codebook is for {freq / 1e9:g} GHz but the paths were traced at {paths.frequency / 1e9:g} GHz"
        )
    rx_pattern = rx_pattern if rx_pattern is not None else receive_pattern()
    if paths.n_paths == 0:
        return np.zeros((codebook.n_beams, 0, 2), dtype=np.complex128), np.zeros((0, 2), np.complex128)
    rx_field = rx_pattern.field(paths.aoa[:, 0], paths.aoa[:, 1])  # (n, 2)
    v = np.einsum("pi,pij->pj", rx_field, paths.jones)  # rx^T J, (n, 2)
    v *= np.exp(-2j * np.pi * paths.frequency * paths.delay)[:, None]
    return codebook.field(paths.aod[:, 0], paths.aod[:, 1]), v


def channel_taps(
    paths: Paths,
    amplitudes: np.ndarray,
    sample_rate: float = SAMPLE_RATE,
    n_bins: int = N_BINS,
    band_limited: bool = False,
) -> np.ndarray:
    """Sampled complex channel per receiver and beam (every path summed coherently).

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
    _check_sampling(sample_rate, n_bins)
    h = np.zeros((paths.n_rx, amplitudes.shape[0], n_bins), np.complex128)
    power = np.zeros(h.shape)
    _bin_into(
        h, power, paths.rx_index, paths.delay * sample_rate, np.ascontiguousarray(amplitudes)[..., None],
        np.ones((paths.n_paths, 1), np.complex128), np.zeros(paths.n_paths, np.bool_), band_limited, SINC_TAPS,
    )  # fmt: skip
    return h


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

    Paths in one bin add as complex amplitudes; diffusely scattered contributions
    (:attr:`~mmwsim.tracer.PathKind.DIFFUSE`) add in power, since their phases are random.

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
    _check_sampling(sample_rate, n_bins)
    out = np.empty((paths.n_rx, codebook.n_beams, n_bins), np.float32)
    incoherent = paths.kind() == PathKind.DIFFUSE
    x = paths.delay * sample_rate
    offsets = paths.offsets()
    # Receivers in blocks, so that the complex accumulators stay small (in cache).
    for r0 in range(0, paths.n_rx, _RX_BLOCK):
        r1 = min(r0 + _RX_BLOCK, paths.n_rx)
        h = np.zeros((r1 - r0, codebook.n_beams, n_bins), np.complex128)
        power = np.zeros(h.shape)
        for a in range(offsets[r0], offsets[r1], _PATH_CHUNK):
            sl = slice(a, min(a + _PATH_CHUNK, offsets[r1]))
            tx_field, v = _factors(paths.select_range(sl), codebook, rx_pattern)
            _bin_into(
                h, power, paths.rx_index[sl] - r0, x[sl], tx_field, v, incoherent[sl], band_limited, SINC_TAPS
            )
        _to_dbm(h, power, float(tx_power_dbm), out[r0:r1])
    return out


_RX_BLOCK = 32  # receivers whose complex profiles are accumulated at once (about 1 MB each)
_PATH_CHUNK = 1 << 15  # paths whose beam amplitudes are held at once (about 1 kB each)


def _check_sampling(sample_rate: float, n_bins: int) -> None:
    if not (sample_rate > 0 and np.isfinite(sample_rate)) or int(n_bins) != n_bins or n_bins < 1:
        raise MmwsimError(f"need a positive sample rate and bin count, got {sample_rate!r}, {n_bins!r}")


@njit(cache=True)
def _bin_into(h, power, rx, x, tx_field, v, incoherent, band_limited, taps):  # pragma: no cover - compiled
    """Add each path's beam amplitudes ``sum_c tx_field[b, p, c] v[p, c]`` into its receiver's bins
    (coherently, or in power)."""
    n_beams, n_bins = h.shape[1], h.shape[2]
    for p in range(len(rx)):
        r = rx[p]
        base = int(np.floor(x[p]))
        lo, hi = (base - taps, base + taps) if band_limited else (base, base)
        for k in range(max(lo, 0), min(hi, n_bins - 1) + 1):
            w = np.sinc(k + 0.5 - x[p]) if band_limited else 1.0
            for b in range(n_beams):
                a = 0.0j
                for c in range(v.shape[1]):
                    a += tx_field[b, p, c] * v[p, c]
                a *= w
                if incoherent[p]:
                    power[r, b, k] += a.real * a.real + a.imag * a.imag
                else:
                    h[r, b, k] += a


@njit(cache=True)
def _to_dbm(h, power, tx_power_dbm, out):  # pragma: no cover - compiled
    for r in range(h.shape[0]):
        for b in range(h.shape[1]):
            for k in range(h.shape[2]):
                v = h[r, b, k]
                p = v.real * v.real + v.imag * v.imag + power[r, b, k]
                # float32 logarithm: the profile is stored as float16 anyway.
                out[r, b, k] = tx_power_dbm + 10.0 * np.log10(np.float32(p)) if p > 0.0 else -np.inf
