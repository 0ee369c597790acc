"""Trajectories in the data set's zarr store: one group ``trajectories/<split>`` per split.

Each split group holds ``positions`` (n, L, 2) float64 metres, ``kind`` (n,) uint8 (index into
``attrs["kinds"]``), ``ids`` (n,) int64, ``events`` (n, L-1) int8 and ``holdout`` (n,) bool, and
in its attributes the provenance (seed, rate, motion models, split parameters) with a content
hash. All splits are written into a hidden sibling group and moved into place in one rename, so
an interrupted run never leaves a half-written ``trajectories`` group.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from zarr.codecs import ZstdCodec

from ..config import content_hash
from .errors import TrajectoryError
from .motion import EVENT_NAMES, KINDS
from .trajectories import Trajectories

__all__ = ["GROUP", "write_trajectories", "read_trajectories", "list_splits", "store_root"]

GROUP = "trajectories"
_ARRAYS = ("positions", "kind", "ids", "events", "holdout")


def store_root(store: str | os.PathLike | zarr.Group) -> Path:
    """Folder of a local zarr store given as a path or an open root group."""
    if isinstance(store, zarr.Group):
        root = getattr(store.store, "root", None)
        if root is None:
            raise TrajectoryError("trajectories can only be stored in a local (folder) zarr store")
        return Path(root) / store.path
    return Path(store)


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def write_trajectories(store: str | os.PathLike | zarr.Group, splits: dict[str, Trajectories]) -> Path:
    """Replace the ``trajectories`` group of a zarr store with these splits.

    Parameters
    ----------
    store : path or zarr.Group
        Root of the data set (a folder zarr store); created if missing.
    splits : dict
        Split name -> Trajectories.

    Returns
    -------
    Path
        Folder of the written group.
    """
    root = store_root(store)
    if root.exists() and not (root / "zarr.json").exists():
        raise TrajectoryError(f"{root}: not a zarr store (no zarr.json)")
    zarr.open_group(root, mode="a")
    final = root / GROUP
    tmp = root / f".{GROUP}.partial"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        group = zarr.open_group(tmp, mode="w", zarr_format=3)
        for name, t in splits.items():
            g = group.create_group(name)
            data = {
                "positions": t.positions,
                "kind": t.kind,
                "ids": t.ids,
                "events": t.events,
                "holdout": t.holdout.astype(np.bool_),
            }
            for key, arr in data.items():
                chunks = (max(1, min(len(arr), 4096)),) + arr.shape[1:]
                a = g.create_array(
                    key, shape=arr.shape, dtype=arr.dtype, chunks=chunks, compressors=ZstdCodec(level=3)
                )
                if arr.size:
                    a[...] = arr
            attrs = _jsonable(
                {
                    **t.attrs,
                    "kinds": list(KINDS),
                    "events": list(EVENT_NAMES),
                    "rate_hz": t.rate_hz,
                    "n": len(t),
                }
            )
            attrs["content_hash"] = content_hash(attrs)
            g.attrs.update(attrs)
        group.attrs.update({"splits": list(splits)})
        old = root / f".{GROUP}.old"
        shutil.rmtree(old, ignore_errors=True)
        if final.exists():
            os.replace(final, old)
        os.replace(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return final


def list_splits(store: str | os.PathLike | zarr.Group) -> list[str]:
    """Names of the stored splits (empty if the store holds no trajectories)."""
    root = store_root(store)
    if not (root / GROUP / "zarr.json").exists():
        return []
    return list(zarr.open_group(root / GROUP, mode="r").attrs.get("splits", []))


def read_trajectories(store: str | os.PathLike | zarr.Group, split: str) -> Trajectories:
    """Read one split back.

    Returns
    -------
    Trajectories
    """
    root = store_root(store)
    names = list_splits(root)
    if split not in names:
        have = ", ".join(names) if names else "none"
        raise TrajectoryError(f"{root}: no trajectory split {split!r} (stored: {have})")
    g = zarr.open_group(root / GROUP / split, mode="r")
    arrays = {k: np.asarray(g[k][...]) for k in _ARRAYS}
    attrs = dict(g.attrs)
    if list(attrs.get("kinds", KINDS)) != list(KINDS):
        raise TrajectoryError(
            f"{root}: trajectory kinds {attrs.get('kinds')} differ from this version's {KINDS}"
        )
    rate = float(attrs.get("rate_hz", 1.0))
    return Trajectories(
        arrays["positions"], arrays["kind"], arrays["ids"], arrays["events"], rate, attrs, arrays["holdout"]
    )
