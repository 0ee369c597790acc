"""mmwsim: physics-grounded 28 GHz mmWave simulation over 3D city meshes.

The flat public API; see the subpackages for details.
"""

from __future__ import annotations

__version__ = "0.1.0"

from .constants import DEFAULT_FREQUENCY, SPEED_OF_LIGHT
from .errors import MaterialRangeWarning, MmwsimError
from .materials import ITU_MATERIALS, Material, get_material, material_names
from .recording import Entity, Recording, Timeline
from .scene import (
    ReceiverGrid,
    Scene,
    SceneObject,
    Transmitter,
    load_mesh_file,
    load_mitsuba,
    load_scene,
    load_toml,
)

__all__ = [
    "DEFAULT_FREQUENCY",
    "SPEED_OF_LIGHT",
    "ITU_MATERIALS",
    "Entity",
    "MaterialRangeWarning",
    "Material",
    "MmwsimError",
    "ReceiverGrid",
    "Recording",
    "Scene",
    "SceneObject",
    "Timeline",
    "Transmitter",
    "get_material",
    "load_mesh_file",
    "load_mitsuba",
    "load_scene",
    "load_toml",
    "material_names",
]
