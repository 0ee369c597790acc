"""Rerun recordings: the one place that owns entity paths, timelines and the blueprint.

Every stage logs into one entity tree::

    meta/config                       resolved config (text)
    world/scene/<material>            scene meshes (shaded; a colour per material, ground darker)
    world/scene/wedges                diffracting edges, the used ones highlighted
    world/tx                          transmitter; world/tx/pattern: the beam's 3D lobe (beam timeline)
    world/rx_grid                     receiver-grid outline
    world/rays/paths, world/rays/candidates, world/rays/diffuse_tiles
    world/coverage/...                received-power maps, draped over the receiver plane in 3D
    map/footprints                    building footprints in 2D; trajectories/map and planner/map:
                                      the outlines around what those views show
    bff/<receiver>/...                PDP and fingerprint images per receiver
    trajectories/<id>/{true,<model>}  whole tracks (static), trail and head on the step timeline
    training/<model>/...              per-epoch scalars (epoch timeline); training/per_epoch/... bar charts
    planner/{tree,ellipse,path}       search on the iteration timeline; planner/result/... its end (static)
    planner/{optimum,corridor,endpoints,summary,cost}
    legend/<tab>/<group>              colour keys shown beside the views of a tab

The viewer has one active timeline for all tabs, so every view shows static content that reads
on its own (final state, whole tracks, bar charts) and the timelines animate on top of it: a tab
never comes up empty whichever timeline is active.

Recordings are written headless to a temporary file next to the target and
renamed into place when complete, so a failed run never leaves a half-written
``.rrd`` where a result is expected.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .config import canonical_json, content_hash
from .errors import MmwsimError
from .files import RECORDING_SUFFIX, check_suffix
from .materials import material_color

if TYPE_CHECKING:
    from .scene import Scene

__all__ = [
    "APP_ID",
    "FAMILIES",
    "Recording",
    "Timeline",
    "Entity",
    "blueprint",
    "camera",
    "colorize",
    "log_colorbar",
    "log_legend",
    "log_map_context",
    "log_scene",
    "log_footprints",
    "log_track",
    "north_up",
    "scene_colors",
]

APP_ID = "mmwsim"
NO_DATA_RGB = (45, 45, 50)
"""Colour of map cells and bins without data (indoors, no signal)."""
LABEL_RGB = (210, 210, 210)


class Timeline:
    """Timeline names; each row carries at most one of them."""

    BEAM = "beam"
    STEP = "step"
    EPOCH = "epoch"
    ITERATION = "iteration"


class Entity:
    """Entity paths of the project's one entity tree."""

    CONFIG = "meta/config"
    WORLD = "world"
    SCENE = "world/scene"
    WEDGES = "world/scene/wedges"
    TX = "world/tx"
    TX_PATTERN = "world/tx/pattern"
    RX_GRID = "world/rx_grid"
    RAYS = "world/rays"
    RAY_PATHS = "world/rays/paths"
    RAY_CANDIDATES = "world/rays/candidates"
    DIFFUSE_TILES = "world/rays/diffuse_tiles"
    COVERAGE = "world/coverage"
    MAP = "map"
    FOOTPRINTS = "map/footprints"
    BFF = "bff"
    TRAJECTORIES = "trajectories"
    TRAINING = "training"
    TRAINING_BARS = "training/per_epoch"
    PLANNER = "planner"
    PLANNER_TREE = "planner/tree"
    PLANNER_ELLIPSE = "planner/ellipse"
    PLANNER_PATH = "planner/path"
    PLANNER_COST = "planner/cost"
    PLANNER_OPTIMUM = "planner/optimum"
    PLANNER_CORRIDOR = "planner/corridor"
    PLANNER_ENDPOINTS = "planner/endpoints"
    PLANNER_RESULT = "planner/result"
    PLANNER_SUMMARY = "planner/summary"
    LEGEND = "legend"

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

    @staticmethod
    def training_bars(what: str, model: str) -> str:
        """Bar chart of ``what`` per epoch, grouped by quantity so one view shows every model."""
        return f"{Entity.TRAINING_BARS}/{what}/{model}"

    @staticmethod
    def legend(tab: str, group: str) -> str:
        return f"{Entity.LEGEND}/{tab}/{group}"


