"""Learned embedding of one fingerprint (M beams x N_s bins of bits) into a d-dimensional vector."""

from __future__ import annotations

import math

import torch
from torch import nn

__all__ = ["FingerprintEmbedding", "sinusoidal_encoding", "RegressionHead"]


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


def sinusoidal_encoding(positions: torch.Tensor, d: int) -> torch.Tensor:
    """Vaswani et al. positional encoding: ``(T,)`` step indices -> ``(T, d)``."""
    pos = positions.float()[:, None]
    j = torch.arange(0, d, 2, dtype=torch.float32)
    freq = torch.exp(-math.log(10000.0) * j / d)
    pe = torch.zeros(len(positions), d)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq[: d // 2])
    return pe


class RegressionHead(nn.Sequential):
    """Fully connected ``d -> hidden -> out`` with ReLU."""

    def __init__(self, d: int, out: int, hidden: int = 64):
        super().__init__(nn.Linear(d, hidden), nn.ReLU(), nn.Linear(hidden, out))
