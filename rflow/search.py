"""Hyperparameter search of RiemannianFlow on one Riemannian LASA shape with Optuna (the paper's Section V-B).

Space (the paper's Table): coupling layers 8..12, activation ReLU or Tanh, optimizer Adam, Adamax, SGD or
RMSprop, learning rate 1e-5..1e-1 on a log scale; every other hyperparameter is the base TrainConfig's.
Sampler: TPE. Pruner: median (a trial stops when its validation DTW at a report is worse than the median of
earlier trials at the same epoch). The objective is the validation DTW after the last epoch.

Validation DTW (`validation_dtw`) uses held-out starts: each demo's point at VALIDATION_START_FRACTIONS of
its length, never its first point (the benchmark protocol's start). From each, the model generates the rest
of the demo (M - 1 - s steps) and DTW compares it with the demo's remainder in the model's z-scored tangent
space; the value is the mean over starts. The protocol's own numbers (DTW from the first points) are never
computed during a search, so picking the best trial does not look at them.

Storage: any SQLAlchemy URL (SQLite for one machine, PostgreSQL for many); processes that open the same
study name at the same URL share it (`load_if_exists`), each running its own trials.
"""

from __future__ import annotations

import dataclasses
import os
import socket
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from rflow.errors import RFlowError
from rflow.generate import rollout
from rflow.lasa import RiemannianLasa, check_manifold, check_shape, riemannian_lasa
from rflow.metrics import dtw
from rflow.model import RiemannianFlow
from rflow.train import TrainConfig, TrainHistory, fit

VALIDATION_START_FRACTIONS = (0.1, 0.25)  # held-out starts: this far along each demo (never its first point)
_VALIDATION_XI = 1e-9  # rollouts run all their steps (as in the benchmark)


@dataclass(frozen=True)
class SearchSpace:
    """The hyperparameters searched and their ranges (the paper's Table of the rough search).

    Attributes:
        layers: (low, high) coupling layers, integers inclusive.
        activations: activation functions to choose from.
        optimizers: optimizers to choose from.
        lr: (low, high) learning rate, sampled on a log scale.
    """

    layers: tuple[int, int] = (8, 12)
    activations: tuple[str, ...] = ("relu", "tanh")
    optimizers: tuple[str, ...] = ("adam", "adamax", "sgd", "rmsprop")
    lr: tuple[float, float] = (1e-5, 1e-1)

    def __post_init__(self) -> None:
        if not (1 <= self.layers[0] <= self.layers[1] and 0 < self.lr[0] < self.lr[1]):
            raise RFlowError(f"search space: need 1 <= layers low <= high and 0 < lr low < high, got {self}")
        if not (self.activations and self.optimizers):
            raise RFlowError("search space: activations and optimizers must not be empty")


@dataclass(frozen=True)
class SearchConfig:
    """One search: the shape, the manifold, the trials and how they are trained and judged.

    Attributes:
        shape: LASA shape (the paper: NShape).
        manifold: "spd" or "uq".
        trials: trials this process runs (processes sharing a study add theirs).
        base: TrainConfig of every trial before the searched fields are set (its seed seeds every trial).
        space: the search space.
        report_every: epochs between validation DTW reports to the pruner (the last epoch always reports).
        n_points: points per demo (1000: the benchmark's).
        sampler_seed: seed of the TPE sampler (None: random; give processes sharing a study different seeds).
        startup_trials: trials completed before the median pruner starts pruning.
    """

    shape: str = "NShape"
    manifold: str = "spd"
    trials: int = 40
    base: TrainConfig = field(default_factory=TrainConfig)
    space: SearchSpace = field(default_factory=SearchSpace)
    report_every: int = 10
    n_points: int = 1000
    sampler_seed: int | None = 0
    startup_trials: int = 5

    def __post_init__(self) -> None:
        check_shape(self.shape)
        check_manifold(self.manifold)
        if self.trials < 1 or self.report_every < 1 or self.startup_trials < 0:
            raise RFlowError(f"need trials >= 1, report_every >= 1 and startup_trials >= 0, got {self.trials}, "
                             f"{self.report_every}, {self.startup_trials}")


def validation_dtw(model: RiemannianFlow, data: RiemannianLasa,
                   fractions: tuple[float, ...] = VALIDATION_START_FRACTIONS) -> float:
    """Mean DTW of the rest of each demo generated from its held-out starts (module docstring).

    Args:
        model: the (possibly partly trained) model.
        data: the demos.
        fractions: where along each demo the starts lie, each in (0, 1).

    Returns:
        The mean DTW over demos and starts, in the model's z-scored tangent space.

    Raises:
        RFlowError: a fraction outside (0, 1), or a rollout that leaves the manifold.
    """
    m = data.demos.shape[1]
    tangent = np.asarray(model.manifold.log(model.manifold.prepare(data.demos), model.goal))
    demos_z = model.normalisation.apply(tangent)
    values = []
    for fraction in fractions:
        if not 0 < fraction < 1:
            raise RFlowError(f"validation start fraction {fraction} must be in (0, 1)")
        s = int(round(fraction * (m - 1)))
        generated = rollout(model, data.demos[:, s], m - 1 - s, xi=_VALIDATION_XI).points
        gen_z = model.normalisation.apply(np.asarray(model.manifold.log(generated, model.goal)))
        values += [dtw(d[s:], g) for d, g in zip(demos_z, gen_z)]
    return float(np.mean(values))


def trial_config(params: dict[str, Any], base: TrainConfig) -> TrainConfig:
    """The TrainConfig of a trial's parameters {"layers", "activation", "optimizer", "lr"} over ``base``."""
    model = dataclasses.replace(base.model, layers=int(params["layers"]), activation=str(params["activation"]))
    return dataclasses.replace(base, model=model, optimizer=str(params["optimizer"]), lr=float(params["lr"]))


