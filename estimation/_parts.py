"""Independent parts of a batch run side by side, each on one thread.

A grid-reading network's prediction is a chain of short stages (the search, the filter's
kernels, the network in chunks, the route and line passes) with Python between them. Run on
two threads each, the stages wait on one another and the cores idle between them; run as two
halves of the batch on one thread each, one half's Python overlaps the other's kernels. On
``default.zarr`` (an 8-minute network, 1000 seen-area sequences, prefixes 2..7 as evaluation
runs them, 2 cores), four runs of ``benchmarks/online_tracking.py`` took 12.1 to 14.2 s per
1000; the trials before, one part at a time, 14.7 to 18.8 s (docs/estimation.md, "Parts side
by side").
Every part is computed as it would be alone, so the results do not depend on the number of
threads.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TypeVar

import torch

from mmwsim._threads import thread_map, threads

__all__ = ["map_parts"]

T = TypeVar("T")
R = TypeVar("R")


def map_parts(fn: Callable[[T], R], parts: Sequence[T]) -> list[R]:
    """``[fn(p) for p in parts]`` on up to :func:`mmwsim._threads.threads` threads, results in
    order, each part on one torch thread and the caller's grad mode.

    Called from one of those threads (a part that maps parts of its own), it runs them in turn
    there. torch's thread count is restored afterwards."""
    if threads() <= 1 or len(parts) <= 1:
        return [fn(p) for p in parts]
    grad = torch.is_grad_enabled()
    before = torch.get_num_threads()

    def run(p: T) -> R:
        torch.set_num_threads(1)  # each pool thread keeps its own count
        with torch.set_grad_enabled(grad):
            return fn(p)

    torch.set_num_threads(1)
    try:
        return thread_map(run, parts)
    finally:
        torch.set_num_threads(before)
