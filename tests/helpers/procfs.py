"""A process's workers and a process group's members, read from Linux /proc: for the tests that kill a run from
outside and then check that nothing of it is left."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path


def _processes() -> Iterator[tuple[int, list[str], bytes]]:
    """(pid, the fields of its stat after the command name: state, parent, group, ..., its command line) of every
    process still there when read."""
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                cmdline = (entry / "cmdline").read_bytes()
            except OSError:  # gone meanwhile
                continue
            yield int(entry.name), fields, cmdline


def worker_processes(pid: int) -> list[int]:
    """The worker processes of ``pid``: its children, forked or spawned, less multiprocessing's resource tracker."""
    return [child for child, fields, cmdline in _processes()
            if int(fields[1]) == pid and b"resource_tracker" not in cmdline]


def process_group(pgid: int) -> list[int]:
    """The living processes (not zombies) of process group ``pgid``."""
    return [member for member, fields, _ in _processes() if fields[0] != "Z" and int(fields[2]) == pgid]
