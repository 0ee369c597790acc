"""mmwsim: physics-grounded 28 GHz mmWave simulation over 3D city meshes.

The flat public API; see the subpackages for details.
"""

from __future__ import annotations

__version__ = "0.1.0"

from .antennas import (
    Codebook,
    Isotropic,
    Pattern,
    PlanarArrayCodebook,
    PyramidalHorn,
    RotatingHorn,
    ShortDipole,
    make_codebook,
)
from .constants import DEFAULT_FREQUENCY, SPEED_OF_LIGHT
from .dataset import Dataset, GenerateConfig
from .dataset import generate as generate_dataset
from .errors import MaterialRangeWarning, MmwsimError
from .fingerprints import FingerprintSampler, fingerprints, power_delay_profile
from .locks import LockHeld, OutputLock
from .materials import ITU_MATERIALS, Material, get_material, material_names
from .recording import Entity, Recording, Timeline
from .scene import (
    OsmScene,
    OsmWarning,
    ReceiverGrid,
    Scene,
    SceneObject,
    Transmitter,
    load_mesh_file,
    load_mitsuba,
    load_osm,
    load_scene,
    load_toml,
)
from .tracer import Paths, Tracer, trace
from .trajectories import (
    GridPdp,
    MotionModel,
    SequenceLoader,
    StreetNetwork,
    TracedPdp,
    Trajectories,
    TrajectoryError,
    read_trajectories,
    split,
    write_trajectories,
)
from .trajectories import generate as generate_trajectories

__all__ = [
    "Codebook",
    "Dataset",
    "FingerprintSampler",
    "GenerateConfig",
    "Isotropic",
    "Paths",
    "Pattern",
    "PlanarArrayCodebook",
    "PyramidalHorn",
    "RotatingHorn",
    "ShortDipole",
    "Tracer",
    "GridPdp",
    "MotionModel",
    "SequenceLoader",
    "StreetNetwork",
    "TracedPdp",
    "Trajectories",
    "TrajectoryError",
    "read_trajectories",
    "split",
    "write_trajectories",
    "generate_trajectories",
    "fingerprints",
    "generate_dataset",
    "make_codebook",
    "power_delay_profile",
    "trace",
    "DEFAULT_FREQUENCY",
    "SPEED_OF_LIGHT",
    "ITU_MATERIALS",
    "Entity",
    "LockHeld",
    "OutputLock",
    "MaterialRangeWarning",
    "Material",
    "MmwsimError",
    "OsmScene",
    "OsmWarning",
    "ReceiverGrid",
    "Recording",
    "Scene",
    "SceneObject",
    "Timeline",
    "Transmitter",
    "get_material",
    "load_mesh_file",
    "load_mitsuba",
    "load_osm",
    "load_scene",
    "load_toml",
    "material_names",
]
