"""File writes that never leave a half-written file, never follow a link and name the file
when they fail.

* ``atomic_write_*``: a temporary file in the destination's directory, flushed, fsynced and
  ``os.replace``d over the destination (atomic on POSIX). A reader never sees a half-written
  result; a destination that is a symbolic link is replaced by the file, never written
  through (``rename`` replaces the link itself).
* ``append_line``: appends one line to a log that this run owns: opened with ``O_NOFOLLOW``
  and refused unless it is a regular file with a single name (a hard link would write into
  another file).
* ``create_exclusive``: a new file that must not exist yet (``O_CREAT | O_EXCL``, which
  also refuses a dangling link): never over a file that this run did not create.
  ``atomic_create_bytes``: the same for a file written whole (a temporary file, then
  ``link``ed to its name, which fails if anything is there).
* ``atomic_write_directory``: a set of files that is complete or absent (an export): written
  into a temporary directory beside the destination, verified, then renamed to it; the
  destination must not exist or be an empty directory.

Every failure is an ``OSError`` whose message names the file and the reason, e.g. "cannot
write runs/x/metrics.npz: No space left on device", so that the command line prints one
line.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np


def _cannot(verb: str, path: str | os.PathLike, e: OSError) -> OSError:
    """OSError 'cannot <verb> <path>: <reason>' (keeps the errno)."""
    err = OSError(f"cannot {verb} {os.fspath(path)}: {e.strerror or e}")
    err.errno = e.errno
    return err


def _write_temporary(path: Path, data: bytes, make_parents: bool = True) -> str:
    """``data`` in a new, fsynced temporary file beside ``path`` (created with its parent
    directories, or, without ``make_parents``, only in an existing one); returns the
    temporary file's name. Errors name ``path``."""
    if not make_parents and not path.parent.is_dir():
        if os.path.lexists(path.parent):
            raise NotADirectoryError(f"cannot write {path}: {path.parent} is not a directory")
        raise FileNotFoundError(
            f"cannot write {path}: the directory {path.parent} does not exist (create it "
            "first, or choose another path)"
        )
    try:
        if make_parents:
            path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except FileExistsError as e:  # mkdir met a file where a directory should be
        raise OSError(f"cannot write {path}: {e.filename} is not a directory") from e
    except OSError as e:
        raise _cannot("write", path, e) from e
    with _removed_on_failure(tmp, path):
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual mode
    return tmp


