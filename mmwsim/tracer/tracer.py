"""The tracer: a thin orchestrator of the solver stages, for one transmitter.

Stages, each in a module of its own:

1. :mod:`.shooting` launches rays from the transmitter and bounces them specularly;
   the reflector sequences they follow are the specular candidates, and the faces
   they hit tell which wedges each sequence lights.
2. :mod:`.cells` bins every candidate's rays into the receiver cells they pass near.
3. :mod:`.specular` solves each (sequence, receiver) pair exactly by the image method.
4. :mod:`.diffraction` launches Keller-cone rays from the lit edges and solves the
   singly diffracted paths (with reflections before and after) exactly.
5. :mod:`.diffuse` scatters from the lit rough surfaces (S > 0) towards each receiver,
   on patches refined with the distance, as the last interaction of a path.

Results do not depend on how receivers are split into calls: every call bins its
receivers on the same lattice of cells, fixed in space.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import DEFAULT_RAYS
from ..errors import MmwsimError
from ..scene import Scene
from ..stages import STAGES
from .cells import CandidateCells, CellLattice, LegSet, mark_cells
from .diffraction import CONE_STEP, LIT_SIDE, DiffractionStage
from .diffuse import DiffuseStage
from .paths import Interaction, Paths
from .polarimetry import FaceMaterials, PathBatch, path_fields
from .reflectors import Reflectors, group_reflectors
from .shooting import Shot, shoot
from .specular import SpecularSolver, mirror_chain
from .utd import ON_BOUNDARY
from .wedges import Wedges, find_wedges

__all__ = ["Tracer", "TracerPlan", "trace", "DEFAULT_RAYS", "MIN_GAIN_DB"]

"""Rays launched from the transmitter by default (mean spacing 1.8 mrad)."""
MIN_GAIN_DB = -180.0
"""Paths weaker than this (for the best pair of polarisations) are dropped by default, dB: the
floor of the reference data set (-150 dBm received at 30 dBm, 0 dBi)."""

# (candidate, receiver) pairs solved per batch: bounds the temporaries (about 1 kB per pair).
_PAIR_BATCH = 1 << 19


@dataclass
class TracerPlan:
    """What a tracer learned from its rays, for one lattice of receiver cells (picklable).

    Attributes
    ----------
    tx : (3,) float64
    max_reflections, n_rays : int
    cell_size, cone_step : float
    min_gain_db : float or None
    diffraction_on : bool
    lattice : CellLattice
    sequences : list of (n_k, k) int64
        Specular candidate sequences by order.
    cells : list of CandidateCells
        Their cells (index 0 unused).
    diffraction : DiffractionCandidates or None
    diffraction_cells : CandidateCells or None
    diffuse_lit : (l, 3) int64 or None
        (order of A, A, rough triangle) pairs lit for diffuse scattering.
    """

    tx: np.ndarray
    max_reflections: int
    n_rays: int
    cell_size: float
    cone_step: float
    min_gain_db: float | None
    diffraction_on: bool
    lattice: CellLattice
    sequences: list
    cells: list
    diffraction: object
    diffraction_cells: object
    diffuse_lit: np.ndarray | None = None


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
        Highest number of interactions per path (reflections and the diffraction);
        0 = line of sight only.
    n_rays : int
        Rays launched from the transmitter for the candidate search.
    cell_size : float
        Side of the square cells binning receivers against ray legs, metres.
    diffraction : bool
        Also trace singly diffracted paths (with reflections before and after).
    cone_step : float
        Angular step of the rays launched on Keller cones from lit edges, radians.
    min_gain_db : float or None
        Paths whose gain is below this for every pair of polarisations are dropped, dB;
        None keeps every path.
    plan : TracerPlan, optional
        Candidates found by another tracer of the same scene and settings (:meth:`plan`):
        no rays are shot, the receivers must lie in the plan's lattice.
    diffuse : bool
        Add diffuse scattering from surfaces whose material has a scattering coefficient
        S > 0 (none of the built-in materials has by default).
    """

    def __init__(
        self,
        scene: Scene,
        tx: np.ndarray | tuple[float, float, float] | None = None,
        max_reflections: int = 3,
        n_rays: int = DEFAULT_RAYS,
        cell_size: float = 4.0,
        diffraction: bool = True,
        cone_step: float = CONE_STEP,
        min_gain_db: float | None = MIN_GAIN_DB,
        plan: TracerPlan | None = None,
        diffuse: bool = True,
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
        if int(n_rays) != n_rays or n_rays < 1:
            raise MmwsimError(f"n_rays must be a positive integer, got {n_rays}")
        if not (np.isfinite(cell_size) and cell_size > 0):
            raise MmwsimError(f"cell_size must be a positive number of metres, got {cell_size}")
        if not (np.isfinite(cone_step) and 0 < cone_step <= 0.5):
            raise MmwsimError(f"cone_step must be in (0, 0.5] radians, got {cone_step}")
        if min_gain_db is not None and not np.isfinite(min_gain_db):
            raise MmwsimError(f"min_gain_db must be a finite number of dB or None, got {min_gain_db}")
        self._plan = plan
        self.n_rays = int(n_rays)
        self.cone_step = float(cone_step)
        self.scene = scene
        self.tx = tx
        self.min_gain_db = None if min_gain_db is None else float(min_gain_db)
        self.max_reflections = int(max_reflections)
        self.cell_size = float(cell_size)
        self.frequency = scene.frequency
        self.materials = FaceMaterials.of(scene)
        self.wavelength = self.materials.wavelength
        self.reflectors: Reflectors = group_reflectors(scene)
        self.caster = scene.ray_caster
        floor = 0.0 if self.min_gain_db is None else 10.0 ** (self.min_gain_db / 20.0)
        self.solver = SpecularSolver(self.reflectors, self.caster, self.materials, floor)
        k = self.max_reflections
        with STAGES("wedges"):
            self.wedges: Wedges | None = (
                find_wedges(scene) if diffraction and k and scene.n_triangles else None
            )
        lit_faces = None
        if self.wedges is not None and self.wedges.count:
            lit_faces = np.zeros(max(int(self.wedges.face_facet.max()) + 1, 1), bool)
            lit_faces[
                np.repeat(np.arange(len(self.wedges.facet_start) - 1), np.diff(self.wedges.facet_start))
            ] = True
            lit_faces = lit_faces[self.wedges.face_facet] & (self.wedges.face_facet >= 0)
        rough = self.materials.rough_faces if diffuse and k else np.zeros(scene.n_triangles, bool)
        hit_faces = lit_faces if not rough.any() else (rough if lit_faces is None else lit_faces | rough)
        if plan is not None:
            self.shot = Shot(
                plan.n_rays, float(np.sqrt(4 * np.pi / plan.n_rays)), plan.sequences, [], 0, [], []
            )
        elif self.reflectors.n and k:
            with STAGES("shooting"):
                self.shot: Shot = shoot(
                    self.caster, self.reflectors, tx, k, int(n_rays), hit_faces=hit_faces, hit_orders=k
                )
        else:
            empty = [np.zeros((0, j), np.int64) for j in range(1, k + 1)]
            self.shot = Shot(
                int(n_rays),
                float(np.sqrt(4 * np.pi / n_rays)),
                [np.zeros((1, 0), np.int64)] + empty,
                [],
                0,
                [],
                [],
            )
        # Image of the transmitter after each prefix of each candidate sequence.
        self._images = [np.zeros((1, 0, 3))] + [
            mirror_chain(self.reflectors, tx, self.shot.sequences[j]) for j in range(1, k + 1)
        ]
        self.diffraction: DiffractionStage | None = None
        if lit_faces is not None:
            self.diffraction = DiffractionStage(
                self.wedges,
                self.reflectors,
                self.solver,
                self.materials,
                tx,
                k,
                self.shot.sequences,
                self._lit_pairs() if plan is None else np.zeros((0, 3), np.int64),
                cone_step,
            )
        self.diffuse: DiffuseStage | None = None
        if rough.any():
            lit = plan.diffuse_lit if plan is not None else self._lit_rough(rough)
            self.diffuse = DiffuseStage(
                scene, self.reflectors, self.solver, self.materials, tx, k, self.shot.sequences, lit
            )
        self._cell_cache: dict = {}
        if plan is not None:
            for j in range(1, k + 1):
                self._cell_cache[(j, plan.lattice)] = plan.cells[j]
            if self.diffraction is not None and plan.diffraction is not None:
                self.diffraction.candidates = plan.diffraction
                self.diffraction._cells[plan.lattice] = plan.diffraction_cells

    def plan(self, rx_positions: np.ndarray) -> TracerPlan:
        """The candidates of every stage for receivers like ``rx_positions`` (n, 3), to share.

        A tracer built with ``plan=`` solves receivers inside the same lattice of cells
        (the scene's extent and these receivers' box, at their heights) without shooting a
        ray, and gives the same paths as this one. Data-set workers and Dask tasks get one.
        """
        rx = np.asarray(rx_positions, dtype=np.float64).reshape(-1, 3)
        lattice = self._lattice(rx)
        cells = [None] + [self._cells(k, lattice) for k in range(1, self.max_reflections + 1)]
        d = self.diffraction
        d_cells = None if d is None else d.cells(lattice)
        return TracerPlan(
            tx=self.tx.copy(),
            max_reflections=self.max_reflections,
            n_rays=self.n_rays,
            cell_size=self.cell_size,
            cone_step=self.cone_step,
            min_gain_db=self.min_gain_db,
            diffraction_on=self.wedges is not None,
            lattice=lattice,
            sequences=self.shot.sequences,
            cells=cells,
            diffraction=None if d is None else d.candidates,
            diffraction_cells=d_cells,
            diffuse_lit=None if self.diffuse is None else self.diffuse.lit,
        )

    @classmethod
    def from_plan(cls, scene: Scene, plan: TracerPlan) -> Tracer:
        """A tracer of ``scene`` that reuses ``plan`` (from :meth:`plan` on the same scene)."""
        return cls(
            scene,
            plan.tx,
            plan.max_reflections,
            plan.n_rays,
            plan.cell_size,
            plan.diffraction_on,
            plan.cone_step,
            plan.min_gain_db,
            plan=plan,
            diffuse=plan.diffuse_lit is not None,
        )

    @property
    def n_candidates(self) -> list[int]:
        """Distinct candidate reflector sequences per order (index = number of reflections)."""
        return [len(s) for s in self.shot.sequences]

    @property
    def rays_cast(self) -> int:
        """Embree queries issued so far, all stages together."""
        extra = self.diffraction.rays_cast if self.diffraction is not None else 0
        return self.shot.rays_cast + self.solver.rays_cast + extra

    def _lit_rough(self, rough: np.ndarray) -> np.ndarray:
        """(order of A, A, triangle) for every rough triangle hit by a ray after sequence A."""
        rows = []
        for a, hits in enumerate(self.shot.hits):
            if a >= self.max_reflections or not len(hits):
                continue
            h = hits[rough[hits[:, 1]]]
            rows.append(np.column_stack([np.full(len(h), a), h[:, 0], h[:, 1]]))
        if not rows:
            return np.zeros((0, 3), np.int64)
        return np.unique(np.concatenate(rows), axis=0).astype(np.int64)

    def _lit_pairs(self) -> np.ndarray:
        """(order of A, A, wedge) for every wedge face hit by a ray after sequence A."""
        w = self.wedges
        rows = []
        for a, hits in enumerate(self.shot.hits):
            if a >= self.max_reflections or not len(hits):
                continue
            src, wid = w.wedges_of_facets(w.face_facet[hits[:, 1]])
            rows.append(np.column_stack([np.full(len(src), a), hits[src, 0], wid]))
        if not rows:
            return np.zeros((0, 3), np.int64)
        return np.unique(np.concatenate(rows), axis=0).astype(np.int64)

    # ------------------------------------------------------------------ public
    def trace(self, rx_positions: np.ndarray) -> Paths:
        """Every path from the transmitter to each receiver.

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
        batches = self.solver.line_of_sight(self.tx, rx)
        if len(rx):
            lattice = self._lattice(rx)
            for k in range(1, self.max_reflections + 1):
                seqs, imgs = self.shot.sequences[k], self._images[k]
                for seq_p, rx_p in self._cells(k, lattice).pairs(rx, _PAIR_BATCH):
                    with STAGES("exact solve"):
                        batches += self.solver.solve(self.tx, seqs, imgs, seq_p, rx_p, rx)
            if self.diffraction is not None:
                for cand_p, rx_p in self.diffraction.cells(lattice).pairs(rx, _PAIR_BATCH):
                    with STAGES("diffraction solve"):
                        batches += self.diffraction.solve(cand_p, rx_p, rx)
            if self.diffuse is not None:
                with STAGES("diffuse"):
                    batches += self.diffuse.solve(rx)
        with STAGES("exact solve"):
            self._settle_boundaries(rx, batches)
            return self._assemble(rx, batches)

    # ------------------------------------------------------------------ receivers vs candidates
    def _lattice(self, rx: np.ndarray) -> CellLattice:
        """Cells over the scene and the receivers, so that every tile of one grid shares them."""
        z = (float(rx[:, 2].min()), float(rx[:, 2].max()))
        if self._plan is not None:
            lat = self._plan.lattice
            lo = np.asarray(lat.origin)
            hi = lo + lat.size * np.asarray(lat.shape)
            if lat.z_range != z or np.any(rx[:, :2].min(axis=0) < lo) or np.any(rx[:, :2].max(axis=0) >= hi):
                raise MmwsimError("receivers outside the lattice of the tracer's plan")
            return lat
        lo, hi = self.scene.extent
        lo = np.minimum(lo[:2], rx[:, :2].min(axis=0))
        hi = np.maximum(hi[:2], rx[:, :2].max(axis=0))
        return CellLattice.covering(lo, hi, self.cell_size, z)

    def _cells(self, k: int, lattice: CellLattice) -> CandidateCells:
        """Cells reachable by each candidate sequence of order ``k`` (cached per lattice)."""
        key = (k, lattice)
        if key not in self._cell_cache:
            legs = self.shot.legs[k] if k < len(self.shot.legs) else None
            if legs is None or len(legs.seq) == 0:
                leg_set = LegSet.empty()
            else:
                sp = self.shot.spacing
                # Rays of one sequence lie about spacing x distance apart; twice that, plus a margin.
                leg_set = LegSet(
                    legs.seq.astype(np.int64),
                    legs.start,
                    legs.direction,
                    legs.length,
                    (2.0 * sp * legs.unfolded + 0.05).astype(np.float32),
                    np.full(len(legs.seq), 2.0 * sp, np.float32),
                )
            with STAGES("candidate cells"):
                self._cell_cache[key] = mark_cells(leg_set, len(self.shot.sequences[k]), lattice)
        return self._cell_cache[key]

    def _settle_boundaries(self, rx: np.ndarray, batches: list[PathBatch]) -> None:
        """Diffracted paths exactly on a shadow boundary take the one-sided limit of the side their
        geometrical-optics partner was found on.

        There the UTD coefficient is the mean of its two one-sided limits, which is right only with
        the partner weighted 1/2. Whether Embree keeps a ray that grazes an edge exactly is a matter
        of float32 rounding; so the partner (the path with the same reflections, plus the face's
        reflection for a reflection boundary) is looked up, and the coefficient is taken on its
        side if it was found (total: partner + lit-side limit) and on the other side if not (total:
        shadow-side limit), both equal to the mean plus half the partner.
        """
        flagged = [
            (b, np.flatnonzero(b.boundary)) for b in batches if b.boundary is not None and b.boundary.any()
        ]
        if not flagged:
            return
        fr = self.reflectors.face_reflector
        targets = set(int(r) for b, i in flagged for r in b.rx[i])
        present = set()
        for b in batches:
            if b.wedge is not None or not len(b):
                continue
            for j in np.flatnonzero(np.isin(b.rx, list(targets))):
                present.add((int(b.rx[j]), tuple(fr[b.faces[j]].tolist())))
        w = self.wedges
        for b, i in flagged:
            nudge = np.zeros(len(i))
            for n, j in enumerate(i):
                d = int(np.flatnonzero(b.types[j] == Interaction.DIFFRACTION)[0])
                refs = fr[b.faces[j]].tolist()
                code = int(b.boundary[j])
                mid = (
                    [] if code <= 2 else [int(fr[w.face0[b.wedge[j]] if code == 3 else w.facen[b.wedge[j]]])]
                )
                twin = (int(b.rx[j]), tuple(refs[:d] + mid + refs[d + 1 :]))
                nudge[n] = (1.0 if twin in present else -1.0) * LIT_SIDE[code] * 4.0 * ON_BOUNDARY
            refl = self.reflectors
            normals = refl.normal[np.where(b.faces[i] >= 0, fr[np.maximum(b.faces[i], 0)], 0)]
            order = np.full(len(i), b.k, np.int64)
            b.jones[i], _, _ = path_fields(
                self.tx, rx[b.rx[i]], b.points[i], order, b.types[i], b.faces[i], normals, b.wedge[i], w,
                self.materials, nudge,
            )  # fmt: skip

    # ------------------------------------------------------------------ assembly
    def _assemble(self, rx: np.ndarray, batches: list[PathBatch]) -> Paths:
        kmax = self.max_reflections
        if not batches:
            batches = [PathBatch.empty(0)]
        n = sum(len(b) for b in batches)
        rx_index = np.concatenate([b.rx for b in batches]).astype(np.int64)
        length = np.concatenate([b.length for b in batches])
        order = np.concatenate([np.full(len(b), b.k, np.int8) for b in batches])
        faces = np.full((n, kmax), -1, np.int64)
        types = np.zeros((n, kmax), np.int8)
        points = np.full((n, kmax, 3), np.nan)
        start = 0
        for b in batches:
            sl = slice(start, start + len(b))
            faces[sl, : b.k] = b.faces
            types[sl, : b.k] = b.types
            points[sl, : b.k] = b.points
            start += len(b)
        jones = np.concatenate([b.jones for b in batches])
        aod = np.concatenate([b.aod for b in batches])
        aoa = np.concatenate([b.aoa for b in batches])
        objects = np.full(faces.shape, -1, np.int64)
        objects[faces >= 0] = self.scene.face_object[faces[faces >= 0]]
        # Deterministic order: receiver, then delay; exact ties (symmetric geometry) by
        # interaction count, faces and kinds.
        delay = np.round(length, 9)
        srt = np.lexsort((delay, rx_index)) if n else np.zeros(0, np.int64)
        tie = np.flatnonzero((rx_index[srt][1:] == rx_index[srt][:-1]) & (delay[srt][1:] == delay[srt][:-1]))
        if len(tie):
            members = np.unique(np.concatenate([tie, tie + 1]))
            sub = srt[members]
            keys = [types[sub, j] for j in range(kmax - 1, -1, -1)]
            keys += [faces[sub, j] for j in range(kmax - 1, -1, -1)] + [order[sub], delay[sub], rx_index[sub]]
            srt[members] = sub[np.lexsort(keys)]
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
            types=types[srt],
        )


def trace(
    scene: Scene,
    tx: np.ndarray | tuple[float, float, float] | None = None,
    rx_positions: np.ndarray | None = None,
    max_reflections: int = 3,
    n_rays: int = DEFAULT_RAYS,
    tile: int = 65536,
    diffraction: bool = True,
    min_gain_db: float | None = MIN_GAIN_DB,
) -> Paths:
    """Every path of line of sight, reflections and (optionally) one diffraction.

    Parameters
    ----------
    scene : Scene
    tx : (3,) float, optional
        Transmitter, metres; defaults to ``scene.transmitter``.
    rx_positions : (n_rx, 3) float, optional
        Receivers, metres; defaults to ``scene.receivers.positions()``.
    max_reflections : int
        Highest number of interactions per path, the diffraction included.
    n_rays : int
        Rays launched for the candidate search.
    tile : int
        Receivers solved per tile (memory bound; results do not depend on it).
    diffraction : bool
        Trace singly diffracted paths too.
    min_gain_db : float or None
        Drop paths weaker than this for every pair of polarisations, dB (None: keep all).

    Returns
    -------
    Paths
    """
    tracer = Tracer(scene, tx, max_reflections, n_rays, diffraction=diffraction, min_gain_db=min_gain_db)
    rx = scene.receivers.positions() if rx_positions is None else np.asarray(rx_positions, dtype=np.float64)
    if rx.ndim == 1 and rx.shape == (3,):
        rx = rx[None]
    if len(rx) <= tile:
        return tracer.trace(rx)
    return Paths.concatenate([tracer.trace(rx[s : s + tile]) for s in range(0, len(rx), tile)])
