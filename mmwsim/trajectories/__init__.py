"""User trajectories (pedestrian, hybrid, vehicle, static), their splits and fingerprint sequences.

Typical use::

    from mmwsim.trajectories import generate, split
    t = generate(scene, {"pedestrian": 1000, "vehicle": 500}, length=7, seed=0)
    parts = split(t, holdout_region=(250, 250, 350, 350))
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
from .generate import MAX_LENGTH, MIN_LENGTH, check_length, generate, generate_kind
from .motion import EVENT_NAMES, HYBRID, KINDS, MODELS, PEDESTRIAN, STATIC, VEHICLE, MotionModel, motion_model
from .record import log_trajectories
from .splits import SPLITS, split, touches_region
from .store import list_splits, read_trajectories, write_trajectories
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
    "generate_kind",
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
