"""Batch evaluation of a trained pose skill: perturbed starts, physics episodes, statistics, JSON record.

Start poses. A centre pose is perturbed: position + d, d uniform in the box [-pos_range_m, pos_range_m]^3;
orientation exp(r) * q, r a rotation vector (world frame) uniform in the ball of radius rot_range_deg
(envs.poses.sample_start_poses). The centre (``around``) is the mean of the demos' start poses
("mean", default: arithmetic mean position, normalised-sum quaternion) or, per episode, the start of a
demo drawn uniformly ("demo": harder, it reaches up to 15 deg past the demos' own orientation range).
The ranges and the centre are the task's (envs.task.StartRange; defaults +-5 cm, +-15 deg). All starts come from
one generator seeded with ``seed``, drawn before any episode runs, so the result does not depend on the number of
workers.

Batch. Episodes are the units of a `batch.run_batch`: in this process, in spawned worker processes or on
Ray; each finished record goes into the run's journal (if any) as it ends, so an interrupted evaluation
resumes from it with the same result. An episode over ``unit_timeout_s`` of wall time is the skill's
outcome, a failed episode "wall_timeout" (the limit, 300 s against ~1 s per episode, leaves a wide margin
for a loaded machine). A lost worker, actor or machine is not: its episode runs again on another worker (it
is deterministic from its start, so the record is the one an undisturbed run gives), and only after every
try is lost is it an infrastructure error -- not scored, not journalled (a resumed run tries it again),
and the evaluation is incomplete. The success rate is over the scored episodes; the infrastructure errors
and events are listed apart.

Episode. The arm is put at the start by the IK (controllers.ik.solve_ik in PegInHoleEnv.reset; an unreachable
or colliding start is recorded as a failure with its reason, not raised), then each control period the policy
(envs.execution.policy) commands a peg_tip pose to the impedance controller. Success is the physics-based check of
envs.success on the MEASURED peg_tip pose (criteria held for hold_s), never the plan. Any exception inside
an episode is recorded as a failure "error: ..." and the batch goes on.

Statistics. The success rate p = k/n with its 95 % Wilson score interval (envs.execution.statistics).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np
import numpy.typing as npt

from batch import Journal, run_batch
from envs.jsonable import to_jsonable
from envs.output import write_json
from envs.errors import EnvError
from envs.perturbation import PerturbationRanges, sample_perturbation
from envs.poses import Pose, StartRegion, format_pose, mean_quat, sample_start_poses
from envs.task import StartRange, Task
from envs.execution.adaptation import ContactAdaptation
from envs.execution.episode import EpisodeRecord, EpisodeTrace, StartPose, run_episode
from envs.execution.statistics import wilson_interval
from envs.execution.config import EvaluationConfig, StiffnessSetting
from envs.execution.policy import make_policy
from rflow.small_linalg import norm

FloatArray = npt.NDArray[np.float64]


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
    """Failed episodes counted by kind: the reason up to its first ':' or ' (' ("time_limit", "force_limit", ...)."""
    kinds: dict[str, int] = {}
    for r in records:
        if not r.success:
            kind = r.reason.split(":")[0].split(" (")[0]
            kinds[kind] = kinds.get(kind, 0) + 1
    return kinds


# --------------------------------------------------------------------------------------------- set-up


def sample_starts(demo_start_pos: npt.ArrayLike, demo_start_quat: npt.ArrayLike, num: int, seed: int,
                  pos_range_m: float, rot_range_deg: float, around: str = "mean",
                  perturbations: PerturbationRanges = PerturbationRanges()) -> list[StartPose]:
    """Perturbed start poses around the demos' starts (module docstring).

    Args:
        demo_start_pos: (N, 3) demo start positions.
        demo_start_quat: (N, 4) demo start orientations.
        num: number of starts.
        seed: generator seed.
        pos_range_m, rot_range_deg: perturbation box half-width and ball radius.
        around: "mean" (the mean demo start; demo_index -1) or "demo" (a random demo's start).
        perturbations: ranges of each episode's hole-pose error and grasp offset, drawn from a second
            generator seeded with (seed, 1) so that the start poses do not depend on them.

    Raises:
        EnvError: malformed demo starts, or ranges or a centre that envs.task.StartRange refuses.
    """
    StartRange(pos_range_m, rot_range_deg, around)
    p = np.asarray(demo_start_pos, dtype=np.float64)
    q = np.asarray(demo_start_quat, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (p.shape[0], 4) or p.shape[0] < 1:
        raise EnvError(f"demo starts must be pos (N, 3) and quat (N, 4), got {p.shape} and {q.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise EnvError("demo start poses contain NaN or inf")
    region = StartRegion(pos_half_width_m=(pos_range_m,) * 3, max_angle_deg=rot_range_deg)
    rng = np.random.default_rng(seed)
    task_rng = np.random.default_rng([seed, 1])
    mean = Pose(pos=p.mean(axis=0), quat=mean_quat(q))
    starts = []
    for k in range(num):
        n = int(rng.integers(p.shape[0])) if around == "demo" else -1
        centre = Pose(pos=p[n], quat=q[n] / norm(q[n])) if n >= 0 else mean
        starts.append(StartPose(k, n, sample_start_poses(centre, region, rng, 1)[0],
                                sample_perturbation(perturbations, task_rng)))
    return starts


def evaluation_starts(demo_starts: dict[str, Any], config: EvaluationConfig) -> list[StartPose]:
    """The ``config.episodes`` starts (and perturbations) of an evaluation around the demos' starts
    ({"pos": (N, 3), "quat": (N, 4)}, the checkpoint's metadata "demo_starts").

    Raises:
        EnvError: malformed demo starts.
    """
    start = config.task.start
    return sample_starts(demo_starts["pos"], demo_starts["quat"], config.episodes, config.seed, start.pos_range_m,
                         start.rot_range_deg, start.around, config.task.perturbations)


def scene_config_for(metadata: dict[str, Any], config: EvaluationConfig, goal: Pose) -> Any:
    """The SceneConfig to evaluate a skill in: the demos' scene, shape and clearance but for the task's shape (when
    set) and the task's fields named in ``config.scene_from_task``.

    The demos' recorded scene (metadata["scene"], from the demo file's config) supplies goal_pos,
    goal_yaw_deg, hole_depth_m and insertion_depth_m when present; ``hole_at_goal`` puts the target
    hole at the skill's goal pose instead.

    Raises:
        EnvError: a scene shape different from the demos' shape, or an invalid scene.
    """
    from envs.scene import SceneConfig

    task = config.task
    demo_shape = metadata.get("shape")
    shape = task.shape or demo_shape or "square"
    if demo_shape is not None and shape != demo_shape:
        raise EnvError(f"the skill was trained on {demo_shape!r} demos but the scene's peg is {shape!r}")
    kwargs: dict[str, Any] = {"shape": shape}
    recorded = metadata.get("scene") or {}
    for key in ("goal_pos", "goal_yaw_deg", "hole_depth_m", "insertion_depth_m"):
        if key in recorded and recorded[key] is not None:
            kwargs[key] = tuple(recorded[key]) if isinstance(recorded[key], list) else recorded[key]
    for key in ("chamfer_m", "peg_mode", "grasp_force_n"):  # the demos' scene unless the task's is asked for
        value = getattr(task, key) if key in config.scene_from_task else recorded.get(key)
        if value is not None:
            kwargs[key] = value
    clearance = task.clearance_m if "clearance_m" in config.scene_from_task else metadata.get("clearance_m")
    if clearance is not None:
        kwargs["clearance_m"] = float(clearance)
    if config.hole_at_goal:
        kwargs["hole_at_goal"] = (tuple(goal.pos.tolist()), tuple(goal.quat.tolist()))
    return SceneConfig(**kwargs)


def check_goal_reachable(env: Any) -> None:
    """Raise EnvError (one line) when mink (the IK of record, `solve_ik(solver="mink")`) cannot put the peg_tip at
    the scene's goal pose. Nothing of the episodes depends on it: they start from the compiled solver's joints."""
    from controllers.errors import ControllerError
    from controllers.ik import solve_ik

    try:
        solve_ik(env.arm_model, "tcp", env.goal.pos, env.goal.quat, env.q_nominal, env.config.ik, solver="mink")
    except ControllerError as err:
        raise EnvError(f"the goal pose {format_pose(env.goal)} is out of the arm's reach ({err})") from None



# --------------------------------------------------------------------------------------------- batch


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
        policy: a user policy's spec, options and privilege (`pih evaluate --policy`); None for the skill.
        task: the task the episodes ran: ``config.task`` with the scene it ran in (`Task.with_scene`); None: the
            config's.
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
        """The JSON record: config (`EvaluationConfig.settings`), the task it ran (`ran`, versioned: envs.task),
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
            **({} if self.policy is None else {"policy": self.policy}),
        }

    def save_json(self, path: str | os.PathLike[str]) -> Path:
        """Write ``to_dict`` (envs.output.write_json: strict, marked, atomic)."""
        out = Path(path)
        if str(out.parent) and not out.parent.is_dir():
            raise EnvError(f"cannot write {out}: folder {out.parent} does not exist")
        return write_json(out, self.to_dict())

    def summary_table(self) -> str:
        """A short plain-text table of the result (the force limit acts on the force held for its window, so a
        success's single-sample peak may exceed it)."""
        from envs.episode_config import EpisodeConfig

        low, high = self.interval
        s = self.statistics()

        def fmt(v: float | None, unit: str, digits: int = 2) -> str:
            return "-" if v is None else f"{v:.{digits}f} {unit}"

        rows = [
            ("policy", self.policy["spec"]) if self.policy is not None else ("mode", self.config.mode),
            ("episodes", str(len(self.records))),
            ("success rate", f"{100 * self.success_rate:.1f} % ({self.num_success}/{len(self.records)}), "
                             f"95 % CI [{100 * low:.1f}, {100 * high:.1f}] %"),
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
            ("infrastructure", self._infrastructure_text()),
            ("wall time", f"{self.wall_s:.1f} s ({self.workers} worker(s))"),
        ]
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)

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


