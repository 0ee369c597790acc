"""Small synthetic data sets for tests, demos and benchmarks: a toy grid and random-walk trajectories.

The toy PDP varies smoothly with position (a sum of random plane waves per beam and bin, in dB), so
nearby points have similar fingerprints and far ones differ, which is all the models need to learn.
"""

from __future__ import annotations

import numpy as np
import torch

from mmwsim.constants import THRESHOLD_DBM
from mmwsim.trajectories.motion import KINDS

from .data import SequenceSet

__all__ = ["toy_grid", "random_walks", "toy_sequence_set"]


def toy_grid(
    nx: int = 32,
    ny: int = 32,
    spacing: float = 1.0,
    n_beams: int = 8,
    n_bins: int = 12,
    threshold: float = THRESHOLD_DBM,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """A rectangular grid and a smooth per-beam PDP on it.

    Returns
    -------
    xy : (nx * ny, 2) float64, metres, x index fastest
    pdp : (nx * ny, n_beams, n_bins) float32, dBm; ``-inf`` where the field is far below the threshold
    """
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(nx) * spacing, np.arange(ny) * spacing)
    xy = np.column_stack([x.ravel(), y.ravel()])
    span = max(nx, ny) * spacing
    n_waves = 4
    k = rng.normal(size=(n_beams, n_bins, n_waves, 2)) * (2 * np.pi / span) * 2.5
    phase = rng.uniform(0, 2 * np.pi, size=(n_beams, n_bins, n_waves))
    arg = np.einsum("bjwc,gc->gbjw", k, xy) + phase
    field = 12.0 * np.sin(arg).sum(-1) / np.sqrt(n_waves)
    pdp = (threshold + field).astype(np.float32)
    pdp[pdp < threshold - 18.0] = -np.inf
    return xy, pdp


def random_walks(
    n: int,
    length: int,
    lo: np.ndarray,
    hi: np.ndarray,
    seed: int = 0,
    speeds: tuple[float, float] = (1.4, 4.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity walks with random turns that bounce off the box ``lo..hi``.

    Returns
    -------
    positions : (n, length, 2) float32, metres (1 s per step)
    kind : (n,) int8, index into :data:`mmwsim.trajectories.KINDS`: pedestrian (speed ``speeds[0]``)
        or vehicle (``speeds[1]``)
    """
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    is_vehicle = rng.integers(0, 2, n).astype(bool)
    kind = np.where(is_vehicle, KINDS.index("vehicle"), KINDS.index("pedestrian")).astype(np.int8)
    speed = np.where(is_vehicle, speeds[1], speeds[0]) * rng.uniform(0.7, 1.3, n)
    heading = rng.uniform(0, 2 * np.pi, n)
    p = rng.uniform(lo, hi, size=(n, 2))
    out = np.empty((n, length, 2))
    for t in range(length):
        out[:, t] = p
        heading += rng.normal(0, 0.15, n)
        step = speed[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        p = p + step
        # bounce: mirror the position and the heading component that left the box
        for c in range(2):
            below, above = p[:, c] < lo[c], p[:, c] > hi[c]
            p[below, c] = 2 * lo[c] - p[below, c]
            p[above, c] = 2 * hi[c] - p[above, c]
            flip = below | above
            if c == 0:
                heading[flip] = np.pi - heading[flip]
            else:
                heading[flip] = -heading[flip]
        p = np.clip(p, lo, hi)
    return out.astype(np.float32), kind


def toy_sequence_set(
    n: int = 256,
    length: int = 8,
    nx: int = 32,
    ny: int = 32,
    n_beams: int = 8,
    n_bins: int = 12,
    seed: int = 0,
    grid_seed: int = 0,
) -> SequenceSet:
    """A complete toy :class:`SequenceSet` (grid seed and trajectory seed kept apart so that splits
    drawn with different ``seed`` share one grid)."""
    xy, pdp = toy_grid(nx, ny, 1.0, n_beams, n_bins, seed=grid_seed)
    lo, hi = xy.min(0), xy.max(0)
    pos, kind = random_walks(n, length, lo, hi, seed=seed)
    ix = np.rint(pos[..., 0] - lo[0]).astype(np.int64)
    iy = np.rint(pos[..., 1] - lo[1]).astype(np.int64)
    index = ix + nx * iy
    return SequenceSet(torch.from_numpy(pdp), xy, index, pos, kind, THRESHOLD_DBM, np.stack([lo, hi]))


TOY_HOLDOUT = (24.0, 24.0, 31.0, 31.0)
"""Hold-out square of the toy data sets: training and validation trajectories never enter it."""


def parse_toy_spec(spec: str) -> dict[str, int]:
    """``"toy"`` or ``"toy:n=2000,length=8,seed=0"`` -> options of :func:`toy_splits`."""
    from .errors import EstimationError

    name, _, rest = spec.partition(":")
    if name != "toy":
        raise EstimationError(f"{spec!r}: not a toy data set spec (toy[:n=N,length=L,seed=S])")
    opts = {"n": 2000, "length": 8, "seed": 0}
    for part in filter(None, rest.split(",")):
        key, _, value = part.partition("=")
        if key not in opts:
            raise EstimationError(f"{spec!r}: unknown toy option {key!r} (n, length, seed)")
        try:
            opts[key] = int(value)
        except ValueError:
            raise EstimationError(f"{spec!r}: toy option {key} must be an integer") from None
        if opts[key] < (0 if key == "seed" else 2):
            raise EstimationError(f"{spec!r}: toy option {key} is too small")
    from mmwsim.limits import check_fits

    # toy_splits draws 3 n walks of `length` steps (float64 x, y and their index) per split
    check_fits(3 * opts["n"] * opts["length"] * 64, f"{spec!r}: the toy data set")
    return opts


def toy_splits(spec: str, names: tuple[str, ...] | list[str]) -> dict[str, SequenceSet]:
    """Toy splits on one 32 x 32 grid; ``train``/``validation`` avoid :data:`TOY_HOLDOUT`,
    ``test/holdout`` touches it, ``test`` and ``test/seen`` do not. ``n`` trajectories for
    training, ``n // 4`` for the others."""
    from .errors import EstimationError

    o = parse_toy_spec(spec)
    x0, y0, x1, y1 = TOY_HOLDOUT
    out = {}
    for name in names:
        base, _, sub = name.partition("/")
        offsets = {"train": 1, "validation": 2, "test": 3}
        if base not in offsets or sub not in ("", "seen", "holdout") or (sub and base != "test"):
            raise EstimationError(
                f"toy data set has no split {name!r} (train, validation, test[/seen|/holdout])"
            )
        n = o["n"] if base == "train" else max(o["n"] // 4, 8)
        s = toy_sequence_set(3 * n, o["length"], seed=o["seed"] * 10 + offsets[base], grid_seed=o["seed"])
        p = s.positions
        inside = ((p[..., 0] >= x0) & (p[..., 0] <= x1) & (p[..., 1] >= y0) & (p[..., 1] <= y1)).any(1)
        keep = np.flatnonzero(inside if sub == "holdout" else ~inside)[:n]
        out[name] = s.subset(keep)
    return out
