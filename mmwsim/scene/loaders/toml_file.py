"""The TOML scene format.

Example::

    name = "downtown"
    frequency_ghz = 28.0

    [materials.tinted_glass]          # user-defined, frequency independent
    permittivity = 6.3
    conductivity = 0.2
    thickness = 0.01

    [[objects]]
    name = "buildings"
    mesh = "meshes/buildings.ply"     # relative to this file, inside its folder
    material = "concrete"             # ITU-R P.2040 name or a [materials] entry
    kind = "building"                 # building | ground | other
    thickness = 0.3                   # optional slab thickness, m
    split = true                      # one object per connected part: buildings_000, ...

    [transmitter]
    position = [200.0, 203.0, 10.0]
    power_dbm = 30.0

    [receivers]
    origin = [0.0, 0.0]
    spacing = 1.0
    shape = [401, 401]
    height = 1.5
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field

from ...config import Int2, StrictModel, Vec2, Vec3, read_toml, validate
from ...errors import MmwsimError
from ...materials import Material, get_material
from ..objects import ReceiverGrid, SceneObject, Transmitter
from ..scene import Scene
from .meshes import read_mesh, resolve_inside

__all__ = ["SceneFile", "load_toml"]


class MaterialSpec(StrictModel):
    permittivity: float = Field(ge=1.0)
    conductivity: float = Field(ge=0.0)
    thickness: float | None = Field(default=None, gt=0.0)


class ObjectSpec(StrictModel):
    name: str = Field(min_length=1)
    mesh: str = Field(min_length=1)
    material: str = Field(min_length=1)
    kind: Literal["building", "ground", "other"] = "building"
    thickness: float | None = Field(default=None, gt=0.0)
    split: bool = False


class TransmitterSpec(StrictModel):
    position: Vec3
    power_dbm: float = 30.0


class ReceiversSpec(StrictModel):
    origin: Vec2 = (0.0, 0.0)
    spacing: float = Field(default=1.0, gt=0.0)
    shape: Int2
    height: float = 1.5


class SceneFile(StrictModel):
    """Schema of a TOML scene file."""

    name: str | None = None
    description: str = ""
    frequency_ghz: float = Field(default=28.0, gt=0.0)
    materials: dict[str, MaterialSpec] = Field(default_factory=dict)
    objects: list[ObjectSpec] = Field(min_length=1)
    transmitter: TransmitterSpec | None = None
    receivers: ReceiversSpec | None = None


def load_toml(path: str | Path, transmitter: tuple[float, float, float] | None = None) -> Scene:
    """Load a TOML scene file.

    Parameters
    ----------
    path : path-like
        The ``.toml`` file; mesh paths in it are relative to its folder and may not leave it.
    transmitter : (3,) float, optional
        Overrides the file's transmitter position, metres.

    Raises
    ------
    MmwsimError
        On any malformed, missing or unsafe input, with a one-line message.
    """
    path = Path(path)
    spec = validate(SceneFile, read_toml(path), str(path))
    custom: dict[str, Material] = {}
    for name, m in spec.materials.items():
        custom[name] = Material.custom(name, m.permittivity, m.conductivity, m.thickness)
    objects = []
    for i, o in enumerate(spec.objects):
        where = f"{path}: objects.{i} ({o.name})"
        try:
            material = custom[o.material] if o.material in custom else get_material(o.material)
        except MmwsimError as e:
            raise MmwsimError(f"{where}: {e}") from None
        if o.thickness is not None:
            material = material.with_thickness(o.thickness)
        try:
            mesh = read_mesh(resolve_inside(o.mesh, path.parent, where))
        except MmwsimError as e:
            raise MmwsimError(str(e) if str(e).startswith(where) else f"{where}: {e}") from None
        if o.split:
            parts = sorted(mesh.split(only_watertight=False), key=lambda m: tuple(m.bounds[0]))
            width = len(str(len(parts) - 1))
            objects += [
                SceneObject(f"{o.name}_{k:0{width}d}", m, material, o.kind) for k, m in enumerate(parts)
            ]
        else:
            objects.append(SceneObject(o.name, mesh, material, o.kind))
    tx = None
    if transmitter is not None:
        tx = Transmitter(
            tuple(float(v) for v in transmitter), spec.transmitter.power_dbm if spec.transmitter else 30.0
        )
    elif spec.transmitter is not None:
        tx = Transmitter(spec.transmitter.position, spec.transmitter.power_dbm)
    grid = None
    if spec.receivers is not None:
        r = spec.receivers
        if min(r.shape) < 1:
            raise MmwsimError(f"{path}: key 'receivers.shape' must be positive, got {list(r.shape)}")
        try:
            grid = ReceiverGrid(r.origin, r.spacing, r.shape, r.height)
        except MmwsimError as e:
            raise MmwsimError(f"{path}: [receivers]: {e}") from None
    try:
        return Scene(
            objects,
            transmitter=tx,
            receivers=grid,
            frequency=spec.frequency_ghz * 1e9,
            name=spec.name or path.stem,
            source=str(path),
        )
    except MmwsimError as e:
        raise MmwsimError(f"{path}: {e}") from None
