"""Scripted peg-in-hole demonstrations executed in physics and recorded as measured tcp poses.

The recorded frame is the ``tcp`` (the nominal peg_tip on the hand, measured through the arm's kinematics, as a
real robot records a demonstration); with the grasped peg it differs from the peg's own peg_tip only by slip
and tilt in the grasp. The expert knows the real hole.

The scripted expert and its path are envs.policies.expert_plan (ExpertConfig, plan_expert_path); the path is planned
from the requested start and run as a policy (envs.policies.expert.ScriptedExpertPolicy) through the episode loop
every policy runs through (envs.rollout.episode). Its actions carry the plan's twist by central differences, xi, and
its rate, so the impedance controller commands the plan led by its own velocity and inertia feed-forward
(x_cmd = x_plan + K^-1 (D(q) xi + Lambda(q) xi_dot), controllers.feedforward) and the compliant arm follows the plan
instead of lagging and swinging beside it (without it the peg reaches the opening 0.3-0.4 mm beside the axis, a bias
every learned skill would copy). The MEASURED tcp pose is recorded every control step and resampled to M samples on
a uniform grid (positions linearly, quaternions by slerp).

Beside the poses, what the robot did is recorded at the control rate, as it happened (not resampled, not snapped
to the goal): the joint positions and velocities, the wrist sensor's reading and the command sent after each control
sample (the tcp pose led by the feed-forward, the translational and rotational stiffness), the demo file's control
signals (envs.demos.file.ControlSignals), from which `pih export` makes a dataset's observations and actions.

A demo is kept only if the success tracker declared success and the settled pose (mean over the last
``settle_window_s``) is within ``goal_tol_m`` / ``goal_tol_deg`` of the nominal goal. The residual is then
removed smoothly over the hold segment: with w(t) the minimum-jerk ramp from 0 at the start of the hold
to 1 at its end, p'(t) = p(t) + w (g_p - p_settled) and q'(t) = exp(w Log(g_q conj(q_settled))) q(t), and
the last sample is set to the goal, so every demo ends exactly at the shared goal (p_M = g) while the
recorded motion is changed by at most the residual (reported per demo). Failed demos are recorded with
their reason and replaced by a new start from the same random stream; none is silently kept.

Stiffness (on by default: ``ExpertConfig.stiffness``). The expert also varies the robot's
compliance as a teacher would: each control step it commands the translational stiffness of its schedule
(envs.policies.stiffness_schedule: stiff in free space, compliant across the hole axis near and in the hole) at the
MEASURED tcp position, K_k = K(h(p_k)), as the 6x6 stiffness [[K_k, 0], [0, k_rot I]] (k_rot: the
controller's default rotational stiffness); damping follows from the damping ratio as always. What it
commanded is recorded with the poses (sample k: the stiffness commanded from pose k; the last: the schedule
at the final pose), resampled to the M-sample grid along Log-Euclidean geodesics (SPD at every sample,
rflow.stiffness.log_euclidean_resample) and stored as the demo file's ``stiffness``. A kept demo ends
seated in the hole, where the schedule is the goal stiffness K_goal exactly, so every demo ends at the
shared K_goal (an attempt whose final stiffness is not K_goal is not kept).
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import numpy.typing as npt

from controllers.impedance import ImpedanceConfig
from envs.cell.contact import ContactConfig
from envs.cell.scene_config import SceneConfig
from envs.demos.file import ControlSignals, DemoSet
from envs.errors import EnvError
from envs.io.jsonable import to_jsonable
from envs.policies.expert import ScriptedExpertPolicy
from envs.policies.expert_plan import ExpertConfig, plan_expert_path
from envs.policies.stiffness_schedule import expert_stiffness
from envs.poses import (
    Pose,
    format_pose,
    make_continuous,
    mean_quat,
    minimum_jerk,
    quat_angle_rad,
    quat_conj,
    quat_from_rotvec,
    quat_mul,
    quat_to_rotvec,
    resample_trajectory,
)
from envs.rollout.episode import EpisodeTrace, StartPose, run_episode
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from envs.task.task import Task
from numerics.small_linalg import norm
from rflow.stiffness import log_euclidean_resample

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DemoAttempt:
    """One executed demonstration (kept or failed).

    Attributes:
        start: the start pose.
        ok: kept.
        reason: "ok" or why it failed.
        times: (K,) control-step times of the measured samples (from 0).
        pos, quat: (K, 3), (K, 4) measured peg_tip poses.
        commanded_pos: (K, 3) commanded peg_tip positions (for drawing).
        residual_pos_m, residual_rot_deg: settled pose minus goal (NaN when not reached).
        wall_s: wall-clock seconds the attempt took.
        stiffness: (K, 3, 3) translational stiffness commanded from each measured sample (N/m, world frame;
            the last: the schedule at the final pose), or None when the expert has no schedule.
        control: the signals of each control sample (envs.demos.file.ControlSignals' arrays, K rows each: joint_pos,
            joint_vel, wrist_wrench as the sensor read it, and the command sent after the sample, action_pos,
            action_quat, action_stiffness, action_rot_stiffness, the last row repeating the one before), or None
            when the attempt did not run.
    """

    start: Pose
    ok: bool
    reason: str
    times: FloatArray
    pos: FloatArray
    quat: FloatArray
    commanded_pos: FloatArray
    residual_pos_m: float
    residual_rot_deg: float
    wall_s: float
    stiffness: FloatArray | None = None
    control: dict[str, FloatArray] | None = None


def settled_pose(times: FloatArray, pos: FloatArray, quat: FloatArray, window_s: float) -> Pose:
    """Mean pose over the last ``window_s`` seconds: arithmetic mean position, normalised-sum quaternion."""
    keep = times >= times[-1] - window_s - 1e-9
    return Pose(pos=pos[keep].mean(axis=0), quat=mean_quat(quat[keep]))


def execute_demo(env: PegInHoleEnv, start: Pose, config: ExpertConfig,
                 on_step: Callable[[PegInHoleEnv], None] | None = None) -> DemoAttempt:
    """Run the scripted expert from ``start`` in physics and judge the result (never raises for a failure).

    The expert's path is planned from ``start`` into the hole, then the expert policy follows it through the episode
    loop (envs.rollout.episode, privileged: it knows the real hole) for the plan's duration. The environment must
    not stop on success (the expert holds the peg to let it settle) and its time limit must exceed
    ``config.duration_s``. With ``config.stiffness`` every step commands the schedule's stiffness at the measured tcp
    position (module docstring), and a demo whose final stiffness is not the goal stiffness is not kept.

    Args:
        on_step: called with the env after the reset and after every control step (e.g. video capture).

    Returns:
        DemoAttempt with the measured trajectory at every control step (t = 0 included).
    """
    wall = time.perf_counter()
    goal = env.goal
    period = env.control_period_s
    num_steps = int(round(config.duration_s / period))
    step_times = period * np.arange(1, num_steps + 1)
    nan = float("nan")
    empty = np.zeros((0, 3))
    try:
        cmd_pos, cmd_quat = plan_expert_path(start, env.hole.pos, env.hole_axis, goal, config, step_times)
    except EnvError as err:
        return DemoAttempt(start, False, f"no path: {err}", np.zeros(0), empty, np.zeros((0, 4)), empty, nan, nan,
                           time.perf_counter() - wall)

    def failed(reason: str, times: FloatArray = np.zeros(0), pos: FloatArray = empty,
               quat: FloatArray = np.zeros((0, 4))) -> DemoAttempt:
        return DemoAttempt(start, False, reason, times, pos, quat, cmd_pos, nan, nan, time.perf_counter() - wall)

    expert = ScriptedExpertPolicy(config, plan=(cmd_pos, cmd_quat))
    record, trace = run_episode(env, expert, StartPose(0, -1, start), record_trace=True, on_step=on_step,
                                privileged=True, max_steps=num_steps)
    if record.failure == "unreachable_start":
        return failed(f"{UNREACHABLE_PREFIX}: {record.reason.removeprefix('unreachable start: ')}")
    if trace is None:
        return failed(record.reason)
    t_arr, p_arr, q_arr = trace.times_s, trace.tcp_pos, make_continuous(trace.tcp_quat)
    schedule = config.stiffness
    k_arr = None
    if schedule is not None:  # the commanded stiffness from each sample, then the schedule at the final pose
        final = expert_stiffness(p_arr[-1], env.hole.pos, env.hole_axis, schedule)
        k_arr = np.concatenate([trace.stiffness[1:], final[None]])
    if record.failure == "error":
        return failed(record.reason, t_arr, p_arr, q_arr)
    if env.done:
        return failed(f"episode ended early: {env.reason}", t_arr, p_arr, q_arr)
    obs = env.observation
    if record.steps == 0 or not obs.success:
        ins = obs.insertion
        return failed(f"not inserted (depth {ins.depth_m * 1e3:.1f} mm, lateral {ins.lateral_m * 1e3:.2f} mm, "
                      f"tilt {ins.tilt_deg:.2f} deg, hole {obs.hole})", t_arr, p_arr, q_arr)
    settled = settled_pose(t_arr, p_arr, q_arr, config.settle_window_s)
    res_pos = norm(settled.pos - goal.pos)
    res_rot = float(np.rad2deg(quat_angle_rad(settled.quat, goal.quat)))
    ok = res_pos <= config.goal_tol_m and res_rot <= config.goal_tol_deg
    reason = "ok" if ok else (f"settled {res_pos * 1e3:.2f} mm / {res_rot:.2f} deg from the goal "
                              f"(tolerance {config.goal_tol_m * 1e3:g} mm / {config.goal_tol_deg:g} deg)")
    if ok and k_arr is not None:
        goal_k = schedule.goal_stiffness(env.hole_axis)
        off = float(np.abs(k_arr[-1] - goal_k).max() / np.abs(goal_k).max())
        if off > STIFFNESS_GOAL_RTOL:
            ok, reason = False, f"final stiffness {off:.2g} (relative) from the goal stiffness"
    return DemoAttempt(start, ok, reason, t_arr, p_arr, q_arr, cmd_pos, res_pos, res_rot, time.perf_counter() - wall,
                       k_arr, _control_signals(trace, k_arr))


def _control_signals(trace: EpisodeTrace, stiffness: FloatArray | None) -> dict[str, FloatArray] | None:
    """The control samples of an attempt as arrays of K rows (`DemoAttempt.control`): what was measured at each
    sample, and the command sent after it (the pose the controller held, led by the feed-forward), the last row
    repeating the one before; the stiffness is ``stiffness`` (the schedule's, K rows) or without one the commanded
    (the controller's default)."""
    rows = trace.times_s.shape[0]
    if rows < 2:
        return None
    out = {"joint_pos": trace.qpos, "joint_vel": trace.qvel, "wrist_wrench": trace.sensed_wrench}
    for name, commanded in (("action_pos", trace.cmd_pos), ("action_quat", trace.cmd_quat)):
        out[name] = np.concatenate([commanded[1:], commanded[-1:]], axis=0)
    out["action_quat"] = make_continuous(out["action_quat"])
    out["action_stiffness"] = np.array(stiffness) if stiffness is not None else trace.stiffness
    out["action_rot_stiffness"] = trace.rot_stiffness
    return out


def finalize_demo(attempt: DemoAttempt, goal: Pose, config: ExpertConfig,
                  goal_stiffness: FloatArray | None = None) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Resample a kept attempt to M samples on [0, T] and make it end exactly at the goal.

    Args:
        attempt: a kept attempt.
        goal: the shared goal pose.
        config: the expert (duration, samples, hold).
        goal_stiffness: (3, 3) the shared goal stiffness the last stiffness sample is set to (needed when the
            attempt recorded stiffness; `execute_demo` kept it only if it ended there).

    Returns:
        (pos (M, 3), quat (M, 4), stiffness (M, 3, 3) or None), quaternions continuous and ending at
        +goal.quat, stiffness resampled along Log-Euclidean geodesics and ending at ``goal_stiffness``.
    """
    grid = np.linspace(0.0, config.duration_s, config.num_samples)
    pos, quat = resample_trajectory(attempt.times, attempt.pos, attempt.quat, grid)
    settled = settled_pose(attempt.times, attempt.pos, make_continuous(attempt.quat), config.settle_window_s)
    weight = minimum_jerk((grid - config.hold_start_s) / config.hold_duration_s)
    pos = pos + weight[:, None] * (goal.pos - settled.pos)
    correction = quat_to_rotvec(quat_mul(goal.quat, quat_conj(settled.quat)))
    quat = quat_mul(quat_from_rotvec(weight[:, None] * correction), quat)
    pos[-1] = goal.pos
    quat[-1] = goal.quat
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    stiffness = None
    if attempt.stiffness is not None:
        if goal_stiffness is None:
            raise EnvError("finalize_demo: an attempt with stiffness needs the goal stiffness")
        stiffness = log_euclidean_resample(attempt.times, attempt.stiffness, grid)
        stiffness[-1] = goal_stiffness
    return pos, make_continuous(quat, reference=goal.quat), stiffness


def demo_episode_config(config: ExpertConfig, base: EpisodeConfig = EpisodeConfig()) -> EpisodeConfig:
    """The episode settings the expert needs: no stop on success, a time limit past the demo's end."""
    return dataclasses.replace(base, stop_on_success=False, time_limit_s=config.duration_s + 1.0,
                               start_region=config.start_region)


@dataclass(frozen=True)
class Collection:
    """Result of :func:`collect_demos`: the demo set, every attempt, and timing."""

    demos: DemoSet
    attempts: list[DemoAttempt]
    wall_s: float

    @property
    def failures(self) -> list[DemoAttempt]:
        """The attempts that were not kept."""
        return [a for a in self.attempts if not a.ok]


def give_up_message(attempts: list[DemoAttempt], kept: int, num: int, shape: str, seed: int | None) -> str:
    """One line saying why a collection gave up: the shape, the seed, how many demos were kept in how many
    attempts, and what the failed attempts reached (their reasons counted, the last one in full, with the
    depth and lateral offset the peg got to)."""
    failed = [a.reason for a in attempts if not a.ok]
    kinds: dict[str, int] = {}
    for reason in failed:
        kind = reason.split(":")[0].split(" (")[0]
        kinds[kind] = kinds.get(kind, 0) + 1
    counted = ", ".join(f"{k}: {v}" for k, v in sorted(kinds.items(), key=lambda kv: -kv[1]))
    return (f"the scripted expert gave up on the {shape} after {len(attempts)} attempts (seed {seed}): "
            f"{kept} of {num} demos kept; failures {counted}; last: {failed[-1] if failed else '-'}")


def collect_demos(num: int, seed: int | None = 0, scene_config: SceneConfig = SceneConfig(),
                  expert: ExpertConfig = ExpertConfig(),
                  controller_config: ImpedanceConfig = ImpedanceConfig(),
                  env: PegInHoleEnv | None = None,
                  on_attempt: Callable[[int, DemoAttempt], None] | None = None,
                  on_step: Callable[[PegInHoleEnv], None] | None = None,
                  before_attempt: Callable[[PegInHoleEnv, Pose, FloatArray], None] | None = None,
                  task: Task | None = None) -> Collection:
    """Record ``num`` successful scripted demonstrations from starts sampled with ``seed``.

    Args:
        num: demonstrations to keep (N).
        seed: seed of the start-pose stream (failed attempts draw the next start from the same stream).
        scene_config, expert, controller_config: the setup (ignored scene/controller when ``env`` given).
        env: reuse an environment (its episode config must come from :func:`demo_episode_config`).
        on_attempt: called with (attempt index, DemoAttempt) after each attempt.
        on_step: called with the env after each attempt's reset and after every control step (e.g. to render).
        before_attempt: called with (env, start, planned positions (K, 3)) before each attempt.
        task: the task the demos are recorded for (envs.task.task), kept in the file's config as "task" with the scene's
            shape and fields (`Task.with_scene`); `pih train` copies it into the checkpoint.

    Returns:
        Collection with the DemoSet (N, M) ending at the shared goal.

    Raises:
        EnvError: bad arguments, or ``expert.max_failed_attempts`` failed attempts (one line: shape, seed, what
            the failures reached).
    """
    if not isinstance(num, int) or num < 1:
        raise EnvError(f"number of demos must be a positive integer, got {num!r}")
    wall = time.perf_counter()
    if env is None:
        env = PegInHoleEnv(scene_config, controller_config, demo_episode_config(expert))
    elif env.config.stop_on_success or env.config.time_limit_s <= expert.duration_s:
        raise EnvError("the demo environment must not stop on success and must outlast the demo "
                       "(build it with demo_episode_config)")
    rng = np.random.default_rng(seed)
    goal = env.goal
    attempts: list[DemoAttempt] = []
    kept: list[tuple[FloatArray, FloatArray, FloatArray | None]] = []
    goal_k = None if expert.stiffness is None else expert.stiffness.goal_stiffness(env.hole_axis)
    while len(kept) < num:
        if len(attempts) - len(kept) >= expert.max_failed_attempts:
            raise EnvError(give_up_message(attempts, len(kept), num, scene_config.shape, seed))
        start = env.sample_start(rng)
        if before_attempt is not None:
            grid = env.control_period_s * np.arange(0, int(round(expert.duration_s / env.control_period_s)) + 1)
            try:
                planned = plan_expert_path(start, env.hole.pos, env.hole_axis, goal, expert, grid)[0]
            except EnvError:
                planned = np.zeros((0, 3))
            before_attempt(env, start, planned)
        attempt = execute_demo(env, start, expert, on_step)
        attempts.append(attempt)
        if on_attempt is not None:
            on_attempt(len(attempts) - 1, attempt)
        if attempt.ok:
            kept.append(finalize_demo(attempt, goal, expert, goal_k))
    kept_attempts = [a for a in attempts if a.ok]
    control = None
    if all(a.control is not None for a in kept_attempts) and \
            len({a.control["joint_pos"].shape[0] for a in kept_attempts}) == 1:
        control = ControlSignals(dt=env.control_period_s, **{name: np.stack([a.control[name] for a in kept_attempts])
                                                             for name, _ in ControlSignals.ARRAYS})
    config = {
        "scene": to_jsonable(env.scene.config),
        "controller": to_jsonable(env.controller.config),
        "episode": to_jsonable(env.config),
        "expert": to_jsonable(expert),
        "seed": seed,
        "starts": [{"pos": a.start.pos.tolist(), "quat": a.start.quat.tolist()} for a in kept_attempts],
        "failures": [{"attempt": i, "reason": a.reason, "start": format_pose(a.start)}
                     for i, a in enumerate(attempts) if not a.ok],
        "attempts": len(attempts),
        "seconds_per_attempt": float(np.mean([a.wall_s for a in attempts])),
        **({} if task is None else {"task": to_jsonable(task.with_scene(env.scene.config).to_dict())}),
    }
    json.dumps(config)  # fail here, not at save time, if something is not serialisable
    demos = DemoSet(
        pos=np.stack([p for p, _, _ in kept]),
        quat=np.stack([q for _, q, _ in kept]),
        dt=expert.duration_s / (expert.num_samples - 1),
        goal_pos=goal.pos.copy(),
        goal_quat=goal.quat.copy(),
        shape=env.shape,
        clearance_m=float(env.scene.config.clearance_m),
        config=config,
        residual_pos_m=np.array([a.residual_pos_m for a in kept_attempts]),
        residual_rot_deg=np.array([a.residual_rot_deg for a in kept_attempts]),
        stiffness=None if goal_k is None else np.stack([k for _, _, k in kept]),
        goal_stiffness=goal_k,
        control=control,
    )
    return Collection(demos=demos, attempts=attempts, wall_s=time.perf_counter() - wall)


UNREACHABLE_PREFIX = "reset failed"
STIFFNESS_GOAL_RTOL: float = 1e-9
"""A kept demo's final commanded stiffness equals the goal stiffness to this (max |K - K_goal| / max |K_goal|)."""


@dataclass(frozen=True)
class SuccessRate:
    """Outcome of :func:`expert_success_rate`.

    Attributes:
        num_starts: starts drawn.
        num_success: demos that succeeded.
        num_unreachable: starts the arm cannot be put at (IK or collision), a property of the start region.
        failures: (index, reason) of every start that did not give a kept demo (unreachable included).
        seconds_per_demo: median wall-clock time of an executed demo.
        max_residual_pos_m, max_residual_rot_deg: worst settled distance from the goal among successes.
    """

    num_starts: int
    num_success: int
    num_unreachable: int
    failures: list[tuple[int, str]]
    seconds_per_demo: float
    max_residual_pos_m: float
    max_residual_rot_deg: float

    @property
    def rate(self) -> float:
        """Successes over all drawn starts (unreachable starts count as failures)."""
        return self.num_success / self.num_starts

    @property
    def rate_reachable(self) -> float:
        """Successes over the starts the arm could be put at (the expert's own success rate)."""
        reachable = self.num_starts - self.num_unreachable
        return self.num_success / reachable if reachable else float("nan")


def expert_success_rate(num_starts: int = 100, seed: int | None = 0, scene_config: SceneConfig = SceneConfig(),
                        expert: ExpertConfig = ExpertConfig(),
                        controller_config: ImpedanceConfig = ImpedanceConfig(),
                        on_attempt: Callable[[int, DemoAttempt], None] | None = None) -> SuccessRate:
    """Run the scripted expert once from each of ``num_starts`` seeded starts (no redraws) and count the
    successes (inserted, settled within the goal tolerances). The bar is >= 99 % of 100.

    Raises:
        EnvError: num_starts < 1.
    """
    if num_starts < 1:
        raise EnvError(f"num_starts={num_starts} must be >= 1")
    env = PegInHoleEnv(scene_config, controller_config, demo_episode_config(expert))
    rng = np.random.default_rng(seed)
    failures: list[tuple[int, str]] = []
    walls, res_pos, res_rot = [], [], []
    unreachable = 0
    for i in range(num_starts):
        attempt = execute_demo(env, env.sample_start(rng), expert)
        if attempt.ok:
            res_pos.append(attempt.residual_pos_m)
            res_rot.append(attempt.residual_rot_deg)
        else:
            failures.append((i, attempt.reason))
        if attempt.reason.startswith(UNREACHABLE_PREFIX):
            unreachable += 1
        else:
            walls.append(attempt.wall_s)
        if on_attempt is not None:
            on_attempt(i, attempt)
    return SuccessRate(
        num_starts=num_starts,
        num_success=num_starts - len(failures),
        num_unreachable=unreachable,
        failures=failures,
        seconds_per_demo=float(np.median(walls)) if walls else float("nan"),
        max_residual_pos_m=float(max(res_pos, default=float("nan"))),
        max_residual_rot_deg=float(max(res_rot, default=float("nan"))),
    )


def scene_config_from_demos(demos: DemoSet) -> SceneConfig:
    """The SceneConfig a demo file was recorded in (shape, clearance, depths and goal from config_json).

    Raises:
        EnvError: a stored scene configuration that does not build a valid SceneConfig.
    """
    stored = demos.config.get("scene", {}) if isinstance(demos.config, dict) else {}
    if not isinstance(stored, dict):
        raise EnvError(f"demo file scene configuration is invalid: 'scene' must be a JSON object, got "
                       f"{type(stored).__name__}")
    fields = {}
    try:
        for name in ("hole_depth_m", "insertion_depth_m", "goal_yaw_deg"):
            if name in stored:
                fields[name] = float(stored[name])
        if "goal_pos" in stored:
            fields["goal_pos"] = tuple(float(v) for v in stored["goal_pos"])
        if stored.get("hole_at_goal") is not None:
            pos, quat = stored["hole_at_goal"]
            fields["hole_at_goal"] = (tuple(float(v) for v in pos), tuple(float(v) for v in quat))
        if isinstance(stored.get("contact"), dict):
            fields["contact"] = ContactConfig(**{k: tuple(v) if isinstance(v, list) else v
                                                for k, v in stored["contact"].items()})
        return SceneConfig(shape=demos.shape, clearance_m=demos.clearance_m, **fields)
    except (TypeError, ValueError) as err:
        raise EnvError(f"demo file scene configuration is invalid: {err}") from None
