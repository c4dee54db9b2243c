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

Stdlib only: every layer (rflow, controllers, envs, batch, scripts) may import it.
"""

from __future__ import annotations

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
        try:
            fd, name = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=f".tmp{self.path.suffix}",
                                        dir=_folder(self.path))
        except OSError as err:  # a read-only folder, a full disk: named after the output, not the temporary name
            raise OSError(err.errno, err.strerror, str(self.path)) from err
        self.temporary = Path(name)
        try:
            os.fchmod(fd, 0o666 & ~umask())  # mkstemp makes 0600
        finally:
            os.close(fd)

    def commit(self) -> Path:
        """Rename the temporary file over ``path``; returns ``path``. On failure the temporary file is deleted."""
        try:
            os.replace(self.temporary, self.path)
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        """Delete the temporary file (idempotent)."""
        self.temporary.unlink(missing_ok=True)

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
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=parent))
    os.chmod(staging, 0o777 & ~umask())  # mkdtemp makes 0700
    aside: Path | None = None
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


__all__ = ["AtomicFile", "atomic_folder", "umask", "write_atomic"]
