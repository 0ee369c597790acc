"""Checkpoints: plain dicts of tensors, numbers and strings, saved atomically, loaded with
``torch.load(weights_only=True)`` so that a file never executes code when read."""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any

import torch

from .errors import EstimationError

__all__ = ["CHECKPOINT_FORMAT", "MODEL_FORMAT", "save_checkpoint", "load_checkpoint"]

CHECKPOINT_FORMAT = "mmwsim-estimation-checkpoint/1"
MODEL_FORMAT = "mmwsim-estimation-model/1"


def save_checkpoint(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """Write ``state`` (which must hold a ``format`` key) to ``path`` via a temporary file and rename."""
    from mmwsim.files import atomic_path

    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def load_checkpoint(path: str | os.PathLike, fmt: str, required: tuple[str, ...] = ()) -> dict[str, Any]:
    """Load a checkpoint of format ``fmt``; anything else is a one-line :class:`EstimationError`.

    Parameters
    ----------
    path : path-like
    fmt : str
        :data:`CHECKPOINT_FORMAT` or :data:`MODEL_FORMAT`.
    required : tuple of str
        Keys that must be present.
    """
    path = Path(path)
    if not path.is_file():
        raise EstimationError(f"{path}: checkpoint not found")
    try:
        # torch warns about some foreign files before refusing them: one line is enough then
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # a truncated zip, pickle of foreign objects, random bytes...
        reason = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise EstimationError(f"{path}: not a readable checkpoint ({reason[:160]})") from None
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if not isinstance(state, dict) or state.get("format") != fmt:
        found = state.get("format") if isinstance(state, dict) else type(state).__name__
        raise EstimationError(f"{path}: not an mmwsim checkpoint of format {fmt!r} (found {found!r})")
    missing = [k for k in required if k not in state]
    if missing:
        raise EstimationError(f"{path}: checkpoint lacks {', '.join(missing)}")
    return state
