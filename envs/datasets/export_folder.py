"""The export folder: written under a temporary name beside it and renamed into place, so a failure or Ctrl-C
leaves nothing half-written; an existing folder is replaced only when asked to and only if it is one of our
exports (it holds the marker file, envs.datasets.features.MARKER_FILE) holding nothing but the files the export
wrote, unchanged (its file list, pihutil.manifest).
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from envs.datasets.features import MARKER_FILE
from envs.errors import EnvError
from pihutil.atomic import atomic_folder
from pihutil.manifest import folder_strangers, read_manifest, shown, write_manifest


def check_export_folder(out: Path, overwrite: bool) -> None:
    """May ``out`` be written? It may not exist yet, or be an empty folder, or (with ``overwrite``) be an export
    of ours.

    Raises:
        EnvError: the parent folder is missing, ``out`` is a file, or a non-empty folder that is not an export
            of ours or that ``overwrite`` does not allow to replace.
    """
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise EnvError(f"--out {out}: folder {parent} does not exist")
    if not out.exists():
        return
    if not out.is_dir():
        raise EnvError(f"--out {out} is a file; an export is a folder")
    if not any(out.iterdir()):
        return
    if not (out / MARKER_FILE).is_file():
        raise EnvError(f"--out {out} is a non-empty folder that is not a `pih export` output (no {MARKER_FILE}); "
                       "choose another folder")
    if not overwrite:
        raise EnvError(f"--out {out} already holds an export (pass --overwrite to replace it)")
    if read_manifest(out) is None:
        raise EnvError(f"--out {out} is an export from before exports listed their files: pih cannot tell its files "
                       "from others there; remove it yourself or choose another folder")
    found = folder_strangers(out, {})
    if found:
        raise EnvError(f"--out {out} holds files the export did not write or that changed since ({shown(found)}): "
                       "not replacing it; move them out or choose another folder")


def _not_only_ours(old: Path) -> bool:
    """Whether a replaced folder, as it was moved aside, holds anything but an export's own listed files."""
    return any(old.iterdir()) and (read_manifest(old) is None or bool(folder_strangers(old, {})))


@contextmanager
def staged_folder(out: Path, overwrite: bool) -> Iterator[Path]:
    """Yield a temporary folder beside ``out`` to write the export into (with its MARKER_FILE); on a normal exit
    swap it in for ``out`` (replacing an export of ours there), else delete it (`pihutil.atomic.atomic_folder`).
    ``out`` is checked again just before the swap: nothing else may have appeared there meanwhile.

    Raises:
        EnvError: see `check_export_folder`; no MARKER_FILE was written.
    """
    check_export_folder(out, overwrite)
    with atomic_folder(out, before_swap=lambda: check_export_folder(out, overwrite),
                       keep_replaced=_not_only_ours) as staging:
        yield staging
        if not (staging / MARKER_FILE).is_file():
            raise EnvError(f"export to {out}: no {MARKER_FILE} was written")
        write_manifest(staging)
