"""What each imperfection of a real cell costs a skill: each alone, paired with the ideal cell on the same episodes.

`IMPERFECTIONS` names the cell's imperfections (envs.task.perturbation, envs.task.sensor_config) at the magnitudes of
the "realistic" task preset (envs/task/presets/realistic.toml combines them all; a test keeps the two equal).
`run_sensitivity` evaluates the skill on the base task (default: the "contact" preset, the ideal cell) and on the base
task with one imperfection set, with the same seed and episodes: the imperfections are drawn from a generator of their
own, so every variant meets the same starts and hole-pose errors as the base, and its episodes pair with the base's
(envs.statistics.comparison: McNemar, the paired difference of success, the paired time to seat and held force).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.statistics.comparison import Comparison, compare_evaluations, load_evaluation
from envs.task.task import Task

IMPERFECTIONS: dict[str, dict[str, Any]] = {
    "friction": {"hole_friction_min": 0.3, "hole_friction_max": 0.8, "pad_friction_min": 0.6,
                 "pad_friction_max": 1.0},
    "compliant_pads": {"pad_stiffness_nm_rad": 67.4},
    "in_hand_pose": {"grasp_lateral_m": 0.001, "grasp_tilt_deg": 1.0, "grasp_yaw_deg": 1.0},
    "grasp_offset": {"grasp_offset_m": 0.003},
    "payload": {"payload_mass_error": 0.2, "payload_com_error_m": 0.002},
    "joint_friction": {"joint_friction_scale_min": 1.0, "joint_friction_scale_max": 1.0,
                       "joint_friction_model": "stick_slip"},
    "torque_noise": {"actuator_noise_nm": 0.05},
    "hole_observation": {"hole_observation_error_m": 0.001, "hole_observation_error_deg": 1.0},
    "joint_torque_sensing": {"sensor_mode": "joint_torque", "joint_torque_noise_nm": 0.005,
                             "joint_torque_bias_nm": 0.15, "sensor_cutoff_hz": 100.0},
}
"""Imperfection -> the task fields that set it (Task.override names), at the realistic preset's magnitudes. The
wrench is sensed as a stock Panda senses it, from its joint torque sensors."""

ALTERNATIVES: dict[str, dict[str, Any]] = {
    "wrist_sensor": {"sensor_mode": "wrist", "force_noise_n": 0.1, "torque_noise_nm": 0.005, "force_bias_n": 0.5,
                     "torque_bias_nm": 0.02, "sensor_cutoff_hz": 100.0},
}
"""Variants measured alone but not part of the realistic cell (nor of "all"): a wrist F/T sensor instead of the
joint torque sensing (one cell has one or the other)."""


@dataclass(frozen=True)
class Curve:
    """An imperfection swept over its magnitude: the x axis's label, the magnitudes, and the task fields that set one
    magnitude (each point a variant paired with the ideal cell, as the single imperfections are)."""

    label: str
    points: tuple[float, ...]
    fields: Callable[[float], dict[str, Any]]


_LARGEST_COULOMB_NM = 0.3591
"""The identified Coulomb friction of the Panda's joint 4, the largest of the seven (envs.sim.joint_friction)."""

