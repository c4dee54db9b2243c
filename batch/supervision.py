"""What the backends of `batch.runner.run_batch` share: the units still to run and their tries, the outcome
of each unit, and the infrastructure events of the batch.

Outcomes and infrastructure. A unit's outcome is what the unit itself did: its record from ``work``, an
exception that escaped ``work`` ("error: Type: message") or a wall time over the limit ("wall_timeout": the
unit is too slow for the limit; a machine slowed by other load can cause it too, so the limit is set with a
wide margin). A lost worker, actor or node is no outcome of the unit: the unit runs again on another or a
fresh worker (units are deterministic from their payload, so its record is the one an undisturbed run
gives). Only after 1 + max_retries lost tries is it an infrastructure error, reason
"infrastructure: worker_died after N tries", kept apart from the records and not journalled, so a resumed
run tries it again. Every loss is an infrastructure event: a JSON object saying what was lost, where (worker
number, pid, exit code; Ray actor, node, ip), what it ran, what became of the unit, and when.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone
import time
from typing import Any, Callable, Sequence

WORKER_DIED = "worker_died"
WALL_TIMEOUT = "wall_timeout"
INFRASTRUCTURE = "infrastructure"

Init = Callable[[Any], Any]
Work = Callable[[Any, Any], dict]
GroupWork = Callable[[Any, list], list]
Failure = Callable[[str, Any, str], dict]


@dataclass(frozen=True)
class UnitGroup:
    """Units run by one call of the batch's group work (`batch.runner.run_batch` with ``group_size``; e.g. episodes
    in lockstep), each keeping its own key and record: the group's answer is {member key: record}. The group's
    wall-time limit is the units' limit times its size; a group over it is split and its members run again one by
    one under the units' own limit, so a unit that hangs is the only one recorded "wall_timeout". A group whose
    worker is lost runs again as a whole, and after its last try each member is an infrastructure error."""

    members: tuple[tuple[str, Any], ...]

    @property
    def key(self) -> str:
        """The group's key in events and tries: its first and last member's."""
        first, last = self.members[0][0], self.members[-1][0]
        return f"group {first}" if first == last else f"group {first}..{last}"


def unit_limit_s(unit: Any, unit_timeout_s: float | None) -> float | None:
    """The wall-time limit of ``unit``: ``unit_timeout_s``, times the members of a `UnitGroup`."""
    if unit_timeout_s is None or not isinstance(unit, UnitGroup):
        return unit_timeout_s
    return unit_timeout_s * len(unit.members)


class Fault(Exception):
    """An infrastructure fault that stops the whole batch (the Ray head lost, no worker able to start); the
    message is one line. `run_batch` puts it in the outcome, whose finished units stay in the journal."""


def error_reason(err: BaseException) -> str:
    """The failure reason of an exception that escaped ``work``: "error: Type: first line of the message"."""
    message = str(err).splitlines()[0] if str(err) else ""
    return f"error: {type(err).__name__}: {message}"


def ended_how(where: dict[str, Any]) -> str:
    """How a lost worker ended, from its event's ``where``: "with exit code 9", "killed by signal 9"."""
    code = where.get("exit_code")
    if not isinstance(code, int):
        return "lost"
    return f"killed by signal {-code}" if code < 0 else f"with exit code {code}"


def infrastructure_reason(tries: int) -> str:
    """The reason of a unit given up after ``tries`` lost tries."""
    return f"{INFRASTRUCTURE}: {WORKER_DIED} after {tries} tries"


def describe_event(event: dict[str, Any]) -> str:
    """One line for a person: what was lost, where, and what became of its unit."""
    where = ", ".join(f"{k} {v}" for k, v in event.get("where", {}).items())
    text = f"{event['event'].replace('_', ' ')}"
    if where:
        text += f" ({where})"
    if event.get("unit") is not None:
        done = "runs again" if event["unit_action"] == "retried" else "is an infrastructure error"
        text += f" running unit {event['unit']}: it {done} ({event['tries']} of {event['max_tries']} tries lost)"
    if event.get("detail"):
        text += f"; {event['detail']}"
    return text


