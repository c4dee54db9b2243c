"""The file list of a folder output (a checkpoint, a dataset export): which files the program wrote there, so that
replacing the folder (--overwrite) never deletes a file somebody else put in it or changed since.

The manifest ``.pih-files.json`` is written last into the folder while it is still being built, and lists every
regular file then in it (relative POSIX paths) with its SHA-256. A folder may be replaced only when everything in
it is listed and unchanged (`strangers` is empty): a file added, a file edited, a new sub-folder or a symbolic
link all make it somebody else's.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Mapping

MANIFEST_NAME = ".pih-files.json"
"""The manifest's file name, inside the folder it lists."""


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_manifest(folder: str | os.PathLike[str]) -> dict[str, str]:
    """List every regular file under ``folder`` (but the manifest) with its SHA-256 into ``folder``/MANIFEST_NAME.
    Call when the folder is complete and not yet visible under its final name.

    Returns:
        The listed files: relative POSIX path -> SHA-256.
    """
    root = Path(folder)
    files = {path.relative_to(root).as_posix(): _sha256(path)
             for path in sorted(root.rglob("*")) if path.is_file() and path.name != MANIFEST_NAME}
    (root / MANIFEST_NAME).write_text(json.dumps({"files": files}, indent=1))
    return files


def read_manifest(folder: str | os.PathLike[str]) -> dict[str, str] | None:
    """The files ``folder``'s manifest lists (relative path -> SHA-256); None when it has none or it is malformed."""
    try:
        record = json.loads((Path(folder) / MANIFEST_NAME).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    files = record.get("files") if isinstance(record, dict) else None
    if not isinstance(files, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in files.items()):
        return None
    return files


def strangers(folder: str | os.PathLike[str], listed: Mapping[str, str | None]) -> list[str]:
    """What under ``folder`` the program did not write: every entry that is not a listed file with its listed
    SHA-256 (None: any content), not the manifest and not a folder on the way to a listed file; symbolic links
    and special files (FIFOs, sockets, devices) always. Relative POSIX paths, sorted; [] when the folder may be
    replaced."""
    root = Path(folder)
    needed = {Path(name).parent.as_posix() for name in listed}
    for name in list(needed):
        needed.update(p.as_posix() for p in Path(name).parents)
    found = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        here = Path(dirpath)
        for name in dirnames + filenames:
            path = here / name
            rel = path.relative_to(root).as_posix()
            if path.is_symlink():
                found.append(rel)
            elif path.is_dir():
                if rel not in needed:
                    found.append(rel)
            elif not path.is_file():  # a FIFO, a socket, a device: never opened
                found.append(rel)
            elif rel == MANIFEST_NAME and here == root:
                continue
            elif rel not in listed or (listed[rel] is not None and _sha256(path) != listed[rel]):
                found.append(rel)
    return sorted(found)


def folder_strangers(folder: str | os.PathLike[str], unlisted: Mapping[str, str | None]) -> list[str]:
    """`strangers` of ``folder`` against its manifest, or against ``unlisted`` (what the program is known to have
    written there) when it has none, e.g. a folder written before folders listed their files."""
    listed = read_manifest(folder)
    return strangers(folder, listed if listed is not None else unlisted)


def shown(found: list[str], most: int = 3) -> str:
    """The first ``most`` of ``found`` for a one-line message ("a, b, c and 4 more")."""
    return ", ".join(found[:most]) + (f" and {len(found) - most} more" if len(found) > most else "")


__all__ = ["MANIFEST_NAME", "folder_strangers", "read_manifest", "shown", "strangers", "write_manifest"]