@dataclass(frozen=True)
class _Setup:
    """What a worker needs to rebuild the environment and policy (picklable)."""

    model_dir: str
    config: EvaluationConfig


def build_env(metadata: dict[str, Any], goal: Pose, config: EvaluationConfig) -> Any:
    """The evaluation's PegInHoleEnv: the demos' scene (`scene_config_for` of the checkpoint's or demo file's
    metadata), the task's time and force limits, perturbation ranges and success tolerances; with ``hole_at_goal``
    the goal must be reachable.

    Raises:
        EnvError: shape mismatch, invalid scene, unreachable goal.
    """
    from envs.env import PegInHoleEnv
    from envs.episode_config import EpisodeConfig

    env = PegInHoleEnv(scene_config_for(metadata, config, goal), episode_config=EpisodeConfig.from_task(config.task))
    if config.hole_at_goal:
        check_goal_reachable(env)
    return env


def build_setup(model_dir: str | os.PathLike[str], config: EvaluationConfig) -> tuple[Any, Any, Any]:
    """Load the skill, build the evaluation environment and the policy.

    Returns:
        (skill, env, policy).

    Raises:
        RFlowError: missing or corrupt checkpoint. EnvError: shape mismatch, invalid scene, unreachable goal.
    """
    from rflow.skill_io import load_skill

    skill = load_skill(model_dir)
    env = build_env(skill.metadata, Pose(pos=skill.goal_pos, quat=skill.goal_quat), config)
    stiffness = None if config.stiffness is None else StiffnessSetting.parse(config.stiffness)
    adaptation = ContactAdaptation() if config.contact_adaptation else ContactAdaptation.off()
    policy = make_policy(skill, config.mode, config.lookahead_s, config.task.time_limit_s, config.speed, stiffness,
                         adaptation)
    return skill, env, policy


