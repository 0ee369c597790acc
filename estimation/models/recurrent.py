"""Recurrent baselines: LSTM, GRU and plain (Elman) RNN."""

from __future__ import annotations

import torch
from torch import nn

from .baseline import BaselineNet

__all__ = ["RecurrentNet"]

_CELLS = {"lstm": nn.LSTM, "gru": nn.GRU, "rnn": nn.RNN}


class RecurrentNet(BaselineNet):
    """Two stacked recurrent layers of ``units`` (the paper's 256, 64) between the shared embedding
    and head (:class:`~estimation.models.baseline.BaselineNet`); causal.

    ``cell``: ``"lstm"``, ``"gru"`` or ``"rnn"``.
    """

    def __init__(
        self,
        cell: str,
        n_beams: int,
        n_bins: int,
        task: str = "tracking",
        horizon: int = 1,
        d: int = 128,
        units: tuple[int, int] = (256, 64),
        dropout: float = 0.01,
        embedding: str = "bag",
        hidden: int = 1024,
        embed_k: int = 16,
        head: str = "cells",
        cells: int = 80,
    ):
        super().__init__(
            n_beams, n_bins, task, horizon, d, units[1], dropout, embedding, hidden, embed_k, head, cells
        )
        rnn = _CELLS[cell]
        self.rnn1 = rnn(d, units[0], batch_first=True)
        self.rnn2 = rnn(units[0], units[1], batch_first=True)
        self.drop = nn.Dropout(dropout)

    def body(self, x: torch.Tensor) -> torch.Tensor:
        h, _ = self.rnn1(x)
        h, _ = self.rnn2(self.drop(h))
        return h
