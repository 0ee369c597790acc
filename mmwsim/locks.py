"""One writer per output: an exclusive lock file next to each data set, run folder and report.

The lock of ``out/`` is the file ``.out.lock`` beside it, held with ``fcntl.flock`` for as long as
the output is being written and removed when the writer is done. It records who holds it
(process id, host, start time, command), so a second writer is refused with one line naming
the holder. The kernel drops the lock of a process that dies, even under ``kill -9``: the file
such a process leaves behind is stale, and the next writer takes it over.

Locks are re-entrant within a process (a command that locks its output before calling a
library function that locks it again).
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import MmwsimError
from .files import make_dirs, remove_tree, write_error

__all__ = ["LockHeld", "OutputLock", "lock_path", "locked_output", "output_lock"]


class LockHeld(MmwsimError):
    """Another process is writing the output (one line naming it; CLI exit 2)."""


_HELD: dict[str, list] = {}  # lock file (absolute) -> [fd, depth]
_REGISTRY = threading.Lock()


def lock_path(output: str | os.PathLike) -> Path:
    """The lock file of ``output``: ``.<name>.lock`` in the same folder."""
    output = Path(os.path.abspath(output))  # "." and "runs/" have a name too
    return output.with_name(f".{output.name}.lock")


def _holder_text(raw: bytes) -> str:
    try:
        h = json.loads(raw.decode())
        return f"process {h['pid']} on {h['host']} (started {h['started']}: {h['command']})"
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        return "another process"


def _command() -> str:
    """This process's command line, short (``python -m mmwsim`` shows as ``mmwsim``)."""
    if not sys.argv:
        return ""
    name = Path(sys.argv[0]).name
    name = "mmwsim" if name == "__main__.py" else name
    return " ".join([name, *sys.argv[1:]])[:300]


class OutputLock:
    """An exclusive, re-entrant lock on one output.

    Parameters
    ----------
    output : path-like
        The data set, run folder or report folder (need not exist yet).
    what : str
        What the output is, for messages (``"data set"``, ``"run folder"``, ...).
    """

    def __init__(self, output: str | os.PathLike, what: str = "output"):
        self.output, self.what = Path(output), what
        self.path = lock_path(self.output)
        self._key = str(self.path)

    def acquire(self) -> OutputLock:
        """Take the lock, or raise :class:`LockHeld` naming the holder."""
        with _REGISTRY:
            held = _HELD.get(self._key)
            if held is not None:
                held[1] += 1
                return self
            fd = self._open_locked()
            _HELD[self._key] = [fd, 1]
        return self

    def _open_locked(self) -> int:
        if not self.path.parent.is_dir():
            raise MmwsimError(f"{self.output}: folder {self.path.parent} does not exist")
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as e:  # named by its folder: the lock file is ours, the folder the user's
                raise write_error(OSError(e.errno, e.strerror, str(self.path.parent)), self.output) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                raw = os.pread(fd, 4096, 0)
                os.close(fd)
                if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise LockHeld(
                        f"{self.output}: the {self.what} is being written by {_holder_text(raw)}; "
                        f"wait for it, or stop it (lock {self.path})"
                    ) from None
                raise write_error(e, self.path) from None
            # The previous holder may have removed the file between our open and our lock:
            # a lock on a name no longer in the folder protects nothing, so start again.
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            # Whatever the file says (a holder killed without cleaning up), the kernel says it
            # is ours now: record ourselves.
            me = {
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "started": time.strftime("%Y-%m-%d %H:%M:%S"),
                "command": _command(),
            }
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, json.dumps(me).encode(), 0)
            except OSError as e:
                os.close(fd)
                raise write_error(e, self.path) from None
            return fd

    def release(self) -> None:
        """Drop one level of the lock; the last one removes the lock file."""
        with _REGISTRY:
            held = _HELD.get(self._key)
            if held is None:
                return
            held[1] -= 1
            if held[1] > 0:
                return
            del _HELD[self._key]
            fd = held[0]
            try:  # remove the name first, then unlock: see _open_locked
                if os.stat(self.path).st_ino == os.fstat(fd).st_ino:
                    self.path.unlink()
            except OSError:
                pass
            os.close(fd)

    @property
    def held(self) -> bool:
        """Whether this process holds the lock."""
        return self._key in _HELD

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


@contextmanager
def output_lock(output: str | os.PathLike, what: str = "output") -> Iterator[OutputLock]:
    """``with output_lock(out, "data set"):`` -- hold the lock of ``out`` for the block."""
    lock = OutputLock(output, what).acquire()
    try:
        yield lock
    finally:
        lock.release()


@contextmanager
def locked_output(
    output: str | os.PathLike, what: str = "output", create: bool = False, keep=None
) -> Iterator[Path]:
    """Write ``output`` in the block: its folder made, its lock held, and nothing left if it fails.

    Parameters
    ----------
    output : path-like
        The run or report folder.
    what : str
        What it is, for messages.
    create : bool
        Also make the folder ``output`` itself (under the lock).
    keep : callable, optional
        Called when the block fails; True keeps the folders this call made (e.g. a training
        run with a checkpoint, which ``--resume`` continues).

    Raises
    ------
    MmwsimError
        For a held lock (naming the holder), and for an :class:`OSError` in the block (disk
        full, read-only, permission), naming the path.
    """
    output = Path(output)
    made = make_dirs(output.parent)
    try:
        lock = OutputLock(output, what).acquire()
    except BaseException:
        if made is not None:
            remove_tree(made)
        raise
    try:
        if create:
            inner = make_dirs(output)
            made = made or inner
        for stray in output.glob(".*.partial*") if output.is_dir() else ():
            remove_tree(stray)  # a temporary of mmwsim.files.atomic_path left by a killed writer
        yield output
    except BaseException as e:
        if made is not None and not (keep is not None and keep()):
            remove_tree(made)
        if isinstance(e, OSError):
            raise write_error(e, output) from None
        raise
    finally:
        lock.release()
