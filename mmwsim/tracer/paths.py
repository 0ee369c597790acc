"""The result of tracing: specular paths from one transmitter to many receivers.

Polarisation convention
-----------------------
Fields are written in the spherical bases (theta_hat, phi_hat) of the antennas:
at the transmitter for the departure direction ``aod``, at the receiver for the
arrival direction ``aoa`` (the direction from the receiver towards where the
wave comes from). ``jones[p] @ [E_theta, E_phi]_tx = [E_theta, E_phi]_rx`` for
unit fields radiated by isotropic antennas, and includes the spreading factor
``lambda / (4 pi L)``; it excludes the propagation phase ``exp(-j 2 pi f tau)``,
which follows from ``delay``. For line of sight ``jones = lambda/(4 pi L) *
diag(1, -1)`` (phi_hat flips sign between the two bases).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from enum import IntEnum

import numpy as np

from ..constants import SPEED_OF_LIGHT

__all__ = ["Paths", "POLARISATIONS", "Interaction", "PathKind"]


class Interaction(IntEnum):
    """What happens at one interaction of a path (values of :attr:`Paths.types`)."""

    NONE = 0
    """Padding after a path's last interaction."""
    REFLECTION = 1
    """Specular reflection off a planar face."""
    DIFFRACTION = 2
    """Diffraction at a wedge (an edge shared by two faces)."""
    DIFFUSE = 3
    """Diffuse scattering off a surface tile (always a path's last interaction)."""


class PathKind(IntEnum):
    """A path's kind as a whole (values of :meth:`Paths.kind`), in the order views colour them."""

    LINE_OF_SIGHT = 0
    REFLECTED = 1
    """Specular reflections only."""
    DIFFRACTED = 2
    """One diffraction, with or without reflections."""
    DIFFUSE = 3
    """Ends in diffuse scattering (its power adds incoherently)."""


POLARISATIONS = {"V": np.array([1.0, 0.0]), "H": np.array([0.0, 1.0])}
"""Unit field vectors in the (theta_hat, phi_hat) basis: V is theta_hat, H is phi_hat."""


