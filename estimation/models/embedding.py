"""Learned embeddings of one fingerprint (M beams x N_s bins of bits) into a d-dimensional vector."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["BagEmbedding", "FingerprintEmbedding", "make_embedding", "sinusoidal_encoding"]


class FingerprintEmbedding(nn.Module):
    """Bits ``(B, T, M, N_s)`` -> ``(B, T, d)``.

    Factorised to keep the parameter count small: a delay filter bank shared by all beams
    (``N_s -> k`` per beam), then a dense map of all beams' features (``M k -> d``). The second map
    keeps beam identity, which is what carries the angle information.
    """

    def __init__(self, n_beams: int, n_bins: int, d: int, k: int = 16, dropout: float = 0.01):
        super().__init__()
        self.delay = nn.Linear(n_bins, k)
        self.beams = nn.Linear(n_beams * k, d)
        self.act = nn.ReLU()
        self.drop = nn.Dropout(dropout)

    def forward(self, bits: torch.Tensor) -> torch.Tensor:
        h = self.act(self.delay(bits))  # (B, T, M, k)
        return self.drop(self.act(self.beams(h.flatten(-2))))


class BagEmbedding(nn.Module):
    """Bits ``(B, T, M, N_s)`` -> ``(B, T, d)`` through a wide hidden layer that reads only the set bits.

    A fingerprint sets a few percent of its ``M N_s`` bits, so the first layer (``M N_s -> hidden``,
    one weight row per (beam, bin)) is a sum of the rows of its set bits (``embedding_bag``): a wide
    layer at the cost of a narrow one. Each hidden unit can then act as a detector of one pattern of
    beams and delays, which is what telling thousands of places apart takes; ReLU, then
    ``hidden -> d`` and a layer norm.
    """

    def __init__(self, n_beams: int, n_bins: int, d: int, hidden: int = 1024, dropout: float = 0.01):
        super().__init__()
        # Rows scaled so that a fingerprint of about a hundred set bits starts near unit variance.
        self.rows = nn.Parameter(torch.randn(n_beams * n_bins, hidden) * 0.1)
        self.bias = nn.Parameter(torch.zeros(hidden))
        self.out = nn.Linear(hidden, d)
        self.norm = nn.LayerNorm(d)
        self.drop = nn.Dropout(dropout)

    def forward(self, bits: torch.Tensor) -> torch.Tensor:
        lead = bits.shape[:-2]
        flat = bits.reshape(-1, bits.shape[-2] * bits.shape[-1])
        which = flat.nonzero()  # (n_set, 2): fingerprint, bit; rows in order
        counts = torch.bincount(which[:, 0], minlength=flat.shape[0])
        offsets = torch.cumsum(counts, 0) - counts
        # Bits are 0/1 here, but a soft input (probabilities) is weighed by its value.
        weights = flat[which[:, 0], which[:, 1]].to(self.rows.dtype)
        h = F.embedding_bag(which[:, 1], self.rows, offsets, mode="sum", per_sample_weights=weights)
        h = self.drop(F.relu(h + self.bias))
        return self.norm(self.out(h)).reshape(*lead, self.out.out_features)


EMBEDDINGS = {
    "bag": lambda n_beams, n_bins, d, hidden, k, dropout: BagEmbedding(n_beams, n_bins, d, hidden, dropout),
    "factorised": lambda n_beams, n_bins, d, hidden, k, dropout: FingerprintEmbedding(
        n_beams, n_bins, d, k, dropout
    ),
}
"""Fingerprint embeddings by name: ``build(n_beams, n_bins, d, hidden, k, dropout)``."""


def make_embedding(
    kind: str, n_beams: int, n_bins: int, d: int, hidden: int = 1024, k: int = 16, dropout: float = 0.01
) -> nn.Module:
    """A fingerprint embedding by name (:data:`EMBEDDINGS`): ``"bag"`` (:class:`BagEmbedding`,
    ``hidden`` units) or ``"factorised"`` (:class:`FingerprintEmbedding`, ``k`` delay filters)."""
    if kind not in EMBEDDINGS:
        raise ValueError(f"unknown embedding {kind!r} (choose from {', '.join(EMBEDDINGS)})")
    return EMBEDDINGS[kind](n_beams, n_bins, d, hidden, k, dropout)


def sinusoidal_encoding(positions: torch.Tensor, d: int) -> torch.Tensor:
    """Vaswani et al. positional encoding: ``(T,)`` step indices -> ``(T, d)``."""
    pos = positions.float()[:, None]
    j = torch.arange(0, d, 2, dtype=torch.float32)
    freq = torch.exp(-math.log(10000.0) * j / d)
    pe = torch.zeros(len(positions), d)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq[: d // 2])
    return pe
