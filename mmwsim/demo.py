"""The end-to-end demo: data set -> trajectories -> transformer -> estimate -> planned path -> one recording.

On the default scene, :func:`run_demo` generates a coarse fingerprint data set, user trajectories
(with a spatial hold-out region), trains the transformer over fingerprint-match candidates
(``tn-match``, the one that generalises to a region without training trajectories) for a few
epochs, estimates the
held-out trajectories from fresh noisy fingerprints, plans a path with Informed RRT* inside the
corridor around one estimated trajectory, and writes everything into one ``.rrd``::

    from mmwsim.demo import run_demo

    result = run_demo("demo", tiny=True)   # under a minute; tiny=False: about 4 minutes on 2 cores
    print(result.rmse_m, result.path_length_m, result.rrd)

Every stage is the library's own (``mmwsim.generate_dataset``, ``mmwsim.trajectories``,
``estimation.train``, ``planning.plan``); this module only chains them. Re-running into the same
folder reuses the finished data set and training run when their settings match and replaces them
when they do not. torch, ompl and the estimation / planning packages are imported inside the
functions, so ``import mmwsim`` stays free of them.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .constants import SIGMA_DB
from .errors import MmwsimError
from .files import RECORDING_SUFFIX, check_suffix, write_text_atomic

if TYPE_CHECKING:
    import planning
    from estimation import SequenceSet

__all__ = [
    "DemoConfig",
    "DemoResult",
    "Estimates",
    "PlannedPath",
    "TrainedRun",
    "check_outputs",
    "demo_config",
    "run_demo",
]

SCENE = "default"
MODEL = "tn-match"
SPLIT = "test/holdout"
RECORDING_FILE = "demo.rrd"
SUMMARY_FILE = "summary.json"


@dataclass(frozen=True)
class DemoConfig:
    """Settings of a demo run (stored in its recording and summary).

    Lengths in metres, noise in dB; ``counts`` maps trajectory kind to number.
    """

    tiny: bool
    seed: int
    scene: str = SCENE
    spacing: float = 2.0
    n_rays: int | None = None
    workers: int = 2
    counts: dict[str, int] = field(default_factory=dict)
    length: int = 7
    # One 100 m block of the block cross-validation (benchmarks/block_cv.py), the one whose mix
    # (line-of-sight / street / vehicle shares of its trajectories, 0.19 / 0.69 / 0.46 against the
    # whole area's 0.34 / 0.62 / 0.42) and block-CV error (0.70 / 1.36 / 1.00 m for tn-match /
    # knn-kalman / match-cv against 0.74 / 1.28 / 0.99 m pooled) are together closest to the
    # area's: the west end of the cross street and shadowed side streets. The block whose mix alone
    # matches best (100,0,200,100) is 1.4x harder than the average.
    holdout_region: tuple[float, float, float, float] = (0.0, 100.0, 100.0, 200.0)
    epochs: int = 12
    epoch_size: int = 2048
    patience: int = 4
    sigma: float = SIGMA_DB
    shown: int = 8
    corridor_width: float = 10.0
    radius: float = 0.5
    iterations: int = 2000
    step: float = 5.0
    snapshots: int = 50

    @property
    def dataset_name(self) -> str:
        return "dataset-tiny.zarr" if self.tiny else "dataset.zarr"

    @property
    def run_name(self) -> str:
        return f"runs/{MODEL}-tiny" if self.tiny else f"runs/{MODEL}"

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def demo_config(tiny: bool = False, seed: int = 0) -> DemoConfig:
    """The full demo (a few minutes on 2 cores) or the tiny one (same chain, well under a minute)."""
    if int(seed) != seed or seed < 0:
        raise MmwsimError(f"--seed must be a non-negative integer, got {seed!r}")
    if tiny:
        return DemoConfig(
            tiny=True,
            seed=int(seed),
            spacing=8.0,
            n_rays=1_000_000,
            workers=1,
            counts={"pedestrian": 300, "vehicle": 300, "hybrid": 100, "static": 20},
            epochs=2,
            epoch_size=256,
            patience=3,
            iterations=600,
            snapshots=20,
        )
    return DemoConfig(
        tiny=False,
        seed=int(seed),
        counts={"pedestrian": 3000, "vehicle": 3000, "hybrid": 1000, "static": 200},
    )


@dataclass
class TrainedRun:
    """The training stage: run folder, the sequence sets it read (``train``, ``validation``, the
    held-out test split and ``test``), its summary and per-epoch history (``train_loss``,
    ``val_loss``, ``val_rmse``, ``lr``, ``seconds``)."""

    run: Path
    sets: dict[str, SequenceSet]
    summary: dict[str, Any]
    history: dict[str, list[float]]


@dataclass
class Estimates:
    """The estimation stage, on the held-out split (``test`` when that is empty).

    Attributes
    ----------
    split : str
    ids : (n,) int64
        Ids of the estimated trajectories.
    pred : (n, L, 2) float64
        Estimated positions, metres.
    rmse : (n,) float64
        Per-trajectory RMSE, metres; ``stats`` summarises it (``n``, ``mean``, ``median``, ``p95``).
    order : (n,) int
        The trajectories in the order they are tried for planning.
    bits : (n, L, M, N_s) bool tensor
        The noisy fingerprints the model was given.
    """

    split: str
    ids: np.ndarray
    pred: np.ndarray
    rmse: np.ndarray
    stats: dict[str, float]
    order: np.ndarray
    bits: Any


@dataclass
class PlannedPath:
    """The planning stage: trajectory ``chosen`` (a row of :attr:`Estimates.pred`), the planner's
    space (its corridor around the estimate), result and the exact optimum; ``target`` says what
    the goal is."""

    chosen: int
    space: planning.AgentSpace
    result: planning.PlanResult
    optimum: planning.ShortestPath | None
    target: str


@dataclass
class DemoResult:
    """What a demo run produced.

    Attributes
    ----------
    out, dataset, run, rrd, summary : Path
        Output folder, data set store, training run folder, recording, ``summary.json``.
    trajectory_id : int
        Id of the held-out trajectory the path was planned along.
    rmse_m : float
        RMSE of its estimate, metres.
    holdout_rmse_m : dict
        ``n``, ``mean``, ``median``, ``p95`` of the per-trajectory RMSE over the held-out split, metres.
    start, goal : (2,) float
        Ends of the planned path, metres; ``target`` says what the goal is.
    path_length_m, optimum_m : float
        Length of the planned path and of the exact shortest path in the same corridor, metres
        (inf when none was found).
    solved : bool
    seconds : dict
        Wall time per stage.
    """

    out: Path
    dataset: Path
    run: Path
    rrd: Path
    summary: Path
    trajectory_id: int
    rmse_m: float
    holdout_rmse_m: dict[str, float]
    start: list[float]
    goal: list[float]
    target: str
    path_length_m: float
    optimum_m: float
    corridor_width_m: float
    solved: bool
    epochs: int
    seconds: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("out", "dataset", "run", "rrd", "summary"):
            d[k] = str(d[k])
        return d


def check_outputs(out: str | os.PathLike, rrd: str | os.PathLike | None = None) -> tuple[Path, Path]:
    """The output folder and recording path, checked before any work; one-line errors."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise MmwsimError(f"--out {out}: exists and is not a folder")
    rrd_path = out / RECORDING_FILE if rrd is None else Path(rrd)
    check_suffix(rrd_path, RECORDING_SUFFIX, "--rrd")
    if rrd_path.exists() and rrd_path.is_dir():
        raise MmwsimError(f"--rrd {rrd_path}: is a folder")
    parent = rrd_path.parent
    if parent.resolve() != out.resolve() and not parent.is_dir():
        raise MmwsimError(f"--rrd {rrd_path}: folder {parent} does not exist")
    for folder in (out, parent):
        probe = folder
        while not probe.exists():
            probe = probe.parent
        if not os.access(probe, os.W_OK):
            raise MmwsimError(f"{folder}: not writable")
    return out, rrd_path


