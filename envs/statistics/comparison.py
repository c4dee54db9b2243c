"""Paired comparison of two evaluations of skills on the same episodes (`pih compare`, `assert_no_regression`).

An evaluation (the JSON of `pih evaluate --json`, its dict, or an EvaluationResult) holds one record per episode.
Two evaluations run with the same --seed, --episodes and start / task options meet the same starts and hole-pose
errors, so their episodes pair up by index (envs.statistics.pairing.pair_records refuses them otherwise).
Compared, pair by pair (the statistics in envs.statistics.fixed_sample):
  * success: rates, the 2x2 table of paired outcomes, McNemar, the paired difference and its interval, the
    non-inferiority decision with a margin, and Barnard's unpaired test for reference;
  * finer per-episode figures (`METRICS`), each a paired difference:
      progress = 1 for a seated episode, else clip(depth reached / target insertion depth, 0, 1), 0 for an
          episode without a measured depth (it never ran: unreachable start, dead worker); higher is better.
          The target depth is the scene's insertion_depth_m of each evaluation; without one, progress is the
          success (1 or 0).
      time_to_seat_s = time to success; a failure counts as T = the larger of the two evaluations' time
          limits, so a failure is never better than a success of either run (a right-censored time set to
          the censoring limit); lower is better.
      held_force_n = peak_sustained_wrist_force_n (the largest wrist force held for the force limit's window);
          episodes without one are left out; lower is better.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from envs.errors import EnvError
from envs.statistics.fixed_sample import (
    DECISIONS,
    MetricComparison,
    SuccessComparison,
    compare_metric,
    compare_success,
)
from envs.statistics.pairing import pair_records

METRICS: dict[str, tuple[str, bool]] = {
    "progress": ("insertion progress (0-1)", True),
    "time_to_seat_s": ("time to seat (s)", False),
    "held_force_n": ("held wrist force (N)", False),
}
"""Finer metric -> (label, higher is better); definitions in the module docstring."""


@dataclass(frozen=True)
class EvaluationSample:
    """What a comparison reads from an evaluation.

    Attributes:
        source: where it came from (a path, or "base" / "candidate" for an object).
        records: the per-episode records (EpisodeRecord.to_dict()).
        time_limit_s: the evaluation's episode time limit.
        target_depth_mm: the scene's insertion depth of a seated peg (None: not recorded).
        task: the task the evaluation ran, as recorded (envs.task.task.Task.to_dict; None: a file of before task files).
    """

    source: str
    records: list[Mapping[str, Any]]
    time_limit_s: float
    target_depth_mm: float | None
    task: Mapping[str, Any] | None = None


def _read_json(path: Path, label: str) -> Any:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise EnvError(f"{label} {path}: file not found") from None
    except (IsADirectoryError, PermissionError, UnicodeDecodeError) as err:
        raise EnvError(f"{label} {path}: cannot read it ({type(err).__name__})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise EnvError(f"{label} {path}: not JSON ({err.msg} at line {err.lineno})") from None


def load_evaluation(source: Any, label: str = "evaluation") -> EvaluationSample:
    """An EvaluationSample from an evaluation JSON path, its dict, or an EvaluationResult (anything with
    ``to_dict``).

    Raises:
        EnvError: a missing or unreadable file, not JSON, or not an evaluation (no per_episode list, no
            task.time_limit_s, or config.time_limit_s in a file of before task files), one line naming ``label`` and
            the source.
    """
    if isinstance(source, (str, os.PathLike)):
        name, data = str(source), _read_json(Path(source), label)
    elif isinstance(source, Mapping):
        name, data = label, source
    elif callable(getattr(source, "to_dict", None)):
        name, data = getattr(source, "model_dir", "") or label, source.to_dict()
    else:
        raise EnvError(f"{label}: expected an evaluation JSON path, dict or EvaluationResult, got {type(source).__name__}")
    where = f"{label} {name}" if name != label else label
    if not isinstance(data, Mapping) or not isinstance(data.get("per_episode"), list):
        raise EnvError(f"{where}: not an evaluation of `pih evaluate --json` (no per_episode list)")
    task, config = data.get("task"), data.get("config")  # the task's time limit; before task files, the config's
    limit = next((values.get("time_limit_s") for values in (task, config) if isinstance(values, Mapping)
                  and "time_limit_s" in values), None)
    if not (isinstance(limit, (int, float)) and math.isfinite(limit) and limit > 0):
        raise EnvError(f"{where}: not an evaluation of `pih evaluate --json` (no task.time_limit_s)")
    scene = data.get("scene") if isinstance(data.get("scene"), Mapping) else {}
    depth = scene.get("insertion_depth_m")
    target = float(depth) * 1e3 if isinstance(depth, (int, float)) and depth > 0 else None
    return EvaluationSample(name, list(data["per_episode"]), float(limit), target,
                            task if isinstance(task, Mapping) else None)


def progress(record: Mapping[str, Any], target_depth_mm: float | None) -> float:
    """Insertion progress of an episode in [0, 1] (module docstring)."""
    if record["success"]:
        return 1.0
    depth = record.get("insertion_depth_mm")
    if target_depth_mm is None or not isinstance(depth, (int, float)) or not math.isfinite(depth):
        return 0.0
    return float(np.clip(depth / target_depth_mm, 0.0, 1.0))


def _time_to_seat(record: Mapping[str, Any], censor_s: float) -> float:
    t = record.get("time_to_insert_s")
    return float(t) if record["success"] and isinstance(t, (int, float)) else censor_s


def _number(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) else math.nan


def metric_values(sample: EvaluationSample, records: Sequence[Mapping[str, Any]], censor_s: float) -> dict[str, np.ndarray]:
    """Each `METRICS` figure of ``records`` (episodes of ``sample``), NaN where missing."""
    return {
        "progress": np.array([progress(r, sample.target_depth_mm) for r in records]),
        "time_to_seat_s": np.array([_time_to_seat(r, censor_s) for r in records]),
        "held_force_n": np.array([_number(r.get("peak_sustained_wrist_force_n")) for r in records]),
    }


def sequential_differences(base: EvaluationSample, candidate: EvaluationSample, base_record: Mapping[str, Any],
                           cand_record: Mapping[str, Any]) -> dict[str, float]:
    """The paired differences in [-1, 1] the sequential test bets on: success s_c - s_b and progress."""
    return {"success": float(cand_record["success"]) - float(base_record["success"]),
            "progress": progress(cand_record, candidate.target_depth_mm) - progress(base_record, base.target_depth_mm)}


@dataclass(frozen=True)
class Comparison:
    """A paired comparison of two evaluations (module docstring), with the tasks they ran as recorded (None: not
    recorded)."""

    base_source: str
    cand_source: str
    success: SuccessComparison
    metrics: dict[str, MetricComparison]
    time_censor_s: float
    base_task: Mapping[str, Any] | None = None
    cand_task: Mapping[str, Any] | None = None

    @property
    def decision(self) -> str:
        """"regression" or "no regression" (of the success rate, with the margin)."""
        return self.success.decision

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record."""
        return {"base": self.base_source, "candidate": self.cand_source, "success": self.success.to_dict(),
                "metrics": {name: m.to_dict() for name, m in self.metrics.items()},
                "time_to_seat_of_a_failure_s": self.time_censor_s, "decision": self.decision,
                "statement": self.statement(), "base_task": self.base_task, "candidate_task": self.cand_task}

    def statement(self) -> str:
        """The decision in words."""
        s = self.success
        low, upper = 100.0 * s.difference_ci[0], 100.0 * s.difference_ci[1]
        bound = f"the {100.0 * (1.0 - s.alpha):g} % upper bound of the difference is {upper:+.1f} points"
        if s.decision == DECISIONS[0]:
            return f"regression: the candidate is worse by more than the margin of {100 * s.margin:g} points ({bound})"
        return (f"no regression shown: {bound}, not below -{100 * s.margin:g} (the interval still allows "
                f"{max(-low, 0.0):.1f} points worse)")

    def message(self) -> str:
        """One paragraph for an assertion: rates, paired counts, difference, p-values, decision."""
        s, c = self.success, self.success.counts
        return (f"{self.statement()}; success {_rate(c.cand_successes, c.pairs)} (candidate {self.cand_source}) vs "
                f"{_rate(c.base_successes, c.pairs)} (base {self.base_source}); paired: both {c.both}, base only "
                f"{c.base_only}, candidate only {c.cand_only}, neither {c.neither}; McNemar exact p = "
                f"{s.mcnemar_p_worse:.3g} (candidate worse), {s.mcnemar_p:.3g} (two-sided)")

    def table(self) -> str:
        """A short plain-text table."""
        s, c = self.success, self.success.counts
        low, high = s.difference_ci
        rows = [
            ("base", self.base_source),
            ("candidate", self.cand_source),
            ("success, base", f"{_rate(c.base_successes, c.pairs)}, 95 % CI {_percent(s.base_ci)}"),
            ("success, candidate", f"{_rate(c.cand_successes, c.pairs)}, 95 % CI {_percent(s.cand_ci)}"),
            (f"paired ({c.pairs} episodes)", f"both {c.both}, base only {c.base_only}, candidate only {c.cand_only}, "
                                             f"neither {c.neither}"),
            ("difference (cand - base)", f"{100 * c.difference:+.1f} points, {100 * (1 - 2 * s.alpha):g} % CI "
                                         f"[{100 * low:+.1f}, {100 * high:+.1f}] (Newcombe, paired)"),
            ("McNemar exact p", f"{s.mcnemar_p_worse:.3g} (candidate worse), {s.mcnemar_p:.3g} (two-sided)"),
            ("unpaired Barnard exact p", f"{s.unpaired_p_worse:.3g} (candidate worse), {s.unpaired_p:.3g} (two-sided)"),
        ]
        for name, m in self.metrics.items():
            label = METRICS[name][0]
            if m.median_difference is None:
                rows.append((label, "no pairs"))
                continue
            ci = "" if m.median_ci is None else f" [{m.median_ci[0]:+.3g}, {m.median_ci[1]:+.3g}]"
            rows.append((label, f"median diff {m.median_difference:+.3g}{ci}, mean {m.mean_difference:+.3g}; "
                                f"better {m.better} / worse {m.worse} / tied {m.tied}; Wilcoxon p "
                                f"{m.wilcoxon_p_worse:.3g} (worse)"))
        rows.append(("decision", self.statement()))
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _rate(k: int, n: int) -> str:
    return f"{100.0 * k / n:.1f} % ({k}/{n})"


