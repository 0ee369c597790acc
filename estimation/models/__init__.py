"""Trajectory-estimation networks and their registry.

A network maps fingerprint bits ``(B, T_in, M, N_s)`` to normalised positions ``(B, T_out, 2)``,
or, if it reads the grid (``tn-match``), the smoothed match candidates of those bits. Each entry of
:data:`MODELS` says how to build a network and what it needs, so that training, prediction and
evaluation ask the registry instead of naming models.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from torch import nn

from ..errors import EstimationError
from ..names import MODEL_NAMES, TASKS, ModelName, Task
from .baseline import BASELINE_PAPER_OPTIONS, BaselineNet
from .candidate_transformer import CandidateTransformer
from .conv import Conv1DNet, TCNNet
from .heads import CellHead, CellOutput, RegressionHead, positions
from .recurrent import RecurrentNet
from .transformer import PAPER_OPTIONS, TransformerNet

TN_RECIPE: dict[str, Any] = {
    "loss": "cells",
    "warmup_epochs": 24,
    "epochs": 200,
    "lr": 3e-4,
    "schedule": "cosine",
    "min_delta": 0.0,
}
"""How ``tn`` and the baselines (which share its embedding and head) train by default (docs/estimation.md,
"Why the paper's transformer was at 7.5 m"): the cell head's loss; 24 warm-up epochs on single fingerprints at a learning rate of 3e-3, then sequences
at 3e-4 (at 1e-3 the attention's first steps throw the trained embedding about), each phase on
its own cosine down to zero, by epoch 200 in all; early stopping counts any
new best as an improvement, however small (the loss falls slowly to the end of a cosine). With
epochs of 2048 trajectories that is about 30 minutes on 2 cores (1771 s for 197 epochs)."""

__all__ = [
    "BASELINE_PAPER_OPTIONS",
    "BaselineNet",
    "MODELS",
    "CandidateTransformer",
    "CellHead",
    "CellOutput",
    "PAPER_OPTIONS",
    "RegressionHead",
    "TN_RECIPE",
    "positions",
    "Conv1DNet",
    "ModelSpec",
    "RecurrentNet",
    "TCNNet",
    "TransformerNet",
    "build_network",
    "count_parameters",
    "model_spec",
]


@dataclass(frozen=True)
class ModelSpec:
    """A trainable network of the registry.

    Attributes
    ----------
    name : str
    build : callable
        ``build(n_beams, n_bins, task, horizon, dropout, **options) -> nn.Module``.
    reads_grid : bool
        The network chooses among the grid's fingerprint-match candidates, so it needs the data
        set's grid attached (:meth:`~estimation.Estimator.attach`) and reads
        :meth:`~estimation.Estimator.inputs` rather than the bits.
    tasks : tuple of str
        Tasks it can be trained for.
    recipe : dict
        Its own defaults of the :class:`~estimation.TrainConfig` settings that are left unset
        (``loss``, ``epochs``, ``lr``, ``schedule``, ``warmup_epochs``; see
        :data:`estimation.estimator.RECIPE_DEFAULTS` for everyone else's).
    """

    name: ModelName
    build: Callable[..., nn.Module]
    reads_grid: bool = False
    tasks: tuple[Task, ...] = TASKS
    recipe: Mapping[str, Any] = field(default_factory=dict)


def _sequence_net(cls: type[nn.Module], *args: Any) -> Callable[..., nn.Module]:
    def build(n_beams: int, n_bins: int, task: Task, horizon: int, dropout: float, **options) -> nn.Module:
        return cls(
            *args, n_beams=n_beams, n_bins=n_bins, task=task, horizon=horizon, dropout=dropout, **options
        )

    return build


def _candidate_net(
    n_beams: int, n_bins: int, task: Task, horizon: int, dropout: float, **options
) -> nn.Module:
    return CandidateTransformer(dropout=dropout, task=task, horizon=horizon, **options)


MODELS: dict[str, ModelSpec] = {
    spec.name: spec
    for spec in (
        ModelSpec("tn", _sequence_net(TransformerNet), recipe=TN_RECIPE),
        ModelSpec("tn-match", _candidate_net, reads_grid=True, recipe={"loss": "rmse"}),
        ModelSpec("lstm", _sequence_net(RecurrentNet, "lstm"), recipe=TN_RECIPE),
        ModelSpec("gru", _sequence_net(RecurrentNet, "gru"), recipe=TN_RECIPE),
        ModelSpec("rnn", _sequence_net(RecurrentNet, "rnn"), recipe=TN_RECIPE),
        ModelSpec("tcn", _sequence_net(TCNNet), recipe=TN_RECIPE),
        ModelSpec("conv1d", _sequence_net(Conv1DNet), recipe=TN_RECIPE),
    )
}
"""Every trainable network by name, in the order of :data:`estimation.names.MODEL_NAMES`."""
assert tuple(MODELS) == MODEL_NAMES, "the registry and the torch-free list of names differ"


def model_spec(name: str) -> ModelSpec:
    """The registry entry of ``name``, or a one-line :class:`EstimationError`."""
    try:
        return MODELS[name]
    except KeyError:
        raise EstimationError(f"unknown model {name!r} (choose from {', '.join(MODELS)})") from None


def build_network(
    name: str, n_beams: int, n_bins: int, task: Task, horizon: int, dropout: float = 0.01, **options
) -> nn.Module:
    """The network ``name`` (one of :data:`MODELS`); ``options`` are passed to its constructor."""
    return model_spec(name).build(n_beams, n_bins, task, horizon, dropout, **options)


def count_parameters(net: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)
