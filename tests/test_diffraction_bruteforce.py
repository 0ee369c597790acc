"""The tracer finds every singly diffracted path that a brute-force enumeration finds.

The reference enumerates every (reflector planes before, wedge, reflector planes after)
combination up to the interaction budget, independently of the tracer's ray search:
the diffraction point by bisection on the path length along the edge (the path is
shortest where Keller's law holds), reflection points by unfolding, reflection points
checked to lie in their triangles and every leg checked against every triangle with
exact float64 segment-triangle tests (no Embree, no ray shooting). Only the wedge table
is shared (it is tested on its own in test_wedges.py).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from mmwsim import Scene, SceneObject, Transmitter, get_material
from mmwsim.tracer import Interaction, Tracer
from mmwsim.tracer.wedges import find_wedges
from scenes.layout import Building, building_mesh, ground_mesh
from tests.test_tracer_bruteforce import _in_triangles, _planes, _segment_hits, tiny_city

RAYS = 1_000_000


def _mirror(p: np.ndarray, n: np.ndarray, d: np.ndarray) -> np.ndarray:
    return p - 2.0 * (np.einsum("mi,mi->m", p, n) - d)[:, None] * n


def _diffraction_point(s, t, o, e, length, iters: int = 80):
    """Minimiser x in (0, length) of |s - q(x)| + |q(x) - t| on the edge line; NaN if at an end."""
    lo = np.zeros(len(s))
    hi = np.broadcast_to(length, len(s)).astype(float).copy()

    def slope(x):
        q = o + x[:, None] * e
        a, b = q - s, q - t
        return np.einsum("mi,mi->m", a, e) / np.linalg.norm(a, axis=1) + np.einsum(
            "mi,mi->m", b, e
        ) / np.linalg.norm(b, axis=1)

    # The length is convex in x: its slope increases; the minimiser is interior iff the slope changes sign.
    interior = (slope(lo) < 0) & (slope(hi) > 0)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        neg = slope(mid) < 0
        lo = np.where(neg, mid, lo)
        hi = np.where(neg, hi, mid)
    return np.where(interior, 0.5 * (lo + hi), np.nan)


def _exterior(u: np.ndarray, t0, n0, nphi) -> np.ndarray:
    phi = np.mod(np.arctan2(np.einsum("mi,mi->m", u, n0), np.einsum("mi,mi->m", u, t0)), 2 * np.pi)
    return (phi > 1e-9) & (phi < nphi - 1e-9)


def brute_force(scene: Scene, tx: np.ndarray, rx: np.ndarray, kmax: int) -> dict:
    """{(rx, planes before, diffraction point rounded to 1 um, planes after): length} of every valid path."""
    normal, offset, face_plane = _planes(scene)
    tri = scene.vertices[scene.faces]
    w = find_wedges(scene)
    # Every (wedge, receiver) pair at once.
    wi = np.repeat(np.arange(w.count), len(rx))
    ri = np.tile(np.arange(len(rx)), w.count)
    out = {}

    def seqs(k):
        return itertools.product(range(len(offset)), repeat=k)

    for a in range(kmax):
        for b in range(kmax - a):
            for pre in seqs(a):
                for post in seqs(b):
                    if all(x != y for x, y in itertools.pairwise(pre)) and all(
                        x != y for x, y in itertools.pairwise(post)
                    ):
                        _one(out, tri, normal, offset, face_plane, w, wi, ri, tx, rx, pre, post)
    return out


def _one(out, tri, normal, offset, face_plane, w, wi, ri, tx, rx, pre, post):
    m = len(wi)
    s = np.broadcast_to(tx, (m, 3)).copy()
    src_imgs = [s]
    for p in pre:
        s = _mirror(s, np.broadcast_to(normal[p], (m, 3)), offset[p])
        src_imgs.append(s)
    t = rx[ri]
    for p in post[::-1]:
        t = _mirror(t, np.broadcast_to(normal[p], (m, 3)), offset[p])
    o, e = w.origin[wi], w.edge[wi]
    x = _diffraction_point(s, t, o, e, w.length[wi])
    ok = np.isfinite(x)
    q = o + np.where(ok, x, 0.0)[:, None] * e
    ok &= _exterior(s - q, w.t0[wi], w.n0[wi], w.n[wi] * np.pi)
    ok &= _exterior(t - q, w.t0[wi], w.n0[wi], w.n[wi] * np.pi)
    # Reflection points before Q, back from Q through the source images.
    pts_a = np.zeros((m, len(pre), 3))
    nxt = q
    for j in range(len(pre) - 1, -1, -1):
        n, d = normal[pre[j]], offset[pre[j]]
        img = src_imgs[j + 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = (d - nxt @ n) / ((img - nxt) @ n)
        ok &= (tt > 0) & (tt < 1)
        nxt = nxt + np.where(ok, tt, 0.0)[:, None] * (img - nxt)
        pts_a[:, j] = nxt
        ok[ok] = _in_triangles(nxt[ok], tri[face_plane == pre[j]])
    # Reflection points after Q, forward through Q's images.
    q_imgs = [q]
    for p in post:
        q_imgs.append(_mirror(q_imgs[-1], np.broadcast_to(normal[p], (m, 3)), offset[p]))
    pts_b = np.zeros((m, len(post), 3))
    nxt = rx[ri]
    for j in range(len(post) - 1, -1, -1):
        n, d = normal[post[j]], offset[post[j]]
        img = q_imgs[j + 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = (d - nxt @ n) / ((img - nxt) @ n)
        ok &= (tt > 0) & (tt < 1)
        nxt = nxt + np.where(ok, tt, 0.0)[:, None] * (img - nxt)
        pts_b[:, j] = nxt
        ok[ok] = _in_triangles(nxt[ok], tri[face_plane == post[j]])
    nodes = np.concatenate(
        [np.broadcast_to(tx, (m, 1, 3)), pts_a, q[:, None], pts_b, rx[ri][:, None]], axis=1
    )
    for j in range(nodes.shape[1] - 1):
        idx = np.flatnonzero(ok)
        if not len(idx):
            return
        ok[idx] = ~_segment_hits(nodes[idx, j], nodes[idx, j + 1], tri).any(axis=1)
    for i in np.flatnonzero(ok):
        key = (int(ri[i]), tuple(pre), tuple(np.round(q[i], 6)), tuple(post))
        out[key] = float(np.linalg.norm(s[i] - q[i]) + np.linalg.norm(q[i] - t[i]))


def traced(scene: Scene, tx: np.ndarray, rx: np.ndarray, kmax: int) -> dict:
    _, _, face_plane = _planes(scene)
    paths = Tracer(scene, tx, kmax, RAYS, min_gain_db=None).trace(rx)
    out = {}
    for i in np.flatnonzero(paths.kind() == 2):
        k = paths.order[i]
        types = paths.types[i, :k]
        j = int(np.flatnonzero(types == Interaction.DIFFRACTION)[0])
        planes = [int(face_plane[f]) for f in paths.faces[i, :k]]
        key = (
            int(paths.rx_index[i]),
            tuple(planes[:j]),
            tuple(np.round(paths.points[i, j], 6)),
            tuple(planes[j + 1 :]),
        )
        assert key not in out, f"path counted twice: {key}"
        out[key] = float(paths.length[i])
    return out


def _compare(scene: Scene, rx: np.ndarray, kmax: int) -> int:
    tx = scene.transmitter.array
    ref = brute_force(scene, tx, rx, kmax)
    got = traced(scene, tx, rx, kmax)
    assert ref, "the reference found no path: the comparison would pass vacuously"
    missed = sorted(set(ref) - set(got))
    extra = sorted(set(got) - set(ref))
    assert not missed, f"{len(missed)} of {len(ref)} paths missed, e.g. {missed[:3]}"
    assert not extra, f"{len(extra)} paths not in the reference, e.g. {extra[:3]}"
    for key, length in ref.items():
        assert got[key] == pytest.approx(length, abs=1e-9)
    return len(ref)


def corner_scene() -> Scene:
    """One 20 m building on the ground, the transmitter off one corner."""
    concrete = get_material("concrete")
    objects = [
        SceneObject("ground", ground_mesh(-60, -60, 60, 60), concrete, "ground"),
        SceneObject("block", building_mesh([Building(0, 0, 20, 15, 20.0)]), concrete),
    ]
    return Scene(objects, Transmitter((-15.0, -10.0, 10.0)), name="corner")


def test_single_building_matches_brute_force():
    scene = corner_scene()
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-55, 55, 120), rng.uniform(-55, 55, 120), np.full(120, 1.5)])
    rx = pts[scene.outdoors(pts)]
    n = _compare(scene, rx, 3)
    assert n > 200  # both the lit and the shadow region hold diffracted paths


def test_tiny_city_matches_brute_force():
    scene = tiny_city()
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(-15, 95, 200), rng.uniform(-15, 75, 200), np.full(200, 1.5)])
    rx = pts[scene.outdoors(pts)][:16]
    n = _compare(scene, rx, 3)
    assert n > 100
