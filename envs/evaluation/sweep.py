"""Success maps: one skill evaluated over a grid of task settings (clearance x hole-pose error x ...).

The commanded translational stiffness is an axis too ("learned", "constant:K", "schedule"; envs.policies.flow_skill.
StiffnessSetting), so the learned variable stiffness and constant ones run over the same starts and settings.

Every cell of the grid (the Cartesian product of the axes) is an EvaluationConfig derived from a base one;
all cells use the same K start poses and per-episode perturbation draws (common random numbers: the seeds
do not depend on the cell, so cells differ only by their setting). The unit of work is one episode of one
cell, run through `batch.run_batch` (processes or Ray, journal, resume), so a sweep survives dead workers and
Ctrl-C like an evaluation: an episode whose worker is lost runs again, and one lost on every try is an
infrastructure error, left out of its cell's statistics and listed apart (envs.evaluation.evaluate). Per cell: the
success rate with its 95 % Wilson interval, the median time to seat, the median and largest peak wrist force of the
successes, the share of episodes touching a wall, and the failures by kind.
"""

from __future__ import annotations

import itertools
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from typing import Any, Sequence


from envs.errors import EnvError
from envs.evaluation.config import SCENE_FROM_TASK
from envs.evaluation.evaluate import (EvaluationConfig, SlotMaker, SlotPool, _failed_unit, build_setup, run_settings,
                                      skill_file)
from envs.evaluation.starts import metadata_starts
from envs.evaluation.result import failure_kinds, finite_max, finite_median, finite_min
from envs.rollout.episode import StartPose, run_episode
from envs.rollout.episode import record_from_dict
from envs.statistics.fixed_sample import wilson_interval

AXES: tuple[str, ...] = ("clearance_m", "hole_error_m", "chamfer_m", "hole_error_deg", "pos_range_m", "stiffness")
"""Sweepable settings, in the order cells are enumerated (all numbers but "stiffness", a StiffnessSetting text)."""


@dataclass(frozen=True)
class SweepAxes:
    """The values of each swept setting (an empty axis keeps the base config's value).

    Attributes:
        clearance_m, hole_error_m, chamfer_m, hole_error_deg, pos_range_m: values per axis.
        stiffness: commanded stiffness per cell, "learned", "constant:K" (K in N/m) or "schedule[:F/L/A]".
    """

    clearance_m: tuple[float, ...] = ()
    hole_error_m: tuple[float, ...] = ()
    chamfer_m: tuple[float, ...] = ()
    hole_error_deg: tuple[float, ...] = ()
    pos_range_m: tuple[float, ...] = ()
    stiffness: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in AXES:
            values = getattr(self, name)
            if len(set(values)) != len(values):
                raise EnvError(f"sweep axis {name} repeats a value: {list(values)}")

    def active(self) -> list[str]:
        """Axes with at least one value."""
        return [name for name in AXES if getattr(self, name)]


@dataclass(frozen=True)
class Cell:
    """One grid point: its index, its settings (axis -> value) and the evaluation it runs."""

    index: int
    settings: dict[str, float | str]
    config: EvaluationConfig = field(repr=False)


def cell_config(base: EvaluationConfig, settings: dict[str, float | str]) -> EvaluationConfig:
    """``base`` with the cell's settings applied: the stiffness to the config, the others to its task (validated by
    envs.task.task.Task); a swept scene field (clearance, chamfer) replaces the demos'.

    Raises:
        EnvError: an invalid value (negative, NaN, out of range), naming it.
    """
    task = base.task.override(**{k: v for k, v in settings.items() if k != "stiffness"})
    swept = [k for k in SCENE_FROM_TASK if k in settings and k not in base.scene_from_task]
    extra = {"stiffness": settings["stiffness"]} if "stiffness" in settings else {}
    return replace(base, task=task, scene_from_task=(*base.scene_from_task, *swept), **extra)


def sweep_cells(base: EvaluationConfig, axes: SweepAxes) -> list[Cell]:
    """All cells of the grid, the first axis slowest.

    Raises:
        EnvError: no axis given, or an invalid value in some cell.
    """
    names = axes.active()
    if not names:
        raise EnvError("a sweep needs at least one axis with values (e.g. --clearance-mm 1,0.5,0.2)")
    cells = []
    for index, values in enumerate(itertools.product(*(getattr(axes, n) for n in names))):
        settings = {n: v if n == "stiffness" else float(v) for n, v in zip(names, values)}
        cells.append(Cell(index, settings, cell_config(base, settings)))
    return cells


def unit_key(cell: int, episode: int) -> str:
    """Journal key of one episode of one cell."""
    return f"cell{cell}/ep{episode}"