def _init_worker(setup: _Setup) -> dict[str, Any]:
    """Worker context: the environment and policy of ``setup`` (torch on one thread per worker)."""
    import torch

    torch.set_num_threads(1)
    _, env, policy = build_setup(setup.model_dir, setup.config)
    return {"env": env, "policy": policy, "gain": setup.config.feedforward_gain}


def _run_unit(context: dict[str, Any], start: StartPose) -> dict[str, Any]:
    """The record (as a dict) of one episode (the policy privileged where the context says so)."""
    return run_episode(context["env"], context["policy"], start, feedforward_gain=context["gain"],
                       privileged=context.get("privileged", False))[0].to_dict()


def _failed_unit(key: str, start: StartPose, reason: str) -> dict[str, Any]:
    """The record of an episode that produced none ("wall_timeout", "error: ...", "infrastructure: ...")."""
    return EpisodeRecord(start.index, start.demo_index, start.pose.pos.tolist(), start.pose.quat.tolist(),
                         reason=reason, perturbation=start.perturbation.to_dict()).to_dict()


def record_from_dict(values: dict[str, Any]) -> EpisodeRecord:
    """An EpisodeRecord from its ``to_dict`` (as read back from JSON); keys it does not know are dropped, so
    journals and files of other versions of the record still load. None stands for NaN.

    Raises:
        EnvError: a field without a default is missing.
    """
    from dataclasses import fields

    known = {f.name for f in fields(EpisodeRecord)}
    try:
        return EpisodeRecord(**{k: v for k, v in values.items() if k in known})
    except TypeError as err:
        raise EnvError(f"episode record {values.get('index', '?')} is incomplete: {err}") from None


