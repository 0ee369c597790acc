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

from .._jit import njit
from ..stages import STAGES
from ._vec import add, dot, mirror, norm, row, scale, sub
from .cells import CandidateCells, CellLattice, LegSet, mark_cells
from .paths import Interaction
from .polarimetry import FaceMaterials, PathBatch
from .reflectors import Reflectors
from .shooting import bounce, sequence_ids
from .specular import SpecularSolver, inside_box, mirror_chain, plane_point
from .utd import ON_BOUNDARY
from .visibility import EPS
from .wedges import Wedges

__all__ = ["DiffractionStage", "DiffractionCandidates", "CONE_STEP", "BOUNDARIES"]

BOUNDARIES = ("none", "incident +", "incident -", "0-face reflection", "n-face reflection")
"""Shadow boundaries a diffracted ray may lie exactly on: incident (phi = phi' +- pi), 0-face
reflection (phi = pi - phi') and n-face reflection (phi = (2n - 1) pi - phi')."""
# Side of each boundary where its geometrical-optics partner exists: -1 at smaller phi, +1 at larger.
LIT_SIDE = np.array([0.0, -1.0, 1.0, -1.0, 1.0])

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
        self._src_imgs: np.ndarray | None = None

    # ------------------------------------------------------------------ candidates
    def cells(self, lattice: CellLattice) -> CandidateCells:
        """Receiver cells of every candidate (launches the cone rays once per lattice)."""
        if lattice not in self._cells:
            with STAGES("diffraction candidates"):
                cands, legs = self._launch()
            if self.candidates is None:
                self.candidates = cands
            with STAGES("candidate cells"):
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
            level = sequence_ids(tables[0], parents[0], ray_pair)
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
                if kb + 1 == nb:
                    break
                # Rays whose lit pair allows no more reflections end here.
                face = np.where(kb < b_max[ray_pair], face, -1)
                keep, ref, origin, dirs, unfolded = bounce(
                    origin,
                    dirs,
                    t,
                    face,
                    self.reflectors.face_reflector,
                    self.reflectors.normal,
                    last,
                    unfolded,
                )
                if not len(keep):
                    break
                ray_pair, level = ray_pair[keep], level[keep]
                level = sequence_ids(tables[kb + 1], parents[kb + 1], level * n_ref + ref)
                last = ref
        sizes = [len(p) for p in parents]
        legs = LegSet.concatenate(leg_parts)
        offset = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        legs.cand = offset[legs.cand % nb] + legs.cand // nb
        return self._table(parents, n_ref), legs

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
        end = q + EPS * self.wedges.bisector(wid)
        out = np.zeros(len(q), bool)
        for a in np.unique(order):
            m = np.flatnonzero(order == a)
            seqs = self.pre_sequences[a]
            images = mirror_chain(self.reflectors, self.tx, seqs)
            out[m] = self.solver.reach(self.tx, seqs, images, seq[m], end[m])
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
        """Exact diffracted paths for (candidate, receiver) pairs, grouped by interaction count."""
        c, w, refl = self.candidates, self.wedges, self.reflectors
        width = c.pre.shape[1]
        if self._src_imgs is None:
            self._src_imgs = np.zeros((len(c), max(width, 1), 3))
            for a in range(1, width + 1):
                m = c.pre_len == a
                if m.any():
                    self._src_imgs[m, :a] = mirror_chain(refl, self.tx, c.pre[m, :a])
        k = self.max_interactions
        ok = np.zeros(len(cand_p), bool)
        points = np.zeros((len(cand_p), k, 3))
        length = np.zeros(len(cand_p))
        boundary = np.zeros(len(cand_p), np.int8)
        _geometry(
            cand_p, rx_p, rx, self.tx, c.pre, c.post, c.pre_len, c.post_len, c.wedge, self._src_imgs,
            w.origin, w.edge, w.length, w.t0, w.n0, w.n, refl.normal, refl.offset, refl.lo, refl.hi,
            ok, points, length, boundary,
        )  # fmt: skip
        idx = np.flatnonzero(ok)
        cand_p, rx_p, points, length, boundary = (
            cand_p[idx],
            rx_p[idx],
            points[idx],
            length[idx],
            boundary[idx],
        )
        a_len, b_len, wid = c.pre_len[cand_p], c.post_len[cand_p], c.wedge[cand_p]
        order = a_len + 1 + b_len
        n = len(idx)
        cols = np.arange(k)[None, :]
        types = np.where(cols < order[:, None], Interaction.REFLECTION, Interaction.NONE).astype(np.int8)
        types[np.arange(n), a_len] = Interaction.DIFFRACTION
        # Reflector of every reflection: A's before the diffraction, B's after it.
        pre = (
            np.take_along_axis(c.pre[cand_p], np.minimum(cols, max(width - 1, 0)), axis=1) if width else None
        )
        after = np.clip(cols - a_len[:, None] - 1, 0, max(width - 1, 0))
        post = np.take_along_axis(c.post[cand_p], after, axis=1) if width else None
        refs = np.where(cols < a_len[:, None], pre, post) if width else np.zeros((n, k), np.int64)
        refs = np.where(types == Interaction.REFLECTION, refs, -1)
        offsets = w.bisector(wid)
        good, faces = self.solver.check(self.tx, rx[rx_p], points, order, types, refs, offsets)
        g = np.flatnonzero(good)
        faces, wid, a_len, points, order = faces[g], wid[g], a_len[g], points[g], order[g]
        faces[np.arange(len(g)), a_len] = w.face0[wid]
        return self.solver.finish(
            self.tx, rx, rx_p[g], length[g], points, order, types[g], faces, wid, w, boundary[g]
        )


