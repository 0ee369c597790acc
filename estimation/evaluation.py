"""Evaluation of trained runs and the classical baseline on held-out trajectories.

All methods see the same noisy fingerprints: for each split and noise level the bits of the full
trajectories are drawn once from a seeded generator, and every method and sequence length uses
(crops of) those bits, so differences between methods are not differences in noise.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from ._parts import map_parts
from .classical import KnnKalman, MatchSmoother
from .data import SequenceSet
from .errors import EstimationError
from .estimator import Estimator
from .matching import blank_steps
from .metrics import summarise_by_kind, trajectory_rmse
from .names import CLASSICAL_NAMES, Task
from .noise import noisy_bits
from .training import read_run_info

if TYPE_CHECKING:
    from .oracle import OracleMethod
    from .smoothing.online import CandidateFilter

__all__ = [
    "Evaluation",
    "KnnKalmanMethod",
    "MatchSmootherMethod",
    "NetworkMethod",
    "classical_method",
    "evaluate",
    "method",
]

_BATCH = 512
# Sequences per part of a grid-reading network's (and match-cv's) prefixes: the parts run side by
# side, one per thread (:func:`~estimation._parts.map_parts`), so two of 256 hold what one of 512
# held. match-cv held all of them at once: 2.4 s against 2.2 s per 1000 sequences, prefixes 2..7.
_PART = 256


def _per_prefix(
    bits: torch.Tensor,
    lengths: list[int],
    per_step: Callable[[torch.Tensor], Any],
    finish: Callable[[Any, int], np.ndarray],
) -> dict[int, tuple[np.ndarray, float]]:
    """``{L: (finish(found, L), seconds)}`` for each length: the per-step work ``per_step`` runs once
    over the longest crop (each step's result is its own, so a prefix's is a prefix), ``finish``
    sees only the first ``L`` steps of it (no look-ahead); each length is charged its share of the
    per-step time."""
    return _shared_prefixes(bits, lengths, per_step, lambda found, lens: [found] * len(lens), finish)


def _shared_prefixes(
    bits: torch.Tensor,
    lengths: list[int],
    per_step: Callable[[torch.Tensor], Any],
    smooth: Callable[[Any, list[int]], list[Any]],
    finish: Callable[[Any, int], np.ndarray],
    part: int | None = None,
) -> dict[int, tuple[np.ndarray, float]]:
    """:func:`_per_prefix` for per-step work whose prefixes share work: ``smooth(found, lengths)``
    gives what ``finish(x, L)`` reads for each length, from the first ``L`` steps only.

    With ``part``, the sequences go in parts of that many, side by side on the process's threads
    (:func:`~estimation._parts.map_parts`), each part's per-step work smoothed and let go before
    the thread takes the next: one part's state (a candidate filter's stored messages, about
    57 kB per user and step) is held per thread. Each length is charged its share of the
    per-step time, its share (by its number of steps) of the shared time, and its own
    ``finish``, measured on each part's thread; with parts side by side, each part's times are
    scaled by the wall-clock time the parts took together over the sum of their own times."""
    Lmax = max(lengths)
    crop = bits[:, :Lmax]

    def run(rows: slice) -> tuple[dict[int, np.ndarray], dict[int, float], float]:
        t0 = time.perf_counter()
        found = per_step(crop[rows])
        step_seconds = (time.perf_counter() - t0) / Lmax
        t1 = time.perf_counter()
        shared = smooth(found, lengths)
        del found
        per_step_shared = (time.perf_counter() - t1) / sum(lengths)
        preds, seconds = {}, {}
        for L, x in zip(lengths, shared, strict=True):
            t2 = time.perf_counter()
            preds[L] = finish(x, L)
            seconds[L] = (step_seconds + per_step_shared) * L + time.perf_counter() - t2
        return preds, seconds, time.perf_counter() - t0

    n = len(bits)
    rows = [slice(a, a + part) for a in range(0, max(n, 1), part)] if part else [slice(0, n)]
    t = time.perf_counter()
    done = map_parts(run, rows)
    wall = time.perf_counter() - t
    busy = sum(b for _, _, b in done)  # the parts' own times, more than the wall's side by side
    scale = wall / busy if busy > 0 else 1.0
    return {
        L: (np.concatenate([p[L] for p, _, _ in done]), scale * sum(s[L] for _, s, _ in done))
        for L in lengths
    }


class NetworkMethod:
    """A trained run as an evaluation method.

    Parameters
    ----------
    estimator : Estimator
    name : str
        Label in tables and recordings.
    train_seconds : float
    epochs : int
    dataset : str, optional
        The data set the run was trained on.
    """

    fitted: dict[float, dict[str, Any]] = {}  # nothing is fitted at evaluation

    def __init__(
        self,
        estimator: Estimator,
        name: str,
        train_seconds: float = float("nan"),
        epochs: int = 0,
        dataset: str | None = None,
    ):
        self.est, self.name, self.dataset = estimator, name, dataset
        cfg = estimator.config
        self.task, self.t_obs, self.horizon = cfg.task, cfg.t_obs, cfg.horizon
        self.n_parameters, self.train_seconds, self.epochs = estimator.n_parameters, train_seconds, epochs

    @classmethod
    def from_run(cls, run: str | os.PathLike) -> NetworkMethod:
        """The best weights of a run folder, labelled by the folder's name."""
        info = read_run_info(run)
        summary = info.get("summary", {})
        seconds, epochs = summary.get("train_seconds", float("nan")), summary.get("epochs", 0)
        trained_on = info.get("data", {}).get("dataset")
        if (
            isinstance(seconds, bool)
            or not isinstance(seconds, (int, float))
            or isinstance(epochs, bool)
            or not isinstance(epochs, int)
            or not isinstance(trained_on, (str, type(None)))
        ):
            raise EstimationError(f"{run}: run.json has a malformed summary or data description")
        return cls(Estimator.load(run), Path(run).resolve().name, float(seconds), epochs, trained_on)

    def for_sigma(self, sigma: float, validation: SequenceSet | None) -> NetworkMethod:
        if self.est.uses_grid:
            if validation is None:
                raise EstimationError(f"{self.name} needs the data set's grid (pass validation trajectories)")
            self.est.attach(validation, sigma)
        return self

    def predict_lengths(self, bits: torch.Tensor, lengths: list[int]) -> dict[int, tuple[np.ndarray, float]]:
        """Predictions for inputs cropped to each length: ``{T_in: (pred (n, T_out, 2), seconds)}``.

        A grid-reading network's candidate filter runs forward once over the longest crop (one
        update per step); each length then costs one backward pass over its steps and the network."""
        if not self.est.uses_grid:
            return _per_prefix(bits, lengths, lambda b: b, lambda b, L: self._predict(b[:, :L].float()))

        def forward(b: torch.Tensor) -> CandidateFilter:
            return self.est.candidate_filter().run(*self.est.search(b.float()), blank_steps(b))

        return _shared_prefixes(
            bits,
            lengths,
            forward,
            lambda f, lens: f.smooth_prefixes(lens),
            lambda x, L: self.est.predict(x).numpy().astype(np.float64),
            part=_PART,
        )

    def _predict(self, x: torch.Tensor) -> np.ndarray:
        return (
            torch.cat([self.est.predict(x[k : k + _BATCH]) for k in range(0, len(x), _BATCH)])
            .numpy()
            .astype(np.float64)
        )


