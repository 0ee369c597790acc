"""Trajectory generators: pedestrian, hybrid, vehicle (free or on the street network) and static.

Every kind follows the same per-step event model (:class:`~.motion.MotionModel`): with the
per-second probabilities scaled by the step duration, a step is a stop, a turn, a speed
change or no change. Unlike the reference generator, a speed change always changes the speed,
and every segment between two samples (not only its end points) is checked against the
buildings. A step that would cross a building or leave the area is retried with a new heading
(the deviation widening with every try, up to a U-turn); a trajectory that still cannot move,
or a vehicle route whose chord cuts a corner, is regenerated from a new start. All of it is
vectorised over trajectories; only the failures are redrawn.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..geometry.freespace import CoverageMask, FreeSpace, scene_obstacles
from ..limits import check_fits
from .errors import TrajectoryError
from .motion import AVOID, KINDS, MOTION_MODELS, NONE, ROAD, SPEED, STOP, TURN, MotionModel, motion_model
from .streets import STREET_HALF_WIDTH, StreetNetwork
from .trajectories import Trajectories

if TYPE_CHECKING:
    from ..dataset import Dataset
    from ..scene import Scene

__all__ = ["MIN_LENGTH", "MAX_LENGTH", "generate", "generate_for_dataset", "generate_kind"]

MIN_LENGTH = 3
MAX_LENGTH = 30
_MAX_ROUNDS = 60
# Peak bytes per trajectory sample while generating (positions, events, headings, draws and the
# segment checks' temporaries; about 90 measured for pedestrians, with margin).
_BYTES_PER_STEP = 256
_MAX_AVOID = 12


def check_length(length: int) -> int:
    """Validate a trajectory length (samples), or raise a one-line error."""
    if isinstance(length, bool) or not isinstance(length, (int, np.integer)):
        raise TrajectoryError(f"trajectory length must be an integer, got {length!r}")
    if not MIN_LENGTH <= length <= MAX_LENGTH:
        raise TrajectoryError(f"trajectory length must be {MIN_LENGTH}..{MAX_LENGTH} steps, got {length}")
    return int(length)


def _speed_process(
    model: MotionModel, n: int, length: int, dt: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Events, step lengths, turn signs and restart flags of ``n`` users over ``length - 1`` steps.

    Returns
    -------
    events : (n, L-1) int8
    steps : (n, L-1) float64, metres travelled in each step
    turn : (n, L-1) float64, heading change of each step, radians (0 where none)
    restart : (n, L-1) bool, the step begins after a stop (new random heading, mean speed)
    """
    k = length - 1
    u = rng.random((n, k))
    sign = rng.integers(0, 2, size=(n, k)) * 2 - 1
    cut = np.cumsum([model.p_stop, model.p_turn, model.p_speed]) * dt
    events = np.full((n, k), NONE, dtype=np.int8)
    events[u < cut[2]] = SPEED
    events[u < cut[1]] = TURN
    events[u < cut[0]] = STOP
    lo, hi, dv = model.speed_floor, model.max_speed, model.speed_change * dt
    speed = np.full(n, model.mean_speed)
    steps = np.empty((n, k))
    restart = np.zeros((n, k), dtype=bool)
    for j in range(k):
        if j > 0:
            restart[:, j] = events[:, j - 1] == STOP
            speed[restart[:, j]] = model.mean_speed
        s = sign[:, j].astype(np.float64)
        # The sign is forced where the other one would leave the speed range: a change always changes.
        s[speed + dv > hi + 1e-12] = -1.0
        s[speed - dv < lo - 1e-12] = 1.0
        change = events[:, j] == SPEED
        speed[change] += s[change] * dv
        steps[:, j] = np.where(events[:, j] == STOP, 0.0, speed * dt)
    turn = np.where(events == TURN, sign * math.radians(model.turn_rate) * dt, 0.0)
    return events, steps, turn, restart


