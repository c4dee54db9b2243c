"""The output policy of every `pih` command: how a file is written, when an existing path may be replaced, and
what is checked about an output before any work starts.

Writing. `AtomicOutput` (the project's one atomic write, `pihutil.atomic`) gives a temporary name in the
output's own folder (".NAME.XXXXXXXX.tmp.SUFFIX": the same suffix, so writers that pick the format from it,
ffmpeg and matplotlib, still do) and renames it over NAME (os.replace, atomic within one file system) only
when the writing ended without an exception; on any error (an exception, a full disk, Ctrl-C) the temporary
file is deleted, so a failure leaves the earlier file or none, never half a file. The file's mode follows
the umask. Every writer below (`write_json`,
`write_text`, `save_npz`, `save_figure`) and the MP4 writer (envs.media.video.Mp4Writer) go through it. JSON is
strict: ``allow_nan=False``, a non-finite float is written as null (`strict_json`).

Ownership. An existing path is replaced only when the command was given --overwrite AND the path carries
this program's marker ``{"command": <the pih subcommand>, "version": <the package version>}``:
  - JSON (.json): the top-level key "pih" (`write_json` adds it);
  - NumPy archives (.npz): the array "pih", that JSON as text (`save_npz` adds it);
  - JSON Lines journals (.jsonl, batch.journal): a first line ``{"kind": "header", "run": {...}}``;
  - checkpoint folders (`pih train`): a skill.json of rflow's checkpoint format (rflow.skill_io.is_checkpoint;
    rflow builds the folder beside its place and swaps it in itself, since rflow does not depend on envs);
  - dataset folders (`pih export`): the marker file pih_export.json (built in a staging folder and swapped in
    by envs.datasets.export_folder, which also takes an empty folder);
  - and both folders only while they hold nothing but the files they list, unchanged (pihutil.manifest's
    .pih-files.json): a file somebody added or edited there keeps the whole folder from being replaced;
  - every other file (MP4, PNG, Markdown): an entry in the registry ".pih-outputs.json" of its folder (a
    marked JSON file) holding the file's SHA-256 as written. A file changed since, or not listed, is not ours.
    The registry is rewritten (atomically) after each such output; two commands writing registered files
    into one folder at the same instant can lose an entry, which only makes a later --overwrite refuse it.

Checks before work (`check_output`): the folder exists and is writable, the path is not a folder (or is one,
for a folder output), it has the right suffix, an existing path is ours and --overwrite was given, the path
is none of the command's inputs, lies inside none of them (a checkpoint folder being read) and contains none,
and the folder's file system has room for a generous estimate of the output's size. A refusal is an
EnvError naming the option and the path (`pih` prints one line and exits 2) and touches nothing.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
from importlib import metadata
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from envs.errors import EnvError
from envs.io.jsonable import to_jsonable
from pihutil.atomic import AtomicFile, write_atomic

MARKER_KEY = "pih"
"""Top-level JSON key, and .npz array name, of the marker."""
REGISTRY_NAME = ".pih-outputs.json"
"""Per-folder registry of the files without a marker of their own (name -> SHA-256)."""
EXPORT_MARKER_FILE = "pih_export.json"
"""The marker file of a `pih export` folder (envs.datasets.features.MARKER_FILE)."""
SELF_MARKED_SUFFIXES: tuple[str, ...] = (".json", ".npz", ".jsonl")
MiB = 1 << 20

_command = "library"


def set_command(name: str) -> None:
    """Name the `pih` subcommand whose outputs this process writes (recorded in every marker)."""
    global _command
    _command = name


def package_version() -> str:
    """The installed pih-rflow version ("unknown" when run from a tree that is not installed)."""
    try:
        return metadata.version("pih-rflow")
    except metadata.PackageNotFoundError:
        return "unknown"


def marker() -> dict[str, str]:
    """This program's marker: which subcommand wrote the output, with which version."""
    return {"command": _command, "version": package_version()}


def strict_json(value: Any) -> Any:
    """``value`` made JSON-ready (envs.io.jsonable.to_jsonable) with every non-finite float replaced by None."""
    value = to_jsonable(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [strict_json(v) for v in value]
    return value


def json_text(value: Any, indent: int | None = 2) -> str:
    """Strict JSON text of ``value`` (non-finite floats as null, never a bare NaN or Infinity)."""
    return json.dumps(strict_json(value), indent=indent, allow_nan=False)


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(MiB), b""):
            digest.update(block)
    return digest.hexdigest()


class AtomicOutput(AtomicFile):
    """`pihutil.atomic.AtomicFile` (a temporary file beside ``path`` that becomes ``path`` on `commit` or
    disappears on `abort`) that can also list the output in its folder's registry after the rename.

    Usage::

        with AtomicOutput(path) as out:
            write_to(out.temporary)      # renamed to path when the block ends without an exception

    Attributes:
        path: the output.  temporary: where it is written until `commit`.
        register: list the output in its folder's registry after the rename (files without a marker).
    """

    def __init__(self, path: str | os.PathLike[str], register: bool = False):
        super().__init__(path)
        self.register = register

    def commit(self) -> Path:
        """Rename the temporary file over ``path`` (and register it); returns ``path``."""
        super().commit()
        if self.register:
            register_output(self.path)
        return self.path


