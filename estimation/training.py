"""Training loop: Adam, early stopping, ReduceLROnPlateau, fresh noise each epoch, checkpoints, resume.

A run folder holds::

    run.json        the training config and a description of the data it was trained on
    checkpoint.pt   the state after the last finished epoch (weights, optimiser, scheduler, history)
    model.pt        the best weights so far (by validation loss); what evaluation loads
    training.rrd    the training curves (written when training ends)

Every epoch reseeds its generators from ``(seed, epoch)``, so resuming after epoch k is bitwise the
same as not having stopped (on CPU).
"""

from __future__ import annotations

import json
import math
import os
import queue
import threading
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mmwsim.faults import fault

from .checkpoint import CHECKPOINT_FORMAT, load_checkpoint, save_checkpoint
from .data import Batch, BatchSampler, SequenceSet
from .errors import EstimationError
from .estimator import MODEL_FILE, Estimator, TrainConfig
from .models import positions

__all__ = ["train", "log_training", "CHECKPOINT_FILE", "RUN_FILE", "read_run_info"]

CHECKPOINT_FILE = "checkpoint.pt"
RUN_FILE = "run.json"
RECORDING_FILE = "training.rrd"
_HISTORY_KEYS = ("train_loss", "val_loss", "val_rmse", "lr", "seconds")
_WARMUP_BATCH = 4  # single fingerprints per warm-up batch, in units of the batch size


def _lengths(cfg: TrainConfig, data: SequenceSet) -> tuple[int, int]:
    if cfg.task == "forecasting":
        return cfg.t_obs, cfg.horizon
    hi = cfg.max_length or data.length
    return min(cfg.min_length, hi), hi


def read_run_info(run: str | os.PathLike) -> dict[str, Any]:
    """The ``run.json`` of a run folder."""
    path = Path(run) / RUN_FILE
    try:
        info = json.loads(path.read_text())
    except FileNotFoundError:
        raise EstimationError(f"{run}: not a training run (no {RUN_FILE})") from None
    except (OSError, ValueError) as e:
        raise EstimationError(f"{path}: unreadable run description ({e})") from None
    if not isinstance(info, dict) or not all(isinstance(info.get(k, {}), dict) for k in ("data", "summary")):
        raise EstimationError(f"{path}: not a run description (expected an object with data and summary)")
    return info


def _write_json(path: Path, obj: Any) -> None:
    from mmwsim.files import write_text_atomic

    write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=True))


@torch.no_grad()
def _validate(est: Estimator, batches: Iterable[Batch]) -> tuple[float, float]:
    """Mean loss (:meth:`Estimator.loss`) and mean per-trajectory RMSE (metres) on fixed-noise batches."""
    est.eval()
    loss_sum, n, rmse = 0.0, 0, []
    for b in batches:
        out = est(b.bits if b.inputs is None else b.inputs)
        total, terms = est.loss(out, b.y)
        loss_sum += float(total)
        n += terms
        err = est.normaliser.to_metres(positions(out)) - b.y
        rmse.append(err.pow(2).sum(-1).mean(-1).sqrt())
    return loss_sum / max(n, 1), float(torch.cat(rmse).mean())


