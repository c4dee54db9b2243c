"""One physics episode of any policy (envs.policies.interface.Policy): reset at a start pose, ask the policy
for an action every control period, record what the simulated peg did (the success check of envs.task.success on the
MEASURED peg, never the command).

The policy sees `envs.policies.interface.Observation` (what a real cell measures, the nominal hole) and nothing else;
the true hole only with ``privileged=True`` (a teacher such as the scripted expert). Each `Action` goes to the
environment, whose controller turns it into the pose and stiffness it holds for one period
(controllers.interface.Controller.command; the impedance controller adds its velocity feed-forward lead). Every
caller runs episodes here: evaluation, the recording of demos (the scripted expert, envs.demos.record), rendering
(a replay of recorded poses, scripts/render.py) and the Gymnasium environment.

An unreachable or colliding start is recorded as a failure with its reason, and any exception inside an
episode is recorded as "error: ..."; an episode never raises. Run as a user's policy (``user_policy=True``, `pih
evaluate --policy`), what the policy itself did wrong is told apart: an exception out of its ``reset`` or ``act``, an
action that is not an `Action`, or one the controller cannot command (envs.errors.ActionError) ends the episode as
failure "policy_error", its reason the traceback's last line, and the record keeps the policy's traceback
(`EpisodeRecord.traceback`) for the evaluation to show or stop on (envs/evaluation/evaluate_policy.py).
"""

from __future__ import annotations

import math
import time
import traceback
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
import numpy.typing as npt

from envs.errors import ActionError, EnvError
from envs.policies.interface import Action, Policy, observe
from envs.poses import Pose, quat_angle_rad
from envs.rollout.failure import ProgressWindow
from envs.task.perturbation import Perturbation
from numerics.small_linalg import eigh_sym, norm

if TYPE_CHECKING:  # for the annotations only: record_from_dict and the records load without the simulator
    from envs.sim.env import PegInHoleEnv, PeriodCommand

FloatArray = npt.NDArray[np.float64]

CONTACT_THRESHOLD_N: float = 1.0
"""An episode "touched" the walls when the peak contact force on the peg exceeded this."""


@dataclass(frozen=True)
class StartPose:
    """A perturbed start: episode index, the demo it was drawn around, the pose, and the episode's task
    perturbation (hole-pose error, grasp offset; envs.task.perturbation)."""

    index: int
    demo_index: int
    pose: Pose
    perturbation: Perturbation = field(default_factory=Perturbation)


