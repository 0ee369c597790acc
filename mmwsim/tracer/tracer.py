"""The exact specular tracer: Embree candidates, image-method geometry, Fresnel polarimetry.

For each candidate reflector sequence (found by shooting rays, :mod:`.shooting`)
and each receiver its rays may reach, the path is solved exactly in float64 by
the image method; it is kept only if every reflection point lies between its
neighbours and on the reflector's actual triangles, and no leg is blocked. Both
last conditions are checked at once with Embree: the first hit of a ray cast
from one interaction towards the next must be a triangle of the expected
reflector (a ray meets a plane at most once, so that hit is the reflection
point), and the last leg must reach the receiver unoccluded.
"""

from __future__ import annotations

import numpy as np

from ..constants import SPEED_OF_LIGHT
from ..errors import MmwsimError
from ..scene import Scene
from .fresnel import bounce_matrices, direction_angles, reflection, spherical_basis
from .paths import Paths
from .reflectors import Reflectors, group_reflectors
from .shooting import CellGrid, Shot, sequence_cells, shoot

__all__ = ["Tracer", "trace", "DEFAULT_RAYS"]

DEFAULT_RAYS = 8_000_000
"""Rays launched from the transmitter by default (mean spacing 1.25 mrad)."""

# Offset of leg origins off the reflecting plane and clearance kept before a receiver, metres.
_EPS = 1e-3
# Reflection points may sit this far outside a reflector's bounds (float64 noise) before
# Embree decides on the exact face.
_BOX_TOL = 1e-6
# (sequence, receiver) pairs solved per batch: bounds the temporaries (about 1 kB per pair).
_PAIR_BATCH = 1 << 20