def log_training(rec: Any, name: str, history: dict[str, list[float]]) -> int:
    """Log a training history into an open :class:`mmwsim.recording.Recording`.

    One row per epoch on the ``epoch`` timeline (1-based) at ``training/<name>/loss/train``,
    ``training/<name>/loss/validation``, ``training/<name>/rmse_m/validation`` (metres) and
    ``training/<name>/learning_rate``; and the same curves as static bar charts by epoch at
    ``training/per_epoch/{loss,rmse_m,learning_rate}/<name>/...``, which the Training tab shows
    whatever timeline is active.

    Parameters
    ----------
    rec : mmwsim.recording.Recording
    name : str
        Label of the run in the entity path (usually the model, e.g. ``tn``).
    history : dict
        Per-epoch lists ``train_loss``, ``val_loss``, ``val_rmse`` and ``lr``, as stored in a
        run's ``checkpoint.pt``.

    Returns
    -------
    int
        Number of epochs logged.
    """
    import rerun as rr

    from mmwsim.recording import Entity, Timeline

    n = len(history["train_loss"])
    for e in range(n):
        rec.set_time(Timeline.EPOCH, e + 1)
        rec.log(Entity.training(name, "loss/train"), rr.Scalars(history["train_loss"][e]))
        rec.log(Entity.training(name, "loss/validation"), rr.Scalars(history["val_loss"][e]))
        rec.log(Entity.training(name, "rmse_m/validation"), rr.Scalars(history["val_rmse"][e]))
        rec.log(Entity.training(name, "learning_rate"), rr.Scalars(history["lr"][e]))
    if n:
        epoch = np.arange(1, n + 1, dtype=np.float64)
        # A bar starts at its abscissa: train and validation side by side around each epoch.
        for key, entity, start, width, colour in (
            ("train_loss", Entity.training_bars("loss", name) + "/train", -0.4, 0.4, (80, 160, 255)),
            ("val_loss", Entity.training_bars("loss", name) + "/validation", 0.0, 0.4, (255, 160, 60)),
            ("val_rmse", Entity.training_bars("rmse_m", name) + "/validation", -0.4, 0.8, (255, 160, 60)),
            ("lr", Entity.training_bars("learning_rate", name), -0.4, 0.8, (150, 210, 120)),
        ):
            rec.log(
                entity,
                rr.BarChart(
                    np.asarray(history[key], dtype=np.float64),
                    abscissa=epoch + start,
                    widths=np.full(n, width),
                    color=colour,
                ),
                static=True,
            )
    return n


def _record(run: Path, cfg: TrainConfig, history: dict[str, list[float]]) -> None:
    from mmwsim.recording import Recording

    with Recording(
        run / RECORDING_FILE,
        f"training-{cfg.model}",
        families=("training",),
        config=json.loads(cfg.to_json()),
    ) as rec:
        log_training(rec, cfg.model, history)


def _prefetch(batches: Iterator, depth: int = 3) -> Iterator:
    """Draw batches (gather + fresh noise) in a background thread while the model trains on the
    previous one. torch releases the GIL in its kernels, so this uses a second core; one thread
    draws all batches in order, so the result is the same as drawing them inline."""
    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def work():
        try:
            for b in batches:
                if stop.is_set():
                    return
                q.put(b)
            q.put(done)
        except BaseException as e:  # re-raised in the consumer
            q.put(e)

    t = threading.Thread(target=work, daemon=True)
    t.start()
    try:
        while True:
            item = q.get()
            if item is done:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while t.is_alive():  # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                t.join(0.01)


def train(
    train_set: SequenceSet,
    val_set: SequenceSet,
    cfg: TrainConfig,
    run: str | os.PathLike,
    resume: bool = False,
    data_info: dict[str, Any] | None = None,
    progress: bool = True,
    record: bool = True,
    log=print,
    time_limit: float | None = None,
) -> dict[str, Any]:
    """Train ``cfg.model`` and write the run folder ``run``.

    Parameters
    ----------
    train_set, val_set : SequenceSet
        Training and validation trajectories (on the same grid).
    cfg : TrainConfig
    run : path-like
        Run folder; created if missing. An existing checkpoint there is an error unless ``resume``.
    resume : bool
        Continue from ``run/checkpoint.pt`` (same config required, except ``epochs``).
    data_info : dict, optional
        Description of the data (data set path, content hash, splits), stored in ``run.json``.
    progress : bool
        Show a tqdm bar per epoch.
    record : bool
        Write ``run/training.rrd`` with the training curves at the end.
    time_limit : float, optional
        Seconds of wall time after which no new epoch is started (the run stays resumable).

    Returns
    -------
    dict
        Summary: ``epochs`` run, ``best_val_loss``, ``best_val_rmse`` (m), ``train_seconds``,
        ``parameters``, ``stopped_early``.
    """
    from mmwsim.locks import locked_output

    run = Path(run)
    if run.exists() and not run.is_dir():
        raise EstimationError(f"{run}: exists and is not a folder")
    if run.is_dir() and any(run.iterdir()) and not (run / RUN_FILE).exists():
        raise EstimationError(f"{run}: a folder that is not a training run; choose another --out")
    if time_limit is not None and not (math.isfinite(time_limit) and time_limit >= 0):
        raise EstimationError(f"time limit must be a finite number of seconds >= 0, got {time_limit}")
    _check_sets(train_set, val_set)
    # One trainer per run folder; a run that fails before its first checkpoint leaves nothing,
    # a later one stays resumable.
    with locked_output(run, "run folder", create=True, keep=(run / CHECKPOINT_FILE).exists):
        if (run / CHECKPOINT_FILE).exists() and not resume:
            raise EstimationError(f"{run}: already holds a checkpoint; pass --resume or choose another --out")
        # Tiny probabilities of far cells underflow to denormals, whose arithmetic is many times
        # slower on CPUs; flushed to zero while training (below 1e-38 nothing here is changed by it).
        torch.set_flush_denormal(True)
        try:
            return _run(train_set, val_set, cfg, run, resume, data_info, progress, record, log, time_limit)
        finally:
            torch.set_flush_denormal(False)


