"""Toy units for the batch tests: module-level functions that spawned workers and Ray actors can import.

A unit is {"n": int, "do": "ok" | "kill" | "exit" | "raise" | "sleep" | "kill_first" | "meet" | "note_pid" |
"await_pid" | "environ"}; its record is computed from n and the worker context so that a correct batch gives the same
records on any backend, and whatever worker it runs on. "kill_first" kills its worker on its first ``times``
tries (counted in files beside ``counter``); "meet" returns once ``count`` such units run at the same time
(each leaves a file in ``folder``); a setup with "kill_starts" and "counter" kills that many workers in
``init``, one with "hang_starts" and "counter" hangs that many in ``init`` (tests.helpers.procfs finds a run's
workers, for the tests that kill them from outside).
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any



def init(setup: dict[str, Any]) -> dict[str, Any]:
    """Worker context: the setup's offset (a failing init, or a killed worker, when asked)."""
    if setup.get("fail_init"):
        raise ValueError("init was told to fail")
    if "kill_starts" in setup and count(setup["counter"]) <= setup["kill_starts"]:
        os.kill(os.getpid(), signal.SIGKILL)
    if "hang_starts" in setup and count(setup["counter"]) <= setup["hang_starts"]:
        time.sleep(600.0)
    return {"offset": setup["offset"]}


def count(counter: str) -> int:
    """How many times this was called with ``counter``, this call included (atomic across processes: call
    n creates the file counter.n)."""
    n = 1
    while True:
        try:
            os.close(os.open(f"{counter}.{n}", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            return n
        except FileExistsError:
            n += 1


def work(context: dict[str, Any], unit: dict[str, Any]) -> dict[str, Any]:
    """Record {"n", "value": n^2 + offset}; or kill this process, exit, raise, or sleep first."""
    action = unit.get("do", "ok")
    if action == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
    elif action == "exit":
        os._exit(3)
    elif action == "raise":
        raise ZeroDivisionError("unit asked to raise")
    elif action == "kill_first" and count(unit["counter"]) <= unit.get("times", 1):
        os.kill(os.getpid(), signal.SIGKILL)
    elif action == "meet":
        Path(unit["folder"], str(unit["n"])).touch()
        deadline = time.monotonic() + unit.get("seconds", 60.0)
        while len(list(Path(unit["folder"]).iterdir())) < unit["count"] and time.monotonic() < deadline:
            time.sleep(0.05)
    elif action == "sleep":
        time.sleep(unit.get("seconds", 60.0))
    elif action == "note_pid":  # write this worker's pid, return once the unit "await_pid" runs in another one
        Path(unit["pidfile"]).write_text(str(os.getpid()))
        _wait_for(Path(unit["started"]), unit.get("seconds", 60.0))
    elif action == "await_pid":  # the noted worker's process must end while this unit runs
        Path(unit["started"]).write_text(str(os.getpid()))
        return {"n": unit["n"], "value": _ended(Path(unit["pidfile"]), unit.get("seconds", 60.0)), "reason": "ok",
                "tuple": (1, 2)}
    elif action == "environ":  # what the worker's environment holds for a variable
        return {"n": unit["n"], "value": os.environ.get(unit["name"]), "reason": "ok", "tuple": (1, 2)}
    return {"n": unit["n"], "value": unit["n"] ** 2 + context["offset"], "reason": "ok", "tuple": (1, 2)}


def _wait_for(path: Path, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    while not path.is_file() and time.monotonic() < deadline:
        time.sleep(0.05)


def _ended(pidfile: Path, seconds: float) -> bool:
    """Whether the process whose pid ``pidfile`` holds (once written) ends -- gone or a zombie -- within
    ``seconds`` (Linux /proc)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if pidfile.is_file() and pidfile.read_text():
            stat = Path(f"/proc/{pidfile.read_text()}/stat")
            try:
                if stat.read_text().rsplit(")", 1)[1].split()[0] == "Z":
                    return True
            except (FileNotFoundError, ProcessLookupError):
                return True
        time.sleep(0.05)
    return False


def failure(key: str, unit: dict[str, Any], reason: str) -> dict[str, Any]:
    """Record of a unit that produced none."""
    return {"n": unit["n"], "value": None, "reason": reason, "tuple": None}


def units(n: int, special: dict[int, dict[str, Any]] | None = None) -> list[tuple[str, dict[str, Any]]]:
    """n units keyed "u000".. with ``special`` payload changes by index."""
    return [(f"u{i:03d}", {"n": i, **(special or {}).get(i, {})}) for i in range(n)]


def work_group(context: dict[str, Any], members: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records of a group of units, each as `work` makes it, marked as run in a group of this size."""
    return [{**work(context, unit), "group": len(members)} for unit in members]