FAMILIES = ("world", "coverage", "bff", "trajectories", "training", "planner")

# The timeline a recording's time panel opens on: the first family present in this order.
_TIMELINE_OF = (
    ("coverage", Timeline.BEAM),
    ("trajectories", Timeline.STEP),
    ("bff", Timeline.BEAM),
    ("planner", Timeline.ITERATION),
    ("training", Timeline.EPOCH),
)
# Playback speed in ticks per second: a slow looping beam sweep, 1 Hz motion at 2x, a search in ~6 s.
_PLAYBACK = {
    Timeline.BEAM: (4.0, "All"),
    Timeline.STEP: (2.0, "Off"),
    Timeline.ITERATION: (100.0, "Off"),
    Timeline.EPOCH: (4.0, "Off"),
}


def camera(extent: np.ndarray | Sequence[Sequence[float]]) -> rrb.EyeControls3D:
    """An orbit camera south of a scene box looking north and down at about 40 degrees.

    Parameters
    ----------
    extent : (2, 3) float
        Lower and upper corners of the scene, metres.
    """
    (x0, y0, z0), (x1, y1, _) = np.asarray(extent, dtype=np.float64)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, z0])
    span = max(x1 - x0, y1 - y0, 1.0)
    return rrb.EyeControls3D(
        kind="Orbital",
        position=centre + span * np.array([0.0, -0.85, 0.75]),
        look_target=centre,
        eye_up=[0.0, 0.0, 1.0],
    )


def _legend_view(tab: str) -> rrb.Spatial2DView:
    return rrb.Spatial2DView(name="Legend", origin=f"{Entity.LEGEND}/{tab}", background=[20, 20, 24])


