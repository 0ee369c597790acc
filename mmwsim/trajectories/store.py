"""Trajectories in the data set's zarr store: one group ``trajectories/<split>`` per split.

The store is a complete data set (:class:`mmwsim.dataset.Dataset`), or, for trajectories
without PDPs, a trajectory-only store (a zarr group marked ``attrs["mmwsim"]["format"] =
"mmwsim-trajectories"``) created on first write. The trajectories group is not part of the
data set's content hash, which covers its generation only, so adding or replacing
trajectories leaves ``Dataset.open`` and ``mmwsim generate --resume`` as they were.

Each split group holds ``positions`` (n, L, 2) float64 metres, ``kind`` (n,) uint8 (index into
``attrs["kinds"]``), ``ids`` (n,) int64, ``events`` (n, L-1) int8 and ``holdout`` (n,) bool, and
in its attributes the provenance (seed, rate, motion models, split parameters) with a content
hash. All splits are written into a hidden sibling group, which then replaces the old group
with :func:`mmwsim.files.replace_dir`: at every instant, a kill included, the store holds the
old splits or the new ones. Writers hold the store's lock (:mod:`mmwsim.locks`).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from zarr.codecs import ZstdCodec
from zarr.storage import LocalStore

from ..config import content_hash
from ..dataset import Dataset
from ..dataset.store import FORMAT as DATASET_FORMAT
from ..faults import fault
from ..files import reading, recover_dir, remove_tree, replace_dir, resolve_dir, write_error
from ..locks import OutputLock
from .errors import TrajectoryError
from .motion import EVENT_NAMES, KINDS
from .trajectories import Trajectories

__all__ = [
    "GROUP",
    "TRAJECTORY_FORMAT",
    "is_trajectory_store",
    "list_splits",
    "read_trajectories",
    "store_root",
    "write_trajectories",
]

GROUP = "trajectories"
TRAJECTORY_FORMAT = "mmwsim-trajectories"
_ARRAYS = ("positions", "kind", "ids", "events", "holdout")

Store = str | os.PathLike | zarr.Group | Dataset


def store_root(store: Store) -> Path:
    """Folder of a local zarr store given as a path, a :class:`Dataset` or an open root group."""
    if isinstance(store, Dataset):
        return store.path
    if isinstance(store, zarr.Group):
        if not isinstance(store.store, LocalStore):
            raise TrajectoryError("trajectories can only be stored in a local (folder) zarr store")
        return Path(store.store.root) / store.path
    return Path(store)


def _format(root: Path) -> str | None:
    """``attrs["mmwsim"]["format"]`` of the zarr group at ``root`` (None if unmarked)."""
    try:
        return json.loads((root / "zarr.json").read_text())["attributes"]["mmwsim"]["format"]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def is_trajectory_store(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a trajectory-only store (trajectories written without a data set)."""
    root = Path(path)
    return (root / "zarr.json").is_file() and _format(root) == TRAJECTORY_FORMAT


def _prepare(store: Store, splits: dict[str, Trajectories]) -> Path:
    """Check that ``store`` may take these trajectories (creating a trajectory-only store if
    missing) and return its folder."""
    root = store_root(store)
    if not root.exists():
        try:
            zarr.open_group(root, mode="w", zarr_format=3).attrs["mmwsim"] = {"format": TRAJECTORY_FORMAT}
        except OSError as e:
            remove_tree(root)
            raise write_error(e, root, "nothing was kept") from None
        return root
    if not (root / "zarr.json").is_file():
        raise TrajectoryError(f"{root}: not a zarr store (no zarr.json)")
    kind = _format(root)
    if kind == TRAJECTORY_FORMAT:
        return root
    if kind != DATASET_FORMAT:
        raise TrajectoryError(f"{root}: neither an mmwsim data set nor a trajectory store")
    ds = store if isinstance(store, Dataset) else Dataset.open(root)  # refuses an incomplete data set
    for name, t in splits.items():
        made_for = t.attrs.get("dataset")
        if made_for is not None and made_for != ds.content_hash:
            raise TrajectoryError(
                f"{root}: split {name!r} was generated for another data set "
                f"(content hash {str(made_for)[:12]}, this one {ds.content_hash[:12]})"
            )
    return root


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def write_trajectories(store: Store, splits: dict[str, Trajectories]) -> Path:
    """Replace the ``trajectories`` group of a data set (or trajectory-only store) with these splits.

    The group is written next to its place and renamed into it, so readers see the old
    splits or the new ones, never a mixture; same splits give the same bytes.

    Parameters
    ----------
    store : Dataset, path or zarr.Group
        A complete data set, a trajectory-only store, or a missing folder (a trajectory-only
        store is created there).
    splits : dict
        Split name -> Trajectories.

    Returns
    -------
    Path
        Folder of the written group.

    Raises
    ------
    TrajectoryError
        If the folder is another kind of zarr store, or a split was generated for another
        data set (its ``attrs["dataset"]`` content hash); an incomplete data set raises
        :class:`~mmwsim.errors.MmwsimError` from ``Dataset.open``.
    """
    root = store_root(store)
    if not root.parent.is_dir():
        try:
            root.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise write_error(e, root.parent) from None
    with OutputLock(root, "store"):
        root = _prepare(store, splits)
        final = root / GROUP
        tmp = root / f".{GROUP}.partial"
        try:
            recover_dir(final)  # a replacement killed halfway: finish it or roll it back
            remove_tree(tmp)  # what a killed run was writing
            _write_group(tmp, splits)
            replace_dir(tmp, final)
        except OSError as e:
            raise write_error(e, final, "the stored trajectories are unchanged") from None
        finally:
            remove_tree(tmp)
    return final


def _write_group(tmp: Path, splits: dict[str, Trajectories]) -> None:
    fault("trajectories.write", tmp)
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


def list_splits(store: Store) -> list[str]:
    """Names of the stored splits (empty if the store holds no trajectories)."""
    group = resolve_dir(store_root(store) / GROUP)
    if not (group / "zarr.json").exists():
        return []
    with reading(group, "trajectory group"):
        names = zarr.open_group(group, mode="r").attrs.get("splits", [])
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise ValueError(f"splits attribute {names!r} is not a list of names")
    return names


def _split_dir(store: Store, split: str) -> Path:
    root = store_root(store)
    names = list_splits(root)
    if split not in names:
        have = ", ".join(names) if names else "none"
        raise TrajectoryError(f"{root}: no trajectory split {split!r} (stored: {have})")
    return resolve_dir(root / GROUP) / split


def split_attrs(store: Store, split: str) -> dict[str, Any]:
    """The attributes of one stored split (how it was generated), without reading its arrays."""
    where = _split_dir(store, split)
    with reading(where, "trajectory split"):
        return dict(zarr.open_group(where, mode="r").attrs)


def read_trajectories(store: Store, split: str) -> Trajectories:
    """Read one split back.

    Returns
    -------
    Trajectories
    """
    root = store_root(store)
    where = _split_dir(store, split)
    with reading(where, "trajectory split"):
        g = zarr.open_group(where, mode="r")
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
