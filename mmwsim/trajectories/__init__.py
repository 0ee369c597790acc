"""User trajectories (pedestrian, hybrid, vehicle, static), their splits and fingerprint sequences.

Typical use, with a data set made by ``mmwsim generate``::

    from mmwsim.dataset import Dataset
    from mmwsim.trajectories import SequenceLoader, generate_for_dataset, split, write_trajectories

    ds = Dataset.open("default.zarr")
    t = generate_for_dataset(ds, {"pedestrian": 1000, "vehicle": 500}, length=7, seed=0)
    write_trajectories(ds, split(t, holdout_region=(250, 250, 350, 350)))
    for bits, positions in SequenceLoader.from_dataset(ds, "train", batch_size=64):
        ...  # bits (64, 7, 32, 81) with fresh noise, positions (64, 7, 2)
"""

from .errors import TrajectoryError
from .fingerprints import (
    FEATURE_BINS,
    GridPdp,
    SequenceLoader,
    TracedPdp,
    noisy_fingerprints,
    pdp_sequences,
)
from .freespace import CoverageMask, FreeSpace, nearest_grid_index
from .generate import MAX_LENGTH, MIN_LENGTH, check_length, generate, generate_for_dataset, generate_kind
from .motion import EVENT_NAMES, HYBRID, KINDS, MODELS, PEDESTRIAN, STATIC, VEHICLE, MotionModel, motion_model
from .record import log_trajectories
from .splits import SPLITS, split, touches_region
from .store import is_trajectory_store, list_splits, read_trajectories, write_trajectories
from .streets import StreetNetwork
from .trajectories import Trajectories

__all__ = [
    "CoverageMask",
    "EVENT_NAMES",
    "FEATURE_BINS",
    "FreeSpace",
    "GridPdp",
    "HYBRID",
    "KINDS",
    "MAX_LENGTH",
    "MIN_LENGTH",
    "MODELS",
    "MotionModel",
    "PEDESTRIAN",
    "SPLITS",
    "STATIC",
    "SequenceLoader",
    "StreetNetwork",
    "TracedPdp",
    "TrajectoryError",
    "Trajectories",
    "VEHICLE",
    "check_length",
    "generate",
    "generate_for_dataset",
    "generate_kind",
    "is_trajectory_store",
    "list_splits",
    "log_trajectories",
    "motion_model",
    "nearest_grid_index",
    "noisy_fingerprints",
    "pdp_sequences",
    "read_trajectories",
    "split",
    "touches_region",
    "write_trajectories",
]