@dataclass(frozen=True)
class SweepSetup:
    """What a worker needs (picklable): the checkpoint and every cell's config."""

    model_dir: str
    configs: tuple[EvaluationConfig, ...]


MAX_CACHED_CELLS: int = 2
"""A worker keeps the environments of this many cells (units arrive cell by cell)."""


def init_sweep_worker(setup: SweepSetup) -> dict[str, Any]:
    """Worker context: a small cache of (env, policy) per cell, built on first use."""
    import torch

    torch.set_num_threads(1)
    return {"setup": setup, "cache": OrderedDict()}


def _cell_slots(context: dict[str, Any], cell: int, slots: int = 1) -> list[tuple[Any, Any]]:
    """``slots`` (env, policy) pairs of ``cell`` (envs.evaluation.evaluate.SlotPool), the pools of the last
    MAX_CACHED_CELLS cells kept."""
    cache: OrderedDict[int, SlotPool] = context["cache"]
    if cell not in cache:
        setup: SweepSetup = context["setup"]
        skill, env, policy = build_setup(setup.model_dir, setup.configs[cell])
        cache[cell] = SlotPool(env, policy, SlotMaker(skill, setup.configs[cell], env))
        while len(cache) > MAX_CACHED_CELLS:
            cache.popitem(last=False)
    cache.move_to_end(cell)
    return cache[cell].take(slots)


def run_sweep_unit(context: dict[str, Any], unit: tuple[int, StartPose]) -> dict[str, Any]:
    """The record (dict) of one episode of one cell, tagged with the cell index."""
    cell, start = unit
    ((env, policy),) = _cell_slots(context, cell)
    gain = context["setup"].configs[cell].feedforward_gain
    record = run_episode(env, policy, start, feedforward_gain=gain)[0].to_dict()
    record["cell"] = cell
    return record


def run_sweep_group(context: dict[str, Any], units: list[tuple[int, StartPose]]) -> list[dict[str, Any]]:
    """The records (dicts) of consecutive episodes, those of each cell run in lockstep (envs.rollout.lockstep) on
    that cell's slots; the same records as `run_sweep_unit` one by one."""
    from envs.rollout.lockstep import run_lockstep

    records: list[dict[str, Any]] = []
    for cell, members in itertools.groupby(units, key=lambda unit: unit[0]):
        starts = [start for _, start in members]
        envs, policies = zip(*_cell_slots(context, cell, len(starts)))
        gain = context["setup"].configs[cell].feedforward_gain
        records += [{**r.to_dict(), "cell": cell} for r in run_lockstep(envs, policies, starts, feedforward_gain=gain)]
    return records


def failed_sweep_unit(key: str, unit: tuple[int, StartPose], reason: str) -> dict[str, Any]:
    """The record of an episode whose worker died or overran."""
    cell, start = unit
    record = _failed_unit(key, start, reason)
    record["cell"] = cell
    return record


def cell_summary(cell: Cell, records: Sequence[dict[str, Any]], task: Any = None) -> dict[str, Any]:
    """Statistics of one cell (module docstring) from its episode records (dicts), with the task it ran (``task``,
    default the cell config's; versioned, envs.task.task)."""
    parsed = [record_from_dict(r) for r in records]
    ok = [r for r in parsed if r.success]
    low, high = wilson_interval(len(ok), len(parsed))
    return {
        "cell": cell.index,
        "settings": cell.settings,
        "task": (cell.config.task if task is None else task).to_dict(),
        "episodes": len(parsed),
        "successes": len(ok),
        "success_rate": len(ok) / max(len(parsed), 1),
        "success_rate_ci95": [low, high],
        "median_time_to_insert_s": finite_median(r.time_to_insert_s for r in ok),
        "median_peak_wrist_force_n": finite_median(r.peak_wrist_force_n for r in ok),
        "max_peak_wrist_force_n": finite_max(r.peak_wrist_force_n for r in ok),
        "median_peak_contact_force_n": finite_median(r.peak_contact_force_n for r in parsed),
        "min_stiffness_n_m": finite_min(r.min_stiffness_n_m for r in parsed),
        "max_stiffness_n_m": finite_max(r.max_stiffness_n_m for r in parsed),
        "contact_rate": sum(r.touched for r in parsed) / max(len(parsed), 1),
        "failures_by_kind": failure_kinds(parsed),
    }


def sweep_run(model_dir: str, cells: Sequence[Cell], checksum: str) -> dict[str, Any]:
    """What identifies a sweep for its journal (every setting that changes a record)."""
    from envs.io.jsonable import to_jsonable

    return to_jsonable({
        "kind": "pih sweep",
        "model": str(model_dir),
        "skill_sha256": checksum,
        "base": run_settings(cells[0].config)["config"],
        "cells": [c.settings for c in cells],
    })


