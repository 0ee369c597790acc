"""The one exception type for user mistakes in :mod:`estimation`."""

from __future__ import annotations

from mmwsim.errors import MmwsimError

__all__ = ["EstimationError"]


class EstimationError(MmwsimError):
    """A user mistake in training or evaluation: bad run folder, checkpoint, data set or option.

    A subclass of :class:`mmwsim.MmwsimError`, so the CLI prints its one-line message and exits 2.
    """
