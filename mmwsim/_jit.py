"""Compiled kernels through numba, for the loops numpy cannot vectorise.

Kernels are compiled on first use and cached on disk next to their module, so a
process pays the compilation once per installation.
"""

from __future__ import annotations

import numba

__all__ = ["njit"]


def njit(*args, **kwargs):
    """``numba.njit`` with the project's defaults (no Python fallback, on-disk cache, no GIL)."""
    kwargs.setdefault("nogil", True)
    return numba.njit(*args, **kwargs)
