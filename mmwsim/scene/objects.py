"""The parts of a scene: named meshes with materials, the transmitter, the receiver grid."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import trimesh

from ..errors import MmwsimError
from ..limits import check_fits
from ..materials import Material

__all__ = ["ObjectKind", "SceneObject", "Transmitter", "ReceiverGrid"]

ObjectKind = Literal["building", "ground", "other"]
OBJECT_KINDS: tuple[str, ...] = ("building", "ground", "other")


@dataclass
class SceneObject:
    """A named triangle mesh with one radio material.

    Parameters
    ----------
    name : str
        Unique within its scene; path results name reflecting objects by it.
    mesh : trimesh.Trimesh
        Triangles in scene coordinates (metres, z up).
    material : Material
        Radio material of every face.
    kind : {"building", "ground", "other"}
        Buildings block the outdoors query, the footprints and collision; ground
        and others only reflect and block rays.
    """

    name: str
    mesh: trimesh.Trimesh
    material: Material
    kind: ObjectKind = "building"


@dataclass(frozen=True)
class Transmitter:
    """The base station.

    Parameters
    ----------
    position : (3,) float
        Phase centre, metres.
    power_dbm : float
        Transmit power, dBm.
    """

    position: tuple[float, float, float]
    power_dbm: float = 30.0

    @property
    def array(self) -> np.ndarray:
        """Position as a (3,) float64 array."""
        return np.asarray(self.position, dtype=np.float64)


@dataclass(frozen=True)
class ReceiverGrid:
    """A regular horizontal grid of receivers, x index running fastest.

    Parameters
    ----------
    origin : (2,) float
        x, y of the first point, metres.
    spacing : float
        Distance between neighbours, metres.
    shape : (2,) int
        Number of points along x and along y.
    height : float
        z of every point, metres.
    """

    origin: tuple[float, float] = (0.0, 0.0)
    spacing: float = 1.0
    shape: tuple[int, int] = (401, 401)
    height: float = 1.5

    def __post_init__(self) -> None:
        numbers = (*self.origin, self.spacing, self.height)
        if len(self.origin) != 2 or not all(math.isfinite(float(v)) for v in numbers):
            raise MmwsimError(
                f"receiver grid: origin, spacing and height must be finite numbers, got origin "
                f"{tuple(self.origin)}, spacing {self.spacing}, height {self.height}"
            )
        if not self.spacing > 0:
            raise MmwsimError(f"receiver grid: spacing must be positive, got {self.spacing}")
        if len(self.shape) != 2 or not all(int(n) == n and n >= 1 for n in self.shape):
            raise MmwsimError(f"receiver grid: shape must be two whole numbers >= 1, got {tuple(self.shape)}")
        _check_size(self.shape)

    @property
    def size(self) -> int:
        """Number of receivers."""
        return int(self.shape[0] * self.shape[1])

    @property
    def xs(self) -> np.ndarray:
        """(nx,) float64 x coordinates."""
        return self.origin[0] + self.spacing * np.arange(self.shape[0])

    @property
    def ys(self) -> np.ndarray:
        """(ny,) float64 y coordinates."""
        return self.origin[1] + self.spacing * np.arange(self.shape[1])

    @property
    def bounds(self) -> np.ndarray:
        """(2, 2) float64 [[xmin, ymin], [xmax, ymax]]."""
        return np.array([[self.xs[0], self.ys[0]], [self.xs[-1], self.ys[-1]]], dtype=np.float64)

    def positions(self) -> np.ndarray:
        """(n, 3) float64 receiver positions, index = ix + nx * iy."""
        gx, gy = np.meshgrid(self.xs, self.ys, indexing="xy")
        return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, float(self.height))])

    def nearest_index(self, xy: np.ndarray) -> np.ndarray:
        """Flat index (ix + nx iy) of the grid point nearest to each position.

        Parameters
        ----------
        xy : (..., 2) or (..., 3) float
            Positions, metres (z ignored); points off the grid snap to its edge.

        Returns
        -------
        (...) int64
        """
        p = np.asarray(xy, dtype=np.float64)
        if p.ndim == 0 or p.shape[-1] not in (2, 3):
            raise MmwsimError(f"positions must have shape (..., 2) or (..., 3), got {p.shape}")
        if not np.isfinite(p[..., :2]).all():
            raise MmwsimError("positions contain NaN or infinite coordinates")
        ix = np.clip(np.rint((p[..., 0] - self.origin[0]) / self.spacing), 0, self.shape[0] - 1).astype(
            np.int64
        )
        iy = np.clip(np.rint((p[..., 1] - self.origin[1]) / self.spacing), 0, self.shape[1] - 1).astype(
            np.int64
        )
        return ix + self.shape[0] * iy

    def with_spacing(self, spacing: float) -> ReceiverGrid:
        """The same area covered at another spacing (the far edge kept where it falls on the grid)."""
        if not (math.isfinite(spacing) and spacing > 0):
            raise MmwsimError(f"receiver spacing must be a positive number of metres, got {spacing!r}")
        span = (np.asarray(self.shape, dtype=np.float64) - 1) * self.spacing
        counts = np.floor(span / spacing + 1e-9) + 1
        _check_size(counts)
        return ReceiverGrid(self.origin, float(spacing), tuple(int(n) for n in counts), self.height)


# Peak bytes per receiver of building the grid's positions: the (n, 3) float64 array and the
# temporaries it is assembled from (the whole grid is held at once when a data set is written).
_BYTES_PER_RECEIVER = 64


def _check_size(shape) -> None:
    nx, ny = (float(n) for n in shape)
    size = " x ".join(f"{n:.0f}" if n < 1e12 else f"{n:.3g}" for n in (nx, ny))
    check_fits(nx * ny * _BYTES_PER_RECEIVER, f"a grid of {size} receivers")
