"""The process backend of `batch.runner.run_batch`: ``workers`` processes, each fed one unit at a time
over a pipe and watched through its sentinel, so a dead worker is seen at once (``multiprocessing.Pool``
would wait forever for it), and a worker not ready within ``BatchConfig.start_timeout_s`` is killed.

A worker that dies (SIGKILL, segfault, os._exit, out of memory) is replaced by a fresh one and the unit it
ran goes back to the queue (`batch.supervision.Schedule`); a worker that dies while it starts is replaced
up to max_retries times in a row, after which the batch goes on with the others. A unit over the wall-time
limit has its worker killed and replaced.

A worker is spawned (a fresh interpreter) or, with ``BatchConfig.start_method`` "fork" on Linux, forked: a copy of
this process that needs none of its imports again (what a spawned evaluation worker spends ~2 s on) and that
ends with ``os._exit``, without the ~0.8 s interpreter shutdown.

No worker outlives this process, whatever ends it (`batch.lifetime`): each dies with it (the parent-death
signal), and a forked one holds none of this process's pipe ends, so it would see end-of-file at its next read.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from typing import Any, Callable, Iterator, Sequence

from batch.config import BatchConfig
from batch.errors import BatchError, WorkerInitError
from batch.lifetime import close_inherited, die_with_parent
from batch.supervision import Fault, Init, Schedule, Work, error_reason, unit_limit_s


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored in this process for the duration (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def start_method(config: BatchConfig) -> str:
    """The multiprocessing start method of ``config``: its ``start_method``, except "fork" off Linux ("spawn")."""
    return config.start_method if sys.platform.startswith("linux") else "spawn"


def _worker_main(conn: Connection, setup: Any, init: Init, work: Work, parent: int = 0,
                 inherited: tuple[int, ...] = ()) -> None:
    """A worker: init once, then answer ("done", key, record) or ("error", key, reason) per unit received
    until None. It dies with its supervisor ``parent`` (`batch.lifetime.die_with_parent`; a forked one also closes
    the supervisor's pipe ends it ``inherited``). Ctrl-C is left to the supervisor (which kills the worker); a
    forked worker also drops the supervisor's SIGTERM handler (`batch.runner`), which would raise KeyboardInterrupt
    in the worker."""
    if parent:
        die_with_parent(parent)
    close_inherited(inherited)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        context = init(setup)
    except BaseException as err:  # noqa: BLE001 -- reported to the supervisor, which raises WorkerInitError
        message = str(err).strip()
        conn.send(("init_error", "", (type(err).__name__, message.splitlines()[0] if message else "")))
        return
    conn.send(("ready", "", None))
    while True:
        message = conn.recv()
        if message is None:
            return
        key, unit = message
        try:
            conn.send(("done", key, work(context, unit)))
        except Exception as err:  # noqa: BLE001
            conn.send(("error", key, error_reason(err)))


@dataclass
class _Worker:
    """A worker process: its slot and number (in start order, from 1), its pipe, when it was started (monotonic
    s), the unit it is running (key, unit, start time, wall-time limit or None) and whether it was asked to end."""

    slot: int
    number: int
    process: Any
    conn: Connection
    started: float = field(default_factory=time.monotonic)
    ready: bool = False
    unit: tuple[str, Any, float, float | None] | None = None
    retired: bool = False

    def where(self) -> dict[str, Any]:
        """The worker in an infrastructure event."""
        return {"worker": self.number, "pid": self.process.pid, "exit_code": self.process.exitcode}

    def kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join(5.0)
        self.conn.close()

    def retire(self) -> None:
        """Ask an idle worker to return, so that its exit handlers release what it holds (e.g. the semaphores
        of its locks); a spawned one's interpreter then takes ~0.8 s to shut down, overlapping whatever still
        runs."""
        if self.ready and self.unit is None and not self.retired and self.process.is_alive():
            with contextlib.suppress(OSError, ValueError):
                self.conn.send(None)
            self.retired = True


WAIT_LIMIT_S = 2_147_483.0
"""The longest single wait: poll(2) takes int milliseconds (a longer deadline is waited for in several waits)."""
RETIRE_GRACE_S = 2.0
"""How long the workers asked to return may take, together, before they are killed."""


def _stop_all(workers: Sequence[_Worker]) -> None:
    """Retire the idle workers (all at once, so their shutdowns overlap) and kill those that are busy or do not
    end within RETIRE_GRACE_S (ended ones are only closed)."""
    for w in workers:
        w.retire()
    deadline = time.monotonic() + RETIRE_GRACE_S
    for w in workers:
        if w.retired:
            w.process.join(max(0.0, deadline - time.monotonic()))
        w.kill()


def run_in_processes(schedule: Schedule, setup: Any, init: Init, work: Work, config: BatchConfig) -> None:
    """Run the units of ``schedule`` in worker processes (module docstring).

    Raises:
        BatchError: ``init`` failing in a worker, or a worker answering for a unit it was not running.
        Fault: every worker died while starting, with units left.
    """
    ctx = multiprocessing.get_context(start_method(config))
    spawned: list[_Worker] = []  # all of them, so that none outlives the batch whatever ends it

    def spawn(slot: int) -> _Worker:
        ours, theirs = ctx.Pipe(duplex=True)
        # A forked worker holds copies of every pipe end open here: it closes the supervisor's (module docstring).
        inherited = tuple(w.conn.fileno() for w in spawned if not w.conn.closed) + (ours.fileno(),)
        process = ctx.Process(target=_worker_main, args=(theirs, setup, init, work, os.getpid(),
                                                         inherited if ctx.get_start_method() == "fork" else ()),
                              daemon=True)
        with _sigint_ignored():  # inherited (through exec too): a Ctrl-C while the worker starts does not reach it
            process.start()
        theirs.close()
        spawned.append(_Worker(slot, len(spawned) + 1, process, ours))
        return spawned[-1]

    workers = [spawn(slot) for slot in range(min(config.workers, schedule.remaining))]
    try:
        while schedule.remaining or any(w.unit is not None for w in workers):
            if not workers:
                raise Fault(f"every worker died while starting ({len(spawned)} starts, the last "
                            f"{schedule.last_start_loss}); no unit can run")
            for w in workers:
                if w.ready and not w.retired and w.unit is None and schedule.remaining:
                    key, unit = schedule.take()
                    w.unit = (key, unit, time.monotonic(), unit_limit_s(unit, config.unit_timeout_s))
                    w.conn.send((key, unit))
                elif not schedule.remaining:
                    w.retire()  # nothing left for it: its shutdown overlaps the units still running
            _wait_for_any(workers, config)
            workers = [kept for w in workers for kept in _serve(w, schedule, config, spawn)]
    finally:
        _stop_all(spawned)


def _wait_for_any(workers: Sequence[_Worker], config: BatchConfig) -> None:
    """Wait until a worker answers or ends, a running unit reaches its wall-time limit or a starting worker its
    start limit, whichever comes first."""
    deadlines = [w.unit[2] + w.unit[3] for w in workers if w.unit is not None and w.unit[3] is not None]
    deadlines += [w.started + config.start_timeout_s for w in workers if not w.ready]
    timeout = min(max(0.0, min(deadlines) - time.monotonic()), WAIT_LIMIT_S) if deadlines else None
    wait([w.conn for w in workers] + [w.process.sentinel for w in workers], timeout)


def _serve(w: _Worker, schedule: Schedule, config: BatchConfig, spawn: Callable[[int], _Worker]) -> list[_Worker]:
    """Read ``w``'s answers and check its health; returns what takes its place: itself, a fresh worker, or
    nothing (a retired worker that ended, a lost one with no work left, a slot that gave up starting)."""
    died = False
    try:
        while w.conn.poll():
            kind, key, payload = w.conn.recv()
            if kind == "init_error":
                raise WorkerInitError(*payload)
            if kind == "ready":
                w.ready = True
                schedule.worker_ready(w.slot)
                continue
            if w.unit is None or w.unit[0] != key:
                raise BatchError(f"a worker answered for unit {key!r} it was not running")
            unit = w.unit[1]
            w.unit = None
            schedule.finished(key, unit, kind, payload)
    except (EOFError, OSError):
        died = True
    died = died or not w.process.is_alive()
    if died:
        w.kill()
        if w.retired and w.unit is None:
            return [spawn(w.slot)] if schedule.remaining else []
        if not w.ready:
            return [spawn(w.slot)] if schedule.start_lost(w.slot, w.where()) else []
        running = None if w.unit is None else w.unit[:2]
        return [spawn(w.slot)] if schedule.worker_lost(running, w.where()) else []
    if not w.ready and time.monotonic() - w.started > config.start_timeout_s:
        w.kill()
        detail = f"not ready {config.start_timeout_s:g} s after it was started"
        return [spawn(w.slot)] if schedule.start_lost(w.slot, w.where(), detail) else []
    if w.unit is not None and w.unit[3] is not None and time.monotonic() - w.unit[2] > w.unit[3]:
        w.kill()
        schedule.timed_out(*w.unit[:2])
        return [spawn(w.slot)] if schedule.remaining else []
    return [w]