CURVES: dict[str, Curve] = {
    "joint_friction": Curve(
        "largest joint Coulomb friction, stick-slip (N m; identified: 0.36)", (0.1, 0.2, 0.3, 0.4),
        lambda x: {"joint_friction_scale_min": x / _LARGEST_COULOMB_NM,
                   "joint_friction_scale_max": x / _LARGEST_COULOMB_NM, "joint_friction_model": "stick_slip"}),
    "in_hand_tilt": Curve("in-hand tilt about the closing axis, up to (deg)", (0.5, 1.0, 1.5, 2.0),
                          lambda x: {"grasp_tilt_deg": x}),
    "sensor_noise": Curve("joint torque sensors' noise per reading (N m, sd; datasheet: 0.005)",
                          (0.005, 0.02, 0.05, 0.1),
                          lambda x: {"sensor_mode": "joint_torque", "sensor_cutoff_hz": 100.0,
                                     "joint_torque_noise_nm": x}),
    "sensor_bias": Curve("joint torque sensors' bias per episode (N m, sd; datasheet: 0.15)", (0.15, 0.3, 0.6, 1.0),
                         lambda x: {"sensor_mode": "joint_torque", "sensor_cutoff_hz": 100.0,
                                    "joint_torque_bias_nm": x}),
    "in_hand_lateral": Curve("in-hand shift in the pads' plane, up to (mm)", (0.5, 1.0, 1.5, 2.0),
                             lambda x: {"grasp_lateral_m": x / 1e3}),
    "in_hand_yaw": Curve("in-hand turn about the peg's axis, up to (deg)", (0.5, 1.0, 1.5, 2.0),
                         lambda x: {"grasp_yaw_deg": x}),
    "torque_noise": Curve("joints' torque noise (N m, sd)", (0.05, 0.1, 0.2, 0.4),
                          lambda x: {"actuator_noise_nm": x}),
    "payload": Curve("payload mass error, up to (fraction; centre of mass 10 mm per 1)", (0.1, 0.2, 0.4, 0.5),
                     lambda x: {"payload_mass_error": x, "payload_com_error_m": 0.01 * x}),
    "part_friction": Curve("peg-sorter friction, up to (pads 0.2 above)", (0.4, 0.8, 1.2, 1.6),
                           lambda x: {"hole_friction_min": 0.5 * x, "hole_friction_max": x,
                                      "pad_friction_min": 0.5 * x + 0.2, "pad_friction_max": x + 0.2}),
}
"""The sensitivity curves (`pih sensitivity --curves`): the issue's four (joint friction, in-hand tilt, the joint torque
sensors' noise and bias) and one per assumption of the realistic preset (docs/tasks.md), each alone on the ideal
cell, its largest point at or above twice the realistic preset's magnitude."""
CURVE_SEPARATOR = "@"
"""A curve point's variant is named CURVE@X (its magnitude)."""


def curve_variants(config: EvaluationConfig, names: Sequence[str]) -> list[tuple[str, dict[str, Any], Task]]:
    """(name, task fields, task) of every point of the curves ``names`` (CURVES), each on ``config.task``.

    Raises:
        EnvError: an unknown curve.
    """
    found = []
    for name in names:
        curve = CURVES.get(name)
        if curve is None:
            raise EnvError(f"unknown sensitivity curve {name!r}; choose from {', '.join(CURVES)}")
        for x in curve.points:
            fields = curve.fields(x)
            found.append((f"{name}{CURVE_SEPARATOR}{x:g}", fields, config.task.override(**fields)))
    return found


TREATMENT: frozenset[str] = frozenset({"grasp_offset_mm"})
"""Perturbation keys an imperfection changes that the ideal cell records too (the grasp offset, 0 there): a variant's
pairs may differ in them (the other imperfections' keys are recorded only where set, envs.statistics.pairing)."""


def with_imperfection(task: Task, name: str) -> Task:
    """``task`` with the imperfection ``name`` of IMPERFECTIONS set.

    Raises:
        EnvError: an unknown name.
    """
    return task.override(**imperfection_settings(name))


def imperfection_settings(name: str) -> dict[str, Any]:
    """The task fields of the imperfection ``name`` (IMPERFECTIONS or ALTERNATIVES; a copy).

    Raises:
        EnvError: an unknown name.
    """
    settings = IMPERFECTIONS.get(name, ALTERNATIVES.get(name))
    if settings is None:
        raise EnvError(f"unknown imperfection {name!r}; choose from {', '.join([*IMPERFECTIONS, *ALTERNATIVES])}")
    return dict(settings)


def realistic(task: Task) -> Task:
    """``task`` with every imperfection of IMPERFECTIONS set (what the "realistic" preset is of "contact")."""
    for name in IMPERFECTIONS:
        task = with_imperfection(task, name)
    return task


