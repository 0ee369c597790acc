"""The fingerprint field: per-beam power-delay profiles (dBm, -inf where no signal) at continuous
positions, which every stage draws fingerprints from.

* :class:`GridField` looks them up on a receiver grid (a data set's: :meth:`Dataset.field
  <mmwsim.dataset.Dataset.field>`), at the nearest grid point, the nearest valid one, or
  interpolated bilinearly in dB between the four surrounding valid points;
* :class:`TracedField` computes them exactly at the positions with the ray tracer and the PDP
  stage (:meth:`TracedField.from_scene`, or with a data set's own configuration
  :meth:`Dataset.traced_field <mmwsim.dataset.Dataset.traced_field>`), or any function.

The bits come from the one noise model (:class:`~mmwsim.fingerprints.noise.NoiseModel`); with the
nearest-point lookup a grid field hands out the exact fast sampler of its rows.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal, Protocol, get_args

import numpy as np
from scipy.spatial import cKDTree

from ..errors import MmwsimError
from .noise import FingerprintSampler, NoiseModel
from .pdp import power_delay_profile

if TYPE_CHECKING:
    from ..scene import ReceiverGrid, Scene

__all__ = ["FingerprintField", "GridField", "Lookup", "TracedField"]

Lookup = Literal["nearest", "linear"]
"""How a grid field answers between grid points: nearest grid point, or bilinear in dB."""

_FLOOR_DBM = -300.0  # stands in for -inf while interpolating in dB

SamplerFactory = Callable[[NoiseModel], FingerprintSampler]
"""``noise -> FingerprintSampler`` over all grid points."""


class FingerprintField(Protocol):
    """PDPs as a function of position: what fingerprints are drawn from."""

    def pdp_at(self, positions: np.ndarray) -> np.ndarray:
        """``(..., 2)`` positions, metres -> ``(..., n_beams, n_bins)`` float32 PDPs, dBm (-inf: no signal)."""
        ...


def _take_rows(pdp: Any, index: np.ndarray, bins: slice) -> np.ndarray:
    """pdp[index, :, bins] as float32, reading each distinct row once (orthogonal read from zarr)."""
    flat = index.reshape(-1)
    uniq, inverse = np.unique(flat, return_inverse=True)
    if hasattr(pdp, "get_orthogonal_selection"):  # a zarr array
        rows = np.asarray(pdp.get_orthogonal_selection((uniq, slice(None), bins)))
    else:
        rows = np.asarray(pdp)[uniq][:, :, bins]
    return rows.astype(np.float32, copy=False)[inverse.reshape(-1)].reshape(index.shape + rows.shape[1:])


class GridField:
    """PDPs stored on a receiver grid, looked up at continuous positions.

    Parameters
    ----------
    grid : ReceiverGrid
        The data set's grid (index = ix + nx * iy).
    pdp : (grid.size, n_beams, n_bins) numpy or zarr array, dBm
        -inf where no signal.
    valid : (grid.size,) bool, optional
        Grid points with data; interpolation ignores the others.
    method : {"nearest", "linear"}
        Nearest grid point, or bilinear in dB over the valid surrounding points.
    bins : slice
        PDP bins to return (default all).
    sampler : callable, optional
        ``noise -> FingerprintSampler`` over all grid points (a data set's cached
        :meth:`~mmwsim.dataset.Dataset.sampler`); default: built here from ``pdp`` on first use.
    """

    def __init__(
        self,
        grid: ReceiverGrid,
        pdp: Any,
        valid: np.ndarray | None = None,
        method: Lookup = "nearest",
        bins: slice = slice(None),
        sampler: SamplerFactory | None = None,
    ):
        if method not in get_args(Lookup):
            raise MmwsimError(f"PDP lookup method must be 'nearest' or 'linear', got {method!r}")
        if len(pdp.shape) != 3 or pdp.shape[0] != grid.size:
            raise MmwsimError(
                f"PDP array of shape {tuple(pdp.shape)} does not fit a grid of {grid.size} points"
            )
        self.grid, self.pdp, self.method, self.bins = grid, pdp, method, bins
        self.valid = (
            np.ones(grid.size, dtype=bool) if valid is None else np.asarray(valid, dtype=bool).reshape(-1)
        )
        self._sampler_factory = sampler
        self._samplers: dict[NoiseModel, FingerprintSampler] = {}
        self._valid_rows: tuple[np.ndarray, cKDTree] | None = None

    @property
    def window(self) -> tuple[int, int] | None:
        """The bins as a contiguous window ``(start, stop)``, or None (strided or empty)."""
        start, stop, step = self.bins.indices(self.pdp.shape[2])
        return (start, stop) if step == 1 and stop > start else None

    def index_at(self, positions: np.ndarray) -> np.ndarray:
        """(...,) int64 index of the grid point nearest to each (..., 2) position."""
        return self.grid.nearest_index(positions)

    def valid_index_at(self, positions: np.ndarray) -> np.ndarray:
        """(...,) int64 index of the valid grid point nearest to each (..., 2) position, metres: the
        nearest grid point where it is valid, else (within a wall's cell, say) the nearest valid one."""
        p = np.asarray(positions, dtype=np.float64)
        index = self.index_at(p)
        bad = ~self.valid[index]
        if bad.any():
            if self._valid_rows is None:
                rows = np.flatnonzero(self.valid)
                if not len(rows):
                    raise MmwsimError("the grid has no valid point")
                xy = self.grid.positions()[rows, :2]
                self._valid_rows = (rows, cKDTree(xy))
            rows, tree = self._valid_rows
            index[bad] = rows[tree.query(p[bad])[1]]
        return index

    def sampler(self, noise: NoiseModel) -> FingerprintSampler | None:
        """Fast exact sampler of the fingerprints at grid points, or None where it does not apply.

        It draws each bit with probability P(PDP + N(0, sigma^2) >= threshold), the
        distribution of noise added to :meth:`pdp_at`, for the nearest-point lookup over a
        contiguous bin window; interpolated PDPs lie between grid points and have no row.

        Returns
        -------
        FingerprintSampler or None
            Rows are grid indices (:meth:`index_at`); fingerprints (n_beams, stop - start).
        """
        window = self.window
        if self.method != "nearest" or window is None:
            return None
        noise = NoiseModel(noise.sigma_db, noise.threshold_dbm, window)
        if self._sampler_factory is not None:
            return self._sampler_factory(noise)
        if noise not in self._samplers:
            self._samplers[noise] = FingerprintSampler(self.pdp, noise)
        return self._samplers[noise]

    def pdp_at(self, positions: np.ndarray) -> np.ndarray:
        """PDPs at positions.

        Parameters
        ----------
        positions : (..., 2) float, metres

        Returns
        -------
        (..., n_beams, n_bins') float32, dBm (-inf where no signal)
        """
        p = np.asarray(positions, dtype=np.float64)
        if self.method == "nearest":
            return _take_rows(self.pdp, self.index_at(p), self.bins)
        g = self.grid
        nx, ny = g.shape
        u = (p[..., 0] - g.origin[0]) / g.spacing
        v = (p[..., 1] - g.origin[1]) / g.spacing
        i0 = np.clip(np.floor(u), 0, max(nx - 2, 0)).astype(np.int64)
        j0 = np.clip(np.floor(v), 0, max(ny - 2, 0)).astype(np.int64)
        fu = np.clip(u - i0, 0.0, 1.0)
        fv = np.clip(v - j0, 0.0, 1.0)
        i1 = np.minimum(i0 + 1, nx - 1)
        j1 = np.minimum(j0 + 1, ny - 1)
        corners = np.stack([i0 + nx * j0, i1 + nx * j0, i0 + nx * j1, i1 + nx * j1], axis=-1)
        w = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=-1)
        w = w * self.valid[corners]
        total = w.sum(axis=-1, keepdims=True)
        # No valid corner: fall back to the nearest point (the caller checked validity there).
        none = total[..., 0] <= 0
        w = np.where(none[..., None], 0.0, w / np.where(total > 0, total, 1.0))
        vals = _take_rows(self.pdp, corners, self.bins)  # (..., 4, beams, bins)
        vals = np.where(np.isfinite(vals), vals, _FLOOR_DBM)
        out = np.einsum("...c,...cbk->...bk", w.astype(np.float32), vals)
        if none.any():
            out[none] = _take_rows(self.pdp, self.index_at(p[none]), self.bins)
        out[out <= _FLOOR_DBM + 1e-3] = -np.inf
        return out