class Tracer:
    """A transmitter's candidate search, reusable for any number of receiver tiles.

    The rays are shot once at construction; :meth:`trace` then solves the exact
    paths for a set of receivers. Results do not depend on how receivers are
    split into tiles.

    Parameters
    ----------
    scene : Scene
    tx : (3,) float, optional
        Transmitter position, metres; defaults to ``scene.transmitter``.
    max_reflections : int
        Highest number of reflections per path (0 = line of sight only).
    n_rays : int
        Rays launched from the transmitter for the candidate search.
    cell_size : float
        Side of the square cells binning receivers against ray legs, metres.
    """

    def __init__(
        self,
        scene: Scene,
        tx: np.ndarray | tuple[float, float, float] | None = None,
        max_reflections: int = 3,
        n_rays: int = DEFAULT_RAYS,
        cell_size: float = 4.0,
    ):
        if tx is None:
            if scene.transmitter is None:
                raise MmwsimError(f"scene {scene.name!r} has no transmitter; give one")
            tx = scene.transmitter.array
        tx = np.asarray(tx, dtype=np.float64)
        if tx.shape != (3,) or not np.all(np.isfinite(tx)):
            raise MmwsimError(f"transmitter position must be three finite numbers, got {tx!r}")
        if int(max_reflections) != max_reflections or not 0 <= max_reflections <= 6:
            raise MmwsimError(f"max_reflections must be an integer from 0 to 6, got {max_reflections}")
        if n_rays < 1:
            raise MmwsimError(f"n_rays must be positive, got {n_rays}")
        self.scene = scene
        self.tx = tx
        self.max_reflections = int(max_reflections)
        self.cell_size = float(cell_size)
        self.frequency = scene.frequency
        self.wavelength = SPEED_OF_LIGHT / scene.frequency
        self.reflectors: Reflectors = group_reflectors(scene)
        self.caster = scene.ray_caster
        eps = np.array([o.material.complex_permittivity(scene.frequency) for o in scene.objects], complex)
        thick = np.array([o.material.thickness or 0.0 for o in scene.objects], dtype=np.float64)
        self._face_eps = eps[scene.face_object] if len(eps) else np.zeros(0, complex)
        self._face_thick = thick[scene.face_object] if len(thick) else np.zeros(0)
        self.rays_cast = 0
        if self.reflectors.n and self.max_reflections:
            self.shot: Shot = shoot(self.caster, self.reflectors, tx, self.max_reflections, int(n_rays))
        else:
            self.shot = Shot(
                int(n_rays), float(np.sqrt(4 * np.pi / n_rays)), [np.zeros((1, 0), np.int64)], [], 0, []
            )
            self.shot.sequences += [np.zeros((0, k), np.int64) for k in range(1, self.max_reflections + 1)]
        self.rays_cast += self.shot.rays_cast
        # Image of the transmitter after each prefix of each candidate sequence.
        self._images: list[np.ndarray] = [np.zeros((1, 0, 3))]
        for k in range(1, self.max_reflections + 1):
            seqs = self.shot.sequences[k]
            imgs = np.empty((len(seqs), k, 3))
            cur = np.broadcast_to(tx, (len(seqs), 3))
            for j in range(k):
                cur = self.reflectors.mirror(cur, seqs[:, j])
                imgs[:, j] = cur
            self._images.append(imgs)

    @property
    def n_candidates(self) -> list[int]:
        """Distinct candidate sequences per order (index = number of reflections)."""
        return [len(s) for s in self.shot.sequences]

    # ------------------------------------------------------------------ public
    def trace(self, rx_positions: np.ndarray) -> Paths:
        """Every specular path from the transmitter to each receiver.

        Parameters
        ----------
        rx_positions : (n_rx, 3) float
            Receiver positions, metres.

        Returns
        -------
        Paths
            Paths sorted by receiver, then by delay.
        """
        rx = np.asarray(rx_positions, dtype=np.float64)
        if rx.ndim == 1 and rx.shape == (3,):
            rx = rx[None]
        if rx.ndim != 2 or rx.shape[1] != 3:
            raise MmwsimError(f"receiver positions must have shape (n, 3), got {rx.shape}")
        if not np.all(np.isfinite(rx)):
            raise MmwsimError("receiver positions contain NaN or infinite coordinates")
        parts = [self._line_of_sight(rx)]
        if len(rx):
            grid = self._grid(rx)
            cells = self._sequence_cells(grid)
            rx_cell = grid.cell_of(rx[:, :2])
            order = np.argsort(rx_cell, kind="stable")
            first = np.searchsorted(rx_cell[order], np.arange(grid.n_cells + 1))
            for k in range(1, self.max_reflections + 1):
                for seq_p, rx_p in _pairs(cells[k], grid.n_cells, order, first):
                    parts.append(self._solve(k, seq_p, rx_p, rx))
        return self._assemble(rx, parts)

    # ------------------------------------------------------------------ receivers vs candidates
    def _grid(self, rx: np.ndarray) -> CellGrid:
        c = self.cell_size
        # Cells on a lattice fixed in space, so that tiles of one receiver set bin alike.
        lo = np.floor(rx[:, :2].min(axis=0) / c) * c
        hi = rx[:, :2].max(axis=0)
        shape = tuple(int(v) for v in np.floor((hi - lo) / c).astype(int) + 1)
        z = (float(rx[:, 2].min()), float(rx[:, 2].max()))
        return CellGrid((float(lo[0]), float(lo[1])), c, shape, z)

    def _sequence_cells(self, grid: CellGrid) -> list[np.ndarray]:
        out = [np.zeros(0, np.int64)]
        for k in range(1, self.max_reflections + 1):
            legs = self.shot.legs[k] if k < len(self.shot.legs) else None
            out.append(
                sequence_cells(legs, grid, self.shot.spacing) if legs is not None else np.zeros(0, np.int64)
            )
        return out

    # ------------------------------------------------------------------ geometry
    def _line_of_sight(self, rx: np.ndarray) -> dict:
        v = rx - self.tx
        dist = np.linalg.norm(v, axis=1)
        ok = dist > _EPS
        d = np.zeros_like(v)
        d[ok] = v[ok] / dist[ok, None]
        blocked = self.caster.occluded(np.broadcast_to(self.tx, v.shape)[ok], d[ok], dist[ok] - _EPS)
        self.rays_cast += int(ok.sum())
        idx = np.flatnonzero(ok)[~blocked]
        return dict(
            k=0,
            rx=idx,
            length=dist[idx],
            points=np.zeros((len(idx), 0, 3)),
            faces=np.zeros((len(idx), 0), np.int64),
            refs=np.zeros((len(idx), 0), np.int64),
        )

    def _solve(self, k: int, seq_p: np.ndarray, rx_p: np.ndarray, rx: np.ndarray) -> dict:
        """Exact paths of order ``k`` for (sequence, receiver) pairs; returns the valid ones."""
        refl = self.reflectors
        seqs = self.shot.sequences[k]
        imgs = self._images[k]
        alive = np.arange(len(seq_p))
        pts = np.empty((len(seq_p), k, 3))
        nxt = rx[rx_p]
        # Back from the receiver: the leg towards image j crosses plane j at the reflection point.
        for j in range(k - 1, -1, -1):
            s = seq_p[alive]
            r = seqs[s, j]
            img = imgs[s, j]
            n = refl.normal[r]
            den = np.einsum("ij,ij->i", n, img - nxt)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (refl.offset[r] - np.einsum("ij,ij->i", n, nxt)) / den
            p = nxt + t[:, None] * (img - nxt)
            ok = (t > 1e-12) & (t < 1.0 - 1e-12)
            ok &= np.all((p >= refl.lo[r] - _BOX_TOL) & (p <= refl.hi[r] + _BOX_TOL), axis=1)
            alive, nxt = alive[ok], p[ok]
            pts[alive, j] = nxt
        seq_p, rx_p, pts = seq_p[alive], rx_p[alive], pts[alive]
        refs = seqs[seq_p]
        # Legs towards each reflection point: the first hit must be on the expected reflector.
        m = len(seq_p)
        faces = np.full((m, k), -1, np.int64)
        good = np.ones(m, bool)
        origins = np.empty((m, k, 3))
        origins[:, 0] = self.tx
        if k > 1:
            prev = pts[:, :-1]
            n = refl.normal[refs[:, :-1]]
            side = np.sign(np.einsum("mki,mki->mk", pts[:, 1:] - prev, n))
            origins[:, 1:] = prev + (side * _EPS)[..., None] * n
        v = pts - origins
        dist = np.linalg.norm(v, axis=2)
        _, f = self.caster.intersect(origins.reshape(-1, 3), (v / dist[..., None]).reshape(-1, 3))
        self.rays_cast += m * k
        f = f.reshape(m, k)
        hit_ref = np.where(f >= 0, refl.face_reflector[np.maximum(f, 0)], -1)
        good &= np.all(hit_ref == refs, axis=1)
        faces[:] = f
        # Last leg to the receiver.
        last = pts[:, -1]
        n = refl.normal[refs[:, -1]]
        to_rx = rx[rx_p] - last
        side = np.sign(np.einsum("mi,mi->m", to_rx, n))
        o = last + (side * _EPS)[:, None] * n
        v = rx[rx_p] - o
        dist = np.linalg.norm(v, axis=1)
        sel = np.flatnonzero(good)
        blocked = self.caster.occluded(o[sel], v[sel] / dist[sel, None], dist[sel] - _EPS)
        self.rays_cast += len(sel)
        good[sel[blocked]] = False
        length = np.linalg.norm(rx[rx_p] - imgs[seq_p, k - 1], axis=1)
        return dict(
            k=k, rx=rx_p[good], length=length[good], points=pts[good], faces=faces[good], refs=refs[good]
        )

    # ------------------------------------------------------------------ physics and assembly
    def _assemble(self, rx: np.ndarray, parts: list[dict]) -> Paths:
        kmax = self.max_reflections
        rx_index = np.concatenate([p["rx"] for p in parts]).astype(np.int64)
        length = np.concatenate([p["length"] for p in parts])
        order = np.concatenate([np.full(len(p["rx"]), p["k"], np.int8) for p in parts])
        n = len(rx_index)
        faces = np.full((n, kmax), -1, np.int64)
        points = np.full((n, kmax, 3), np.nan)
        jones = np.empty((n, 2, 2), complex)
        aod = np.empty((n, 2))
        aoa = np.empty((n, 2))
        start = 0
        for p in parts:
            m, k = len(p["rx"]), p["k"]
            sl = slice(start, start + m)
            faces[sl, :k] = p["faces"]
            points[sl, :k] = p["points"]
            jones[sl], aod[sl], aoa[sl] = self._polarimetry(rx[p["rx"]], p["points"], p["faces"], p["refs"])
            start += m
        jones *= (self.wavelength / (4.0 * np.pi * np.maximum(length, 1e-300)))[:, None, None]
        objects = np.full(faces.shape, -1, np.int64)
        objects[faces >= 0] = self.scene.face_object[faces[faces >= 0]]
        # Deterministic order: receiver, then delay, then reflection order, then interaction faces.
        keys = [faces[:, j] for j in range(kmax - 1, -1, -1)] + [order, np.round(length, 9), rx_index]
        srt = np.lexsort(keys) if n else np.zeros(0, np.int64)
        return Paths(
            tx=self.tx.copy(),
            rx=rx.copy(),
            frequency=self.frequency,
            rx_index=rx_index[srt],
            length=length[srt],
            jones=jones[srt],
            aod=aod[srt],
            aoa=aoa[srt],
            order=order[srt],
            faces=faces[srt],
            objects=objects[srt].astype(np.int32),
            points=points[srt],
        )

    def _polarimetry(
        self, rx: np.ndarray, pts: np.ndarray, faces: np.ndarray, refs: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Jones matrices (without spreading), departure and arrival angles of paths of one order."""
        m, k = refs.shape
        nodes = np.concatenate([np.broadcast_to(self.tx, (m, 1, 3)), pts, rx[:, None, :]], axis=1)
        legs = np.diff(nodes, axis=1)
        legs /= np.linalg.norm(legs, axis=2, keepdims=True)
        t = np.broadcast_to(np.eye(3, dtype=complex), (m, 3, 3)).copy()
        for j in range(k):
            n = self.reflectors.normal[refs[:, j]]
            cos = np.abs(np.einsum("mi,mi->m", legs[:, j], n))
            f = faces[:, j]
            r_te, r_tm = reflection(
                self._face_eps[f], self._face_thick[f], np.minimum(cos, 1.0), self.wavelength
            )
            t = bounce_matrices(legs[:, j], legs[:, j + 1], n, r_te, r_tm) @ t
        aod = direction_angles(legs[:, 0])
        aoa = direction_angles(-legs[:, -1])
        th_t, ph_t = spherical_basis(aod)
        th_r, ph_r = spherical_basis(aoa)
        w = np.stack([th_t, ph_t], axis=2)  # (m, 3, 2): columns are the TX basis
        u = np.stack([th_r, ph_r], axis=1)  # (m, 2, 3): rows are the RX basis
        return u @ t @ w, aod, aoa


def _pairs(keys: np.ndarray, n_cells: int, order: np.ndarray, first: np.ndarray):
    """(sequence, receiver) index pairs of the receivers in each (sequence, cell), in batches."""
    if len(keys) == 0:
        return
    seq = keys // n_cells
    cell = keys % n_cells
    counts = first[cell + 1] - first[cell]
    keep = counts > 0
    seq, cell, counts = seq[keep], cell[keep], counts[keep]
    cum = np.cumsum(counts)
    start = 0
    while start < len(seq):
        done = cum[start - 1] if start else 0
        stop = max(int(np.searchsorted(cum, done + _PAIR_BATCH, side="right")), start + 1)
        c = counts[start:stop]
        rep = np.repeat(np.arange(stop - start), c)
        within = np.arange(len(rep)) - (np.cumsum(c) - c)[rep]
        rx_p = order[first[cell[start:stop]][rep] + within]
        yield seq[start:stop][rep], rx_p
        start = stop


def trace(
    scene: Scene,
    tx: np.ndarray | tuple[float, float, float] | None = None,
    rx_positions: np.ndarray | None = None,
    max_reflections: int = 3,
    n_rays: int = DEFAULT_RAYS,
    tile: int = 65536,
) -> Paths:
    """Every specular path (line of sight and up to ``max_reflections`` reflections).

    Parameters
    ----------
    scene : Scene
    tx : (3,) float, optional
        Transmitter, metres; defaults to ``scene.transmitter``.
    rx_positions : (n_rx, 3) float, optional
        Receivers, metres; defaults to ``scene.receivers.positions()``.
    max_reflections : int
    n_rays : int
        Rays launched for the candidate search.
    tile : int
        Receivers solved per tile (memory bound; results do not depend on it).

    Returns
    -------
    Paths
    """
    tracer = Tracer(scene, tx, max_reflections, n_rays)
    rx = scene.receivers.positions() if rx_positions is None else np.asarray(rx_positions, dtype=np.float64)
    if rx.ndim == 1 and rx.shape == (3,):
        rx = rx[None]
    if len(rx) <= tile:
        return tracer.trace(rx)
    return Paths.concatenate([tracer.trace(rx[s : s + tile]) for s in range(0, len(rx), tile)])
