"""The Ray backend of `batch.runner.run_batch`: one actor per worker, ``init`` once per actor, units streamed
back with ``ray.wait`` as they finish.

A dead actor (its process killed, a segfault, its node lost) surfaces as RayActorError on the unit's result:
a fresh actor takes its place and the unit runs again (`batch.supervision.Schedule`); an actor lost before
it was ready is replaced up to max_retries times in a row. A unit over the wall-time limit has its actor
killed and is recorded "wall_timeout". Without an address a local Ray instance is started on all local cores
(and shut down after the batch; its processes are watched by a `batch.lifetime.Reaper`, so none outlives this one,
whatever ends it); with HOST:PORT the driver joins that cluster (started with `ray start
--head` / `ray start --address`), whose nodes must have this project installed.

The head. Ray's driver waits 60 s for a lost head (its GCS) and then ends the process with exit status 1 and
no message; ``ray.kill`` and actor creation block meanwhile. So the GCS port is probed with a plain TCP
connection every second (`_HeadWatch`), no Ray call waits longer than a second (Ctrl-C is seen between
them), and a head that has not answered for HEAD_LOST_AFTER_S stops the batch with a one-line `Fault`;
the finished units are in the journal. The driver's shutdown does not wait on the lost head either: its
task-event flush is bounded and it exports no metrics (QUICK_SHUTDOWN_ENV, set while Ray starts).

Ray's own messages. The driver prints the cluster's error messages (e.g. a lost raylet's last 20 log lines)
on stdout from a background thread; while the batch runs they go to stderr, one line each, so stdout keeps
only the program's own output.
"""

from __future__ import annotations

import contextlib
import os
import socket
import sys
import time
from dataclasses import dataclass
from typing import Any, Iterator

from batch.config import BatchConfig
from batch.errors import BatchError
from batch.lifetime import Reaper
from batch.supervision import Fault, Init, Schedule, Work, error_reason, unit_limit_s

POLL_S = 1.0
"""Longest single wait on Ray (Ctrl-C and the head's health are looked at between waits)."""
HEAD_LOST_AFTER_S = 3.0
"""A head whose GCS refuses or ignores connections this long is lost."""
PROBE_TIMEOUT_S = 1.0
QUICK_SHUTDOWN_ENV: dict[str, str] = {
    "RAY_task_events_shutdown_flush_timeout_ms": "1000",
    "RAY_enable_metrics_collection": "0",
}
"""Driver settings (unless already set) that keep its shutdown from waiting 15 s on a lost head."""


class _UnitActor:
    """Holds one worker context; runs units in it."""

    def __init__(self, setup: Any, init: Init, work: Work):
        self._work = work
        self._context = init(setup)

    def ready(self) -> dict[str, Any]:
        """Where this actor runs (for infrastructure events); answers once ``init`` has run, so a unit's
        wall-time clock starts only then."""
        import ray

        context = ray.get_runtime_context()
        return {"actor": context.get_actor_id(), "node": context.get_node_id(), "ip": ray.util.get_node_ip_address(),
                "pid": os.getpid()}

    def run(self, unit: Any) -> tuple[str, Any]:
        """("done", record) or ("error", reason) of one unit."""
        try:
            return "done", self._work(self._context, unit)
        except Exception as err:  # noqa: BLE001 -- work should catch its own; record what escapes
            return "error", error_reason(err)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise BatchError("the ray backend needs Ray: pip install -e '.[cluster]'") from None
    return ray


class _HeadWatch:
    """Whether the Ray head's GCS accepts TCP connections (module docstring)."""

    def __init__(self, address: str):
        host, _, port = address.rpartition(":")
        self.address = address
        self._target = (host, int(port))
        self._failing_since: float | None = None
        self._last_probe = -float("inf")

    @property
    def lost(self) -> bool:
        """The last probe failed."""
        return self._failing_since is not None

    def answers(self) -> bool:
        """Probe now."""
        self._last_probe = time.monotonic()
        try:
            socket.create_connection(self._target, timeout=PROBE_TIMEOUT_S).close()
        except OSError:
            if self._failing_since is None:
                self._failing_since = self._last_probe
            return False
        self._failing_since = None
        return True

    def check(self) -> None:
        """Probe at most once per POLL_S.

        Raises:
            Fault: no answer for HEAD_LOST_AFTER_S.
        """
        if time.monotonic() - self._last_probe >= POLL_S:
            self.answers()
        if self._failing_since is not None and time.monotonic() - self._failing_since >= HEAD_LOST_AFTER_S:
            raise Fault(f"lost the Ray head at {self.address}: its GCS has not answered for "
                        f"{time.monotonic() - self._failing_since:.0f} s")


