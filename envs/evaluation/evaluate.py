"""Batch evaluation of a trained pose skill: the evaluation's environment and policy, its episodes run as a batch,
and replays of chosen episodes. Where the episodes start is envs.evaluation.starts; the result, its statistics and
JSON, envs.evaluation.result.

Batch. Episodes are the units of a `batch.run_batch`: in this process, in forked worker processes or on
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
(envs.policies.flow_skill) commands a peg_tip pose to the impedance controller. Success is the physics-based check of
envs.task.success on the MEASURED peg_tip pose (criteria held for hold_s), never the plan. Any exception inside
an episode is recorded as a failure "error: ..." and the batch goes on.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

from batch import Journal, run_batch
from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.evaluation.starts import evaluation_starts, metadata_starts, sample_starts
from envs.io.jsonable import to_jsonable
from envs.policies.adaptation import ContactAdaptation
from envs.policies.flow_skill import make_policy
from envs.policies.skill_settings import StiffnessSetting
from envs.poses import Pose, format_pose
from envs.rollout.episode import EpisodeRecord, EpisodeTrace, StartPose, record_from_dict, run_episode
from numerics.small_linalg import norm

if TYPE_CHECKING:  # the result (with scipy.stats, ~0.7 s to import) is built in the parent only, never in a worker
    from envs.evaluation.result import EvaluationResult


# --------------------------------------------------------------------------------------------- set-up


def scene_config_for(metadata: dict[str, Any], config: EvaluationConfig, goal: Pose) -> Any:
    """The SceneConfig to evaluate a skill in: the demos' scene, shape and clearance but for the task's shape (when
    set), the task's fields named in ``config.scene_from_task`` and the task's finger pads (always: a property of
    the cell the skill runs in, as its perturbations are).

    The demos' recorded scene (metadata["scene"], from the demo file's config) supplies goal_pos,
    goal_yaw_deg, hole_depth_m and insertion_depth_m when present; ``hole_at_goal`` puts the target
    hole at the skill's goal pose instead.

    Raises:
        EnvError: a scene shape different from the demos' shape, or an invalid scene.
    """
    from envs.cell.scene_config import SceneConfig

    task = config.task
    demo_shape = metadata.get("shape")
    shape = task.shape or demo_shape or "square"
    if demo_shape is not None and shape != demo_shape:
        raise EnvError(f"the skill was trained on {demo_shape!r} demos but the scene's peg is {shape!r}")
    kwargs: dict[str, Any] = {"shape": shape}
    recorded = metadata.get("scene") or {}
    if not isinstance(recorded, dict):
        raise EnvError(f"the skill's metadata 'scene' must be a JSON object, got {type(recorded).__name__}")
    for key in ("goal_pos", "goal_yaw_deg", "hole_depth_m", "insertion_depth_m"):
        if key in recorded and recorded[key] is not None:
            kwargs[key] = tuple(recorded[key]) if isinstance(recorded[key], list) else recorded[key]
    for key in ("chamfer_m", "peg_mode", "grasp_force_n"):  # the demos' scene unless the task's is asked for
        value = getattr(task, key) if key in config.scene_from_task else recorded.get(key)
        if value is not None:
            kwargs[key] = value
    clearance = task.clearance_m if "clearance_m" in config.scene_from_task else metadata.get("clearance_m")
    if clearance is not None:
        if isinstance(clearance, bool) or not isinstance(clearance, (int, float)):
            raise EnvError(f"the skill's metadata clearance_m={clearance!r} must be a number")
        kwargs["clearance_m"] = float(clearance)
    kwargs["pad_stiffness_nm_rad"] = task.pad_stiffness_nm_rad  # the cell's pads, like its perturbations
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


@dataclass(frozen=True)
class _Setup:
    """What a worker needs to rebuild the environment and policy (picklable)."""

    model_dir: str
    config: EvaluationConfig
    record_dir: str | None = None
    record_only: frozenset[int] | None = None


def build_env(metadata: dict[str, Any], goal: Pose, config: EvaluationConfig) -> Any:
    """The evaluation's PegInHoleEnv: the demos' scene (`scene_config_for` of the checkpoint's or demo file's
    metadata), the task's time and force limits, perturbation ranges and success tolerances; with ``hole_at_goal``
    the goal must be reachable.

    Raises:
        EnvError: shape mismatch, invalid scene, unreachable goal.
    """
    from envs.sim.env import PegInHoleEnv
    from envs.sim.episode_config import EpisodeConfig

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
    return skill, env, _policy_for(skill, config)


def build_slots(model_dir: str | os.PathLike[str], config: EvaluationConfig, slots: int) -> tuple[Any, list, list]:
    """`build_setup` for ``slots`` episodes in lockstep (envs.rollout.lockstep): one skill, and per slot an
    environment of its own (its own MjModel and MjData) and a policy of its own on that skill.

    Returns:
        (skill, envs, policies).

    Raises:
        as `build_setup`.
    """
    skill, env, policy = build_setup(model_dir, config)
    envs, policies = zip(*SlotPool(env, policy, SlotMaker(skill, config, env)).take(slots))
    return skill, list(envs), list(policies)


def _policy_for(skill: Any, config: EvaluationConfig) -> Any:
    """The evaluation's policy on ``skill`` (mode, lookahead, stiffness, contact adaptation of ``config``; with
    ``follow_observed_hole`` run in the observed hole's frame, envs.policies.goal_frame)."""
    stiffness = None if config.stiffness is None else StiffnessSetting.parse(config.stiffness)
    adaptation = (ContactAdaptation() if config.contact_adaptation else ContactAdaptation.off()).without(
        config.adaptation_off)
    policy = make_policy(skill, config.mode, config.lookahead_s, config.task.time_limit_s, config.speed, stiffness,
                         adaptation)
    if config.follow_observed_hole:
        from envs.policies.goal_frame import GoalFramePolicy

        return GoalFramePolicy(policy, Pose(pos=skill.goal_pos, quat=skill.goal_quat))
    return policy