def _attempt_free(
    model: MotionModel, n: int, length: int, dt: float, fs: FreeSpace, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One vectorised attempt for ``n`` users moving freely; returns positions, events, success."""
    pos = fs.sample(n, rng)
    out = np.empty((n, length, 2))
    out[:, 0] = pos
    if not model.moving:
        out[:] = pos[:, None]
        return out, np.zeros((n, length - 1), dtype=np.int8), np.ones(n, dtype=bool)
    events, steps, turn, restart = _speed_process(model, n, length, dt, rng)
    fresh = rng.uniform(0.0, 2.0 * np.pi, size=(n, length))
    heading = fresh[:, 0].copy()
    alive = np.ones(n, dtype=bool)
    for j in range(length - 1):
        heading = np.where(restart[:, j], fresh[:, j + 1], heading) + turn[:, j]
        step = steps[:, j]
        nxt = pos + step[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        bad = alive.copy()
        bad[alive] = ~fs.segments_ok(pos[alive], nxt[alive])
        for t in range(1, _MAX_AVOID + 1):
            if not bad.any():
                break
            idx = np.flatnonzero(bad)
            h = heading[idx] + rng.uniform(-1.0, 1.0, len(idx)) * np.pi * t / _MAX_AVOID
            cand = pos[idx] + step[idx, None] * np.column_stack([np.cos(h), np.sin(h)])
            good = fs.segments_ok(pos[idx], cand)
            gi = idx[good]
            heading[gi], nxt[gi], bad[gi] = h[good], cand[good], False
            events[gi, j] = AVOID
        alive &= ~bad
        pos = nxt
        out[:, j + 1] = pos
    return out, events, alive


def _attempt_streets(
    model: MotionModel,
    n: int,
    length: int,
    dt: float,
    fs: FreeSpace,
    net: StreetNetwork,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One attempt for ``n`` vehicles following the street network."""
    events, steps, _, _ = _speed_process(model, n, length, dt, rng)
    events[events == TURN] = ROAD  # the streets decide the heading
    arc = np.concatenate([np.zeros((n, 1)), np.cumsum(steps, axis=1)], axis=1)
    pts, cum = net.random_routes(n, arc[:, -1] + 1e-6, rng)
    out = np.empty((n, length, 2))
    rows = np.arange(n)
    last = cum.shape[1] - 2
    for k in range(length):
        j = np.clip((cum <= arc[:, k, None]).sum(axis=1) - 1, 0, last)
        seg = cum[rows, j + 1] - cum[rows, j]
        f = np.divide(arc[:, k] - cum[rows, j], seg, out=np.zeros(n), where=seg > 0)
        out[:, k] = pts[rows, j] + np.clip(f, 0.0, 1.0)[:, None] * (pts[rows, j + 1] - pts[rows, j])
    # Chords between samples may cut a corner of the centre line: check them like any other step.
    a = out[:, :-1].reshape(-1, 2)
    b = out[:, 1:].reshape(-1, 2)
    ok = fs.segments_ok(a, b).reshape(n, length - 1).all(axis=1)
    return out, events, ok


def generate_kind(
    scene: Scene | None,
    kind: str | MotionModel,
    n: int,
    length: int,
    rng: np.random.Generator,
    rate_hz: float = 1.0,
    coverage: CoverageMask | None = None,
    streets: StreetNetwork | None = None,
    free_space: FreeSpace | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` trajectories of one kind.

    Parameters
    ----------
    scene : Scene
        Obstacles (:func:`~mmwsim.geometry.scene_obstacles`) and area (receiver-grid bounds); may be None when
        ``free_space`` is given.
    kind : str or MotionModel
        ``pedestrian``, ``vehicle``, ``hybrid``, ``static`` or a custom model.
    n, length : int
        Number of trajectories and samples per trajectory.
    rng : numpy.random.Generator
    rate_hz : float
        Samples per second.
    coverage : CoverageMask, optional
        Every sample must lie nearest to a valid data-set grid point.
    streets : StreetNetwork, optional
        Vehicles (moving kinds) drive along these centre lines instead of freely.
    free_space : FreeSpace, optional
        Overrides the free space derived from ``scene`` and the model's clearance.

    Returns
    -------
    positions : (n, length, 2) float64, metres
    events : (n, length - 1) int8
    """
    model = motion_model(kind) if isinstance(kind, str) else kind
    length = check_length(length)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise TrajectoryError(f"number of {model.kind} trajectories must be an integer >= 0, got {n!r}")
    model.check_rate(rate_hz)
    dt = 1.0 / rate_hz
    if free_space is None:
        if scene is None:
            raise TrajectoryError("generate_kind needs a scene or a free space")
        free_space = FreeSpace.from_scene(scene, model.clearance, coverage)
    positions = np.empty((n, length, 2))
    events = np.zeros((n, length - 1), dtype=np.int8)
    todo = np.arange(n)
    for _ in range(_MAX_ROUNDS):
        if len(todo) == 0:
            break
        if streets is not None and model.moving:
            p, e, ok = _attempt_streets(model, len(todo), length, dt, free_space, streets, rng)
            # Route starts come from the network, so the coverage/bounds of the samples are checked here.
            ok &= free_space.points_ok(p.reshape(-1, 2)).reshape(len(todo), length).all(axis=1)
        else:
            p, e, ok = _attempt_free(model, len(todo), length, dt, free_space, rng)
        positions[todo[ok]] = p[ok]
        events[todo[ok]] = e[ok]
        todo = todo[~ok]
    if len(todo):
        raise TrajectoryError(
            f"{free_space.name}: could not fit {len(todo)} of {n} {model.kind} trajectories of {length} steps "
            "in the free area (too cramped for this speed?)"
        )
    return positions, events


def generate(
    scene: Scene | None,
    counts: dict[str, int],
    length: int,
    seed: int,
    rate_hz: float = 1.0,
    coverage: CoverageMask | None = None,
    vehicles_on_streets: bool = False,
    models: dict[str, MotionModel] | None = None,
    street_half_width: float = STREET_HALF_WIDTH,
    free_space_bounds: np.ndarray | None = None,
) -> Trajectories:
    """Generate trajectories of several kinds, reproducibly.

    Each kind draws from its own stream (``SeedSequence(seed, spawn_key=(kind code,))``), so
    asking for more vehicles does not change the pedestrians. Ids run over the kinds in
    :data:`~.motion.KINDS` order.

    Parameters
    ----------
    scene : Scene
        Buildings and area (the receiver-grid bounds, or ``free_space_bounds``).
    counts : dict
        Number of trajectories per kind, e.g. ``{"pedestrian": 100, "vehicle": 50}``.
    length : int
        Samples per trajectory, 3..30.
    seed : int
        Same seed and parameters, same arrays.
    rate_hz : float
        Samples per second (1 Hz in the reference).
    coverage : CoverageMask, optional
        Data-set validity; every sample must be nearest to a valid grid point.
    vehicles_on_streets : bool
        Vehicles keep to the street network derived from the free space.
    models : dict, optional
        Motion models by kind, overriding the reference ones.
    street_half_width : float
        Minimum distance of a street centre line from the buildings, metres.
    free_space_bounds : (2, 2) float, optional
        Area instead of the scene's receiver-grid bounds, metres.

    Returns
    -------
    Trajectories
    """
    length = check_length(length)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TrajectoryError(f"seed must be an integer >= 0, got {seed!r}")
    unknown = set(counts) - set(KINDS)
    if unknown:
        raise TrajectoryError(f"unknown trajectory kind {sorted(unknown)[0]!r} (use {', '.join(KINDS)})")
    total = 0
    for kind in KINDS:
        n = counts.get(kind, 0)
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise TrajectoryError(f"number of {kind} trajectories must be an integer >= 0, got {n!r}")
        total += int(n)
    check_fits(total * length * _BYTES_PER_STEP, f"generating {total} trajectories of {length} steps")
    models = {**MOTION_MODELS, **(models or {})}
    bounds = (
        scene.receivers.bounds if free_space_bounds is None else np.asarray(free_space_bounds, dtype=float)
    )
    obstacles = scene_obstacles(scene) if scene is not None else []
    name = f"scene {scene.name!r}" if scene is not None else "area"
    net = None
    parts: list[Trajectories] = []
    next_id = 0
    for code, kind in enumerate(KINDS):
        n = counts.get(kind, 0)
        if n == 0:
            continue
        model = models[kind]
        fs = FreeSpace(obstacles, bounds, model.clearance, coverage, name=name)
        streets = None
        if kind == "vehicle" and vehicles_on_streets:
            if net is None:
                net = (
                    StreetNetwork.from_scene(scene, street_half_width, bounds=bounds)
                    if scene is not None
                    else StreetNetwork.from_footprints([], bounds, street_half_width)
                )
            streets = net
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(code,)))
        pos, ev = generate_kind(None, model, n, length, rng, rate_hz, free_space=fs, streets=streets)
        parts.append(Trajectories(pos, np.full(n, code), np.arange(next_id, next_id + n), ev, rate_hz))
        next_id += n
    if not parts:
        raise TrajectoryError("no trajectories requested: give at least one kind a count > 0")
    attrs = {
        "seed": int(seed),
        "rate_hz": float(rate_hz),
        "length": length,
        "counts": {k: int(counts.get(k, 0)) for k in KINDS},
        "vehicles_on_streets": bool(vehicles_on_streets),
        "street_half_width": float(street_half_width),
        "models": {k: models[k].as_dict() for k in KINDS},
        "scene": None if scene is None else (scene.source or scene.name),
        "bounds": np.asarray(bounds, dtype=float).tolist(),
    }
    return Trajectories.concatenate(parts, attrs)


def generate_for_dataset(
    dataset: Dataset,
    counts: dict[str, int],
    length: int,
    seed: int,
    scene: Scene | None = None,
    **options,
) -> Trajectories:
    """Trajectories in a data set's scene, every sample nearest to a valid grid point.

    The area is the data set's grid (which may be coarser than the scene's own), the
    coverage its validity mask (outdoors and detected), and the buildings those of the scene
    it was generated from (:meth:`mmwsim.dataset.Dataset.scene`).

    Parameters
    ----------
    dataset : Dataset
    counts, length, seed
        As in :func:`generate`.
    scene : Scene, optional
        The data set's scene if already loaded (default: loaded from the data set's config).
    **options
        ``rate_hz``, ``vehicles_on_streets``, ``models``, ``street_half_width`` of :func:`generate`.

    Returns
    -------
    Trajectories
        With ``attrs["dataset"]``, the content hash of the data set they belong to, and
        ``attrs["scene"]``, the scene as the data set names it.
    """
    t = generate(
        dataset.scene() if scene is None else scene,
        counts,
        length,
        seed,
        coverage=CoverageMask.from_dataset(dataset),
        free_space_bounds=dataset.grid.bounds,
        **options,
    )
    t.attrs.update(scene=dataset.config["scene"], dataset=dataset.content_hash)
    return t
