"""Output heads: from a network's per-step vector to a 2D position (normalised units)."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

__all__ = ["CellHead", "CellOutput", "RegressionHead", "make_head", "positions"]


class RegressionHead(nn.Sequential):
    """Fully connected ``d -> hidden -> out`` with ReLU: direct regression of normalised coordinates."""

    def __init__(self, d: int, out: int, hidden: int = 64):
        super().__init__(nn.Linear(d, hidden), nn.ReLU(), nn.Linear(hidden, out))


class CellOutput(NamedTuple):
    """What a :class:`CellHead` gives: the position and the cell scores behind it.

    Attributes
    ----------
    position : (..., 2) tensor, normalised units
    log_probs : (..., n_cells) tensor, log posterior of each cell
    """

    position: torch.Tensor
    log_probs: torch.Tensor


def positions(out: torch.Tensor | CellOutput) -> torch.Tensor:
    """The positions of a network's output, with or without the cell scores behind them."""
    return out.position if isinstance(out, CellOutput) else out


class CellHead(nn.Module):
    """Classification over the cells of a square lattice plus an offset, read out as a position.

    The normalised box ``[-1, 1]^2`` (the grid's extent, see :class:`~estimation.data.Normaliser`)
    is cut into ``cells x cells`` squares of side ``w = 2 / cells``. The head scores every cell
    (``d -> cells^2``) and moves the posterior mean of the cell centres by a learned offset of at
    most one cell (``w tanh(.)``). A fingerprint says which place it came from, or which few; a
    score per cell keeps those alternatives apart where a regression averages them, and its
    gradient says which cell was right however far the guess was.

    :meth:`forward` returns a :class:`CellOutput`: the position and the scores :meth:`loss` needs.

    Parameters
    ----------
    d : int
        Input width.
    cells : int
        Cells per side (80 on a 400 m area: 5 m cells).
    width : float
        Width of the soft target, in cells: the true position spreads its target over the cells
        around it as a Gaussian of standard deviation ``width * w`` (default half a cell).
    """

    _REACH = 2  # cells on each side of the true one that the soft target covers

    def __init__(self, d: int, cells: int = 80, width: float = 0.5):
        super().__init__()
        if cells < 1 or width <= 0:
            raise ValueError(f"cells must be >= 1 and width > 0 (got {cells}, {width})")
        self.cells, self.w, self.width = int(cells), 2.0 / cells, float(width)
        c = -1.0 + self.w * (torch.arange(self.cells, dtype=torch.float32) + 0.5)
        cy, cx = torch.meshgrid(c, c, indexing="ij")
        self.register_buffer("centres", torch.stack([cx.ravel(), cy.ravel()], -1), persistent=False)
        self.score = nn.Linear(d, self.cells**2)
        self.offset = nn.Linear(d, 2)
        nn.init.zeros_(self.offset.weight)
        nn.init.zeros_(self.offset.bias)

    def forward(self, h: torch.Tensor) -> CellOutput:
        # One normalisation serves the read-out and the loss (over thousands of cells it is most
        # of a training step's cost).
        log_probs = self.score(h).log_softmax(-1)
        position = log_probs.exp() @ self.centres + self.w * torch.tanh(self.offset(h))
        return CellOutput(position, log_probs)

    def loss(self, out: CellOutput, target: torch.Tensor) -> tuple[torch.Tensor, int]:
        """Cross-entropy against the soft target plus the position error in cells (squared up to one
        cell, linear beyond: Huber), summed over all steps; returns ``(sum, number of steps)``.

        Parameters
        ----------
        out : CellOutput with ``position (..., 2)`` and ``log_probs (..., cells^2)``
        target : (..., 2) tensor, normalised units
        """
        n, r = self.cells, self._REACH
        t = target.reshape(-1, 2)
        log_p = out.log_probs.reshape(-1, n * n)
        ij = torch.floor((t + 1.0) / self.w).long().clamp(0, n - 1)  # (S, 2): column, row
        step = torch.arange(-r, r + 1)
        col = ij[:, :1, None] + step[None, None, :]  # (S, 1, 2r+1)
        row = ij[:, 1:, None] + step[None, :, None]  # (S, 2r+1, 1)
        inside = ((col >= 0) & (col < n) & (row >= 0) & (row < n)).reshape(len(t), -1)
        cell = (row.clamp(0, n - 1) * n + col.clamp(0, n - 1)).reshape(len(t), -1)  # (S, (2r+1)^2)
        d2 = (self.centres[cell] - t[:, None, :]).square().sum(-1)
        logit_q = torch.where(inside, -d2 / (2 * (self.width * self.w) ** 2), -torch.inf)
        q = logit_q.softmax(-1)
        cross_entropy = -(q * log_p.gather(1, cell)).sum(-1)
        # Huber in cells: squared within a cell, linear beyond, so that a track lost 200 m away
        # (the cross-entropy's business) cannot throw the weights about.
        miss2 = (out.position.reshape(-1, 2) - t).square().sum(-1) / self.w**2
        position = torch.where(miss2 < 1.0, miss2, 2.0 * miss2.clamp(min=1.0).sqrt() - 1.0)
        return (cross_entropy + position).sum(), len(t)


HEADS = {
    "cells": lambda d, cells, hidden: CellHead(d, cells),
    "regression": lambda d, cells, hidden: RegressionHead(d, 2, hidden=hidden or d),
}
"""Position heads by name: ``build(d, cells, hidden)``."""


def make_head(kind: str, d: int, cells: int = 80, hidden: int | None = None) -> nn.Module:
    """A position head by name (:data:`HEADS`): ``"cells"`` (:class:`CellHead` of ``cells x cells``)
    or ``"regression"`` (:class:`RegressionHead` ``d -> hidden -> 2``, ``hidden`` defaulting to ``d``)."""
    if kind not in HEADS:
        raise ValueError(f"unknown head {kind!r} (choose from {', '.join(HEADS)})")
    return HEADS[kind](d, cells, hidden)
