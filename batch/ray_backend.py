"""The Ray backend of `batch.runner.run_batch`: one actor per worker, ``init`` once per actor, units
streamed back with ``ray.wait`` as they finish.

A dead actor (its process killed, a segfault, its node lost) surfaces as RayActorError on the unit's
result and is recorded "worker_died"; a unit over the wall-time limit has its actor killed and is
recorded "wall_timeout"; either way a fresh actor takes the next unit. Without an address a local Ray
instance is started on all local cores (and shut down after the batch); with HOST:PORT the driver joins
that cluster (started with `ray start --head` / `ray start --address`), whose nodes must have this
project installed.
"""

from __future__ import annotations

import os
import time
from typing import Any, Callable, Sequence

from batch.errors import BatchError
from batch.runner import WALL_TIMEOUT, WORKER_DIED, BatchConfig, Failure, Init, Work, error_reason


class _UnitActor:
    """Holds one worker context; runs units in it."""

    def __init__(self, setup: Any, init: Init, work: Work):
        self._work = work
        self._context = init(setup)

    def ready(self) -> bool:
        """Answers once ``init`` has run (a unit's wall-time clock starts only then)."""
        return True

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


def run_on_ray(todo: Sequence[tuple[str, Any]], setup: Any, init: Init, work: Work, failure: Failure,
               config: BatchConfig, record: Callable[[str, dict], None]) -> None:
    """Run ``todo`` on Ray actors, calling ``record(key, record)`` as each unit ends (see module docstring).

    Raises:
        BatchError: Ray missing, the cluster unreachable, or ``init`` failing in an actor.
    """
    ray = _import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        try:
            if config.ray_address is None:
                ray.init(num_cpus=os.cpu_count() or 1, include_dashboard=False, log_to_driver=False,
                         configure_logging=False)
            else:
                ray.init(address=config.ray_address, log_to_driver=False, configure_logging=False)
        except (ConnectionError, RuntimeError, ValueError) as err:
            where = config.ray_address or "a local instance"
            raise BatchError(f"cannot start Ray on {where}: {str(err).splitlines()[0] if str(err) else err}") from None
    try:
        _stream(ray, todo, setup, init, work, failure, config, record)
    finally:
        if started_here:
            ray.shutdown()


def _stream(ray: Any, todo: Sequence[tuple[str, Any]], setup: Any, init: Init, work: Work, failure: Failure,
            config: BatchConfig, record: Callable[[str, dict], None]) -> None:
    actor_class = ray.remote(num_cpus=1, max_restarts=0, max_task_retries=0)(_UnitActor)
    workers = config.workers
    if workers == 1:
        workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
    setup_ref = ray.put(setup)
    queue = list(reversed(todo))
    starting: dict[Any, Any] = {}  # ready() ref -> actor: not given a unit before init has run
    running: dict[Any, tuple[Any, str, Any, float]] = {}  # result ref -> (actor, key, unit, start)
    idle: list[Any] = []

    def start_actor() -> None:
        actor = actor_class.remote(setup_ref, init, work)
        starting[actor.ready.remote()] = actor

    for _ in range(min(workers, len(todo))):
        start_actor()
    try:
        while queue or running:
            while idle and queue:
                actor = idle.pop()
                key, unit = queue.pop()
                running[actor.run.remote(unit)] = (actor, key, unit, time.monotonic())
            timeout = None
            if config.unit_timeout_s is not None and running:
                timeout = max(0.0, min(s for *_, s in running.values()) + config.unit_timeout_s - time.monotonic())
            finished, _ = ray.wait(list(running) + list(starting), num_returns=1, timeout=timeout)
            for ref in finished:
                if ref in starting:
                    actor = starting.pop(ref)
                    try:
                        ray.get(ref)
                    except ray.exceptions.RayActorError as err:
                        detail = str(err).strip().splitlines()[-1] if str(err).strip() else type(err).__name__
                        raise BatchError(f"a Ray worker failed to start: {detail}") from None
                    idle.append(actor)
                    continue
                actor, key, unit, _ = running.pop(ref)
                try:
                    kind, payload = ray.get(ref)
                except ray.exceptions.RayActorError:
                    record(key, failure(key, unit, WORKER_DIED))
                    if queue:
                        start_actor()
                    continue
                record(key, payload if kind == "done" else failure(key, unit, payload))
                idle.append(actor)
            if config.unit_timeout_s is not None:
                now = time.monotonic()
                for ref in [r for r, (*_, s) in running.items() if now - s > config.unit_timeout_s]:
                    actor, key, unit, _ = running.pop(ref)
                    ray.kill(actor, no_restart=True)
                    record(key, failure(key, unit, WALL_TIMEOUT))
                    if queue:
                        start_actor()
    finally:
        for actor in idle + list(starting.values()) + [a for a, *_ in running.values()]:
            try:
                ray.kill(actor, no_restart=True)
            except Exception:  # noqa: BLE001 -- already dead
                pass
