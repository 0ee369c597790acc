"""Trajectory estimation from beamformed-fingerprint sequences (torch lives only here).

Tasks: tracking (positions y_1..y_T from fingerprints X_1..X_T) and forecasting (from X_1..X_Tobs,
positions y_Tobs+1..y_L). Models: the transformer encoder-decoder of the paper (``tn``), LSTM, GRU,
plain RNN, TCN and Conv1D baselines, a classical nearest-fingerprint + Kalman-smoother baseline
(``knn-kalman``), and ours: ``tn-match``, a transformer over the grid's most likely points of every
step, which starts from the classical candidate smoother ``match-cv``.

Pipeline::

    sets, info = load_splits("data.zarr", ("train", "validation"))     # or synthetic.toy_splits
    train(sets["train"], sets["validation"], TrainConfig(model="tn"), "runs/tn")
    ev = evaluate([NetworkMethod(Estimator.load("runs/tn"), "tn"), KnnKalmanMethod()], test_sets, [6, 9], val)
    write_report(ev, "report", [6, 9])
"""

from __future__ import annotations

from .adapter import GridTable, load_splits, open_dataset, sequence_set
from .checkpoint import CHECKPOINT_FORMAT, MODEL_FORMAT, load_checkpoint, save_checkpoint
from .classical import FingerprintMatcher, KnnKalman, MatchSmoother, kalman_forecast, rts_smoother
from .data import KINDS, Batch, BatchSampler, Normaliser, SequenceSet, fingerprint_bits
from .errors import EstimationError
from .estimator import Estimator, TrainConfig
from .evaluation import Evaluation, KnnKalmanMethod, MatchSmootherMethod, NetworkMethod, evaluate, noisy_bits
from .metrics import summarise, summarise_by_kind, trajectory_rmse
from .models import MODELS, MixtureMotion, MotionTable, build_network, count_parameters
from .report import (
    accuracy_table,
    cost_table,
    log_trajectories,
    plot_error_vs_length,
    record_trajectories,
    write_report,
)
from .training import log_training, read_run_info, train

__all__ = [
    "Batch",
    "BatchSampler",
    "CHECKPOINT_FORMAT",
    "EstimationError",
    "Estimator",
    "Evaluation",
    "FingerprintMatcher",
    "GridTable",
    "KINDS",
    "KnnKalman",
    "KnnKalmanMethod",
    "MatchSmoother",
    "MatchSmootherMethod",
    "MixtureMotion",
    "MotionTable",
    "MODELS",
    "MODEL_FORMAT",
    "NetworkMethod",
    "Normaliser",
    "SequenceSet",
    "TrainConfig",
    "accuracy_table",
    "build_network",
    "cost_table",
    "count_parameters",
    "evaluate",
    "fingerprint_bits",
    "kalman_forecast",
    "load_checkpoint",
    "load_splits",
    "log_trajectories",
    "noisy_bits",
    "open_dataset",
    "plot_error_vs_length",
    "read_run_info",
    "log_training",
    "record_trajectories",
    "rts_smoother",
    "save_checkpoint",
    "sequence_set",
    "summarise",
    "summarise_by_kind",
    "train",
    "trajectory_rmse",
    "write_report",
]