def write_file(path: str | os.PathLike[str], write: Callable[[Any], None], binary: bool = False,
               register: bool = False) -> Path:
    """Write through ``write(handle)`` into an `AtomicOutput` (`pihutil.atomic.write_atomic`: flushed and fsynced
    before the rename).

    Raises:
        OSError: the write failed (a full disk, ...); named after ``path`` when the system did not name a file.
    """
    return write_atomic(path, write, binary, output=lambda target: AtomicOutput(target, register))


def write_json(path: str | os.PathLike[str], record: Mapping[str, Any], mark: bool = True) -> Path:
    """Write a JSON object (strict, indented) with this program's marker under "pih", atomically; ``mark``
    False for a file of another program's format inside a marked output (LeRobot's meta/info.json in an
    export folder, which its own marker file makes ours)."""
    if not isinstance(record, Mapping):
        raise TypeError(f"write_json writes JSON objects, got {type(record).__name__}")
    text = json_text({**record, MARKER_KEY: marker()} if mark else record)
    return write_file(path, lambda handle: handle.write(text + "\n"))


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write a text file atomically and list it in the folder's registry."""
    return write_file(path, lambda handle: handle.write(text), register=True)


def save_npz(path: str | os.PathLike[str], arrays: Mapping[str, Any]) -> Path:
    """Write an .npz archive of ``arrays`` plus the marker array "pih", atomically."""
    if MARKER_KEY in arrays:
        raise ValueError(f"array name {MARKER_KEY!r} is reserved for the marker")
    import numpy as np

    marked = {**arrays, MARKER_KEY: np.str_(json.dumps(marker()))}
    return write_file(path, lambda handle: np.savez(handle, **marked), binary=True)


def save_figure(figure: Any, path: str | os.PathLike[str], dpi: int = 120) -> Path:
    """Save a matplotlib figure as PNG atomically (registered) and close it; a failure to save raises."""
    import matplotlib.pyplot as plt

    try:
        return write_file(path, lambda handle: figure.savefig(handle, format="png", dpi=dpi), binary=True,
                          register=True)
    finally:
        plt.close(figure)


# ---- ownership ---------------------------------------------------------------------------------------------
def _read_registry(folder: Path) -> dict[str, Any] | None:
    """The registry's entries (name -> {"sha256": ...}); {} when there is none; None when it is not ours."""
    path = folder / REGISTRY_NAME
    if not path.exists():
        return {}
    if not _is_marked_json(path):
        return None
    files = json.loads(path.read_text(encoding="utf-8")).get("files")
    return dict(files) if isinstance(files, dict) else None


def register_output(path: str | os.PathLike[str]) -> None:
    """Record ``path``'s SHA-256 in its folder's registry (rewritten atomically)."""
    out = Path(path)
    folder = out.parent if str(out.parent) else Path(".")
    files = _read_registry(folder)
    if files is None:
        raise EnvError(f"{folder / REGISTRY_NAME} was not written by pih: not replacing it")
    files[out.name] = {"sha256": file_sha256(out), "command": _command}
    write_json(folder / REGISTRY_NAME, {"files": dict(sorted(files.items()))})


def _is_marked_json(path: Path) -> bool:
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(record, dict) and isinstance(record.get(MARKER_KEY), dict)


def _is_marked_npz(path: Path) -> bool:
    import zipfile

    from envs.io.npz import open_npz

    try:
        with open_npz(path) as archive:
            return MARKER_KEY in archive.files
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return False


def _is_journal(path: Path) -> bool:
    try:
        with open(path, encoding="utf-8") as handle:
            header = json.loads(handle.readline(4 * MiB))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(header, dict) and header.get("kind") == "header" and isinstance(header.get("run"), dict)