def _import_optuna() -> Any:
    try:
        import optuna
    except ImportError:
        raise RFlowError("the search needs Optuna: pip install -e '.[search]'") from None
    return optuna


def make_objective(config: SearchConfig, data: RiemannianLasa,
                   on_trial: Callable[[str], None] | None = None) -> Callable[[Any], float]:
    """The Optuna objective: sample a config, train, report the validation DTW every ``report_every`` epochs
    (pruning when told), return the validation DTW of the final model."""
    optuna = _import_optuna()
    space = config.space

    def objective(trial: Any) -> float:
        params = {
            "layers": trial.suggest_int("layers", *space.layers),
            "activation": trial.suggest_categorical("activation", list(space.activations)),
            "optimizer": trial.suggest_categorical("optimizer", list(space.optimizers)),
            "lr": trial.suggest_float("lr", *space.lr, log=True),
        }
        train = trial_config(params, config.base)
        trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")  # who ran it, in a shared study
        start = time.perf_counter()

        def report(epoch: int, model: RiemannianFlow, history: TrainHistory) -> None:
            if epoch % config.report_every and epoch != train.epochs:
                return
            value = validation_dtw(model, data)
            trial.report(value, epoch)
            trial.set_user_attr("last_validation_dtw", value)
            if epoch != train.epochs and trial.should_prune():
                if on_trial is not None:
                    on_trial(f"trial {trial.number} pruned at epoch {epoch}: validation DTW {value:.1f} {params}")
                raise optuna.TrialPruned(f"validation DTW {value:.1f} at epoch {epoch}")

        fit(data.demos, data.manifold, data.dt, train, progress=False, on_epoch=report)
        value = float(trial.user_attrs["last_validation_dtw"])
        trial.set_user_attr("train_seconds", time.perf_counter() - start)
        if on_trial is not None:
            on_trial(f"trial {trial.number}: validation DTW {value:.1f} {params} ({time.perf_counter() - start:.0f} s)")
        return value

    return objective


CREATE_ATTEMPTS: int = 5
"""Processes that open a new database at once race to create Optuna's tables (PostgreSQL answers the loser with
a unique violation); the loser looks again, up to this many times."""


CREATED_ELSEWHERE = ("42P07", "42710")
"""PostgreSQL SQLSTATEs of a table or type that another process created first (duplicate_table, duplicate_object)."""


def open_study(storage: str, study_name: str, sampler_seed: int | None = 0, startup_trials: int = 5) -> Any:
    """Create or load the study ``study_name`` at the SQLAlchemy URL ``storage`` (TPE, median pruner, minimise).

    Raises:
        RFlowError: the storage cannot be opened, or the study exists with another direction.
    """
    import time

    from sqlalchemy.exc import IntegrityError, ProgrammingError

    optuna = _import_optuna()
    sampler = optuna.samplers.TPESampler(seed=sampler_seed)
    pruner = optuna.pruners.MedianPruner(n_startup_trials=startup_trials)
    for attempt in range(CREATE_ATTEMPTS):
        try:
            return optuna.create_study(storage=storage, study_name=study_name, sampler=sampler, pruner=pruner,
                                       direction="minimize", load_if_exists=True)
        except (IntegrityError, ProgrammingError) as err:
            # another process created the same tables (PostgreSQL: duplicate table 42P07 or type 42710, a
            # ProgrammingError) or study (a unique violation) a moment earlier: look again
            if isinstance(err, ProgrammingError) and getattr(err.orig, "sqlstate", None) not in CREATED_ELSEWHERE:
                raise RFlowError(f"cannot open storage {storage}: {str(err).strip().splitlines()[0]}") from None
            if attempt == CREATE_ATTEMPTS - 1:
                raise RFlowError(f"study {study_name!r} at {storage}: could not create or load it after "
                                 f"{CREATE_ATTEMPTS} attempts (other processes creating it)") from None
            time.sleep(0.2 * (attempt + 1))
        except ValueError as err:
            raise RFlowError(f"study {study_name!r} at {storage}: {err}") from None
        except Exception as err:  # noqa: BLE001 - SQLAlchemy's errors: unreachable server, bad credentials, ...
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise RFlowError(f"cannot open storage {storage}: {type(err).__name__}: {first}") from None
    raise AssertionError("unreachable")


def run_search(config: SearchConfig, storage: str, study_name: str,
               on_trial: Callable[[str], None] | None = None) -> Any:
    """Run ``config.trials`` trials in the study (failed trainings are recorded as failed trials).

    Returns:
        The Optuna study (all its trials, this process's and others').

    Raises:
        RFlowError: bad data or storage.
    """
    optuna = _import_optuna()
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    data = riemannian_lasa(config.shape, config.manifold, config.n_points)
    study = open_study(storage, study_name, config.sampler_seed, config.startup_trials)
    study.set_user_attr("shape", config.shape)
    study.set_user_attr("manifold", config.manifold)
    study.optimize(make_objective(config, data, on_trial), n_trials=config.trials, catch=(RFlowError,))
    return study


def best_config(study: Any, base: TrainConfig) -> tuple[TrainConfig, float, int]:
    """(TrainConfig, validation DTW, trial number) of the study's best completed trial.

    Raises:
        RFlowError: no trial has completed.
    """
    optuna = _import_optuna()
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    if not done:
        raise RFlowError(f"study {study.study_name!r} has no completed trial (all pruned or failed)")
    best = min(done, key=lambda t: t.value)
    return trial_config(best.params, base), float(best.value), int(best.number)


__all__ = ["SearchConfig", "SearchSpace", "VALIDATION_START_FRACTIONS", "best_config",
           "make_objective", "open_study", "run_search", "trial_config", "validation_dtw"]
