"""JSON Lines journal of a batch run, so an interrupted run can be resumed with identical results.

File layout, one JSON object per line::

    {"kind": "header", "run": {...}}                     what the run is (config, inputs' checksums)
    {"kind": "unit", "key": "...", "record": {...}, "segment": 0, "elapsed_s": 12.5}
                                                         one line per finished unit, in finishing order
    {"kind": "event", "event": {...}, "segment": 0, "elapsed_s": 3.2}
                                                         an infrastructure event (batch.supervision)

``segment`` counts the times the run was started (0, then one more per resume) and ``elapsed_s`` is the wall
time since the journal was opened in that segment, so the wall time of the earlier segments (each up to its
last line) is known on resume. Each line is written whole, flushed and fsynced before `append` returns, so a crash loses at most the line
being written. A journal is locked (``fcntl.flock``) while a run owns it: a second run on it (a --resume or an
--overwrite started while the first still goes) is refused in one line instead of duplicating the work and tearing
the file; the lock goes with the process, however it ends. Such a torn last line (no newline, or not JSON) is ignored on resume and cut off before the
next append. A resumed run must describe the same run: its header's ``run`` must equal the new one (after
a JSON round trip, so tuples and lists compare equal).
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, TextIO

from batch.errors import BatchError
from pihutil.atomic import write_atomic

HEADER = "header"
UNIT = "unit"
EVENT = "event"


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, inf) replaced by None, so the journal is strict JSON."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def as_json(value: Any, what: str) -> Any:
    """``value`` after a strict JSON round trip (tuples become lists, keys strings, NaN and inf None).

    Raises:
        BatchError: ``value`` is not JSON-serialisable.
    """
    try:
        return json.loads(json.dumps(_finite(value), allow_nan=False))
    except (TypeError, ValueError) as err:
        raise BatchError(f"{what} is not JSON-serialisable: {err}") from None


def _first_difference(old: Any, new: Any, path: str = "") -> str:
    """A short description of the first place where two run descriptions differ: the path into them down to the
    first differing value (e.g. 'cells[1].settings.clearance_m' was 0.0002, now 0.0003)."""
    if isinstance(old, dict) and isinstance(new, dict):
        for key in sorted(set(old) | set(new)):
            where = f"{path}.{key}" if path else str(key)
            if key not in old:
                return f"{where!r} is new"
            if key not in new:
                return f"{where!r} is missing"
            if old[key] != new[key]:
                return _first_difference(old[key], new[key], where)
    elif isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        for index, (a, b) in enumerate(zip(old, new)):
            if a != b:
                return _first_difference(a, b, f"{path}[{index}]")
    if old == new:
        return "none"
    return f"{path!r} was {json.dumps(old)[:80]}, now {json.dumps(new)[:80]}"


@dataclass
class _Contents:
    """What a journal file holds: the run, the finished units, the events, each segment's wall time."""

    run: dict[str, Any]
    done: dict[str, dict[str, Any]] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    wall_s: dict[int, float] = field(default_factory=dict)
    good_bytes: int = 0


