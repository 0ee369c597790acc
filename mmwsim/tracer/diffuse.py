"""Diffuse scattering as the last interaction of a path, from surfaces of scattering coefficient S > 0.

A diffusely scattered contribution is ``TX -A-> tile -> RX``: specular reflections A (none
or up to ``max_interactions - 1``) then one surface tile that scatters by the effective-
roughness model of :mod:`.scattering`. Tiles are not fixed in advance: each rough triangle
lit through A is split adaptively for each receiver, halving its edges (into four) until a
patch is smaller than ``1 / quality`` of its distance to the source image and to the
receiver, so tiles near either end are small and distant ones coarse; only the triangles a
receiver sees at all (found by :data:`VIEW_RAYS` rays cast from it) are split. Every patch whose
centre sees the source (through A, exactly, by the image method) and the receiver adds one
contribution; its power is ``(lambda / 4 pi)^2 (S Gamma)^2 f_s cos(theta_i) dA / (r_i r_s)^2``
split into a co- and a cross-polarised part, both kept as paths of kind DIFFUSE whose
powers the profiles add (their phases are random, so they never add coherently).

Which triangles are lit through which sequences A comes from the shooting stage (the faces
the rays hit after following A), as for the wedges of :mod:`.diffraction`.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from .paths import Interaction
from .polarimetry import FaceMaterials, PathBatch, antenna_jones, reflection_chain, spectral_norm, unit_legs
from .reflectors import Reflectors
from .scattering import diffuse_matrices
from .shooting import fibonacci_directions
from .specular import SpecularSolver, mirror_chain
from .visibility import EPS

__all__ = ["DiffuseStage", "QUALITY", "VIEW_RAYS"]

QUALITY = 3.0
"""Patches are split until their longest edge is below distance / QUALITY (to source and receiver)."""
VIEW_RAYS = 8192
"""Rays from each receiver over the sphere (mean spacing 2.2 deg) that find the triangles it sees;
only those are split into patches (a triangle seen only through a gap narrower than the ray
spacing is missed)."""
_MAX_DEPTH = 12  # halvings of a triangle's edges at most (4^12 patches)
_ITEM_BATCH = 1 << 18  # (patch, receiver) contributions handled at once
_RX_BATCH = 16  # receivers whose patches are generated at once


class DiffuseStage:
    """Diffuse contributions from the rough triangles lit by the transmitter (directly or via reflections).

    Parameters
    ----------
    scene : Scene
    reflectors : Reflectors
    solver : SpecularSolver
    materials : FaceMaterials
    tx : (3,) float64
    max_interactions : int
        Interactions per path, the diffuse scattering included.
    pre_sequences : list of (n_k, k) int64
        Reflector sequences of the shooting stage by order.
    lit : (l, 3) int64
        (order of A, index of A, rough triangle) pairs whose rays hit the triangle.
    quality : float
        Patch size over distance (see :data:`QUALITY`).
    view_rays : int
        Rays cast from each receiver to find the triangles it sees at all (:data:`VIEW_RAYS`).
    """

    def __init__(
        self,
        scene,
        reflectors: Reflectors,
        solver: SpecularSolver,
        materials: FaceMaterials,
        tx: np.ndarray,
        max_interactions: int,
        pre_sequences: list[np.ndarray],
        lit: np.ndarray,
        quality: float = QUALITY,
        view_rays: int = VIEW_RAYS,
    ):
        self.reflectors = reflectors
        self.solver = solver
        self.materials = materials
        self.tx = np.asarray(tx, dtype=np.float64)
        self.max_interactions = int(max_interactions)
        self.pre_sequences = pre_sequences
        self.lit = lit
        self.quality = float(quality)
        self.view_rays = int(view_rays)
        self.triangles = np.ascontiguousarray(scene.vertices[scene.faces])
        self.normals = np.ascontiguousarray(scene.face_normals)
        # Source image of every lit pair, and the images after each prefix of its sequence.
        width = max(self.max_interactions - 1, 1)
        self._imgs = np.zeros((len(lit), width, 3))
        self._src = np.broadcast_to(self.tx, (len(lit), 3)).copy()
        for a in np.unique(lit[:, 0]) if len(lit) else []:
            if a == 0:
                continue
            m = lit[:, 0] == a
            imgs = mirror_chain(reflectors, self.tx, pre_sequences[a][lit[m, 1]])
            self._imgs[m, :a] = imgs
            self._src[m] = imgs[:, -1]

    def solve(self, rx: np.ndarray) -> list[PathBatch]:
        """Every diffuse contribution to receivers ``rx`` (n, 3), as co- and cross-polar paths."""
        if not len(self.lit) or not len(rx):
            return []
        rx = np.ascontiguousarray(rx, np.float64)
        out = []
        views = fibonacci_directions(self.view_rays)
        # A few receivers at a time: each may see thousands of patches.
        for r0 in range(0, len(rx), _RX_BATCH):
            chunk = rx[r0 : r0 + _RX_BATCH]
            # Triangles each receiver sees at all (one of its view rays ends on them).
            _, hit = self.solver.caster.intersect(
                np.repeat(chunk, len(views), axis=0), np.tile(views, (len(chunk), 1))
            )
            self.solver.rays_cast += len(hit)
            seen = np.zeros((len(chunk), len(self.normals)), np.bool_)
            rows = np.repeat(np.arange(len(chunk)), len(views))
            seen[rows[hit >= 0], hit[hit >= 0]] = True
            pair, rx_i, centre, area = _patches(
                self._src, self.lit[:, 2], chunk, seen, self.triangles, self.normals, self.quality, _MAX_DEPTH,
            )  # fmt: skip
            rx_i += r0
            for a in range(0, len(pair), _ITEM_BATCH):
                sl = slice(a, a + _ITEM_BATCH)
                out += self._contributions(pair[sl], rx_i[sl], centre[sl], area[sl], rx)
        return out

    def _contributions(self, pair, rx_i, centre, area, rx) -> list[PathBatch]:
        lit, refl = self.lit, self.reflectors
        face = lit[pair, 2]
        a_len = lit[pair, 0]
        normal = self.normals[face]
        # Orient each normal towards the source: the side that is lit.
        normal = normal * np.sign(np.einsum("ij,ij->i", self._src[pair] - centre, normal))[:, None]
        lifted = centre + EPS * normal
        # The receiver sees the patch, and the source reaches it through A exactly.
        v = rx[rx_i] - lifted
        dist = np.linalg.norm(v, axis=1)
        ok = ~self.solver.caster.occluded(lifted, v / dist[:, None], dist - EPS)
        self.solver.rays_cast += len(v)
        batches = []
        for a in np.unique(a_len[ok]):
            m = np.flatnonzero(ok & (a_len == a))
            seqs = self.pre_sequences[a]
            seq = lit[pair[m], 1]
            reach, points = self.solver.reach(
                self.tx, seqs, mirror_chain(refl, self.tx, seqs), seq, lifted[m], True
            )
            m, points = m[reach], points[reach]
            if len(m):
                batches += self._fields(
                    m, a, seqs[lit[pair[m], 1]], points, face, normal, centre, area, rx_i, rx
                )
        return batches

    def _fields(self, m, a, refs, points, face, normal, centre, area, rx_i, rx) -> list[PathBatch]:
        c = centre[m]
        nodes = np.concatenate(
            [np.broadcast_to(self.tx, (len(m), 1, 3)), points, c[:, None], rx[rx_i[m]][:, None]], axis=1
        )
        k_legs, legs = unit_legs(nodes)
        faces_a = self._faces_of(refs, points)
        before = reflection_chain(k_legs[:, : a + 1], self.reflectors.normal[refs], faces_a, self.materials)
        surf = self.materials.surface(face[m])
        obj = self.materials.owner[face[m]]
        co, cross = diffuse_matrices(
            k_legs[:, a], k_legs[:, a + 1], normal[m], surf, surf.roughness,
            self.materials.xpd[obj], self.materials.pattern[obj], self.materials.alpha_r[obj], area[m],
            self.materials.wavelength,
        )  # fmt: skip
        r_i = legs[:, : a + 1].sum(axis=1)
        r_s = legs[:, a + 1]
        spread = self.materials.wavelength / (4.0 * np.pi * r_i * r_s)
        points_all = np.concatenate([points, c[:, None]], axis=1)
        faces = np.concatenate([faces_a, face[m][:, None]], axis=1)
        types = np.full(faces.shape, Interaction.REFLECTION, np.int8)
        types[:, a] = Interaction.DIFFUSE
        out = []
        for part in (co, cross):
            jones, aod, aoa = antenna_jones(part @ before, k_legs[:, 0], k_legs[:, -1])
            jones *= spread[:, None, None]
            keep = (
                spectral_norm(jones) >= self.solver.floor if self.solver.floor > 0 else np.ones(len(m), bool)
            )
            out.append(
                PathBatch(
                    rx_i[m][keep], (r_i + r_s)[keep], points_all[keep], faces[keep], types[keep], jones[keep],
                    aod[keep], aoa[keep],
                )
            )  # fmt: skip
        return [b for b in out if len(b)]

    def _faces_of(self, refs: np.ndarray, points: np.ndarray) -> np.ndarray:
        """A triangle of each reflection (the materials of one reflector's triangles may differ)."""
        if not refs.shape[1]:
            return np.zeros((len(refs), 0), np.int64)
        _, f = self.solver.caster.intersect(
            points.reshape(-1, 3) + 0.5 * EPS * self.reflectors.normal[refs].reshape(-1, 3),
            -self.reflectors.normal[refs].reshape(-1, 3),
        )
        f2 = f.reshape(refs.shape)
        miss = f2 < 0
        if miss.any():  # from the other side of a thin wall
            _, g = self.solver.caster.intersect(
                points.reshape(-1, 3) - 0.5 * EPS * self.reflectors.normal[refs].reshape(-1, 3),
                self.reflectors.normal[refs].reshape(-1, 3),
            )
            f2 = np.where(miss, g.reshape(refs.shape), f2)
        return np.maximum(f2, 0)


@njit(cache=True)
def _patches(src, face, rx, seen, tri, normal, quality, max_depth):  # pragma: no cover - compiled
    """Adaptive patches of the lit triangles, per receiver on their lit side.

    For every (lit pair p, receiver r) with the receiver in front of the triangle (on the
    side of the pair's source image) and the triangle among those it sees (``seen[r, f]``),
    the triangle is split into four (edge midpoints)
    until each patch's longest edge is at most a ``1 / quality`` of its distance to the
    source and to the receiver. Returns (pair, receiver, centre (n, 3), area) per patch.
    """
    cap = 1 << 16
    out_p = np.empty(cap, np.int64)
    out_r = np.empty(cap, np.int64)
    out_c = np.empty((cap, 3))
    out_a = np.empty(cap)
    n = 0
    stack = np.empty((4 * max_depth + 4, 10))
    for p in range(len(face)):
        f = face[p]
        nx, ny, nz = normal[f, 0], normal[f, 1], normal[f, 2]
        v0x, v0y, v0z = tri[f, 0, 0], tri[f, 0, 1], tri[f, 0, 2]
        side = (src[p, 0] - v0x) * nx + (src[p, 1] - v0y) * ny + (src[p, 2] - v0z) * nz
        if side == 0.0:
            continue
        for r in range(len(rx)):
            if not seen[r, f]:
                continue
            front = (rx[r, 0] - v0x) * nx + (rx[r, 1] - v0y) * ny + (rx[r, 2] - v0z) * nz
            if front * side <= 0.0:
                continue
            top = 0
            for k in range(3):
                for a in range(3):
                    stack[0, 3 * k + a] = tri[f, k, a]
            stack[0, 9] = 0.0
            top = 1
            while top:
                top -= 1
                s = stack[top].copy()
                cx = (s[0] + s[3] + s[6]) / 3.0
                cy = (s[1] + s[4] + s[7]) / 3.0
                cz = (s[2] + s[5] + s[8]) / 3.0
                e = 0.0
                for i, j in ((0, 3), (3, 6), (6, 0)):
                    dd = (s[i] - s[j]) ** 2 + (s[i + 1] - s[j + 1]) ** 2 + (s[i + 2] - s[j + 2]) ** 2
                    e = max(e, dd)
                ds = (cx - src[p, 0]) ** 2 + (cy - src[p, 1]) ** 2 + (cz - src[p, 2]) ** 2
                dr = (cx - rx[r, 0]) ** 2 + (cy - rx[r, 1]) ** 2 + (cz - rx[r, 2]) ** 2
                if e * quality * quality > min(ds, dr) and s[9] < max_depth:
                    m01 = 0.5 * (s[0:3] + s[3:6])
                    m12 = 0.5 * (s[3:6] + s[6:9])
                    m20 = 0.5 * (s[6:9] + s[0:3])
                    for child in range(4):
                        if child == 0:
                            a0, a1, a2 = s[0:3], m01, m20
                        elif child == 1:
                            a0, a1, a2 = m01, s[3:6], m12
                        elif child == 2:
                            a0, a1, a2 = m20, m12, s[6:9]
                        else:
                            a0, a1, a2 = m01, m12, m20
                        stack[top, 0:3] = a0
                        stack[top, 3:6] = a1
                        stack[top, 6:9] = a2
                        stack[top, 9] = s[9] + 1.0
                        top += 1
                    continue
                ux, uy, uz = s[3] - s[0], s[4] - s[1], s[5] - s[2]
                wx, wy, wz = s[6] - s[0], s[7] - s[1], s[8] - s[2]
                cxp = uy * wz - uz * wy
                cyp = uz * wx - ux * wz
                czp = ux * wy - uy * wx
                if n == len(out_p):
                    out_p = _grow_i(out_p, n)
                    out_r = _grow_i(out_r, n)
                    out_c = _grow_c(out_c, n)
                    out_a = _grow_f(out_a, n)
                out_p[n] = p
                out_r[n] = r
                out_c[n, 0], out_c[n, 1], out_c[n, 2] = cx, cy, cz
                out_a[n] = 0.5 * np.sqrt(cxp * cxp + cyp * cyp + czp * czp)
                n += 1
    return out_p[:n].copy(), out_r[:n].copy(), out_c[:n].copy(), out_a[:n].copy()


@njit(cache=True)
def _grow_i(a, n):  # pragma: no cover - compiled
    b = np.empty(2 * len(a), a.dtype)
    b[:n] = a[:n]
    return b


@njit(cache=True)
def _grow_f(a, n):  # pragma: no cover - compiled
    b = np.empty(2 * len(a))
    b[:n] = a[:n]
    return b


@njit(cache=True)
def _grow_c(a, n):  # pragma: no cover - compiled
    b = np.empty((2 * len(a), 3))
    b[:n] = a[:n]
    return b
