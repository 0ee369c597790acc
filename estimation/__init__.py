"""Trajectory estimation from beamformed-fingerprint sequences (torch lives only here).

Tasks: tracking (positions y_1..y_T from fingerprints X_1..X_T) and forecasting (from X_1..X_Tobs,
positions y_Tobs+1..y_L). Models: the transformer encoder-decoder of the paper (``tn``), LSTM, GRU,
plain RNN, TCN and Conv1D baselines (the registry :data:`MODELS`), the classical trackers
``knn-kalman`` (nearest fingerprint + Kalman smoother) and ``match-cv`` (match candidates +
hidden-Markov smoother), and ours: ``tn-match``, a transformer over the grid's most likely points of
every step, which starts from ``match-cv``.

Layout: :mod:`.data` (sequence sets and batches), :mod:`.noise` (fresh noisy bits in torch),
:mod:`.matching` (fingerprint likelihood on the grid), :mod:`.smoothing` (Kalman and hidden-Markov
smoothers), :mod:`.models` (networks and their registry), :mod:`.classical`, :mod:`.estimator`,
:mod:`.training`, :mod:`.evaluation`, :mod:`.report`; :mod:`.names` holds the vocabularies without
torch. Public names load on first use, so ``import estimation`` alone does not import torch.

Pipeline::

    sets, info = load_splits("data.zarr", ("train", "validation"))     # or synthetic.toy_splits
    train(sets["train"], sets["validation"], TrainConfig(model="tn"), "runs/tn")
    ev = evaluate([method("runs/tn"), method("knn-kalman")], test_sets, [6, 9], sets["validation"])
    write_report(ev, "report", [6, 9])
"""

from __future__ import annotations

from mmwsim.lazy import lazy_exports

_EXPORTS = {
    "GridTable": ".adapter",
    "load_splits": ".adapter",
    "open_dataset": ".adapter",
    "sequence_set": ".adapter",
    "CHECKPOINT_FORMAT": ".checkpoint",
    "MODEL_FORMAT": ".checkpoint",
    "load_checkpoint": ".checkpoint",
    "save_checkpoint": ".checkpoint",
    "KnnKalman": ".classical",
    "MatchSmoother": ".classical",
    "Batch": ".data",
    "BatchSampler": ".data",
    "Normaliser": ".data",
    "SequenceSet": ".data",
    "EstimationError": ".errors",
    "Estimator": ".estimator",
    "TrainConfig": ".estimator",
    "Evaluation": ".evaluation",
    "KnnKalmanMethod": ".evaluation",
    "MatchSmootherMethod": ".evaluation",
    "NetworkMethod": ".evaluation",
    "classical_method": ".evaluation",
    "evaluate": ".evaluation",
    "method": ".evaluation",
    "FingerprintMatcher": ".matching",
    "summarise": ".metrics",
    "summarise_by_kind": ".metrics",
    "trajectory_rmse": ".metrics",
    "MODELS": ".models",
    "ModelSpec": ".models",
    "build_network": ".models",
    "count_parameters": ".models",
    "model_spec": ".models",
    "CLASSICAL_NAMES": ".names",
    "MODEL_NAMES": ".names",
    "noisy_bits": ".noise",
    "accuracy_table": ".report",
    "cost_table": ".report",
    "log_estimates": ".report",
    "plot_error_vs_length": ".report",
    "record_estimates": ".report",
    "write_report": ".report",
    "MixtureMotion": ".smoothing",
    "MotionTable": ".smoothing",
    "kalman_forecast": ".smoothing",
    "rts_smoother": ".smoothing",
    "log_training": ".training",
    "read_run_info": ".training",
    "train": ".training",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