def _init_worker(setup: _Setup) -> dict[str, Any]:
    """Worker context: the environment and policy of ``setup`` (torch on one thread per worker), and how to make
    more slots for episodes in lockstep."""
    import torch

    torch.set_num_threads(1)
    skill, env, policy = build_setup(setup.model_dir, setup.config)
    return {"env": env, "policy": policy, "gain": setup.config.feedforward_gain,
            "slots": SlotPool(env, policy, SlotMaker(skill, setup.config, env)), "record_dir": setup.record_dir,
            "record_only": setup.record_only}


class SlotPool:
    """The lockstep slots of a worker (envs.rollout.lockstep): its first environment and policy, and more made by
    ``make()`` when a group needs them, kept for the next groups."""

    def __init__(self, env: Any, policy: Any, make: Callable[[], tuple[Any, Any]]):
        self._slots = [(env, policy)]
        self._make = make

    def take(self, slots: int) -> list[tuple[Any, Any]]:
        """The first ``slots`` (env, policy) pairs, made as needed."""
        while len(self._slots) < slots:
            self._slots.append(self._make())
        return self._slots[:slots]


class SlotMaker:
    """Another lockstep slot of an evaluation: an environment of its own and a policy of its own on the skill. The
    environment runs on a copy of the scene's model as it was when this was made, before any episode wrote its
    perturbation into it (a copy instead of a new build: ~1 ms instead of ~110 ms)."""

    def __init__(self, skill: Any, config: EvaluationConfig, env: Any):
        self.skill, self.config = skill, config
        self.scene = dataclasses.replace(env.scene, model=copy.copy(env.scene.model))
        self.episode_config = env.config

    def __call__(self) -> tuple[Any, Any]:
        from envs.sim.env import PegInHoleEnv

        scene = dataclasses.replace(self.scene, model=copy.copy(self.scene.model))
        return PegInHoleEnv(scene=scene, episode_config=self.episode_config), _policy_for(self.skill, self.config)