@contextlib.contextmanager
def _env_defaults(values: dict[str, str]) -> Iterator[None]:
    """``values`` in os.environ (where not set) for the duration."""
    added = [k for k in values if k not in os.environ]
    os.environ.update({k: values[k] for k in added})
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)


@contextlib.contextmanager
def _driver_messages_on_stderr() -> Iterator[None]:
    """Ray's driver prints the cluster's error messages through ``ray._private.worker.print_to_stdstream`` (to
    stdout); for the duration each goes to stderr as its first line. A Ray without that function is left as
    it is."""
    import ray._private.worker as driver

    original = getattr(driver, "print_to_stdstream", None)
    if original is None:
        yield
        return

    def first_line_to_stderr(data: dict[str, Any], ignore_prefix: bool = False) -> None:
        for text in data.get("lines", [])[:1]:
            line = str(text).strip().splitlines()[0] if str(text).strip() else ""
            print(f"ray ({data.get('pid', '?')}): {line[:300]}", file=sys.stderr, flush=True)

    driver.print_to_stdstream = first_line_to_stderr
    try:
        yield
    finally:
        driver.print_to_stdstream = original


def run_on_ray(schedule: Schedule, setup: Any, init: Init, work: Work, config: BatchConfig) -> None:
    """Run the units of ``schedule`` on Ray actors (module docstring).

    Raises:
        BatchError: Ray missing, the cluster unreachable, or ``init`` failing in an actor.
        Fault: the head lost, or no actor able to start.
    """
    ray = _import_ray()
    started_here = not ray.is_initialized()
    local = started_here and config.ray_address is None
    with Reaper() if local else contextlib.nullcontext(), _driver_messages_on_stderr():
        if started_here:
            try:
                with _env_defaults(QUICK_SHUTDOWN_ENV):
                    if config.ray_address is None:
                        ray.init(num_cpus=os.cpu_count() or 1, include_dashboard=False, log_to_driver=False,
                                 configure_logging=False)
                    else:
                        ray.init(address=config.ray_address, log_to_driver=False, configure_logging=False)
            except (ConnectionError, RuntimeError, ValueError) as err:
                where = config.ray_address or "a local instance"
                detail = str(err).splitlines()[0] if str(err) else type(err).__name__
                raise BatchError(f"cannot start Ray on {where}: {detail}") from None
        try:
            _Stream(ray, schedule, setup, init, work, config).run()
        finally:
            if started_here:
                ray.shutdown()


@dataclass
class _Running:
    """A unit on an actor: the actor's slot, the actor, the unit's key and payload, its start time."""

    slot: int
    actor: Any
    key: str
    unit: Any
    start: float


