"""Trajectory estimation from beamformed-fingerprint sequences (torch lives only here).

Tasks: tracking (positions y_1..y_T from fingerprints X_1..X_T) and forecasting (from X_1..X_Tobs,
positions y_Tobs+1..y_L). Models: the transformer of the paper (``tn``, by default in the
configuration measured best on our data: a wide embedding of the set bits, a cell head, a warm-up
on single fingerprints; :data:`PAPER_OPTIONS` gives the paper's), LSTM, GRU,
plain RNN, TCN and Conv1D baselines (the registry :data:`MODELS`), the classical trackers
``knn-kalman`` (nearest fingerprint + Kalman smoother) and ``match-cv`` (match candidates +
hidden-Markov smoother), and ours: ``tn-match``, a transformer over the grid's most likely points of
every step, which starts from ``match-cv``.

Layout: :mod:`.data` (sequence sets and batches), :mod:`.noise` (fresh noisy bits in torch),
:mod:`.matching` (fingerprint likelihood on the grid), :mod:`.smoothing` (Kalman and hidden-Markov
smoothers), :mod:`.models` (networks and their registry), :mod:`.classical`, :mod:`.estimator`,
:mod:`.training`, :mod:`.refit` (a trained ``tn-match``'s motion tables measured again), :mod:`.evaluation`, :mod:`.report`, :mod:`.oracle` (the floor: a particle
smoother that knows how the data were made); :mod:`.names` holds the vocabularies without torch. Public names load on first use, so ``import estimation`` alone does not import torch.

Pipeline::

    sets, info = load_splits("data.zarr", ("train", "validation"))     # or synthetic.toy_splits
    train(sets["train"], sets["validation"], TrainConfig(model="tn"), "runs/tn")
    ev = evaluate([method("runs/tn"), method("knn-kalman")], test_sets, [6, 9], sets["validation"])
    write_report(ev, "report", [6, 9])
"""

from __future__ import annotations

from mmwsim.lazy import lazy_exports

_EXPORTS = {
    ".adapter": ("GridTable", "load_splits", "open_dataset", "sequence_set"),
    ".checkpoint": ("CHECKPOINT_FORMAT", "MODEL_FORMAT", "load_checkpoint", "save_checkpoint"),
    ".classical": ("KnnKalman", "MatchSmoother"),
    ".data": ("Batch", "BatchSampler", "Normaliser", "SequenceSet"),
    ".errors": ("EstimationError",),
    ".estimator": ("Estimator", "OnlineTracker", "TrainConfig"),
    ".evaluation": (
        "Evaluation",
        "KnnKalmanMethod",
        "MatchSmootherMethod",
        "NetworkMethod",
        "classical_method",
        "evaluate",
        "method",
    ),
    ".matching": ("FingerprintMatcher",),
    ".metrics": ("summarise", "summarise_by_kind", "trajectory_rmse"),
    ".models": (
        "MODELS",
        "PAPER_OPTIONS",
        "CellHead",
        "ModelSpec",
        "build_network",
        "count_parameters",
        "model_spec",
    ),
    ".names": ("CLASSICAL_NAMES", "MODEL_NAMES"),
    ".noise": ("noisy_bits",),
    ".refit": ("refit_motion",),
    ".oracle": ("ORACLE_PARTICLES", "Oracle", "OracleMethod"),
    ".report": (
        "accuracy_table",
        "cost_table",
        "log_estimates",
        "plot_error_vs_length",
        "record_estimates",
        "write_report",
    ),
    ".smoothing": (
        "CandidateFilter",
        "MixtureMotion",
        "MotionMemory",
        "MotionTable",
        "extrapolate",
        "forecast_tracks",
        "kalman_forecast",
        "route_track",
        "rts_smoother",
    ),
    ".training": ("log_training", "read_run_info", "train"),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
