"""Local worker processes that never outlive the process that started them.

A worker asks the kernel for ``SIGKILL`` when its parent dies (Linux ``PR_SET_PDEATHSIG``),
which holds even when the parent is killed with ``kill -9`` and has no chance to clean up;
elsewhere, and as a second guard, a thread in the worker polls its parent id and exits
when it changes.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor

from ._threads import cores, set_threads
from .faults import fault

__all__ = ["worker_pool"]

_PR_SET_PDEATHSIG = 1
_POLL_SECONDS = 0.5


def _watch_parent(parent: int) -> None:
    while True:
        time.sleep(_POLL_SECONDS)
        if os.getppid() != parent:
            os._exit(1)


def _die_with_parent(parent: int, threads: int, then=None, then_args: tuple = ()) -> None:
    """Initializer of every worker: arrange to die with ``parent``, take its share of the cores
    (``threads`` for its own parallel sections), then run ``then(*then_args)``."""
    set_threads(threads)
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the polling thread still guards
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True, name="mmwsim-parent-watch").start()
    fault("worker.start")
    if then is not None:
        then(*then_args)


def worker_pool(workers: int, initializer=None, initargs: tuple = ()) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes that die with this one (each first runs ``initializer``).

    Spawned rather than forked: Embree and BLAS thread pools do not survive ``fork`` reliably.
    Each worker's threads are capped at its share of the cores so the pool does not
    oversubscribe them. The pool must be used from the thread that lives as long as it does (the kernel's
    parent-death signal follows the thread that started each worker).
    """
    return ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_die_with_parent,
        initargs=(os.getpid(), max(1, cores() // workers), initializer, initargs),
    )
