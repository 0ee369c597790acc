"""Closed meshes of extruded footprints, with touching and overlapping buildings merged.

Each building is a prism: its footprint (holes kept) between ``z_min`` and ``z_max``. Where
buildings touch or overlap, the mesh is the boundary of the union of their prisms, so no face lies
inside the solid or between two buildings:

1. The footprints' outlines are noded together and polygonized (shapely) into *cells*: pieces of
   the plane that every footprint either covers or misses entirely.
2. Above each cell the solid is the union of the covering buildings' height intervals. A roof
   (normal up) is laid where the solid ends going up, a floor (normal down) where it starts.
3. Along every cell edge a wall stands wherever the solid is on one side only, facing the other.

Walls are split at every height at which any face meets their vertical sides, and roofs use the
cells' own vertices (constrained Delaunay triangulation, no new points), so every edge is shared
by exactly two triangles: the meshes are closed (watertight) with outward normals. Two solids that
touch along a line only (e.g. buildings meeting at a corner) would leave an edge shared by four
triangles; :func:`merge_prisms_closed` grows the footprints involved by :data:`TOUCH_GROWTH` so that
they overlap instead, and merges again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["MergedSolids", "merge_prisms", "merge_prisms_closed", "non_manifold_owners"]

TOUCH_GROWTH = 0.002  # metres a footprint grows by where it only touches a neighbour along an edge


@dataclass
class MergedSolids:
    """The boundary of the union of prisms.

    Attributes
    ----------
    vertices : (v, 3) float64, metres
    faces : (f, 3) int64
        Counter-clockwise seen from outside.
    face_owner : (f,) int64
        Index of the prism each face belongs to.
    group : (n_prisms,) int64
        Connected group (touching or overlapping footprints) of each prism, numbered by the
        first prism in it.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_owner: np.ndarray
    group: np.ndarray


def _groups(polys: np.ndarray) -> np.ndarray:
    tree = shapely.STRtree(polys)
    i, j = tree.query(polys, predicate="intersects")
    n = len(polys)
    adj = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    # number groups by their first member so the labels do not depend on scipy's traversal
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[label]


