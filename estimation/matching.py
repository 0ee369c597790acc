"""Maximum-likelihood matching of noisy fingerprints against the grid's PDPs.

With the noise model ``bit = 1 iff PDP + N(0, sigma^2) >= threshold`` every grid point g predicts
bit (i, j) with probability ``p_gij = Phi((PDP_gij - threshold) / sigma)``, and an observed
fingerprint x scores ``sum_ij x_ij log p_gij + (1 - x_ij) log(1 - p_gij)``, i.e. one matrix product
``x @ W.T + c`` with ``W = logit p`` and ``c = sum log(1 - p)``.
"""

from __future__ import annotations

import math
import weakref

import numpy as np
import torch

from .errors import EstimationError
from .noise import check_bits, log_detection_probabilities
from .tile_search import TileIndex

__all__ = ["FingerprintMatcher", "GUIDE", "blank_steps"]

# Selection bonus of :meth:`FingerprintMatcher.track_candidates`: odds A near the predicted
# position, and its spread s in metres, plus a share of the last step's length. With A = 50 (at
# most 3.9 nats, which an informative fingerprint's likelihood differences dwarf) the tn-match and
# match-cv figures of the default data set did not move in the third decimal, and a vehicle whose
# fingerprint was empty at the area's edge was tracked at 1 m instead of 197 m (docs/estimation.md).
GUIDE = (50.0, 3.0, 0.5)

# The matchers in use, by the arrays, noise and threshold they were made for (FingerprintMatcher.shared).
_IN_USE: weakref.WeakValueDictionary[tuple, FingerprintMatcher] = weakref.WeakValueDictionary()


def blank_steps(bits: torch.Tensor | np.ndarray) -> np.ndarray:
    """``(B, T)`` bool: the steps of ``bits (B, T, M, N_s)`` (a tensor or array of any dtype) with
    no bit set, where a user is out of coverage: every grid point a fingerprint might come from
    alike weak reads them alike."""
    b = torch.as_tensor(bits)
    return (b.flatten(2) == 0).all(-1).numpy()


