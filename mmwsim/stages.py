"""Wall time per pipeline stage, for the benchmarks (shooting, cells, exact solve, diffraction, PDP, store).

Stages wrap their work in ``with STAGES("name"):``; each process accumulates its own
totals, and data-set tiles carry theirs back to the parent, so a benchmark can show each
stage's share of a whole run without a profiler.
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager

__all__ = ["Stages", "STAGES"]


class Stages:
    """Seconds spent in each named stage of this process."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, name: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - t

    def take(self) -> dict[str, float]:
        """The totals so far, reset to zero."""
        out = dict(self.seconds)
        self.seconds.clear()
        return out

    def add(self, other: dict[str, float]) -> None:
        """Add totals measured elsewhere (another process)."""
        for k, v in other.items():
            self.seconds[k] += v


STAGES = Stages()
"""This process's stage clock."""