class KnnKalmanMethod:
    """The classical baseline (:class:`~estimation.classical.KnnKalman`), fitted per noise level on
    validation trajectories."""

    name = "knn-kalman"
    n_parameters = 0
    train_seconds = 0.0
    epochs = 0

    def __init__(
        self,
        task: str = "tracking",
        t_obs: int = 5,
        horizon: int = 2,
        fit_length: int = 7,
        n_fit: int = 300,
        seed: int = 0,
    ):
        self.task, self.t_obs, self.horizon = task, t_obs, horizon
        self.fit_length, self.n_fit, self.seed = fit_length, n_fit, seed
        self.model: KnnKalman | None = None
        self.fitted: dict[float, dict[str, Any]] = {}

    def for_sigma(self, sigma: float, validation: SequenceSet | None) -> KnnKalmanMethod:
        if validation is None or validation.n == 0:
            raise EstimationError("knn-kalman needs validation trajectories to fit its Kalman parameters")
        m = KnnKalmanMethod(self.task, self.t_obs, self.horizon, self.fit_length, self.n_fit, self.seed)
        m.fitted = self.fitted
        m.model = KnnKalman(validation, sigma, self.task, self.horizon)
        pick = np.random.default_rng(self.seed).permutation(validation.n)[: self.n_fit]
        val = validation.subset(np.sort(pick))  # a random subset: splits may be ordered by kind
        T = self.t_obs + self.horizon if self.task == "forecasting" else min(self.fit_length, val.length)
        val = val.crop(0, T)
        bits = noisy_bits(val, sigma, torch.Generator().manual_seed(self.seed + 99))
        if self.task == "tracking":
            fit = m.model.fit(bits, val.positions)
        else:
            fit = m.model.fit(bits[:, : self.t_obs], val.positions[:, self.t_obs :])
        self.fitted[sigma] = fit
        return m

    def predict_lengths(self, bits: torch.Tensor, lengths: list[int]) -> dict[int, tuple[np.ndarray, float]]:
        assert self.model is not None
        return _per_prefix(bits, lengths, self.model.matcher.match, lambda z, L: self.model.smooth(z[:, :L]))