class _Stream:
    """One batch on Ray actors: starting, feeding and replacing them, watching the head."""

    def __init__(self, ray: Any, schedule: Schedule, setup: Any, init: Init, work: Work, config: BatchConfig):
        self.ray = ray
        self.schedule = schedule
        self.config = config
        self.head = _HeadWatch(ray.get_runtime_context().gcs_address)
        sent = {name: os.environ[name] for name in config.worker_environment if name in os.environ}
        options: dict[str, Any] = {"runtime_env": {"env_vars": sent}} if sent else {}
        self.actor_class = ray.remote(num_cpus=1, max_restarts=0, max_task_retries=0, **options)(_UnitActor)
        self.setup_ref = ray.put(setup)
        self.init, self.work = init, work
        self.starting: dict[Any, tuple[int, Any]] = {}  # ready() ref -> (slot, actor): no unit before init ran
        self.running: dict[Any, _Running] = {}  # result ref -> the unit
        self.idle: list[tuple[int, Any]] = []
        self.unstarted: list[int] = []  # slots whose actor waits for the head to answer
        self.where: dict[Any, dict[str, Any]] = {}  # actor -> its ready() answer

    def start(self, slot: int) -> None:
        """A fresh actor in ``slot`` (creating one waits on the head: not while it does not answer)."""
        if not self.head.answers():
            self.unstarted.append(slot)
            return
        actor = self.actor_class.remote(self.setup_ref, self.init, self.work)
        self.starting[actor.ready.remote()] = (slot, actor)

    def run(self) -> None:
        workers = self.config.workers
        if workers == 1:
            workers = max(1, int(self.ray.cluster_resources().get("CPU", 1)))
        for slot in range(min(workers, self.schedule.remaining)):
            self.start(slot)
        try:
            while self.schedule.remaining or self.running:
                self.step()
        finally:
            actors = [a for _, a in self.idle] + [a for _, a in self.starting.values()]
            for actor in actors + [r.actor for r in self.running.values()]:
                self.kill(actor)

    def kill(self, actor: Any) -> None:
        """End an actor (a call to the head: skipped while the head does not answer)."""
        if self.head.lost or not self.head.answers():
            return
        with contextlib.suppress(Exception):  # already dead
            self.ray.kill(actor, no_restart=True)

    def step(self) -> None:
        """Feed the idle actors, wait up to POLL_S for an answer, handle it; check the head and the limits."""
        while self.idle and self.schedule.remaining:
            slot, actor = self.idle.pop()
            key, unit = self.schedule.take()
            self.running[actor.run.remote(unit)] = _Running(slot, actor, key, unit, time.monotonic())
        if self.unstarted and self.head.answers():
            slots, self.unstarted = self.unstarted, []
            for slot in slots:
                self.start(slot)
        if not (self.running or self.starting or self.idle or self.unstarted):
            raise Fault("every Ray worker was lost while starting; no unit can run")
        self.head.check()
        limit = self.config.unit_timeout_s
        timeout = POLL_S
        if limit is not None and self.running:
            first = min(r.start + unit_limit_s(r.unit, limit) for r in self.running.values())
            timeout = min(timeout, max(0.0, first - time.monotonic()))
        refs = list(self.running) + list(self.starting)
        if refs:
            finished, _ = self.ray.wait(refs, num_returns=1, timeout=timeout)
        else:
            time.sleep(timeout)
            finished = []
        for ref in finished:
            if ref in self.starting:
                self.started(ref)
            else:
                self.answered(ref)
        if limit is not None:
            now = time.monotonic()
            for ref in [r for r, run in self.running.items() if now - run.start > unit_limit_s(run.unit, limit)]:
                run = self.running.pop(ref)
                self.kill(run.actor)
                self.schedule.timed_out(run.key, run.unit)
                if self.schedule.remaining:
                    self.start(run.slot)

    def started(self, ref: Any) -> None:
        slot, actor = self.starting.pop(ref)
        try:
            self.where[actor] = self.ray.get(ref)
        except self.ray.exceptions.RayActorError as err:
            if err.actor_init_failed:
                raise BatchError(f"a Ray worker failed to start: {_last_line(err)}") from None
            self.kill(actor)
            if self.schedule.start_lost(slot, {"actor": err.actor_id}, _last_line(err)):
                self.start(slot)
            return
        self.schedule.worker_ready(slot)
        self.idle.append((slot, actor))

    def answered(self, ref: Any) -> None:
        run = self.running.pop(ref)
        try:
            kind, payload = self.ray.get(ref)
        except self.ray.exceptions.RayActorError as err:
            where = self.where.pop(run.actor, {"actor": err.actor_id})
            self.kill(run.actor)  # "unavailable" may come back: it must not hold a CPU then
            if self.schedule.worker_lost((run.key, run.unit), where, _last_line(err)):
                self.start(run.slot)
            return
        self.schedule.finished(run.key, run.unit, kind, payload)
        self.idle.append((run.slot, run.actor))


def _last_line(err: BaseException, limit: int = 200) -> str:
    """The last line of an error's message (Ray's say what happened last), at most ``limit`` characters."""
    text = str(err).strip()
    return text.splitlines()[-1].strip()[:limit] if text else type(err).__name__
