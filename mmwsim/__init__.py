"""mmwsim: physics-grounded 28 GHz mmWave simulation over 3D city meshes.

The flat public API; see the subpackages for details. Names load on first use, so that
``import mmwsim`` (and ``mmwsim --help``) stays fast: the heavy libraries (trimesh, Embree, numba,
zarr, rerun) are imported by the stage that needs them.

Layers, lowest first (``tests/test_layers.py`` enforces them): the core (``scene``, ``geometry``,
``materials``, ``antennas``, ``tracer``, ``fingerprints``, ``dataset``, ``trajectories``,
``recording``), then ``estimation`` and ``planning``, then the application (``mmwsim.cli``,
``mmwsim.demo``). The scene catalogue (``scenes``) is reached through the registry of
:mod:`mmwsim.scene.catalogue`.
"""

from __future__ import annotations

from .lazy import lazy_exports
from .version import __version__ as __version__

_EXPORTS = {
    "Codebook": ".antennas",
    "Isotropic": ".antennas",
    "Pattern": ".antennas",
    "PlanarArrayCodebook": ".antennas",
    "PyramidalHorn": ".antennas",
    "RotatingHorn": ".antennas",
    "ShortDipole": ".antennas",
    "make_codebook": ".antennas",
    "DEFAULT_FREQUENCY": ".constants",
    "SPEED_OF_LIGHT": ".constants",
    "Dataset": ".dataset.store",
    "GenerateConfig": ".dataset.config",
    "generate_dataset": ".dataset.generate:generate",
    "MaterialRangeWarning": ".errors",
    "MmwsimError": ".errors",
    "FingerprintSampler": ".fingerprints.noise",
    "GridField": ".fingerprints.field",
    "NoiseModel": ".fingerprints.noise",
    "TracedField": ".fingerprints.field",
    "power_delay_profile": ".fingerprints.pdp",
    "FreeSpace": ".geometry.freespace",
    "ITU_MATERIALS": ".materials",
    "Material": ".materials",
    "get_material": ".materials",
    "material_names": ".materials",
    "Entity": ".recording",
    "Recording": ".recording",
    "Timeline": ".recording",
    "OsmScene": ".scene",
    "OsmWarning": ".scene",
    "ReceiverGrid": ".scene",
    "Scene": ".scene",
    "SceneObject": ".scene",
    "Transmitter": ".scene",
    "load_mesh_file": ".scene",
    "load_mitsuba": ".scene",
    "load_osm": ".scene",
    "load_scene": ".scene",
    "load_toml": ".scene",
    "register_scene": ".scene.catalogue",
    "scene_names": ".scene.catalogue",
    "Paths": ".tracer",
    "Tracer": ".tracer",
    "trace": ".tracer",
    "MotionModel": ".trajectories",
    "SequenceLoader": ".trajectories",
    "StreetNetwork": ".trajectories",
    "Trajectories": ".trajectories",
    "TrajectoryError": ".trajectories",
    "generate_trajectories": ".trajectories.generate:generate",
    "read_trajectories": ".trajectories.store",
    "split": ".trajectories.splits",
    "write_trajectories": ".trajectories.store",
}

__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