def journal_run(model_dir: str | os.PathLike[str], config: EvaluationConfig) -> dict[str, Any]:
    """What identifies an evaluation for its journal: the checkpoint (path and skill.json checksum), the task and
    every other config field that changes a record (not workers, backend, address or the wall-time limit).

    Raises:
        RFlowError: no skill.json in ``model_dir``.
    """
    from rflow.errors import RFlowError
    from rflow.skill_io import SKILL_FILE, file_sha256

    try:
        checksum = file_sha256(Path(model_dir) / SKILL_FILE)
    except OSError:
        raise RFlowError(f"no {SKILL_FILE} in checkpoint {model_dir} (not a `pih train` output?)") from None
    return {"task": "pih evaluate", "model": str(Path(model_dir).resolve()), "skill_sha256": checksum,
            **run_settings(config)}


def run_settings(config: EvaluationConfig) -> dict[str, Any]:
    """{"config": the config's settings that change a record, its task (versioned) among them}: what a journal's run
    holds of an evaluation (`journal_run`, envs.execution.evaluate_policy.policy_journal_run)."""
    settings = {k: v for k, v in config.settings().items() if k not in ("workers", "unit_timeout_s", "backend",
                                                                         "ray_address")}
    return {"config": to_jsonable({**settings, "task": config.task.to_dict()})}


def evaluate(model_dir: str | os.PathLike[str], config: EvaluationConfig = EvaluationConfig(),
             progress: bool = True, starts: Sequence[StartPose] | None = None,
             journal: Journal | None = None) -> EvaluationResult:
    """Run ``config.episodes`` episodes of the skill in ``model_dir`` and collect the records.

    Args:
        model_dir: a `pih train` checkpoint directory.
        config: the evaluation.
        progress: tqdm bar.
        starts: explicit start poses (default: `sample_starts` from the skill's demo starts).
        journal: episodes already in it are not run again; new records are appended as they finish
            (open it with `journal_run(model_dir, config)` as the run).

    Returns:
        EvaluationResult (records sorted by episode index; ``complete`` False and ``interrupted`` True
        after Ctrl-C / SIGTERM, with the episodes finished so far; ``complete`` False with infrastructure
        errors, or with ``fault`` set when the whole batch was stopped).

    Raises:
        RFlowError / EnvError: bad checkpoint, shape mismatch, unreachable goal with hole_at_goal.
        BatchError: Ray unreachable, or workers that cannot build the environment.
    """
    wall = time.perf_counter()
    skill, env, policy = build_setup(model_dir, config)  # validates everything in this process first
    goal_mismatch_mm = norm(skill.goal_pos - env.goal.pos) * 1e3
    env_scene = env.scene.config
    if starts is None:
        starts = evaluation_starts(metadata_starts(skill.metadata, f"checkpoint {model_dir}"), config)
    here = {"env": env, "policy": policy, "gain": config.feedforward_gain}
    del env, policy  # workers build their own
    outcome, records, earlier_s = run_episodes(starts, _Setup(str(model_dir), config), _init_worker, here, config,
                                               progress, journal, f"evaluate ({config.mode})")
    return EvaluationResult(config, records, earlier_s + time.perf_counter() - wall, str(model_dir), skill.metadata,
                            to_jsonable(asdict(env_scene)), goal_mismatch_mm, outcome.complete, outcome.interrupted,
                            [record_from_dict(r) for r in outcome.infrastructure_errors.values()], outcome.events,
                            outcome.workers, outcome.fault, task=config.task.with_scene(env_scene))


