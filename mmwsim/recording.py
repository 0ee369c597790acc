"""Rerun recordings: the one place that owns entity paths, timelines and the blueprint.

Every stage logs into one entity tree::

    meta/config                       resolved config (text)
    world/scene/<material>            scene meshes, coloured by material
    world/tx                          transmitter; world/tx/pattern/... beam patterns
    world/rx_grid                     receiver-grid outline
    world/rays/paths, world/rays/candidates
    world/coverage/...                received-power maps (beam timeline)
    map/footprints                    building footprints in 2D (context of 2D views)
    bff/<receiver>/...                power-delay profiles and fingerprints
    trajectories/<id>/{true,<model>}  step timeline
    training/<model>/...              epoch timeline
    planner/{tree,ellipse,path,cost}  iteration timeline
    planner/{optimum,corridor,endpoints}  exact shortest path, corridor, start and goal (static)

Recordings are written headless to a temporary file next to the target and
renamed into place when complete, so a failed run never leaves a half-written
``.rrd`` where a result is expected.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .config import canonical_json, content_hash
from .errors import MmwsimError
from .materials import material_color

if TYPE_CHECKING:
    from .scene import Scene

__all__ = [
    "APP_ID",
    "Recording",
    "Timeline",
    "Entity",
    "blueprint",
    "log_scene",
    "log_footprints",
]

APP_ID = "mmwsim"


class Timeline:
    """Timeline names."""

    BEAM = "beam"
    STEP = "step"
    EPOCH = "epoch"
    ITERATION = "iteration"


class Entity:
    """Entity paths of the project's one entity tree."""

    CONFIG = "meta/config"
    WORLD = "world"
    SCENE = "world/scene"
    TX = "world/tx"
    TX_PATTERN = "world/tx/pattern"
    RX_GRID = "world/rx_grid"
    RAYS = "world/rays"
    RAY_PATHS = "world/rays/paths"
    RAY_CANDIDATES = "world/rays/candidates"
    COVERAGE = "world/coverage"
    MAP = "map"
    FOOTPRINTS = "map/footprints"
    BFF = "bff"
    TRAJECTORIES = "trajectories"
    TRAINING = "training"
    PLANNER = "planner"
    PLANNER_TREE = "planner/tree"
    PLANNER_ELLIPSE = "planner/ellipse"
    PLANNER_PATH = "planner/path"
    PLANNER_COST = "planner/cost"
    PLANNER_OPTIMUM = "planner/optimum"
    PLANNER_CORRIDOR = "planner/corridor"
    PLANNER_ENDPOINTS = "planner/endpoints"

    @staticmethod
    def scene_material(name: str) -> str:
        return f"{Entity.SCENE}/{name}"

    @staticmethod
    def coverage(name: str) -> str:
        return f"{Entity.COVERAGE}/{name}"

    @staticmethod
    def bff(receiver: str, what: str) -> str:
        return f"{Entity.BFF}/{receiver}/{what}"

    @staticmethod
    def trajectory(ident: str | int, source: str) -> str:
        return f"{Entity.TRAJECTORIES}/{ident}/{source}"

    @staticmethod
    def training(model: str, what: str) -> str:
        return f"{Entity.TRAINING}/{model}/{what}"


FAMILIES = ("world", "coverage", "bff", "trajectories", "training", "planner")


def blueprint(families: tuple[str, ...] | list[str] = ("world",)) -> rrb.Blueprint:
    """The default blueprint: one tab per entity family the recording holds.

    Parameters
    ----------
    families : sequence of str
        Any of ``world``, ``coverage``, ``bff``, ``trajectories``, ``training``, ``planner``.
    """
    unknown = set(families) - set(FAMILIES)
    if unknown:
        raise ValueError(f"unknown recording families {sorted(unknown)}")
    tabs: list[Any] = []
    if "world" in families:
        tabs.append(
            rrb.Spatial3DView(
                name="Scene and rays", origin=Entity.WORLD, contents=["world/**", "- world/coverage/**"]
            )
        )
    if "coverage" in families:
        tabs.append(rrb.Spatial2DView(name="Coverage", origin=Entity.COVERAGE))
    if "bff" in families:
        tabs.append(
            rrb.Horizontal(
                rrb.TimeSeriesView(name="PDP", origin=Entity.BFF),
                rrb.TensorView(name="Fingerprint", origin=Entity.BFF),
            )
        )
    if "trajectories" in families:
        tabs.append(
            rrb.Spatial2DView(name="Trajectories", origin="/", contents=["trajectories/**", "map/**"])
        )
    if "training" in families:
        tabs.append(rrb.TimeSeriesView(name="Training", origin=Entity.TRAINING))
    if "planner" in families:
        tabs.append(
            rrb.Horizontal(
                rrb.Spatial2DView(
                    name="Planner", origin="/", contents=["planner/**", "- planner/cost/**", "map/**"]
                ),
                rrb.TimeSeriesView(name="Cost", origin=Entity.PLANNER_COST),
                column_shares=[3, 1],
            )
        )
    return rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=False)