def blueprint(
    families: Sequence[str] = ("world",),
    extent: np.ndarray | None = None,
    timeline: str | None = None,
    config: bool = True,
) -> rrb.Blueprint:
    """The default blueprint: one named tab per entity family the recording holds.

    Every view shows content whatever timeline is active (see the module docstring), and every
    tab with colours has a legend beside it.

    Parameters
    ----------
    families : sequence of str
        Any of ``world``, ``coverage``, ``bff``, ``trajectories``, ``training``, ``planner``.
    extent : (2, 3) float, optional
        Scene box the 3D camera frames, metres; without one the viewer frames the content itself.
    timeline : str, optional
        Timeline the time panel opens on; by default the one of the first family that has one.
    config : bool
        Add a tab with the resolved configuration (``meta/config``).
    """
    unknown = set(families) - set(FAMILIES)
    if unknown:
        raise ValueError(f"unknown recording families {sorted(unknown)}")
    tabs: list[Any] = []
    if "world" in families:
        eye = None if extent is None else camera(extent)
        tabs.append(
            rrb.Horizontal(
                rrb.Spatial3DView(
                    name="Scene, rays and coverage" if "coverage" in families else "Scene and rays",
                    origin=Entity.WORLD,
                    contents=["world/**", f"- {Entity.coverage('best_beam')}"],
                    eye_controls=eye,
                ),
                _legend_view("scene"),
                column_shares=[4, 1],
                name="Scene",
            )
        )
    if "coverage" in families:
        tabs.append(
            rrb.Horizontal(
                rrb.Spatial2DView(
                    name="Received power of the current beam, dBm (no beam timeline: of the best beam)",
                    origin=Entity.COVERAGE,
                    contents=["$origin/beam_power", "$origin/best_power"],
                ),
                rrb.Spatial2DView(name="Best beam", origin=Entity.COVERAGE, contents=["$origin/best_beam"]),
                _legend_view("coverage"),
                column_shares=[5, 5, 2],
                name="Coverage",
            )
        )
    if "bff" in families:
        tabs.append(
            rrb.Horizontal(
                rrb.Spatial2DView(name="PDP (dBm) and fingerprint, beam x delay bin", origin=Entity.BFF),
                _legend_view("bff"),
                column_shares=[5, 1],
                name="Fingerprints",
            )
        )
    if "trajectories" in families:
        tabs.append(
            rrb.Horizontal(
                # Origin at the root: the north-up mirror sits on `trajectories` itself.
                rrb.Spatial2DView(name="Trajectories", origin="/", contents=["trajectories/**"]),
                _legend_view("trajectories"),
                column_shares=[5, 1],
                name="Trajectories",
            )
        )
    if "training" in families:
        bars = Entity.TRAINING_BARS
        tabs.append(
            rrb.Vertical(
                rrb.BarChartView(name="Loss per epoch (train, validation)", origin=f"{bars}/loss"),
                rrb.Horizontal(
                    rrb.BarChartView(name="Validation RMSE per epoch, m", origin=f"{bars}/rmse_m"),
                    rrb.BarChartView(name="Learning rate per epoch", origin=f"{bars}/learning_rate"),
                    name="RMSE and learning rate",
                ),
                name="Training",
            )
        )
    if "planner" in families:
        tabs.append(
            rrb.Horizontal(
                rrb.Spatial2DView(
                    name="Planner",
                    origin="/",
                    contents=["planner/**", f"- {Entity.PLANNER_COST}/**", f"- {Entity.PLANNER_SUMMARY}"],
                ),
                rrb.Vertical(
                    rrb.TextDocumentView(name="Result", origin=Entity.PLANNER_SUMMARY),
                    rrb.BarChartView(name="Path length above the optimum, m", origin=Entity.PLANNER_COST),
                    _legend_view("planner"),
                    row_shares=[1, 2, 3],
                    name="Result, cost and legend",
                ),
                column_shares=[3, 1],
                name="Planner",
            )
        )
    if config:
        tabs.append(rrb.TextDocumentView(name="Config", origin=Entity.CONFIG))
    if timeline is None:
        timeline = next((t for fam, t in _TIMELINE_OF if fam in families), None)
    fps, loop = _PLAYBACK.get(timeline, (None, None))
    time_panel = rrb.TimePanel(
        state="collapsed" if timeline else "hidden", timeline=timeline, fps=fps, loop_mode=loop
    )
    return rrb.Blueprint(
        rrb.Tabs(*tabs, name="mmwsim"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        time_panel,
    )


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
    extent : (2, 3) float, optional
        Scene box the 3D view's camera frames (recordings with the ``world`` family).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        name: str,
        families=("world",),
        config: Any = None,
        extent: np.ndarray | None = None,
    ):
        self.path = check_suffix(path, RECORDING_SUFFIX)
        parent = self.path.parent
        if not parent.is_dir() or not os.access(parent, os.W_OK):
            raise MmwsimError(f"{self.path}: folder {parent} does not exist or is not writable")
        self._tmp = self.path.with_name(f".{self.path.name}.partial")
        self._legend: dict[str, dict[str, tuple[int, int]]] = {}
        rid = f"{name}-{content_hash(config)[:16]}" if config is not None else name
        self.stream = rr.RecordingStream(APP_ID, recording_id=rid)
        # Only our own timelines: rows keyed by wall-clock time would be one more timeline to pick.
        self.stream.set_log_time_enabled(False)
        self.stream.set_log_tick_enabled(False)
        bp = blueprint(tuple(families), extent=extent, config=config is not None)
        self.stream.save(str(self._tmp), default_blueprint=bp)
        if config is not None:
            pretty = json.dumps(json.loads(canonical_json(config)), indent=2)
            self.stream.log(
                Entity.CONFIG,
                rr.TextDocument(
                    f"content hash `{content_hash(config)}`\n\n```json\n{pretty}\n```\n",
                    media_type="text/markdown",
                ),
                static=True,
            )

    def log(self, entity: str, *args: Any, **kwargs: Any) -> None:
        """Log to the underlying stream (see ``rerun.RecordingStream.log``)."""
        self.stream.log(entity, *args, **kwargs)

    def set_time(self, timeline: str, value: int) -> None:
        """Put the next rows on one sequence timeline (``beam``, ``step``, ``epoch``, ``iteration``).

        Any other timeline set before is cleared: the timelines are independent, and a row that
        carried, say, the last beam and a step would also show on the beam timeline.
        """
        self.stream.reset_time()
        self.stream.set_time(timeline, sequence=int(value))

    def legend_row(self, tab: str, group: str, rows: int) -> int:
        """First row of legend ``group`` (``rows`` rows) in ``tab``'s legend, below the groups
        logged before; a group logged again keeps its place."""
        groups = self._legend.setdefault(tab, {})
        if group in groups and groups[group][1] >= rows:
            return groups[group][0]
        start = max((r + h + 1 for r, h in groups.values()), default=0)
        groups[group] = (start, rows)
        return start

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