def _run(
    train_set: SequenceSet,
    val_set: SequenceSet,
    cfg: TrainConfig,
    run: Path,
    resume: bool,
    data_info: dict[str, Any] | None,
    progress: bool,
    record: bool,
    log,
    time_limit: float | None,
) -> dict[str, Any]:
    """The body of :func:`train`, with the run folder checked and locked."""
    lengths = _lengths(cfg, train_set)
    sampler = BatchSampler(
        train_set, cfg.task, cfg.sigma, cfg.batch_size, lengths, cfg.seed, epoch_size=cfg.epoch_size
    )
    val_lengths = (lengths[1], lengths[1]) if cfg.task == "tracking" else lengths
    val_sampler = BatchSampler(val_set, cfg.task, cfg.sigma, 256, val_lengths, cfg.seed + 1, shuffle=False)
    est = _build_estimator(cfg, train_set, val_set)
    opt = torch.optim.Adam(est.net.parameters(), lr=cfg.lr, foreach=True)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=cfg.lr_factor, patience=cfg.lr_patience)
    state = _State()
    if resume and (run / CHECKPOINT_FILE).exists():
        state = _resume(run / CHECKPOINT_FILE, cfg, est, opt, sched)
        log(f"resuming {cfg.model} after epoch {state.epoch}")
    info = {
        "config": json.loads(cfg.to_json()),
        "data": data_info or {},
        "parameters": est.n_parameters,
        "n_beams": train_set.n_beams,
        "n_bins": train_set.n_bins,
        "lengths": list(lengths),
        "n_train": train_set.n,
        "n_val": val_set.n,
    }
    _write_json(run / RUN_FILE, info)
    val_batches = _validation_batches(est, val_sampler)
    started = time.perf_counter()
    while not state.done and state.epoch < cfg.epochs:
        if time_limit is not None and time.perf_counter() - started >= time_limit:
            log(f"{cfg.model}: time limit reached after epoch {state.epoch}; continue with --resume")
            break
        t0 = time.perf_counter()
        lr = _epoch_lr(cfg, state.epoch)
        if lr is not None:
            for group in opt.param_groups:
                group["lr"] = lr
        train_loss = _train_epoch(est, opt, sampler, cfg, state.epoch, progress)
        val_loss, val_rmse = _validate(est, val_batches)
        lr = opt.param_groups[0]["lr"]
        if cfg.schedule == "plateau" and state.epoch >= cfg.warmup_epochs:  # a warm-up's plateau
            sched.step(val_loss)  # says nothing of the sequences
        _end_epoch(
            run, cfg, est, opt, sched, state, (train_loss, val_loss, val_rmse, lr, time.perf_counter() - t0)
        )
        log(
            f"{cfg.model} {'warm-up' if state.epoch <= cfg.warmup_epochs else 'epoch'} {state.epoch}: "
            f"train {train_loss:.5f} val {val_loss:.5f} "
            f"rmse {val_rmse:.2f} m lr {lr:.1e} ({state.history['seconds'][-1]:.1f} s)"
        )
    if record and state.history["train_loss"]:
        _record(run, cfg, state.history)
    summary = _summary(state, est)
    _write_json(run / RUN_FILE, info | {"summary": summary})
    return summary


def _epoch_lr(cfg: TrainConfig, epoch: int) -> float | None:
    """The learning rate of 0-based ``epoch``, or None where the plateau scheduler sets it."""
    warm = cfg.warmup_epochs
    first, length, top = (0, warm, cfg.warmup_lr) if epoch < warm else (warm, cfg.epochs - warm, cfg.lr)
    if cfg.schedule == "cosine":
        return top * 0.5 * (1.0 + math.cos(math.pi * (epoch - first) / length))
    return top if epoch == first else None


