"""The paper's comparison under one protocol: train every model, evaluate all, write the table.

    python benchmarks/paper_table.py DATA.zarr --out DIR [--budget-minutes 30] [--models lstm tn ...]
        [--tasks tracking forecasting] [--noises 6 9] [--max-trajectories N] [--max-test N]
        [--epoch-size 2048] [--no-fill-budget] [--reuse OTHER_DIR ...]

Every model (LSTM, GRU, RNN, TCN, Conv1D, tn, tn-match) is trained for each task under one
protocol: the same training and validation trajectories, the same epoch size, early stopping on the
validation loss with the same patience, and one wall-clock budget per model (no epoch starts after
it; the budget is stated in the table; a cosine recipe is extended to the epochs a timed probe
epoch says fit it, never shortened below the recipe scaled by budget / 30 minutes, and past the
recipe's own length unless ``--no-fill-budget``). Runs go to DIR/runs/<model>-<task>. Then the runs and the
classical trackers (the oracle first, when ``estimation.method("oracle")`` exists; knn-kalman;
match-cv) are evaluated on test/seen and test/holdout at each noise level, all on the same noisy
fingerprints, and DIR/paper_table.md (accuracy at 7 steps for tracking, the forecast for forecasting,
vehicle / pedestrian / all, per noise level and split; parameters, training time, epochs and prediction
time) and DIR/error_vs_length.png (tracking error against sequence length) are written.

Resumable: rerun the same command after a kill. Finished runs are skipped, an interrupted run
continues from its last checkpoint with the rest of its budget, and evaluations are cached per
method in DIR/cache (recomputed only when the run or the evaluation settings change). DIR keeps the
protocol it was started with (DIR/protocol.json); a rerun under another protocol is refused. The
tasks may be run one at a time in one folder: the table keeps every task made there. A
classical tracker's evaluation depends on the data and the test draws, not on how the networks are
trained: ``--reuse OTHER_DIR`` takes it from another table's folder (another budget, patience or
epoch size) where it was made on the same data, test draws and noise levels.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _common import budget_settings

MODELS = ("lstm", "gru", "rnn", "tcn", "conv1d", "tn", "tn-match")
TASKS = ("tracking", "forecasting")
SPLITS = ("test/seen", "test/holdout")
SPLIT_LABELS = {"test/seen": "seen", "test/holdout": "held-out"}
KINDS = ("vehicle", "pedestrian", "all")
CLASSICAL = ("oracle", "knn-kalman", "match-cv")
CACHE_FORMAT = 1
# protocol entries that only shape training: a classical tracker's evaluation does not depend on them
TRAINING_ONLY = (
    "epoch_size",
    "patience",
    "max_epochs",
    "budget_minutes",
    "calibrate",
    "fill_budget",
    "sigma",
)


class _Usage(Exception):
    """A bad command line: one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line instead of usage + message
        raise _Usage(message)


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(
        prog="paper_table.py",
        description=__doc__.splitlines()[0],
        epilog=__doc__.split("\n\n", 2)[2],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("dataset", help="data set with trajectories (zarr), or toy[:n=N,length=L,seed=S]")
    ap.add_argument("--out", required=True, help="output folder (runs, cache, table, plot)")
    ap.add_argument(
        "--budget-minutes", type=float, default=30.0, help="wall-clock training budget per model (default 30)"
    )
    ap.add_argument("--models", nargs="+", default=list(MODELS), help=f"default: {' '.join(MODELS)}")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), help="default: tracking forecasting")
    ap.add_argument("--noises", nargs="+", type=float, default=[6.0, 9.0], help="dB (default 6 9)")
    ap.add_argument(
        "--max-trajectories",
        type=int,
        default=0,
        help="at most N trajectories per split (train, validation, test; a seeded subset; default all)",
    )
    ap.add_argument(
        "--max-test",
        type=int,
        default=0,
        help="at most N trajectories per test split (a seeded subset; default all): the classical "
        "trackers and the oracle cost seconds per trajectory",
    )
    ap.add_argument(
        "--epoch-size", type=int, default=2048, help="trajectories per epoch, fresh each epoch (default 2048)"
    )
    ap.add_argument("--patience", type=int, default=8, help="early-stopping patience, epochs (default 8)")
    ap.add_argument(
        "--max-epochs", type=int, default=1000, help="epoch cap (default 1000: budget and patience decide)"
    )
    ap.add_argument(
        "--calibrate",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="extend each cosine recipe to the epochs that a timed probe epoch says fit the budget "
        "(default; never shorter than the recipe scaled by budget / 30 minutes); --no-calibrate "
        "only scales it",
    )
    ap.add_argument(
        "--fill-budget",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="let the calibration extend a cosine recipe past its own length, to all the epochs the "
        "budget holds (default: forecasting recipes end at 200 epochs after a third to a half of 30 "
        "minutes); --no-fill-budget stops at the recipe's length, as folders made before this default",
    )
    ap.add_argument(
        "--classical",
        nargs="*",
        default=list(CLASSICAL),
        help=f"classical trackers to evaluate beside the runs (default: {' '.join(CLASSICAL)}; the oracle "
        "only where it exists)",
    )
    ap.add_argument(
        "--reuse",
        nargs="+",
        default=[],
        metavar="DIR",
        help="other table folders whose classical evaluations to take where data, test draws and "
        "noise levels are the same (e.g. a table at another budget)",
    )
    ap.add_argument("--sigma", type=float, default=6.0, help="training noise, dB (default 6)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--threads", type=int, default=1, help="torch threads (default 1; batches drawn on a second)"
    )
    return ap


