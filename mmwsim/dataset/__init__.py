"""The data set: zarr v3 store of receiver grid, per-beam PDPs and paths; its generation."""

from .config import CodebookConfig, GenerateConfig
from .generate import generate as generate_dataset
from .record import log_dataset, record_dataset
from .store import Dataset

__all__ = [
    "CodebookConfig",
    "Dataset",
    "GenerateConfig",
    "generate_dataset",
    "log_dataset",
    "record_dataset",
]