# ---------------------------------------------------------------------- colours and legends
LEGEND_WIDTH = 8.0
"""Width of a legend group (colour bars span it), in the legend view's units (one unit per row)."""
_SWATCH = 1.5
_PITCH = 1.6  # legend units per row: labels are drawn at a fixed pixel size and need the room
_LABEL_LIFT = 0.35  # the viewer draws a point's label below it; lift it level with its swatch


def colorize(
    values: np.ndarray, cmap: Any, lo: float, hi: float, valid: np.ndarray | None = None
) -> np.ndarray:
    """Values mapped linearly from ``lo..hi`` onto a matplotlib colour map, clipped at both ends.

    Parameters
    ----------
    values : (...) float
    cmap : str or matplotlib Colormap
        Colour map or its name (``viridis``, ``twilight``, ...).
    lo, hi : float
        Values shown with the first and the last colour.
    valid : (...) bool, optional
        Cells to colour; the others (and non-finite values) get :data:`NO_DATA_RGB`.

    Returns
    -------
    (..., 3) uint8 RGB
    """
    import matplotlib

    v = np.asarray(values, dtype=np.float64)
    cm = matplotlib.colormaps[cmap] if isinstance(cmap, str) else cmap
    rgb = cm(np.clip((v - lo) / (hi - lo), 0.0, 1.0), bytes=True)[..., :3]
    ok = np.isfinite(v) if valid is None else np.isfinite(v) & np.asarray(valid, dtype=bool)
    rgb[~ok] = NO_DATA_RGB
    return np.ascontiguousarray(rgb)


def _legend_group(rec: Recording, tab: str, group: str, title: str, rows: int) -> str:
    row = rec.legend_row(tab, group, rows + 1)
    base = Entity.legend(tab, group)
    rec.log(base, rr.Transform3D(translation=[0.0, row * _PITCH, 0.0]), static=True)
    # The title, and two invisible corners that make every legend as wide as LEGEND_WIDTH: a 2D
    # view frames its content, and labels (drawn in screen pixels) would spill out of a narrower one.
    rec.log(
        f"{base}/title",
        rr.Points2D(
            [[LEGEND_WIDTH / 2, -_LABEL_LIFT]],
            radii=0.01,
            colors=[LABEL_RGB],
            labels=[title],
            show_labels=True,
        ),
        static=True,
    )
    rec.log(
        f"{base}/frame",
        rr.Points2D(
            [[-0.5, -0.5], [LEGEND_WIDTH + 0.5, (rows + 0.5) * _PITCH]], radii=0.01, colors=[(0, 0, 0, 0)]
        ),
        static=True,
    )
    return base


def log_legend(
    rec: Recording, tab: str, group: str, title: str, entries: Sequence[tuple[str, Sequence[int]]]
) -> None:
    """A colour key at ``legend/<tab>/<group>``: a title, then one coloured swatch per entry with
    its label beside it, below the groups logged into the same tab's legend before.

    Parameters
    ----------
    rec : Recording
    tab : str
        Legend of which tab (``scene``, ``coverage``, ``bff``, ``trajectories``, ``planner``).
    group : str
        Name of the key within the tab; logging the same group again replaces it in place.
    title : str
    entries : sequence of (label, (r, g, b))
    """
    if not entries:
        return
    base = _legend_group(rec, tab, group, title, len(entries))
    y = _PITCH * (1.0 + np.arange(len(entries)))
    rec.log(
        f"{base}/swatches",
        rr.LineStrips2D(
            [np.array([[0.0, yi], [_SWATCH, yi]]) for yi in y],
            colors=[tuple(c)[:3] for _, c in entries],
            radii=0.3,
        ),
        static=True,
    )
    rec.log(
        f"{base}/labels",
        rr.Points2D(
            np.column_stack([np.full(len(y), (_SWATCH + LEGEND_WIDTH) / 2 + 0.5), y - _LABEL_LIFT]),
            radii=0.01,
            colors=[LABEL_RGB],
            labels=[label for label, _ in entries],
            show_labels=True,
        ),
        static=True,
    )