@dataclass
class SweepResult:
    """A finished (or interrupted) sweep: the cells, their statistics and every scored episode record; the
    episodes lost to infrastructure, the infrastructure events and the fault that stopped it (if any) apart;
    the wall time includes the earlier parts of a resumed sweep."""

    model_dir: str
    cells: list[Cell]
    summaries: list[dict[str, Any]]
    """Per cell: statistics and the task it ran, resolved against the demos' scene (`cell_summary`)."""
    records: dict[str, dict[str, Any]]
    complete: bool
    interrupted: bool
    wall_s: float
    infrastructure_errors: dict[str, dict[str, Any]] = field(default_factory=dict)
    infrastructure_events: list[dict[str, Any]] = field(default_factory=list)
    fault: str | None = None
    events_before: int = 0
    """How many of ``infrastructure_events`` (the first) happened in the earlier parts of a resumed sweep."""

    def to_dict(self) -> dict[str, Any]:
        """The JSON record of the sweep (sweep.json)."""
        from envs.io.jsonable import to_jsonable

        base = self.cells[0].config.settings() if self.cells else {}
        return to_jsonable({
            "model": self.model_dir,
            "complete": self.complete,
            "interrupted": self.interrupted,
            "axes": sorted({k for c in self.cells for k in c.settings}, key=AXES.index),
            "base_config": base,  # the task of each cell is in its summary
            "cells": self.summaries,
            "wall_s": self.wall_s,
            "fault": self.fault,
            "per_episode": [self.records[k] for k in sorted(self.records, key=_key_order)],
            "infrastructure_errors": [self.infrastructure_errors[k] for k in sorted(self.infrastructure_errors,
                                                                                     key=_key_order)],
            "infrastructure_events": self.infrastructure_events,
        })


def _key_order(key: str) -> tuple[int, int]:
    cell, episode = key.split("/")
    return int(cell[4:]), int(episode[2:])


def sweep_units(cells: Sequence[Cell], demo_starts: dict[str, Any]) -> list[tuple[str, tuple[int, StartPose]]]:
    """Every (key, (cell, start)) unit; each cell's starts come from its own config (the same seeds in all)."""
    from envs.evaluation.starts import evaluation_starts

    units = []
    for cell in cells:
        for start in evaluation_starts(demo_starts, cell.config):
            units.append((unit_key(cell.index, start.index), (cell.index, start)))
    return units


def sweep(model_dir: str, cells: Sequence[Cell], progress: bool = True, journal: Any = None) -> SweepResult:
    """Run every episode of every cell (module docstring) and summarise each cell.

    Every cell's environment is built once here first, so a setting the scene rejects fails before any work.

    Raises:
        RFlowError / EnvError: bad checkpoint or a cell whose scene cannot be built.
        BatchError: workers that cannot start.
    """
    import time

    from tqdm import tqdm

    from batch import run_batch

    wall = time.perf_counter()
    skill = None
    ran = {}
    for cell in cells:  # validate every cell's scene before any episode runs
        skill, env, _ = build_setup(model_dir, cell.config)
        ran[cell.index] = cell.config.task.with_scene(env.scene.config)
        del env
    meta = metadata_starts(skill.metadata if skill is not None else {}, skill_file(model_dir))
    units = sweep_units(cells, meta)
    done = journal.done() if journal is not None else {}
    bar = tqdm(total=len(units), initial=sum(k in done for k, _ in units), desc="sweep", unit="ep",
               disable=not progress, leave=False)
    setup = SweepSetup(str(model_dir), tuple(c.config for c in cells))
    try:
        outcome = run_batch(units, setup, init_sweep_worker, run_sweep_unit, failed_sweep_unit,
                            cells[0].config.batch_config(), journal, lambda key, record: bar.update(1),
                            group_size=cells[0].config.lockstep, work_group=run_sweep_group)
    finally:
        bar.close()
    by_cell: dict[int, list[dict[str, Any]]] = {c.index: [] for c in cells}
    for key, record in outcome.records.items():
        by_cell[int(record.get("cell", _key_order(key)[0]))].append(record)
    summaries = [cell_summary(c, by_cell[c.index], ran[c.index]) for c in cells]
    earlier_s = journal.earlier_wall_s if journal is not None else 0.0
    return SweepResult(str(model_dir), list(cells), summaries, dict(outcome.records), outcome.complete,
                       outcome.interrupted, earlier_s + time.perf_counter() - wall, outcome.infrastructure_errors,
                       outcome.events, outcome.fault, outcome.events_before)
