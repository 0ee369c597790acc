"""Beamformed fingerprints: bits from a power-delay profile, fresh log-normal noise and a threshold.

bit(beam i, bin j) = 1 iff PDP_dBm[i, j] + N(0, sigma^2) >= threshold, with noise drawn
afresh at every use, over a window of bins (default 1..81: N_s = 81).

:class:`NoiseModel` states the model; numpy draws its bits two ways, with the same distribution:

- :meth:`NoiseModel.bits` adds float32 Gaussian noise to every entry, literally.
- :class:`FingerprintSampler` precomputes, per receiver, the probability of a one,
  ``Q((threshold - PDP) / sigma)``, quantised to 2^-32, and draws each bit as an
  exact Bernoulli variable from raw random bytes: one byte decides unless it ties
  with the probability's top byte (1 in 256), then 24 more bits decide. Entries whose
  probability rounds to 0 (no path, or more than ~6 sigma below the threshold) need
  no randomness; entries that round to 1 are sure ones. This is what makes a million
  fingerprints per second possible: Gaussian draws cost about 10 ns each and a
  fingerprint has 2,592 entries, most of them empty bins.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.special import erfc

from ..constants import BINS, SIGMA_DB, THRESHOLD_DBM
from ..errors import MmwsimError

__all__ = ["FingerprintSampler", "NoiseModel"]


_CHUNK = 2048  # fingerprints per task; fixes the random streams, so results do not depend on threads


@dataclass(frozen=True)
class NoiseModel:
    """The fingerprint noise model: ``bit = 1 iff PDP_dBm + N(0, sigma^2) >= threshold`` over a
    window of bins, noise drawn afresh at every use.

    This is the one specification; its back-ends draw the bits: :meth:`bits` (numpy, Gaussian
    noise on every entry, the literal definition), :class:`FingerprintSampler` (numpy, exact
    Bernoulli draws of :meth:`probability` for a fixed set of PDPs) and
    :mod:`estimation.noise` (torch, for training and evaluation).

    Parameters
    ----------
    sigma_db : float
        Noise standard deviation, dB (0: the bit is deterministic).
    threshold_dbm : float
        Detection threshold, dBm.
    bins : (start, stop)
        Bin window of the fingerprint, ``[start, stop)``.
    """

    sigma_db: float = SIGMA_DB
    threshold_dbm: float = THRESHOLD_DBM
    bins: tuple[int, int] = BINS

    def __post_init__(self) -> None:
        if not (np.isfinite(self.sigma_db) and self.sigma_db >= 0):
            raise MmwsimError(f"noise sigma must be >= 0 dB, got {self.sigma_db!r}")
        if not np.isfinite(self.threshold_dbm):
            raise MmwsimError(
                f"the detection threshold must be a finite number of dBm, got {self.threshold_dbm!r}"
            )
        object.__setattr__(self, "sigma_db", float(self.sigma_db))
        object.__setattr__(self, "threshold_dbm", float(self.threshold_dbm))
        object.__setattr__(self, "bins", (int(self.bins[0]), int(self.bins[1])))

    def window(self, n_bins: int) -> slice:
        """The bin window as a slice of profiles of ``n_bins`` bins (a one-line error if it does not fit)."""
        lo, hi = self.bins
        if not 0 <= lo < hi <= n_bins:
            raise MmwsimError(f"bin window {lo}..{hi - 1} does not fit in {n_bins} bins")
        return slice(lo, hi)

    def whole(self, n_bins: int) -> NoiseModel:
        """The same noise over all ``n_bins`` bins (for PDPs already cut to the window)."""
        return NoiseModel(self.sigma_db, self.threshold_dbm, (0, int(n_bins)))

    def probability(self, pdp_dbm: np.ndarray) -> np.ndarray:
        """P(PDP + N(0, sigma^2) >= threshold), same shape as ``pdp_dbm`` (all bins), float64."""
        p = np.asarray(pdp_dbm, dtype=np.float64)
        if self.sigma_db == 0:
            return (p >= self.threshold_dbm).astype(np.float64)
        with np.errstate(invalid="ignore"):
            return 0.5 * erfc((self.threshold_dbm - p) / (self.sigma_db * np.sqrt(2.0)))

    def bits(self, pdp_dbm: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Fingerprints of PDPs with fresh Gaussian noise on every entry of the window.

        Parameters
        ----------
        pdp_dbm : (..., n_beams, n_bins) float
            Power-delay profiles, dBm (-inf: no signal).
        rng : numpy.random.Generator
            Source of the noise; advanced by the call.

        Returns
        -------
        (..., n_beams, stop - start) uint8
            0 / 1 bits.
        """
        pdp = np.asarray(pdp_dbm)
        w = self.window(pdp.shape[-1])
        margin = (np.float32(self.threshold_dbm) - pdp[..., w].astype(np.float32)) / np.float32(
            max(self.sigma_db, 1e-30)
        )
        if self.sigma_db == 0:
            return (margin <= 0).astype(np.uint8)
        noise = rng.standard_normal(margin.shape, dtype=np.float32)
        return (noise >= margin).view(np.uint8)