@njit(cache=True)
def _geometry(
    cand_p, rx_p, rx, tx, pre, post, pre_len, post_len, wedge, src_imgs,
    w_origin, w_edge, w_length, w_t0, w_n0, w_n, normal, offset, lo, hi,
    ok, points, length, boundary,
):  # pragma: no cover - compiled  # fmt: skip
    """Diffraction point and reflection points of every (candidate, receiver) pair.

    Sets ``ok`` where the diffraction point lies on the edge, both ends are in the wedge's
    exterior, and every reflection point lies inside its segment and its reflector's
    bounds; ``points`` gets [reflections before, Q, reflections after] and ``length`` the
    unfolded length, ``boundary`` the :data:`BOUNDARIES` code of a shadow boundary the
    diffracted ray lies exactly on. Blockage is checked afterwards with Embree.
    """
    t = (float(tx[0]), float(tx[1]), float(tx[2]))
    for i in range(len(cand_p)):
        c = cand_p[i]
        a = pre_len[c]
        b = post_len[c]
        w = wedge[c]
        s = row(src_imgs[c], a - 1) if a else t
        # The receiver's image through B reversed: the unfolded end after Q.
        end = row(rx, rx_p[i])
        img = end
        for j in range(b - 1, -1, -1):
            r = post[c, j]
            img = mirror(img, row(normal, r), offset[r])
        o = row(w_origin, w)
        e = row(w_edge, w)
        so = sub(s, o)
        to = sub(img, o)
        sz = dot(so, e)
        tz = dot(to, e)
        da = norm(sub(so, scale(e, sz)))
        db = norm(sub(to, scale(e, tz)))
        if not (da + db > 0.0):
            continue
        x = (db * sz + da * tz) / (da + db)
        if not (0.0 <= x <= w_length[w]):
            continue
        q = add(o, scale(e, x))
        v_in = sub(q, s)
        v_out = sub(img, q)
        s_in = norm(v_in)
        s_out = norm(v_out)
        if not (s_in > 0.0 and s_out > 0.0):
            continue
        if abs(dot(v_in, e)) >= (1.0 - 1e-12) * s_in:
            continue  # along the edge: no Keller cone
        # Both ends in the exterior region 0 < phi < n pi.
        nphi = w_n[w] * np.pi
        t0 = row(w_t0, w)
        n0 = row(w_n0, w)
        phi_in = np.arctan2(-dot(v_in, n0), -dot(v_in, t0)) % (2.0 * np.pi)
        phi_out = np.arctan2(dot(v_out, n0), dot(v_out, t0)) % (2.0 * np.pi)
        if not (0.0 < phi_in < nphi and 0.0 < phi_out < nphi):
            continue
        good = True
        # Reflections before Q: back from Q through the transmitter's images.
        nxt = q
        for j in range(a - 1, -1, -1):
            r = pre[c, j]
            im = row(src_imgs[c], j)
            p = plane_point(nxt, im, row(normal, r), offset[r])
            if not inside_box(p, lo, hi, r):
                good = False
                break
            points[i, j, 0], points[i, j, 1], points[i, j, 2] = p
            nxt = p
        if not good:
            continue
        points[i, a, 0], points[i, a, 1], points[i, a, 2] = q
        # Reflections after Q: back from the receiver through Q's images.
        qim = q
        for j in range(b):
            r = post[c, j]
            qim = mirror(qim, row(normal, r), offset[r])
            points[i, a + 1 + j, 0], points[i, a + 1 + j, 1], points[i, a + 1 + j, 2] = qim
        nxt = end
        for j in range(b - 1, -1, -1):
            r = post[c, j]
            im = row(points[i], a + 1 + j)
            p = plane_point(nxt, im, row(normal, r), offset[r])
            if not inside_box(p, lo, hi, r):
                good = False
                break
            points[i, a + 1 + j, 0], points[i, a + 1 + j, 1], points[i, a + 1 + j, 2] = p
            nxt = p
        if not good:
            continue
        ok[i] = True
        length[i] = s_in + s_out
        for code in range(1, 5):
            if code == 1:
                eps = phi_out - phi_in - np.pi
            elif code == 2:
                eps = phi_out - phi_in + np.pi
            elif code == 3:
                eps = phi_out + phi_in - np.pi
            else:
                eps = phi_out + phi_in - (2.0 * w_n[w] - 1.0) * np.pi
            if abs(eps) <= ON_BOUNDARY:
                boundary[i] = code
                break


def _distance_to_segment(
    p: np.ndarray, origin: np.ndarray, edge: np.ndarray, length: np.ndarray
) -> np.ndarray:
    x = np.clip(np.einsum("ij,ij->i", p - origin, edge), 0.0, length)
    return np.linalg.norm(p - origin - x[:, None] * edge, axis=1)


def _no_candidates(width: int) -> DiffractionCandidates:
    z = np.zeros(0, np.int64)
    return DiffractionCandidates(np.zeros((0, width), np.int64), z, np.zeros((0, width), np.int64), z, z)