def _check(args) -> None:
    """Reject bad values with one line (a :class:`_Usage`)."""
    if not (math.isfinite(args.budget_minutes) and args.budget_minutes > 0):
        raise _Usage(f"--budget-minutes must be a finite number > 0, got {args.budget_minutes}")
    bad = [m for m in args.models if m not in MODELS]
    if bad:
        raise _Usage(f"--models: unknown {' '.join(bad)} (choose from {' '.join(MODELS)})")
    bad = [c for c in args.classical if c not in CLASSICAL]
    if bad:
        raise _Usage(f"--classical: unknown {' '.join(bad)} (choose from {' '.join(CLASSICAL)})")
    bad = [t for t in args.tasks if t not in TASKS]
    if bad:
        raise _Usage(f"--tasks: unknown {' '.join(bad)} (choose from {' '.join(TASKS)})")
    if not all(math.isfinite(n) and n >= 0 for n in args.noises):
        raise _Usage(f"--noises must be finite and >= 0 dB, got {' '.join(f'{n:g}' for n in args.noises)}")
    if args.max_trajectories < 0 or args.max_test < 0 or args.epoch_size < 0:
        raise _Usage("--max-trajectories, --max-test and --epoch-size must be >= 0")
    if args.patience < 1 or args.max_epochs < 1 or args.threads < 1:
        raise _Usage("--patience, --max-epochs and --threads must be >= 1")
    if not (math.isfinite(args.sigma) and args.sigma >= 0):
        raise _Usage(f"--sigma must be finite and >= 0 dB, got {args.sigma}")
    if not str(args.dataset).startswith("toy") and not Path(args.dataset).exists():
        raise _Usage(f"{args.dataset}: data set not found")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise _Usage(f"--out {out}: exists and is not a folder")
    bad = [d for d in args.reuse if not (Path(d) / "cache").is_dir()]
    if bad:
        raise _Usage(f"--reuse: {' '.join(bad)}: not a table folder (no cache/ in it)")
    args.models = list(dict.fromkeys(args.models))
    args.tasks = list(dict.fromkeys(args.tasks))
    args.noises = list(dict.fromkeys(float(n) for n in args.noises))


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        _check(args)
    except _Usage as e:
        print(f"paper_table.py: error: {e}", file=sys.stderr)
        return 2
    import torch

    from estimation import EstimationError
    from mmwsim.errors import MmwsimError

    threads = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    try:
        return _main(args)
    except (EstimationError, MmwsimError) as e:
        print(f"paper_table.py: error: {e}", file=sys.stderr)
        return 2
    finally:
        torch.set_num_threads(threads)