class Recording:
    """A headless Rerun recording written to ``path`` with the project's blueprint.

    Use as a context manager; the file appears at ``path`` only when the block
    ends without an exception.

    Parameters
    ----------
    path : path-like
        Target ``.rrd`` file.
    name : str
        What the recording shows, e.g. ``"scene"``; part of the recording id.
    families : sequence of str
        Tabs of the default blueprint (see :func:`blueprint`).
    config : dict or pydantic model, optional
        Resolved config stored at ``meta/config`` with its content hash.
    """

    def __init__(self, path: str | os.PathLike, name: str, families=("world",), config: Any = None):
        self.path = Path(path)
        if self.path.suffix != ".rrd":
            raise MmwsimError(f"{self.path}: a recording must end in .rrd")
        parent = self.path.parent
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            raise MmwsimError(f"{self.path}: folder {parent} does not exist or is not writable")
        self._tmp = self.path.with_name(f".{self.path.name}.partial")
        rid = f"{name}-{content_hash(config)[:16]}" if config is not None else name
        self.stream = rr.RecordingStream(APP_ID, recording_id=rid)
        self.stream.save(str(self._tmp), default_blueprint=blueprint(tuple(families)))
        if config is not None:
            text = canonical_json(config)
            self.stream.log(
                Entity.CONFIG,
                rr.TextDocument(f"content hash {content_hash(config)}\n\n{text}"),
                static=True,
            )

    def log(self, entity: str, *args: Any, **kwargs: Any) -> None:
        """Log to the underlying stream (see ``rerun.RecordingStream.log``)."""
        self.stream.log(entity, *args, **kwargs)

    def set_time(self, timeline: str, value: int) -> None:
        """Set a sequence timeline (``beam``, ``step``, ``epoch``, ``iteration``)."""
        self.stream.set_time(timeline, sequence=int(value))

    def close(self, keep: bool = True) -> None:
        """Finish the file (footer) and move it into place, or drop it."""
        self.stream.disconnect()
        if keep:
            os.replace(self._tmp, self.path)
        else:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(keep=exc_type is None)


def log_scene(rec: Recording, scene: Scene) -> None:
    """Scene meshes coloured by material, transmitter, receiver-grid outline and footprints (static)."""
    verts, faces = scene.vertices.astype(np.float32), scene.faces
    mat_of_face = np.array([o.material.name for o in scene.objects])[scene.face_object] if len(faces) else []
    for name in sorted(set(mat_of_face)):
        sel = faces[np.asarray(mat_of_face) == name]
        used, inverse = np.unique(sel, return_inverse=True)
        rec.log(
            Entity.scene_material(name),
            rr.Mesh3D(
                vertex_positions=verts[used],
                triangle_indices=inverse.reshape(-1, 3).astype(np.uint32),
                albedo_factor=(*material_color(name), 255),
            ),
            static=True,
        )
    if scene.transmitter is not None:
        rec.log(
            Entity.TX,
            rr.Points3D([scene.transmitter.position], radii=1.5, colors=[(230, 40, 40)], labels=["TX"]),
            static=True,
        )
    g = scene.receivers
    (x0, y0), (x1, y1) = g.bounds
    outline = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])
    rec.log(
        Entity.RX_GRID,
        rr.LineStrips3D(
            [np.column_stack([outline, np.full(5, g.height)])],
            colors=[(40, 160, 240)],
            radii=0.3,
            labels=[f"{g.shape[0]} x {g.shape[1]} receivers, {g.spacing:g} m"],
        ),
        static=True,
    )
    log_footprints(rec, scene)


def log_footprints(rec: Recording, scene: Scene) -> None:
    """Building footprints as 2D line strips at ``map/footprints`` (context for 2D views)."""
    strips = [np.asarray(p.exterior.coords) for p in scene.footprints]
    strips += [np.asarray(r.coords) for p in scene.footprints for r in p.interiors]
    if strips:
        rec.log(Entity.FOOTPRINTS, rr.LineStrips2D(strips, colors=[(120, 120, 120)], radii=0.3), static=True)