@dataclass
class EpisodeRecord:
    """Outcome of one episode (JSON-ready through ``to_dict``; NaN where not applicable).

    Attributes:
        index: episode index.
        demo_index: the demo whose start was perturbed (-1: the mean demo start).
        start_pos, start_quat: start pose (m; w, x, y, z).
        success: the physics check declared success.
        reason: "success", "time_limit (...)", "force_limit (...)", "instability: ...", "unreachable start: ...",
            "error: ...", "policy_error: Type: message at file:line" (a user's policy, module docstring).
        failure: what went wrong when it failed (envs.rollout.failure: "jammed", "free_space_timeout",
            "left_grasp", "time_limit", "force_limit", "instability", "unreachable_start", "error",
            "policy_error"); None on success.
        perturbation: the episode's hole-pose error and grasp offset (mm, deg).
        time_to_insert_s: simulated time until success (None on failure).
        final_pos_error_mm: ||p_final - g_p|| against the real (perturbed) hole's goal.
        final_angle_error_deg: angle between the final and the real goal orientation.
        insertion_depth_mm: depth of the peg_tip below the target hole's opening (negative above).
        lateral_error_mm, tilt_deg: peg_tip distance from the hole axis and peg tilt at the end.
        wall_penetration_mm: how far the peg would have to sink into the walls at the end (<= 0: inside).
        grasp_shift_mm: |peg_tip - tcp| at the end: grasp offset plus slip and tilt in the grasp.
        peak_contact_force_n: largest sum of the environment's normal-force magnitudes on the peg (1 kHz).
        peak_single_contact_n: largest single contact normal force on the peg.
        touched: peak_contact_force_n > CONTACT_THRESHOLD_N.
        peak_wrist_force_n, median_wrist_force_n: |F| of the wrist F/T sensor (zeroed for the tool load).
        peak_sustained_wrist_force_n: largest |F| held for the force limit's window (what the limit compares).
        peak_wrist_torque_nm, median_wrist_torque_nm: |tau| of the wrist F/T sensor.
        min_stiffness_n_m, max_stiffness_n_m: smallest and largest eigenvalue of the translational stiffness
            commanded over the episode (N/m; the controller's default when the policy commands none).
        start_stiffness_eig_n_m, final_stiffness_eig_n_m: eigenvalues (ascending, N/m) of the translational
            stiffness commanded at the first and the last control step.
        final_pos, final_quat: measured peg_tip pose at the end.
        steps: control steps run.
        wall_s: wall-clock seconds.
        traceback: a user's policy's traceback when it failed ("policy_error"), else None (and then left out of
            ``to_dict``, so every other record reads as before).
    """

    index: int
    demo_index: int
    start_pos: list[float]
    start_quat: list[float]
    success: bool = False
    reason: str = "not run"
    failure: str | None = None
    perturbation: dict[str, float] = field(default_factory=dict)
    time_to_insert_s: float | None = None
    final_pos_error_mm: float = float("nan")
    final_angle_error_deg: float = float("nan")
    insertion_depth_mm: float = float("nan")
    lateral_error_mm: float = float("nan")
    tilt_deg: float = float("nan")
    wall_penetration_mm: float = float("nan")
    grasp_shift_mm: float = float("nan")
    peak_contact_force_n: float = float("nan")
    peak_single_contact_n: float = float("nan")
    touched: bool = False
    peak_wrist_force_n: float = float("nan")
    peak_sustained_wrist_force_n: float = float("nan")
    median_wrist_force_n: float = float("nan")
    peak_wrist_torque_nm: float = float("nan")
    median_wrist_torque_nm: float = float("nan")
    min_stiffness_n_m: float = float("nan")
    max_stiffness_n_m: float = float("nan")
    start_stiffness_eig_n_m: list[float] | None = None
    final_stiffness_eig_n_m: list[float] | None = None
    final_pos: list[float] | None = None
    final_quat: list[float] | None = None
    steps: int = 0
    wall_s: float = 0.0
    traceback: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (NaN becomes None; ``traceback`` only when there is one)."""
        return {k: _finite_or_none(v) for k, v in asdict(self).items() if k != "traceback" or v is not None}


def record_from_dict(values: dict[str, Any]) -> EpisodeRecord:
    """An EpisodeRecord from its ``to_dict`` (as read back from JSON); keys it does not know are dropped, so
    journals and files of other versions of the record still load. None stands for NaN.

    Raises:
        EnvError: a field without a default is missing.
    """
    known = {f.name for f in fields(EpisodeRecord)}
    try:
        return EpisodeRecord(**{k: v for k, v in values.items() if k in known})
    except TypeError as err:
        raise EnvError(f"episode record {values.get('index', '?')} is incomplete: {err}") from None


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@dataclass
class EpisodeTrace:
    """The executed trajectory of one episode, one row per control step (t = 0 first), for figures and
    dataset export (envs.datasets). Row 0 is the observation after the reset, row k the one after step k.

    Attributes:
        times_s: simulated time of each row, seconds.
        pos, quat: the peg's own peg_tip pose (simulator truth).
        cmd_pos, cmd_quat: the tcp pose commanded for the step ending at each row (row 0 repeats the start).
        force_n: contact force magnitude.
        stiffness: (K, 3, 3) translational stiffness commanded for the step ending at each row (row 0: the
            first step's), N/m, world frame.
        tcp_pos, tcp_quat: the measured tcp (the nominal peg_tip through the arm's kinematics).
        qpos, qvel: (K, 7) arm joint positions (rad) and velocities (rad/s).
        wrist_wrench: (K, 6) the true wrist wrench [N; N m], sensor frame, tool load removed.
        success: (K,) the simulator's success flag at each row.
        sensed_wrench: (K, 6) what the cell's sensor read of it (noise, bias, low-pass: what the policy saw).
        rot_stiffness: (K,) rotational stiffness commanded for the step ending at each row (as ``stiffness``),
            N m/rad (the mean of K_r's diagonal for a 6x6 stiffness).
        sim_qpos: (K, nq) the simulator's whole position state (arm, fingers, peg) at each row: what draws the
            episode again without running it (envs.evaluation.recording).
    """

    times_s: FloatArray
    pos: FloatArray
    quat: FloatArray
    cmd_pos: FloatArray
    cmd_quat: FloatArray
    force_n: FloatArray
    stiffness: FloatArray
    tcp_pos: FloatArray
    tcp_quat: FloatArray
    qpos: FloatArray
    qvel: FloatArray
    wrist_wrench: FloatArray
    success: npt.NDArray[np.bool_]
    sensed_wrench: FloatArray | None = None
    rot_stiffness: FloatArray | None = None
    sim_qpos: FloatArray | None = None


# --------------------------------------------------------------------------------------------- episode


def run_episode(env: PegInHoleEnv, policy: Policy, start: StartPose, record_trace: bool = False,
                on_step: Callable[[PegInHoleEnv], None] | None = None, feedforward_gain: float = 1.0,
                privileged: bool = False, max_steps: int | None = None,
                user_policy: bool = False) -> tuple[EpisodeRecord, EpisodeTrace | None]:
    """Run one episode from ``start`` with ``policy`` and score it (never raises for a failed episode: an action
    that is not an `Action`, or one the controller rejects, ends it as "error: ...").

    Args:
        env: a PegInHoleEnv (stop_on_success=True for an evaluation; a demo's runs on to its plan's end).
        policy: any `Policy` (``reset(observation, period_s)``, ``act(observation) -> Action``).
        start: the start pose.
        record_trace: also return the executed trajectory.
        on_step: called with the env after reset and after every step (e.g. video capture).
        feedforward_gain: scale of the controller's velocity feed-forward (controllers.feedforward); 0 disables it.
        privileged: hand the policy the true hole and goal (``Observation.privileged``), for a teacher only.
        max_steps: end the episode after this many control periods even if the env would go on (a caller's
            horizon, e.g. a demo's plan); None: the env's end (success, time or force limit, instability).
        user_policy: a user's policy: its own errors end the episode as "policy_error" with its traceback (module
            docstring); False: as "error" (the built-in skill, the expert recording demos).

    Returns:
        (EpisodeRecord, EpisodeTrace or None).
    """
    run = EpisodeRun(env, policy, start, record_trace, on_step, feedforward_gain, privileged, max_steps, user_policy)
    run.begin()
    while run.running:
        period = run.command(run.act())
        if period is not None:
            run.physics(period)
            run.complete(period)
    return run.finish()


class EpisodeRun:
    """One episode as the steps of its control periods, so that a loop can interleave many episodes
    (envs.rollout.lockstep) while each runs exactly the arithmetic of `run_episode`, which is this class run
    alone: ``begin``; while ``running``: ``act`` (or an action from a batched policy), ``command`` -> a prepared
    period, ``physics``, ``complete``; then ``finish``. Any exception inside ends the episode as "error: ..." (never
    raised); with ``user_policy``, the policy's own as "policy_error: ..." (module docstring)."""

    def __init__(self, env: PegInHoleEnv, policy: Policy, start: StartPose, record_trace: bool = False,
                 on_step: Callable[[PegInHoleEnv], None] | None = None, feedforward_gain: float = 1.0,
                 privileged: bool = False, max_steps: int | None = None, user_policy: bool = False):
        self.env = env
        self.policy = policy
        self.start = start
        self.record_trace = record_trace
        self.on_step = on_step
        self.gain = feedforward_gain
        self.privileged = privileged
        self.max_steps = max_steps
        self.user_policy = user_policy
        self.record = EpisodeRecord(start.index, start.demo_index, start.pose.pos.tolist(), start.pose.quat.tolist(),
                                    perturbation=start.perturbation.to_dict())
        self.running = False
        self._wall = time.perf_counter()
        self._rows: list[tuple[Any, Pose]] = []  # (observation, commanded tcp pose) of every row
        self._commanded: list[FloatArray] = []  # translational stiffness of every step
        self._rotational: list[float] = []  # rotational stiffness of every step (for the trace)
        self._states: list[FloatArray] = []  # the simulator's qpos of every row (for the trace)
        self._progress: ProgressWindow | None = None
        self._action: Action | None = None
        self._steps = 0
        self._finished = False

    def begin(self) -> bool:
        """Reset the env at the start and the policy at its first observation; whether the episode runs (an
        unreachable start or an error ends it here)."""
        env, rec = self.env, self.record
        try:
            try:
                obs = env.reset(start_pose=self.start.pose, perturbation=self.start.perturbation)
            except EnvError as err:
                rec.reason, rec.failure = f"unreachable start: {err}", "unreachable_start"
                self._finished = True
                return False
            period = env.control_period_s
            try:
                self.policy.reset(observe(env, self.privileged), period)
            except Exception as err:
                self.fail(err, by_policy=True)
                return False
            self._rows.append((obs, obs.tcp))
            if self.record_trace:
                self._states.append(env.data.qpos.copy())
            self._progress = ProgressWindow(period)
            _add_progress(self._progress, obs)
            if self.on_step is not None:
                self.on_step(env)
            self.running = not env.done and self.max_steps != 0
        except Exception as err:  # an episode must never abort the batch
            self.fail(err)
        return self.running

    def observation(self) -> Any:
        """What the policy sees now (`envs.policies.interface.observe`)."""
        return observe(self.env, self.privileged)

    def act(self) -> Any:
        """The policy's action for the coming period (None after an error, which ended the episode)."""
        try:
            observation = self.observation()
        except Exception as err:
            self.fail(err)
            return None
        try:
            return self.policy.act(observation)
        except Exception as err:
            self.fail(err, by_policy=True)
            return None

    def command(self, action: Any) -> PeriodCommand | None:
        """The env's prepared period (envs.sim.env.PeriodCommand) of ``action``: the pose and stiffness its controller
        holds for it (with a twist, the pose led by the feed-forward); None when the episode has ended (an error, a bad
        action)."""
        if not self.running:
            return None
        try:
            if not isinstance(action, Action):
                raise ActionError(f"{type(self.policy).__name__}.act returned a {type(action).__name__}, not an "
                                  "Action")
            for name in ("pose", "anchor"):
                value = getattr(action, name)
                if not (isinstance(value, Pose) or (name == "anchor" and value is None)):
                    raise ActionError(f"{type(self.policy).__name__}.act returned an Action whose {name} is a "
                                      f"{type(value).__name__}, not an envs.poses.Pose")
            period = self.env.prepare_period(action, feedforward_gain=self.gain)
        except ActionError as err:
            self.fail(err, by_policy=True, in_action=True)
            return None
        except Exception as err:
            self.fail(err)
            return None
        self._action = action
        return period

    def physics(self, period: PeriodCommand) -> None:
        """The env's physics of the prepared period (``env.run_period``; safe on a thread of its own: it touches this
        episode's env only)."""
        try:
            self.env.run_period(period)
        except Exception as err:
            self.fail(err)

    def complete(self, period: PeriodCommand) -> None:
        """Score the period the env ran (``env.finish_period``) and book it (nothing after an error in ``physics``)."""
        if not self.running:
            return
        env = self.env
        try:
            result = env.finish_period(period)
            if period.stiffness is not None:  # None: a controller without a Cartesian stiffness
                self._commanded.append(period.stiffness[:3, :3].copy())
                if self.record_trace:
                    self._rotational.append(_rotational_stiffness(self._action, period.stiffness))
            _add_progress(self._progress, result.obs)
            self._steps += 1
            if self.record_trace:
                self._rows.append((result.obs, period.commanded))
                self._states.append(env.data.qpos.copy())
            if self.on_step is not None:
                self.on_step(env)
            self.running = not env.done and (self.max_steps is None or self._steps < self.max_steps)
        except Exception as err:
            self.fail(err)

    def finish(self) -> tuple[EpisodeRecord, EpisodeTrace | None]:
        """The episode's record (scored from the env's last observation) and trace."""
        rec = self.record
        if not self._finished:
            self._finished = True
            try:
                self._score()
            except Exception as err:
                self.fail(err)
        rec.wall_s = time.perf_counter() - self._wall
        trace = None
        rows, commanded = self._rows, self._commanded
        if self.record_trace and rows:
            k = np.stack(commanded[:1] + commanded) if commanded else np.full((len(rows), 3, 3), np.nan)
            kr = np.array(self._rotational[:1] + self._rotational) if self._rotational else np.full(len(rows), np.nan)
            trace = _trace_of(rows, k[:len(rows)], kr[:len(rows)])
            if len(self._states) == len(rows):
                trace.sim_qpos = np.array(self._states)
        return rec, trace

    def _score(self) -> None:
        rec, env = self.record, self.env
        rec.steps = self._steps
        obs = env.observation
        rec.success = bool(obs.success)
        ins = obs.insertion
        if rec.success:
            rec.reason = "success"
            rec.time_to_insert_s = float(env.tracker.success_time_s)
        else:
            reason = env.reason or "not inserted"
            rec.reason = (f"{reason} (depth {ins.depth_m * 1e3:.1f} mm, lateral {ins.lateral_m * 1e3:.2f} mm, "
                          f"tilt {ins.tilt_deg:.1f} deg, yaw {ins.yaw_error_deg:.1f} deg, "
                          f"speed {ins.speed_m_s * 1e3:.1f} mm/s, hole {obs.hole})")
            rec.failure = self._progress.failure(reason)
        rec.final_pos = obs.peg_tip.pos.tolist()
        rec.final_quat = obs.peg_tip.quat.tolist()
        rec.final_pos_error_mm = norm(obs.peg_tip.pos - env.goal.pos) * 1e3
        rec.final_angle_error_deg = float(np.rad2deg(quat_angle_rad(obs.peg_tip.quat, env.goal.quat)))
        rec.insertion_depth_mm = float(ins.depth_m * 1e3)
        rec.lateral_error_mm = float(ins.lateral_m * 1e3)
        rec.tilt_deg = float(ins.tilt_deg)
        rec.wall_penetration_mm = float(ins.wall_penetration_m * 1e3)
        rec.grasp_shift_mm = norm(obs.peg_tip.pos - obs.tcp.pos) * 1e3
        for key, value in env.stats.summary().items():
            setattr(rec, key, float("nan") if value is None else float(value))
        rec.touched = bool(rec.peak_contact_force_n > CONTACT_THRESHOLD_N)
        if self._commanded:
            eig = eigh_sym(np.stack(self._commanded))[0]
            rec.min_stiffness_n_m, rec.max_stiffness_n_m = float(eig.min()), float(eig.max())
            rec.start_stiffness_eig_n_m, rec.final_stiffness_eig_n_m = eig[0].tolist(), eig[-1].tolist()

    def fail(self, err: BaseException, by_policy: bool = False, in_action: bool = False) -> None:
        """End the episode as "error: Type: message at file:line" (an episode must never abort the batch); an error
        ``by_policy`` (its reset or act raised, or ``in_action``: its action is not one the controller can command)
        of a user's policy as "policy_error: ..." with the policy's traceback (module docstring)."""
        rec = self.record
        kind = "policy_error" if by_policy and self.user_policy else "error"
        tb = err.__traceback__
        if kind == "policy_error":  # where in the policy's own code; none for its action, which our code refused
            tb = None if in_action else _policy_frames(tb)
        last = traceback.extract_tb(tb)[-1] if tb else None
        where = f" at {Path(last.filename).name}:{last.lineno}" if last else ""
        try:
            text = str(err)
        except Exception:  # noqa: BLE001 -- an exception that cannot print itself still ends only its episode
            text = "(its message could not be printed)"
        rec.success, rec.failure = False, kind
        rec.reason = f"{kind}: {type(err).__name__}: {text.splitlines()[0] if text else ''}{where}"
        if kind == "policy_error":
            rec.traceback = policy_traceback(err, tb, self.policy)
        self.running = False
        self._finished = True


_LOOP_MODULES = (__name__, "envs.rollout.lockstep")
"""The episode loop's own modules: their frames are left out of a policy's traceback."""


def _policy_frames(tb: Any) -> Any:
    """The traceback ``tb`` from its first frame outside the episode loop on (the policy's own call)."""
    while tb is not None and tb.tb_frame.f_globals.get("__name__") in _LOOP_MODULES:
        tb = tb.tb_next
    return tb


def policy_traceback(err: BaseException, tb: Any, policy: Any) -> str:
    """The traceback of a user's policy's error as Python prints it, ``tb`` its frames from the policy's own on;
    without them (an action our code refused), the exception line and where the policy's class is defined."""
    try:
        text = "".join(traceback.format_exception(type(err), err, tb))
    except Exception:  # noqa: BLE001 -- an exception that cannot print itself
        text = f"{type(err).__name__}: (its message could not be printed)\n"
    if tb is None:
        import inspect

        cls = type(policy)
        try:
            where = f"{inspect.getsourcefile(cls)}, line {inspect.getsourcelines(cls)[1]}"
        except (OSError, TypeError):
            where = "its source is not available"
        text = f"the policy {cls.__module__}.{cls.__qualname__} ({where}):\n{text}"
    return text


def _add_progress(progress: ProgressWindow, obs: Any) -> None:
    """One period of the failure judge (envs.rollout.failure): depth, contact force, |peg_tip - tcp|."""
    progress.add(obs.insertion.depth_m, obs.contact_force_n, norm(obs.peg_tip.pos - obs.tcp.pos))


def _rotational_stiffness(action: Action, stiffness: FloatArray) -> float:
    """The rotational stiffness ``action`` commands, N m/rad: its own, the mean of K_r's diagonal of its (6, 6)
    stiffness, or else the k_r of K_r = k_r I in the 6x6 ``stiffness`` the controller holds (its default's)."""
    if action.rotational_stiffness is not None:
        return float(action.rotational_stiffness)
    if action.stiffness is not None and np.shape(action.stiffness) == (6, 6):
        return float(np.trace(np.asarray(action.stiffness, dtype=float)[3:, 3:]) / 3.0)
    k_r = stiffness.diagonal()[3:]
    return float(k_r[0]) if k_r[0] == k_r[1] == k_r[2] else float(np.trace(stiffness[3:, 3:]) / 3.0)


def _trace_of(rows: list[tuple[Any, Pose]], stiffness: FloatArray, rot_stiffness: FloatArray) -> EpisodeTrace:
    """The EpisodeTrace of the (observation, commanded pose) rows of an episode."""
    obs = [o for o, _ in rows]

    def stack(get: Callable[[Any], Any]) -> Any:
        return np.array([get(o) for o in obs])

    return EpisodeTrace(
        times_s=stack(lambda o: o.time_s), pos=stack(lambda o: o.peg_tip.pos), quat=stack(lambda o: o.peg_tip.quat),
        cmd_pos=np.array([c.pos for _, c in rows]), cmd_quat=np.array([c.quat for _, c in rows]),
        force_n=stack(lambda o: o.contact_force_n), stiffness=stiffness, tcp_pos=stack(lambda o: o.tcp.pos),
        tcp_quat=stack(lambda o: o.tcp.quat), qpos=stack(lambda o: o.qpos), qvel=stack(lambda o: o.qvel),
        wrist_wrench=stack(lambda o: o.wrist_wrench), success=stack(lambda o: bool(o.success)),
        sensed_wrench=stack(lambda o: o.sensed_wrench), rot_stiffness=rot_stiffness)