class MatchSmootherMethod:
    """The candidate smoother :class:`~estimation.classical.MatchSmoother` (tracking; nothing to fit)."""

    name = "match-cv"
    task, t_obs, horizon = "tracking", 0, 0
    n_parameters = 0
    train_seconds = 0.0
    epochs = 0
    fitted: dict[float, dict[str, Any]] = {}  # nothing to fit

    def __init__(self) -> None:
        self.model: MatchSmoother | None = None

    def for_sigma(self, sigma: float, validation: SequenceSet | None) -> MatchSmootherMethod:
        if validation is None:
            raise EstimationError("match-cv needs the data set's grid (pass validation trajectories)")
        m = MatchSmootherMethod()
        m.model = MatchSmoother(validation, sigma)
        return m

    def predict_lengths(self, bits: torch.Tensor, lengths: list[int]) -> dict[int, tuple[np.ndarray, float]]:
        assert self.model is not None
        return _shared_prefixes(
            bits,
            lengths,
            lambda b: self.model.filter(*self.model.search(b.float())),
            lambda f, lens: f.smooth_prefixes(lens),
            lambda x, L: x[2].numpy().astype(np.float64),
            part=_PART,
        )


def classical_method(
    name: str, task: Task = "tracking", t_obs: int = 5, horizon: int = 2, fit_length: int = 7, seed: int = 0
) -> KnnKalmanMethod | MatchSmootherMethod | OracleMethod:
    """The untrained tracker ``name`` (one of :data:`estimation.names.CLASSICAL_NAMES`) as a method.

    ``task``, ``t_obs`` and ``horizon`` set what ``knn-kalman`` estimates, ``fit_length`` the
    validation crops its parameters are fitted on; ``match-cv`` tracks and fits nothing. ``oracle``
    (the floor, :class:`~estimation.oracle.OracleMethod`, either task) still needs its data set:
    ``use_dataset(path)`` before :func:`evaluate`.
    """
    if name == "knn-kalman":
        return KnnKalmanMethod(task, t_obs, horizon, fit_length, seed=seed)
    if name == "match-cv":
        return MatchSmootherMethod()
    if name == "oracle":
        from .oracle import OracleMethod  # scipy and shapely only when asked for

        return OracleMethod(seed=seed, task=task, t_obs=t_obs, horizon=horizon)
    raise EstimationError(f"unknown classical tracker {name!r} (choose from {', '.join(CLASSICAL_NAMES)})")


def method(
    run: str | os.PathLike, **classical_options: Any
) -> NetworkMethod | KnnKalmanMethod | MatchSmootherMethod | OracleMethod:
    """An evaluation method by what names it: a classical tracker or the oracle (see
    :func:`classical_method`, which ``classical_options`` go to) or a training run folder."""
    if str(run) in CLASSICAL_NAMES:
        return classical_method(str(run), **classical_options)
    if not Path(run).is_dir():
        raise EstimationError(f"{run}: not a run folder (nor {' or '.join(CLASSICAL_NAMES)})")
    return NetworkMethod.from_run(run)


