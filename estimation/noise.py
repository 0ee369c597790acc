"""The torch back-end of the fingerprint noise model: fresh bits, and their log probabilities.

The model is the one of :mod:`mmwsim.fingerprints.noise`: ``bit = 1 iff PDP_dBm + N(0, sigma^2) >=
threshold``, noise drawn afresh at every use. The numpy back-end draws the bits of the data set and
the trajectories; this one draws them on torch generators for training and evaluation, and gives
the matcher the exact log probabilities of a one and a zero.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch

from .errors import EstimationError

if TYPE_CHECKING:
    from .data import SequenceSet

__all__ = ["check_bits", "fingerprint_bits", "log_detection_probabilities", "noisy_bits"]


def check_bits(bits: torch.Tensor, beams: int, bins: int, ndim: int | None = None) -> torch.Tensor:
    """``bits`` as a tensor, or an :class:`EstimationError` that names what is wrong with them.

    Fingerprints from outside (a user's measurements) reach the matcher and the networks here.
    The matcher reads every nonzero entry as a one, so a NaN, an infinite or a soft value would
    give a position as if it were a bit, silently.

    Parameters
    ----------
    bits : (..., M, N_s) tensor or array of 0/1 (any dtype)
    beams, bins : int
        ``M`` and ``N_s`` of the model or grid.
    ndim : int, optional
        The number of dimensions ``bits`` must have.
    """
    bits = torch.as_tensor(bits)
    if (ndim is not None and bits.ndim != ndim) or bits.ndim < 2 or tuple(bits.shape[-2:]) != (beams, bins):
        lead = "..., " if ndim is None else "".join(f"{c}, " for c in "BTS"[: ndim - 2])
        raise EstimationError(
            f"fingerprints must be ({lead}{beams}, {bins}) bits, got shape {tuple(bits.shape)}"
        )
    if bits.dtype != torch.bool:
        bad = (bits != 0) & (bits != 1)
        if bool(bad.any()):
            raise EstimationError(
                f"fingerprint bits must be 0 or 1, got {bits[bad][0].item()!r} (at {int(bad.sum())} of "
                f"{bits.numel()} entries)"
            )
    return bits


def fingerprint_bits(
    pdp: torch.Tensor, sigma: float, threshold: float, generator: torch.Generator
) -> torch.Tensor:
    """Fresh noisy fingerprint bits.

    Parameters
    ----------
    pdp : (..., M, N_s) tensor, dBm (``-inf`` = no signal)
    sigma : float, dB
        Standard deviation of the Gaussian noise added in dB (log-normal in power).
    threshold : float, dBm
    generator : torch.Generator

    Returns
    -------
    (..., M, N_s) float32 tensor of 0/1
    """
    pdp = pdp.float()
    if sigma <= 0:
        return (pdp >= threshold).float()
    # Only bins with some signal can fire; they are a few percent of a real fingerprint, so noise is
    # drawn for those alone (same distribution, far fewer draws).
    finite = torch.isfinite(pdp)
    values = pdp[finite]
    bits = torch.zeros(pdp.shape, dtype=torch.float32)
    noise = torch.randn(values.shape, generator=generator, dtype=torch.float32)
    bits[finite] = (values + sigma * noise >= threshold).float()
    return bits


def noisy_bits(data: SequenceSet, sigma: float, generator: torch.Generator, chunk: int = 256) -> torch.Tensor:
    """Fresh fingerprints of every step of every trajectory: ``(n, L, M, N_s)`` bool (1 byte each)."""
    out = torch.empty((data.n, data.length, data.n_beams, data.n_bins), dtype=torch.bool)
    for k in range(0, data.n, chunk):
        pdp = data.grid_pdp[torch.from_numpy(data.index[k : k + chunk])]
        out[k : k + chunk] = fingerprint_bits(pdp, sigma, data.threshold, generator).bool()
    return out


def log_detection_probabilities(
    pdp: torch.Tensor, sigma: float, threshold: float, floor: float = -math.inf
) -> tuple[torch.Tensor, torch.Tensor]:
    """Log probabilities of a one and of a zero, ``log P(PDP + N >= threshold)`` and its complement.

    Parameters
    ----------
    pdp : (...) float tensor, dBm (``-inf`` = no signal)
    sigma : float, dB
        0: the bit is deterministic (probabilities 0 and 1).
    threshold : float, dBm
    floor : float
        Lower clip of both logarithms (a bit the model calls impossible then costs ``floor``).

    Returns
    -------
    log_p, log_q : (...) float tensors
    """
    if sigma > 0:
        z = (pdp - threshold) / sigma
        log_p, log_q = torch.special.log_ndtr(z), torch.special.log_ndtr(-z)  # exact in both tails
    else:
        hit = pdp >= threshold
        log_p, log_q = torch.where(hit, 0.0, -math.inf), torch.where(hit, -math.inf, 0.0)
    return log_p.clamp(min=floor), log_q.clamp(min=floor)