def log(text: str) -> None:
    print(text, flush=True)


def _subset(data, n: int, seed: int):
    """At most ``n`` trajectories of ``data`` (0 = all): a seeded random subset in stored order."""
    if not n or data.n <= n:
        return data
    return data.subset(np.sort(np.random.default_rng(seed).permutation(data.n)[:n]))


def _write_json(path: Path, obj: Any) -> None:
    from mmwsim.files import write_text_atomic

    write_text_atomic(path, json.dumps(obj, indent=1, sort_keys=True, default=float))


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _main(args) -> int:
    from estimation import TrainConfig
    from estimation.adapter import load_sets
    from mmwsim.locks import locked_output

    out = Path(args.out)
    t_start = time.perf_counter()
    sets, info = load_sets(args.dataset, ("train", "validation", *SPLITS))
    sets = {k: _subset(v, args.max_trajectories, args.seed + i) for i, (k, v) in enumerate(sets.items())}
    sets = {k: _subset(v, args.max_test, args.seed + 100) if k in SPLITS else v for k, v in sets.items()}
    protocol = {
        "dataset": info.get("dataset", str(args.dataset)),
        "content_hash": info.get("content_hash", ""),
        "max_trajectories": args.max_trajectories,
        "max_test": args.max_test,
        "n_train": sets["train"].n,
        "n_validation": sets["validation"].n,
        "epoch_size": min(args.epoch_size, sets["train"].n) if args.epoch_size else sets["train"].n,
        "patience": args.patience,
        "max_epochs": args.max_epochs,
        "budget_minutes": args.budget_minutes,
        **({"calibrate": True} if args.calibrate else {}),  # older folders continue with --no-calibrate
        # older folders: --no-fill-budget; without the calibration there is no probe to fill by
        **({"fill_budget": True} if args.calibrate and args.fill_budget else {}),
        "sigma": args.sigma,
        "seed": args.seed,
        # forecasting: observed and predicted steps (the training defaults, used by every method)
        "t_obs": TrainConfig(model="lstm").t_obs,
        "horizon": TrainConfig(model="lstm").horizon,
    }
    log(
        f"protocol: {protocol['n_train']} training / {protocol['n_validation']} validation trajectories, "
        f"epoch size {protocol['epoch_size']}, patience {args.patience}, budget {args.budget_minutes:g} min "
        f"per model, training noise {args.sigma:g} dB, {args.threads} torch thread(s); "
        f"test: {', '.join(f'{k} {sets[k].n}' for k in SPLITS)}"
    )
    # One writer per folder; what is made here stays if the script fails or is stopped (resumable).
    with locked_output(out, "table folder", create=True, keep=lambda: True):
        _check_protocol(out, protocol)
        runs = _train_all(args, out, sets, info, protocol)
        ev, names, skipped = _evaluate_all(args, out, sets, runs, protocol)
        written = _write_outputs(args, out, ev, names, protocol, skipped)
    log(f"wrote {', '.join(map(str, written))} ({time.perf_counter() - t_start:.0f} s)")
    return 0


def _check_protocol(out: Path, protocol: dict[str, Any]) -> None:
    from estimation import EstimationError

    path = out / "protocol.json"
    old = _read_json(path) if path.exists() else None
    if old is None:
        _write_json(path, protocol)
        return
    # a switch is recorded only where it is on: one the folder has and this run lacks differs too
    differ = [k for k in dict.fromkeys([*protocol, *old]) if old.get(k) != protocol.get(k)]
    if differ:
        raise EstimationError(
            f"{out}: was started under another protocol ("
            + ", ".join(f"{k} {old.get(k)} != {protocol.get(k)}" for k in differ)
            + "); rerun with its settings or choose another --out"
        )


# ---------------------------------------------------------------------------------------- training