def run_demo(
    out: str | os.PathLike = "demo",
    rrd: str | os.PathLike | None = None,
    tiny: bool = False,
    seed: int = 0,
    progress: bool = True,
    log: Callable[[str], None] = print,
    config: DemoConfig | None = None,
) -> DemoResult:
    """Run the whole chain on the default scene and write one recording.

    Parameters
    ----------
    out : path-like
        Folder for the data set, the training run, ``summary.json`` and (by default) ``demo.rrd``.
    rrd : path-like, optional
        Recording to write (default ``out/demo.rrd``).
    tiny : bool
        The small, fast version (what the tests run).
    seed : int
        Seeds trajectories, training, the evaluation noise and the planner; same seed, same results
        (on CPU).
    progress : bool
        Show progress bars of the data set and training stages.
    log : callable
        Receives one line per stage.
    config : DemoConfig, optional
        Overrides ``tiny`` and ``seed``.

    Returns
    -------
    DemoResult
    """
    from .locks import OutputLock

    cfg = config or demo_config(tiny, seed)
    out, rrd_path = check_outputs(out, rrd)
    out.mkdir(parents=True, exist_ok=True)
    with OutputLock(out, "demo folder"):  # one demo per folder: it replaces stale stages in it
        return _stages(cfg, out, rrd_path, progress, log)


