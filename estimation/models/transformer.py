"""The transformer encoder-decoder network (TN) of the paper."""

from __future__ import annotations

import warnings

import torch
from torch import nn

from .embedding import FingerprintEmbedding, RegressionHead, sinusoidal_encoding

__all__ = ["TransformerNet"]


class TransformerNet(nn.Module):
    """Encoder-decoder transformer over fingerprint sequences.

    The encoder reads the embedded fingerprints ``X_1..X_Tin`` plus a sinusoidal positional encoding;
    the decoder produces one vector per output step, which a fully connected head maps to a 2D
    position (normalised units).

    Parameters
    ----------
    task : ``"tracking"`` (outputs ``y_1..y_T``) or ``"forecasting"`` (outputs the ``horizon`` steps
        after the observed ones).
    decoder : ``"parallel"`` (default): the decoder's inputs are a learned query plus the positional
        encoding of each output step, all decoded at once; ``"autoregressive"``: as in the paper, the
        decoder input at step t is a learned embedding of the position at t-1 (teacher forcing in
        training, the model's own previous output in inference) under a causal mask.
    norm_first : layer normalisation before attention / feed-forward (pre-norm) instead of after
        (the original post-norm of Vaswani et al., the default).
    """

    def __init__(
        self,
        n_beams: int,
        n_bins: int,
        task: str = "tracking",
        horizon: int = 1,
        d: int = 48,
        heads: int = 2,
        layers: int = 2,
        ff: int = 96,
        dropout: float = 0.01,
        embed_k: int = 16,
        decoder: str = "parallel",
        norm_first: bool = False,
    ):
        super().__init__()
        if decoder not in ("parallel", "autoregressive"):
            raise ValueError(f"unknown decoder {decoder!r}")
        self.task, self.horizon, self.d, self.decoder_kind = task, horizon, d, decoder
        self.embed = FingerprintEmbedding(n_beams, n_bins, d, k=embed_k, dropout=dropout)
        with warnings.catch_warnings():  # pre-norm merely disables a fast path it warns about
            warnings.filterwarnings("ignore", message="enable_nested_tensor is True")
            self.transformer = nn.Transformer(
                d_model=d,
                nhead=heads,
                num_encoder_layers=layers,
                num_decoder_layers=layers,
                dim_feedforward=ff,
                dropout=dropout,
                batch_first=True,
                norm_first=bool(norm_first),
            )
        self.query = nn.Parameter(torch.zeros(d))
        self.start = nn.Parameter(torch.zeros(d))
        self.embed_y = nn.Linear(2, d)
        self.head = RegressionHead(d, 2, hidden=d)

    def _steps_out(self, t_in: int) -> torch.Tensor:
        if self.task == "tracking":
            return torch.arange(t_in)
        return torch.arange(t_in, t_in + self.horizon)

    def forward(self, bits: torch.Tensor, y_prev: torch.Tensor | None = None) -> torch.Tensor:
        """``bits (B, T_in, M, N_s)`` -> ``(B, T_out, 2)`` normalised positions.

        ``y_prev (B, T_out, 2)``: the true normalised targets, used for teacher forcing by the
        autoregressive decoder in training (ignored otherwise).
        """
        B, T = bits.shape[:2]
        src = self.embed(bits) + sinusoidal_encoding(torch.arange(T), self.d)
        memory = self.transformer.encoder(src)
        steps = self._steps_out(T)
        pe_out = sinusoidal_encoding(steps, self.d)
        if self.decoder_kind == "parallel":
            tgt = (self.query + pe_out).expand(B, -1, -1)
            return self.head(self.transformer.decoder(tgt, memory))
        n_out = len(steps)
        mask = nn.Transformer.generate_square_subsequent_mask(n_out)
        if self.training and y_prev is not None:
            tgt = torch.cat([self.start.expand(B, 1, -1), self.embed_y(y_prev[:, :-1])], 1) + pe_out
            return self.head(self.transformer.decoder(tgt, memory, tgt_mask=mask, tgt_is_causal=True))
        tokens = self.start.expand(B, 1, -1)
        out = []
        for t in range(n_out):
            h = self.transformer.decoder(tokens + pe_out[: t + 1], memory, tgt_mask=mask[: t + 1, : t + 1])
            y_t = self.head(h[:, -1:])
            out.append(y_t)
            tokens = torch.cat([tokens, self.embed_y(y_t)], 1)
        return torch.cat(out, 1)
