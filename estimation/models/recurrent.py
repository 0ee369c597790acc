"""Recurrent baselines: LSTM, GRU and plain (Elman) RNN."""

from __future__ import annotations

import torch
from torch import nn

from .embedding import FingerprintEmbedding
from .heads import RegressionHead

__all__ = ["RecurrentNet"]

_CELLS = {"lstm": nn.LSTM, "gru": nn.GRU, "rnn": nn.RNN}


class RecurrentNet(nn.Module):
    """Embedding, two stacked recurrent layers of ``units`` (the paper's 256, 64), then a 2-layer MLP.

    Tracking: one position per step from the last layer's output at that step (causal).
    Forecasting: all ``horizon`` positions from the last layer's output at the last observed step.
    """

    def __init__(
        self,
        cell: str,
        n_beams: int,
        n_bins: int,
        task: str = "tracking",
        horizon: int = 1,
        d: int = 64,
        units: tuple[int, int] = (256, 64),
        dropout: float = 0.01,
        embed_k: int = 16,
    ):
        super().__init__()
        self.task, self.horizon = task, horizon
        self.embed = FingerprintEmbedding(n_beams, n_bins, d, k=embed_k, dropout=dropout)
        rnn = _CELLS[cell]
        self.rnn1 = rnn(d, units[0], batch_first=True)
        self.rnn2 = rnn(units[0], units[1], batch_first=True)
        self.drop = nn.Dropout(dropout)
        self.head = RegressionHead(units[1], 2 if task == "tracking" else 2 * horizon, hidden=64)

    def forward(self, bits: torch.Tensor, y_prev: torch.Tensor | None = None) -> torch.Tensor:
        h, _ = self.rnn1(self.embed(bits))
        h, _ = self.rnn2(self.drop(h))
        if self.task == "tracking":
            return self.head(h)
        return self.head(h[:, -1]).view(len(bits), self.horizon, 2)
