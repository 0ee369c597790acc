"""The trajectory package's user-error type."""

from __future__ import annotations

from ..errors import MmwsimError

__all__ = ["TrajectoryError"]


class TrajectoryError(MmwsimError):
    """A bad trajectory parameter or a scene without room to move in (one line, CLI exit 2)."""