def metadata_starts(metadata: dict[str, Any], source: str) -> dict[str, Any]:
    """The demos' start poses of a checkpoint's (or demo file's) metadata, {"pos": (N, 3), "quat": (N, 4)}.

    Raises:
        EnvError: naming ``source`` when there are none.
    """
    meta_starts = metadata.get("demo_starts")
    if not isinstance(meta_starts, dict) or "pos" not in meta_starts or "quat" not in meta_starts:
        raise EnvError(f"{source} has no demo start poses (metadata 'demo_starts')")
    return meta_starts


def run_episodes(starts: Sequence[StartPose], setup: Any, init_worker: Callable[[Any], dict[str, Any]],
                 here: dict[str, Any], config: EvaluationConfig, progress: bool, journal: Journal | None,
                 desc: str) -> tuple[Any, list[EpisodeRecord], float]:
    """The batch of an evaluation: each start an episode (`_run_unit`) in this process on ``here`` (the context of
    env, policy and gain built already) or in workers that build theirs with ``init_worker(setup)``.

    Returns:
        (the batch outcome, the records sorted by episode index, the wall time of the journal's earlier parts).
    """
    from tqdm import tqdm

    batch = config.batch_config()
    in_process = batch.backend == "process" and batch.workers == 1
    done = journal.done() if journal is not None else {}
    bar = tqdm(total=len(starts), initial=sum(str(s.index) in done for s in starts), desc=desc,
               unit="ep", disable=not progress, leave=False)
    successes = [sum(bool(done[str(s.index)].get("success")) for s in starts if str(s.index) in done)]

    def on_record(key: str, record: dict[str, Any]) -> None:
        successes[0] += bool(record.get("success"))
        bar.update(1)
        bar.set_postfix(success=f"{successes[0]}/{bar.n}")

    import torch

    threads = torch.get_num_threads()
    if in_process:
        torch.set_num_threads(1)
    try:
        outcome = run_batch([(str(s.index), s) for s in starts], setup, (lambda _: here) if in_process else init_worker,
                            _run_unit, _failed_unit, batch, journal, on_record)
    finally:
        torch.set_num_threads(threads)
        bar.close()
    records = sorted((record_from_dict(r) for r in outcome.records.values()), key=lambda r: r.index)
    return outcome, records, journal.earlier_wall_s if journal is not None else 0.0


def iter_replays(model_dir: str | os.PathLike[str], config: EvaluationConfig, starts: Sequence[StartPose],
                 on_step: Callable[[Any], None] | None = None,
                 on_episode: Callable[[StartPose, Any], None] | None = None) -> Iterator[tuple[EpisodeRecord, EpisodeTrace | None]]:
    """Re-run chosen episodes in this process with traces, one at a time (one environment and policy for all);
    physics is deterministic, so a replay reproduces the batch episode.

    Args:
        model_dir, config: as for `evaluate`.
        starts: the episodes to replay.
        on_step: called with the env after reset and every step.
        on_episode: called with (start, env) before each episode.

    Yields:
        (record, trace) of each start in turn.
    """
    import torch

    _, env, policy = build_setup(model_dir, config)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for start in starts:
            if on_episode is not None:
                on_episode(start, env)
            yield run_episode(env, policy, start, record_trace=True, on_step=on_step,
                              feedforward_gain=config.feedforward_gain)
    finally:
        torch.set_num_threads(threads)


def replay_episodes(model_dir: str | os.PathLike[str], config: EvaluationConfig, starts: Sequence[StartPose],
                    on_step: Callable[[Any], None] | None = None,
                    on_episode: Callable[[StartPose, Any], None] | None = None) -> list[tuple[EpisodeRecord, EpisodeTrace | None]]:
    """`iter_replays` collected in a list (for figures and video)."""
    return list(iter_replays(model_dir, config, starts, on_step, on_episode))


__all__ = [
    "EpisodeRecord",
    "EpisodeTrace",
    "EvaluationConfig",
    "EvaluationResult",
    "StartPose",
    "build_env",
    "build_setup",
    "check_goal_reachable",
    "evaluate",
    "finite_min",
    "iter_replays",
    "journal_run",
    "metadata_starts",
    "record_from_dict",
    "replay_episodes",
    "run_settings",
    "run_episode",
    "run_episodes",
    "evaluation_starts",
    "sample_starts",
    "scene_config_for",
]
