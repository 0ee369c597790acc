"""A trained network with its normalisation and configuration: what a run folder holds."""

from __future__ import annotations

import json
import math
import os
import threading
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from mmwsim._threads import pieces, threads
from mmwsim.constants import SIGMA_DB
from mmwsim.trajectories import StreetNetwork, TrajectoryError

from ._parts import map_parts
from ._stamps import same_stamp, stamp
from .checkpoint import MODEL_FORMAT, load_checkpoint, save_checkpoint
from .data import Normaliser, SequenceSet
from .errors import EstimationError
from .matching import FingerprintMatcher, blank_steps
from .models import CellHead, CellOutput, ModelSpec, build_network, count_parameters, model_spec, positions
from .models.candidate_transformer import grid_spacing
from .names import LOSSES, SCHEDULES, TASKS, Loss, ModelName, Schedule, Task
from .noise import check_bits
from .smoothing.forecast import extrapolate, forecast_tracks
from .smoothing.hmm import LOGP_FLOOR
from .smoothing.line import LINE_MIN_STEPS, line_weight
from .smoothing.motion import (
    BROADENED_BLOCKED,
    BROADENED_OPEN,
    PLACE_SPEED,
    POOLED_SPEED,
    MixtureMotion,
    MotionTable,
)
from .smoothing.online import (
    ADAPTED_PRIOR,
    ALTERNATIVE_PRIOR,
    FILTER_CANDIDATES,
    MODE_CHAIN,
    WALKER_SPEED_PRIOR,
    CandidateFilter,
)
from .smoothing.route import route_track
from .smoothing.two_lines import FreeRaster, free_raster
from .smoothing.walks import WALK_FREE_PRIOR, walk_track

__all__ = ["TrainConfig", "Estimator", "MODEL_FILE", "OnlineTracker"]

MODEL_FILE = "model.pt"
MODEL_KEYS = ("config", "n_beams", "n_bins", "normaliser", "state_dict")
"""What a model file holds beside its format (and whatever training adds, e.g. its epoch)."""


_WHOLE = (
    "epochs",
    "batch_size",
    "patience",
    "lr_patience",
    "min_length",
    "max_length",
    "t_obs",
    "horizon",
    "seed",
    "epoch_size",
    "warmup_epochs",
)
# Sequences per network call in prediction: the activations of a few hundred sequences take
# tens of megabytes, which the allocator maps afresh for every call; 64 at a time stay in the
# allocator's pool and the caches (prediction 1.2x to 1.6x faster, the same to float32 rounding).
PREDICT_CHUNK = 64
# Sequences per route pass (and forecast) in prediction: the route pass costs about 11 ms per call
# whatever its size (the street map's feet, the candidates' lookup), a third of its time on
# chunks of 64 (1000 seven-step sequences: 0.52 s in 16 calls, 0.35 s in one); bounded, as its
# arrays grow with the block, as do the candidate filter's, which prediction makes per block too.
ROUTE_CHUNK = 1024
ONLINE_ROUTE_STEPS = 5
"""Steps (the current one and those before it) over which :meth:`OnlineTracker.update` smooths
its drivers along their routes. On the default data set's 500 first seen-area vehicles (10 steps,
6 dB, one network) the current position's RMS error was 0.570 m filtered, 0.511 m over the last
5 or 7 steps, 0.514 m over 10."""


def _length(x: Any) -> int:
    """Sequences in a network input (a tensor, or a tuple of tensors whose first is one)."""
    return len(x[0]) if isinstance(x, tuple) else len(x)


def _blocks(n: int, size: int) -> list[slice]:
    """``range(n)`` in slices of ``size`` (one empty slice for none)."""
    return [slice(a, a + size) for a in range(0, max(n, 1), size)]


def _rows(x: Any, rows: slice) -> Any:
    """The sequences ``rows`` of a network input: a tensor, or a tuple of tensors (or None)."""
    if isinstance(x, tuple):
        return tuple(None if t is None else t[rows] for t in x)
    return x[rows]


_REAL = ("sigma", "lr", "warmup_lr", "dropout", "min_delta", "lr_factor")

