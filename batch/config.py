"""How a batch runs: the workers, the wall-time limit per unit, the retries of units lost to infrastructure and
the backend."""

from __future__ import annotations

from dataclasses import dataclass

from batch.errors import BatchError
from pihutil.bounds import TIMEOUT_S, WORKERS

BACKENDS: tuple[str, ...] = ("process", "ray")
START_METHODS: tuple[str, ...] = ("spawn", "fork")
"""How the process backend starts a worker (`BatchConfig.start_method`)."""


@dataclass(frozen=True)
class BatchConfig:
    """How a batch runs.

    Attributes:
        workers: parallel workers; 1 runs the units in this process, no pool (process backend; see ``isolate``).
            With the ray backend, the number of actors (1: one per CPU of the Ray cluster).
        unit_timeout_s: wall-clock limit per unit (None: no limit), in pihutil.bounds.TIMEOUT_S (the timers'
            range); a unit over it is recorded "wall_timeout", an outcome of the unit (batch.supervision).
        max_retries: a unit whose worker, actor or node is lost runs again on another or a fresh worker up to
            this many times; after 1 + max_retries lost tries it is an infrastructure error (not journalled, so
            a resumed run tries it again). A lost worker that was still starting is replaced up to this many
            times in a row.
        backend: "process" (worker processes supervised here) or "ray".
        ray_address: None: start a local Ray instance on all local cores; else HOST:PORT of a cluster's head.
        start_method: how the process backend starts a worker: "spawn", a fresh interpreter that imports what the
            work needs (about 1 s with torch, 2 s with MuJoCo and the compiled kernels), or "fork", a copy of this
            process with all it has imported (milliseconds; Linux only, elsewhere it spawns). Fork only work that
            runs torch on one thread: a forked child that enters a parallel region of its parent's OpenMP pool
            hangs (the evaluation's and the training's workers set one thread first thing).
        start_timeout_s: process backend: a worker not ready this long after it was started (a spawned one stuck
            importing, a forked one stuck on a lock that another thread of this process held at the fork) is
            killed and counts as lost at start, so a start never hangs the batch.
        isolate: process backend: run the units in a supervised worker process even when ``workers`` is 1, so
            that code which may crash the interpreter (a segfault, os._exit: a user's policy) loses one try of a
            unit, never the batch.
        worker_environment: ray backend: names of environment variables every actor starts with, at the values
            they have in this process (Ray's runtime_env; one this process has not set is not sent). A cluster's
            nodes run with the environment they were started with, so settings read once when a process starts
            (the CPU dispatch `numerics.cpu_dispatch` pins) would otherwise hold on this machine only; the process
            backend's workers inherit this process's whole environment.
    """

    workers: int = 1
    unit_timeout_s: float | None = None
    max_retries: int = 2
    backend: str = "process"
    ray_address: str | None = None
    start_method: str = "spawn"
    start_timeout_s: float = 600.0
    isolate: bool = False
    worker_environment: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not WORKERS.contains(self.workers):
            raise BatchError(f"workers={self.workers!r} must be an integer {WORKERS.text()}")
        if self.unit_timeout_s is not None and not TIMEOUT_S.contains(self.unit_timeout_s):
            raise BatchError(f"unit_timeout_s={self.unit_timeout_s!r} must be a number of seconds {TIMEOUT_S.text()} "
                             "(the range of the timers that enforce it) or None")
        if isinstance(self.max_retries, bool) or not isinstance(self.max_retries, int) or self.max_retries < 0:
            raise BatchError(f"max_retries={self.max_retries!r} must be an integer >= 0")
        if self.backend not in BACKENDS:
            raise BatchError(f"backend={self.backend!r} must be one of {', '.join(BACKENDS)}")
        if not TIMEOUT_S.contains(self.start_timeout_s):
            raise BatchError(f"start_timeout_s={self.start_timeout_s!r} must be a number of seconds {TIMEOUT_S.text()}")
        if self.start_method not in START_METHODS:
            raise BatchError(f"start_method={self.start_method!r} must be one of {', '.join(START_METHODS)}")
        names = self.worker_environment
        if not (isinstance(names, tuple) and all(isinstance(n, str) and n and "=" not in n for n in names)):
            raise BatchError(f"worker_environment={names!r} must be a tuple of environment variable names")
        if self.ray_address is not None:
            host, _, port = self.ray_address.rpartition(":")
            if not host or not port.isdigit() or not 0 < int(port) < 65536:
                raise BatchError(f"ray_address={self.ray_address!r} must be HOST:PORT (e.g. 127.0.0.1:6379)")
            if self.backend != "ray":
                raise BatchError("ray_address is set but the backend is not 'ray'")