class Schedule:
    """The units of a batch still to run, the tries of each, and the outcome of each try.

    A lost unit goes back to the front of the queue; ``record`` receives outcomes, ``give_up`` the records of
    units lost 1 + max_retries times, ``note`` each infrastructure event (module docstring).
    """

    def __init__(self, todo: Sequence[tuple[str, Any]], failure: Failure, max_retries: int,
                 record: Callable[[str, dict], None], give_up: Callable[[str, dict], None],
                 note: Callable[[dict[str, Any]], None]):
        self._queue = list(reversed(todo))  # pop() from the end: units start in their given order
        self._tries: dict[str, int] = {}
        self._start_losses: dict[int, int] = {}
        self._failure = failure
        self._max_tries = 1 + max_retries
        self._record = record
        self._give_up = give_up
        self._note = note
        self._started = time.monotonic()
        self._ready_slots: set[int] = set()
        self.last_start_loss = ""
        """How the last worker lost while starting ended ("with exit code 9", or the detail given), for messages."""

    @property
    def workers(self) -> int:
        """Workers (slots) that ran: those where a worker got ready."""
        return len(self._ready_slots)

    @property
    def remaining(self) -> int:
        """Units waiting for a worker."""
        return len(self._queue)

    def take(self) -> tuple[str, Any]:
        """The next unit (key, payload) to run; counts a try."""
        key, unit = self._queue.pop()
        self._tries[key] = self._tries.get(key, 0) + 1
        return key, unit

    def finished(self, key: str, unit: Any, kind: str, payload: Any) -> None:
        """A worker answered: ("done", record) or ("error", reason); for a `UnitGroup` ("done", {key: record}) or
        ("error", reason), which is every member's."""
        if not isinstance(unit, UnitGroup):
            self._record(key, payload if kind == "done" else self._failure(key, unit, payload))
            return
        for member_key, member in unit.members:
            if kind == "done" and isinstance(payload, dict) and member_key in payload:
                self._record(member_key, payload[member_key])
            else:
                reason = payload if kind != "done" else f"error: the group's work returned no record of {member_key}"
                self._record(member_key, self._failure(member_key, member, reason))

    def timed_out(self, key: str, unit: Any) -> None:
        """The unit ran over the wall-time limit (its worker is killed): an outcome, "wall_timeout". A group of
        several units is split instead: its members run again one by one (`UnitGroup`)."""
        if isinstance(unit, UnitGroup) and len(unit.members) > 1:
            self._queue.extend(reversed(unit.members))  # next, in their order
            self.note("group_split", {}, f"{key} ran over its wall-time limit; its units run again one by one")
            return
        if isinstance(unit, UnitGroup):
            key, unit = unit.members[0]
        self._record(key, self._failure(key, unit, WALL_TIMEOUT))

    def worker_lost(self, running: tuple[str, Any] | None, where: dict[str, Any], detail: str = "") -> bool:
        """A worker that had started was lost, running ``running`` (key, payload) or idle (None). The unit goes
        back to the queue, or is given up after its last try.

        Returns:
            Whether a fresh worker should take the lost one's place (units are waiting).
        """
        event: dict[str, Any] = {"unit": None}
        if running is not None:
            key, unit = running
            tries = self._tries[key]
            if tries < self._max_tries:
                self._queue.append((key, unit))
                action = "retried"
            else:
                members = unit.members if isinstance(unit, UnitGroup) else ((key, unit),)
                for member_key, member in members:
                    self._give_up(member_key, self._failure(member_key, member, infrastructure_reason(tries)))
                action = "given_up"
            event = {"unit": key, "tries": tries, "max_tries": self._max_tries, "unit_action": action}
        replace = self.remaining > 0
        self.note("worker_lost", where, detail, replaced=replace, **event)
        return replace

    def start_lost(self, slot: int, where: dict[str, Any], detail: str = "") -> bool:
        """A worker was lost before it was ready (e.g. killed while it imported its libraries).

        Returns:
            Whether to start a fresh one in its place: units are waiting and this slot has not lost
            1 + max_retries starts in a row (else the batch goes on with the other workers).
        """
        self._start_losses[slot] = self._start_losses.get(slot, 0) + 1
        self.last_start_loss = detail or ended_how(where)
        replace = self.remaining > 0 and self._start_losses[slot] < self._max_tries
        self.note("worker_lost_at_start", where, detail, replaced=replace,
                  starts_lost=self._start_losses[slot])
        return replace

    def worker_ready(self, slot: int) -> None:
        """A worker of ``slot`` started: its count of lost starts begins again."""
        self._start_losses.pop(slot, None)
        self._ready_slots.add(slot)

    def note(self, what: str, where: dict[str, Any], detail: str = "", **fields: Any) -> None:
        """Record an infrastructure event (module docstring)."""
        self._note({"event": what, "where": where, **fields, "detail": detail,
                    "time": datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
                    "elapsed_s": round(time.monotonic() - self._started, 3)})