RECIPE_DEFAULTS: dict[str, Any] = {
    "epochs": 100,
    "lr": 1e-3,
    "schedule": "plateau",
    "warmup_epochs": 0,
    "warmup_lr": 3e-3,
    "min_delta": 1e-3,
    "loss": "mse",
}
"""The settings a :class:`TrainConfig` leaves unset take the model's own
(:attr:`~estimation.models.ModelSpec.recipe`), else these: the paper's."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run (stored in the run folder and every checkpoint).

    Attributes
    ----------
    model : one of :data:`estimation.names.MODEL_NAMES` (``tn tn-match lstm gru rnn tcn conv1d``)
    task : ``tracking`` or ``forecasting``
    sigma : float, dB; noise of the training fingerprints
    epochs, batch_size, lr, dropout : the paper's optimisation settings (``epochs`` and ``lr``
        unset: the model's own, see :data:`RECIPE_DEFAULTS`)
    schedule : ``plateau`` (the paper's: the learning rate falls by ``lr_factor`` after
        ``lr_patience`` epochs without improvement) or ``cosine`` (each phase, the warm-up and the
        sequences, falls from its rate to zero along half a cosine by its last epoch); unset: the
        model's own
    patience : epochs without validation improvement before early stopping
    min_delta : relative fall of the validation loss that counts as an improvement for early stopping
        (unset: the model's own, 0 for ``tn``, whose cosine schedule makes the loss fall slowly to
        the end, else 1e-3)
    lr_patience, lr_factor : ReduceLROnPlateau settings
    min_length, max_length : tracking crops of T steps, T uniform in this range (max 0 = trajectory length)
    t_obs, horizon : forecasting: observed steps and predicted steps
    seed : int
    epoch_size : trajectories drawn (afresh, with fresh noise) per epoch; 0 = all of them
    loss : ``mse`` (the paper's, over all coordinates), ``rmse`` (mean per-trajectory RMSE, the
        evaluation metric, which weighs a lost track less than squared errors do) or ``cells`` (a
        cell head's cross-entropy plus a Huber position term, see :class:`~estimation.models.CellHead`); unset:
        the model's own (``rmse`` for ``tn-match``, ``cells`` for the others)
    warmup_epochs : tracking: epochs of single fingerprints before the sequences: every step of the
        epoch's trajectories on its own, shuffled, in batches of ``4 * batch_size`` at learning rate
        ``warmup_lr`` (unset: 3e-3); they teach the fingerprint embedding far faster than sequences, whose
        steps crowd one place. A network's ``sequence_parameters()`` (``tn``'s attention layers)
        are held meanwhile; the baselines train whole on one-step sequences. They count towards
        ``epochs``; early stopping and the plateau schedule wait for the sequences. Unset: the
        model's own (24 of 200 for the sequence networks, 0 for ``tn-match``), in proportion when
        ``epochs`` is set
    options : extra constructor arguments of the network (e.g. ``{"d": 64}``)
    """

    model: ModelName
    task: Task = "tracking"
    sigma: float = SIGMA_DB
    epochs: int | None = None
    batch_size: int = 64
    lr: float | None = None
    dropout: float = 0.01
    patience: int = 8
    min_delta: float | None = None
    lr_patience: int = 3
    lr_factor: float = 0.5
    min_length: int = 2
    max_length: int = 0
    t_obs: int = 5
    horizon: int = 2
    seed: int = 0
    epoch_size: int = 0
    warmup_epochs: int | None = None
    warmup_lr: float | None = None
    schedule: Schedule | None = None
    loss: Loss | None = None
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        spec = model_spec(self.model)
        own_epochs = self.epochs is None
        for name, default in RECIPE_DEFAULTS.items():
            current = getattr(self, name)
            if current is None:
                value = spec.recipe.get(name, default)
                if name == "warmup_epochs" and self.task != "tracking":
                    value = 0
                elif name == "warmup_epochs" and not own_epochs and isinstance(self.epochs, int):
                    # the recipe's warm-up keeps its share of a number of epochs set by hand
                    value = round(value * self.epochs / spec.recipe.get("epochs", self.epochs))
                object.__setattr__(self, name, value)
        for name in _WHOLE:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int):
                raise EstimationError(f"{name} must be a whole number (got {v!r})")
        for name in _REAL:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise EstimationError(f"{name} must be a finite number (got {v!r})")
        for name in ("lr_patience", "max_length", "seed", "epoch_size"):
            if getattr(self, name) < 0:
                raise EstimationError(f"{name} must not be negative (got {getattr(self, name)})")
        if not 0 < self.lr_factor < 1:
            raise EstimationError(f"lr_factor must be in (0, 1) (got {self.lr_factor})")
        if self.task not in TASKS:
            raise EstimationError(f"unknown task {self.task!r} ({', '.join(TASKS)})")
        for name in ("epochs", "batch_size", "patience", "min_length", "t_obs", "horizon"):
            if getattr(self, name) < 1:
                raise EstimationError(f"{name} must be at least 1 (got {getattr(self, name)})")
        if self.task not in spec.tasks:
            raise EstimationError(f"{self.model} is trained for {', '.join(spec.tasks)} only")
        if self.schedule not in SCHEDULES:
            raise EstimationError(f"unknown schedule {self.schedule!r} (choose from {', '.join(SCHEDULES)})")
        if not 0 <= self.warmup_epochs < self.epochs:
            raise EstimationError(
                f"warmup_epochs must be in 0..epochs-1 (got {self.warmup_epochs} of {self.epochs})"
            )
        if self.warmup_epochs and (spec.reads_grid or self.task != "tracking"):
            raise EstimationError(
                f"warm-up epochs train on single fingerprints: for tracking with a network that reads "
                f"the bits (not {self.model} {self.task})"
            )
        if self.loss not in LOSSES:
            raise EstimationError(f"unknown loss {self.loss!r} (choose from {', '.join(LOSSES)})")
        if not 0 <= self.min_delta < 1:
            raise EstimationError(f"min_delta must be in [0, 1) (got {self.min_delta})")
        if self.sigma < 0 or self.lr <= 0 or self.warmup_lr <= 0 or not 0 <= self.dropout < 1:
            raise EstimationError(f"bad sigma/lr/dropout ({self.sigma}, {self.lr}, {self.dropout})")

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> TrainConfig:
        data = json.loads(text)
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise EstimationError(f"unknown training settings {sorted(unknown)}")
        return cls(**data)

    def horizon_out(self) -> int:
        return self.horizon if self.task == "forecasting" else 1


