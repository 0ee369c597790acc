"""Cheap keys that tell whether tensors changed since something was made from them.

The estimator keeps copies made from its motion tables (their lanes, broadened and speed-pooled
copies, the kernels' arrays) and must make them again when a table changes. Hashing the tables'
contents to find out took 20 ms per call, as much as a whole online update of one user. A
:func:`stamp` instead holds each tensor with its version counter, which torch bumps on every
in-place change, so comparing two stamps (:func:`same_stamp`) costs a few comparisons.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

__all__ = ["same_stamp", "stamp"]


def stamp(*objs: Any) -> tuple:
    """A key of ``objs``: a tensor by identity and version, a module by its buffers, a numpy
    array by identity (it must be read-only: numpy keeps no version), anything else by value.
    The key holds the objects themselves, so that an id cannot be reused while it lives."""
    out: list[tuple[Any, int | None, bool]] = []  # (object, version, compared by identity)
    for obj in objs:
        if isinstance(obj, nn.Module):
            out.extend((b, b._version, True) for b in obj.buffers())
        elif isinstance(obj, torch.Tensor):
            out.append((obj, obj._version, True))
        elif isinstance(obj, np.ndarray):
            if obj.flags.writeable:
                raise ValueError("a numpy array in a stamp must be read-only")
            out.append((obj, None, True))
        else:
            out.append((obj, None, False))
    return tuple(out)


def same_stamp(a: tuple | None, b: tuple | None) -> bool:
    """Whether two :func:`stamp` keys are of the same unchanged objects."""
    if a is None or b is None or len(a) != len(b):
        return False
    for (x, vx, ident), (y, vy, _) in zip(a, b, strict=True):
        if vx != vy or (x is not y if ident else x != y):
            return False
    return True
