"""The transformer network (TN) of the paper, and the configuration that makes it work on our data."""

from __future__ import annotations

import warnings
from typing import Any

import torch
from torch import nn

from .embedding import EMBEDDINGS, make_embedding, sinusoidal_encoding
from .heads import HEADS, CellOutput, make_head, positions

__all__ = ["PAPER_OPTIONS", "TransformerNet"]

PAPER_OPTIONS: dict[str, Any] = {
    "d": 48,
    "heads": 2,
    "layers": 2,
    "ff": 96,
    "embedding": "factorised",
    "head": "regression",
    "decoder": "parallel",
    "norm_first": False,
    "positions": "sinusoidal",
    "identity_init": False,
}
"""The paper's configuration (encoder-decoder of 2 + 2 layers, 2 heads, a small factorised
fingerprint embedding, direct regression of the position, about 1.2e5 parameters), kept for the
ablation: ``TransformerNet(..., **PAPER_OPTIONS)`` or ``mmwsim train --model tn --option d=48 ...``."""

_MAX_STEPS = 64  # learned positions: trajectories are at most 30 steps, plus a forecast horizon


class TransformerNet(nn.Module):
    """Transformer over fingerprint sequences: ``bits (B, T_in, M, N_s)`` -> ``(B, T_out, 2)``.

    Each fingerprint is embedded on its own, a stack of self-attention layers lets every step read
    the others, and a head turns each step's vector into a position in normalised units. The
    defaults are the configuration measured best within a 30-minute budget on 2 cores (docs/estimation.md,
    "Why the paper's transformer was at 7.5 m"); :data:`PAPER_OPTIONS` gives the paper's.

    Parameters
    ----------
    task : ``"tracking"`` (outputs ``y_1..y_T``) or ``"forecasting"`` (the ``horizon`` steps after
        the observed ones).
    d, heads, layers, ff : model width, attention heads, layers (of the encoder, and of the decoder
        if any), feed-forward width.
    embedding : ``"bag"`` (:class:`~estimation.models.embedding.BagEmbedding`, a wide layer over
        the set bits, ``hidden`` units) or ``"factorised"`` (the small delay filter bank and beam map,
        ``embed_k`` filters).
    head : ``"cells"`` (:class:`~estimation.models.heads.CellHead`: scores over ``cells x cells``
        cells of the area plus an offset) or ``"regression"`` (a 2-layer MLP to the coordinates).
    decoder : ``"none"``: tracking reads each step's encoder output; forecasting appends one token
        per future step (the last observed token plus a learned step embedding) to the encoder's
        input. ``"parallel"``: the paper's decoder, its inputs a learned query plus the positional
        encoding of each output step, all decoded at once; ``"autoregressive"``: the decoder input at
        step t is a learned embedding of the position at t-1 (teacher forcing in training, the
        model's own output in inference) under a causal mask.
    norm_first : layer normalisation before attention and feed-forward (pre-norm) rather than after.
    positions : ``"learned"`` (a learned vector per step, zero at the start) or ``"sinusoidal"``.
    identity_init : start every encoder layer's residual branches at zero, so that the untrained
        stack passes each step's embedding through unchanged: what the model learns from single
        fingerprints (:attr:`TrainConfig.warmup_epochs`) carries over to sequences intact.
    """

    def __init__(
        self,
        n_beams: int,
        n_bins: int,
        task: str = "tracking",
        horizon: int = 1,
        d: int = 128,
        heads: int = 4,
        layers: int = 2,
        ff: int = 256,
        dropout: float = 0.01,
        embedding: str = "bag",
        hidden: int = 1024,
        embed_k: int = 16,
        head: str = "cells",
        cells: int = 80,
        decoder: str = "none",
        norm_first: bool = True,
        positions: str = "learned",
        identity_init: bool = True,
    ):
        super().__init__()
        for name, value, allowed in (
            ("embedding", embedding, EMBEDDINGS),
            ("head", head, HEADS),
            ("decoder", decoder, ("none", "parallel", "autoregressive")),
            ("positions", positions, ("learned", "sinusoidal")),
        ):
            if value not in allowed:
                raise ValueError(f"unknown {name} {value!r} (choose from {', '.join(allowed)})")
        self.task, self.horizon, self.d, self.decoder_kind = task, horizon, d, decoder
        self.positions = positions
        self.embed = make_embedding(embedding, n_beams, n_bins, d, hidden, embed_k, dropout)
        with warnings.catch_warnings():  # pre-norm merely disables a fast path it warns about
            warnings.filterwarnings("ignore", message="enable_nested_tensor is True")
            self.encoder = nn.TransformerEncoder(
                nn.TransformerEncoderLayer(
                    d, heads, ff, dropout, batch_first=True, norm_first=bool(norm_first)
                ),
                layers,
                enable_nested_tensor=False,
            )
        if identity_init:
            for layer in self.encoder.layers:
                for branch_out in (layer.self_attn.out_proj, layer.linear2):
                    nn.init.zeros_(branch_out.weight)
                    nn.init.zeros_(branch_out.bias)
        self.decoder = None
        if decoder != "none":
            self.decoder = nn.TransformerDecoder(
                nn.TransformerDecoderLayer(
                    d, heads, ff, dropout, batch_first=True, norm_first=bool(norm_first)
                ),
                layers,
            )
            self.query = nn.Parameter(torch.zeros(d))
            self.start = nn.Parameter(torch.zeros(d))
            self.embed_y = nn.Linear(2, d)
        self.step = nn.Parameter(torch.zeros(_MAX_STEPS, d)) if positions == "learned" else None
        self.future = nn.Parameter(torch.zeros(horizon, d)) if task == "forecasting" else None
        # pre-norm layers leave their output unnormalised
        self.final_norm = nn.LayerNorm(d) if norm_first else nn.Identity()
        self.head = make_head(head, d, cells)

    def _encoding(self, steps: torch.Tensor) -> torch.Tensor:
        if self.step is None:
            return sinusoidal_encoding(steps, self.d)
        if int(steps.max()) >= _MAX_STEPS:
            raise ValueError(f"sequences of at most {_MAX_STEPS} steps (got {int(steps.max()) + 1})")
        return self.step[steps]

    def _steps_out(self, t_in: int) -> torch.Tensor:
        if self.task == "tracking":
            return torch.arange(t_in)
        return torch.arange(t_in, t_in + self.horizon)

    def _read(self, h: torch.Tensor) -> torch.Tensor | CellOutput:
        return self.head(self.final_norm(h))

    def forward(self, bits: torch.Tensor, y_prev: torch.Tensor | None = None) -> torch.Tensor | CellOutput:
        """``bits (B, T_in, M, N_s)`` -> ``(B, T_out, 2)`` normalised positions (with the cell head: a
        :class:`~estimation.models.heads.CellOutput` of those and their cell scores).

        ``y_prev (B, T_out, 2)``: the true normalised targets, used for teacher forcing by the
        autoregressive decoder in training (ignored otherwise).
        """
        B, T = bits.shape[:2]
        src = self.embed(bits) + self._encoding(torch.arange(T))
        if self.decoder is None:
            if self.task == "forecasting":
                ahead = src[:, -1:] + self.future  # learns what a step ahead adds
                return self._read(self.encoder(torch.cat([src, ahead], 1))[:, T:])
            return self._read(self.encoder(src))
        memory = self.encoder(src)
        steps = self._steps_out(T)
        pe_out = self._encoding(steps)
        if self.decoder_kind == "parallel":
            tgt = (self.query + pe_out).expand(B, -1, -1)
            return self._read(self.decoder(tgt, memory))
        n_out = len(steps)
        mask = nn.Transformer.generate_square_subsequent_mask(n_out)
        if self.training and y_prev is not None:
            tgt = torch.cat([self.start.expand(B, 1, -1), self.embed_y(y_prev[:, :-1])], 1) + pe_out
            return self._read(self.decoder(tgt, memory, tgt_mask=mask, tgt_is_causal=True))
        tokens = self.start.expand(B, 1, -1)
        out = []
        for t in range(n_out):
            h = self.decoder(tokens + pe_out[: t + 1], memory, tgt_mask=mask[: t + 1, : t + 1])
            y_t = self._read(h[:, -1:])
            out.append(y_t)
            tokens = torch.cat([tokens, self.embed_y(positions(y_t))], 1)
        if isinstance(out[0], CellOutput):
            return CellOutput(*(torch.cat(parts, 1) for parts in zip(*out, strict=True)))
        return torch.cat(out, 1)

    def sequence_parameters(self) -> list[nn.Parameter]:
        """What reads across steps (attention layers, step and future embeddings, the decoder): held
        still during warm-up epochs, so that with ``identity_init`` the stack stays the identity
        while the embedding and head learn single fingerprints."""
        modules = [m for m in (self.encoder, self.decoder) if m is not None]
        extra = [p for p in (self.step, self.future) if p is not None]
        return [p for m in modules for p in m.parameters()] + extra