class FingerprintSampler:
    """Fast fingerprint sampling for a fixed set of PDPs (e.g. a data set's receivers).

    Parameters
    ----------
    pdp_dbm : (n_rx, n_beams, n_bins) array-like
        Power-delay profiles, dBm; any float dtype; may be a zarr array (read in chunks).
    noise : NoiseModel
        Noise, threshold and bin window (default the contract's: 6 dB, -115 dBm, bins 1..81).

    Notes
    -----
    Memory: 8 bytes per (receiver, beam, bin) entry whose probability of a one is
    neither 0 nor 1 to 32 bits, plus 8 bytes per sure one.
    """

    def __init__(self, pdp_dbm, noise: NoiseModel | None = None):
        noise = NoiseModel() if noise is None else noise
        shape = tuple(pdp_dbm.shape)
        if len(shape) != 3:
            raise MmwsimError(f"PDPs must have shape (n_rx, n_beams, n_bins), got {shape}")
        w = noise.window(shape[2])
        self.n_rx, self.n_beams = shape[0], shape[1]
        self.n_window = w.stop - w.start
        self.shape = (self.n_beams, self.n_window)
        n_entries = self.n_beams * self.n_window
        if n_entries > 65536:
            raise MmwsimError(f"{n_entries} entries per fingerprint exceed the sampler's 65,536")
        self.noise = noise
        counts, pos, hi, lo = [], [], [], []
        step = max(1, (1 << 22) // max(1, n_entries))  # about 4 M entries per block
        for s in range(0, self.n_rx, step):
            block = np.asarray(pdp_dbm[s : s + step, :, w.start : w.stop]).reshape(-1, n_entries)
            q = np.rint(noise.probability(block) * 2.0**32).astype(np.uint64)
            rows, cols = np.nonzero(q)
            q = q[rows, cols]
            counts.append(np.bincount(rows, minlength=len(block)))
            pos.append(cols.astype(np.uint16))
            hi.append((q >> np.uint64(24)).astype(np.uint16))  # 256 = sure one
            lo.append((q & np.uint64(0xFFFFFF)).astype(np.uint32))
        count = np.concatenate(counts) if counts else np.zeros(0, np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(count)]).astype(np.int64)
        self.pos = np.concatenate(pos) if pos else np.zeros(0, np.uint16)
        self.hi = np.concatenate(hi) if hi else np.zeros(0, np.uint16)
        self.lo = np.concatenate(lo) if lo else np.zeros(0, np.uint32)

    @property
    def nbytes(self) -> int:
        return int(self.offsets.nbytes + self.pos.nbytes + self.hi.nbytes + self.lo.nbytes)

    def sample(
        self, index: np.ndarray, rng: np.random.Generator, threads: int = 1, out: np.ndarray | None = None
    ) -> np.ndarray:
        """Fingerprints of receivers ``index`` with fresh noise.

        Parameters
        ----------
        index : (n,) int
            Receivers (rows of the PDP array), repeats allowed.
        rng : numpy.random.Generator
            Seeds one stream per block of 2,048 fingerprints; the result does not depend on ``threads``.
        threads : int
            Worker threads (numpy releases the GIL in the heavy parts).
        out : (n, n_beams, n_window) uint8, optional

        Returns
        -------
        (n, n_beams, n_window) uint8
            0 / 1 bits.
        """
        raw = np.asarray(index).ravel()
        # a boolean mask would be read as receivers 0 and 1, a fraction rounded down
        if raw.size and raw.dtype.kind not in "iu":
            if raw.dtype.kind == "b":
                raise MmwsimError(
                    "receiver indices must be whole numbers, got a boolean mask (use np.flatnonzero)"
                )
            bad = raw[raw != np.rint(raw)] if raw.dtype.kind == "f" else raw
            if bad.size:
                raise MmwsimError(f"receiver indices must be whole numbers, got {bad[0].item()!r}")
        idx = raw.astype(np.int64)
        if len(idx) and (idx.min() < 0 or idx.max() >= self.n_rx):
            raise MmwsimError(f"receiver index out of range 0..{self.n_rx - 1}")
        if out is None:
            out = np.empty((len(idx),) + self.shape, dtype=np.uint8)
        flat = out.reshape(len(idx), int(np.prod(self.shape)))
        starts = range(0, len(idx), _CHUNK)
        seeds = rng.integers(0, 2**63, size=len(starts), dtype=np.int64)

        def task(i: int) -> None:
            s = starts[i]
            self._fill(idx[s : s + _CHUNK], np.random.default_rng(int(seeds[i])), flat[s : s + _CHUNK])

        if threads > 1 and len(starts) > 1:
            with ThreadPoolExecutor(threads) as pool:
                list(pool.map(task, range(len(starts))))
        else:
            for i in range(len(starts)):
                task(i)
        return out

    def _fill(self, idx: np.ndarray, rng: np.random.Generator, out: np.ndarray) -> None:
        out.fill(0)
        first = self.offsets[idx]
        count = (self.offsets[idx + 1] - first).astype(np.int32)
        total = int(count.sum())
        if total == 0:
            return
        # Gather the CSR rows of the chosen receivers: entry e of row r sits at first[r] + e.
        # int32 indices (a block holds at most 2,048 x 65,536 entries) halve the memory traffic.
        ends = np.cumsum(count, dtype=np.int64)
        src = np.repeat(first - (ends - count), count)
        src += np.arange(total, dtype=np.int64)
        hi = self.hi[src]
        u = np.frombuffer(rng.bytes(total), dtype=np.uint8)
        bit = u < hi
        tie = np.flatnonzero(u == hi)
        if len(tie):
            lo = (np.frombuffer(rng.bytes(4 * len(tie)), dtype=np.uint32) >> np.uint32(8)) < self.lo[src[tie]]
            bit[tie] = lo
        dest = np.repeat(np.arange(len(idx), dtype=np.int32) * np.int32(out.shape[1]), count)
        dest += self.pos[src]
        out.reshape(-1)[dest] = bit
