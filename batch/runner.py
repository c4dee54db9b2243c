"""Run the units of a batch (episodes, sweep cells, LASA shapes) so that no fault loses or hangs the batch.

Each unit ends in exactly one record:
  - ``work(context, unit)`` returned it, or
  - ``failure(key, unit, reason)`` made it, with reason "worker_died" (the worker process exited: SIGKILL,
    segfault, os._exit, out of memory), "wall_timeout" (the unit ran longer than ``unit_timeout_s`` of wall
    time; its worker is killed) or "error: Type: message" (an exception escaped ``work``).
A lost worker is replaced and the batch goes on. Every record goes through a JSON round trip and into the
journal (if any) as soon as it exists; units the journal already holds are not run again. Records are
returned in the order of ``units`` whatever order they finished in, so the result does not depend on the
number of workers or the backend.

Backends:
  - workers = 1: in this process (the wall-time limit by SIGALRM, main thread only; a unit that kills its
    process kills the batch -- use workers >= 2 for fault isolation);
  - "process": ``workers`` spawned processes, each fed one unit at a time over a pipe and watched through
    its sentinel, so a dead worker is seen at once (``multiprocessing.Pool`` would wait forever for it);
  - "ray": one Ray actor per worker (``init`` once per actor), units streamed back with ``ray.wait``, on a
    local Ray instance (``ray_address`` None) or a cluster at HOST:PORT.

Ctrl-C or SIGTERM stops the batch: workers are killed, the journal keeps every finished unit and is
closed, and the outcome says ``interrupted``.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
import threading
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any, Callable, Iterator, Sequence

from batch.errors import BatchError
from batch.journal import Journal, as_json

BACKENDS: tuple[str, ...] = ("process", "ray")
WORKER_DIED = "worker_died"
WALL_TIMEOUT = "wall_timeout"

Init = Callable[[Any], Any]
Work = Callable[[Any, Any], dict]
Failure = Callable[[str, Any, str], dict]


@dataclass(frozen=True)
class BatchConfig:
    """How a batch runs.

    Attributes:
        workers: parallel workers; 1 runs the units in this process, no pool (process backend).
            With the ray backend, the number of actors (1: one per CPU of the Ray cluster).
        unit_timeout_s: wall-clock limit per unit (None: no limit); a unit over it is recorded "wall_timeout".
        backend: "process" (spawned processes supervised here) or "ray".
        ray_address: None: start a local Ray instance on all local cores; else HOST:PORT of a cluster's head.
    """

    workers: int = 1
    unit_timeout_s: float | None = None
    backend: str = "process"
    ray_address: str | None = None

    def __post_init__(self) -> None:
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise BatchError(f"workers={self.workers!r} must be an integer >= 1")
        if self.unit_timeout_s is not None and not (isinstance(self.unit_timeout_s, (int, float))
                                                    and 0.0 < self.unit_timeout_s < float("inf")):
            raise BatchError(f"unit_timeout_s={self.unit_timeout_s!r} must be a positive number of seconds or None")
        if self.backend not in BACKENDS:
            raise BatchError(f"backend={self.backend!r} must be one of {', '.join(BACKENDS)}")
        if self.ray_address is not None:
            host, _, port = self.ray_address.rpartition(":")
            if not host or not port.isdigit() or not 0 < int(port) < 65536:
                raise BatchError(f"ray_address={self.ray_address!r} must be HOST:PORT (e.g. 127.0.0.1:6379)")
            if self.backend != "ray":
                raise BatchError("ray_address is set but the backend is not 'ray'")


@dataclass
class BatchOutcome:
    """What a batch produced.

    Attributes:
        records: key -> record in the order of the units (the journal's finished units included).
        complete: every unit has a record.
        interrupted: stopped by Ctrl-C / SIGTERM.
    """

    records: dict[str, dict]
    complete: bool
    interrupted: bool


def error_reason(err: BaseException) -> str:
    """The failure reason of an exception that escaped ``work``: "error: Type: first line of the message"."""
    message = str(err).splitlines()[0] if str(err) else ""
    return f"error: {type(err).__name__}: {message}"


def run_batch(units: Sequence[tuple[str, Any]], setup: Any, init: Init, work: Work, failure: Failure,
              config: BatchConfig = BatchConfig(), journal: Journal | None = None,
              on_record: Callable[[str, dict], None] | None = None) -> BatchOutcome:
    """Run every unit not yet in ``journal`` and collect one record per unit (module docstring).

    Args:
        units: (key, picklable payload) pairs; keys unique.
        setup: picklable; ``init(setup)`` runs once per worker and returns its context.
        init: module-level function setup -> context.
        work: module-level function (context, unit) -> JSON-able record.
        failure: (key, unit, reason) -> record of a unit that produced none (called in this process).
        config: workers, wall-time limit, backend.
        journal: finished units are skipped and new records appended as they finish.
        on_record: called in this process with (key, record) for each new record.

    Returns:
        BatchOutcome.

    Raises:
        BatchError: duplicate keys, a record that is not JSON, or ``init`` failing in a worker.
    """
    keys = [str(key) for key, _ in units]
    if len(set(keys)) != len(keys):
        raise BatchError("unit keys must be unique")
    done = journal.done() if journal is not None else {}
    todo = [(str(key), unit) for key, unit in units if str(key) not in done]
    found: dict[str, dict] = {k: done[k] for k in keys if k in done}

    interrupts = _Interrupts()

    def record(key: str, rec: dict) -> None:
        rec = as_json(rec, f"record of unit {key!r}")
        with interrupts.critical():
            if journal is not None:
                journal.append(key, rec)
            found[key] = rec
        if on_record is not None:
            on_record(key, rec)

    interrupted = False
    try:
        with interrupts.installed():
            if not todo:
                pass
            elif config.backend == "ray":
                from batch.ray_backend import run_on_ray

                run_on_ray(todo, setup, init, work, failure, config, record)
            elif config.workers == 1:
                _run_here(todo, setup, init, work, failure, config.unit_timeout_s, record)
            else:
                _run_in_processes(todo, setup, init, work, failure, config, record)
    except KeyboardInterrupt:
        interrupted = True
        if journal is not None:
            journal.close()
    records = {k: found[k] for k in keys if k in found}
    return BatchOutcome(records, complete=len(records) == len(keys), interrupted=interrupted)


class _Interrupts:
    """Ctrl-C (SIGINT) and SIGTERM raise KeyboardInterrupt while the batch runs, but never inside
    `critical` (where a finished record goes into the journal and the outcome): there the stop waits until
    the record is in both. Installed in the main thread only; the previous handlers are restored after."""

    def __init__(self) -> None:
        self._depth = 0
        self._pending = False

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        previous = {sig: signal.signal(sig, self._handle) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

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


def _run_here(todo: Sequence[tuple[str, Any]], setup: Any, init: Init, work: Work, failure: Failure,
              timeout_s: float | None, record: Callable[[str, dict], None]) -> None:
    context = init(setup)
    for key, unit in todo:
        try:
            with _alarm(timeout_s):
                rec = work(context, unit)
        except WallTimeout:
            rec = failure(key, unit, WALL_TIMEOUT)
        except Exception as err:  # noqa: BLE001 -- work should catch its own; record what escapes
            rec = failure(key, unit, error_reason(err))
        record(key, rec)


# --------------------------------------------------------------------------------------------- processes


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


def _worker_main(conn: Connection, setup: Any, init: Init, work: Work) -> None:
    """A spawned worker: init once, then answer ("done", key, record) or ("error", key, reason) per unit
    received until None. Ctrl-C is left to the supervisor (which kills the worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        context = init(setup)
    except BaseException as err:  # noqa: BLE001 -- reported to the supervisor, which raises BatchError
        conn.send(("init_error", "", f"{error_reason(err)}\n{traceback.format_exc()}"))
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
    """A spawned worker process, its pipe, the unit it is running (key, unit, start time) and whether it was
    asked to end."""

    process: Any
    conn: Connection
    ready: bool = False
    unit: tuple[str, Any, float] | None = None
    retired: bool = False

    def kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join(5.0)
        self.conn.close()

    def retire(self) -> None:
        """Ask an idle worker to return, so that its exit handlers release what it holds (e.g. the semaphores
        of its locks); its interpreter then takes ~0.8 s to shut down, overlapping whatever still runs."""
        if self.ready and self.unit is None and not self.retired and self.process.is_alive():
            with contextlib.suppress(OSError, ValueError):
                self.conn.send(None)
            self.retired = True


RETIRE_GRACE_S = 2.0
"""How long the workers asked to return may take, together, before they are killed."""


def _stop_all(workers: Sequence[_Worker]) -> None:
    """Retire the idle workers (all at once, so their shutdowns overlap) and kill those that are busy or do not
    end within RETIRE_GRACE_S."""
    for w in workers:
        w.retire()
    deadline = time.monotonic() + RETIRE_GRACE_S
    for w in workers:
        if w.retired:
            w.process.join(max(0.0, deadline - time.monotonic()))
        w.kill()


def _run_in_processes(todo: Sequence[tuple[str, Any]], setup: Any, init: Init, work: Work, failure: Failure,
                      config: BatchConfig, record: Callable[[str, dict], None]) -> None:
    ctx = multiprocessing.get_context("spawn")
    queue = list(reversed(todo))  # pop() from the end: units start in their given order

    def spawn() -> _Worker:
        ours, theirs = ctx.Pipe(duplex=True)
        process = ctx.Process(target=_worker_main, args=(theirs, setup, init, work), daemon=True)
        with _sigint_ignored():  # inherited through exec: a Ctrl-C while the worker starts up does not reach it
            process.start()
        theirs.close()
        return _Worker(process, ours)

    workers: list[Any] = [spawn() for _ in range(min(config.workers, len(todo)))]
    try:
        while queue or any(w.unit is not None for w in workers):
            for w in workers:
                if w.ready and w.unit is None and queue:
                    key, unit = queue.pop()
                    w.unit = (key, unit, time.monotonic())
                    w.conn.send((key, unit))
                elif not queue:
                    w.retire()  # nothing left for it: its shutdown overlaps the units still running
            timeout = None
            if config.unit_timeout_s is not None:
                started = [w.unit[2] for w in workers if w.unit is not None]
                if started:
                    timeout = max(0.0, min(started) + config.unit_timeout_s - time.monotonic())
            ready = set(wait([w.conn for w in workers] + [w.process.sentinel for w in workers], timeout))
            for i, w in enumerate(workers):
                lost: str | None = None
                if w.conn in ready or w.process.sentinel in ready:
                    try:
                        while w.conn.poll():
                            kind, key, payload = w.conn.recv()
                            if kind == "init_error":
                                raise BatchError(f"a worker failed to start: {payload}")
                            if kind == "ready":
                                w.ready = True
                                continue
                            if w.unit is None or w.unit[0] != key:
                                raise BatchError(f"a worker answered for unit {key!r} it was not running")
                            rec = payload if kind == "done" else failure(key, w.unit[1], payload)
                            w.unit = None
                            record(key, rec)
                    except (EOFError, OSError):
                        lost = WORKER_DIED
                    if not w.process.is_alive() and lost is None:
                        lost = WORKER_DIED
                    if lost is not None and not w.ready:
                        code = w.process.exitcode
                        raise BatchError(f"a worker died while starting (exit code {code})")
                if (lost is None and w.unit is not None and config.unit_timeout_s is not None
                        and time.monotonic() - w.unit[2] > config.unit_timeout_s):
                    lost = WALL_TIMEOUT
                if lost is not None:
                    w.kill()
                    if w.unit is not None:
                        key, unit, _ = w.unit
                        record(key, failure(key, unit, lost))
                    workers[i] = spawn() if queue else None
            workers = [w for w in workers if w is not None]
    finally:
        _stop_all(workers)