@contextlib.contextmanager
def _removed_on_failure(tmp: str, path: Path):
    """Removes the temporary file ``tmp`` if the block fails; an OSError (a full disk, a
    quota, a read-only remount) is reworded to name ``path``."""
    try:
        yield
    except OSError as e:
        Path(tmp).unlink(missing_ok=True)
        raise _cannot("write", path, e) from e
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Writes ``data`` to ``path`` atomically; creates the parent directory."""
    path = Path(path)
    tmp = _write_temporary(path, data)
    with _removed_on_failure(tmp, path):
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    return path


def atomic_create_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Writes ``data`` to the new file ``path``, atomically; FileExistsError naming it if
    anything (a file, a link) is there already, FileNotFoundError if its directory does not
    exist (a typo there must not create directories)."""
    path = Path(path)
    if os.path.lexists(path):
        raise FileExistsError(f"{path} exists already; it is never overwritten: choose another")
    tmp = _write_temporary(path, data, make_parents=False)
    try:
        os.link(tmp, path)  # fails, like O_EXCL, if the name was taken meanwhile
    except FileExistsError:
        raise FileExistsError(f"{path} exists already; it is never overwritten") from None
    except OSError as e:
        raise _cannot("write", path, e) from e
    finally:
        Path(tmp).unlink(missing_ok=True)
    _fsync_dir(path.parent)
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_dir(directory: Path) -> None:
    """Makes the rename durable (POSIX); a no-op where directories cannot be opened."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode())


def atomic_write_json(path: str | os.PathLike, obj: Any, compact_lists: bool = False) -> Path:
    """``obj`` as indented JSON; ``compact_lists``: a list of numbers on one line (figures'
    series stay readable and a few times smaller)."""
    text = json.dumps(obj, indent=2, default=_jsonable)
    if compact_lists:
        text = _NUMBER_LIST.sub(lambda m: "[" + " ".join(m.group(1).split()) + "]", text)
    return atomic_write_text(path, text + "\n")


_NUMBER_LIST = re.compile(r"\[\s+((?:(?:-?[0-9.eE+-]+|null|true|false),?\s+)+)\]")


def atomic_write_npz(path: str | os.PathLike, **arrays: np.ndarray) -> Path:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return atomic_write_bytes(path, buf.getvalue())


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def check_own_file(fd: int, path: str | os.PathLike) -> None:
    """Raises OSError unless the open ``fd`` is a regular file with one name: not a device,
    FIFO or directory, and not a hard link whose writes would land in another file too."""
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        raise OSError(f"{os.fspath(path)} is not a regular file; remove it or choose another path")
    if info.st_nlink != 1:
        raise OSError(
            f"{os.fspath(path)} has {info.st_nlink} names (a hard link): writing it would "
            "change another file too; remove it"
        )


def open_no_follow(path: str | os.PathLike, flags: int, mode: int = 0o644) -> int:
    """``os.open`` that refuses a symbolic link at ``path`` (``O_NOFOLLOW``) and anything but
    a regular file with one name (``check_own_file``), with messages naming the path."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, mode)
    except OSError as e:
        if os.path.islink(path):
            raise OSError(
                f"{os.fspath(path)} is a symbolic link; advisor-jax never writes through a "
                "link it did not make: remove it"
            ) from None
        raise _cannot("open", path, e) from e
    try:
        check_own_file(fd, path)
    except BaseException:
        os.close(fd)
        raise
    return fd


def append_line(path: str | os.PathLike, line: str) -> None:
    """Appends ``line`` + newline to ``path`` (created if missing), never through a link."""
    fd = open_no_follow(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    try:
        data = (line + "\n").encode()
        while data:
            written = os.write(fd, data)
            data = data[written:]
    except OSError as e:
        raise _cannot("write", path, e) from e
    finally:
        os.close(fd)


def create_exclusive(path: str | os.PathLike) -> IO[str]:
    """A new text file at ``path`` (line-buffered, UTF-8); OSError naming it if anything,
    a dangling symbolic link included, is there already."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
    except FileExistsError:
        raise FileExistsError(
            f"{os.fspath(path)} exists already; it is never overwritten: choose another path"
        ) from None
    except OSError as e:
        raise _cannot("create", path, e) from e
    return os.fdopen(fd, "w", encoding="utf-8", buffering=1)


def atomic_write_directory(
    path: str | os.PathLike,
    files: Mapping[str, bytes],
    verify: Callable[[str], Any] | None = None,
) -> Path:
    """Writes ``files`` (name -> bytes) as the new directory ``path``: into a temporary
    directory beside it, fsynced, checked by ``verify(temporary path)`` if given, then
    renamed to ``path`` (which must not exist, or be an empty directory: rename(2) replaces
    only those). On any failure nothing is left behind."""
    path = Path(path)
    try:
        path.absolute().parent.mkdir(parents=True, exist_ok=True)
        tmp = tempfile.mkdtemp(
            prefix=f".{path.name}.", suffix=".partial", dir=path.absolute().parent
        )
    except OSError as e:
        raise _cannot("write", path, e) from e
    try:
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; give the usual mode
        for name, data in files.items():
            atomic_write_bytes(os.path.join(tmp, name), data)
        if verify is not None:
            verify(tmp)
        try:
            os.rename(tmp, path)
        except OSError as e:
            raise _cannot("write", path, e) from e
        _fsync_dir(path.absolute().parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path
