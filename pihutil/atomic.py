"""Atomic writes: an output appears whole under its name, or not at all. The project's one implementation.

A file is written to a temporary name in its own folder and renamed over the target with ``os.replace``,
which POSIX makes atomic within one file system: a reader sees the old file or the new one, never a part.
On any error (an exception, a full disk, Ctrl-C) the temporary file is deleted, so a failure leaves the
earlier file or none. A folder (a checkpoint, a dataset) is built the same way under a temporary name and
swapped in: the old folder is first renamed aside, the new one renamed into place, the old one deleted; if
the swap fails the old folder is put back. Two renames are not one, so a crash between them leaves the old
folder under its ".old-" name beside the target (never a half-written target).

New files and folders get the modes a plain ``open`` or ``mkdir`` would give (0666 / 0777 less the umask),
not ``mkstemp``'s 0600.

Killed runs. A process killed outright (SIGKILL, the OOM killer, a power cut) deletes nothing: its temporary file
or folder stays beside the output. So each is locked (``fcntl.flock``) while its writer lives (a temporary file
through its own open handle, a folder through a lock file ".NAME.lock-XXXXXXXX" beside it), and the next write of
the same output removes those whose lock is free (`remove_stale`), saying so on stderr: a lock held is a live
writer, left alone.

Stdlib only: every layer (rflow, controllers, envs, batch, scripts) may import it.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Callable, Iterator


def umask() -> int:
    """The process's umask (read by setting it and setting it back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _folder(path: Path) -> Path:
    return path.parent if str(path.parent) else Path(".")