class _Inherited:
    """The init of a forked worker that runs on the context its parent built before the fork (its own copy of it,
    the environment and policy as `_init_worker` would build them), so the worker starts without building the
    scene and loading the skill again (~0.2-0.4 s each). Torch goes to one thread first, as in `_init_worker` (a
    forked child must not enter its parent's OpenMP pool, `batch.BatchConfig.start_method`)."""

    def __init__(self, context: dict[str, Any]):
        self.context = context

    def __call__(self, setup: Any) -> dict[str, Any]:
        import torch

        torch.set_num_threads(1)
        return self.context


def _run_unit(context: dict[str, Any], start: StartPose) -> dict[str, Any]:
    """The record (as a dict) of one episode (the policy privileged where the context says so, a user's policy's
    errors told apart, and the episode recorded into the context's "record_dir", `recorder`)."""
    save = recorder(context)
    record, trace = run_episode(context["env"], context["policy"], start, record_trace=save is not None,
                                feedforward_gain=context["gain"], privileged=context.get("privileged", False),
                                user_policy=context.get("user_policy", False))
    if save is not None and trace is not None:
        save(record, trace)
    return record.to_dict()


def _run_group(context: dict[str, Any], starts: list[StartPose]) -> list[dict[str, Any]]:
    """The records (as dicts) of episodes run in lockstep (envs.rollout.lockstep) on the context's slots
    (`SlotPool`), as `_run_unit` runs one."""
    from envs.rollout.lockstep import run_lockstep

    envs, policies = zip(*context["slots"].take(len(starts)))
    records = run_lockstep(envs, policies, starts, feedforward_gain=context["gain"],
                           privileged=context.get("privileged", False),
                           user_policy=context.get("user_policy", False), on_trace=recorder(context))
    return [r.to_dict() for r in records]


def recorder(context: dict[str, Any]) -> Callable[[EpisodeRecord, EpisodeTrace], None] | None:
    """What writes an episode's trace into the recording (envs.evaluation.recording) when the context has one
    ("record_dir"; "record_only": the indices to record, None for all), else None."""
    folder = context.get("record_dir")
    if folder is None:
        return None
    only = context.get("record_only")

    def save(record: EpisodeRecord, trace: EpisodeTrace) -> None:
        from envs.evaluation.recording import save_episode

        if only is None or record.index in only:
            save_episode(folder, record.to_dict(), trace)

    return save


def _failed_unit(key: str, start: StartPose, reason: str) -> dict[str, Any]:
    """The record of an episode that produced none ("wall_timeout", "error: ...", "infrastructure: ...")."""
    return EpisodeRecord(start.index, start.demo_index, start.pose.pos.tolist(), start.pose.quat.tolist(),
                         reason=reason, perturbation=start.perturbation.to_dict()).to_dict()


def skill_file(model_dir: str | os.PathLike[str]) -> str:
    """The checkpoint's skill.json, as an error about its metadata names it."""
    return str(Path(model_dir) / "skill.json")


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
    holds of an evaluation (`journal_run`, envs.evaluation.evaluate_policy.policy_journal_run)."""
    settings = {k: v for k, v in config.settings().items() if k not in ("workers", "unit_timeout_s", "start_timeout_s",
                                                                         "backend", "ray_address", "lockstep")}
    return {"config": to_jsonable({**settings, "task": config.task.to_dict()})}


def evaluate(model_dir: str | os.PathLike[str], config: EvaluationConfig = EvaluationConfig(),
             progress: bool = True, starts: Sequence[StartPose] | None = None,
             journal: Journal | None = None, record_dir: str | os.PathLike[str] | None = None) -> EvaluationResult:
    """Run ``config.episodes`` episodes of the skill in ``model_dir`` and collect the records.

    Args:
        model_dir: a `pih train` checkpoint directory.
        config: the evaluation.
        progress: tqdm bar.
        starts: explicit start poses (default: `evaluation_starts` around the skill's demo starts).
        journal: episodes already in it are not run again; new records are appended as they finish
            (open it with `journal_run(model_dir, config)` as the run).
        record_dir: record every episode's trace into this folder as it ends (envs.evaluation.recording; prepared
            with `prepare_recording`); the result names it.

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
        starts = evaluation_starts(metadata_starts(skill.metadata, skill_file(model_dir)), config)
    folder = None if record_dir is None else str(Path(record_dir).resolve())
    here = {"env": env, "policy": policy, "gain": config.feedforward_gain,
            "slots": SlotPool(env, policy, SlotMaker(skill, config, env)), "record_dir": folder}
    del env, policy  # forked workers take their copy of ``here``, others build their own
    outcome, records, earlier_s = run_episodes(starts, _Setup(str(model_dir), config, folder), _init_worker, here,
                                               config, progress, journal, f"evaluate ({config.mode})", inherit=True)
    from envs.evaluation.result import EvaluationResult

    return EvaluationResult(config, records, earlier_s + time.perf_counter() - wall, str(model_dir), skill.metadata,
                            to_jsonable(asdict(env_scene)), goal_mismatch_mm, outcome.complete, outcome.interrupted,
                            [record_from_dict(r) for r in outcome.infrastructure_errors.values()], outcome.events,
                            outcome.workers, outcome.fault, task=config.task.with_scene(env_scene),
                            events_before=outcome.events_before, recorded_episodes=folder)