def _train_all(args, out: Path, sets, info, protocol) -> dict[str, Path]:
    """Train (or resume, or skip) every (model, task); returns run name -> run folder of the runs
    that exist."""
    from estimation import EstimationError, TrainConfig

    budget = 60.0 * args.budget_minutes
    jobs = [(m, t) for t in args.tasks for m in args.models]
    runs: dict[str, Path] = {}
    (out / "cache").mkdir(exist_ok=True)
    for i, (model, task) in enumerate(jobs, 1):
        name = f"{model}-{task}"
        head = f"[train {i}/{len(jobs)}] {name}"
        run, marker = out / "runs" / name, out / "cache" / f"train-{name}.json"
        done = _finished(out, name)
        if done:
            log(f"{head}: finished before ({_describe(done)}), skipped")
            runs[name] = run
            continue
        try:
            base = dict(
                model=model, task=task, sigma=args.sigma, patience=args.patience,
                epoch_size=protocol["epoch_size"], seed=args.seed,
            )  # fmt: skip
            if args.calibrate:
                settings, probe = _calibrated(
                    base, budget, args.max_epochs, sets, out, name, head, fill=args.fill_budget
                )
            else:
                settings, probe = budget_settings(model, args.budget_minutes, cap=args.max_epochs), 0.0
            cfg = TrainConfig(**base, **settings)
        except EstimationError as e:
            log(f"{head}: skipped ({e})")
            continue
        trained = _spent(run)
        left = max(budget - trained - probe, 0.0)
        log(f"{head}: {f'resuming after {trained:.1f} s' if trained else 'training'}, {left:.0f} s left")
        summary = _train_one(sets, cfg, run, info, protocol, left)
        if summary["epochs"] == 0 or not (run / "model.pt").exists():
            log(f"{head}: no epoch finished within the budget; left out")
            continue
        summary["ended"] = _ended(summary, cfg, budget)
        _write_json(marker, summary)
        log(f"{head}: {_describe(summary)}")
        runs[name] = run
    return runs


