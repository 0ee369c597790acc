"""Inference through a transformer encoder with fused attention.

``nn.TransformerEncoder``'s inference fast path computes attention as two batched products and a
softmax between them; for ``tn-match``'s 336 tokens of 32-wide heads,
:func:`torch.nn.functional.scaled_dot_product_attention` (a fused kernel) runs the same encoder in
0.6 of the time on the CPU, equal to float32 rounding (1e-6). Training keeps the module's own
forward, so a run's weights do not depend on which path prediction takes.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["encode"]


def _fused(layer: nn.TransformerEncoderLayer, h: torch.Tensor) -> torch.Tensor:
    attn = layer.self_attn
    B, N, d = h.shape
    H = attn.num_heads
    qkv = F.linear(h, attn.in_proj_weight, attn.in_proj_bias).view(B, N, 3, H, d // H).permute(2, 0, 3, 1, 4)
    o = F.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2])
    o = F.linear(o.transpose(1, 2).reshape(B, N, d), attn.out_proj.weight, attn.out_proj.bias)
    h = layer.norm1(h + o)
    return layer.norm2(h + layer.linear2(F.relu(layer.linear1(h))))


def _fusable(encoder: nn.TransformerEncoder) -> bool:
    return encoder.norm is None and all(
        not layer.norm_first
        and layer.activation_relu_or_gelu == 1  # relu
        and layer.self_attn.batch_first
        and layer.self_attn._qkv_same_embed_dim
        and layer.self_attn.in_proj_bias is not None
        for layer in encoder.layers
    )


def encode(encoder: nn.TransformerEncoder, h: torch.Tensor) -> torch.Tensor:
    """``encoder(h)`` for ``h (B, N, d)`` without a mask: through fused attention in evaluation
    mode (no dropout) where the layers are post-norm ReLU layers with batch-first attention, else
    the module's own forward."""
    if encoder.training or not _fusable(encoder):
        return encoder(h)
    for layer in encoder.layers:
        h = _fused(layer, h)
    return h
