"""Result files: their names checked once, and written so that a reader never sees a half-written one."""

from __future__ import annotations

import os
from pathlib import Path

from .errors import MmwsimError

__all__ = ["RECORDING_SUFFIX", "check_suffix", "write_text_atomic"]

RECORDING_SUFFIX = ".rrd"
"""The suffix of Rerun recordings."""


def check_suffix(path: str | os.PathLike, suffix: str, what: str = "") -> Path:
    """``path`` as a :class:`~pathlib.Path` when it ends in ``suffix``, else a one-line
    :class:`MmwsimError` naming the option ``what`` (e.g. ``--rrd``) and the path."""
    p = Path(path)
    if p.suffix.lower() != suffix:
        kind = "a recording" if suffix == RECORDING_SUFFIX else "the file"
        raise MmwsimError(f"{f'{what} ' if what else ''}{p}: {kind} must end in {suffix}")
    return p


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to a hidden sibling of ``path``, then rename it over ``path``; returns ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path