@dataclass
class _State:
    """Where a training run stands after ``epoch`` epochs (what a checkpoint restores)."""

    epoch: int = 0
    best_val: float = math.inf  # best validation loss: the weights in model.pt
    ref_val: float = math.inf  # the last validation loss that counted as an improvement
    bad: int = 0  # epochs since then
    done: bool = False  # stopped early
    history: dict[str, list[float]] = field(default_factory=lambda: {k: [] for k in _HISTORY_KEYS})


def _check_sets(train_set: SequenceSet, val_set: SequenceSet) -> None:
    if train_set.n == 0 or val_set.n == 0:
        raise EstimationError("training and validation sets must not be empty")
    if (train_set.n_beams, train_set.n_bins) != (val_set.n_beams, val_set.n_bins):
        raise EstimationError("training and validation fingerprints differ in shape")


def _build_estimator(cfg: TrainConfig, train_set: SequenceSet, val_set: SequenceSet) -> Estimator:
    """The untrained estimator, seeded; a grid-reading network gets the grid and its motion tables."""
    torch.manual_seed(cfg.seed)
    est = Estimator(cfg, train_set.n_beams, train_set.n_bins, train_set.normaliser()).attach(train_set)
    if not est.uses_grid:
        return est
    same_grid = val_set.grid_pdp is train_set.grid_pdp or (
        val_set.grid_pdp.shape == train_set.grid_pdp.shape
        and torch.equal(val_set.grid_pdp, train_set.grid_pdp)
    )
    if not same_grid:
        raise EstimationError(f"{cfg.model} needs training and validation sets on one grid")
    if train_set.length >= 3:
        # The smoothers' motion statistics, measured where their candidates live: on grid points,
        # and on the sub-cell lattice.
        est.fit_motion(train_set)
    return est


def _resume(path: Path, cfg: TrainConfig, est: Estimator, opt, sched) -> _State:
    """Load the checkpoint at ``path`` into the network, optimiser and scheduler; its state."""
    state = load_checkpoint(
        path, CHECKPOINT_FORMAT, ("config", "epoch", "model", "optimizer", "scheduler", "history", "best_val")
    )
    try:
        saved = TrainConfig.from_json(state["config"])
    except (ValueError, TypeError) as e:
        raise EstimationError(f"{path}: unreadable config ({e})") from None
    if json.loads(saved.to_json()) | {"epochs": 0} != json.loads(cfg.to_json()) | {"epochs": 0}:
        raise EstimationError(f"{path}: was written with other settings ({saved.to_json()})")
    try:
        est.net.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
    except (RuntimeError, ValueError, KeyError, TypeError) as e:
        raise EstimationError(f"{path}: does not fit this model ({str(e).splitlines()[0][:160]})") from None
    best_val = float(state["best_val"])
    return _State(
        epoch=int(state["epoch"]),
        best_val=best_val,
        ref_val=float(state.get("ref_val", best_val)),
        bad=int(state.get("bad_epochs", 0)),
        done=bool(state.get("done", False)),
        history={k: list(state["history"][k]) for k in _HISTORY_KEYS},
    )


def _validation_batches(est: Estimator, val_sampler: BatchSampler) -> Iterable[Batch]:
    """The validation batches: the noise of epoch 0 every time, so that epochs are comparable. A
    grid-reading network's candidate search is the costly part and depends on the noise alone:
    done once here."""
    if not est.uses_grid:
        return _Epoch0(val_sampler)
    return [replace(b, bits=b.bits[:0], inputs=_inputs(est, b.bits)) for b in val_sampler.epoch(0)]


def _inputs(est: Estimator, bits: torch.Tensor) -> Any:
    """What the network trains on: a grid-reading network's inputs from a filter of its own ``k``
    candidates per step, its split cells one mode. Prediction's filter keeps more
    (``FILTER_CANDIDATES``) and places each mode of the split cells apart (``MODE_CHAIN``),
    whose better estimate a network trained this way reads with a gain; trained on that
    filter's own candidates, the 8-minute network tracked worse (docs/estimation.md, "More
    candidates kept than read"; on its modes, "Modes of the split cells")."""
    if not est.uses_grid:
        return est.inputs(bits)
    return est.inputs(bits, candidates=est.net.k, mode_chain=math.inf)


