"""Reading mesh files with trimesh, confined to a scene folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ...errors import MmwsimError

__all__ = ["resolve_inside", "read_mesh", "read_mesh_parts"]


def resolve_inside(relative: str, root: Path, where: str) -> Path:
    """Resolve ``relative`` against ``root``; the result must stay inside ``root``.

    Symbolic links are followed before the check, so a link cannot lead out either.
    """
    if Path(relative).is_absolute():
        raise MmwsimError(f"{where}: mesh path {relative!r} must be relative to the scene folder")
    root = root.resolve()
    path = (root / relative).resolve()
    if not path.is_relative_to(root):
        raise MmwsimError(f"{where}: mesh path {relative!r} leaves the scene folder {root}")
    return path


def _load(path: Path, force: str):
    if not path.is_file():
        raise MmwsimError(f"{path}: mesh file not found")
    try:
        loaded = trimesh.load(str(path), force=force, process=False)
        # Check the coordinates as read: processing drops the faces of non-finite vertices silently.
        parts = loaded.geometry.values() if isinstance(loaded, trimesh.Scene) else [loaded]
        for part in parts:
            if not np.all(np.isfinite(np.asarray(getattr(part, "vertices", np.zeros((0, 3)))))):
                raise MmwsimError(f"{path}: mesh has non-finite vertex coordinates")
            if isinstance(part, trimesh.Trimesh):
                part.process()
        return loaded
    except MmwsimError:
        raise
    except Exception as e:  # trimesh raises many types for unreadable files
        text = " ".join(str(e).split())[:200]
        raise MmwsimError(f"{path}: not a readable mesh ({type(e).__name__}: {text})") from None


def _check(mesh, path: Path, label: str = "") -> trimesh.Trimesh:
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MmwsimError(f"{path}{label}: not a triangle mesh (no faces)")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MmwsimError(f"{path}{label}: mesh has non-finite vertex coordinates")
    return mesh


def read_mesh(path: Path) -> trimesh.Trimesh:
    """One triangle mesh from any file trimesh reads (OBJ, PLY, GLB, STL, ...), parts merged."""
    return _check(_load(path, "mesh"), path)


def read_mesh_parts(path: Path) -> list[tuple[str, trimesh.Trimesh]]:
    """The named geometries of a mesh file with their node transforms applied, in file order."""
    scene = _load(path, "scene")
    parts: list[tuple[str, trimesh.Trimesh]] = []
    for node in sorted(scene.graph.nodes_geometry):
        transform, geom_name = scene.graph[node]
        geom = scene.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        mesh = geom.copy()
        mesh.apply_transform(transform)
        parts.append((str(node), _check(mesh, path, f" [{node}]")))
    if not parts:
        raise MmwsimError(f"{path}: not a triangle mesh (no faces)")
    return parts