def run_episodes(starts: Sequence[StartPose], setup: Any, init_worker: Callable[[Any], dict[str, Any]],
                 here: dict[str, Any], config: EvaluationConfig, progress: bool, journal: Journal | None,
                 desc: str, inherit: bool = False, isolate: bool = False,
                 check: Callable[[dict[str, Any]], None] | None = None) -> tuple[Any, list[EpisodeRecord], float]:
    """The batch of an evaluation: each start an episode (`_run_unit`) in this process on ``here`` (the context of
    env, policy and gain built already) or in workers that build theirs with ``init_worker(setup)``; with
    ``inherit``, forked workers take their copy of ``here`` instead (`_Inherited`), and only spawned or Ray workers
    build their own. With ``isolate`` even one worker is a supervised process (`batch.BatchConfig.isolate`).
    ``check`` sees every new record as it comes, after the journal got it: an exception it raises stops the batch
    (its workers stopped, the journal keeping what finished) and leaves here.

    Returns:
        (the batch outcome, the records sorted by episode index, the wall time of the journal's earlier parts).
    """
    from tqdm import tqdm

    from batch.processes import start_method

    batch = dataclasses.replace(config.batch_config(), isolate=isolate)
    in_process = batch.backend == "process" and batch.workers == 1 and not isolate
    if inherit and batch.backend == "process" and start_method(batch) == "fork":
        init_worker = _Inherited(here)
    done = journal.done() if journal is not None else {}
    bar = tqdm(total=len(starts), initial=sum(str(s.index) in done for s in starts), desc=desc,
               unit="ep", disable=not progress, leave=False)
    successes = [sum(bool(done[str(s.index)].get("success")) for s in starts if str(s.index) in done)]

    def on_record(key: str, record: dict[str, Any]) -> None:
        successes[0] += bool(record.get("success"))
        bar.update(1)
        bar.set_postfix(success=f"{successes[0]}/{bar.n}")
        if check is not None:
            check(record)

    import torch

    threads = torch.get_num_threads()
    if in_process:
        torch.set_num_threads(1)
    try:
        outcome = run_batch([(str(s.index), s) for s in starts], setup, (lambda _: here) if in_process else init_worker,
                            _run_unit, _failed_unit, batch, journal, on_record, group_size=config.lockstep,
                            work_group=_run_group)
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
    "EpisodeRecord",  # the config and episode names the evaluation's users have imported from here
    "EpisodeTrace",
    "EvaluationConfig",
    "StartPose",
    "build_env",
    "build_setup",
    "build_slots",
    "SlotMaker",
    "SlotPool",
    "check_goal_reachable",
    "evaluate",
    "iter_replays",
    "journal_run",
    "replay_episodes",
    "run_settings",
    "run_episode",
    "run_episodes",
    "sample_starts",  # tests/helpers/policy_record_cases.py imports it from here: the same file runs on older commits
    "scene_config_for",
]
