"""Fused-attention inference equals the encoder module's own forward."""

from __future__ import annotations

import torch
from torch import nn

from estimation.models.encoder import encode


def _encoder(**kw) -> nn.TransformerEncoder:
    torch.manual_seed(0)
    layer = nn.TransformerEncoderLayer(16, 2, 32, 0.2, batch_first=True, **kw)
    return nn.TransformerEncoder(layer, 2, enable_nested_tensor=False)


def test_encode_equals_the_module_in_evaluation():
    enc = _encoder().eval()
    h = torch.randn(3, 11, 16)
    with torch.no_grad():
        want = enc(h)
    assert torch.allclose(encode(enc, h), want, atol=1e-5)
    # and with gradients wanted (the module's fast path is off then)
    assert torch.allclose(encode(enc, h.requires_grad_()), want, atol=1e-5)


def test_encode_keeps_the_module_where_it_cannot_fuse():
    enc = _encoder().train()  # dropout: the module's own forward, random per call
    h = torch.randn(3, 11, 16)
    torch.manual_seed(1)
    a = encode(enc, h)
    torch.manual_seed(1)
    assert torch.equal(a, enc(h))
    pre = _encoder(norm_first=True).eval()  # another layout: the module's forward
    with torch.no_grad():
        assert torch.equal(encode(pre, h), pre(h))
