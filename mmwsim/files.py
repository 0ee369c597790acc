"""Writing results so that a reader never sees a half-written one, and a failed write says where.

Every output is written under a temporary name and moved into place in one rename (files), or
one exchange of folders (:func:`replace_dir`). An :class:`OSError` while writing (disk full,
quota, read-only file system, permission) becomes one :class:`~mmwsim.errors.MmwsimError` line
naming the path, and the temporary is removed.
"""

from __future__ import annotations

import ctypes
import errno
import os
import shutil
import sys
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from .errors import MmwsimError
from .faults import fault

__all__ = [
    "RECORDING_SUFFIX",
    "atomic_path",
    "check_suffix",
    "check_output_folder",
    "make_dirs",
    "reading",
    "recover_dir",
    "remove_tree",
    "replace_dir",
    "resolve_dir",
    "write_error",
    "write_text_atomic",
    "writing",
]

_HINTS = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is exhausted",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
}


def write_error(e: OSError, path: str | os.PathLike, note: str = "") -> MmwsimError:
    """The one-line error for an :class:`OSError` raised while writing ``path``.

    Parameters
    ----------
    e : OSError
    path : path-like
        The output being written (named when ``e`` names no file).
    note : str
        What became of the output, e.g. ``"the unfinished run is kept: --resume it"``.
    """
    where = e.filename if e.filename is not None else path
    reason = _HINTS.get(e.errno or 0) or e.strerror or type(e).__name__
    return MmwsimError(f"{where}: cannot write ({reason})" + (f"; {note}" if note else ""))


@contextmanager
def writing(path: str | os.PathLike, note: str = "") -> Iterator[None]:
    """Turn an :class:`OSError` raised in the block into :func:`write_error` for ``path``."""
    try:
        yield
    except OSError as e:
        raise write_error(e, path, note) from None


@contextmanager
def reading(path: str | os.PathLike, what: str) -> Iterator[None]:
    """Turn the errors of reading a damaged store (bad JSON, wrong metadata, a missing array or
    file, a chunk that does not decompress) in the block into one :class:`MmwsimError` line naming
    ``path`` and ``what`` it should be."""
    try:
        yield
    except (OSError, ValueError, TypeError, KeyError, IndexError, RuntimeError) as e:  # codecs: RuntimeError
        reason = " ".join(str(e).split())[:160] or type(e).__name__
        raise MmwsimError(f"{path}: not a readable {what} ({type(e).__name__}: {reason})") from None


def check_output_folder(path: str | os.PathLike, flag: str = "") -> Path:
    """Refuse, before any work, an output file whose folder is missing or cannot be written
    (read-only file system, immutable folder); the write itself reports what this cannot foresee.

    Parameters
    ----------
    path : path-like
        The output file (a recording, a JSON file).
    flag : str
        The option that named it, for the message (e.g. ``"--rrd"``).
    """
    path = Path(path)
    parent = path.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise MmwsimError(
            f"{flag + ' ' if flag else ''}{path}: folder {parent} does not exist or is not writable"
        )
    return path


def make_dirs(path: str | os.PathLike) -> Path | None:
    """``mkdir -p path``; returns the outermost folder it created (None if it created none), so
    that a run that fails can remove what it made and nothing else."""
    path = Path(path)
    missing = [p for p in [path, *path.parents] if not p.exists()]
    with writing(path):
        path.mkdir(parents=True, exist_ok=True)
    return missing[-1] if missing else None


def _unlink_quietly(path: Path) -> None:
    with suppress(OSError):
        path.unlink(missing_ok=True)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a hidden sibling of ``path`` to write; rename it over ``path`` when the block ends.

    The sibling keeps the suffix (``.name.partial.png``), so writers that pick a format by
    suffix work. On any failure the sibling is removed and ``path`` keeps what it held; an
    :class:`OSError` becomes one :class:`MmwsimError` line naming the path.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        fault("file.write", tmp)
        yield tmp
        fault("file.rename", path)
        os.replace(tmp, path)
    except OSError as e:
        _unlink_quietly(tmp)
        raise write_error(OSError(e.errno, e.strerror), path) from None  # the target, not its temporary
    except BaseException:
        _unlink_quietly(tmp)
        raise


RECORDING_SUFFIX = ".rrd"
"""The suffix of Rerun recordings."""


def check_suffix(path: str | os.PathLike, suffix: str, what: str = "") -> Path:
    """``path`` as a :class:`~pathlib.Path` when it ends in ``suffix``, else a one-line
    :class:`MmwsimError` naming the option ``what`` (e.g. ``--rrd``) and the path."""
    p = Path(path)
    if p.suffix.lower() != suffix:
        kind = "a recording" if suffix == RECORDING_SUFFIX else "the file"
        raise MmwsimError(f"{f'{what} ' if what else ''}{p}: {kind} must end in {suffix}")
    return p


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to a hidden sibling of ``path``, then rename it over ``path``; returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def remove_tree(path: str | os.PathLike) -> None:
    """Remove a folder (or file) if it is there; a folder removed by someone else meanwhile is fine."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        _unlink_quietly(path)


# ---------------------------------------------------------------------- folder replacement
def _aside(final: Path) -> Path:
    return final.with_name(f".{final.name}.old")


def _exchange(a: Path, b: Path) -> None:
    """Swap two paths in one system call (Linux ``renameat2(RENAME_EXCHANGE)``)."""
    fault("replace.exchange", b)
    renameat2 = (
        getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None) if sys.platform == "linux" else None
    )
    if renameat2 is None:
        raise OSError(errno.ENOSYS, os.strerror(errno.ENOSYS), str(b))
    renameat2.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) != 0:
        code = ctypes.get_errno()
        raise OSError(code, os.strerror(code), str(a), None, str(b))


def replace_dir(new: str | os.PathLike, final: str | os.PathLike) -> None:
    """Make folder ``final`` hold what folder ``new`` holds; at every instant ``final`` holds
    the old contents or the new ones.

    Where the file system can exchange two names in one call (Linux ``renameat2``), ``new`` and
    ``final`` are swapped and the old contents, now under ``new``, removed. Elsewhere the old
    folder is first renamed to ``.<name>.old`` and the new one renamed into place: a kill
    between the two renames leaves the old contents under ``.<name>.old``, where
    :func:`resolve_dir` finds them and :func:`recover_dir` puts them back.

    Call :func:`recover_dir` before writing ``new``, under the output's lock.
    """
    new, final = Path(new), Path(final)
    fault("replace.written", new)
    if not final.exists():
        os.rename(new, final)
        return
    try:
        _exchange(new, final)
        old = new
    except OSError as e:
        if e.errno not in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
            raise
        old = _aside(final)
        os.rename(final, old)
        fault("replace.between", final)
        os.rename(new, final)
    fault("replace.switched", final)
    remove_tree(old)


def resolve_dir(final: str | os.PathLike) -> Path:
    """Where the current contents of a folder replaced by :func:`replace_dir` are: ``final``, or
    its ``.<name>.old`` while a portable replacement was interrupted between its renames."""
    final = Path(final)
    if not final.exists() and _aside(final).is_dir():
        return _aside(final)
    return final


def recover_dir(final: str | os.PathLike) -> None:
    """Finish or roll back a :func:`replace_dir` interrupted by a kill (call under the lock)."""
    final = Path(final)
    old = _aside(final)
    if not old.exists():
        return
    if final.exists():
        remove_tree(old)  # killed after the switch: the new contents are in place
    else:
        os.rename(old, final)  # killed between the renames: the old contents go back
