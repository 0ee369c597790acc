"""Errors of the planning package."""

from __future__ import annotations

from mmwsim.errors import MmwsimError

__all__ = ["PlanningError"]


class PlanningError(MmwsimError):
    """A planning input is unusable: start or goal outside the free space, a bad corridor file, ...

    The CLI prints its one-line message and exits with status 2.
    """
