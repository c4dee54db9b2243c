"""A process's workers and a process group's members, read from Linux /proc: for the tests that kill a run from
outside and then check that nothing of it is left."""

from __future__ import annotations

from pathlib import Path


def _stat_fields(entry: Path) -> list[str] | None:
    """The fields of ``entry/stat`` after the command name (state, parent, group, ...); None once the process is
    gone."""
    try:
        return (entry / "stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def worker_processes(pid: int) -> list[int]:
    """The worker processes of ``pid``: its children, forked or spawned, less multiprocessing's resource tracker."""
    kids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat_fields(entry)
            try:
                cmdline = (entry / "cmdline").read_bytes()
            except OSError:
                continue
            if fields is not None and int(fields[1]) == pid and b"resource_tracker" not in cmdline:
                kids.append(int(entry.name))
    return kids


def process_group(pgid: int) -> list[int]:
    """The living processes (not zombies) of process group ``pgid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat_fields(entry)
            if fields is not None and fields[0] != "Z" and int(fields[2]) == pgid:
                found.append(int(entry.name))
    return found
