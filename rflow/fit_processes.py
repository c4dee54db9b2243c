"""Train the models of a skill at the same time, one process each (`rflow.train.fit` per model).

The models of a pose skill (position on R^3, orientation on S^3) are independent and each trains on one
torch thread (``TrainConfig.threads``, 1 by default), so on two cores training both in two processes halves
the wall time. Each model is the one `fit` gives in this process -- same seed, data and thread count -- so the
weights are bit-identical to training the models one after the other.

The processes are the batch runner's (`batch.runner.run_batch`, "process" backend; forked where training runs on
one thread, spawned otherwise): a process that dies trains its model again in a fresh one (up to twice), and
neither that nor a Ctrl-C hangs training. Only arrays, configs and loss histories cross the process boundary: a worker
writes its model with `RiemannianFlow.save` into a private temporary directory and this process reads it back
with `RiemannianFlow.load` (torch.load with weights_only=True), so no model object is ever unpickled.
"""

from __future__ import annotations

import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from batch import BatchConfig, BatchError, run_batch
from rflow.errors import RFlowError
from rflow.manifolds import Manifold
from rflow.model import RiemannianFlow
from rflow.train import TrainConfig, TrainHistory, fit

FitJob = tuple[np.ndarray, str | Manifold]
"""(demos, manifold or its name) of one model, as `rflow.train.fit` takes them."""


@dataclass(frozen=True)
class _FitSetup:
    """What every worker shares: sampling time, hyperparameters and the folder models are written to."""

    dt: float
    config: TrainConfig
    scratch: str


def _init(setup: _FitSetup) -> _FitSetup:
    """Worker start: torch on the training's threads before any torch call (a forked worker must not enter its
    parent's OpenMP pool); tqdm gets a thread lock instead of the multiprocessing lock it would make (a semaphore
    that a worker killed on Ctrl-C would leave for the resource tracker to warn about); workers print no
    progress."""
    import threading

    import torch
    from tqdm import tqdm

    if setup.config.threads is not None:
        torch.set_num_threads(setup.config.threads)
    tqdm.set_lock(threading.RLock())
    return setup


def _fit_unit(setup: _FitSetup, unit: tuple[str, np.ndarray, str]) -> dict[str, Any]:
    """Fit one model, save it under the scratch folder, return its history as plain numbers."""
    name, demos, manifold = unit
    model, history = fit(demos, manifold, setup.dt, setup.config, progress=False)
    model.save(Path(setup.scratch) / name)
    return {"history": asdict(history)}


def _start(config: TrainConfig) -> str:
    """Fork the workers when they train on one torch thread (a forked child must not enter its parent's OpenMP
    pool, `batch.BatchConfig.start_method`); this process has imported torch already, so they start at once."""
    return "fork" if config.threads == 1 else "spawn"


def _failure(key: str, unit: Any, reason: str) -> dict[str, Any]:
    return {"failure": reason}


def fit_in_processes(jobs: Mapping[str, FitJob], dt: float, config: TrainConfig, workers: int,
                     progress: bool = True, load: Callable[[Path], RiemannianFlow] = RiemannianFlow.load
                     ) -> dict[str, tuple[RiemannianFlow, TrainHistory]]:
    """Fit every job's model with `rflow.train.fit`, ``workers`` at a time in worker processes.

    Args:
        jobs: model name -> (demos, manifold name).
        dt: sampling time of the demos (s).
        config: hyperparameters shared by the models.
        workers: processes at once (>= 1; 1 fits here, one model after the other).
        progress: print a line when each model is done.
        load: reads a model back from the folder a worker saved it in (a subclass's ``load`` that knows more
            manifolds by name, e.g. `rflow.skill_io.PoseFlow.load`).

    Returns:
        model name -> (model, history), in the order of ``jobs``.

    Raises:
        RFlowError: workers < 1, or a model that failed to train ("<name> model: <reason>", e.g. a diverged
            loss or a worker process that died).
        KeyboardInterrupt: Ctrl-C or SIGTERM (the workers are killed).
    """
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise RFlowError(f"workers={workers!r} must be an integer >= 1")

    def report(name: str, record: dict) -> None:
        if progress and "history" in record:
            history = record["history"]
            print(f"trained the {name} model: {len(history['train_loss'])} epochs, loss "
                  f"{history['train_loss'][-1]:.3f}, {history['seconds']:.1f} s", flush=True)

    with tempfile.TemporaryDirectory(prefix="rflow-fit-") as scratch:
        units = [(name, (name, np.asarray(demos), manifold)) for name, (demos, manifold) in jobs.items()]
        try:
            outcome = run_batch(units, _FitSetup(dt, config, scratch), _init, _fit_unit, _failure,
                                BatchConfig(workers=min(workers, max(1, len(units))), start_method=_start(config)),
                                on_record=report)
        except BatchError as err:  # e.g. a worker that could not start
            raise RFlowError(f"training in processes failed: {err}") from None
        if outcome.interrupted:
            raise KeyboardInterrupt
        if outcome.fault is not None:
            raise RFlowError(f"training in processes failed: {outcome.fault}")
        results: dict[str, tuple[RiemannianFlow, TrainHistory]] = {}
        for name in jobs:
            record = outcome.records.get(name) or outcome.infrastructure_errors[name]
            if "failure" in record:
                reason = record["failure"].removeprefix("error: RFlowError: ")
                raise RFlowError(f"{name} model: {reason}")
            h = record["history"]
            history = TrainHistory([float(x) for x in h["train_loss"]], [float(x) for x in h["val_loss"]],
                                   float(h["seconds"]))
            results[name] = (load(Path(scratch) / name), history)
    return results
