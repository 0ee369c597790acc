"""The tracer's options, shared by ``mmwsim trace`` and ``mmwsim generate``."""

from __future__ import annotations

import math

from ..constants import DEFAULT_RAYS
from ..errors import MmwsimError

__all__ = ["add_physics_arguments", "check_diffuse"]


def add_physics_arguments(p) -> None:
    """``--max-reflections``, ``--no-diffraction``, ``--diffuse S`` and ``--rays N`` on parser ``p``."""
    p.add_argument(
        "--max-reflections",
        type=int,
        default=3,
        help="interactions per path: reflections, the diffraction and diffuse scattering together (default 3)",
    )
    p.add_argument("--no-diffraction", action="store_true", help="trace line of sight and reflections only")
    p.add_argument(
        "--diffuse",
        type=float,
        metavar="S",
        help="diffuse scattering: set the scattering coefficient S (0..1) of every material for this run",
    )
    p.add_argument(
        "--rays", type=int, metavar="N", help=f"rays shot for the candidate search (default {DEFAULT_RAYS})"
    )


def check_diffuse(s: float | None) -> float | None:
    """``--diffuse``'s value, checked: None or a number from 0 to 1."""
    if s is not None and not (math.isfinite(s) and 0.0 <= s <= 1.0):
        raise MmwsimError(f"--diffuse must be a scattering coefficient from 0 to 1, got {s!r}")
    return s
