"""Fault injection: stop or fail the process at named points of each commit, for tests.

Set the environment variable ``MMWSIM_FAULT`` to a comma-separated list of
``POINT[@N][:ACTION]``; when the program reaches ``POINT`` (for the ``N``-th time in this
process, default every time) it performs ``ACTION``:

``kill`` (default)
    ``SIGKILL`` to this process: nothing is cleaned up, as with ``kill -9``.
``hang``
    Say so on stderr (``mmwsim fault: POINT: hanging (pid N)``), then sleep until killed: lets
    a test observe locks and worker processes, then kill.
``enospc``, ``edquot``, ``erofs``, ``eacces``, ``eio``
    Raise the :class:`OSError` that a full disk, an exhausted quota, a read-only file
    system, a refused permission or a failing device raises, naming the file being written.
``enosys``
    Raise ``OSError(ENOSYS)``: the operation is not supported here (used at
    ``replace.exchange`` to take the portable path).

Points, in the order each commit reaches them:

data set (:mod:`mmwsim.dataset.store`, ``mmwsim generate``)
    ``dataset.create`` (the new ``<out>.partial`` is being laid out),
    ``dataset.tile`` (a tile's arrays are being written, before its commit marker),
    ``dataset.committed`` (after a tile's marker),
    ``dataset.rename`` (the finished store, before its rename into place),
    ``dataset.renamed`` (after the rename, before the marker is dropped).
tile computation (:mod:`mmwsim.dataset.generate`)
    ``worker.start`` (a local worker process has started, before its first tile).
directory replacement (:func:`mmwsim.files.replace_dir`: ``mmwsim trajectories``)
    ``replace.written`` (the new folder is complete, nothing switched yet),
    ``replace.exchange`` (the one-call atomic exchange of old and new),
    ``replace.between`` (portable path only: the old folder moved aside, the new one not yet in
    place), ``replace.switched`` (the new folder in place, the old one not yet removed).
trajectory store (:mod:`mmwsim.trajectories.store`)
    ``trajectories.write`` (the new splits are being written).
training run (:mod:`estimation.training`)
    ``train.epoch`` (an epoch has been trained, before its checkpoint is written),
    ``train.checkpointed`` (after it).
atomic files (:func:`mmwsim.files.write_text_atomic`, checkpoints, reports)
    ``file.write`` (a file's temporary sibling is being written), ``file.rename`` (before its rename).
evaluation report (:mod:`estimation.report`)
    ``report.write`` (before the report files are written).
"""

from __future__ import annotations

import errno
import os
import signal
import sys
import time
from collections import Counter

__all__ = ["ENV", "fault"]

ENV = "MMWSIM_FAULT"

_ERRNO = {
    "enospc": errno.ENOSPC,
    "edquot": errno.EDQUOT,
    "erofs": errno.EROFS,
    "eacces": errno.EACCES,
    "eio": errno.EIO,
    "enosys": errno.ENOSYS,
}
_hits: Counter[str] = Counter()


def fault(point: str, path: str | os.PathLike | None = None) -> None:
    """Perform the action ``MMWSIM_FAULT`` asks for at ``point``; nothing when it names none.

    Parameters
    ----------
    point : str
        One of the points listed in the module docstring.
    path : path-like, optional
        File or folder being written there (named by the injected :class:`OSError`).
    """
    spec = os.environ.get(ENV)
    if not spec:
        return
    _hits[point] += 1
    for item in spec.split(","):
        target, _, action = item.strip().partition(":")
        name, _, nth = target.partition("@")
        if name != point or (nth and int(nth) != _hits[point]):
            continue
        action = action or "kill"
        if action == "kill":
            os.kill(os.getpid(), signal.SIGKILL)
        elif action == "hang":
            print(f"mmwsim fault: {point}: hanging (pid {os.getpid()})", file=sys.stderr, flush=True)
            while True:
                time.sleep(60)
        elif action in _ERRNO:
            code = _ERRNO[action]
            raise OSError(code, os.strerror(code), None if path is None else str(path))
        else:
            raise ValueError(f"{ENV}: unknown action {action!r} at {point}")