class TracedField:
    """PDPs computed exactly at the continuous positions.

    Parameters
    ----------
    function : callable
        ``function(points)`` with points (m, 3) metres returning (m, n_beams, n_bins) dBm;
        e.g. the tracer followed by the PDP stage.
    height : float
        Receiver height, metres (z of every point).
    bins : slice
        PDP bins to return.
    """

    def __init__(
        self, function: Callable[[np.ndarray], np.ndarray], height: float, bins: slice = slice(None)
    ):
        self.function, self.height, self.bins = function, float(height), bins

    @classmethod
    def from_scene(
        cls,
        scene: Scene,
        codebook: Any = None,
        max_reflections: int = 3,
        n_rays: int | None = None,
        bins: slice = slice(None),
        height: float | None = None,
        **pdp_options: Any,
    ) -> TracedField:
        """Trace exactly with :mod:`mmwsim.tracer` and :func:`mmwsim.fingerprints.power_delay_profile`.

        The candidate rays are shot once; every call solves the paths to the given positions.

        Parameters
        ----------
        scene : Scene
            With a transmitter.
        codebook : Codebook, optional
            Default: the 32-beam rotating horn at the scene's frequency.
        max_reflections : int
        n_rays : int, optional
            Candidate rays (tracer default if omitted).
        bins : slice
        height : float, optional
            Receiver height, metres (default the scene's receiver-grid height).
        **pdp_options
            Passed to ``power_delay_profile`` (rx_pattern, tx_power_dbm, n_bins, band_limited, ...).
        """
        from ..antennas import make_codebook
        from ..tracer import Tracer

        book = codebook if codebook is not None else make_codebook("rotating_horn", scene.frequency)
        kw = {} if n_rays is None else {"n_rays": n_rays}
        tracer = Tracer(scene, max_reflections=max_reflections, **kw)

        def function(points: np.ndarray) -> np.ndarray:
            return power_delay_profile(tracer.trace(points), book, **pdp_options)

        return cls(function, scene.receivers.height if height is None else height, bins)

    def pdp_at(self, positions: np.ndarray) -> np.ndarray:
        """(..., n_beams, n_bins') float32 PDPs at (..., 2) positions, dBm."""
        p = np.asarray(positions, dtype=np.float64)
        flat = p.reshape(-1, 2)
        pts = np.column_stack([flat, np.full(len(flat), self.height)])
        out = np.asarray(self.function(pts), dtype=np.float32)[:, :, self.bins]
        return out.reshape(p.shape[:-1] + out.shape[1:])
