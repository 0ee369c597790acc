"""Figures of an OpenStreetMap scene: load time, buildings against a second reader, valid paths.

    python benchmarks/osm_scene.py Helsinki.osm.pbf --center 60.1675,24.946 --size 400x400 --tx 200,200,10

1. Load time of the area, first (empty cache) and cached, each in this process after imports.
2. Building count and footprint area against a second reading of the same file: a pyosmium
   ``SimpleHandler`` pass that assembles the buildings itself (closed ways as polygons,
   multipolygon relations by shapely's polygonize of their member ways), projected with pyproj
   directly, clipped to the area and unioned with shapely.
3. Every path the tracer finds from ``--tx`` to receivers on the street network, checked
   independently: no leg blocked (trimesh's numpy ray-triangle test, not Embree), each
   reflection point inside its triangle, the law of reflection, and the unfolded length.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings

import numpy as np
import osmium
import pyproj
import shapely
import trimesh

import mmwsim
from mmwsim.scene.osm import OsmArea, OsmWarning
from mmwsim.tracer import Interaction, Tracer


def load_times(path: str, area: dict) -> tuple[mmwsim.OsmScene, float, float]:
    with tempfile.TemporaryDirectory() as cache:
        os.environ["MMWSIM_CACHE_DIR"] = cache
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OsmWarning)
            t0 = time.perf_counter()
            mmwsim.load_osm(path, **area)
            t1 = time.perf_counter()
            scene = mmwsim.load_osm(path, **area)
            t2 = time.perf_counter()
    return scene, t1 - t0, t2 - t1


class _Relations(osmium.SimpleHandler):
    def __init__(self):
        super().__init__()
        self.members: dict[int, list[tuple[int, str]]] = {}

    def relation(self, r):
        tags = r.tags
        if tags.get("type") == "multipolygon" and (
            tags.get("building", "no") != "no" or tags.get("building:part", "no") != "no"
        ):
            if tags.get("location") != "underground":
                self.members[r.id] = [(m.ref, m.role) for m in r.members if m.type == "w"]


class _Ways(osmium.SimpleHandler):
    def __init__(self, wanted: set[int]):
        super().__init__()
        self.wanted = wanted
        self.closed: list[list[tuple[float, float]]] = []
        self.lines: dict[int, list[tuple[float, float]]] = {}

    def way(self, w):
        try:
            coords = [(n.lon, n.lat) for n in w.nodes]
        except osmium.InvalidLocationError:
            return
        tags = w.tags
        building = tags.get("building", "no") != "no" or tags.get("building:part", "no") != "no"
        if building and tags.get("location") != "underground" and w.is_closed() and len(coords) >= 4:
            self.closed.append(coords)
        if w.id in self.wanted:
            self.lines[w.id] = coords


def second_reader(path: str) -> list[shapely.Geometry]:
    """Building polygons (lon/lat) read without pyosmium's area assembler."""
    rel = _Relations()
    rel.apply_file(path)
    wanted = {ref for ms in rel.members.values() for ref, _ in ms}
    ways = _Ways(wanted)
    ways.apply_file(path, locations=True)
    polys = [shapely.make_valid(shapely.Polygon(c)) for c in ways.closed]
    for ms in rel.members.values():
        if not all(ref in ways.lines for ref, _ in ms):
            continue  # a member outside the extract
        outer = [shapely.LineString(ways.lines[r]) for r, role in ms if role != "inner"]
        inner = [shapely.LineString(ways.lines[r]) for r, role in ms if role == "inner"]
        shell = shapely.union_all(shapely.get_parts(shapely.polygonize(outer)))
        holes = shapely.union_all(shapely.get_parts(shapely.polygonize(inner))) if inner else None
        polys.append(shell if holes is None else shell.difference(holes))
    return polys


def compare_footprints(scene, path: str) -> None:
    area: OsmArea = scene.area
    utm = pyproj.Transformer.from_crs("EPSG:4326", area.crs_name, always_xy=True)
    o = scene.origin

    def project(c):
        x, y = utm.transform(c[:, 0], c[:, 1])
        return np.column_stack([x - o[0], y - o[1]])

    t0 = time.perf_counter()
    polys = shapely.transform(np.array(second_reader(path), dtype=object), project)
    box = shapely.box(0, 0, *area.extent)
    clipped = shapely.intersection(polys, box)
    # pieces under 1 cm2 cannot exist on the 1 cm grid footprints are snapped to
    inside = polys[(shapely.area(clipped) > 1e-4) & (shapely.area(polys) >= 1.0)]
    theirs = shapely.union_all(inside).intersection(box)
    ours = shapely.union_all(scene.footprints)
    s = scene.osm_stats
    print(f"second reader ({time.perf_counter() - t0:.2f} s): {len(inside)} building polygons in the area")
    print(
        f"  mmwsim: {s['in_area']} buildings in the area + {s['outlines_dropped']} outlines drawn by their"
        f" parts alone = {s['in_area'] + s['outlines_dropped']} ({s['outlines_trimmed']} outlines trimmed to what"
        f" their parts leave); merged into {s['blocks']} blocks"
    )
    diff = shapely.symmetric_difference(ours, theirs).area
    print(
        f"  footprint area: mmwsim {ours.area:.1f} m2, second reader {theirs.area:.1f} m2,"
        f" symmetric difference {diff:.1f} m2 ({100 * diff / theirs.area:.3f} %)"
    )