class Estimator(nn.Module):
    """Network plus normalisation: fingerprint bits in, positions in metres out.

    Parameters
    ----------
    config : TrainConfig
    n_beams, n_bins : int
        Fingerprint shape ``M x N_s``.
    normaliser : Normaliser

    Attributes
    ----------
    robust_motion : bool
        Whether a grid-reading network's filter also weighs a broadened and a speed-pooled copy
        of the measured motion for users who do not move like the training users (default True;
        see :meth:`candidate_filter`).
    street_lanes : bool
        Whether a grid-reading network's lanes (where it expects fast users) come from the
        street map of the data it is attached to, where that has one, instead of the place
        table measured on the training trajectories (default True; see :meth:`attach`).
    lane_forecast : bool
        Whether a grid-reading network trained for forecasting carries its fast users (vehicles)
        on along the lanes its filter uses (:func:`~estimation.smoothing.forecast.forecast_tracks`)
        when predicting, instead of at their last velocity as in training (default True).
    street_forecast : bool
        Whether, in that forecast, fast users driving along a street of the attached data's
        street map follow its streets, taking any onward street at a junction
        (:func:`~estimation.smoothing.forecast.follow_streets`), instead of being carried through
        the motion table (default True; only where :attr:`street_lanes` gives the lanes).
    route_tracking : bool
        Whether a grid-reading network's tracks of users driving along the streets of the
        attached data's street map are smoothed along their routes
        (:func:`~estimation.smoothing.route.route_track`: arc length and speed, by the speeds
        measured on the training users) before they are returned or forecast (default True;
        only where :attr:`street_lanes` gives the lanes and the model measured those speeds).
    line_tracking : bool
        Whether a grid-reading network's tracks of users who walk (a median step no longer than
        the place tables' speed) of at least :data:`~estimation.smoothing.line.LINE_MIN_STEPS`
        steps are mixed with their straight-line tracks at the speeds measured on the training
        users (:func:`~estimation.smoothing.line.line_track`), and with walks of two lines
        (:func:`~estimation.smoothing.two_lines.two_line_track`): a turn where the attached grid's
        free space ends ahead, and a stop where the model measured how its walkers set off after
        one; a fast walker's searched again around its likeliest candidates near its track
        (:func:`~estimation.smoothing.walks.walk_track`); and all of it again at speeds of
        their own (a flat speed prior, its share :data:`~estimation.smoothing.walks.WALK_FREE_PRIOR`);
        each by how well the lines explain its steps, before they are returned (default
        True; only where the model measured those speeds). :meth:`OnlineTracker.update`'s
        current positions do not.
    """

    def __init__(self, config: TrainConfig, n_beams: int, n_bins: int, normaliser: Normaliser):
        super().__init__()
        self.config, self.n_beams, self.n_bins, self.normaliser = config, n_beams, n_bins, normaliser
        self.matcher: FingerprintMatcher | None = None
        self.robust_motion = True
        self.street_lanes = True
        self.lane_forecast = True
        self.street_forecast = True
        self.route_tracking = True
        self.line_tracking = True
        self._streets: tuple[np.ndarray, np.ndarray] | None = None  # (centre lines, grid points)
        # (tables' stamp, the free space they read, their broadened copies)
        self._broadened: tuple[tuple, Any, tuple] | None = None
        self._steady: tuple[tuple, tuple | None] | None = None  # (stamp, _steady_motion's tables)
        self._lanes: tuple[tuple, tuple] | None = None  # (tables' and map's stamp, lane copies)
        self._street_net: tuple[tuple, StreetNetwork | None] | None = None  # (map's stamp, graph)
        self._free: tuple[np.ndarray, FreeRaster] | None = None  # (the matcher's grid points, their raster)
        self.net = build_network(
            config.model,
            n_beams,
            n_bins,
            config.task,
            config.horizon,
            dropout=config.dropout,
            **config.options,
        )
        if config.loss == "cells" and not isinstance(getattr(self.net, "head", None), CellHead):
            raise EstimationError(f"loss 'cells' needs a cell head ({config.model} with head=cells)")

    @property
    def name(self) -> str:
        return self.config.model

    @property
    def n_parameters(self) -> int:
        return count_parameters(self.net)

    @property
    def spec(self) -> ModelSpec:
        """The registry entry of the network."""
        return model_spec(self.config.model)

    @property
    def uses_grid(self) -> bool:
        """Whether the network reads the data set's grid (see :meth:`attach`)."""
        return self.spec.reads_grid

    def attach(self, data: Any, sigma: float | None = None) -> Estimator:
        """Give a grid-reading network (``tn-match``) the grid of ``data`` (a :class:`SequenceSet`
        or an opened ``mmwsim.Dataset``): its fingerprint likelihood proposes the candidates the
        network chooses from. A no-op for the other networks; returns ``self``.

        ``sigma`` (dB) is the noise level that likelihood assumes, by default the training noise.
        A receiver knows its noise figure, so evaluation attaches at the noise it evaluates.

        Where ``data`` has a street map (``SequenceSet.streets``, a data set's scene), the
        network's lanes are that map's (:meth:`CandidateTransformer.lane_tables`): vehicles are
        expected on streets no training vehicle drove, e.g. in another region or city. Set
        :attr:`street_lanes` to False to keep the lanes measured on the training trajectories."""
        if not self.uses_grid:
            return self
        if isinstance(data, SequenceSet):
            pdp, xy, threshold, streets = data.grid_pdp, data.grid_xy, data.threshold, data.streets
        else:
            from .adapter import GridTable, dataset_threshold

            table = GridTable(data)
            pdp, xy, threshold, streets = table.pdp, table.xy, dataset_threshold(data), table.streets
        self._streets = None if streets is None else (_frozen(streets), _frozen(xy))
        sigma = self.config.sigma if sigma is None else float(sigma)
        if self.matcher is None or self.matcher.grid_pdp is not pdp or self.matcher.sigma != sigma:
            if pdp.shape[1:] != (self.n_beams, self.n_bins):
                raise EstimationError(
                    f"grid fingerprints are {tuple(pdp.shape[1:])}, the model expects "
                    f"{(self.n_beams, self.n_bins)}"
                )
            self.matcher = FingerprintMatcher.shared(pdp, xy, sigma, threshold)
            self.matcher.tile_index()  # build the tables now
        return self

    def search(self, bits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A grid-reading network's per-step candidates for ``bits (B, T, M, N_s)``: the matcher's
        most likely grid points ``xy (B, T, K, 2)`` metres with their log-likelihoods ``(B, T, K)``
        (:meth:`FingerprintMatcher.track_candidates`: near where the steps before lead where a
        fingerprint says little). A step's depend on the steps before it only, so the candidates
        of a sequence's prefix are a prefix of these."""
        return self._search(bits)[:2]

    def _search(
        self, bits: torch.Tensor, refs: np.ndarray | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
        """:meth:`search` continuing from ``refs`` (see :meth:`FingerprintMatcher.track_candidates`),
        and the references to continue from."""
        if self.matcher is None:
            raise EstimationError(
                f"{self.name} reads the data set's grid: call attach(dataset) before predicting"
            )
        return self.matcher.track_candidates(bits, self.net.search, refs)

    def fit_motion(self, data: SequenceSet) -> Estimator:
        """Measure a grid-reading network's motion tables (both smoothers', the alternatives'
        and the acceleration memory: :meth:`CandidateTransformer.fit_motion`) on the
        trajectories of ``data`` (at least 3 steps each, on the grid the network reads), the
        network's weights kept. Training does this before its first epoch; on a trained model it
        teaches the smoothers the motion of other users (a deployment's own, say), or gives a
        model saved by an older version the tables added since. Returns ``self``."""
        if not self.uses_grid:
            raise EstimationError(
                f"{self.name} has no motion tables: only a grid-reading network (tn-match) has"
            )
        if data.n == 0 or data.length < 3:
            raise EstimationError(
                f"motion tables need trajectories of at least 3 steps, got {data.n} of {data.length}"
            )
        if bool(self.net.motion.fitted):
            spacing = grid_spacing(data.grid_xy)
            if not math.isclose(spacing, float(self.net.grid_step), rel_tol=1e-9):
                raise EstimationError(
                    f"trajectories on a grid of {spacing:g} m, the network reads one of {float(self.net.grid_step):g} m"
                )
        self.net.fit_motion(data.positions, data.grid_xy, data.index, kind=data.kind)
        return self

    def adapt_motion(self, bits: torch.Tensor | np.ndarray, progress: bool = False) -> Estimator:
        """Adapt a grid-reading network to a population whose positions nobody knows: measure
        its adapted tables (:meth:`CandidateTransformer.fit_adapted`) on its own tracks
        (:meth:`predict`) of their unlabelled fingerprint sequences ``bits (n, L >= 3, M, N_s)``
        of 0/1 from the attached grid. The filter weighs them as one more hypothesis at
        :data:`~estimation.smoothing.online.ADAPTED_PRIOR`, taken from the other hypotheses'
        priors in proportion, beside the measured tables, which stay as they are, as do the
        network's weights: users who move as the training users did keep the measured tables by
        their evidence. ``progress`` shows a bar of the tracking
        (about 30 ms per 15-step sequence). Returns ``self``."""
        if not self.uses_grid:
            raise EstimationError(
                f"{self.name} has no motion tables: only a grid-reading network (tn-match) has"
            )
        if self.matcher is None:
            raise EstimationError(
                f"{self.name} reads the data set's grid: call attach(dataset) before adapting"
            )
        x = check_bits(bits, self.n_beams, self.n_bins, ndim=4)
        if x.shape[0] == 0 or x.shape[1] < 3:
            raise EstimationError(
                f"motion tables need sequences of at least 3 steps, got {x.shape[0]} of {x.shape[1]}"
            )
        self.net.fit_adapted(self.predict(x, progress=progress).double().numpy(), self.matcher.grid_xy)
        return self

    def candidate_filter(
        self, robust: bool | None = None, candidates: int | None = None, mode_chain: float | None = None
    ) -> CandidateFilter:
        """A fresh online filter over the grid's match candidates with the network's motion
        tables (:class:`~estimation.smoothing.online.CandidateFilter`): feed it one step of
        :meth:`search` results at a time, then :meth:`~CandidateFilter.smooth` gives what the
        network reads for any prefix. Only for a grid-reading network. With measured tables it
        carries ``candidates`` per step (default
        :data:`~estimation.smoothing.online.FILTER_CANDIDATES`; at most the search's, at least
        the network's ``k``): the network reads the first ``k`` of them, the route pass all; with
        the hand-set motion, ``k`` (``match-cv``'s filter). ``mode_chain`` (default
        :data:`~estimation.smoothing.online.MODE_CHAIN` with measured tables, ``math.inf`` with
        the hand-set motion): see :class:`~estimation.smoothing.online.CandidateFilter`.

        With ``robust`` (default :attr:`robust_motion`) and measured tables, the filter weighs
        the measured motion against their
        :meth:`~estimation.smoothing.motion.MotionTable.broadened` copies, the tables of
        steady users at other speeds (:meth:`_steady_motion`) and, where training measured them,
        the tables of the training cyclists alone (:meth:`_kind_motion`) by the evidence of each
        user's fingerprints, for users who do not move like the training users as a whole.
        Where training measured it, the smoothed sub-cell tracks also weigh the acceleration
        memory (:class:`~estimation.smoothing.memory.MotionMemory`), but for the tables of
        steady users at other speeds, whose lattice patterns it never saw."""
        if not self.uses_grid:
            raise EstimationError(f"{self.name} reads the bits, not match candidates")
        net = self.net
        if not bool(net.motion.fitted):  # the hand-set motion: match-cv's filter
            chain = math.inf if mode_chain is None else mode_chain
            return CandidateFilter(
                MixtureMotion(), net.motion_fine, float(net.grid_step), net.k, mode_chain=chain
            )
        wanted = FILTER_CANDIDATES if candidates is None else int(candidates)
        k, step = min(max(net.k, wanted), net.search), float(net.grid_step)
        alternative, priors, fine_weighed, skips = (
            self._alternative_motion()
            if (self.robust_motion if robust is None else robust)
            else (None, ALTERNATIVE_PRIOR, (), ())
        )
        return CandidateFilter(
            *self._lane_motion(), step, k, alternative=alternative, alternative_prior=priors,
            fine_weighed=fine_weighed, memory=net.memory, memory_skips=skips,
            mode_chain=MODE_CHAIN if mode_chain is None else mode_chain,
        )  # fmt: skip

    def _tables_stamp(self, *extra: Any) -> tuple:
        """Key of the motion tables (and of ``extra``, read-only arrays or values) that the copies
        made of them are kept under (:func:`~estimation._stamps.stamp`)."""
        net = self.net
        return stamp(net.grid_step, net.motion, net.motion_fine, net.motion_scaled, *extra)

    def _lane_motion(self) -> tuple[MotionTable, MotionTable]:
        """The motion tables the filter uses: the network's, with the attached data's street map
        as their place tables where it has one (and the tables have a measured place table to
        replace), made again only when the tables or the map change."""
        net = self.net
        streets = self._map_lanes()
        if streets is None:
            return net.motion, net.motion_fine
        key = self._tables_stamp(*streets)
        if self._lanes is None or not same_stamp(self._lanes[0], key):
            self._lanes = (key, net.lane_tables(*streets))
        return self._lanes[1]

    def _map_lanes(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The attached data's street map (centre lines, grid points) where the filter's tables
        take their lanes from it, else None (the tables keep their measured place tables)."""
        if self._streets is None or not self.street_lanes or not self.net.motion.has_place:
            return None
        return self._streets

    def _alternative_motion(
        self,
    ) -> tuple[
        list[tuple[MotionTable, MotionTable | None]],
        tuple[float, ...],
        tuple[int, ...],
        tuple[int, ...],
    ]:
        """The alternatives the filter weighs the measured tables against: their broadened
        copies, the tables for steady users at other speeds (:meth:`_steady_motion`) and those of
        one kind alone (:meth:`_kind_motion`) where the model has them, sharing
        :data:`~estimation.smoothing.online.ALTERNATIVE_PRIOR`, and the walkers' tables at other
        speeds where it has them, at :data:`~estimation.smoothing.online.WALKER_SPEED_PRIOR`,
        and the adapted tables (:meth:`adapt_motion`) where it has them, at
        :data:`~estimation.smoothing.online.ADAPTED_PRIOR` taken from every other model's prior
        (the measured tables' too) in proportion; their priors, one per alternative; the indices
        of those the filter tells from the measured tables by their sub-cell evidence
        (``CandidateFilter(fine_weighed=...)``); and those of the tables measured at speeds the
        training users did not keep or on estimates, whose paths the acceleration memory does
        not weigh (``CandidateFilter(memory_skips=...)``)."""
        net = self.net
        steady = self._steady_motion()
        kind = [self._kind_motion()] if bool(net.motion_kind.fitted) else []
        alts = [self._broadened_motion(), *([] if steady is None else [steady]), *kind]
        fine_weighed = (1,) if steady is not None and self._scaled_fine() else ()
        skips = (1,) if steady is not None else ()
        priors = [ALTERNATIVE_PRIOR / len(alts)] * len(alts)
        # each at a prior of its own; the memory, measured at the training speeds, weighs neither
        if bool(net.motion_walk.fitted):
            skips += (len(alts),)
            alts.append((net.motion_walk, net.motion_walk_fine))
            priors.append(WALKER_SPEED_PRIOR)
        if bool(net.motion_adapted.fitted):
            # In proportion, not from the measured tables alone: those keep their odds against
            # the others, or blurred tables take the ambiguous steps of users they fit exactly.
            priors = [p * (1.0 - ADAPTED_PRIOR) for p in priors] + [ADAPTED_PRIOR]
            skips += (len(alts),)
            alts.append((net.motion_adapted, net.motion_adapted_fine))
        return alts, tuple(priors), fine_weighed, skips

    def _kind_motion(self) -> tuple[MotionTable, MotionTable | None]:
        """The tables measured on the training users of one kind alone
        (:data:`~estimation.models.candidate_transformer.KIND_TABLE`)."""
        return self.net.motion_kind, self.net.motion_kind_fine

    def _scaled_fine(self) -> bool:
        """Whether the model has its sub-cell table's speed-scaled copy (models trained before
        it existed have not, and weigh the speed-pooled tables instead)."""
        return bool(self.net.motion_scaled.fitted)

    def _steady_motion(self) -> tuple[MotionTable, MotionTable] | None:
        """The tables of users as steady as the training users at speeds they did not keep: the
        cell-level table's speed-pooled copy (:meth:`MotionTable.speed_pooled`; the table itself
        where it has no fast bands to pool) and the sub-cell table measured on speed-scaled
        training trajectories (``net.motion_scaled``), with the attached street map's lanes where
        :meth:`_lane_motion` uses them. Models saved without the scaled table pool the sub-cell
        table too, and have none where either has nothing to pool. Made again only when the
        tables or the map change."""
        net, streets = self.net, self._map_lanes()
        key = self._tables_stamp(*(streets or ()))
        if self._steady is None or not same_stamp(self._steady[0], key):
            cell = net.motion.speed_pooled(POOLED_SPEED)
            if self._scaled_fine():
                tables = (net.motion if cell is None else cell, net.motion_scaled)
            else:
                fine = net.motion_fine.speed_pooled(POOLED_SPEED / float(net.grid_step))
                tables = None if cell is None or fine is None else (cell, fine)
            if tables is not None and streets is not None:
                tables = net.lane_tables(*streets, tables=tables)
            self._steady = (key, tables)
        return self._steady[1]

    def _broadened_motion(self) -> tuple[MotionTable, MotionTable | None]:
        """The motion tables' broadened copies, made again only when the tables or the attached
        grid change (a filter is made per batch in training and evaluation). With a grid
        attached they read its free space (:meth:`MotionTable.with_walls`): a turn is likely
        where the way straight ahead is blocked (:data:`BROADENED_BLOCKED`) and seldom elsewhere
        (:data:`BROADENED_OPEN`)."""
        key = self._tables_stamp()
        walls = None if self.matcher is None else self._free_space()
        kept = self._broadened
        if kept is None or not same_stamp(kept[0], key) or kept[1] is not walls:
            self._broadened = (key, walls, self._broaden(walls))
        return self._broadened[2]

    def _broaden(self, walls: FreeRaster | None) -> tuple[MotionTable, MotionTable | None]:
        """The broadened copies of :meth:`_broadened_motion`, read against the free space
        ``walls`` (metres; the lattice's table in grid units) where it is given."""
        net, step = self.net, float(self.net.grid_step)
        fitted = bool(net.motion_fine.fitted)
        if walls is None:
            return net.motion.broadened(), (net.motion_fine.broadened(unit=step) if fitted else None)
        free, origin, res = walls
        turn, steer = BROADENED_OPEN
        cell = net.motion.broadened(turn=turn, steer=steer, blocked=BROADENED_BLOCKED)
        cell.with_walls(free, origin, res)
        if not fitted:
            return cell, None
        fine = net.motion_fine.broadened(unit=step, turn=turn, steer=steer, blocked=BROADENED_BLOCKED)
        return cell, fine.with_walls(free, origin / step, res / step)

    def inputs(
        self,
        bits: torch.Tensor | None = None,
        found: tuple[torch.Tensor, torch.Tensor] | None = None,
        candidates: int | None = None,
        mode_chain: float | None = None,
    ) -> Any:
        """What the network reads for ``bits (B, T, M, N_s)``: the bits themselves, or for a
        grid-reading network its filtered and smoothed candidates ``(xy (B, T, K, 2) metres,
        posteriors (B, T, K, P))`` and the classical estimate ``(B, T, 2)`` metres it starts from
        (see :meth:`candidate_filter`, whose ``K`` candidates per step, ``candidates``, may be
        more than the network's ``k``, and ``mode_chain`` as there), from the bits or from their
        :meth:`search` result ``found``."""
        if not self.uses_grid:
            return bits
        xy, score = self.search(bits) if found is None else found
        blank = None if bits is None else blank_steps(bits)
        return (
            self.candidate_filter(candidates=candidates, mode_chain=mode_chain).run(xy, score, blank).smooth()
        )

    def tracker(self) -> OnlineTracker:
        """An online tracker of a batch of users: :meth:`OnlineTracker.update` takes each new
        fingerprint and returns the users' current positions in constant time per step."""
        return OnlineTracker(self)

    def forward(self, x: Any, y: torch.Tensor | None = None) -> torch.Tensor | CellOutput:
        """Normalised output ``(B, T_out, 2)`` for bits or :meth:`inputs` (a network with a cell
        head gives a :class:`~estimation.models.CellOutput` of those and their scores, for
        :meth:`loss`); ``y`` (metres) enables teacher forcing where used."""
        if self.uses_grid:
            xy, post, fine = self.inputs(x) if isinstance(x, torch.Tensor) else x
            return self.normaliser.to_unit(self.net(xy, post, fine))
        return self.net(x, None if y is None else self.normaliser.to_unit(y))

    def loss(self, out: torch.Tensor | CellOutput, y: torch.Tensor) -> tuple[torch.Tensor, int]:
        """The training loss of normalised output ``out (B, T, 2)`` against ``y (B, T, 2)`` metres,
        as its sum over the batch and the number of terms summed (coordinates for ``mse``,
        trajectories for ``rmse``, steps for ``cells``), so that batches of any size average
        exactly."""
        target = self.normaliser.to_unit(y)
        if isinstance(out, CellOutput):
            if self.config.loss == "cells":
                return self.net.head.loss(out, target)  # checked at construction: a CellHead
            out = out.position
        d = out - target
        if self.config.loss == "rmse":
            per = (d.square().sum(-1).mean(-1) + 1e-12).sqrt()  # the floor keeps the gradient finite
            return per.sum(), per.numel()
        return d.square().sum(), d.numel()

    @torch.no_grad()
    def predict(self, x: Any, progress: bool = False) -> torch.Tensor:
        """``bits (B, T, M, N_s)`` of 0/1, a tensor or array of any dtype (or their :meth:`inputs`)
        -> positions ``(B, T_out, 2)`` float32, metres; with ``progress``, a tqdm bar of the
        sequences done on stderr.

        Bits go through in blocks of :data:`ROUTE_CHUNK` sequences, each block's :meth:`inputs`
        made and let go in turn: memory is a block's, whatever ``B`` (a grid-reading network's
        filter holds about 60 kB per sequence and step). A grid-reading network's blocks run side
        by side, one per thread of :func:`mmwsim._threads.threads` (each of ``ROUTE_CHUNK``
        divided by the threads, so memory is the same), each on one torch thread; the results
        do not depend on the number of threads."""
        was = self.training
        self.eval()
        try:
            raw = isinstance(x, (torch.Tensor, np.ndarray))
            if raw:
                x = check_bits(x, self.n_beams, self.n_bins, ndim=4).float()
                if x.shape[1] == 0:
                    raise EstimationError("fingerprint sequences need at least one step, got 0")
            prepare = self.inputs if raw and self.uses_grid else (lambda block: block)
            n = _length(x)
            from tqdm import tqdm

            bar = tqdm(total=n, desc="predict", unit="seq", dynamic_ncols=True, disable=not progress)
            done = threading.Lock()  # the blocks' threads share the bar

            def block(rows: slice) -> torch.Tensor:
                out = self._predict_rows(prepare(_rows(x, rows)))
                with done:
                    bar.update(out.shape[0])
                return out

            try:
                if self.uses_grid:  # blocks side by side, one per thread (one block within a part's)
                    blocks = pieces(n, PREDICT_CHUNK, max(1, ROUTE_CHUNK // threads())) or [slice(0, 0)]
                    parts = map_parts(block, blocks)
                else:
                    parts = [block(b) for b in _blocks(n, ROUTE_CHUNK)]
            finally:
                bar.close()
            return torch.cat(parts) if len(parts) != 1 else parts[0]
        finally:
            self.train(was)

    def _predict_rows(self, x: Any) -> torch.Tensor:
        """:meth:`predict` of one block of inputs, metres: the network over chunks of
        :data:`PREDICT_CHUNK` sequences, the route pass and the forecast over the whole block."""
        forecasting = self.config.task == "forecasting"
        lanes = self.lane_forecast and self.uses_grid and forecasting
        parts = [
            self.net.track(*rows) if lanes else self.normaliser.to_metres(positions(self(rows)))
            for rows in (_rows(x, b) for b in _blocks(_length(x), PREDICT_CHUNK))
        ]
        out = torch.cat(parts) if len(parts) != 1 else parts[0]
        if lanes:
            return self.forecast(self._along_routes(out, x), self.config.horizon).float()
        return self._along_lines(self._along_routes(out, x), x) if self.uses_grid and not forecasting else out

    def _along_routes(self, tracked: torch.Tensor, x: Any) -> torch.Tensor:
        """``tracked (B, T, 2)`` metres with the users who drive along the attached street map
        smoothed along their routes (:attr:`route_tracking`), from the candidates of the
        inputs ``x``; as it is where that does not apply."""
        return self._route_tracks(tracked, x[0], x[1][..., 0])

    def _along_lines(self, tracked: torch.Tensor, x: Any) -> torch.Tensor:
        """``tracked (B, T, 2)`` metres with each user who walks mixed with its straight-line
        track, or its walks of two lines (:attr:`line_tracking`), by their weight
        (:func:`~estimation.smoothing.line.line_weight`), from the candidates of the inputs
        ``x``; as it is where that does not apply."""
        fine = self.net.motion_fine
        if not self.line_tracking or not len(fine.walk_speeds) or tracked.shape[1] < LINE_MIN_STEPS:
            return tracked
        step = float(self.net.grid_step)
        t = tracked.double().numpy()
        # walkers as fit_walks measured them: a median step within the place tables' speed
        typical = np.median(np.linalg.norm(np.diff(t, axis=1), axis=-1), axis=1)
        walk = np.flatnonzero(typical <= PLACE_SPEED)
        if not len(walk):
            return tracked
        xy, lp = np.asarray(x[0], np.float64)[walk], np.asarray(x[1][..., 0], np.float64)[walk]
        # models saved before the restart speeds were measured weigh no stops
        line, delta = walk_track(
            t[walk], xy, lp, fine.walk_speeds.numpy(), step, fine.walk_restarts.numpy(),
            float(fine.walk_stop), self._free_space(), WALK_FREE_PRIOR,
        )  # fmt: skip
        w = line_weight(delta)[:, None, None]
        out = tracked.clone()
        out[torch.from_numpy(walk)] = torch.from_numpy(w * line + (1 - w) * t[walk]).to(out.dtype)
        return out

    def _free_space(self) -> FreeRaster:
        """The attached grid's free space (its points with fingerprints), made once per grid."""
        xy = self.matcher.grid_xy
        if self._free is None or self._free[0] is not xy:
            self._free = (xy, free_raster(xy, float(self.net.grid_step)))
        return self._free[1]

    def _route_tracks(self, tracked: torch.Tensor, xy: Any, lp: Any) -> torch.Tensor:
        """:meth:`_along_routes` from the steps' candidates ``xy (B, T, k, 2)`` metres and their
        log-likelihoods ``lp (B, T, k)`` (tensors or arrays)."""
        fine = self._lane_motion()[1]
        net = self._street_network() if self.route_tracking else None
        if net is None or not len(fine.route_speeds) or tracked.shape[1] < 2:
            return tracked
        step = float(self.net.grid_step)
        track, on = route_track(
            tracked.double().numpy(), np.asarray(xy, np.float64), np.asarray(lp, np.float64), net,
            fine.route_speeds.numpy(), float(fine.route_change), step, float(fine.place_speed) * step,
        )  # fmt: skip
        out = tracked.clone()
        out[torch.from_numpy(on)] = torch.from_numpy(track[on]).to(out.dtype)
        return out

    @torch.no_grad()
    def forecast(self, tracked: torch.Tensor, horizon: int) -> torch.Tensor:
        """Positions ``(B, horizon, 2)`` metres after tracked ones ``(B, T, 2)`` metres, as a
        grid-reading network's :meth:`predict` forecasts: users faster than its place table's
        speed carried on along the lanes its filter uses (street map or measured,
        :func:`~estimation.smoothing.forecast.forecast_tracks`), the others at their last
        velocity; all at their last velocity where the tables are not measured (or for other
        networks)."""
        fine = self._lane_motion()[1] if self.uses_grid else None
        if fine is None or not bool(fine.fitted):
            return extrapolate(tracked, horizon)
        net = self._street_network() if self.street_forecast else None
        return forecast_tracks(tracked, horizon, fine, float(self.net.grid_step), net)

    def _street_network(self) -> StreetNetwork | None:
        """The attached street map as a graph (for :meth:`forecast` and the route smoother), made
        again only when the map changes; None without one."""
        streets = self._map_lanes()
        if streets is None:
            return None
        key = stamp(streets[0])
        if self._street_net is None or not same_stamp(self._street_net[0], key):
            try:
                graph: StreetNetwork | None = StreetNetwork.from_segments(streets[0])
            except TrajectoryError:  # no piece left to drive along
                graph = None
            self._street_net = (key, graph)
        return self._street_net[1]

    def save(self, path: str | os.PathLike, extra: dict[str, Any] | None = None) -> None:
        save_checkpoint(
            path,
            {
                "format": MODEL_FORMAT,
                "config": self.config.to_json(),
                "n_beams": self.n_beams,
                "n_bins": self.n_bins,
                "normaliser": json.dumps(self.normaliser.as_dict()),
                "state_dict": self.net.state_dict(),
                **(extra or {}),
            },
        )

    @classmethod
    def from_state(cls, state: dict[str, Any], where: str) -> Estimator:
        try:
            config = TrainConfig.from_json(state["config"])
            norm = Normaliser(**json.loads(state["normaliser"]))
            est = cls(config, int(state["n_beams"]), int(state["n_bins"]), norm)
            est.net.load_state_dict(state["state_dict"])
        except EstimationError as e:
            raise EstimationError(f"{where}: {e}") from None
        except (KeyError, TypeError, ValueError, RuntimeError) as e:
            msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise EstimationError(f"{where}: checkpoint does not fit its model ({msg[:160]})") from None
        est.eval()
        return est

    @classmethod
    def load(cls, path: str | os.PathLike) -> Estimator:
        """Load from a model file or a run folder (its ``model.pt``)."""
        path = Path(path)
        if path.is_dir():
            path = path / MODEL_FILE
        state = load_checkpoint(path, MODEL_FORMAT, MODEL_KEYS)
        return cls.from_state(state, str(path))


def _frozen(a: Any) -> np.ndarray:
    """A read-only float64 copy of ``a``: what the estimator keeps of the data it is attached
    to, so that a caller changing its own array in place cannot leave copies made from it
    stale (:func:`~estimation._stamps.stamp`)."""
    out = np.array(a, dtype=np.float64)
    out.flags.writeable = False
    return out


class OnlineTracker:
    """Tracks a batch of users one fingerprint at a time (see :meth:`Estimator.tracker`).

    For a grid-reading network (``tn-match``) each :meth:`update` runs the matcher on the new
    fingerprints and one step of the candidate filter, so it costs the same at every step; for
    the others, which read whole sequences, it runs the network on the sequence so far. Where
    the network smooths its drivers along the attached street map's routes
    (:attr:`Estimator.route_tracking`), a driver's current position is the route pass's over the
    filter's estimates and candidates of the last :data:`ONLINE_ROUTE_STEPS` steps: a window of
    the same size at every step.
    """

    def __init__(self, estimator: Estimator):
        if not estimator.uses_grid and estimator.config.task != "tracking":
            raise EstimationError(
                f"{estimator.name} forecasts from whole sequences: it has no current position"
            )
        self.est = estimator
        self.filter = estimator.candidate_filter() if estimator.uses_grid else None
        self._bits: list[torch.Tensor] = []
        self._refs: np.ndarray | None = None  # the search's best candidates of the last two steps

    @property
    def steps(self) -> int:
        """Fingerprints seen so far."""
        return len(self._bits)

    def update(self, bits: torch.Tensor) -> np.ndarray:
        """Add one fingerprint per user, ``bits (B, M, N_s)``; returns their current positions
        ``(B, 2)`` float64 metres (the filtered estimate: the last step given the steps so far;
        for drivers along the attached street map, the route pass's over the last steps)."""
        bits = torch.as_tensor(bits)
        if bits.ndim != 3 or tuple(bits.shape[1:]) != (self.est.n_beams, self.est.n_bins):
            raise EstimationError(
                f"one step's fingerprints must be (B, {self.est.n_beams}, {self.est.n_bins}), "
                f"got {tuple(bits.shape)}"
            )
        if self._bits and bits.shape[0] != self._bits[0].shape[0]:
            raise EstimationError(f"a step of {bits.shape[0]} users after steps of {self._bits[0].shape[0]}")
        self._bits.append(bits)
        if self.filter is None:
            return self.est.predict(torch.stack(self._bits, 1).float())[:, -1].double().numpy()
        xy, score, self._refs = self.est._search(bits[:, None].float(), self._refs)
        now = self.filter.update(xy[:, 0], score[:, 0], blank_steps(bits[:, None])[:, 0])
        f, T = self.filter, self.steps
        if T < 2 or not self.est.route_tracking:
            return now
        lo = max(0, T - ONLINE_ROUTE_STEPS)
        window = torch.from_numpy(np.stack(f.positions[lo:], 1))
        lp = np.maximum(f.cells.likelihoods(T)[:, lo:], LOGP_FLOOR)  # as the smoothed features are
        return self.est._route_tracks(window, f.cells.points(T)[:, lo:], lp)[:, -1].double().numpy()

    def track(self) -> torch.Tensor:
        """The network's estimate ``(B, T, 2)`` metres of every step so far (the smoothed track;
        the forecast for a forecasting network)."""
        if not self._bits:
            raise EstimationError("no fingerprints yet: call update first")
        if self.filter is None:
            return self.est.predict(torch.stack(self._bits, 1).float())
        return self.est.predict(self.filter.smooth())
