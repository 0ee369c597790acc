"""How many threads this process's own parallel sections use.

The compiled kernels and Embree release the GIL, so a few large independent pieces of work
(halves of the candidate marking, chunks of rays) run on threads. A process that is one of
several workers sharing the cores (``mmwsim generate``'s pool) sets :func:`set_threads` to 1.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import TypeVar

__all__ = ["cores", "threads", "set_threads", "thread_map", "pieces"]

T = TypeVar("T")
R = TypeVar("R")

_threads: int | None = None


def cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def threads() -> int:
    """Threads a parallel section may use: :func:`set_threads`'s value, else the cores."""
    return _threads if _threads is not None else cores()


def set_threads(n: int | None) -> None:
    """Cap the threads of this process's parallel sections (``None``: one per core)."""
    global _threads
    _threads = None if n is None else max(1, int(n))


def thread_map(fn: Callable[[T], R], items: Sequence[T]) -> list[R]:
    """``[fn(x) for x in items]`` on up to :func:`threads` threads, results in order."""
    n = min(threads(), len(items))
    if n <= 1:
        return [fn(x) for x in items]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(n) as pool:
        return list(pool.map(fn, items))


def pieces(n: int, min_piece: int, max_piece: int | None = None) -> list[slice]:
    """``range(n)`` cut into contiguous slices of near-equal size for :func:`thread_map`: one per
    thread once ``n`` reaches ``min_piece`` per thread (one slice below that), and at most
    ``max_piece`` long each."""
    k = max(1, min(threads(), n // max(min_piece, 1)))
    if max_piece:
        k = max(k, -(-n // max_piece))
    step = -(-n // k) if n else 1
    return [slice(s, min(n, s + step)) for s in range(0, n, step)]