def _percent(interval: tuple[float, float]) -> str:
    return f"[{100 * interval[0]:.1f}, {100 * interval[1]:.1f}] %"


def compare_evaluations(base: EvaluationSample, candidate: EvaluationSample, margin: float = 0.0,
                        alpha: float = 0.05, treatment: frozenset[str] = frozenset()) -> Comparison:
    """Pair the two evaluations' episodes and compare them (module docstring); perturbation keys in ``treatment``
    may differ between the pairs (`pair_records`).

    Raises:
        EnvError: the episodes do not pair (pair_records), or margin / alpha out of range.
    """
    base_records, cand_records = pair_records(base.records, candidate.records, treatment=treatment)
    success = compare_success([r["success"] for r in base_records], [r["success"] for r in cand_records],
                              margin, alpha)
    censor = max(base.time_limit_s, candidate.time_limit_s)
    b, c = metric_values(base, base_records, censor), metric_values(candidate, cand_records, censor)
    metrics = {name: compare_metric(b[name], c[name], higher) for name, (_, higher) in METRICS.items()}
    return Comparison(base.source, candidate.source, success, metrics, censor, base.task, candidate.task)


__all__ = [
    "Comparison",
    "EvaluationSample",
    "METRICS",
    "compare_evaluations",
    "load_evaluation",
    "metric_values",
    "progress",
    "sequential_differences",
]
