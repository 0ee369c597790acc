"""The tracer finds exactly the specular paths of a brute-force image method over all reflector sequences.

The reference below is independent of the tracer: its own plane grouping, exact
float64 point-in-triangle tests for the reflection points and exact
segment-triangle intersection for blockage (no Embree, no ray shooting).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import scenes
from mmwsim import Scene, SceneObject, Transmitter, get_material
from mmwsim.tracer import Tracer
from scenes.layout import Building, building_mesh, ground_mesh

# Shooting density of these tests (mean spacing 3.5 mrad); the library default is denser.
RAYS = 1_000_000


def _planes(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unoriented planes of the triangles: (normal, offset) per plane, plane of each face."""
    tri = scene.vertices[scene.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    flip = (n[:, 0] < -1e-9) | ((np.abs(n[:, 0]) <= 1e-9) & (n[:, 1] < -1e-9))
    flip |= (np.abs(n[:, 0]) <= 1e-9) & (np.abs(n[:, 1]) <= 1e-9) & (n[:, 2] < 0)
    n[flip] *= -1
    d = np.einsum("ij,ij->i", n, tri[:, 0])
    key = np.round(np.column_stack([n, d]), 6)
    uniq, face_plane = np.unique(key, axis=0, return_inverse=True)
    return uniq[:, :3], uniq[:, 3], face_plane.ravel()


def _segment_hits(a: np.ndarray, b: np.ndarray, tri: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """(m, F) whether the open segment a->b (m, 3) crosses triangle f (Moller-Trumbore, float64)."""
    d = b - a
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None, :], e2[None])
    det = np.einsum("mfi,fi->mf", p, e1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = a[:, None, :] - tri[None, :, 0]
    u = np.einsum("mfi,mfi->mf", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("mi,mfi->mf", d, q) * inv
    t = np.einsum("fi,mfi->mf", e2, q) * inv
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > tol) & (t < 1 - tol)


def _in_triangles(p: np.ndarray, tri: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """(m,) whether each point (on the triangles' plane) lies in any of the triangles (F, 3, 3)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    w = p[:, None, :] - tri[None, :, 0]
    d00, d01, d11 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    d20, d21 = np.einsum("mfi,fi->mf", w, e1), np.einsum("mfi,fi->mf", w, e2)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    u = (d00 * d21 - d01 * d20) / den
    return np.any((u >= -tol) & (v >= -tol) & (u + v <= 1 + tol), axis=1)


def brute_force(scene: Scene, tx: np.ndarray, rx: np.ndarray, kmax: int) -> dict:
    """{(rx index, plane sequence): length} of every valid specular path up to ``kmax`` reflections."""
    normal, offset, face_plane = _planes(scene)
    tri = scene.vertices[scene.faces]
    out = {}
    for i, r in enumerate(rx):
        if not _segment_hits(tx[None], r[None], tri).any():
            out[(i, ())] = float(np.linalg.norm(r - tx))
    for k in range(1, kmax + 1):
        seqs = [
            s
            for s in itertools.product(range(len(offset)), repeat=k)
            if all(a != b for a, b in itertools.pairwise(s))
        ]
        if not seqs:
            continue
        seqs = np.array(seqs)
        imgs = [np.broadcast_to(tx, (len(seqs), 3))]
        for j in range(k):
            n, d = normal[seqs[:, j]], offset[seqs[:, j]]
            prev = imgs[-1]
            imgs.append(prev - 2 * (np.einsum("si,si->s", prev, n) - d)[:, None] * n)
        si, ri = np.meshgrid(np.arange(len(seqs)), np.arange(len(rx)), indexing="ij")
        si, ri = si.ravel(), ri.ravel()
        ok = np.ones(len(si), bool)
        pts = np.zeros((len(si), k, 3))
        nxt = rx[ri]
        for j in range(k - 1, -1, -1):
            n, d = normal[seqs[si, j]], offset[seqs[si, j]]
            img = imgs[j + 1][si]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (d - np.einsum("mi,mi->m", n, nxt)) / np.einsum("mi,mi->m", n, img - nxt)
            ok &= (t > 0) & (t < 1)
            nxt = nxt + np.where(ok, t, 0.0)[:, None] * (img - nxt)
            pts[:, j] = nxt
            for pl in np.unique(seqs[si[ok], j]):
                m = ok & (seqs[si, j] == pl)
                ok[m] = _in_triangles(pts[m, j], tri[face_plane == pl])
        nodes = np.concatenate([np.broadcast_to(tx, (len(si), 1, 3)), pts, rx[ri][:, None]], axis=1)
        for j in range(k + 1):
            idx = np.flatnonzero(ok)
            ok[idx] = ~_segment_hits(nodes[idx, j], nodes[idx, j + 1], tri).any(axis=1)
        for m in np.flatnonzero(ok):
            out[(int(ri[m]), tuple(int(p) for p in seqs[si[m]]))] = float(
                np.linalg.norm(rx[ri[m]] - imgs[k][si[m]])
            )
    return out


def traced(scene: Scene, tx: np.ndarray, rx: np.ndarray, kmax: int) -> dict:
    _, _, face_plane = _planes(scene)
    paths = Tracer(scene, tx, kmax, RAYS, diffraction=False, min_gain_db=None).trace(rx)
    out = {}
    for i in range(paths.n_paths):
        f = paths.faces[i, : paths.order[i]]
        key = (int(paths.rx_index[i]), tuple(int(face_plane[x]) for x in f))
        assert key not in out, f"path counted twice: {key}"
        out[key] = float(paths.length[i])
    return out


def tiny_city() -> Scene:
    concrete = get_material("concrete")
    blocks = [
        Building(10, 10, 30, 25, 15.0),
        Building(30, 10, 45, 25, 15.0),  # shares a wall plane and facades with the first
        Building(55, 5, 70, 30, 25.0),
        Building(10, 40, 40, 55, 8.0),  # lower than the transmitter: its roof reflects
    ]
    objects = [SceneObject("ground", ground_mesh(-20, -20, 100, 80), concrete, "ground")]
    objects += [SceneObject(f"b{i}", building_mesh([b]), concrete) for i, b in enumerate(blocks)]
    return Scene(objects, Transmitter((50.0, 34.0, 10.0)), name="tiny_city")


def _compare(scene: Scene, tx, rx, kmax: int) -> None:
    tx = np.asarray(tx, float)
    ref = brute_force(scene, tx, rx, kmax)
    got = traced(scene, tx, rx, kmax)
    # more paths than receivers: the reference holds reflections, so the comparison is not vacuous
    assert len(ref) > len(rx), f"the reference found only {len(ref)} paths"
    missed = sorted(set(ref) - set(got))
    extra = sorted(set(got) - set(ref))
    assert not missed, f"{len(missed)} paths missed, e.g. {missed[:5]}"
    assert not extra, f"{len(extra)} paths not in the reference, e.g. {extra[:5]}"
    for key, length in ref.items():
        assert got[key] == pytest.approx(length, abs=1e-9)


@pytest.mark.parametrize("name", ["ground_only", "ground_wall", "street_canyon", "corner_reflector"])
def test_canonical_scenes_match_brute_force(name):
    scene = scenes.load(name)
    rx = scene.receivers.positions()[::3]
    _compare(scene, scene.transmitter.array, rx, 3)


def test_street_canyon_path_counts():
    scene = scenes.load("street_canyon")
    rx = np.array([[30.0, 3.0, 1.5], [-60.0, -7.0, 1.5]])
    ref = brute_force(scene, scene.transmitter.array, rx, 3)
    counts = np.bincount([k[0] for k in ref], minlength=2)
    # Two walls and a ground: 1 + 3 + 4 + 4 paths of orders 0..3 reach each of these receivers.
    assert counts.tolist() == [12, 12]
    got = Tracer(scene, None, 3, RAYS, diffraction=False, min_gain_db=None).trace(rx)
    assert got.count().tolist() == [12, 12]
    assert np.bincount(got.order, minlength=4).tolist() == [2, 6, 8, 8]


def test_tiny_city_matches_brute_force():
    scene = tiny_city()
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-15, 95, 400), rng.uniform(-15, 75, 400), np.full(400, 1.5)])
    rx = pts[scene.outdoors(pts)][:60]
    _compare(scene, scene.transmitter.array, rx, 3)