class FingerprintMatcher:
    """Maximum-likelihood grid points of noisy fingerprints.

    Parameters
    ----------
    grid_pdp : (G, M, N_s) tensor, dBm
    grid_xy : (G, 2) float, metres
    sigma : float, dB
        Noise level assumed by the likelihood (that of the observations).
    threshold : float, dBm
    eps : float
        Probabilities are clipped to ``[eps, 1 - eps]`` (in log space) so that a bit the model calls
        impossible costs a point ``log eps`` instead of vetoing it. The observations follow the
        model exactly, so a small floor is best: 1e-6 puts users standing still about 1.2 m closer on
        average than 1e-3 (13 on test/seen of the default data set at 6 dB).
    chunk : int
        Grid points per block when the weights are built.

    Notes
    -----
    The weights ``logit p`` are built on first use, for the ``C`` fingerprint entries in which any
    grid point has signal, so that scoring a fingerprint is a sum of the weight rows of its ones.
    :meth:`candidates`, :meth:`track_candidates` and :meth:`match` search them tile by tile
    (:class:`~estimation.tile_search.TileIndex`, 515 MB for the default data set's 79,097 points
    and 1,472 entries); :meth:`scores`, every point's log-likelihood, reads them as one dense
    ``(C, G)`` float32 table (466 MB), built only if it is called. Methods that read the same
    grid at the same noise share one matcher through :meth:`shared`.
    """

    def __init__(
        self,
        grid_pdp: torch.Tensor,
        grid_xy: np.ndarray,
        sigma: float,
        threshold: float,
        eps: float = 1e-6,
        chunk: int = 16384,
    ):
        if not (math.isfinite(float(sigma)) and float(sigma) >= 0.0):
            raise EstimationError(
                f"the fingerprint noise sigma must be a finite number of dB >= 0, got {sigma!r}"
            )
        self.grid_pdp, self.grid_xy = grid_pdp, np.asarray(grid_xy, np.float64)
        self._xy_given = grid_xy  # what shared() compares
        self.sigma, self.threshold, self.eps, self.chunk = float(sigma), float(threshold), eps, chunk
        flat = grid_pdp.reshape(len(grid_pdp), -1)
        # Columns where no grid point has any signal can never read 1 and score all points alike.
        self.columns = torch.nonzero(torch.isfinite(flat).any(0)).flatten()
        self._w: torch.Tensor | None = None
        self._c: torch.Tensor | None = None
        self._tiles: TileIndex | None = None

    @classmethod
    def shared(
        cls, grid_pdp: torch.Tensor, grid_xy: np.ndarray, sigma: float, threshold: float
    ) -> FingerprintMatcher:
        """A matcher of these very arrays (the same objects) at this noise and threshold: the one
        another method is using, if any, else a new one. Its tables are built once for all its
        users (515 MB on the default data set), e.g. for every grid-reading method that
        ``mmwsim evaluate`` compares on one data set. Matchers change nothing once made, so sharing
        one changes no result."""
        key = (id(grid_pdp), id(grid_xy), float(sigma), float(threshold))
        m = _IN_USE.get(key)
        # a matcher in use holds its arrays, so their ids cannot have been reused; checked anyway
        if m is None or m.grid_pdp is not grid_pdp or m._xy_given is not grid_xy:
            m = cls(grid_pdp, grid_xy, sigma, threshold)
            _IN_USE[key] = m
        return m

    def _weights(self, rows: slice | np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        pdp = self.grid_pdp[rows].reshape(-1, self.grid_pdp.shape[1] * self.grid_pdp.shape[2])
        pdp = pdp[:, self.columns].float()
        log_p, log_q = log_detection_probabilities(pdp, self.sigma, self.threshold, math.log(self.eps))
        return log_p - log_q, log_q.sum(1)

    def _tables(self) -> tuple[torch.Tensor, torch.Tensor]:
        if self._w is None:
            G = len(self.grid_pdp)
            w = torch.empty((len(self.columns), G), dtype=torch.float32)
            c = torch.empty(G, dtype=torch.float32)
            for k in range(0, G, self.chunk):
                wk, ck = self._weights(slice(k, k + self.chunk))
                w[:, k : k + len(ck)] = wk.T
                c[k : k + len(ck)] = ck
            self._w, self._c = w, c
        assert self._c is not None
        return self._w, self._c

    def tile_index(self) -> TileIndex:
        """The grid's tiles with their weights (:class:`~estimation.tile_search.TileIndex`), built
        on first use: what :meth:`candidates` and :meth:`track_candidates` search."""
        if self._tiles is None:

            def weights(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
                w, c = self._weights(torch.from_numpy(rows))
                return w.numpy(), c.numpy()

            self._tiles = TileIndex(self.grid_xy, weights, len(self.columns))
        return self._tiles

    def _ones(self, bits: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """The ones of ``bits (N, M, N_s)`` as rows of the weights: ``indptr (N + 1,)``, ``ones``."""
        bits = check_bits(bits, *self.grid_pdp.shape[1:])
        x = bits.reshape(-1, bits.shape[-2] * bits.shape[-1])[:, self.columns]
        nz = torch.nonzero(x)
        indptr = torch.searchsorted(nz[:, 0].contiguous(), torch.arange(len(x) + 1))
        return indptr.numpy(), nz[:, 1].contiguous().numpy()

    @torch.no_grad()
    def scores(self, bits: torch.Tensor) -> torch.Tensor:
        """Log-likelihood of every grid point: ``bits (N, M, N_s)`` -> ``(N, G)`` float32."""
        w, c = self._tables()
        # Fingerprints are sparse (a few percent ones): x @ W as a sum of W's rows over the ones,
        # i.e. an embedding bag, is several times faster than the dense product.
        indptr, ones = self._ones(bits)
        offsets = torch.from_numpy(indptr[:-1])
        return torch.nn.functional.embedding_bag(torch.from_numpy(ones), w, offsets, mode="sum") + c

    @torch.no_grad()
    def candidates(self, bits: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The ``k`` most likely grid points of each fingerprint, best first (ties: lower row
        first), searched tile by tile (:class:`~estimation.tile_search.TileIndex`): the same
        points as the top ``k`` of :meth:`scores`.

        Parameters
        ----------
        bits : (..., M, N_s) tensor of 0/1
        k : int

        Returns
        -------
        scores : (..., k) float32 log-likelihoods
        rows : (..., k) int64 grid rows (indices into ``grid_xy``)
        """
        lead = bits.shape[:-2]
        k = min(int(k), len(self.grid_pdp))
        score, rows = self.tile_index().topk(*self._ones(bits.reshape(-1, *bits.shape[-2:])), k)
        return torch.from_numpy(score).reshape(*lead, k), torch.from_numpy(rows).reshape(*lead, k)

    @torch.no_grad()
    def track_candidates(
        self, bits: torch.Tensor, k: int, refs: np.ndarray | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
        """Candidates of sequences of fingerprints, chosen with an eye on where each user goes.

        A fingerprint that says little (no bit set where a user walks out of coverage: every weak
        point explains it alike) has far more equally likely grid points than any ``k``, and the
        ``k`` a plain top-``k`` keeps may all lie far from the user. So each step's ``k`` are the
        points of highest log-likelihood plus a selection bonus ``log(1 + A exp(-d^2 / 2 s^2))``
        (:data:`GUIDE`) for the distance ``d`` to the position the best candidates of the two
        steps before predict at constant velocity; the scores returned are the plain
        log-likelihoods, so what the smoothers weigh is unchanged. A fingerprint that tells its
        place (its ``k``-th most likely point more than ``log(1 + A)`` below its best) keeps its
        ``k`` most likely points. A step's candidates depend on the steps before it only: a
        prefix's are a prefix of these.

        Parameters
        ----------
        bits : (B, T, M, N_s) tensor of 0/1
        k : int
        refs : (B, r, 2) float64, metres, optional
            The best candidates of the ``r <= 2`` steps before (the third output of an earlier
            call, for a tracker fed one step at a time).

        Returns
        -------
        xy : (B, T, k, 2) float32, metres; best first by the guided selection
        score : (B, T, k) float32 log-likelihoods
        refs : (B, r, 2) float64, metres; the best candidates of the last two steps
        """
        B, T = bits.shape[:2]
        k = min(int(k), len(self.grid_pdp))
        tiles = self.tile_index()
        ref = [] if refs is None else list(np.asarray(refs, np.float64).transpose(1, 0, 2))
        bonus, spread, per_step = GUIDE
        # Every step's plain top k in one search (a user's steps score the same tiles), then the
        # guided selection where the steps before are needed.
        indptr, ones = self._ones(bits.reshape(B * T, *bits.shape[2:]))
        score, rows = (a.reshape(B, T, k) for a in tiles.topk(indptr, ones, k))
        for t in range(T):
            # Only where the k-th point is about as likely as the best can the bonus matter.
            vague = np.flatnonzero(score[:, t, 0] - score[:, t, -1] < math.log1p(bonus))
            if ref and len(vague):
                last = ref[-1][vague]
                v = last - ref[-2][vague] if len(ref) > 1 else np.zeros_like(last)
                s = spread + per_step * np.linalg.norm(v, axis=-1)
                fp = vague * T + t
                n_ones = indptr[fp + 1] - indptr[fp]
                sub_ptr = np.r_[0, np.cumsum(n_ones)]
                sub = np.repeat(indptr[fp] - sub_ptr[:-1], n_ones) + np.arange(sub_ptr[-1])
                score[vague, t], rows[vague, t] = tiles.topk(sub_ptr, ones[sub], k, (last + v, s, bonus))
            ref = (ref + [self.grid_xy[rows[:, t, 0]]])[-2:]
        refs_out = np.stack(ref, 1) if ref else np.zeros((B, 0, 2))
        return torch.from_numpy(self.grid_xy[rows]).float(), torch.from_numpy(score), refs_out

    def match(self, bits: torch.Tensor) -> np.ndarray:
        """Best grid point per fingerprint.

        Parameters
        ----------
        bits : (..., M, N_s) tensor of 0/1

        Returns
        -------
        (..., 2) float64 positions of the matched grid points, metres
        """
        _, rows = self.candidates(bits, 1)
        return self.grid_xy[rows[..., 0].numpy()]
