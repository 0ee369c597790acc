"""How many threads this process's own parallel sections use.

The compiled kernels and Embree release the GIL, so a few large independent pieces of work
(halves of the candidate marking, chunks of rays) run on threads. A process that is one of
several workers sharing the cores (``mmwsim generate``'s pool) sets :func:`set_threads` to 1.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np

__all__ = ["cores", "threads", "set_threads", "thread_map", "pieces", "batch_map"]

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
    """Threads a parallel section may use: one within a thread of :func:`thread_map`'s (its
    sections run in turn there), else :func:`set_threads`'s value, else the cores."""
    if threading.current_thread().name.startswith(_PREFIX):
        return 1
    return _threads if _threads is not None else cores()


def set_threads(n: int | None) -> None:
    """Cap the threads of this process's parallel sections (``None``: one per core)."""
    global _threads
    _threads = None if n is None else max(1, int(n))


def thread_map(fn: Callable[[T], R], items: Sequence[T]) -> list[R]:
    """``[fn(x) for x in items]`` on up to :func:`threads` threads, results in order.

    The threads are kept between calls (starting them costs more than a small kernel); a call
    from one of them runs in that thread, so nested calls cannot wait on each other."""
    n = min(threads(), len(items))
    if n <= 1:
        return [fn(x) for x in items]
    return list(_pool(n).map(fn, items))


_PREFIX = "mmwsim-thread"
_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()


def _pool(n: int) -> ThreadPoolExecutor:
    with _pools_lock:
        if n not in _pools:
            _pools[n] = ThreadPoolExecutor(n, thread_name_prefix=f"{_PREFIX}-{n}")
        return _pools[n]


def _forget_pools() -> None:
    # A forked worker (mmwsim generate's pool) has none of its parent's threads, and the lock
    # may have been held by one of them.
    global _pools_lock
    _pools.clear()
    _pools_lock = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pools)


def pieces(n: int, min_piece: int, max_piece: int | None = None) -> list[slice]:
    """``range(n)`` cut into contiguous slices of near-equal size for :func:`thread_map`: one per
    thread once ``n`` reaches ``min_piece`` per thread (one slice below that), and at most
    ``max_piece`` long each."""
    k = max(1, min(threads(), n // max(min_piece, 1)))
    if max_piece:
        k = max(k, -(-n // max_piece))
    step = -(-n // k) if n else 1
    return [slice(s, min(n, s + step)) for s in range(0, n, step)]


def batch_map(kernel: Callable, n_batched: int, *args):
    """``kernel(*args)`` over slices of the batch (the first ``n_batched`` arguments' first axis)
    on the process's threads, the slices' results joined along that axis (each of a tuple's).

    For compiled kernels that release the GIL and treat every item of the batch alone, so the
    result is the same for any number of threads. Items differ in cost, so with several threads
    the batch goes in slices of at most 32 items, taken by whichever thread is free."""
    B = args[0].shape[0]
    parts = pieces(B, 32, 32) if threads() > 1 else [slice(0, B)]
    if len(parts) <= 1:  # one slice, or an empty batch (the kernel's own empty results)
        return kernel(*args)
    outs = thread_map(lambda s: kernel(*(a[s] for a in args[:n_batched]), *args[n_batched:]), parts)
    if isinstance(outs[0], tuple):
        return tuple(np.concatenate(o) for o in zip(*outs, strict=True))
    return np.concatenate(outs)