@dataclass
class Paths:
    """Specular paths, flat over all receivers, grouped by receiver.

    Parameters
    ----------
    tx : (3,) float64
        Transmitter position, metres.
    rx : (n_rx, 3) float64
        Receiver positions, metres.
    frequency : float
        Carrier, Hz.
    rx_index : (n_paths,) int64
        Receiver of each path; non-decreasing, so each receiver's paths are one run.
    length : (n_paths,) float64
        Unfolded path length, metres.
    jones : (n_paths, 2, 2) complex128
        Field transfer matrix (see module docstring), includes lambda / (4 pi L).
    aod, aoa : (n_paths, 2) float64
        Departure and arrival directions as (zenith, azimuth), radians.
    order : (n_paths,) int8
        Number of interactions (reflections, diffraction, diffuse); 0 is line of sight.
    faces : (n_paths, max_reflections) int64
        Triangles hit, in order; -1 pads.
    objects : (n_paths, max_reflections) int32
        Index of each interaction's scene object; -1 pads.
    points : (n_paths, max_reflections, 3) float64
        Interaction points, metres; NaN pads.
    types : (n_paths, max_reflections) int8, optional
        :class:`Interaction` of each interaction; by default a reflection for each of
        the first ``order`` columns and :attr:`Interaction.NONE` after them.
    """

    tx: np.ndarray
    rx: np.ndarray
    frequency: float
    rx_index: np.ndarray
    length: np.ndarray
    jones: np.ndarray
    aod: np.ndarray
    aoa: np.ndarray
    order: np.ndarray
    faces: np.ndarray
    objects: np.ndarray
    points: np.ndarray
    types: np.ndarray | None = None

    def __post_init__(self):
        if self.types is None:
            k = np.arange(self.faces.shape[1])
            self.types = np.where(k[None, :] < self.order[:, None], Interaction.REFLECTION, 0).astype(np.int8)

    @property
    def n_paths(self) -> int:
        return int(len(self.length))

    @property
    def n_rx(self) -> int:
        return int(len(self.rx))

    @property
    def max_reflections(self) -> int:
        return int(self.faces.shape[1])

    @property
    def delay(self) -> np.ndarray:
        """(n_paths,) float64 propagation delay, seconds."""
        return self.length / SPEED_OF_LIGHT

    @property
    def wavelength(self) -> float:
        return SPEED_OF_LIGHT / self.frequency

    def kind(self) -> np.ndarray:
        """(n_paths,) int8 :class:`PathKind` of each path."""
        t = self.types
        out = np.where(self.order > 0, PathKind.REFLECTED, PathKind.LINE_OF_SIGHT).astype(np.int8)
        out[np.any(t == Interaction.DIFFRACTION, axis=1)] = PathKind.DIFFRACTED
        out[np.any(t == Interaction.DIFFUSE, axis=1)] = PathKind.DIFFUSE
        return out

    def offsets(self) -> np.ndarray:
        """(n_rx + 1,) int64: paths of receiver i are ``offsets[i]:offsets[i+1]``."""
        return np.searchsorted(self.rx_index, np.arange(self.n_rx + 1)).astype(np.int64)

    def count(self) -> np.ndarray:
        """(n_rx,) int64 number of paths per receiver."""
        return np.diff(self.offsets())

    def amplitude(self, tx_pol: str | np.ndarray = "V", rx_pol: str | np.ndarray = "V") -> np.ndarray:
        """Complex amplitude per path for isotropic antennas of given polarisations.

        Parameters
        ----------
        tx_pol, rx_pol : {"V", "H"} or (2,) complex
            Field vectors in the (theta_hat, phi_hat) bases.

        Returns
        -------
        (n_paths,) complex128
            ``rx_pol^T @ jones @ tx_pol`` (no conjugation: a receiving antenna's
            effective length is its transmit pattern, by reciprocity).
        """
        t = POLARISATIONS[tx_pol] if isinstance(tx_pol, str) else np.asarray(tx_pol)
        r = POLARISATIONS[rx_pol] if isinstance(rx_pol, str) else np.asarray(rx_pol)
        return np.einsum("i,pij,j->p", r, self.jones, t)

    def gain_db(self, tx_pol: str = "V", rx_pol: str = "V") -> np.ndarray:
        """(n_paths,) float64 path gain 20 log10 |amplitude|, dB."""
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(np.abs(self.amplitude(tx_pol, rx_pol)))

    def merge_diffuse(self, bin_width: float) -> Paths:
        """The same paths with the diffuse contributions merged per receiver, surface triangle,
        reflections before it and delay bin of ``bin_width`` seconds (for storage).

        A merged contribution keeps the total power exactly for every transmit polarisation,
        summed over receive polarisations: its Jones matrix is ``sqrtm(sum J^H J)``. Its delay,
        directions and interaction points are power-weighted means, so a profile rebuilt from
        merged paths with another antenna is close to, not equal to, one built from the patches.
        """
        diffuse = self.kind() == PathKind.DIFFUSE
        if not diffuse.any():
            return self
        d = np.flatnonzero(diffuse)
        bins = np.floor(self.delay[d] / bin_width).astype(np.int64)
        keys = np.column_stack([self.rx_index[d], self.faces[d], bins])
        _, group, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        group = group.ravel()
        order = np.argsort(group, kind="stable")
        d, group = d[order], group[order]
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        j = self.jones[d]
        w = np.sum(np.abs(j) ** 2, axis=(1, 2))
        gram = np.add.reduceat(np.conj(np.swapaxes(j, 1, 2)) @ j, starts, axis=0)
        wsum = np.add.reduceat(w, starts)
        wn = np.where(wsum[group] > 0, w / np.maximum(wsum[group], 1e-300), 1.0 / counts[group])

        def mean(a: np.ndarray) -> np.ndarray:
            return np.add.reduceat(np.nan_to_num(a) * wn.reshape((-1,) + (1,) * (a.ndim - 1)), starts, axis=0)

        def direction(angles: np.ndarray) -> np.ndarray:
            t, p = angles[:, 0], angles[:, 1]
            v = mean(np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1))
            r = np.linalg.norm(v, axis=1)
            return np.stack(
                [np.arccos(np.clip(v[:, 2] / np.maximum(r, 1e-300), -1, 1)), np.arctan2(v[:, 1], v[:, 0])], 1
            )

        first = d[starts]
        points = mean(self.points[d])
        points[np.isnan(self.points[first])] = np.nan
        merged = Paths(
            self.tx, self.rx, self.frequency, self.rx_index[first], mean(self.length[d]), _psd_sqrt(gram),
            direction(self.aod[d]), direction(self.aoa[d]), self.order[first], self.faces[first],
            self.objects[first], points, self.types[first],
        )  # fmt: skip
        keep = self.select(~diffuse)
        both = Paths.concatenate_same([keep, merged])
        srt = np.lexsort((both.kind(), np.round(both.length, 9), both.rx_index))
        return both.select(srt)

    @staticmethod
    def concatenate_same(parts: list[Paths]) -> Paths:
        """Join path sets to the same receivers (same transmitter and receivers)."""
        first = parts[0]
        kw = {f.name: getattr(first, f.name) for f in fields(first)}
        for name in _PER_PATH:
            kw[name] = np.concatenate([getattr(p, name) for p in parts])
        return Paths(**kw)

    def select_range(self, sl: slice) -> Paths:
        """The paths in the slice ``sl`` of the path axis (views, no copies), receivers unchanged."""
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in _PER_PATH:
            kw[name] = kw[name][sl]
        return Paths(**kw)

    def select(self, mask: np.ndarray) -> Paths:
        """The paths where ``mask`` (n_paths,) is true, receivers unchanged."""
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in _PER_PATH:
            kw[name] = kw[name][mask]
        return Paths(**kw)

    @staticmethod
    def concatenate(parts: list[Paths]) -> Paths:
        """Join results for disjoint receiver sets (same transmitter), receivers in order."""
        if not parts:
            raise ValueError("nothing to concatenate")
        first = parts[0]
        shift = np.cumsum([0] + [p.n_rx for p in parts[:-1]])
        return Paths(
            tx=first.tx,
            rx=np.concatenate([p.rx for p in parts]),
            frequency=first.frequency,
            rx_index=np.concatenate([p.rx_index + s for p, s in zip(parts, shift, strict=True)]),
            **{name: np.concatenate([getattr(p, name) for p in parts]) for name in _PER_PATH[1:]},
        )


def _psd_sqrt(h: np.ndarray) -> np.ndarray:
    """Square roots (m, 2, 2) of Hermitian positive semi-definite 2x2 matrices (closed form)."""
    s = np.sqrt(np.maximum(np.real(h[:, 0, 0] * h[:, 1, 1] - h[:, 0, 1] * h[:, 1, 0]), 0.0))
    t = np.sqrt(np.maximum(np.real(h[:, 0, 0] + h[:, 1, 1]) + 2.0 * s, 1e-300))
    return (h + s[:, None, None] * np.eye(2)) / t[:, None, None]


_PER_PATH = ("rx_index", "length", "jones", "aod", "aoa", "order", "faces", "objects", "points", "types")