def log_colorbar(
    rec: Recording,
    tab: str,
    group: str,
    title: str,
    cmap: Any,
    lo: float,
    hi: float,
    ticks: Sequence[str] | None = None,
) -> None:
    """A colour bar for :func:`colorize` (``cmap`` over ``lo..hi``) in ``tab``'s legend.

    ``ticks`` label the left end, the middle and the right end (default: the values).
    """
    base = _legend_group(rec, tab, group, title, 2)
    # As many pixels as legend units, smoothed by the viewer: a 2D view frames its largest image's
    # pixel size, so a wider ramp would shrink the whole legend.
    # Two rows: a single-row image would be read as a greyscale column (unit axes are dropped).
    n = int(LEGEND_WIDTH)
    ramp = colorize(np.repeat(np.linspace(lo, hi, n)[None, :], 2, axis=0), cmap, lo, hi)
    rec.log(
        f"{base}/bar",
        rr.Transform3D(translation=[0.0, 0.9 * _PITCH, 0.0], scale=[LEGEND_WIDTH / n, 0.2, 1.0]),
        rr.Image(ramp, magnification_filter="Linear"),
        static=True,
    )
    if ticks is None:
        ticks = [f"{lo:g}", f"{(lo + hi) / 2:g}", f"{hi:g}"]
    rec.log(
        f"{base}/ticks",
        rr.Points2D(
            np.array([[0.0, 1.0], [LEGEND_WIDTH / 2, 1.0], [LEGEND_WIDTH, 1.0]]) * [1.0, 1.5 * _PITCH],
            radii=0.01,
            colors=[LABEL_RGB],
            labels=list(ticks),
            show_labels=True,
        ),
        static=True,
    )


# ---------------------------------------------------------------------- scene
_GROUND_TONE = np.array([58.0, 62.0, 70.0])
_BUILDING_TONE = np.array([235.0, 230.0, 220.0])


def scene_colors(scene: Scene) -> np.ndarray:
    """Display colour of each scene object: its material's colour, darkened towards a blue-grey
    for ground, lightened for buildings with a per-building brightness (so that neighbours of
    one material still differ).

    Returns
    -------
    (n_objects, 3) uint8 RGB
    """
    base = np.array([material_color(o.material.name) for o in scene.objects], dtype=np.float64)
    kind = np.array([o.kind for o in scene.objects])
    # Golden-ratio spread: neighbouring indices get well separated brightnesses, deterministically.
    tint = 0.86 + 0.26 * ((np.arange(len(base)) * 0.6180339887) % 1.0)
    building = (0.7 * base + 0.3 * _BUILDING_TONE) * tint[:, None]
    ground = 0.4 * base + 0.6 * _GROUND_TONE
    out = np.where(
        (kind == "ground")[:, None], ground, np.where((kind == "building")[:, None], building, base)
    )
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def log_scene(rec: Recording, scene: Scene) -> None:
    """Scene meshes (one entity per material, flat-shaded with face normals, coloured by
    :func:`scene_colors`), transmitter, receiver-grid outline, footprints and the scene legend
    (all static)."""
    if scene.n_triangles:
        tri = scene.vertices[scene.faces].astype(np.float32)  # unmerged: one normal per face
        normals = scene.face_normals.astype(np.float32)
        colours = scene_colors(scene)[scene.face_object]
        materials = np.array([o.material.name for o in scene.objects])[scene.face_object]
        for name in sorted(set(materials.tolist())):
            sel = materials == name
            rec.log(
                Entity.scene_material(name),
                rr.Mesh3D(
                    vertex_positions=tri[sel].reshape(-1, 3),
                    vertex_normals=np.repeat(normals[sel], 3, axis=0),
                    vertex_colors=np.repeat(colours[sel], 3, axis=0),
                ),
                static=True,
            )
        colours = scene_colors(scene)
        shown: dict[str, tuple[int, ...]] = {}
        for o, c in zip(scene.objects, colours, strict=True):
            shown.setdefault(f"{o.material.name} {o.kind}", tuple(int(v) for v in c))
        log_legend(rec, "scene", "materials", "scene (material, kind)", sorted(shown.items()))
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
            show_labels=False,
        ),
        static=True,
    )
    log_footprints(rec, scene)


