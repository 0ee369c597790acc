"""Sizes checked before allocating: a grid or tile that cannot fit in memory is refused up front."""

from __future__ import annotations

import math
import os

from .errors import MmwsimError

__all__ = ["check_fits", "format_bytes", "memory_bytes"]


def memory_bytes() -> int:
    """Physical memory of this machine, bytes (a fixed figure, so a check does not depend on load)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # not POSIX: assume a generous 1 TiB
        return 1 << 40


def format_bytes(n: float) -> str:
    """``76_000_000_000_000_000`` -> ``'67.5 PiB'``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError("unreachable")


def check_fits(n_bytes: float, what: str, share: float = 1.0) -> None:
    """Raise :class:`MmwsimError` if ``n_bytes`` exceed ``share`` of this machine's memory.

    Parameters
    ----------
    n_bytes : float
        Estimated peak memory of the allocation, bytes.
    what : str
        What would be allocated, e.g. ``"grid of 100000000 x 100000000 receivers"``.
    share : float
        Fraction of the machine's memory it may take.
    """
    limit = share * memory_bytes()
    if not math.isfinite(n_bytes):
        raise MmwsimError(f"{what} is too large to hold in memory")
    if n_bytes > limit:
        raise MmwsimError(
            f"{what} needs about {format_bytes(n_bytes)} of memory, more than this machine's "
            f"{format_bytes(limit)}" + ("" if share == 1.0 else f" ({share:.0%} of its memory)")
        )
