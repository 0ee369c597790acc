"""A bare mesh file (OBJ, PLY, GLB, STL, ...) as a scene: one object per named geometry."""

from __future__ import annotations

from pathlib import Path

from ...errors import MmwsimError
from ...materials import get_material
from ..objects import SceneObject, Transmitter
from ..scene import Scene
from .meshes import read_mesh_parts
from .mitsuba import guess_kind

__all__ = ["load_mesh_file"]


def load_mesh_file(
    path: str | Path,
    material: str = "concrete",
    ground_material: str = "concrete",
    transmitter: tuple[float, float, float] | None = None,
) -> Scene:
    """Load any mesh file trimesh reads as a scene, coordinates as given (z up).

    Flat horizontal parts, or parts named like ground, become ground; the rest
    buildings. Every building gets ``material``, every ground ``ground_material``.
    """
    path = Path(path)
    building, ground = get_material(material), get_material(ground_material)
    objects = []
    for name, mesh in read_mesh_parts(path):
        kind = guess_kind(name, mesh)
        objects.append(SceneObject(name, mesh, ground if kind == "ground" else building, kind))
    tx = Transmitter(tuple(float(v) for v in transmitter)) if transmitter is not None else None
    try:
        return Scene(objects, transmitter=tx, name=path.stem, source=str(path))
    except MmwsimError as e:
        raise MmwsimError(f"{path}: {e}") from None