def log_footprints(rec: Recording, scene: Scene) -> None:
    """Building footprints as 2D line strips at ``map/footprints`` (context for 2D views).

    2D views draw y downwards; ``map`` (like ``trajectories`` and ``planner``) is mirrored so
    that north is up while the logged coordinates stay in metres.
    """
    strips = [np.asarray(p.exterior.coords) for p in scene.footprints]
    strips += [np.asarray(r.coords) for p in scene.footprints for r in p.interiors]
    if strips:
        north_up(rec, Entity.MAP)
        rec.log(Entity.FOOTPRINTS, rr.LineStrips2D(strips, colors=[(110, 110, 118)], radii=0.3), static=True)


def north_up(rec: Recording, root: str) -> None:
    """Mirror the 2D entity subtree ``root`` in y so that maps show north up (static)."""
    rec.log(root, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)


def log_map_context(
    rec: Recording, root: str, footprints: Sequence[Any], points: np.ndarray, margin: float = 25.0
) -> None:
    """Building outlines around ``points`` at ``<root>/map`` (static), as backdrop of a 2D view.

    A view framed on the whole city would show a short trajectory or a planned path as a speck;
    clipping the outlines to the data (plus ``margin`` metres) lets the view open on the data.

    Parameters
    ----------
    rec : Recording
    root : str
        ``trajectories`` or ``planner``.
    footprints : sequence of shapely Polygon
    points : (n, 2) float
        What the view shows, metres.
    margin : float
    """
    import shapely

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(footprints) or not len(pts):
        return
    (x0, y0), (x1, y1) = pts.min(axis=0) - margin, pts.max(axis=0) + margin
    lines = shapely.clip_by_rect(shapely.boundary(np.asarray(list(footprints), dtype=object)), x0, y0, x1, y1)
    strips = [np.asarray(g.coords) for g in shapely.get_parts(lines) if not g.is_empty and len(g.coords) > 1]
    if strips:
        rec.log(f"{root}/map", rr.LineStrips2D(strips, colors=[(110, 110, 118)], radii=0.3), static=True)


def log_track(
    rec: Recording,
    entity: str,
    positions: np.ndarray,
    colour: Sequence[int],
    label: str | None = None,
    width: float = 1.2,
    alpha: int = 255,
    trail: float = 2.0,
    head: float = 4.5,
) -> None:
    """One trajectory: the whole track at ``entity`` (static), and at ``entity/now`` on the
    ``step`` timeline, at step k, the trail ``positions[:k+1]`` and the head ``positions[k]``.

    Parameters
    ----------
    rec : Recording
    entity : str
        e.g. :meth:`Entity.trajectory` ``(id, source)``.
    positions : (L, 2) float, metres
    colour : (r, g, b)
    label : str, optional
        Shown on hover.
    width, trail, head : float
        Screen points: the static track's line, the trail's line and the head's radius.
    alpha : int
        Opacity of the static track (0..255).
    """
    pos = np.asarray(positions, dtype=np.float32).reshape(-1, 2)
    rgb = tuple(int(c) for c in colour[:3])
    rec.log(
        entity,
        rr.LineStrips2D(
            [pos],
            colors=[(*rgb, int(alpha))],
            radii=rr.Radius.ui_points(width),
            labels=[label] if label else None,
            show_labels=False,
        ),
        static=True,
    )
    steps = np.arange(len(pos))
    # One columnar call per track: row k holds the trail up to step k and the head.
    columns = [
        *rr.LineStrips2D.columns(
            strips=[pos[: k + 1] for k in steps],
            colors=[rgb] * len(pos),
            radii=rr.Radius.ui_points(np.full(len(pos), trail)),
        ),
        *rr.Points2D.columns(
            positions=pos,
            colors=[rgb] * len(pos),
            radii=rr.Radius.ui_points(np.full(len(pos), head)),
            labels=[label] * len(pos) if label else None,
            show_labels=np.zeros(len(pos), dtype=bool),
        ),
    ]
    rec.stream.send_columns(
        f"{entity}/now", indexes=[rr.TimeColumn(Timeline.STEP, sequence=steps)], columns=columns
    )