def _zipper(left: np.ndarray, right: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangles of a vertical strip between two sorted chains of heights.

    Returns index pairs as ``(side, k)`` flattened: side 0 is ``left``, 1 is ``right``; each
    triangle is counter-clockwise for the quad (left_lo, right_lo, right_hi, left_hi).
    """
    tris = []
    i = j = 0
    k, m = len(left) - 1, len(right) - 1
    while i < k or j < m:
        if j < m and (i == k or right[j + 1] <= left[i + 1]):
            tris.append(((0, i), (1, j), (1, j + 1)))
            j += 1
        else:
            tris.append(((0, i), (1, j), (0, i + 1)))
            i += 1
    return tris


def merge_prisms(polys: np.ndarray, z_min: np.ndarray, z_max: np.ndarray) -> MergedSolids:
    """Closed boundary mesh of the union of prisms (footprint x [z_min, z_max]).

    Parameters
    ----------
    polys : (n,) shapely Polygon or MultiPolygon
        Valid footprints, metres.
    z_min, z_max : (n,) float
        Base and top of every prism, metres; ``z_max > z_min``.

    Returns
    -------
    MergedSolids
    """
    polys = np.asarray(polys, dtype=object)
    z_min = np.asarray(z_min, dtype=np.float64)
    z_max = np.asarray(z_max, dtype=np.float64)
    n = len(polys)
    if n == 0:
        return MergedSolids(
            np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
        )
    group = _groups(polys)

    # 1. cells of the arrangement of all outlines
    lines = shapely.get_parts(shapely.union_all(shapely.boundary(polys)))
    cells = shapely.get_parts(shapely.polygonize(lines))
    cells = shapely.orient_polygons(cells[shapely.area(cells) > 0])  # exteriors CCW, holes CW
    inside_cell, inside_poly = shapely.STRtree(polys).query(
        shapely.point_on_surface(cells), predicate="within"
    )
    n_cells = len(cells)
    covers: list[list[int]] = [[] for _ in range(n_cells)]
    for c, b in zip(inside_cell.tolist(), inside_poly.tolist(), strict=True):
        covers[c].append(b)

    # 2. per cell: the heights where anything changes and the owner of each interval between them
    levels: list[np.ndarray] = []
    owners: list[np.ndarray] = []
    for c in range(n_cells):
        bs = sorted(covers[c])
        if not bs:
            levels.append(np.zeros(0))
            owners.append(np.zeros(0, np.int64))
            continue
        lv = np.unique(np.concatenate([z_min[bs], z_max[bs]]))
        mid = 0.5 * (lv[:-1] + lv[1:])
        own = np.full(len(mid), -1, np.int64)
        for b in reversed(bs):  # the lowest index wins where prisms overlap
            own[(mid > z_min[b]) & (mid < z_max[b])] = b
        levels.append(lv)
        owners.append(own)

    def owner_at(c: int, z: float) -> int:
        if c < 0 or len(levels[c]) == 0:
            return -1
        k = int(np.searchsorted(levels[c], z)) - 1
        return int(owners[c][k]) if 0 <= k < len(owners[c]) else -1

    # vertices of the arrangement, shared exactly between neighbouring cells
    rings, ring_cell = shapely.get_rings(cells, return_index=True)
    coords, ring_of = shapely.get_coordinates(rings, return_index=True)
    xy, vid = np.unique(coords, axis=0, return_inverse=True)
    vid = vid.reshape(-1)
    same = ring_of[1:] == ring_of[:-1]
    seg_a, seg_b = vid[:-1][same], vid[1:][same]
    seg_cell = ring_cell[ring_of[:-1][same]]
    nv = len(xy)

    # heights met at each vertex: every change level of every cell around it
    vz: list[set[float]] = [set() for _ in range(nv)]
    for a, c in zip(seg_a.tolist(), seg_cell.tolist(), strict=True):
        vz[a].update(levels[c].tolist())

    z_table: dict[float, int] = {}
    tri_v: list[tuple[int, float]] = []  # flattened triangle corners (vertex id, z)
    tri_owner: list[int] = []

    # 3. walls
    key = seg_a * nv + seg_b
    order = np.argsort(key)
    twin_pos = np.searchsorted(key[order], seg_b * nv + seg_a)
    twin_pos = np.minimum(twin_pos, len(order) - 1)
    has_twin = key[order][twin_pos] == seg_b * nv + seg_a
    right_cell = np.where(has_twin, seg_cell[order[twin_pos]], -1)
    for a, b, left, right in zip(
        seg_a.tolist(), seg_b.tolist(), seg_cell.tolist(), right_cell.tolist(), strict=True
    ):
        if right >= 0 and a > b:
            continue  # the twin segment builds this wall
        lv = np.union1d(levels[left], levels[right] if right >= 0 else np.zeros(0))
        if len(lv) < 2:
            continue
        pieces: list[list] = []  # [z0, z1, solid_left, owner]
        for z0, z1 in zip(lv[:-1].tolist(), lv[1:].tolist(), strict=True):
            m = 0.5 * (z0 + z1)
            ol, orr = owner_at(left, m), owner_at(right, m)
            if (ol >= 0) == (orr >= 0):
                continue
            state = (ol >= 0, ol if ol >= 0 else orr)
            if pieces and pieces[-1][1] == z0 and (pieces[-1][2], pieces[-1][3]) == state:
                pieces[-1][1] = z1
            else:
                pieces.append([z0, z1, *state])
        for z0, z1, solid_left, own in pieces:
            # outward normal points to the empty side; (a, b) runs with the left cell on its left
            p, q = (a, b) if solid_left else (b, a)
            chains = []
            for v in (p, q):
                zs = np.array(sorted(z for z in vz[v] if z0 < z < z1))
                chains.append(np.concatenate([[z0], zs, [z1]]))
            for tri in _zipper(*chains):
                for side, k in tri:
                    tri_v.append(((p, q)[side], float(chains[side][k])))
                tri_owner.append(own)

    # 4. roofs and floors
    solid_cells = [c for c in range(n_cells) if len(levels[c])]
    if solid_cells:
        tri_geoms, tri_cell = shapely.get_parts(
            shapely.constrained_delaunay_triangles(cells[solid_cells]), return_index=True
        )
        tc = shapely.get_coordinates(shapely.get_exterior_ring(tri_geoms)).reshape(-1, 4, 2)[:, :3]
        # map triangle corners back to arrangement vertices (exact coordinates)
        key_xy = xy[:, 0] + 1j * xy[:, 1]
        q = tc[..., 0] + 1j * tc[..., 1]
        pos = np.clip(np.searchsorted(key_xy, q), 0, nv - 1)
        if not np.array_equal(key_xy[pos], q):
            raise RuntimeError("roof triangulation introduced vertices not on the footprint outlines")
        ccw = (
            (tc[:, 1, 0] - tc[:, 0, 0]) * (tc[:, 2, 1] - tc[:, 0, 1])
            - (tc[:, 2, 0] - tc[:, 0, 0]) * (tc[:, 1, 1] - tc[:, 0, 1])
        ) > 0
        pos = np.where(ccw[:, None], pos, pos[:, ::-1])  # all counter-clockwise seen from above
        by_cell: dict[int, np.ndarray] = {}
        for cell_k, tri in zip(np.asarray(solid_cells)[tri_cell].tolist(), pos, strict=True):
            by_cell.setdefault(cell_k, []).append(tri)
        for c in solid_cells:
            tris = np.asarray(by_cell.get(c, np.zeros((0, 3), np.int64)))
            lv, own = levels[c], owners[c]
            for k, z in enumerate(lv.tolist()):
                below = int(own[k - 1]) if k >= 1 else -1
                above = int(own[k]) if k < len(own) else -1
                if (below >= 0) == (above >= 0):
                    continue
                up = below >= 0
                for t in tris.tolist():
                    for v in t if up else t[::-1]:
                        tri_v.append((v, z))
                    tri_owner.append(below if up else above)

    if not tri_v:
        return MergedSolids(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), group)
    zs = np.array(sorted({z for _, z in tri_v}))
    for i, z in enumerate(zs.tolist()):
        z_table[z] = i
    corner = np.array([v * len(zs) + z_table[z] for v, z in tri_v], dtype=np.int64)
    uniq, inv = np.unique(corner, return_inverse=True)
    vertices = np.column_stack([xy[uniq // len(zs)], zs[uniq % len(zs)]])
    faces = inv.reshape(-1, 3).astype(np.int64)
    return MergedSolids(vertices, faces, np.asarray(tri_owner, dtype=np.int64), group)


def non_manifold_owners(solids: MergedSolids) -> np.ndarray:
    """Prisms that own a face on an edge not shared by exactly two faces (sorted, unique)."""
    edges = np.sort(solids.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, inv, count = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    bad = count[inv.reshape(-1)] != 2
    return np.unique(np.repeat(solids.face_owner, 3)[bad])


def merge_prisms_closed(
    polys: np.ndarray,
    z_min: np.ndarray,
    z_max: np.ndarray,
    bounds: shapely.Geometry | None = None,
    rounds: int = 3,
) -> tuple[MergedSolids, np.ndarray]:
    """:func:`merge_prisms`, with footprints that meet a neighbour along a line only grown until
    every edge is shared by two faces (at most ``rounds`` times); grown footprints stay inside
    ``bounds`` when given.

    Returns
    -------
    solids : MergedSolids
    polys : (n,) shapely geometries
        The footprints used (the grown ones replaced).
    """
    polys = np.array(polys, dtype=object)
    solids = merge_prisms(polys, z_min, z_max)
    for _ in range(rounds):
        owners = non_manifold_owners(solids)
        if len(owners) == 0:
            break
        grown = shapely.buffer(polys[owners], TOUCH_GROWTH, join_style="mitre")
        polys[owners] = grown if bounds is None else shapely.intersection(grown, bounds)
        solids = merge_prisms(polys, z_min, z_max)
    return solids, polys
