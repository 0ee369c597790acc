"""What the baselines share: a fingerprint embedding before their sequence layers and a head after.

The LSTM, GRU, RNN, TCN and Conv1D networks differ only in how they read across steps. With the
same embedding and head as ``tn`` (the defaults) a comparison measures that difference and nothing
else; :data:`BASELINE_PAPER_OPTIONS` gives the paper's small factorised embedding and regression
head instead.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from .embedding import make_embedding
from .heads import CellOutput, make_head

__all__ = ["BASELINE_PAPER_OPTIONS", "BaselineNet"]

BASELINE_PAPER_OPTIONS: dict[str, Any] = {"d": 64, "embedding": "factorised", "head": "regression"}
"""The paper's baselines: a factorised embedding of width 64 and a 2-layer MLP regressing the
coordinates (``build_network("lstm", ..., **BASELINE_PAPER_OPTIONS)``)."""


class BaselineNet(nn.Module):
    """Embedding -> :meth:`body` (the subclass's sequence layers) -> head; ``bits (B, T_in, M, N_s)``
    -> ``(B, T_out, 2)`` normalised positions (with the cell head, a
    :class:`~estimation.models.heads.CellOutput` of those and their scores).

    Tracking reads a position from the body's output at every step; forecasting maps the output
    at the last observed step to one vector per future step (a linear layer) and reads each.

    Parameters
    ----------
    task, horizon : as for :class:`~estimation.models.transformer.TransformerNet`.
    d : width of the fingerprint embedding.
    width : width of the body's output.
    embedding, hidden, embed_k : see :func:`~estimation.models.embedding.make_embedding`.
    head, cells : see :func:`~estimation.models.heads.make_head`.
    """

    def __init__(
        self,
        n_beams: int,
        n_bins: int,
        task: str,
        horizon: int,
        d: int,
        width: int,
        dropout: float,
        embedding: str,
        hidden: int,
        embed_k: int,
        head: str,
        cells: int,
    ):
        super().__init__()
        self.task, self.horizon, self.width = task, horizon, width
        self.embed = make_embedding(embedding, n_beams, n_bins, d, hidden, embed_k, dropout)
        self.ahead = nn.Linear(width, horizon * width) if task == "forecasting" else None
        self.head = make_head(head, width, cells, hidden=64)

    def body(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, T, d)`` embedded fingerprints -> ``(B, T, width)``, causal where the model is."""
        raise NotImplementedError

    def forward(self, bits: torch.Tensor, y_prev: torch.Tensor | None = None) -> torch.Tensor | CellOutput:
        h = self.body(self.embed(bits))
        if self.ahead is not None:
            h = self.ahead(h[:, -1]).view(len(bits), self.horizon, self.width)
        return self.head(h)
