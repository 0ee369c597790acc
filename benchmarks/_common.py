"""Helpers shared by the benchmark scripts (run as ``python benchmarks/NAME.py``)."""

from __future__ import annotations

import time

import numpy as np


def raw_embree_rate(scene, n: int = 2_000_000) -> float:
    """Rays per second of one bare embreex intersect call from the transmitter of ``scene``.

    The float32 origin and direction arrays (``(n, 3)``) are prepared beforehand, so the
    figure is Embree's own throughput on one core: the ceiling any tracer stage can reach.
    """
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.tile(scene.transmitter.array.astype(np.float32), (n, 1))
    t = time.perf_counter()
    scene.ray_caster._scene.run(o, d, output=1)
    return n / (time.perf_counter() - t)