class AtomicFile:
    """A temporary file beside ``path`` that becomes ``path`` on `commit` or disappears on `abort`.

    Usage::

        with AtomicFile(path) as out:
            write_to(out.temporary)      # renamed to path when the block ends without an exception

    The temporary name is ".NAME.XXXXXXXX.tmp.SUFFIX": hidden, unique, and with the target's suffix, so a
    writer that picks the format from the name (ffmpeg, matplotlib) still does.

    Raises:
        OSError: the temporary file could not be made (named after ``path``, not the temporary name).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        remove_stale(self.path)
        try:
            fd, name = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=f".tmp{self.path.suffix}",
                                        dir=_folder(self.path))
        except OSError as err:  # a read-only folder, a full disk: named after the output, not the temporary name
            raise OSError(err.errno, err.strerror, str(self.path)) from err
        self.temporary = Path(name)
        self._lock: int | None = fd  # held until commit or abort: a live writer's file (module docstring)
        try:
            _lock(fd)
            os.fchmod(fd, 0o666 & ~umask())  # mkstemp makes 0600
        except BaseException:
            self.abort()
            raise

    def commit(self) -> Path:
        """Rename the temporary file over ``path``; returns ``path``. On failure the temporary file is deleted."""
        try:
            os.replace(self.temporary, self.path)
        except BaseException:
            self.abort()
            raise
        self._release()
        return self.path

    def abort(self) -> None:
        """Delete the temporary file (idempotent)."""
        self.temporary.unlink(missing_ok=True)
        self._release()

    def _release(self) -> None:
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None

    def __enter__(self) -> AtomicFile:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.abort()


def write_atomic(path: str | os.PathLike[str], write: Callable[[IO[Any]], None], binary: bool = False,
                 output: Callable[[str | os.PathLike[str]], AtomicFile] = AtomicFile) -> Path:
    """Write ``path`` through ``write(handle)`` into ``output(path)`` (an `AtomicFile` or one of its subclasses),
    flushed and fsynced before the rename, so the bytes are on disk before the name points at them.

    Raises:
        OSError: the write failed (a full disk, ...); named after ``path`` when the system did not name a file.
    """
    try:
        with output(path) as out:
            with open(out.temporary, "wb" if binary else "w", encoding=None if binary else "utf-8") as handle:
                write(handle)
                handle.flush()
                os.fsync(handle.fileno())
    except OSError as err:
        if err.filename is None and err.errno is not None:
            raise OSError(err.errno, err.strerror, str(path)) from err
        raise
    return Path(path)


@contextmanager
def atomic_folder(path: str | os.PathLike[str], before_swap: Callable[[], None] | None = None,
                  keep_replaced: Callable[[Path], bool] | None = None) -> Iterator[Path]:
    """Yield a new empty folder beside ``path`` (".NAME.tmp-XXXXXXXX", mode 0777 less the umask) to build a
    folder output in; when the block ends without an exception, swap it in for ``path``.

    The swap: ``before_swap()`` (the caller's last check, e.g. that what is at ``path`` may still be
    replaced; it may raise), then an existing ``path`` is renamed aside into ".NAME.old-XXXXXXXX", the new
    folder renamed to ``path`` and the old one deleted, unless ``keep_replaced(old)`` says otherwise (the same
    check again, on the folder as it was moved: a file that appeared between the check and the move is then
    kept there, and a line on stderr says where). On any error the new folder is deleted and, if ``path`` was
    moved aside, it is put back.

    Raises:
        Whatever the block or ``before_swap`` raises; OSError from the renames.
    """
    out = Path(path)
    parent = _folder(out)
    remove_stale(out)
    lock_fd, lock_name = tempfile.mkstemp(prefix=f".{out.name}.lock-", dir=parent)  # locked before the folder exists
    aside: Path | None = None
    staging = parent / f".{out.name}.tmp-{Path(lock_name).name.rsplit('.lock-', 1)[1]}"
    try:
        _lock(lock_fd)
        os.mkdir(staging, 0o777 & ~umask())
    except BaseException:
        os.close(lock_fd)
        os.unlink(lock_name)
        raise
    try:
        yield staging
        if before_swap is not None:
            before_swap()
        if out.exists() or out.is_symlink():
            aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=parent))
            os.replace(out, aside / out.name)
        os.replace(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if aside is not None and not out.exists() and (aside / out.name).exists():
            os.replace(aside / out.name, out)  # put the previous folder back
        raise
    finally:
        if aside is not None:
            replaced = aside / out.name
            if keep_replaced is not None and replaced.exists() and keep_replaced(replaced):
                sys.stderr.write(f"kept the replaced {out} at {replaced}: files appeared in it while it was "
                                 "replaced\n")
            else:
                shutil.rmtree(aside, ignore_errors=True)
        os.unlink(lock_name)  # the staging folder is gone (renamed or removed): its lock goes last
        os.close(lock_fd)


def _lock(fd: int) -> None:
    """Hold an exclusive lock on ``fd`` (released when the last descriptor of its open file closes: at exit, or at
    the death of the process, whatever kills it)."""
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def _free(path: Path) -> bool:
    """Whether no process holds the lock of ``path`` (a missing file is free)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return True
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def remove_stale(path: str | os.PathLike[str]) -> list[Path]:
    """Remove what killed writers of ``path`` left beside it: temporary files ".NAME.XXXXXXXX.tmp.SUFFIX" and
    staging folders ".NAME.tmp-XXXXXXXX" (with their lock files) whose lock no process holds (module docstring);
    one line on stderr names them. A replaced folder moved aside (".NAME.old-XXXXXXXX", a crash between the two
    renames of a swap) is only named: it may be the only copy of the previous output.

    Returns:
        What was removed.
    """
    out = Path(path)
    parent = _folder(out)
    try:
        entries = [entry for entry in parent.iterdir() if entry.name.startswith(f".{out.name}.")]
    except OSError:
        return []
    removed: list[Path] = []
    for entry in entries:
        rest = entry.name[len(out.name) + 2:]
        if rest.startswith("tmp-") and entry.is_dir() and not entry.is_symlink():
            lock = parent / f".{out.name}.lock-{rest[4:]}"
            if _free(lock):
                shutil.rmtree(entry, ignore_errors=True)
                lock.unlink(missing_ok=True)
                removed.append(entry)
        elif rest.startswith("lock-") and entry.is_file() and not (parent / f".{out.name}.tmp-{rest[5:]}").exists():
            if _free(entry):
                entry.unlink(missing_ok=True)
        elif (rest.endswith(f".tmp{out.suffix}") and len(rest) == 8 + len(f".tmp{out.suffix}") and entry.is_file()
              and not entry.is_symlink() and _free(entry)):
            entry.unlink(missing_ok=True)
            removed.append(entry)
        elif rest.startswith("old-") and entry.is_dir() and (entry / out.name).exists():
            sys.stderr.write(f"an earlier {out} replaced by an interrupted write is kept at {entry / out.name}\n")
    if removed:
        sys.stderr.write(f"removed {', '.join(p.name for p in removed)} beside {out}: left by a run that was killed "
                         "while writing it\n")
    return removed


__all__ = ["AtomicFile", "atomic_folder", "remove_stale", "umask", "write_atomic"]