@dataclass
class Evaluation:
    """Results of :func:`evaluate`.

    Attributes
    ----------
    rows : list of dict
        One per (method, split, sigma, task, length, kind): ``n, mean, median, p95`` (metres).
    cost : dict method -> dict
        ``parameters``, ``train_seconds``, ``epochs``, ``predict_seconds`` (per 1000 sequences of
        ``table_length`` steps).
    examples : dict split -> dict
        ``true (k, L, 2)``, ``kind (k,)`` and per method ``(k, L, 2)`` tracking predictions of a few
        trajectories at the first noise level, for the recording.
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    cost: dict[str, dict[str, Any]] = field(default_factory=dict)
    examples: dict[str, dict[str, Any]] = field(default_factory=dict)
    table_length: int = 7
    fitted: dict[str, Any] = field(default_factory=dict)

    def select(self, **where) -> list[dict[str, Any]]:
        return [r for r in self.rows if all(r.get(k) == v for k, v in where.items())]


def evaluate(
    methods: list,
    sets: dict[str, SequenceSet],
    noises: list[float],
    validation: SequenceSet | None,
    lengths: list[int] | None = None,
    table_length: int = 7,
    max_trajectories: int | None = None,
    n_examples: int = 4,
    seed: int = 0,
    progress: bool = True,
    log=print,
) -> Evaluation:
    """Evaluate methods on the trajectory sets.

    Parameters
    ----------
    methods : list of NetworkMethod / KnnKalmanMethod
    sets : dict split name -> SequenceSet
        Test trajectories (e.g. ``test/seen`` and ``test/holdout``).
    noises : list of float, dB
    validation : SequenceSet or None
        For fitting the classical baseline.
    lengths : list of int, optional
        Tracking sequence lengths to evaluate (default 2..L); ``table_length`` is always included.
    table_length : int
        Length of the accuracy table (the paper's 7 steps).
    max_trajectories : int, optional
        Evaluate at most this many trajectories per split (a seeded random subset).
    n_examples : int
        Trajectories per kind kept for the recording.
    seed : int
    progress : bool
        Show a bar of the runs (method, noise level, split) done on stderr where it is a
        terminal (tqdm); ``log``'s lines are written above it.
    log : callable
        Takes each run's summary line.
    """
    if not all(math.isfinite(float(n)) and n >= 0 for n in noises):
        raise EstimationError(f"noise levels must be finite and >= 0 dB, got {list(noises)}")
    if table_length < 1 or (max_trajectories is not None and max_trajectories < 0):
        raise EstimationError(
            f"table_length must be >= 1 and max_trajectories >= 0, got {table_length}, {max_trajectories}"
        )
    longest = max((d.length for d in sets.values() if d.n), default=None)
    if lengths and longest is not None and not all(1 <= v <= longest for v in lengths):
        raise EstimationError(
            f"sequence lengths {list(lengths)} must be within 1..{longest} (the trajectories' length)"
        )
    ev = Evaluation(table_length=table_length)
    names = [m.name for m in methods]
    if len(set(names)) != len(names):
        raise EstimationError(f"two methods share a name: {names}")
    runs = sum(1 for d in sets.values() if d.n) * len(noises) * len(methods)
    with _runs_bar(runs, progress, log) as (bar, log):
        for si, (split, data) in enumerate(sets.items()):
            if data.n == 0:
                log(f"split {split}: no trajectories, skipped")
                continue
            data = _subsample(data, max_trajectories, seed)
            tl = min(table_length, data.length)
            lens = _tracking_lengths(data.length, lengths, tl)
            ex_rows = np.concatenate(
                [np.flatnonzero(data.kind == k)[:n_examples] for k in np.unique(data.kind)]
            )
            ev.examples[split] = {"true": data.positions[ex_rows], "kind": data.kind[ex_rows]}
            for ni, sigma in enumerate(noises):
                # The same noisy bits for every method: differences between methods are not noise.
                bits = noisy_bits(
                    data, sigma, torch.Generator().manual_seed(seed * 1_000_003 + si * 1009 + ni)
                )
                for m in methods:
                    t0 = time.perf_counter()
                    pm = m.for_sigma(sigma, validation)
                    fitted = getattr(m, "fitted", {})  # what a method fitted per noise level, if anything
                    if sigma in fitted:
                        ev.fitted.setdefault(m.name, {})[str(sigma)] = fitted[sigma]
                    if pm.task == "tracking":
                        secs = _evaluate_tracking(
                            ev, pm, split, data, sigma, bits, lens, tl, ex_rows if ni == 0 else None
                        )
                    else:
                        secs = _evaluate_forecasting(ev, pm, split, data, sigma, bits)
                    if ni == 0 and si == 0:
                        ev.cost[m.name] = {
                            "parameters": m.n_parameters,
                            "train_seconds": m.train_seconds,
                            "epochs": m.epochs,
                            "predict_seconds": secs * 1000 / data.n,
                        }
                    r = ev.select(method=m.name, split=split, sigma=sigma, kind="all")
                    log(
                        f"{split} {sigma:g} dB {m.name}: mean RMSE "
                        + ", ".join(
                            f"{x['length']}:{x['mean']:.2f}" for x in r if x["length"] in (tl, max(lens))
                        )
                        + f" m ({time.perf_counter() - t0:.1f} s)"
                    )
                    bar.update(1)
    return ev


@contextlib.contextmanager
def _runs_bar(total: int, show: bool, log):
    """A tqdm bar of ``total`` runs where ``show`` and stderr is a terminal, and ``log`` writing
    above it; with neither, a bar that shows nothing and ``log`` itself."""
    from tqdm import tqdm

    bar = tqdm(total=total, desc="evaluate", unit="run", leave=False, disable=None if show else True)

    def above(line: str) -> None:
        with tqdm.external_write_mode():
            log(line)

    try:
        yield bar, (log if bar.disable else above)
    finally:
        bar.close()


def _subsample(data: SequenceSet, max_trajectories: int | None, seed: int) -> SequenceSet:
    """At most ``max_trajectories`` of the set, a seeded random subset in their stored order."""
    if not max_trajectories or data.n <= max_trajectories:
        return data
    return data.subset(np.sort(np.random.default_rng(seed).permutation(data.n)[:max_trajectories]))


def _tracking_lengths(L: int, lengths: list[int] | None, table_length: int) -> list[int]:
    """The tracking sequence lengths evaluated on ``L``-step trajectories (the table's included)."""
    lens = sorted({min(v, L) for v in (lengths or range(2, L + 1))} | {table_length})
    return [v for v in lens if v >= 1]


def _evaluate_tracking(ev, method, split, data, sigma, bits, lens, table_length, examples) -> float:
    """Rows of every tracking length; the examples' tracks when ``examples`` rows are given.
    Returns the prediction seconds of the table length."""
    preds = method.predict_lengths(bits, lens)
    for T, (pred, _) in preds.items():
        _add(ev, method.name, split, sigma, "tracking", T, pred, data.positions[:, :T], data.kind)
    if examples is not None:
        ev.examples[split][method.name] = preds[max(lens)][0][examples]
    return preds[table_length][1]


def _evaluate_forecasting(ev, method, split, data, sigma, bits) -> float:
    """Rows of the forecast of ``method.horizon`` steps after ``method.t_obs``; returns its seconds."""
    need = method.t_obs + method.horizon
    if need > data.length:
        raise EstimationError(f"{method.name}: forecasting needs {need} steps, {split} has {data.length}")
    pred, secs = method.predict_lengths(bits, [method.t_obs])[method.t_obs]
    _add(
        ev,
        method.name,
        split,
        sigma,
        "forecasting",
        need,
        pred,
        data.positions[:, method.t_obs : need],
        data.kind,
    )
    return secs


def _add(ev: Evaluation, method, split, sigma, task, length, pred, true, kind) -> None:
    rmse = trajectory_rmse(pred, true)
    for k, s in summarise_by_kind(rmse, kind).items():
        ev.rows.append(
            {
                "method": method,
                "split": split,
                "sigma": float(sigma),
                "task": task,
                "length": int(length),
                "kind": k,
                **s,
            }
        )