class _Epoch0:
    """The batches of a sampler's epoch 0, drawn afresh (same noise) at every pass."""

    def __init__(self, sampler: BatchSampler):
        self.sampler = sampler

    def __iter__(self) -> Iterator[Batch]:
        return iter(self.sampler.epoch(0))


def _train_epoch(
    est: Estimator, opt, sampler: BatchSampler, cfg: TrainConfig, epoch: int, progress: bool
) -> float:
    """One pass over the epoch's batches; the mean training loss per trajectory (per fingerprint in
    a warm-up epoch)."""
    torch.manual_seed(cfg.seed * 7919 + epoch + 1)  # dropout masks of this epoch
    est.train()
    warm = epoch < cfg.warmup_epochs
    if warm:
        size = _WARMUP_BATCH * cfg.batch_size
        drawn, n_batches = sampler.singles(epoch, size), -(-sampler.per_epoch * sampler.data.length // size)
    else:
        drawn, n_batches = sampler.epoch(epoch), len(sampler)
    # The worker thread also prepares what the network reads (candidate search for tn-match).
    batches = _prefetch(replace(b, inputs=_inputs(est, b.bits)) for b in drawn)
    if progress:
        from tqdm import tqdm

        what = "warm-up" if warm else "epoch"
        batches = tqdm(
            batches, total=n_batches, desc=f"{cfg.model} {what} {epoch + 1}", leave=False, unit="batch"
        )
    held = [p for p in getattr(est.net, "sequence_parameters", list)() if p.requires_grad] if warm else []
    total, count = 0.0, 0
    try:
        for p in held:  # a warm-up teaches single fingerprints: what reads across steps waits
            p.requires_grad_(False)
        for b in batches:
            out = est(b.inputs, b.y)
            total_loss, terms = est.loss(out, b.y)
            loss = total_loss / terms
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(b.rows)
            count += len(b.rows)
    finally:
        for p in held:
            p.requires_grad_(True)
    return total / count


def _end_epoch(
    run: Path, cfg: TrainConfig, est: Estimator, opt, sched, state: _State, figures: tuple
) -> None:
    """Book an epoch's ``(train_loss, val_loss, val_rmse, lr, seconds)``: history, best weights,
    early stopping, and the checkpoint."""
    state.epoch += 1
    for k, v in zip(_HISTORY_KEYS, figures, strict=True):
        state.history[k].append(float(v))
    _, val_loss, val_rmse, _, _ = figures
    if val_loss < state.best_val:
        state.best_val = val_loss
        est.save(run / MODEL_FILE, {"epoch": state.epoch, "val_loss": val_loss, "val_rmse": val_rmse})
    # Early stopping waits for a real improvement; the best model is kept whatever its margin.
    if state.epoch <= cfg.warmup_epochs:
        state.ref_val, state.bad = min(state.ref_val, val_loss), 0
    elif state.epoch == cfg.warmup_epochs + 1 and cfg.warmup_epochs:
        # The sequence phase restarts its learning rate, so its loss first rises above the
        # warm-up's best; patience counts from the phase's own first epoch.
        state.ref_val, state.bad = val_loss, 0
    elif val_loss < state.ref_val * (1 - cfg.min_delta):
        state.ref_val, state.bad = val_loss, 0
    else:
        state.bad += 1
    state.done = state.bad >= cfg.patience
    fault("train.epoch", run / CHECKPOINT_FILE)
    save_checkpoint(
        run / CHECKPOINT_FILE,
        {
            "format": CHECKPOINT_FORMAT,
            "config": cfg.to_json(),
            "epoch": state.epoch,
            "model": est.net.state_dict(),
            "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(),
            "history": state.history,
            "best_val": state.best_val,
            "ref_val": state.ref_val,
            "bad_epochs": state.bad,
            "done": state.done,
        },
    )
    fault("train.checkpointed", run / CHECKPOINT_FILE)


def _summary(state: _State, est: Estimator) -> dict[str, Any]:
    history = state.history
    best_epoch = int(np.argmin(history["val_loss"])) if history["val_loss"] else -1
    return {
        "epochs": state.epoch,
        "best_epoch": best_epoch + 1,
        "best_val_loss": state.best_val,
        "best_val_rmse": history["val_rmse"][best_epoch] if best_epoch >= 0 else math.nan,
        "train_seconds": float(sum(history["seconds"])),
        "parameters": est.n_parameters,
        "stopped_early": state.done,
    }
