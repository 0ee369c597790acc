"""Thin adapter from the data set on disk (grid PDPs + stored trajectory splits) to :class:`SequenceSet`.

The grid PDP of every valid point is read once (in chunks, cut to the fingerprint bins, stored as
float16 to halve memory) and shared by all splits; each trajectory step is mapped to its nearest
valid grid point, whose row index the training pipeline gathers per batch.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mmwsim.constants import BINS, THRESHOLD_DBM
from mmwsim.fingerprints import GridField
from mmwsim.trajectories.motion import KINDS
from mmwsim.trajectories.streets import STREET_HALF_WIDTH

from .data import SequenceSet
from .errors import EstimationError

__all__ = [
    "open_dataset",
    "GridTable",
    "dataset_threshold",
    "load_splits",
    "load_sets",
    "scene_footprints",
    "sequence_set",
    "street_lines",
]

_CHUNK = 8192  # grid points per read


def open_dataset(path: str | os.PathLike) -> Any:
    """``mmwsim.Dataset.open(path)``, with one-line errors."""
    from mmwsim.errors import MmwsimError

    try:
        from mmwsim.dataset import Dataset
    except ImportError:
        raise EstimationError(f"{path}: cannot open data sets (mmwsim.dataset is not available)") from None
    if not Path(path).exists():
        raise EstimationError(f"{path}: data set not found")
    try:
        return Dataset.open(path)
    except MmwsimError as e:
        raise EstimationError(str(e)) from None


class GridTable:
    """The valid grid points of a data set with their fingerprint-window PDPs.

    Parameters
    ----------
    dataset : object with ``.grid`` (ReceiverGrid), ``.valid`` ((G,) bool), ``.pdp`` ((G, M, n_bins)
        dBm, numpy or zarr array)
    bins : slice
        Fingerprint bin window (default the data set's ``config["bins"]``, else
        the contract's window ``mmwsim.constants.BINS``, bins 1..81).
    dtype : torch dtype of the stored PDP (float16 default; about 0.03 dB resolution at -115 dBm,
        far below the noise).

    Attributes
    ----------
    pdp : (G_valid, M, N_s) tensor, dBm
    xy : (G_valid, 2) float64, metres
    flat_index : (G_valid,) int64, index of each row in the full grid
    extent : (2, 2) float64, ``[[x_min, y_min], [x_max, y_max]]`` of the full grid
    streets : (e, 2, 2) float64 or None, the scene's street centre lines (:func:`street_lines`)
    """

    def __init__(self, dataset: Any, bins: slice | None = None, dtype: torch.dtype = torch.float16):
        if bins is None:
            stored = (getattr(dataset, "config", None) or {}).get("bins")
            if stored is not None:
                bins = slice(int(stored[0]), int(stored[1]))
            else:
                bins = slice(*BINS)
        grid = dataset.grid
        valid = np.asarray(dataset.valid, dtype=bool).reshape(-1)
        pdp = dataset.pdp
        if len(pdp.shape) != 3 or pdp.shape[0] != grid.size or valid.shape != (grid.size,):
            raise EstimationError(
                f"data set arrays do not fit its grid: pdp {tuple(pdp.shape)}, valid {valid.shape}, "
                f"grid {grid.size} points"
            )
        self.flat_index = np.flatnonzero(valid)
        if not len(self.flat_index):
            raise EstimationError("data set has no valid grid point")
        nx = grid.shape[0]
        self.xy = np.column_stack([grid.xs[self.flat_index % nx], grid.ys[self.flat_index // nx]])
        self.extent = np.asarray(grid.bounds, dtype=np.float64)
        self.grid = grid
        n_bins = len(range(*bins.indices(pdp.shape[2])))
        from mmwsim.files import reading

        out = torch.empty((len(self.flat_index), pdp.shape[1], n_bins), dtype=dtype)
        with reading(getattr(dataset, "path", "data set"), "data set (its power-delay profiles)"):
            for k in range(0, len(self.flat_index), _CHUNK):
                rows = self.flat_index[k : k + _CHUNK]
                lo, hi = int(rows[0]), int(rows[-1]) + 1
                block = np.asarray(pdp[lo:hi])[rows - lo][:, :, bins]  # contiguous read, then pick valid rows
                out[k : k + len(rows)] = torch.from_numpy(np.ascontiguousarray(block, dtype=np.float32))
        self.pdp = out
        self._row_of_flat = np.full(grid.size, -1, dtype=np.int64)
        self._row_of_flat[self.flat_index] = np.arange(len(self.flat_index))
        self._field = GridField(grid, pdp, valid)
        self.streets = street_lines(dataset)

    def rows(self, positions: np.ndarray) -> np.ndarray:
        """Row of the nearest valid grid point for each ``(..., 2)`` position (metres) -> ``(...,)`` int64."""
        return self._row_of_flat[self._field.valid_index_at(positions)]


def sequence_set(
    table: GridTable, positions: np.ndarray, kind_names: np.ndarray, threshold: float
) -> SequenceSet:
    """A :class:`SequenceSet` of trajectories ``positions (n, L, 2)`` with kinds given by name."""
    names = np.asarray(kind_names).astype(str)
    unknown = sorted(set(names) - set(KINDS))
    if unknown:
        raise EstimationError(f"unknown trajectory kinds {unknown}")
    kind = np.array([KINDS.index(k) for k in names], dtype=np.int8).reshape(len(names))
    pos = np.asarray(positions, dtype=np.float32)
    return SequenceSet(
        table.pdp, table.xy, table.rows(pos), pos, kind, float(threshold), table.extent, table.streets
    )


def street_lines(dataset: Any) -> np.ndarray | None:
    """Street centre lines ``(e, 2, 2)`` metres of a data set's scene within its grid, where its
    vehicles keep to them: the network :class:`mmwsim.trajectories.StreetNetwork` derives from
    the free space (or the scene's own street lines, e.g. OpenStreetMap's) at the street half
    width and within the bounds its trajectories were generated with. None where the data set has no scene, its scene
    no street wide enough for a vehicle, or its stored trajectories say that their vehicles
    went anywhere (``mmwsim trajectories`` without ``--streets``)."""
    from mmwsim.errors import MmwsimError
    from mmwsim.trajectories import list_splits, split_attrs
    from mmwsim.trajectories.streets import StreetNetwork

    scene_of = getattr(dataset, "scene", None)
    if scene_of is None:
        return None
    try:
        splits = list_splits(dataset)
        attrs = split_attrs(dataset, splits[0]) if splits else {}
        if not attrs.get("vehicles_on_streets", True):
            return None
        half_width = float(attrs.get("street_half_width", STREET_HALF_WIDTH))
        bounds = np.asarray(attrs.get("bounds") or dataset.grid.bounds, dtype=np.float64).reshape(2, 2)
        net = StreetNetwork.from_scene(scene_of(), half_width, bounds=bounds)
    except (MmwsimError, OSError, ValueError, TypeError):
        return None
    return net.lines()


def dataset_threshold(dataset: Any) -> float:
    """Detection threshold of a data set, dBm: its ``config["threshold_dbm"]``, else its
    ``threshold_dbm`` attribute, else ``mmwsim.constants.THRESHOLD_DBM``."""
    stored = (getattr(dataset, "config", None) or {}).get("threshold_dbm")
    return float(stored if stored is not None else getattr(dataset, "threshold_dbm", THRESHOLD_DBM))


def load_splits(
    path: str | os.PathLike, splits: tuple[str, ...], dataset: Any = None, threshold: float | None = None
) -> tuple[dict[str, SequenceSet], dict[str, Any]]:
    """Read trajectory splits of a data set as :class:`SequenceSet` s over one shared grid table.

    Parameters
    ----------
    path : path-like
        The data set (zarr store) holding ``trajectories/<split>``.
    splits : tuple of str
        Split names, e.g. ``("train", "validation")``; ``"test/holdout"`` and ``"test/seen"`` select
        the test trajectories that do / do not touch the spatial hold-out region.
    dataset : object, optional
        An already opened data set (``.grid``, ``.valid``, ``.pdp``); opened from ``path`` if None.
    threshold : float, optional
        Detection threshold, dBm (default the data set's ``config["threshold_dbm"]``, else its
        ``threshold_dbm`` attribute, else ``mmwsim.constants.THRESHOLD_DBM``).

    Returns
    -------
    sets : dict split -> SequenceSet
    info : dict describing the data (path, content hash, grid, splits and their sizes)
    """
    from mmwsim.errors import MmwsimError
    from mmwsim.trajectories import read_trajectories

    ds = open_dataset(path) if dataset is None else dataset
    if threshold is None:
        threshold = dataset_threshold(ds)
    table = GridTable(ds)
    sets: dict[str, SequenceSet] = {}
    for name in splits:
        base, _, sub = name.partition("/")
        try:
            t = read_trajectories(path, base)
        except MmwsimError as e:
            raise EstimationError(str(e)) from None
        keep = np.ones(len(t), dtype=bool)
        if sub == "holdout":
            keep = t.holdout
        elif sub == "seen":
            keep = ~t.holdout
        elif sub:
            raise EstimationError(f"unknown split {name!r} (use SPLIT, SPLIT/holdout or SPLIT/seen)")
        names = np.asarray(KINDS)[t.kind[keep]]
        sets[name] = sequence_set(table, t.positions[keep], names, threshold)
    info = {
        "dataset": str(Path(path).resolve()),
        "content_hash": str(getattr(ds, "content_hash", "")),
        "grid_points": int(len(table.flat_index)),
        "threshold_dbm": threshold,
        "splits": {k: v.n for k, v in sets.items()},
    }
    return sets, info


def load_sets(
    spec: str, splits: tuple[str, ...] | list[str]
) -> tuple[dict[str, SequenceSet], dict[str, Any]]:
    """Trajectory splits from a data set path, or from a toy spec (``toy[:n=N,length=L,seed=S]``, see
    :func:`estimation.synthetic.toy_splits`) for demos and tests without a data set."""
    if str(spec).startswith("toy"):
        from .synthetic import toy_splits

        sets = toy_splits(str(spec), tuple(splits))
        return sets, {"dataset": str(spec), "content_hash": "", "splits": {k: v.n for k, v in sets.items()}}
    return load_splits(spec, tuple(splits))


def scene_footprints(spec: str) -> list | None:
    """Building footprints of the scene a data set was generated from (for recordings), or None
    when the data set is a toy one or its scene cannot be loaded."""
    if str(spec).startswith("toy"):
        return None
    from mmwsim.errors import MmwsimError

    try:
        from mmwsim.scene import load_scene

        name = open_dataset(spec).config.get("scene")
        return list(load_scene(name).footprints) if name else None
    except (MmwsimError, OSError, AttributeError):
        return None
