"""The result of an evaluation: its scored episodes, their statistics, the JSON record and the summary table.

Statistics. The success rate p = k/n over the scored episodes with its 95 % Wilson score interval
(envs.statistics.fixed_sample); medians and maxima of the per-episode figures over the finite values; failures counted
by kind. Infrastructure errors (episodes whose every try lost its worker) and a user's policy's errors ("policy_error":
the policy raised, or returned an action that cannot be commanded; not failed insertions) are listed apart, not
scored.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.io.owned_output import write_json
from envs.rollout.episode import EpisodeRecord
from envs.statistics.fixed_sample import wilson_interval
from envs.task.task import Task


def finite_median(values: Iterable[float | None]) -> float | None:
    """Median of the finite values (None when there is none)."""
    kept = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.median(kept)) if kept else None


def finite_max(values: Iterable[float | None]) -> float | None:
    """Largest finite value (None when there is none)."""
    kept = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.max(kept)) if kept else None


def finite_min(values: Iterable[float | None]) -> float | None:
    """Smallest finite value (None when there is none)."""
    kept = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.min(kept)) if kept else None


def failure_kinds(records: Iterable[EpisodeRecord]) -> dict[str, int]:
    """Failed episodes counted by kind: the record's failure kind (envs.rollout.failure: "jammed",
    "free_space_timeout", ...), else (records of the batch runner, older files) the reason up to its first ':' or ' ('
    ("wall_timeout", "infrastructure", ...)."""
    kinds: dict[str, int] = {}
    for r in records:
        if not r.success:
            kind = r.failure or r.reason.split(":")[0].split(" (")[0]
            kinds[kind] = kinds.get(kind, 0) + 1
    return kinds


@dataclass
class EvaluationResult:
    """All episodes of an evaluation and their statistics.

    Attributes:
        records: the scored episodes (the statistics are theirs).
        wall_s: wall time, the earlier parts of a resumed run included.
        infrastructure_errors: episodes whose every try lost its worker (not scored; module docstring).
        infrastructure_events: lost workers, actors, nodes and retried episodes (batch.supervision).
        workers: processes or actors the episodes ran on (0: all were in the journal already).
        fault: what stopped the whole evaluation (e.g. the Ray head lost), else None.
        events_before: how many of ``infrastructure_events`` (the first ones) happened in the earlier parts of a
            resumed evaluation (`new_events` are the others).
        policy: a user policy's spec, options and privilege (`pih evaluate --policy`); None for the skill.
        task: the task the episodes ran: ``config.task`` with the scene it ran in (`Task.with_scene`); None: the
            config's.
        policy_errors: episodes in which a user's policy failed (failure "policy_error": it raised, or returned an
            action that cannot be commanded; `pih evaluate --policy --keep-going`): not failed insertions, so not
            scored -- out of ``records``, the success rate's denominator and the statistics -- and listed apart.
        recorded_episodes: the folder the episodes' traces were recorded into (envs.evaluation.recording), or None.
    """

    config: EvaluationConfig
    records: list[EpisodeRecord]
    wall_s: float
    model_dir: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)
    scene: dict[str, Any] = field(default_factory=dict)
    goal_mismatch_mm: float = 0.0
    complete: bool = True
    interrupted: bool = False
    infrastructure_errors: list[EpisodeRecord] = field(default_factory=list)
    infrastructure_events: list[dict[str, Any]] = field(default_factory=list)
    workers: int = 1
    fault: str | None = None
    policy: dict[str, Any] | None = None
    task: Task | None = None
    events_before: int = 0
    policy_errors: list[EpisodeRecord] = field(default_factory=list)
    recorded_episodes: str | None = None

    @property
    def new_events(self) -> list[dict[str, Any]]:
        """The infrastructure events of this part of the run (a resumed run's earlier ones are not news)."""
        return self.infrastructure_events[self.events_before:]

    @property
    def ran(self) -> Task:
        """The task the episodes ran (``task``, else the config's)."""
        return self.task if self.task is not None else self.config.task

    @property
    def num_success(self) -> int:
        """Episodes that succeeded."""
        return sum(r.success for r in self.records)

    @property
    def success_rate(self) -> float:
        """Successes / scored episodes."""
        return self.num_success / max(len(self.records), 1)

    @property
    def interval(self) -> tuple[float, float]:
        """95 % Wilson interval of the success rate."""
        return wilson_interval(self.num_success, len(self.records))

    def statistics(self) -> dict[str, Any]:
        """Medians / maxima of the per-episode figures and failure counts by kind."""
        ok = [r for r in self.records if r.success]
        kinds = failure_kinds(self.records)
        med, top = finite_median, finite_max

        return {
            "median_time_to_insert_s": med(r.time_to_insert_s for r in ok),
            "max_time_to_insert_s": top(r.time_to_insert_s for r in ok),
            "median_final_pos_error_mm": med(r.final_pos_error_mm for r in self.records),
            "median_final_angle_error_deg": med(r.final_angle_error_deg for r in self.records),
            "median_insertion_depth_mm": med(r.insertion_depth_mm for r in self.records),
            "contact_rate": sum(r.touched for r in self.records) / max(len(self.records), 1),
            "median_peak_contact_force_n": med(r.peak_contact_force_n for r in self.records),
            "max_peak_contact_force_n": top(r.peak_contact_force_n for r in self.records),
            "max_single_contact_n": top(r.peak_single_contact_n for r in self.records),
            "median_peak_wrist_force_n_successes": med(r.peak_wrist_force_n for r in ok),
            "max_peak_wrist_force_n_successes": top(r.peak_wrist_force_n for r in ok),
            "max_sustained_wrist_force_n_successes": top(r.peak_sustained_wrist_force_n for r in ok),
            "median_peak_wrist_force_n": med(r.peak_wrist_force_n for r in self.records),
            "median_peak_wrist_torque_nm": med(r.peak_wrist_torque_nm for r in self.records),
            "min_stiffness_n_m": finite_min(r.min_stiffness_n_m for r in self.records),
            "max_stiffness_n_m": top(r.max_stiffness_n_m for r in self.records),
            "failures_by_kind": kinds,
            "median_episode_wall_s": med(r.wall_s for r in self.records),
        }

    @property
    def stiffness_reproduction(self) -> dict[str, Any] | None:
        """With the learned stiffness: how the skill reproduces the demos' stiffness, from skill.json (written
        by `pih train --stiffness`: mean Log-Euclidean distance of the stiffness generated from each demo's
        start to the demo's, per demo, and how often the eigenvalue clip acted); None otherwise."""
        record = self.metadata.get("stiffness")
        if self.config.stiffness != "learned" or not isinstance(record, dict):
            return None
        keys = ("source", "log_euclidean_mean", "log_euclidean_per_demo", "clip_fraction")
        return {k: record[k] for k in keys if k in record}

    def to_dict(self) -> dict[str, Any]:
        """The JSON record: config (`EvaluationConfig.settings`), the task it ran (`ran`, versioned: envs.task.task),
        success rate with its Wilson interval over the scored episodes, statistics,
        the learned stiffness's reproduction of the demos' (`stiffness_reproduction`), the scored episodes, the
        infrastructure errors and events, the workers that ran and the fault that stopped the run (if any), and for a
        user policy its spec ("policy")."""
        low, high = self.interval
        return {
            "model": self.model_dir,
            "complete": self.complete,
            "interrupted": self.interrupted,
            "config": self.config.settings(),
            "task": self.ran.to_dict(),
            "scene": self.scene,
            "skill": self.metadata,
            "episodes": len(self.records),
            "successes": self.num_success,
            "success_rate": self.success_rate,
            "success_rate_ci95": [low, high],
            "goal_mismatch_mm": self.goal_mismatch_mm,
            "statistics": self.statistics(),
            "stiffness_reproduction": self.stiffness_reproduction,
            "wall_s": self.wall_s,
            "workers": self.workers,
            "fault": self.fault,
            "per_episode": [r.to_dict() for r in self.records],
            "infrastructure_errors": [r.to_dict() for r in self.infrastructure_errors],
            "infrastructure_events": self.infrastructure_events,
            **({} if self.policy is None else {"policy": self.policy,
                                               "policy_errors": [r.to_dict() for r in self.policy_errors]}),
            **({} if self.recorded_episodes is None else {"recorded_episodes": {"folder": self.recorded_episodes}}),
        }

    def save_json(self, path: str | os.PathLike[str]) -> Path:
        """Write ``to_dict`` (envs.io.owned_output.write_json: strict, marked, atomic)."""
        out = Path(path)
        if str(out.parent) and not out.parent.is_dir():
            raise EnvError(f"cannot write {out}: folder {out.parent} does not exist")
        return write_json(out, self.to_dict())

    def summary_table(self) -> str:
        """A short plain-text table of the result (the force limit acts on the force held for its window, so a
        success's single-sample peak may exceed it)."""
        from envs.sim.episode_config import EpisodeConfig

        low, high = self.interval
        s = self.statistics()

        def fmt(v: float | None, unit: str, digits: int = 2) -> str:
            return "-" if v is None else f"{v:.{digits}f} {unit}"

        rows = [
            ("policy", self.policy["spec"]) if self.policy is not None else ("mode", self.config.mode),
            ("episodes", str(len(self.records))),
            ("success rate", f"{100 * self.success_rate:.1f} % ({self.num_success}/{len(self.records)}), "
                             f"95 % CI [{100 * low:.1f}, {100 * high:.1f}] %" if self.records else
                             "none: no episode completed" + (f" ({len(self.infrastructure_errors)} lost to "
                                                              "infrastructure)" if self.infrastructure_errors else "")
                             + (f" ({len(self.policy_errors)} policy errors, not scored)" if self.policy_errors
                                else "")),
            ("time to insert (median/max)", f"{fmt(s['median_time_to_insert_s'], 's')} / {fmt(s['max_time_to_insert_s'], 's')}"),
            ("final position error (median)", fmt(s["median_final_pos_error_mm"], "mm")),
            ("final angle error (median)", fmt(s["median_final_angle_error_deg"], "deg")),
            ("insertion depth (median)", fmt(s["median_insertion_depth_mm"], "mm", 1)),
            ("episodes touching a wall", f"{100 * s['contact_rate']:.0f} % (peak contact force > 1 N)"),
            ("peak contact force (median/max)",
             f"{fmt(s['median_peak_contact_force_n'], 'N', 1)} / {fmt(s['max_peak_contact_force_n'], 'N', 1)}"),
            ("peak wrist force, successes (median/max)",
             f"{fmt(s['median_peak_wrist_force_n_successes'], 'N', 1)} / "
             f"{fmt(s['max_peak_wrist_force_n_successes'], 'N', 1)} (largest single 1 ms reading)"),
            ("force limit", f"{self.ran.force_limit_n:g} N on the wrist force held for "
                            f"{EpisodeConfig().force_limit_window_s * 1e3:g} ms; single-sample peaks may exceed "
                            f"it (held max of successes {fmt(s['max_sustained_wrist_force_n_successes'], 'N', 1)})"),
            ("commanded stiffness", f"{self.config.stiffness or ('the policy' if self.policy else 'controller default')}, eigenvalues "
                                    f"{fmt(s['min_stiffness_n_m'], 'N/m', 0)} to {fmt(s['max_stiffness_n_m'], 'N/m', 0)}"),
            *self._reproduction_rows(),
            ("failures", ", ".join(f"{k}: {v}" for k, v in s["failures_by_kind"].items()) or "none"),
            *self._policy_error_rows(),
            ("infrastructure", self._infrastructure_text()),
            ("wall time", f"{self.wall_s:.1f} s ({self.workers} worker(s))"),
        ]
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)

    def _policy_error_rows(self) -> list[tuple[str, str]]:
        if not self.policy_errors:
            return []
        first = self.policy_errors[0]
        return [("policy errors", f"{len(self.policy_errors)} episode(s), not scored (first: episode {first.index}, "
                                  f"{first.reason.removeprefix('policy_error: ')})")]

    def _infrastructure_text(self) -> str:
        events = self.infrastructure_events
        if not events:
            return "no worker lost"
        lost = sum(e["event"].startswith("worker_lost") for e in events)
        return (f"{lost} worker(s) lost, {sum(e.get('unit_action') == 'retried' for e in events)} episode try(s) "
                f"run again, {len(self.infrastructure_errors)} episode(s) not scored")

    def _reproduction_rows(self) -> list[tuple[str, str]]:
        rec = self.stiffness_reproduction
        if rec is None or "log_euclidean_mean" not in rec:
            return []
        per_demo = ", ".join(f"{d:.3f}" for d in rec.get("log_euclidean_per_demo", []))
        return [("stiffness vs demos (Log-Euclidean)", f"mean {rec['log_euclidean_mean']:.3f} (per demo {per_demo}; "
                                                       f"generated from each demo's start)")]