class Journal:
    """JSON Lines journal of a batch run: line 1 {"kind": "header", "run": {...}}; then one line per finished
    unit and per infrastructure event, flushed and fsynced as it is written (module docstring).

    Attributes:
        path: the file.
        run: the run description (its header).
        earlier_wall_s: wall seconds the earlier segments of this run took, each up to its last line (0 for a
            new journal); a resumed run's wall time is this plus its own.
    """

    def __init__(self, path: Path, contents: _Contents, handle: TextIO):
        """Use `Journal.open`."""
        self.path = path
        self.run = contents.run
        self._done = contents.done
        self._events = contents.events
        self.earlier_wall_s = sum(contents.wall_s.values())
        self._segment = max(contents.wall_s, default=-1) + 1
        self._opened = time.monotonic()
        self._handle: TextIO | None = handle

    @classmethod
    def open(cls, path: str | os.PathLike[str], run: dict[str, Any], resume: bool = False,
             overwrite: bool = False) -> Journal:
        """Start a new journal at ``path`` or continue the one there.

        Args:
            path: the journal file.
            run: JSON-ready description of the run (written in the header; must match on resume).
            resume: continue the journal at ``path`` (it must exist and describe the same run).
            overwrite: without ``resume``, replace an existing journal (only a file whose first line is a
                journal header; anything else is never replaced).

        Raises:
            BatchError: the folder does not exist; ``path`` exists without resume (or is not a journal);
                resume of a missing, corrupt or different run's journal.
        """
        out = Path(path)
        header = as_json(run, "the run description")
        if not isinstance(header, dict):
            raise BatchError(f"the run description of journal {out} must be a JSON object")
        parent = out.parent if str(out.parent) else Path(".")
        if not parent.is_dir():
            raise BatchError(f"cannot write journal {out}: folder {parent} does not exist")
        if resume:
            if not out.is_file():
                raise BatchError(f"cannot resume: journal {out} does not exist")
            handle = open(out, "r+", encoding="utf-8")
            try:
                _lock(handle, out)
                contents = _read(out)
                if contents.run != header:
                    raise BatchError(f"cannot resume from journal {out}: it records a different run "
                                     f"(key {_first_difference(contents.run, header)})")
                handle.truncate(contents.good_bytes)  # drop a torn last line before appending
                handle.seek(contents.good_bytes)
            except BaseException:
                handle.close()
                raise
            return cls(out, contents, handle)
        if out.exists() or out.is_symlink():
            if not overwrite:
                raise BatchError(f"journal {out} already exists: use --resume or choose another path")
            _read(out)  # raises unless it is a journal: never replace a file that is not ours
            with open(out, "r", encoding="utf-8") as old:
                _lock(old, out)  # not while another run writes it
        return cls(out, _Contents(header), _create(out, header))

    def done(self) -> dict[str, dict[str, Any]]:
        """key -> record of the units already finished (a copy)."""
        return dict(self._done)

    def events(self) -> list[dict[str, Any]]:
        """The infrastructure events written so far, earlier segments' included (a copy)."""
        return list(self._events)

    def append(self, key: str, record: dict[str, Any]) -> None:
        """Write one finished unit, flushed and fsynced before returning.

        Raises:
            BatchError: the journal is closed or the record is not JSON-serialisable.
        """
        self._done[str(key)] = self._write({"kind": UNIT, "key": str(key),
                                            "record": as_json(record, f"record of unit {key!r}")})["record"]

    def note(self, event: dict[str, Any]) -> None:
        """Write one infrastructure event, flushed and fsynced before returning.

        Raises:
            BatchError: the journal is closed or the event is not JSON-serialisable.
        """
        self._events.append(self._write({"kind": EVENT, "event": as_json(event, "an infrastructure event")})["event"])

    def _write(self, entry: dict[str, Any]) -> dict[str, Any]:
        if self._handle is None:
            raise BatchError(f"journal {self.path} is closed")
        entry = {**entry, "segment": self._segment, "elapsed_s": round(time.monotonic() - self._opened, 3)}
        self._handle.write(json.dumps(entry, allow_nan=False) + "\n")
        self._handle.flush()
        os.fsync(self._handle.fileno())
        return entry

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._handle is not None:
            self._handle.close()
            self._handle = None

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def _create(out: Path, header: dict[str, Any]) -> TextIO:
    """Write the header atomically (`pihutil.atomic.write_atomic`: mode per umask, renamed into place), open it
    locked."""
    line = json.dumps({"kind": HEADER, "run": header}, allow_nan=False) + "\n"
    write_atomic(out, lambda handle: handle.write(line))
    handle = open(out, "a", encoding="utf-8")
    try:
        _lock(handle, out)
    except BaseException:
        handle.close()
        raise
    return handle


def _lock(handle: TextIO, path: Path) -> None:
    """Lock the journal ``path`` open as ``handle`` for this run (module docstring).

    Raises:
        BatchError: another run holds it.
    """
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise BatchError(f"journal {path} is in use by another run that is still going: wait for it to end (or stop "
                         "it), or choose another journal") from None


def _read(path: Path) -> _Contents:
    """The contents of a journal, with the bytes up to the end of its last whole line.

    Raises:
        BatchError: unreadable, no header, or a corrupt line before the last one.
    """
    try:
        data = path.read_bytes()
    except OSError as err:
        raise BatchError(f"cannot read journal {path}: {err.strerror or err}") from None
    lines = data.split(b"\n")
    # A file ending in "\n" splits into [..., b""]; anything after the last "\n" is a torn line.
    whole, torn = lines[:-1], lines[-1]
    good_bytes = len(data) - len(torn)
    entries: list[dict[str, Any]] = []
    for number, raw in enumerate(whole, start=1):
        try:
            entry = json.loads(raw.decode("utf-8"))
            if not isinstance(entry, dict):
                raise ValueError("not a JSON object")
        except (UnicodeDecodeError, ValueError) as err:
            if number == len(whole) and not torn:
                good_bytes -= len(raw) + 1  # a torn last line that happens to end in a newline
                break
            raise BatchError(f"{path} line {number} is not a journal line ({err})") from None
        entries.append(entry)
    if not entries or entries[0].get("kind") != HEADER or not isinstance(entries[0].get("run"), dict):
        raise BatchError(f"{path} is not a batch journal (no header line)")
    contents = _Contents(entries[0]["run"], good_bytes=good_bytes)
    for number, entry in enumerate(entries[1:], start=2):
        if entry.get("kind") == UNIT and isinstance(entry.get("key"), str) and isinstance(entry.get("record"), dict):
            contents.done[entry["key"]] = entry["record"]
        elif entry.get("kind") == EVENT and isinstance(entry.get("event"), dict):
            contents.events.append(entry["event"])
        else:
            raise BatchError(f"{path} line {number} is neither a unit nor an event line")
        segment, elapsed = entry.get("segment", 0), entry.get("elapsed_s", 0.0)
        if isinstance(segment, int) and isinstance(elapsed, (int, float)):
            contents.wall_s[segment] = max(contents.wall_s.get(segment, 0.0), float(elapsed))
    return contents