def check_paths(scene, tx: np.ndarray, n_rx: int) -> None:
    net = mmwsim.StreetNetwork.from_scene(scene)
    pts = net.nodes[scene.outdoors(net.nodes)]
    pick = np.linspace(0, len(pts) - 1, min(n_rx, len(pts))).astype(int)
    rx = np.column_stack([pts[pick], np.full(len(pick), scene.receivers.height)])
    t0 = time.perf_counter()
    paths = Tracer(scene, tx, 3).trace(rx)
    t_trace = time.perf_counter() - t0
    mesh = trimesh.Trimesh(scene.vertices, scene.faces, process=False)
    rays = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    tri = scene.vertices[scene.faces]
    n = scene.face_normals
    bad = {"blocked": 0, "off_face": 0, "not_specular": 0, "off_edge": 0, "not_keller": 0, "length": 0}
    for i in range(paths.n_paths):
        k = int(paths.order[i])
        chain = np.vstack([tx, paths.points[i, :k], paths.rx[paths.rx_index[i]]])
        faces = paths.faces[i, :k]
        legs = np.diff(chain, axis=0)
        dist = np.linalg.norm(legs, axis=1)
        if abs(dist.sum() - paths.length[i]) > 1e-6:
            bad["length"] += 1
        # blockage: any hit strictly inside a leg, other than the faces at its ends
        loc, ray_idx, tri_idx = rays.intersects_location(chain[:-1], legs / dist[:, None], multiple_hits=True)
        loc = np.asarray(loc, dtype=np.float64).reshape(-1, 3)
        t = np.einsum("ij,ij->i", loc - chain[:-1][ray_idx], legs[ray_idx] / dist[ray_idx, None])
        own = np.zeros(len(tri_idx), dtype=bool)
        for j, f in enumerate(faces):
            own |= (tri_idx == f) & ((ray_idx == j) | (ray_idx == j + 1))
        if np.any((t > 1e-6) & (t < dist[ray_idx] - 1e-6) & ~own):
            bad["blocked"] += 1
        for j, f in enumerate(faces):
            p, (a, b, c) = chain[j + 1], tri[f]
            d_in, d_out = legs[j] / dist[j], legs[j + 1] / dist[j + 1]
            if paths.types[i, j] == Interaction.DIFFRACTION:
                # on the line of one of the face's edges (collinear pieces act as one edge), and
                # on Keller's cone: the same angle to the edge in and out
                lines = [(a, b - a), (b, c - b), (c, a - c)]
                off = [np.linalg.norm(np.cross(p - q, e / np.linalg.norm(e))) for q, e in lines]
                q, e = lines[int(np.argmin(off))]
                e = e / np.linalg.norm(e)
                bad["off_edge"] += min(off) > 1e-6
                bad["not_keller"] += abs(d_in @ e - d_out @ e) > 1e-6
                continue
            v0, v1, v2 = b - a, c - a, p - a
            d00, d01, d11, d20, d21 = v0 @ v0, v0 @ v1, v1 @ v1, v2 @ v0, v2 @ v1
            den = d00 * d11 - d01 * d01
            v, w = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
            if abs((p - a) @ n[f]) > 1e-6 or min(v, w, 1 - v - w) < -1e-9:
                bad["off_face"] += 1
            if np.abs(d_out - (d_in - 2 * (d_in @ n[f]) * n[f])).max() > 1e-6:
                bad["not_specular"] += 1
    by_order = np.bincount(paths.order, minlength=4)
    diffracted = int((paths.types == Interaction.DIFFRACTION).any(axis=1).sum())
    print(
        f"paths: {paths.n_paths} to {len(rx)} receivers on the streets in {t_trace:.2f} s"
        f" (by interactions {', '.join(f'{k}: {c}' for k, c in enumerate(by_order))};"
        f" {diffracted} with a diffraction); invalid: {sum(bad.values())} {bad}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("osm")
    ap.add_argument("--center", default="60.1675,24.946")
    ap.add_argument("--size", default="400x400")
    ap.add_argument("--tx", default="200,200,10")
    ap.add_argument("--receivers", type=int, default=40)
    args = ap.parse_args()
    area = dict(center=args.center, size=args.size)
    scene, first, cached = load_times(args.osm, area)
    print(f"load: first {first:.2f} s, cached {cached:.2f} s")
    print(scene.summary())
    compare_footprints(scene, args.osm)
    check_paths(scene, np.array([float(v) for v in args.tx.split(",")]), args.receivers)


if __name__ == "__main__":
    main()
