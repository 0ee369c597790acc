"""The scene: named meshes with materials, and the queries every stage asks of them."""

from __future__ import annotations

import re
from functools import cached_property

import numpy as np
import shapely
import trimesh

from ..constants import DEFAULT_FREQUENCY
from ..errors import MmwsimError
from ..geometry import CollisionModel, RayCaster
from ..materials import Material, material_color
from .objects import ReceiverGrid, SceneObject, Transmitter

__all__ = ["Scene"]


class Scene:
    """A set of named triangle meshes with radio materials, a transmitter and a receiver grid.

    Geometry back-ends (Embree for rays, FCL for collision) are built lazily, once,
    from the same triangles.

    Parameters
    ----------
    objects : list of SceneObject
        At least one object with at least one triangle; names unique.
    transmitter : Transmitter, optional
        Default transmitter; must be outdoors and above the scene's footprint.
    receivers : ReceiverGrid, optional
        Default receiver grid; by default the scene's extent at 1 m spacing, 1.5 m
        above its lowest point.
    frequency : float
        Carrier, Hz.
    name : str
        Shown in summaries and recordings.
    source : str, optional
        File or catalogue entry the scene came from.
    bounds : (2, 3) float, optional
        Extent to use instead of the triangles' bounds; lets a scene without
        triangles (free space) exist.
    """

    def __init__(
        self,
        objects: list[SceneObject],
        transmitter: Transmitter | None = None,
        receivers: ReceiverGrid | None = None,
        frequency: float = DEFAULT_FREQUENCY,
        name: str = "scene",
        source: str | None = None,
        bounds: np.ndarray | None = None,
    ):
        if bounds is None and (not objects or sum(len(o.mesh.faces) for o in objects) == 0):
            raise MmwsimError(f"scene {name!r} is empty: it has no triangles")
        self._bounds = None if bounds is None else np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        names = [o.name for o in objects]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise MmwsimError(f"scene {name!r}: object names must be unique, repeated: {', '.join(dup)}")
        for o in objects:
            v = np.asarray(o.mesh.vertices)
            if not np.all(np.isfinite(v)):
                raise MmwsimError(f"scene {name!r}: object {o.name!r} has non-finite vertex coordinates")
        self.objects = list(objects)
        self.frequency = float(frequency)
        self.name = name
        self.source = source
        self.transmitter = transmitter
        self.receivers = receivers if receivers is not None else self._default_grid()
        if receivers is not None:
            self.check_receivers(receivers)
        if transmitter is not None:
            self.check_transmitter(transmitter.position)

    # ------------------------------------------------------------------ triangles
    @cached_property
    def _merged(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        verts = [np.zeros((0, 3))]
        faces = [np.zeros((0, 3), dtype=np.int64)]
        owner = [np.zeros(0, dtype=np.int32)]
        offset = 0
        for i, o in enumerate(self.objects):
            v = np.asarray(o.mesh.vertices, dtype=np.float64)
            f = np.asarray(o.mesh.faces, dtype=np.int64)
            verts.append(v)
            faces.append(f + offset)
            owner.append(np.full(len(f), i, dtype=np.int32))
            offset += len(v)
        return np.concatenate(verts), np.concatenate(faces), np.concatenate(owner)

    @property
    def vertices(self) -> np.ndarray:
        """(n_vertices, 3) float64 vertex positions of all objects, metres."""
        return self._merged[0]

    @property
    def faces(self) -> np.ndarray:
        """(n_faces, 3) int64 vertex indices of all triangles."""
        return self._merged[1]

    @property
    def face_object(self) -> np.ndarray:
        """(n_faces,) int32 index into :attr:`objects` of each triangle's owner."""
        return self._merged[2]

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(n_faces, 3) float64 unit normals by the right-hand rule (zero for degenerate faces)."""
        tri = self.vertices[self.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)

    @property
    def n_triangles(self) -> int:
        return int(len(self.faces))

    def object_index(self, name: str) -> int:
        """Index of the object called ``name``."""
        for i, o in enumerate(self.objects):
            if o.name == name:
                return i
        raise MmwsimError(f"scene {self.name!r} has no object {name!r}")

    @property
    def materials(self) -> dict[str, Material]:
        """Materials in use, by name."""
        return {o.material.name: o.material for o in self.objects}

    def _kind_faces(self, kinds: tuple[str, ...]) -> np.ndarray:
        idx = [i for i, o in enumerate(self.objects) if o.kind in kinds]
        return np.flatnonzero(np.isin(self.face_object, idx))

    # ------------------------------------------------------------------ extent
    @cached_property
    def extent(self) -> np.ndarray:
        """(2, 3) float64 axis-aligned bounds [[xmin, ymin, zmin], [xmax, ymax, zmax]], metres."""
        if self._bounds is not None:
            return self._bounds.copy()
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def _default_grid(self) -> ReceiverGrid:
        lo, hi = self.extent
        x0, y0 = np.ceil(lo[:2])
        nx, ny = (np.floor(hi[:2]) - (x0, y0)).astype(int) + 1
        return ReceiverGrid(
            (float(x0), float(y0)), 1.0, (max(int(nx), 1), max(int(ny), 1)), float(lo[2]) + 1.5
        )

    # ------------------------------------------------------------------ back-ends
    @cached_property
    def ray_caster(self) -> RayCaster:
        """Embree ray queries over every triangle; face ids index :attr:`faces`."""
        return RayCaster(self.vertices, self.faces)

    @cached_property
    def collision_model(self) -> CollisionModel:
        """FCL BVH over the buildings and other non-ground objects."""
        idx = self._kind_faces(("building", "other"))
        return CollisionModel(self.vertices, self.faces[idx])

    # ------------------------------------------------------------------ queries
    @cached_property
    def _roofs(self) -> tuple[shapely.STRtree, np.ndarray, np.ndarray]:
        """Non-vertical building triangles: xy index, plane coefficients, sign of normal z."""
        idx = self._kind_faces(("building",))
        tri = self.vertices[self.faces[idx]]
        n = self.face_normals[idx]
        keep = np.abs(n[:, 2]) > 1e-9
        tri, n = tri[keep], n[keep]
        # plane z(x, y) = c0 + c1 x + c2 y through the triangle
        c1, c2 = -n[:, 0] / n[:, 2], -n[:, 1] / n[:, 2]
        c0 = tri[:, 0, 2] - c1 * tri[:, 0, 0] - c2 * tri[:, 0, 1]
        tree = shapely.STRtree(shapely.polygons(tri[:, :, :2]))
        return tree, np.column_stack([c0, c1, c2]), np.sign(n[:, 2]).astype(np.int32)

    def outdoors(self, points: np.ndarray, z: float | None = None) -> np.ndarray:
        """Whether each point lies outside every building.

        Counts the building faces crossed by a vertical ray upwards from each
        point, +1 for a face whose normal points up (a roof seen from inside) and
        -1 for one whose normal points down (an overhang seen from outside): the
        point is inside when the sum is positive. Vertical walls do not count, so
        touching buildings, shared walls and stacked parts cannot confuse the test.
        Building meshes must be closed with outward normals for this to hold.

        Parameters
        ----------
        points : (n, 3) or (n, 2) float
            Positions, metres; 2D points are taken at height ``z``.
        z : float, optional
            Height for 2D points; defaults to the receiver-grid height.

        Returns
        -------
        (n,) bool
        """
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] not in (2, 3):
            raise MmwsimError(f"points must have shape (n, 2) or (n, 3), got {p.shape}")
        if p.shape[1] == 2:
            height = self.receivers.height if z is None else z
            p = np.column_stack([p, np.full(len(p), float(height))])
        if not np.all(np.isfinite(p)):
            raise MmwsimError("points contain NaN or infinite coordinates")
        tree, plane, sign = self._roofs
        if len(sign) == 0:
            return np.ones(len(p), dtype=bool)
        ip, it = tree.query(shapely.points(p[:, :2]), predicate="intersects")
        z_face = plane[it, 0] + plane[it, 1] * p[ip, 0] + plane[it, 2] * p[ip, 1]
        above = z_face > p[ip, 2]
        winding = np.bincount(ip[above], weights=sign[it[above]], minlength=len(p))
        return winding <= 0

    @cached_property
    def footprints(self) -> list[shapely.Polygon]:
        """Building footprints: the union of the buildings' triangles projected on the xy plane.

        Returns
        -------
        list of shapely.Polygon
            Sorted by (xmin, ymin) of their bounds.
        """
        idx = self._kind_faces(("building",))
        if len(idx) == 0:
            return []
        tri = self.vertices[self.faces[idx]][:, :, :2]
        area2 = np.abs(
            (tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1])
            - (tri[:, 2, 0] - tri[:, 0, 0]) * (tri[:, 1, 1] - tri[:, 0, 1])
        )
        tri = tri[area2 > 1e-9]
        union = shapely.union_all(shapely.polygons(tri), grid_size=1e-6)
        polys = [g for g in getattr(union, "geoms", [union]) if isinstance(g, shapely.Polygon) and g.area > 0]
        return sorted(polys, key=lambda g: g.bounds[:2])

    def free_area_fraction(self) -> float:
        """Fraction of the receiver-grid area not covered by building footprints."""
        (x0, y0), (x1, y1) = self.receivers.bounds
        box = shapely.box(x0, y0, x1, y1)
        if box.area == 0:
            return 1.0
        covered = shapely.union_all(self.footprints).intersection(box).area if self.footprints else 0.0
        return float(1.0 - covered / box.area)

    def check_transmitter(self, position: tuple[float, float, float] | np.ndarray) -> np.ndarray:
        """Validate a transmitter position: finite, above the scene's footprint, outdoors.

        Returns
        -------
        (3,) float64
        """
        p = np.asarray(position, dtype=np.float64)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise MmwsimError(f"transmitter position must be three finite numbers, got {position!r}")
        lo, hi = self.extent
        if np.any(p[:2] < lo[:2]) or np.any(p[:2] > hi[:2]):
            raise MmwsimError(
                f"transmitter at {_fmt(p)} is outside the scene (x {lo[0]:g}..{hi[0]:g}, y {lo[1]:g}..{hi[1]:g})"
            )
        if p[2] <= lo[2]:
            raise MmwsimError(
                f"transmitter at {_fmt(p)} is below the scene (its lowest point is z {lo[2]:g} m)"
            )
        if not self.outdoors(p[None])[0]:
            raise MmwsimError(f"transmitter at {_fmt(p)} is inside a building")
        return p

    def with_scattering(self, coefficient: float) -> Scene:
        """The same scene with the diffuse scattering coefficient S of every material set to ``coefficient``."""
        objects = [
            SceneObject(o.name, o.mesh, o.material.with_scattering(coefficient), o.kind) for o in self.objects
        ]
        return Scene(
            objects,
            self.transmitter,
            self.receivers,
            self.frequency,
            self.name,
            self.source,
            None if self._bounds is None else self._bounds.copy(),
        )

    def check_receivers(self, grid: ReceiverGrid) -> ReceiverGrid:
        """Validate a receiver grid against the scene: it must overlap the scene's extent and lie
        above its lowest point (a grid under the ground has no valid receiver)."""
        lo, hi = self.extent
        (x0, y0), (x1, y1) = grid.bounds
        if x1 < lo[0] or x0 > hi[0] or y1 < lo[1] or y0 > hi[1]:
            raise MmwsimError(
                f"receiver grid x {x0:g}..{x1:g}, y {y0:g}..{y1:g} lies outside the scene "
                f"(x {lo[0]:g}..{hi[0]:g}, y {lo[1]:g}..{hi[1]:g})"
            )
        if grid.height <= lo[2]:
            raise MmwsimError(
                f"receiver height {grid.height:g} m is not above the scene (its lowest point is z {lo[2]:g} m)"
            )
        return grid

    # ------------------------------------------------------------------ export
    def merged_mesh(self) -> trimesh.Trimesh:
        """All objects as one mesh, faces coloured by material."""
        colors = np.array([material_color(o.material.name) + (255,) for o in self.objects], dtype=np.uint8)
        return trimesh.Trimesh(self.vertices, self.faces, face_colors=colors[self.face_object], process=False)

    def summary(self) -> str:
        """A human-readable multi-line summary."""
        lo, hi = self.extent
        lines = [
            f"scene {self.name}" + (f" ({self.source})" if self.source else ""),
            f"  carrier      {self.frequency / 1e9:g} GHz",
            f"  extent       x {lo[0]:.1f}..{hi[0]:.1f}  y {lo[1]:.1f}..{hi[1]:.1f}  z {lo[2]:.1f}..{hi[2]:.1f} m",
            f"  triangles    {self.n_triangles}",
            f"  objects      {len(self.objects)}",
        ]
        groups: dict[tuple, list[SceneObject]] = {}
        for o in self.objects:  # building_00 .. building_80 of one kind and material: one line
            key = (re.sub(r"_?\d+$", "", o.name), o.kind, o.material.name, o.material.thickness)
            groups.setdefault(key, []).append(o)
        rows = []
        for (_, kind, mat_name, thick), objs in groups.items():
            label = objs[0].name if len(objs) == 1 else f"{objs[0].name}..{objs[-1].name} ({len(objs)})"
            eps = objs[0].material.complex_permittivity(self.frequency, warn=False)
            slab = f", {thick:g} m slab" if thick else ""
            tris = sum(len(o.mesh.faces) for o in objs)
            rows.append((label, kind, tris, f"{mat_name}{slab} (eps {eps.real:.3g}{eps.imag:+.3g}j)"))
        width = max(len(r[0]) for r in rows) if rows else 0
        lines += [f"    {a:<{width}}  {b:<8} {c:>7} tri  {d}" for a, b, c, d in rows]
        mats = sorted(self.materials)
        lines.append(f"  materials    {', '.join(mats)}")
        for name in mats:
            if not self.materials[name].in_range(self.frequency):
                lines.append(f"  warning      {name} is used outside its stated frequency range")
        lines.append(f"  buildings    {len(self.footprints)} footprints")
        lines.append(f"  free area    {100 * self.free_area_fraction():.1f} % of the receiver grid")
        tx = self.transmitter
        lines.append(
            f"  transmitter  {_fmt(tx.array)} m, {tx.power_dbm:g} dBm" if tx else "  transmitter  none"
        )
        g = self.receivers
        lines.append(
            f"  receivers    {g.shape[0]} x {g.shape[1]} at {g.spacing:g} m from ({g.origin[0]:g}, {g.origin[1]:g}),"
            f" height {g.height:g} m"
        )
        return "\n".join(lines)


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:g}" for v in p) + ")"