def _calibrated(
    base: dict, budget: float, cap: int, sets, out: Path, name: str, head: str, *, fill: bool
) -> tuple[dict, float]:
    """TrainConfig settings that fit a cosine recipe into ``budget`` seconds on this machine, and the
    seconds their probe took.

    The recipe scaled by ``budget / 30 minutes`` (:func:`budget_settings`) was sized on ``tn``'s
    tracking epochs; a model or task with cheaper epochs (forecasting: 3 to 4x) ends it long before
    the budget. A probe trains one warm-up epoch (when the recipe has a warm-up) and one sequence
    epoch, and the recipe is extended to as many epochs as the rest of the budget holds at those
    costs (95 % of it, as epochs vary), at most ``cap`` and, unless ``fill``, the recipe's own
    length; never shortened below the scaled one (sized to end within 8 minutes, tracking trained
    worse than cut short by the budget: docs/estimation.md). The probe's time counts against the
    budget.
    The result is kept in DIR/cache, so a resumed run keeps its schedule. Models on the plateau
    schedule get ``epochs = cap`` (the budget and early stopping end them).
    """
    from estimation import TrainConfig, train
    from estimation.models import model_spec

    recipe = model_spec(base["model"]).recipe
    if recipe.get("schedule") != "cosine":
        return {"epochs": cap}, 0.0
    marker = out / "cache" / f"calibration-{name}.json"
    saved = _read_json(marker)
    if saved:
        return {"epochs": int(saved["epochs"])}, float(sum(saved["probe_seconds"]))
    warm = 1 if base["task"] == "tracking" and recipe.get("warmup_epochs") else 0
    probe = TrainConfig(**base, epochs=warm + 1, warmup_epochs=warm)
    where = out / "cache" / f"probe-{name}"
    shutil.rmtree(where, ignore_errors=True)  # what a killed probe left
    try:
        train(
            sets["train"], sets["validation"], probe, where, progress=False, record=False, log=lambda s: None
        )
        seconds = _history(where)
    finally:
        shutil.rmtree(where, ignore_errors=True)
    share = recipe.get("warmup_epochs", 0) / recipe["epochs"] if warm else 0.0
    per_epoch = share * seconds[0] + (1 - share) * seconds[-1]
    left = 0.95 * budget - sum(seconds)
    # Never shorter than the recipe scaled by the budget: at 8 minutes a cosine sized to end within
    # the budget trained worse than the longer one the budget cut (docs/estimation.md).
    scaled = budget_settings(base["model"], budget / 60.0)["epochs"]
    epochs = int(min(max(2, left // per_epoch, scaled), cap if fill else min(cap, recipe["epochs"])))
    _write_json(
        marker, {"epochs": epochs, "probe_seconds": seconds, "per_epoch": per_epoch, "scaled": scaled}
    )
    log(f"{head}: probe epochs {', '.join(f'{t:.1f}' for t in seconds)} s -> {epochs} epochs in the budget")
    return {"epochs": epochs}, float(sum(seconds))


def _finished(out: Path, name: str) -> dict[str, Any] | None:
    """The training summary of run ``name`` in table folder ``out`` if it finished, else None."""
    done = _read_json(out / "cache" / f"train-{name}.json")
    return done if done and (out / "runs" / name / "model.pt").exists() else None


def _history(run: Path) -> list[float]:
    """Seconds of every epoch a run's checkpoint holds."""
    from estimation.checkpoint import CHECKPOINT_FORMAT, load_checkpoint
    from estimation.training import CHECKPOINT_FILE

    path = run / CHECKPOINT_FILE
    if not path.exists():
        return []
    return [float(t) for t in load_checkpoint(path, CHECKPOINT_FORMAT, ("history",))["history"]["seconds"]]


def _spent(run: Path) -> float:
    """Training seconds of the epochs a run's checkpoint holds (0 without one)."""
    return float(sum(_history(run)))


def _train_one(sets, cfg, run: Path, info, protocol, seconds: float) -> dict[str, Any]:
    from estimation import train

    data_info = dict(info, train_split="train", val_split="validation", protocol=protocol)
    return train(
        sets["train"],
        sets["validation"],
        cfg,
        run,
        resume=True,  # a fresh start when there is no checkpoint yet
        data_info=data_info,
        progress=False,
        log=lambda text: log(f"    {text}"),
        time_limit=seconds,
    )


def _ended(summary: dict[str, Any], cfg, budget: float) -> str:
    if summary.get("stopped_early"):
        return "early stop"
    if summary["epochs"] >= cfg.epochs:
        return "epoch cap"
    return "budget"


def _describe(s: dict[str, Any]) -> str:
    return (
        f"{s['epochs']} epochs, {s['train_seconds']:.0f} s, best validation RMSE {s['best_val_rmse']:.2f} m "
        f"at epoch {s['best_epoch']}, ended by {s.get('ended', '?')}"
    )


# -------------------------------------------------------------------------------------- evaluation


def _classical(name: str, task: str, t_obs: int, horizon: int, seed: int, dataset: str):
    """The classical method ``name`` for ``task``, or None (with the reason) when it does not exist,
    does not do that task, or (the oracle) cannot know the data set's generator."""
    from estimation import method

    try:
        m = method(name, task=task, t_obs=t_obs, horizon=horizon, fit_length=7, seed=seed)
        if getattr(m, "task", task) == task and hasattr(m, "use_dataset"):
            m.use_dataset(dataset)
    except Exception as e:  # a method still being written, or refusing its options: leave it out
        return None, " ".join(str(e).split())[:160] or type(e).__name__
    if getattr(m, "task", task) != task:
        return None, f"does {m.task} only"
    return m, ""


def _evaluate_all(args, out: Path, sets, runs: dict[str, Path], protocol):
    """Evaluate every run and classical tracker (cached); returns the merged Evaluation, the method
    order for the tables, and what was left out with why."""
    from estimation import method
    from estimation.evaluation import Evaluation
    from estimation.training import read_run_info

    test = {k: sets[k] for k in SPLITS}
    setting = {
        "format": CACHE_FORMAT,
        "protocol": protocol,
        "noises": args.noises,
        "splits": {k: v.n for k, v in test.items()},
        "table_length": 7,
        "seed": args.seed,
    }
    jobs: list[tuple[str, str, str, Any]] = []  # (label, task, cache key, how to build)
    skipped: list[str] = []
    first = [c for c in args.classical if c == "oracle"]  # the floor heads every table
    last = [c for c in CLASSICAL if c in args.classical and c != "oracle"]
    t_obs, horizon = protocol["t_obs"], protocol["horizon"]
    # A task run before in this folder (the table's tasks split over several runs of the
    # script) keeps its rows in the table: its cached evaluations are read, nothing is made.
    for task in TASKS:
        if task in args.tasks:
            task_runs = runs
        else:
            names = (f"{m}-{task}" for m in args.models)
            task_runs = {n: out / "runs" / n for n in names if _finished(out, n)}
        for name in first:
            jobs.append((name, task, f"{name}-{task}", ("classical", name)))
        for model in args.models:
            name = f"{model}-{task}"
            if name in task_runs:
                jobs.append((model, task, name, ("run", task_runs[name])))
        for name in last:
            jobs.append((name, task, f"{name}-{task}", ("classical", name)))
    merged = Evaluation(table_length=7)
    order: list[str] = []
    n_jobs, i = sum(task in args.tasks for _, task, _, _ in jobs), 0
    for label, task, key, (kind, what) in jobs:
        earlier = task not in args.tasks
        i += not earlier
        head = f"[earlier] {key}" if earlier else f"[evaluate {i}/{n_jobs}] {key}"
        if kind == "run":
            run_summary = read_run_info(what).get("summary", {})
            want = setting | {"run": run_summary}
        else:
            data_only = {k: v for k, v in protocol.items() if k not in TRAINING_ONLY}
            want = setting | {"protocol": data_only, "method": key}
        want = json.loads(json.dumps(want, default=float))
        name = f"eval-{key}.json"
        path = out / "cache" / name
        # a network's evaluation is its own run's; a classical tracker's may be another table's
        folders = [out, *([] if kind == "run" else args.reuse)]
        hit = next(((d, r) for d in folders if (r := _cached(d, name, want)) is not None), None)
        if earlier and (hit is None or hit[0] != out):
            # not made in this folder: nothing to show, unless the method cannot do the task
            why = _classical(what, task, t_obs, horizon, args.seed, args.dataset)[1] if kind != "run" else ""
            if why:
                skipped.append(f"{key}: {why}")
            continue
        if hit is not None:
            where, result = hit
            if where != out:
                _write_json(path, result)
            log(f"{head}: " + ("cached" if where == out else f"taken from {where}"))
        else:
            if kind == "run":
                m = method(what)
            else:
                m, why = _classical(what, task, t_obs, horizon, args.seed, args.dataset)
                if m is None:
                    log(f"{head}: left out ({why})")
                    skipped.append(f"{key}: {why}")
                    continue
            log(f"{head}: evaluating")
            t0 = time.perf_counter()
            result = _evaluate_one(m, test, args.noises, sets["validation"], args.seed)
            result["setting"] = want
            result["name"] = m.name
            _write_json(path, result)
            log(f"{head}: done in {time.perf_counter() - t0:.0f} s")
        for r in result["rows"]:
            merged.rows.append(dict(r, method=label))
        cost = dict(result["cost"].get(result.get("name", key)) or _no_cost(result))
        if kind == "run":
            done = _read_json(out / "cache" / f"train-{key}.json") or {}
            cost["ended"] = done.get("ended", "–")
            cost["best_epoch"] = done.get("best_epoch", "–")
        merged.cost[key] = cost
        if label not in order:
            order.append(label)
    return merged, order, skipped


def _cached(folder: str | Path, name: str, want: dict[str, Any]) -> dict[str, Any] | None:
    """The evaluation ``name`` in table folder ``folder``'s cache if it was made under ``want``."""
    found = _read_json(Path(folder) / "cache" / name)
    return found if found and found.get("setting") == want else None


def _no_cost(result: dict[str, Any]) -> dict[str, Any]:
    """Cost of a method whose first split was empty (evaluate books cost on the first one)."""
    return {"parameters": 0, "train_seconds": math.nan, "epochs": 0, "predict_seconds": math.nan}


def _evaluate_one(m, test, noises, validation, seed) -> dict[str, Any]:
    from estimation import evaluate

    ev = evaluate(
        [m],
        test,
        list(noises),
        validation,
        table_length=7,
        n_examples=0,
        seed=seed,
        progress=False,
        log=lambda text: log(f"    {text}"),
    )
    return {"rows": ev.rows, "cost": ev.cost, "fitted": ev.fitted}


# ----------------------------------------------------------------------------------------- outputs


def _write_outputs(args, out: Path, ev, order: list[str], protocol, skipped: list[str]) -> list[Path]:
    """Write DIR/paper_table.md and, where there are tracking rows, DIR/error_vs_length.png; the
    files written."""
    from estimation.report import comparison_table, cost_table, plot_error_grid
    from mmwsim.files import write_text_atomic

    budget = f"{args.budget_minutes:g} min"
    if protocol.get("calibrate"):
        schedule = "scaled to the budget and extended to the epochs a timed probe epoch says fit it, " + (
            "past the recipe's own length if the budget holds more"
            if protocol.get("fill_budget")
            else "at most to the recipe's own length"
        )
    else:
        schedule = "shortened in proportion to the budget"
    n_test = {
        sp: {r["kind"]: r["n"] for r in ev.rows if r["split"] == sp and r["kind"] in KINDS} for sp in SPLITS
    }
    parts = [
        f"# The paper's comparison under one protocol: training budget {budget} per model\n",
        f"Data set `{protocol['dataset']}`"
        + (f" (content hash {protocol['content_hash'][:12]})" if protocol["content_hash"] else "")
        + f". Every model was trained on the same {protocol['n_train']} training trajectories "
        f"(epochs of {protocol['epoch_size']} drawn afresh, fingerprints with fresh {protocol['sigma']:g} dB "
        f"noise) with early stopping on the loss over the same {protocol['n_validation']} validation "
        f"trajectories (patience {protocol['patience']} epochs, at most {protocol['max_epochs']} epochs; a model "
        "whose recipe decays its learning rate to zero by a set epoch (`tn` and the baselines, which share "
        f"its recipe) has that schedule {schedule}) and a wall-clock budget of {budget} per model: no "
        "epoch starts after it. The weights of the best "
        "validation epoch are evaluated. All methods see the same noisy fingerprints per split and noise "
        "level. Mean per-trajectory RMSE (m); *seen*: test trajectories outside the spatial hold-out "
        "region, *held-out*: those touching it.\n",
        "Test trajectories (vehicle / pedestrian / all): "
        + "; ".join(
            f"{SPLIT_LABELS[sp]} {n.get('vehicle', 0)} / {n.get('pedestrian', 0)} / {n.get('all', 0)}"
            for sp, n in n_test.items()
        )
        + ".\n",
    ]
    for task, title in (
        ("tracking", "## Tracking, 7-step sequences"),
        (
            "forecasting",
            f"## Forecasting: the {protocol['horizon']} steps after {protocol['t_obs']} observed ones",
        ),
    ):
        t = comparison_table(ev, task, list(SPLITS), args.noises, KINDS, order, SPLIT_LABELS)
        if t:
            parts.append(f"{title}\n\n{t}")
    parts.append(
        "## Cost\n\nTraining time is the sum of the finished epochs (validation included); prediction time "
        "is measured on the seen split at the first noise level, on this machine (noisy when shared).\n\n"
        + cost_table(ev, {"best_epoch": "Best epoch", "ended": "Ended by"})
    )
    if skipped:
        parts.append("Left out: " + "; ".join(skipped) + ".\n")
    panels = [(sp, s) for s in args.noises for sp in SPLITS]
    png = out / "error_vs_length.png"
    plotted = plot_error_grid(ev, panels, png, KINDS, methods=order, split_labels=SPLIT_LABELS, log_y=True)
    if plotted:
        parts.append(f"![error against sequence length]({png.name})\n")
    md = out / "paper_table.md"
    write_text_atomic(md, "\n".join(parts))
    return [md, png] if plotted else [md]


if __name__ == "__main__":
    sys.exit(main())