@dataclass(frozen=True)
class SensitivityRow:
    """One variant against the base, paired (module docstring).

    Attributes:
        name: the imperfection ("ideal" for the base itself, "all" for every imperfection at once).
        settings: the task fields it sets.
        successes, episodes: seated episodes of the variant.
        median_time_s: median time to seat of its successes (None without one).
        median_peak_force_n, median_held_force_n: medians over its episodes of the peak and the held (sustained
            for the force limit's window) wrist force.
        failures: its failures by kind (envs.rollout.failure).
        comparison: the paired comparison with the base (None for the base's own row).
    """

    name: str
    settings: Mapping[str, Any]
    successes: int
    episodes: int
    median_time_s: float | None
    median_peak_force_n: float | None
    median_held_force_n: float | None
    failures: Mapping[str, int]
    comparison: Comparison | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record."""
        return {"name": self.name, "settings": dict(self.settings), "successes": self.successes,
                "episodes": self.episodes, "median_time_to_seat_s": self.median_time_s,
                "median_peak_wrist_force_n": self.median_peak_force_n,
                "median_held_wrist_force_n": self.median_held_force_n, "failures": dict(self.failures),
                "paired_with_ideal": None if self.comparison is None else self.comparison.to_dict()}


def _row(name: str, settings: Mapping[str, Any], result: Any, comparison: Comparison | None) -> SensitivityRow:
    from envs.evaluation.result import failure_kinds, finite_median

    records = result.records
    return SensitivityRow(
        name, settings, sum(int(r.success) for r in records), len(records),
        finite_median(r.time_to_insert_s for r in records if r.success),
        finite_median(r.peak_wrist_force_n for r in records),
        finite_median(r.peak_sustained_wrist_force_n for r in records),
        failure_kinds(records), comparison)


class Stopped(Exception):
    """A variant's evaluation did not finish (Ctrl-C or SIGTERM, a fault that stopped its batch, episodes lost to
    infrastructure): ``name`` and its ``result``; the variants before it finished, and every finished episode is in
    its journal (`run_sensitivity`'s ``journal``), so the same run continues from there."""

    def __init__(self, name: str, result: Any):
        super().__init__(f"variant {name!r} did not finish")
        self.name, self.result = name, result


def variants(config: EvaluationConfig, names: Sequence[str],
             curves: Sequence[str] = ()) -> list[tuple[str, dict[str, Any], Task]]:
    """(name, task fields it sets, task) of every variant `run_sensitivity` runs, in its order: "ideal", each of
    ``names``, then "all" when more than one of IMPERFECTIONS is among them, then the points of ``curves``.

    Raises:
        EnvError: an unknown imperfection or curve.
    """
    found: list[tuple[str, dict[str, Any], Task]] = [("ideal", {}, config.task)]
    for name in names:
        found.append((name, imperfection_settings(name), with_imperfection(config.task, name)))
    cell = [name for name in names if name in IMPERFECTIONS]
    if len(cell) > 1:
        combined = {k: v for name in cell for k, v in IMPERFECTIONS[name].items()}
        found.append(("all", combined, config.task.override(**combined)))
    return found + curve_variants(config, curves)


def run_sensitivity(model_dir: str | os.PathLike[str], config: EvaluationConfig, names: Sequence[str],
                    evaluate: Callable[..., Any] | None = None,
                    on_variant: Callable[[str], None] | None = None,
                    journal: Callable[[str, EvaluationConfig], Any] | None = None,
                    curves: Sequence[str] = ()) -> list[SensitivityRow]:
    """Evaluate the skill on ``config.task`` (the ideal row), on it with each imperfection of ``names`` alone and,
    with more than one of IMPERFECTIONS, with those at once ("all"; ALTERNATIVES only alone); every variant on the
    same seed and episodes, paired with the ideal row.

    Args:
        model_dir: a `pih train` checkpoint.
        config: the evaluation of the ideal cell (its task is the base).
        names: imperfections of IMPERFECTIONS or ALTERNATIVES.
        evaluate: the evaluation function (default envs.evaluation.evaluate.evaluate).
        on_variant: called with each variant's name before it runs (progress).
        journal: called with a variant's name and evaluation, returns the `batch.Journal` its episodes go into (and
            are taken from, when it holds some already), used as a context manager around the variant; None: none.
        curves: sensitivity curves of CURVES, each point a variant after the imperfections (`curve_variants`).

    Raises:
        Stopped: a variant's evaluation did not finish (the rows before it did).
        EnvError: an unknown imperfection, episodes that do not pair (they always do: a bug), or an evaluation's
            own errors. RFlowError: a missing or corrupt checkpoint.
    """
    if evaluate is None:
        from envs.evaluation.evaluate import evaluate
    rows: list[SensitivityRow] = []
    base_sample = None
    for name, settings, task in variants(config, names, curves):
        if on_variant is not None:
            on_variant(name)
        variant = replace(config, task=task)
        if journal is None:
            result = evaluate(model_dir, variant, progress=False)
        else:
            with journal(name, variant) as log:
                result = evaluate(model_dir, variant, progress=False, journal=log)
        if result.interrupted or result.fault is not None or not result.complete:
            raise Stopped(name, result)
        sample = load_evaluation(result.to_dict(), name)
        comparison = None if base_sample is None else compare_evaluations(base_sample, sample, treatment=TREATMENT)
        base_sample = sample if base_sample is None else base_sample
        rows.append(_row(name, settings, result, comparison))
    return rows


def sensitivity_table(rows: Sequence[SensitivityRow]) -> str:
    """A Markdown table: success, the paired difference to the ideal cell with its 95 % interval and McNemar's p,
    medians of time to seat, peak and held wrist force, and the failures by kind."""
    head = ("| imperfection | seated | vs ideal (paired, 95 % CI) | McNemar p | fixed / lost | time to seat (s) | "
            "peak force (N) | held force (N) | failures |")
    lines = [head, "|" + " --- |" * 9]

    def number(value: float | None, digits: int = 2) -> str:
        return "-" if value is None else f"{value:.{digits}f}"

    for row in rows:
        rate = f"{row.successes}/{row.episodes} ({100.0 * row.successes / max(row.episodes, 1):.1f} %)"
        if row.comparison is None:
            paired, p, moved = "-", "-", "-"
        else:
            s = row.comparison.success
            low, high = s.difference_ci
            paired = f"{100 * s.counts.difference:+.1f} [{100 * low:+.1f}, {100 * high:+.1f}] points"
            p, moved = f"{s.mcnemar_p:.3g}", f"{s.counts.cand_only} / {s.counts.base_only}"
        failures = ", ".join(f"{k} {v}" for k, v in row.failures.items()) or "none"
        lines.append(f"| {row.name} | {rate} | {paired} | {p} | {moved} | {number(row.median_time_s)} | "
                     f"{number(row.median_peak_force_n, 1)} | {number(row.median_held_force_n, 1)} | {failures} |")
    return "\n".join(lines)


def plot_curves(rows: Sequence[SensitivityRow], folder: str | os.PathLike[str]) -> list[Path]:
    """One figure per curve among ``rows`` (CURVE@X rows), ``folder``/curve_CURVE.png: the success rate against the
    magnitude with Wilson 95 % intervals, the ideal cell's rate as a line, and the points whose paired difference to
    the ideal cell excludes 0 (Newcombe 95 %) marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from envs.io.owned_output import save_figure
    from envs.statistics.fixed_sample import wilson_interval

    ideal = rows[0]
    written = []
    for name, curve in CURVES.items():
        points = [r for r in rows if r.name.split(CURVE_SEPARATOR)[0] == name and CURVE_SEPARATOR in r.name]
        if not points:
            continue
        x = np.array([float(r.name.split(CURVE_SEPARATOR)[1]) for r in points])
        rates = np.array([r.successes / max(r.episodes, 1) for r in points]) * 100.0
        intervals = np.array([wilson_interval(r.successes, r.episodes) for r in points]) * 100.0
        worse = np.array([r.comparison is not None and r.comparison.success.difference_ci[1] < 0.0 for r in points])
        fig, ax = plt.subplots(figsize=(5.5, 3.8), constrained_layout=True)
        ax.errorbar(x, rates, yerr=[rates - intervals[:, 0], intervals[:, 1] - rates], fmt="-o", color="C0",
                    capsize=3, label=f"with the imperfection ({points[0].episodes} episodes a point)")
        if worse.any():
            ax.plot(x[worse], rates[worse], "o", color="C3", label="paired: worse than the ideal cell (95 %)")
        ax.axhline(100.0 * ideal.successes / max(ideal.episodes, 1), color="grey", ls="--", lw=0.8,
                   label="the ideal cell, same episodes")
        ax.set_xlabel(curve.label)
        ax.set_ylabel("seated (%), Wilson 95 % interval")
        ax.set_ylim(min(50.0, float(intervals[:, 0].min()) - 5.0), 101.0)
        ax.legend(fontsize=8, loc="lower left")
        written.append(save_figure(fig, Path(folder) / f"curve_{name}.png"))
    return written


def costliest(rows: Sequence[SensitivityRow]) -> SensitivityRow | None:
    """The single imperfection whose paired success difference to the ideal cell is the most negative (ties: the
    larger held force); None when none lowered the success rate."""
    single = [(r.comparison.success.counts.difference, -(r.median_held_force_n or 0.0), k, r)
              for k, r in enumerate(rows)
              if r.comparison is not None and r.name != "all" and CURVE_SEPARATOR not in r.name]
    if not single:
        return None
    worst = min(single)
    return worst[3] if worst[0] < 0.0 else None


def curve_onsets(rows: Sequence[SensitivityRow]) -> dict[str, SensitivityRow | None]:
    """Per curve among ``rows`` (CURVE@X), its first point in order of magnitude whose paired success difference to the
    ideal cell is negative; None for a curve where no point lowered the success rate."""
    onsets: dict[str, SensitivityRow | None] = {}
    for row in rows:
        curve, separator, _ = row.name.partition(CURVE_SEPARATOR)
        if not separator:
            continue
        onsets.setdefault(curve, None)
        if (onsets[curve] is None and row.comparison is not None
                and row.comparison.success.counts.difference < 0.0):
            onsets[curve] = row
    return onsets


def sensitivity_verdict(rows: Sequence[SensitivityRow]) -> str:
    """The lines under the table: the costliest single imperfection (when any ran) and, per curve, the first
    magnitude that cost successes."""
    lines = []
    if any(CURVE_SEPARATOR not in r.name and r.name not in ("ideal", "all") for r in rows):
        worst = costliest(rows)
        lines.append("no imperfection alone lowered the success rate on these episodes" if worst is None else
                     f"costliest imperfection: {worst.name} ({worst.successes}/{worst.episodes} seated)")
    for curve, row in curve_onsets(rows).items():
        lines.append(f"curve {curve}: no point lowered the success rate" if row is None else
                     f"curve {curve}: first cost at {row.name.partition(CURVE_SEPARATOR)[2]} "
                     f"({row.successes}/{row.episodes} seated)")
    return "\n".join(lines)


def plot_sensitivity(rows: Sequence[SensitivityRow], path: str | os.PathLike[str]) -> Path:
    """Two panels: the success rate of each variant with its Wilson 95 % interval (the ideal cell's as a line),
    and its paired difference to the ideal cell with the Newcombe interval."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from envs.io.owned_output import save_figure
    from envs.statistics.fixed_sample import wilson_interval

    names = [r.name.replace("_", " ") for r in rows]
    rates = np.array([r.successes / max(r.episodes, 1) for r in rows]) * 100.0
    intervals = np.array([wilson_interval(r.successes, r.episodes) for r in rows]) * 100.0
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    y = np.arange(len(rows))[::-1]
    left.errorbar(rates, y, xerr=[rates - intervals[:, 0], intervals[:, 1] - rates], fmt="o", color="C0", capsize=3)
    left.axvline(rates[0], color="grey", lw=0.8, ls="--")
    left.set_yticks(y, names)
    left.set_xlabel("seated (%), Wilson 95 % interval")
    left.set_title(f"success per variant ({rows[0].episodes} episodes each)")
    for k, row in enumerate(rows):
        if row.comparison is None:
            continue
        s = row.comparison.success
        d, (low, high) = 100.0 * s.counts.difference, s.difference_ci
        right.errorbar([d], [y[k]], xerr=[[d - 100.0 * low], [100.0 * high - d]], fmt="o",
                       color="C3" if high < 0 else "C0", capsize=3)
    right.axvline(0.0, color="grey", lw=0.8)
    right.set_yticks(y, names)
    right.set_xlabel("paired difference to the ideal cell (points), Newcombe 95 % interval")
    right.set_title("the cost of each imperfection, same episodes")
    return save_figure(fig, path)
