"""Run the units of a batch (episodes, sweep cells, LASA shapes) so that no fault loses or hangs the batch.

Each unit ends in exactly one record (`batch.supervision`):
  - ``work(context, unit)`` returned it, or
  - ``failure(key, unit, reason)`` made it, with reason "wall_timeout" (the unit ran longer than
    ``unit_timeout_s`` of wall time; its worker is killed) or "error: Type: message" (an exception escaped
    ``work``) -- outcomes of the unit -- or
  - its worker, actor or node was lost on every one of its 1 + max_retries tries: an infrastructure error
    ("infrastructure: worker_died after N tries"), kept in ``infrastructure_errors``, not in the records or
    the journal. A lost try is run again on another or a fresh worker and leaves no trace in the records.
Every record goes through a JSON round trip and into the journal (if any) as soon as it exists, and every
infrastructure event into the outcome and the journal; units the journal already holds are not run again.
Records are returned in the order of ``units`` whatever order they finished in, so the result does not
depend on the number of workers, the backend or the faults survived.

Backends:
  - workers = 1: in this process (the wall-time limit by SIGALRM, main thread only; a unit that kills its
    process kills the batch -- use workers >= 2 for fault isolation);
  - "process": ``workers`` spawned processes (`batch.processes`);
  - "ray": one Ray actor per worker (`batch.ray_backend`), on a local Ray instance (``ray_address`` None) or
    a cluster at HOST:PORT.

Ctrl-C or SIGTERM stops the batch: workers are killed, the journal keeps every finished unit and is
closed, and the outcome says ``interrupted``. A fault that stops the whole batch (the Ray head lost, no
worker able to start) ends it the same way, with the fault's one-line description in ``fault``.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

from batch.config import BatchConfig
from batch.errors import BatchError
from batch.journal import Journal, as_json
from batch.processes import run_in_processes
from batch.ray_backend import run_on_ray
from batch.supervision import Failure, Fault, GroupWork, Init, Schedule, UnitGroup, Work, error_reason, unit_limit_s
from pihutil.interrupts import handling


@dataclass
class BatchOutcome:
    """What a batch produced.

    Attributes:
        records: key -> record in the order of the units (the journal's finished units included).
        complete: every unit has a record.
        interrupted: stopped by Ctrl-C / SIGTERM.
        infrastructure_errors: key -> record of each unit given up after 1 + max_retries lost tries (its
            reason "infrastructure: ..."), in the order of the units; not journalled.
        events: the infrastructure events, the journal's earlier ones first (`batch.supervision`).
        workers: workers (processes or actors) that ran units: at most the workers asked for (with Ray and
            workers=1, the cluster's CPUs); 0 when nothing was left to run.
        fault: the one-line description of a fault that stopped the whole batch, else None.
        events_before: how many of ``events`` the journal held from the earlier parts of the run (they come first):
            a resumed run reports only the others as its own.
    """

    records: dict[str, dict]
    complete: bool
    interrupted: bool
    infrastructure_errors: dict[str, dict] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    workers: int = 0
    fault: str | None = None
    events_before: int = 0


def run_batch(units: Sequence[tuple[str, Any]], setup: Any, init: Init, work: Work, failure: Failure,
              config: BatchConfig = BatchConfig(), journal: Journal | None = None,
              on_record: Callable[[str, dict], None] | None = None, group_size: int = 1,
              work_group: GroupWork | None = None) -> BatchOutcome:
    """Run every unit not yet in ``journal`` and collect one record per unit (module docstring).

    Args:
        units: (key, picklable payload) pairs; keys unique.
        setup: picklable; ``init(setup)`` runs once per worker and returns its context.
        init: module-level function setup -> context.
        work: module-level function (context, unit) -> JSON-able record.
        failure: (key, unit, reason) -> record of a unit that produced none (called in this process).
        config: workers, wall-time limit, retries, backend.
        journal: finished units are skipped and new records appended as they finish.
        on_record: called in this process with (key, record) for each new record.
        group_size: with ``work_group``, the units still to run go to the workers in groups of up to this many
            consecutive units (`batch.supervision.UnitGroup`), and ``work_group(context, [unit, ...])`` returns
            their records in order in one call; each unit keeps its key, record, journal entry and tries.
        work_group: module-level function (context, units) -> list of JSON-able records, one per unit.

    Returns:
        BatchOutcome.

    Raises:
        BatchError: duplicate keys, a record that is not JSON, or ``init`` failing in a worker.
    """
    keys = [str(key) for key, _ in units]
    if len(set(keys)) != len(keys):
        raise BatchError("unit keys must be unique")
    if isinstance(group_size, bool) or not isinstance(group_size, int) or group_size < 1:
        raise BatchError(f"group_size={group_size!r} must be an integer >= 1")
    done = journal.done() if journal is not None else {}
    todo: list[tuple[str, Any]] = [(str(key), unit) for key, unit in units if str(key) not in done]
    if work_group is not None and group_size > 1:
        todo = [(g.key, g) for g in unit_groups(todo, group_size, config.workers)]
        work = _Dispatch(work, work_group)
    found: dict[str, dict] = {k: done[k] for k in keys if k in done}
    lost: dict[str, dict] = {}
    events: list[dict[str, Any]] = journal.events() if journal is not None else []
    events_before = len(events)

    interrupts = _Interrupts()

    def record(key: str, rec: dict) -> None:
        rec = as_json(rec, f"record of unit {key!r}")
        with interrupts.critical():
            if journal is not None:
                journal.append(key, rec)
            found[key] = rec
        if on_record is not None:
            on_record(key, rec)

    def give_up(key: str, rec: dict) -> None:
        lost[key] = as_json(rec, f"record of unit {key!r}")

    def note(event: dict[str, Any]) -> None:
        with interrupts.critical():
            if journal is not None:
                journal.note(event)
            events.append(event)

    schedule = Schedule(todo, failure, config.max_retries, record, give_up, note)
    interrupted, fault = False, None
    try:
        with interrupts.installed():
            if not todo:
                pass
            elif config.backend == "ray":
                run_on_ray(schedule, setup, init, work, config)
            elif config.workers == 1 and not config.isolate:
                _run_here(schedule, setup, init, work, config.unit_timeout_s)
            else:
                run_in_processes(schedule, setup, init, work, config)
    except KeyboardInterrupt:
        interrupted = True
    except Fault as err:
        fault = str(err)
        schedule.note("batch_stopped", {}, fault)
    if journal is not None and (interrupted or fault is not None):
        journal.close()
    records = {k: found[k] for k in keys if k in found}
    return BatchOutcome(records, complete=len(records) == len(keys), interrupted=interrupted,
                        infrastructure_errors={k: lost[k] for k in keys if k in lost}, events=events,
                        workers=schedule.workers, fault=fault, events_before=events_before)


def unit_groups(todo: Sequence[tuple[str, Any]], group_size: int, workers: int) -> list[UnitGroup]:
    """The units in consecutive groups of at most ``group_size``, smaller toward the end (guided scheduling: each
    group at most the units left over twice the workers), so that the last groups the workers take are short and
    none waits long for another's."""
    groups, i = [], 0
    while i < len(todo):
        size = max(1, min(group_size, -(-(len(todo) - i) // (2 * max(1, workers)))))
        groups.append(UnitGroup(tuple(todo[i:i + size])))
        i += size
    return groups


class _Dispatch:
    """The work of a batch with unit groups: a `UnitGroup` to the group work ({member key: record}), any other unit
    to the unit's work. Module-level and holding module-level functions, so it pickles to a spawned worker."""

    def __init__(self, work: Work, work_group: GroupWork):
        self.work, self.work_group = work, work_group

    def __call__(self, context: Any, unit: Any) -> Any:
        if not isinstance(unit, UnitGroup):
            return self.work(context, unit)
        records = self.work_group(context, [member for _, member in unit.members])
        if len(records) != len(unit.members):
            raise BatchError(f"the group work returned {len(records)} records for {len(unit.members)} units")
        return {key: record for (key, _), record in zip(unit.members, records)}


class _Interrupts:
    """Ctrl-C (SIGINT) and SIGTERM raise KeyboardInterrupt while the batch runs, but never inside
    `critical` (where a finished record goes into the journal and the outcome): there the stop waits until
    the record is in both. Installed in the main thread only; the previous handlers are restored after."""

    def __init__(self) -> None:
        self._depth = 0
        self._pending = False

    def installed(self) -> contextlib.AbstractContextManager[None]:
        """The handler for SIGINT and SIGTERM while the batch runs, except over a signal this process was started
        with ignored (`pihutil.interrupts.handling`)."""
        return handling((signal.SIGINT, signal.SIGTERM), self._handle)

    @contextlib.contextmanager
    def critical(self) -> Iterator[None]:
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
        if self._depth == 0 and self._pending:
            self._pending = False
            raise KeyboardInterrupt

    def _handle(self, signum: int, frame: Any) -> None:
        if self._depth:
            self._pending = True
        else:
            raise KeyboardInterrupt


# --------------------------------------------------------------------------------------------- in process


class WallTimeout(BaseException):
    """Raised by SIGALRM inside an in-process unit over its wall-time limit (a BaseException, so the unit's
    own ``except Exception`` does not swallow it)."""


@contextlib.contextmanager
def _alarm(seconds: float | None) -> Iterator[None]:
    """Raise WallTimeout after ``seconds`` of wall time (no-op without a limit or outside the main thread)."""
    if seconds is None or threading.current_thread() is not threading.main_thread():
        yield
        return

    def expire(signum: int, frame: Any) -> None:
        raise WallTimeout

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


def _run_here(schedule: Schedule, setup: Any, init: Init, work: Work, timeout_s: float | None) -> None:
    context = init(setup)
    schedule.worker_ready(0)
    while schedule.remaining:
        key, unit = schedule.take()
        try:
            with _alarm(unit_limit_s(unit, timeout_s)):
                rec = work(context, unit)
        except WallTimeout:
            schedule.timed_out(key, unit)
            continue
        except Exception as err:  # noqa: BLE001 -- work should catch its own; record what escapes
            schedule.finished(key, unit, "error", error_reason(err))
            continue
        schedule.finished(key, unit, "done", rec)
