"""Motion models of the users: pedestrian, vehicle, hybrid and static kinematics.

The reference parameters (mean/max speed, speed change, direction change and the
per-second probabilities of no change, stop, turn and speed change) are those of
the reference data set (bff-conventions.md). Two flaws of the reference generator
are fixed here and in :mod:`.generate`: a speed change always changes the speed
(by exactly ``speed_change * dt``, the sign chosen so that the speed stays within
``[min_speed, max_speed]``), and every segment is checked against the buildings.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Literal, get_args

from .errors import TrajectoryError

__all__ = [
    "KINDS",
    "Kind",
    "MOTION_MODELS",
    "MotionModel",
    "PEDESTRIAN",
    "VEHICLE",
    "HYBRID",
    "STATIC",
    "motion_model",
    "EVENT_NAMES",
    "NONE",
    "STOP",
    "TURN",
    "SPEED",
    "AVOID",
    "ROAD",
]

Kind = Literal["static", "pedestrian", "hybrid", "vehicle"]
"""A kind of user."""
KINDS: tuple[Kind, ...] = get_args(Kind)
"""Kind codes stored with trajectories (and estimation's sequence sets): index into this tuple."""

# Per-step event codes stored with every trajectory (why a step looks the way it does).
NONE, STOP, TURN, SPEED, AVOID, ROAD = 0, 1, 2, 3, 4, 5
EVENT_NAMES: tuple[str, ...] = ("none", "stop", "turn", "speed", "avoid", "road")


@dataclass(frozen=True)
class MotionModel:
    """Kinematics of one kind of user.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    mean_speed : float
        Speed at the start and after every stop, m/s.
    max_speed : float
        Upper bound of the speed, m/s.
    speed_change : float
        Magnitude of one speed change, m/s per second (m/s^2).
    turn_rate : float
        Magnitude of one direction change, degrees per second.
    p_stop, p_turn, p_speed : float
        Probability per second of a stop, a turn and a speed change; the rest is
        "no change". A stop holds the user still for one step, after which it
        restarts in a uniformly random direction at ``mean_speed``.
    min_speed : float, optional
        Lower bound of the speed while moving, m/s; default ``2 mean - max``
        (clipped at 0), which keeps the long-run mean speed at ``mean_speed``.
    clearance : float
        Minimum distance of every sample and segment from the buildings, metres.
    """

    kind: Kind
    mean_speed: float
    max_speed: float
    speed_change: float
    turn_rate: float
    p_stop: float
    p_turn: float
    p_speed: float
    min_speed: float | None = None
    clearance: float = 0.5

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise TrajectoryError(f"unknown trajectory kind {self.kind!r} (use {', '.join(KINDS)})")
        for name in ("mean_speed", "max_speed", "speed_change", "turn_rate", "clearance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise TrajectoryError(f"{self.kind}: {name} must be a finite number >= 0, got {v!r}")
        for name in ("p_stop", "p_turn", "p_speed"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
                raise TrajectoryError(f"{self.kind}: {name} must be a probability in [0, 1], got {v!r}")
        if self.p_stop + self.p_turn + self.p_speed > 1.0 + 1e-12:
            raise TrajectoryError(f"{self.kind}: p_stop + p_turn + p_speed must not exceed 1")
        if self.max_speed < self.mean_speed:
            raise TrajectoryError(
                f"{self.kind}: max_speed {self.max_speed:g} m/s is below mean_speed {self.mean_speed:g} m/s"
            )
        lo = self.speed_floor
        if not (0.0 <= lo <= self.mean_speed):
            raise TrajectoryError(f"{self.kind}: min_speed must lie in [0, mean_speed], got {lo:g}")

    @property
    def moving(self) -> bool:
        """Whether users of this kind move at all."""
        return self.mean_speed > 0.0

    @property
    def speed_floor(self) -> float:
        """Lower speed bound while moving, m/s."""
        if self.min_speed is not None:
            return float(self.min_speed)
        return max(0.0, 2.0 * self.mean_speed - self.max_speed)

    @property
    def p_none(self) -> float:
        """Probability per second of no change."""
        return 1.0 - self.p_stop - self.p_turn - self.p_speed

    def check_rate(self, rate_hz: float) -> None:
        """Raise unless the model can run at ``rate_hz`` samples per second."""
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise TrajectoryError(f"sampling rate must be a positive number of Hz, got {rate_hz!r}")
        dt = 1.0 / rate_hz
        if (self.p_stop + self.p_turn + self.p_speed) * dt > 1.0 + 1e-12:
            raise TrajectoryError(
                f"{self.kind}: at {rate_hz:g} Hz the change probabilities per step exceed 1; raise the rate"
            )
        if self.moving and self.p_speed > 0 and self.speed_change * dt > self.max_speed - self.speed_floor:
            raise TrajectoryError(
                f"{self.kind}: a speed change of {self.speed_change * dt:g} m/s does not fit in the speed "
                f"range {self.speed_floor:g}..{self.max_speed:g} m/s"
            )

    def replace(self, **changes) -> MotionModel:
        """A copy with some parameters changed (validated again)."""
        return MotionModel(**{**asdict(self), **changes})

    def as_dict(self) -> dict:
        return asdict(self)


PEDESTRIAN = MotionModel(
    "pedestrian", 1.4, 2.0, 0.3, 10.0, p_stop=0.10, p_turn=0.05, p_speed=0.05, clearance=0.5
)
VEHICLE = MotionModel("vehicle", 8.3, 13.9, 3.0, 5.0, p_stop=0.02, p_turn=0.05, p_speed=0.13, clearance=1.5)
# Between the two (a cyclist): speed-like quantities are the geometric means of the pedestrian's
# and the vehicle's, angles and probabilities their arithmetic means.
HYBRID = MotionModel("hybrid", 3.4, 5.3, 0.95, 7.5, p_stop=0.06, p_turn=0.05, p_speed=0.09, clearance=1.0)
STATIC = MotionModel("static", 0.0, 0.0, 0.0, 0.0, p_stop=0.0, p_turn=0.0, p_speed=0.0, clearance=0.5)

MOTION_MODELS: dict[Kind, MotionModel] = {m.kind: m for m in (STATIC, PEDESTRIAN, HYBRID, VEHICLE)}
"""The reference motion model of every kind."""


def motion_model(kind: str) -> MotionModel:
    """The reference model of ``kind``."""
    try:
        return MOTION_MODELS[kind]
    except KeyError:
        raise TrajectoryError(f"unknown trajectory kind {kind!r} (use {', '.join(KINDS)})") from None
