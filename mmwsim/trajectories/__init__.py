"""User trajectories (pedestrian, hybrid, vehicle, static), their splits and fingerprint sequences.

Typical use, with a data set made by ``mmwsim generate``::

    from mmwsim.dataset import Dataset
    from mmwsim.trajectories import SequenceLoader, generate_for_dataset, split, write_trajectories

    ds = Dataset.open("default.zarr")
    t = generate_for_dataset(ds, {"pedestrian": 1000, "vehicle": 500}, length=7, seed=0)
    write_trajectories(ds, split(t, holdout_region=(250, 250, 350, 350)))
    for bits, positions in SequenceLoader.from_dataset(ds, "train", batch_size=64):
        ...  # bits (64, 7, 32, 81) with fresh noise, positions (64, 7, 2)

Users move in the scene's free space (:class:`mmwsim.geometry.FreeSpace`), the same the planner
plans in.
"""

from .errors import TrajectoryError
from .generate import MAX_LENGTH, MIN_LENGTH, generate_for_dataset, generate_kind
from .generate import generate as generate_trajectories
from .motion import EVENT_NAMES, KINDS, MOTION_MODELS, Kind, MotionModel, motion_model
from .record import log_trajectories
from .sequences import SequenceLoader, pdp_sequences
from .splits import SPLITS, BlockFolds, block_folds, split, touches_region
from .store import is_trajectory_store, list_splits, read_trajectories, split_attrs, write_trajectories
from .streets import StreetNetwork, segment_feet
from .trajectories import Trajectories

__all__ = [
    "EVENT_NAMES",
    "KINDS",
    "MAX_LENGTH",
    "MIN_LENGTH",
    "MOTION_MODELS",
    "Kind",
    "MotionModel",
    "SPLITS",
    "BlockFolds",
    "SequenceLoader",
    "StreetNetwork",
    "segment_feet",
    "TrajectoryError",
    "Trajectories",
    "block_folds",
    "generate_for_dataset",
    "generate_kind",
    "generate_trajectories",
    "is_trajectory_store",
    "list_splits",
    "log_trajectories",
    "motion_model",
    "pdp_sequences",
    "read_trajectories",
    "split_attrs",
    "split",
    "touches_region",
    "write_trajectories",
]
