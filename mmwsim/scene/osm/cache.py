"""On-disk cache of built OSM scenes, keyed by the file's content hash, the area and the options.

Entries are ``.npz`` files read with ``allow_pickle=False`` (plain arrays and one JSON string), in
``$MMWSIM_CACHE_DIR`` or else ``$XDG_CACHE_HOME/mmwsim/osm`` (``~/.cache/mmwsim/osm``). A cache that
cannot be written is skipped silently; an unreadable entry is rebuilt.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path

import numpy as np

__all__ = ["cache_dir", "file_sha256", "read_entry", "write_entry"]


def cache_dir() -> Path:
    """Folder of the OSM scene cache."""
    env = os.environ.get("MMWSIM_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "mmwsim" / "osm"


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes."""
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def read_entry(key: str) -> tuple[dict, dict[str, np.ndarray]] | None:
    """(metadata, arrays) stored under ``key``, or None when absent or unreadable."""
    path = cache_dir() / f"{key}.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        meta = json.loads(str(arrays.pop("meta")[()]))
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError):
        return None
    return meta, arrays


def write_entry(key: str, meta: dict, arrays: dict[str, np.ndarray]) -> Path | None:
    """Store an entry atomically; returns its path, or None when the cache cannot be written."""
    folder = cache_dir()
    path = folder / f"{key}.npz"
    tmp = folder / f".{key}.{os.getpid()}.partial.npz"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        np.savez(tmp, meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)
        os.replace(tmp, path)
    except OSError:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        return None
    return path
