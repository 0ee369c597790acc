"""The data set: zarr v3 store of receiver grid, per-beam PDPs and paths; its generation."""

from .config import CodebookConfig, GenerateConfig, resolve_config
from .generate import generate, run_tiles
from .record import log_dataset, record_dataset
from .store import Dataset
from .tiles import TileResult, compute_tile

__all__ = [
    "CodebookConfig",
    "Dataset",
    "GenerateConfig",
    "TileResult",
    "compute_tile",
    "generate",
    "log_dataset",
    "record_dataset",
    "resolve_config",
    "run_tiles",
]