def is_own_output(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` carries this program's marker (module docstring), so that --overwrite may replace it."""
    p = Path(path)
    if p.is_symlink():
        return False
    if p.is_dir():
        from pihutil.manifest import folder_strangers, read_manifest
        from rflow.skill_io import checkpoint_strangers, is_checkpoint

        if is_checkpoint(p):
            return not checkpoint_strangers(p)
        return (p / EXPORT_MARKER_FILE).is_file() and read_manifest(p) is not None and not folder_strangers(p, {})
    if not p.is_file():
        return False
    suffix = p.suffix.lower()
    if suffix == ".json":
        return _is_marked_json(p)
    if suffix == ".npz":
        return _is_marked_npz(p)
    if suffix == ".jsonl":
        return _is_journal(p)
    entry = (_read_registry(p.parent) or {}).get(p.name)
    return isinstance(entry, dict) and entry.get("sha256") == file_sha256(p)


# ---- checks before work ------------------------------------------------------------------------------------
def _inside(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def _check_not_input(where: str, resolved: Path, inputs: Iterable[str | os.PathLike[str] | None]) -> None:
    """An output (``resolved``) is no input, lies inside none (a checkpoint being read) and holds none."""
    for given in inputs:
        if given is None:
            continue
        source = Path(given).resolve()
        if resolved == source:
            raise EnvError(f"{where} is an input of this command ({given}): choose another output")
        if _inside(resolved, source):
            raise EnvError(f"{where} lies inside the input {given}: choose another output")
        if _inside(source, resolved):
            raise EnvError(f"{where} holds the input {given}: choose another output")


def check_output(option: str, path: str | os.PathLike[str] | None, overwrite: bool, *, suffix: str | None = None,
                 inputs: Iterable[str | os.PathLike[str] | None] = (), estimate_bytes: int = 0,
                 folder: bool = False) -> Path | None:
    """Check an output before any work (module docstring); None passes through.

    Args:
        option: the command-line option that named the output (for the message).
        path: the output (a file; with ``folder``, a folder output such as a checkpoint).
        overwrite: --overwrite was given (a path that is ours may be replaced).
        suffix: the required suffix (e.g. ".json"), or None.
        inputs: the command's input files and folders (None entries are skipped).
        estimate_bytes: a generous estimate of the output's size; the file system must have that much free.

    Raises:
        EnvError: naming ``option`` and the problem.
    """
    if path is None:
        return None
    out = Path(path)
    where = f"{option} {out}"
    if suffix is not None and out.suffix.lower() != suffix:
        raise EnvError(f"{where}: must end in {suffix}")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise EnvError(f"{where}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise EnvError(f"{where}: folder {parent} is not writable")
    _check_not_input(where, out.resolve(), inputs)
    if out.exists() or out.is_symlink():
        if out.is_dir() and not folder:
            raise EnvError(f"{where} is a folder")
        if not is_own_output(out):
            kind = "folder" if out.is_dir() else "file"
            what = "is not a checkpoint written by pih" if folder else "was not written by pih (no pih marker)"
            if out.is_dir() and not out.is_symlink():
                from pihutil.manifest import shown
                from rflow.skill_io import checkpoint_strangers, is_checkpoint

                found = checkpoint_strangers(out) if is_checkpoint(out) else []
                if found:
                    what = f"holds files its checkpoint did not write or that changed since ({shown(found)})"
            raise EnvError(f"{where}: the {kind} there {what}: not replacing it; choose another path")
        if not overwrite:
            raise EnvError(f"{where} already exists (use --overwrite to replace it)")
    elif out.suffix.lower() not in SELF_MARKED_SUFFIXES and not folder and _read_registry(parent) is None:
        raise EnvError(f"{where}: {parent / REGISTRY_NAME} was not written by pih: not replacing it")
    check_free_space(where, parent, estimate_bytes)
    return out


def check_output_folder(option: str, path: str | os.PathLike[str], *,
                        inputs: Iterable[str | os.PathLike[str] | None] = (), estimate_bytes: int = 0) -> bool:
    """Check a folder that a command writes its outputs into (created with its missing parents; the files in it
    are checked one by one with `check_output`): it is a folder or does not exist yet, it (or its nearest
    existing parent) is writable and has room for ``estimate_bytes``, and it is none of the inputs, inside
    none, and holds none.

    Returns:
        True when the folder does not exist yet (the command creates it).

    Raises:
        EnvError: naming ``option`` and the problem.
    """
    out = Path(path)
    where = f"{option} {out}"
    if out.exists() and not out.is_dir():
        raise EnvError(f"{where} is a file, not a folder")
    new = not out.exists()
    folder = out.absolute()
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        raise EnvError(f"{where}: {folder} is a file, not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise EnvError(f"{where}: folder {folder} is not writable")
    _check_not_input(where, out.resolve(), inputs)
    check_free_space(where, folder, estimate_bytes)
    return new


def check_free_space(where: str, folder: Path, estimate_bytes: int) -> None:
    """The file system of ``folder`` must have ``estimate_bytes`` (plus 1 MiB) free. Raises EnvError."""
    free = shutil.disk_usage(folder).free
    need = int(estimate_bytes) + MiB
    if free < need:
        raise EnvError(f"{where}: only {free / MiB:.1f} MiB free in {folder}, the output needs about "
                       f"{need / MiB:.1f} MiB")


def check_distinct(outputs: Mapping[str, str | os.PathLike[str] | None]) -> None:
    """No two outputs of one command are the same path. Raises EnvError naming both options."""
    seen: dict[Path, str] = {}
    for option, path in outputs.items():
        if path is None:
            continue
        key = Path(path).resolve()
        if key in seen:
            raise EnvError(f"{option} {path} is also {seen[key]}")
        seen[key] = option
