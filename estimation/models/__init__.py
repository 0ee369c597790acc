"""Trajectory-estimation networks: the transformer (``tn``) and the neural baselines.

Every network maps fingerprint bits ``(B, T_in, M, N_s)`` to normalised positions ``(B, T_out, 2)``.
"""

from __future__ import annotations

from torch import nn

from ..errors import EstimationError
from .candidates import CandidateTransformer
from .conv import Conv1DNet, TCNNet
from .motion import MixtureMotion, MotionTable
from .recurrent import RecurrentNet
from .transformer import TransformerNet

__all__ = [
    "MODELS",
    "CANDIDATE_MODELS",
    "CandidateTransformer",
    "build_network",
    "count_parameters",
    "TransformerNet",
    "RecurrentNet",
    "TCNNet",
    "Conv1DNet",
    "MixtureMotion",
    "MotionTable",
]

MODELS = ("tn", "tn-match", "lstm", "gru", "rnn", "tcn", "conv1d")
CANDIDATE_MODELS = ("tn-match",)  # networks that choose among the grid's fingerprint-match candidates


def build_network(
    name: str, n_beams: int, n_bins: int, task: str, horizon: int, dropout: float = 0.01, **options
) -> nn.Module:
    """The network ``name`` (one of :data:`MODELS`); ``options`` are passed to its constructor."""
    common = dict(n_beams=n_beams, n_bins=n_bins, task=task, horizon=horizon, dropout=dropout, **options)
    if name == "tn":
        return TransformerNet(**common)
    if name == "tn-match":  # tracking only: TrainConfig refuses another task
        return CandidateTransformer(dropout=dropout, **options)
    if name in ("lstm", "gru", "rnn"):
        return RecurrentNet(name, **common)
    if name == "tcn":
        return TCNNet(**common)
    if name == "conv1d":
        return Conv1DNet(**common)
    raise EstimationError(f"unknown model {name!r} (choose from {', '.join(MODELS)})")


def count_parameters(net: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)
