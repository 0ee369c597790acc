"""The vocabularies of trajectory estimation, importable without torch (the CLI offers them)."""

from __future__ import annotations

from typing import Literal, get_args

__all__ = [
    "CLASSICAL_NAMES",
    "ClassicalName",
    "LOSSES",
    "Loss",
    "MODEL_NAMES",
    "SCHEDULES",
    "Schedule",
    "ModelName",
    "TASKS",
    "Task",
]

Task = Literal["tracking", "forecasting"]
"""Tracking: positions of every observed step. Forecasting: the steps after the observed ones."""
TASKS: tuple[Task, ...] = get_args(Task)

Loss = Literal["mse", "rmse", "cells"]
"""``mse``: the paper's, over all coordinates; ``rmse``: the mean per-trajectory RMSE; ``cells``: a
cell head's own (cross-entropy over the cells plus a Huber term on the position, see
:class:`estimation.models.heads.CellHead`)."""
LOSSES: tuple[Loss, ...] = get_args(Loss)

Schedule = Literal["plateau", "cosine"]
"""How the learning rate falls: on plateaus of the validation loss (the paper's) or along a cosine."""
SCHEDULES: tuple[Schedule, ...] = get_args(Schedule)

ModelName = Literal["tn", "tn-match", "lstm", "gru", "rnn", "tcn", "conv1d"]
"""The trainable networks (:data:`estimation.models.MODELS` holds their specifications)."""
MODEL_NAMES: tuple[ModelName, ...] = get_args(ModelName)

ClassicalName = Literal["knn-kalman", "match-cv", "oracle"]
"""The trackers evaluated without training (:func:`estimation.evaluation.classical_method`): the two
classical ones and the ``oracle`` floor (:mod:`estimation.oracle`)."""
CLASSICAL_NAMES: tuple[ClassicalName, ...] = get_args(ClassicalName)
