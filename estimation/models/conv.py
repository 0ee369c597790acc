"""Convolutional baselines: temporal convolutional network (dilated causal) and plain Conv1D."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from .baseline import BaselineNet

__all__ = ["TCNNet", "Conv1DNet"]


class _CausalBlock(nn.Module):
    """Residual block of two dilated causal convolutions (Bai et al. 2018, keras-tcn)."""

    def __init__(self, channels: int, kernel: int, dilation: int, dropout: float):
        super().__init__()
        self.pad = (kernel - 1) * dilation
        self.c1 = nn.Conv1d(channels, channels, kernel, dilation=dilation)
        self.c2 = nn.Conv1d(channels, channels, kernel, dilation=dilation)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.drop(F.relu(self.c1(F.pad(x, (self.pad, 0)))))
        h = self.drop(F.relu(self.c2(F.pad(h, (self.pad, 0)))))
        return F.relu(x + h)


class _SeqConvNet(BaselineNet):
    """A 1x1 convolution from the embedding to ``channels``, then the subclass's :meth:`convolve`."""

    def __init__(
        self, n_beams, n_bins, task, horizon, d, channels, dropout, embedding, hidden, embed_k, head, cells
    ):
        super().__init__(
            n_beams, n_bins, task, horizon, d, channels, dropout, embedding, hidden, embed_k, head, cells
        )
        self.inp = nn.Conv1d(d, channels, 1)

    def convolve(self, x: torch.Tensor) -> torch.Tensor:  # (B, C, T) -> (B, C, T)
        raise NotImplementedError

    def body(self, x: torch.Tensor) -> torch.Tensor:
        return self.convolve(self.inp(x.transpose(1, 2))).transpose(1, 2)


class TCNNet(_SeqConvNet):
    """Dilated causal residual blocks (dilations 1, 2, 4, kernel 3): receptive field 29 steps."""

    def __init__(
        self,
        n_beams: int,
        n_bins: int,
        task: str = "tracking",
        horizon: int = 1,
        d: int = 128,
        channels: int = 128,
        kernel: int = 3,
        dilations: tuple[int, ...] = (1, 2, 4),
        dropout: float = 0.01,
        embedding: str = "bag",
        hidden: int = 1024,
        embed_k: int = 16,
        head: str = "cells",
        cells: int = 80,
    ):
        super().__init__(
            n_beams, n_bins, task, horizon, d, channels, dropout, embedding, hidden, embed_k, head, cells
        )
        self.blocks = nn.Sequential(*[_CausalBlock(channels, kernel, q, dropout) for q in dilations])

    def convolve(self, x):
        return self.blocks(x)


class Conv1DNet(_SeqConvNet):
    """Two plain ('same'-padded, non-causal) 1D convolutions over time."""

    def __init__(
        self,
        n_beams: int,
        n_bins: int,
        task: str = "tracking",
        horizon: int = 1,
        d: int = 128,
        channels: int = 64,
        kernel: int = 3,
        dropout: float = 0.01,
        embedding: str = "bag",
        hidden: int = 1024,
        embed_k: int = 16,
        head: str = "cells",
        cells: int = 80,
    ):
        super().__init__(
            n_beams, n_bins, task, horizon, d, channels, dropout, embedding, hidden, embed_k, head, cells
        )
        self.convs = nn.Sequential(
            nn.Conv1d(channels, channels, kernel, padding="same"),
            nn.ReLU(),
            nn.Dropout(dropout),
            nn.Conv1d(channels, channels, kernel, padding="same"),
            nn.ReLU(),
        )

    def convolve(self, x):
        return self.convs(x)
