"""The TOML scene format.

Example::

    name = "downtown"
    frequency_ghz = 28.0

    [materials.tinted_glass]          # user-defined, frequency independent
    permittivity = 6.3
    conductivity = 0.2
    thickness = 0.01
    scattering_coefficient = 0.2      # optional diffuse scattering: S, Kx, pattern, alpha_R
    xpd_coefficient = 0.1
    scattering_pattern = "directive"  # lambertian (default) | directive
    alpha_r = 4

    [materials.concrete]              # a built-in (ITU-R P.2040-3) name: only thickness and
    scattering_coefficient = 0.3      # scattering keys, which every object using it gets

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

An ``[osm]`` table builds the scene from an OpenStreetMap extract instead, or besides the
objects (see :mod:`mmwsim.scene.osm.toml_source`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field

from ...config import Int2, StrictModel, Vec2, Vec3, read_toml, validate
from ...errors import MmwsimError
from ...materials import Material, canonical_name, get_material
from ..objects import ReceiverGrid, SceneObject, Transmitter
from ..osm.toml_source import OsmSource, scene_with_osm
from ..scene import Scene
from .meshes import read_mesh, resolve_inside

__all__ = ["SceneFile", "load_toml"]


class MaterialSpec(StrictModel):
    """A user-defined material (permittivity and conductivity) or overrides of a built-in one."""

    permittivity: float | None = Field(default=None, ge=1.0)
    conductivity: float | None = Field(default=None, ge=0.0)
    thickness: float | None = Field(default=None, gt=0.0)
    scattering_coefficient: float | None = None  # ranges checked by Material
    xpd_coefficient: float | None = None
    scattering_pattern: str | None = None
    alpha_r: int | None = None


def _spec_material(name: str, m: MaterialSpec) -> tuple[str, Material]:
    """(key objects find it by, material) of one ``[materials.NAME]`` entry."""
    scattering = {
        "S": m.scattering_coefficient,
        "xpd": m.xpd_coefficient,
        "pattern": m.scattering_pattern,
        "alpha_r": m.alpha_r,
    }
    if m.permittivity is None and m.conductivity is None:
        base = canonical_name(name)
        if base is None:
            raise MmwsimError(f"{name!r} is not a built-in material: give 'permittivity' and 'conductivity'")
        return base, get_material(base, m.thickness).with_scattering(**scattering)
    if m.permittivity is None or m.conductivity is None:
        raise MmwsimError("a user-defined material needs both 'permittivity' and 'conductivity'")
    mat = Material.custom(name, m.permittivity, m.conductivity, m.thickness)
    return name, mat.with_scattering(**scattering)


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
    objects: list[ObjectSpec] = Field(default_factory=list)
    osm: OsmSource | None = None
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
    if not spec.objects and spec.osm is None:
        raise MmwsimError(f"{path}: missing key 'objects' (or an [osm] table)")
    custom: dict[str, Material] = {}  # user-defined, by their own name
    overrides: dict[str, Material] = {}  # built-ins with thickness / scattering, by canonical name
    for name, m in spec.materials.items():
        try:
            key, mat = _spec_material(name, m)
        except MmwsimError as e:
            raise MmwsimError(f"{path}: materials.{name}: {e}") from None
        (custom if mat.source == "user-defined" else overrides)[key] = mat
    objects = []
    for i, o in enumerate(spec.objects):
        where = f"{path}: objects.{i} ({o.name})"
        try:
            material = custom.get(o.material) or overrides.get(canonical_name(o.material) or "")
            material = material or get_material(o.material)
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
    if spec.osm is not None:
        try:
            return scene_with_osm(
                spec.osm, path, objects, tx, grid, spec.frequency_ghz * 1e9, spec.name or path.stem
            )
        except MmwsimError as e:
            raise MmwsimError(str(e) if str(e).startswith(str(path)) else f"{path}: {e}") from None
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
