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
    ".antennas": (
        "Codebook",
        "Isotropic",
        "Pattern",
        "PlanarArrayCodebook",
        "PyramidalHorn",
        "RotatingHorn",
        "ShortDipole",
        "make_codebook",
    ),
    ".constants": ("DEFAULT_FREQUENCY", "SPEED_OF_LIGHT"),
    ".dataset.config": ("GenerateConfig",),
    ".dataset.generate": ("generate_dataset=generate",),
    ".dataset.store": ("Dataset",),
    ".errors": ("MaterialRangeWarning", "MmwsimError"),
    ".fingerprints.field": ("GridField", "TracedField"),
    ".fingerprints.noise": ("FingerprintSampler", "NoiseModel"),
    ".fingerprints.pdp": ("power_delay_profile",),
    ".locks": ("LockHeld", "OutputLock"),
    ".geometry.freespace": ("FreeSpace",),
    ".materials": ("ITU_MATERIALS", "Material", "get_material", "material_names"),
    ".recording": ("Entity", "Recording", "Timeline"),
    ".scene": (
        "OsmScene",
        "OsmWarning",
        "ReceiverGrid",
        "Scene",
        "SceneObject",
        "Transmitter",
        "load_mesh_file",
        "load_mitsuba",
        "load_osm",
        "load_scene",
        "load_toml",
    ),
    ".scene.catalogue": ("register_scene", "scene_names"),
    ".tracer": ("Paths", "Tracer", "trace"),
    ".trajectories": ("MotionModel", "SequenceLoader", "StreetNetwork", "Trajectories", "TrajectoryError"),
    ".trajectories.generate": ("generate_trajectories=generate",),
    ".trajectories.splits": ("split",),
    ".trajectories.store": ("read_trajectories", "write_trajectories"),
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