def _stages(cfg: DemoConfig, out: Path, rrd_path: Path, progress: bool, log) -> DemoResult:
    seconds: dict[str, float] = {}

    t0 = time.perf_counter()
    ds, scene = _dataset(cfg, out / cfg.dataset_name, progress, log)
    seconds["dataset"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    _trajectories(cfg, ds, scene, log)
    seconds["trajectories"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    trained = _train(cfg, ds, out / cfg.run_name, progress, log)
    seconds["training"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    est = _estimate(cfg, ds, trained, log)
    seconds["estimation"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    planned = _plan(cfg, scene, est, log)
    seconds["planning"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    log(f"[6/6] recording {rrd_path}")
    _record(cfg, rrd_path, ds, scene, trained, est, planned)
    seconds["recording"] = time.perf_counter() - t0

    plan = planned.result
    result = DemoResult(
        out=out,
        dataset=out / cfg.dataset_name,
        run=trained.run,
        rrd=rrd_path,
        summary=out / SUMMARY_FILE,
        trajectory_id=int(est.ids[planned.chosen]),
        rmse_m=float(est.rmse[planned.chosen]),
        holdout_rmse_m=est.stats,
        start=[float(v) for v in plan.start],
        goal=[float(v) for v in plan.goal],
        target=planned.target,
        path_length_m=float(plan.length),
        optimum_m=float(planned.optimum.length) if planned.optimum is not None else math.inf,
        corridor_width_m=float(planned.space.corridor.width),
        solved=bool(plan.solved),
        epochs=int(trained.summary["epochs"]),
        seconds={k: round(v, 2) for k, v in seconds.items()},
    )
    _write_json(result.summary, {"config": cfg.as_dict(), **result.to_dict()})
    return result


# ---------------------------------------------------------------------- stages
def _dataset(cfg: DemoConfig, path: Path, progress: bool, log):
    from .dataset import Dataset, generate_dataset
    from .dataset.config import resolve_config
    from .scene import load_scene

    scene = load_scene(cfg.scene)
    if path.exists():
        want = resolve_config(cfg.scene, scene, cfg.spacing, n_rays=cfg.n_rays).hash()
        try:
            have = Dataset.open(path).content_hash
        except MmwsimError:
            have = None
        if have != want:  # the demo's own store from other settings (or software version): replace it
            log(f"      {path} holds other settings; regenerating it")
            shutil.rmtree(path)
    log(f"[1/6] data set: scene {cfg.scene!r}, receivers every {cfg.spacing:g} m -> {path}")
    if path.exists():
        log("      reusing the finished data set of the same settings")
    generate_dataset(
        cfg.scene,
        path,
        spacing=cfg.spacing,
        n_rays=cfg.n_rays,
        workers=cfg.workers,
        resume=True,
        progress=progress and not path.exists(),
    )
    ds = Dataset.open(path)
    log(f"      {ds!r}")
    return ds, scene


def _trajectories(cfg: DemoConfig, ds, scene, log) -> None:
    from .trajectories import generate_for_dataset, split, write_trajectories

    t = generate_for_dataset(ds, cfg.counts, cfg.length, cfg.seed, scene=scene, vehicles_on_streets=True)
    parts = split(t, (0.8, 0.1, 0.1), seed=cfg.seed, holdout_region=cfg.holdout_region)
    write_trajectories(ds, parts)
    sizes = ", ".join(f"{name} {len(p)}" for name, p in parts.items())
    log(
        f"[2/6] trajectories: {len(t)} of {cfg.length} steps ({sizes}); "
        f"{int(parts['test'].holdout.sum())} touch the hold-out region {cfg.holdout_region}"
    )


def _train(cfg: DemoConfig, ds, run: Path, progress: bool, log) -> TrainedRun:
    import torch

    from estimation import TrainConfig, load_checkpoint, load_splits, read_run_info, train
    from estimation.checkpoint import CHECKPOINT_FORMAT
    from estimation.training import CHECKPOINT_FILE

    from .config import content_hash

    torch.set_num_threads(1)  # the trainer draws noisy batches on the second core meanwhile
    sets, info = load_splits(ds.path, ("train", "validation", SPLIT, "test"), dataset=ds)
    tcfg = TrainConfig(
        model=MODEL,
        epochs=cfg.epochs,
        patience=cfg.patience,
        sigma=cfg.sigma,
        seed=cfg.seed,
        max_length=cfg.length,
        epoch_size=cfg.epoch_size,
    )
    info["demo"] = content_hash(cfg.as_dict())
    resume = False
    if (run / CHECKPOINT_FILE).exists():
        try:
            resume = read_run_info(run).get("data", {}).get("demo") == info["demo"]
        except MmwsimError:
            resume = False
        if not resume:
            log(f"      {run} was trained with other settings; training afresh")
            shutil.rmtree(run)
    log(
        f"[3/6] training {MODEL} on {sets['train'].n} trajectories "
        f"(validation {sets['validation'].n}), at most {cfg.epochs} epochs -> {run}"
    )
    summary = train(
        sets["train"],
        sets["validation"],
        tcfg,
        run,
        resume=resume,
        data_info=info,
        progress=progress,
        record=False,
        log=lambda text: log(f"      {text}"),
    )
    history = load_checkpoint(run / CHECKPOINT_FILE, CHECKPOINT_FORMAT, ("history",))["history"]
    log(
        f"      {summary['epochs']} epochs, best validation RMSE {summary['best_val_rmse']:.2f} m "
        f"at epoch {summary['best_epoch']}"
    )
    return TrainedRun(run, sets, summary, history)


def _estimate(cfg: DemoConfig, ds, trained: TrainedRun, log) -> Estimates:
    """Estimates of the held-out trajectories from fresh noisy fingerprints, and the one to plan along."""
    import torch

    from estimation import Estimator, noisy_bits, summarise, trajectory_rmse

    from .trajectories import read_trajectories

    split = SPLIT if trained.sets[SPLIT].n else "test"
    data = trained.sets[split]
    if data.n == 0:
        raise MmwsimError("the demo's test split is empty; use more trajectories")
    t = read_trajectories(ds.path, "test")
    ids = t.ids[t.holdout] if split == SPLIT else t.ids
    est = Estimator.load(trained.run).attach(data)
    gen = torch.Generator().manual_seed(cfg.seed * 1_000_003 + 17)
    bits = noisy_bits(data, cfg.sigma, gen)
    pred = np.concatenate(
        [est.predict(bits[k : k + 512].float()).numpy() for k in range(0, data.n, 512)]
    ).astype(np.float64)
    rmse = trajectory_rmse(pred, data.positions)
    stats = summarise(rmse)
    log(
        f"[4/6] estimate of {data.n} {split} trajectories at {cfg.sigma:g} dB: "
        f"RMSE mean {stats['mean']:.2f} m, median {stats['median']:.2f} m"
    )
    return Estimates(split, ids, pred, rmse, stats, _candidates(pred, rmse, cfg.step), bits)


def _candidates(pred: np.ndarray, rmse: np.ndarray, step: float) -> np.ndarray:
    """Held-out trajectories in the order they are tried for planning.

    First those estimated no worse than the median whose estimated ends lie at least three planner
    steps apart, the farthest-apart first (a representative estimate with a path worth planning,
    not the best estimate); then the others, the better estimated first.
    """
    apart = np.linalg.norm(pred[:, -1] - pred[:, 0], axis=-1)
    good = (rmse <= np.median(rmse)) & (apart >= 3 * step)
    return np.lexsort((np.arange(len(rmse)), np.where(good, -apart, rmse), ~good))


def _plan(cfg: DemoConfig, scene, est: Estimates, log) -> PlannedPath:
    """Informed RRT* inside the corridor around the estimate of a held-out trajectory, from its
    estimated first position to its estimated last one.

    Ends that fall in a building are moved to the nearest point with clearance. When the estimated
    ends lie closer than one planner step (a user standing still, or an estimate that does not
    move), the target is the free point of the corridor farthest from the start instead. The
    corridor is widened once when it holds no path, and the next candidate trajectory is taken
    when it still holds none.
    """
    import planning

    for chosen in est.order[:_MAX_TRIES]:
        estimate = est.pred[chosen]
        for width in (cfg.corridor_width, 2 * cfg.corridor_width):
            corridor = planning.Corridor.from_array(estimate, width)
            space = planning.AgentSpace(scene, radius=cfg.radius, corridor=corridor)
            start, goal = space.nearest_free_point(estimate[0]), space.nearest_free_point(estimate[-1])
            target = "the estimated last position"
            if start is not None and (goal is None or np.linalg.norm(goal - start) < cfg.step):
                goal, target = space.farthest_free_point(start), "the farthest free point of the corridor"
            if start is None or goal is None or np.linalg.norm(goal - start) < cfg.step:
                break
            optimum = planning.shortest_path(space, start, goal)
            if optimum is not None:
                return _run_planner(cfg, int(chosen), space, start, goal, target, optimum, est, log)
    raise MmwsimError(
        f"none of {min(len(est.order), _MAX_TRIES)} estimated trajectories leaves a collision-free path "
        f"of at least {cfg.step:g} m within {2 * cfg.corridor_width:g} m of it"
    )


_MAX_TRIES = 10


def _run_planner(
    cfg: DemoConfig, chosen: int, space, start, goal, target: str, optimum, est: Estimates, log
) -> PlannedPath:
    import planning

    result = planning.plan(
        space,
        start,
        goal,
        planner="irrtstar",
        iterations=cfg.iterations,
        step=cfg.step,
        seed=cfg.seed,
        snapshots=cfg.snapshots,
    )
    found = f"{result.length:.2f} m" if result.solved else "no path"
    log(
        f"[5/6] trajectory {int(est.ids[chosen])} (estimate RMSE {est.rmse[chosen]:.2f} m): "
        f"{result.label} in the {space.corridor.width:g} m corridor around its estimate, from the estimated "
        f"first position ({start[0]:.1f}, {start[1]:.1f}) to {target} ({goal[0]:.1f}, {goal[1]:.1f}): "
        f"{found} after {result.iterations} iterations (optimum {optimum.length:.2f} m)"
    )
    return PlannedPath(chosen, space, result, optimum, target)


# ---------------------------------------------------------------------- recording
def _record(
    cfg: DemoConfig, path: Path, ds, scene, trained: TrainedRun, est: Estimates, planned: PlannedPath
) -> None:
    from estimation import Evaluation, log_estimates, log_training
    from planning import log_plan

    from .dataset.record import log_dataset, log_fingerprint_steps
    from .recording import FAMILIES, Recording
    from .tracer.record import log_path_context, log_paths
    from .tracer.wedges import find_wedges

    data, chosen = trained.sets[est.split], planned.chosen
    true = data.positions[chosen].astype(np.float64)
    grid_index = ds.nearest(true)
    visited = grid_index[np.sort(np.unique(grid_index, return_index=True)[1])]  # in the order walked
    rest = [i for i in np.argsort(est.rmse, kind="stable") if i != chosen][: cfg.shown - 1]
    shown = np.array([chosen, *rest], dtype=np.int64)
    with Recording(path, "demo", families=FAMILIES, config=cfg.as_dict(), extent=scene.extent) as rec:
        # Scene, beam patterns, coverage per beam, and PDP / one fingerprint at the receivers along
        # the trajectory.
        log_dataset(rec, ds, receivers=visited, scene=scene, seed=cfg.seed)
        shown_paths = ds.paths(grid_index)
        log_paths(rec, shown_paths)
        log_path_context(rec, shown_paths, find_wedges(scene))
        # The fingerprints the model saw, step by step.
        ident = int(est.ids[chosen])
        log_fingerprint_steps(
            rec,
            f"trajectory_{ident}",
            data.grid_pdp[data.index[chosen]].float().numpy(),
            est.bits[chosen].numpy().astype(np.uint8),
            f"trajectory {ident} (planned along)",
        )
        # True against estimated trajectories.
        examples = {"true": data.positions[shown], "kind": data.kind[shown], MODEL: est.pred[shown]}
        log_estimates(rec, Evaluation(examples={est.split: examples}), footprints=scene.footprints)
        log_training(rec, MODEL, trained.history)
        log_plan(rec, planned.space, planned.result, planned.optimum)


def _write_json(path: Path, obj: Any) -> None:
    write_text_atomic(path, json.dumps(obj, indent=1, default=float) + "\n")
