"""3-vector helpers on tuples, for compiled kernels (no heap allocation per call)."""

from __future__ import annotations

import numpy as np

from .._jit import njit


@njit(cache=True, inline="always")
def dot(a, b):  # pragma: no cover - compiled
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def cross(a, b):  # pragma: no cover - compiled
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def sub(a, b):  # pragma: no cover - compiled
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, inline="always")
def add(a, b):  # pragma: no cover - compiled
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@njit(cache=True, inline="always")
def scale(a, s):  # pragma: no cover - compiled
    return (a[0] * s, a[1] * s, a[2] * s)


@njit(cache=True, inline="always")
def norm(a):  # pragma: no cover - compiled
    return np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@njit(cache=True, inline="always")
def unit(a):  # pragma: no cover - compiled
    n = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return (a[0] / n, a[1] / n, a[2] / n)


@njit(cache=True, inline="always")
def row(arr, i):  # pragma: no cover - compiled
    """Row ``i`` of an (n, 3) array as a tuple of floats."""
    return (float(arr[i, 0]), float(arr[i, 1]), float(arr[i, 2]))


@njit(cache=True, inline="always")
def mirror(p, n, d):  # pragma: no cover - compiled
    """Mirror image of point ``p`` in the plane ``n . x = d``."""
    s = 2.0 * (dot(p, n) - d)
    return (p[0] - s * n[0], p[1] - s * n[1], p[2] - s * n[2])
