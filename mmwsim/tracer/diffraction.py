"""Single edge diffraction, with specular reflections before and after it.

A diffracted path is ``TX -A-> Q -B-> RX``: reflector sequences A before and B after
one diffraction point Q on a wedge, ``len(A) + 1 + len(B)`` interactions in all.

Candidates are found in three steps, all deterministic:

1. *Lit wedges.* A wedge can be lit through sequence A if some transmitter ray that
   followed A next hit one of the wedge's faces (recorded by the shooting stage).
2. *Keller-cone rays.* Along the lit part of each such edge (points whose exact
   unfolded path back to the transmitter is clear), rays are launched on the Keller
   cone of the incident direction, over the exterior angle, and bounced specularly;
   each distinct reflector sequence B they follow gives a candidate (A, wedge, B).
3. *Cells.* The candidates' rays mark the receiver cells they pass near (:mod:`.cells`),
   with a tolerance covering the sampling of the edge and of the cone.

Each (candidate, receiver) pair is then solved exactly: the transmitter's image S
through A and the receiver's image T through B reversed fix the diffraction point in
closed form (Keller's cone, :func:`.utd.keller_point`); the reflection points follow by
unfolding; the path is kept only if Q lies on the edge, both ends are in the wedge's
exterior, every reflection lands on its reflector and no leg is blocked. The field is
``(lambda / 4 pi) B_after D B_before / sqrt(s s' (s + s'))`` with the UTD coefficient
``D`` of :mod:`.utd`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cells import CandidateCells, CellLattice, LegSet, mark_cells
from .paths import Interaction
from .polarimetry import FaceMaterials, PathBatch, antenna_jones, reflection_chain, unit_legs
from .reflectors import Reflectors
from .specular import EPS, SpecularSolver, mirror_chain
from .utd import diffraction_matrices, keller_point
from .wedges import Wedges

__all__ = ["DiffractionStage", "DiffractionCandidates", "CONE_STEP"]

CONE_STEP = np.radians(1.0)
"""Angular step of the Keller-cone rays around the edge, radians."""
_EDGE_STEP_MAX = 2.0  # longest spacing of launch points along an edge, metres
_EDGE_STEP_MIN = 0.1  # ... and shortest
_SAFETY = 1.5  # cell-marking tolerance over the sampling error bound
_POINT_BATCH = 2048  # launch points per batch of cone rays (a few hundred rays each)


@dataclass
class DiffractionCandidates:
    """Candidate diffraction sequences (A, wedge, B).

    Attributes
    ----------
    pre : (c, max_interactions - 1) int64
        Reflectors before the diffraction, padded with -1 (``pre_len`` of them).
    wedge : (c,) int64
    post : (c, max_interactions - 1) int64
        Reflectors after the diffraction, padded with -1.
    pre_len, post_len : (c,) int64
    """

    pre: np.ndarray
    wedge: np.ndarray
    post: np.ndarray
    pre_len: np.ndarray
    post_len: np.ndarray

    def __len__(self) -> int:
        return int(len(self.wedge))


class DiffractionStage:
    """Candidate search and exact solve of singly diffracted paths from one transmitter.

    Parameters
    ----------
    wedges : Wedges
    reflectors : Reflectors
    solver : SpecularSolver
        Shared with the specular stage (unfolding, leg checks, Embree).
    materials : FaceMaterials
    tx : (3,) float64
    max_interactions : int
        Interactions per path, the diffraction included (at least 1).
    pre_sequences : list of (n_k, k) int64
        Reflector sequences found by the shooting stage, by order (index 0: empty).
    lit : (l, 3) int64
        (order of A, index of A in ``pre_sequences[order]``, wedge) of every lit pair.
    cone_step : float
        Angular step of the Keller-cone rays, radians.
    """

    def __init__(
        self,
        wedges: Wedges,
        reflectors: Reflectors,
        solver: SpecularSolver,
        materials: FaceMaterials,
        tx: np.ndarray,
        max_interactions: int,
        pre_sequences: list[np.ndarray],
        lit: np.ndarray,
        cone_step: float = CONE_STEP,
    ):
        self.wedges = wedges
        self.reflectors = reflectors
        self.solver = solver
        self.materials = materials
        self.tx = np.asarray(tx, dtype=np.float64)
        self.max_interactions = int(max_interactions)
        self.pre_sequences = pre_sequences
        self.lit = lit
        self.cone_step = float(cone_step)
        self.rays_cast = 0
        self.candidates: DiffractionCandidates | None = None
        self._cells: dict[CellLattice, CandidateCells] = {}

    # ------------------------------------------------------------------ candidates
    def cells(self, lattice: CellLattice) -> CandidateCells:
        """Receiver cells of every candidate (launches the cone rays once per lattice)."""
        if lattice not in self._cells:
            cands, legs = self._launch()
            if self.candidates is None:
                self.candidates = cands
            self._cells[lattice] = mark_cells(legs, len(cands), lattice)
        return self._cells[lattice]

    def _launch(self) -> tuple[DiffractionCandidates, LegSet]:
        """Cone rays from the lit parts of every lit edge; candidates in order of discovery."""
        w = self.wedges
        lit = self.lit
        if len(lit) == 0 or self.max_interactions < 1:
            return _no_candidates(max(self.max_interactions - 1, 1)), LegSet.empty()
        order, seq, wid = lit[:, 0], lit[:, 1], lit[:, 2]
        src = self._sources(order, seq)
        # Launch spacing along the edge: the cone turns by about dx / s' per metre.
        d_line = _distance_to_segment(src, w.origin[wid], w.edge[wid], w.length[wid])
        dx = np.clip(self.cone_step * d_line, _EDGE_STEP_MIN, _EDGE_STEP_MAX)
        n_s = np.maximum(np.ceil(w.length[wid] / dx).astype(np.int64), 1)
        dx = w.length[wid] / n_s
        pair = np.repeat(np.arange(len(lit)), n_s)
        j = np.arange(int(n_s.sum())) - np.repeat(np.cumsum(n_s) - n_s, n_s)
        x = (j + 0.5) * dx[pair]
        q = w.point(wid[pair], x)
        lit_pt = self._visible(order[pair], seq[pair], wid[pair], q)
        pair, q = pair[lit_pt], q[lit_pt]
        # Candidate ids: (pair, B) in order of discovery, B up to the remaining interactions.
        nb = self.max_interactions  # B lengths 0 .. max_interactions - 1
        tables: list[dict[int, int]] = [{} for _ in range(nb)]
        parents: list[list[int]] = [[] for _ in range(nb)]
        leg_parts: list[LegSet] = []
        n_ref = max(self.reflectors.n, 1)
        slope_p = _SAFETY * (self.cone_step + dx / np.maximum(d_line, 1e-3))
        gap0_p = _SAFETY * 0.5 * dx + 0.05
        b_max = self.max_interactions - 1 - order  # reflections allowed after the diffraction, per lit pair
        for b0 in range(0, len(pair), _POINT_BATCH):
            ray_pair, origin, dirs = self._cone(pair[b0 : b0 + _POINT_BATCH], q[b0 : b0 + _POINT_BATCH], src)
            level = self._ids(tables[0], parents[0], ray_pair)
            unfolded = np.zeros(len(ray_pair))
            last = np.full(len(ray_pair), -1, np.int64)
            for kb in range(nb):
                t, face = self.solver.caster.intersect(origin, dirs)
                self.rays_cast += len(origin)
                leg_parts.append(
                    LegSet(
                        level * nb + kb,
                        origin.astype(np.float32),
                        dirs.astype(np.float32),
                        t.astype(np.float32),
                        (gap0_p[ray_pair] + slope_p[ray_pair] * unfolded).astype(np.float32),
                        slope_p[ray_pair].astype(np.float32),
                    )
                )
                ref = np.where(face >= 0, self.reflectors.face_reflector[np.maximum(face, 0)], -1)
                keep = (ref >= 0) & (ref != last) & (kb < b_max[ray_pair])
                if kb + 1 == nb or not keep.any():
                    break
                t, ref, origin, dirs = t[keep], ref[keep], origin[keep], dirs[keep]
                ray_pair, unfolded, level = ray_pair[keep], unfolded[keep] + t, level[keep]
                n = self.reflectors.normal[ref]
                point = origin + t[:, None] * dirs
                dn = np.einsum("ij,ij->i", dirs, n)
                dirs = dirs - 2.0 * dn[:, None] * n
                origin = point - np.sign(dn)[:, None] * EPS * n
                level = self._ids(tables[kb + 1], parents[kb + 1], level * n_ref + ref)
                last = ref
        sizes = [len(p) for p in parents]
        legs = LegSet.concatenate(leg_parts)
        offset = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        legs.cand = offset[legs.cand % nb] + legs.cand // nb
        return self._table(parents, n_ref), legs

    @staticmethod
    def _ids(table: dict[int, int], parents: list[int], keys: np.ndarray) -> np.ndarray:
        uniq, inv = np.unique(keys, return_inverse=True)
        out = np.empty(len(uniq), np.int64)
        for i, key in enumerate(uniq.tolist()):
            if key not in table:
                table[key] = len(table)
                parents.append(key)
            out[i] = table[key]
        return out[inv.ravel()]

    def _table(self, parents: list[list[int]], n_ref: int) -> DiffractionCandidates:
        """Candidates (A, wedge, B) of every B length, in id order (B length, then discovery)."""
        lit = self.lit
        width = max(self.max_interactions - 1, 1)
        pair = np.asarray(parents[0], np.int64)
        post = np.full((len(pair), width), -1, np.int64)
        rows_pair, rows_post = [pair], [post]
        for kb in range(1, len(parents)):
            keys = np.asarray(parents[kb], np.int64)
            par = keys // n_ref
            pair, post = pair[par], post[par].copy()
            post[:, kb - 1] = keys % n_ref
            rows_pair.append(pair)
            rows_post.append(post)
        pair = np.concatenate(rows_pair)
        post = np.concatenate(rows_post)
        a_len = lit[pair, 0]
        pre = np.full((len(pair), width), -1, np.int64)
        for a in np.unique(a_len[a_len > 0]):
            m = a_len == a
            pre[m, :a] = self.pre_sequences[a][lit[pair[m], 1]]
        return DiffractionCandidates(pre, lit[pair, 2], post, a_len, (post >= 0).sum(axis=1))

    def _sources(self, order: np.ndarray, seq: np.ndarray) -> np.ndarray:
        """(l, 3) image of the transmitter through each lit pair's sequence A."""
        out = np.broadcast_to(self.tx, (len(order), 3)).copy()
        for a in np.unique(order[order > 0]):
            m = order == a
            if m.any():
                out[m] = mirror_chain(self.reflectors, self.tx, self.pre_sequences[a][seq[m]])[:, -1]
        return out

    def _visible(self, order: np.ndarray, seq: np.ndarray, wid: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Whether each edge point is reached from the transmitter through its sequence A."""
        end = q + 1e-3 * self.wedges.bisector(wid)
        out = np.zeros(len(q), bool)
        for a in np.unique(order):
            m = np.flatnonzero(order == a)
            refs = self.pre_sequences[a][seq[m]] if a else np.zeros((len(m), 0), np.int64)
            imgs = mirror_chain(self.reflectors, self.tx, refs)
            alive, pts = self.solver.unfold(imgs, refs, end[m])
            good, _ = self.solver.check(
                np.broadcast_to(self.tx, (len(alive), 3)), pts, refs[alive], end[m][alive]
            )
            out[m[alive[good]]] = True
        return out

    def _cone(self, pair: np.ndarray, q: np.ndarray, src: np.ndarray):
        """Rays on the Keller cone at edge points ``q`` (p, 3) of lit pairs ``pair`` over the exterior.

        ``src`` (l, 3) holds the source image of every lit pair.
        """
        w = self.wedges
        wid = self.lit[pair, 2]
        e = w.edge[wid]
        k_in = q - src[pair]
        k_in /= np.linalg.norm(k_in, axis=1, keepdims=True)
        cos_b = np.clip(np.einsum("ij,ij->i", k_in, e), -1.0, 1.0)
        sin_b = np.sqrt(1.0 - cos_b**2)
        n_phi = np.maximum(np.ceil(w.n[wid] * np.pi / self.cone_step).astype(np.int64), 1)
        rep = np.repeat(np.arange(len(pair)), n_phi)
        j = np.arange(int(n_phi.sum())) - np.repeat(np.cumsum(n_phi) - n_phi, n_phi)
        phi = (j + 0.5) * (w.n[wid] * np.pi / n_phi)[rep]
        wr = wid[rep]
        d = (
            cos_b[rep, None] * e[rep]
            + (sin_b[rep] * np.cos(phi))[:, None] * w.t0[wr]
            + (sin_b[rep] * np.sin(phi))[:, None] * w.n0[wr]
        )
        origin = q[rep] + 1e-3 * w.bisector(wr)
        return pair[rep], origin, d

    # ------------------------------------------------------------------ exact paths
    def solve(self, cand_p: np.ndarray, rx_p: np.ndarray, rx: np.ndarray) -> list[PathBatch]:
        """Exact diffracted paths for (candidate, receiver) pairs, grouped by (len A, len B)."""
        c = self.candidates
        out = []
        nb = self.max_interactions
        key = c.pre_len[cand_p] * nb + c.post_len[cand_p]
        for k in np.unique(key):
            m = key == k
            out.append(self._solve_group(int(k // nb), int(k % nb), cand_p[m], rx_p[m], rx))
        return [b for b in out if len(b)]

    def _solve_group(self, a: int, b: int, cand_p: np.ndarray, rx_p: np.ndarray, rx: np.ndarray) -> PathBatch:
        c, w, refl = self.candidates, self.wedges, self.reflectors
        pre, post, wid = c.pre[cand_p, :a], c.post[cand_p, :b], c.wedge[cand_p]
        tx = self.tx
        src_imgs = mirror_chain(refl, tx, pre)
        s = src_imgs[:, -1] if a else np.broadcast_to(tx, (len(cand_p), 3))
        # Receiver's image through B reversed: the unfolded end of the path after Q.
        t = mirror_chain(refl, rx[rx_p], post[:, ::-1])[:, -1] if b else rx[rx_p]
        x, _ = keller_point(s, t, w.origin[wid], w.edge[wid])
        ok = (x >= 0.0) & (x <= w.length[wid])
        q = w.point(wid, np.where(ok, x, 0.0))
        k_in = q - s
        k_out = t - q
        s_in = np.linalg.norm(k_in, axis=1)
        s_out = np.linalg.norm(k_out, axis=1)
        k_in /= np.maximum(s_in, 1e-300)[:, None]
        k_out /= np.maximum(s_out, 1e-300)[:, None]
        # Rays along the edge have no Keller cone (UTD is singular there).
        ok &= np.abs(np.einsum("ij,ij->i", k_in, w.edge[wid])) < 1.0 - 1e-12
        # Both ends in the exterior region 0 < phi < n pi.
        nphi = w.n[wid] * np.pi
        phi_in = w.angle(wid, -k_in)
        phi_out = w.angle(wid, k_out)
        ok &= (phi_in > 0) & (phi_in < nphi) & (phi_out > 0) & (phi_out < nphi)
        sel = np.flatnonzero(ok)
        cand_p, rx_p, wid, q, k_in, k_out, s_in, s_out, pre, post = (
            v[sel] for v in (cand_p, rx_p, wid, q, k_in, k_out, s_in, s_out, pre, post)
        )
        src_imgs = src_imgs[sel]
        q_off = q + 1e-3 * w.bisector(wid)
        # Before Q: back from Q through the transmitter's images.
        alive, pts_a = self.solver.unfold(src_imgs, pre, q_off) if a else (np.arange(len(sel)), src_imgs)
        keep = np.zeros(len(sel), bool)
        keep[alive] = True
        pts_a_full = np.zeros((len(sel), a, 3))
        pts_a_full[alive] = pts_a
        # After Q: Q's images through B, back from the receiver.
        q_imgs = mirror_chain(refl, q, post)
        alive_b, pts_b = self.solver.unfold(q_imgs, post, rx[rx_p]) if b else (np.arange(len(sel)), q_imgs)
        keep_b = np.zeros(len(sel), bool)
        keep_b[alive_b] = True
        pts_b_full = np.zeros((len(sel), b, 3))
        pts_b_full[alive_b] = pts_b
        idx = np.flatnonzero(keep & keep_b)
        good_a, faces_a = self.solver.check(
            np.broadcast_to(self.tx, (len(idx), 3)), pts_a_full[idx], pre[idx], q_off[idx]
        )
        good_b, faces_b = self.solver.check(q_off[idx], pts_b_full[idx], post[idx], rx[rx_p[idx]])
        good = good_a & good_b
        idx = idx[good]
        faces_a, faces_b = faces_a[good], faces_b[good]
        m = len(idx)
        rx_p, wid, q = rx_p[idx], wid[idx], q[idx]
        s_in, s_out = s_in[idx], s_out[idx]
        pa, pb = pts_a_full[idx], pts_b_full[idx]
        points = np.concatenate([pa, q[:, None], pb], axis=1)
        faces = np.concatenate([faces_a, w.face0[wid][:, None], faces_b], axis=1)
        types = np.full((m, a + 1 + b), Interaction.REFLECTION, np.int8)
        types[:, a] = Interaction.DIFFRACTION
        nodes = np.concatenate([np.broadcast_to(self.tx, (m, 1, 3)), points, rx[rx_p][:, None]], axis=1)
        k_legs, _ = unit_legs(nodes)
        before = reflection_chain(k_legs[:, : a + 1], refl.normal[pre[idx]], faces_a, self.materials)
        after = reflection_chain(k_legs[:, a + 1 :], refl.normal[post[idx]], faces_b, self.materials)
        d = self._coefficient(wid, k_legs[:, a], k_legs[:, a + 1], s_in, s_out)
        jones, aod, aoa = antenna_jones(after @ d @ before, k_legs[:, 0], k_legs[:, -1])
        spread = self.materials.wavelength / (4.0 * np.pi * np.sqrt(s_in * s_out * (s_in + s_out)))
        jones *= spread[:, None, None]
        return PathBatch(rx_p, s_in + s_out, points, faces, types, jones, aod, aoa)

    def _coefficient(self, wid, k_in, k_out, s_in, s_out) -> np.ndarray:
        w = self.wedges
        return diffraction_matrices(
            k_in,
            k_out,
            w.edge[wid],
            w.t0[wid],
            w.n0[wid],
            w.tn[wid],
            w.nn[wid],
            s_in,
            s_out,
            self.materials.wavelength,
            self.materials.surface(w.face0[wid]),
            self.materials.surface(w.facen[wid]),
        )


def _distance_to_segment(
    p: np.ndarray, origin: np.ndarray, edge: np.ndarray, length: np.ndarray
) -> np.ndarray:
    x = np.clip(np.einsum("ij,ij->i", p - origin, edge), 0.0, length)
    return np.linalg.norm(p - origin - x[:, None] * edge, axis=1)


def _no_candidates(width: int) -> DiffractionCandidates:
    z = np.zeros(0, np.int64)
    return DiffractionCandidates(np.zeros((0, width), np.int64), z, np.zeros((0, width), np.int64), z, z)
