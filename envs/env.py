"""The peg-in-hole episode: the one place that owns the simulator state (MjData) of an episode.

Each ``step`` holds one commanded peg_tip pose for one control period (default 10 ms = 10 physics steps at
1 kHz, i.e. commands at 100 Hz) while the Cartesian impedance controller runs at the physics rate:

    tau = J^T (K e - D v) + nullspace(q_ref) + c(q, qdot)      (controllers.impedance)

with q_ref from a mink NullspaceReference that follows the commanded pose. After the period the state is
checked (NaN, MuJoCo's bad-qpos/qvel/qacc warnings, joint speeds) and the insertion is scored from the
MEASURED peg_tip pose (envs.success). An episode ends on success, at the time limit, or on an instability;
physics failures are recorded as the end reason, never raised.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import mujoco
import numpy as np
import numpy.typing as npt

from controllers.errors import ControllerError
from controllers.ik import IKConfig, NullspaceReference, solve_ik
from controllers.impedance import CartesianImpedanceController, ImpedanceConfig, validate_stiffness
from envs.errors import EnvError
from envs.poses import (
    Pose,
    StartRegion,
    format_pose,
    nominal_start,
    resample_trajectory,
    rotate,
    sample_start_poses,
    validate_pose,
)
from envs.scene import Scene, SceneConfig, build_scene
from envs.success import (
    MIN_ENTRY_DEPTH_M,
    Assessment,
    InsertionState,
    SuccessConfig,
    SuccessTracker,
    assess_insertion,
    insertion_state,
)

FloatArray = npt.NDArray[np.float64]

REASON_SUCCESS = "success"
REASON_TIME_LIMIT = "time_limit"
REASON_INSTABILITY = "instability"
"""End reasons; an instability reason reads 'instability: <what was detected>'."""

MAX_START_DRAWS = 100
"""reset(seed) redraws unreachable or colliding starts at most this many times."""

_BAD_STATE_WARNINGS: tuple[mujoco.mjtWarning, ...] = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)


@dataclass(frozen=True)
class EpisodeConfig:
    """How an episode runs and ends.

    Attributes:
        control_period_s: time one commanded pose is held (a multiple of the physics timestep).
        time_limit_s: the episode ends (reason "time_limit") once this much simulated time has passed.
        success: insertion criteria (envs.success).
        stop_on_success: end the episode when the success tracker declares success; False keeps it
            running (the scripted expert holds the peg in the hole to let it settle).
        max_joint_speed_rad_s: a joint faster than this is an instability (the Panda's limit is 2.6 rad/s).
        start_penetration_m: a start pose whose contacts penetrate deeper than this is rejected.
        nullspace_iterations: mink iterations per command of the nullspace joint reference.
        start_region: where ``reset`` samples a start when none is given.
        ik: IK settings for placing the arm at the start pose.
    """

    control_period_s: float = 0.01
    time_limit_s: float = 20.0
    success: SuccessConfig = field(default_factory=SuccessConfig)
    stop_on_success: bool = True
    max_joint_speed_rad_s: float = 10.0
    start_penetration_m: float = 1e-3
    nullspace_iterations: int = 3
    start_region: StartRegion = field(default_factory=StartRegion)
    ik: IKConfig = field(default_factory=IKConfig)

    def __post_init__(self) -> None:
        for name in ("control_period_s", "time_limit_s", "max_joint_speed_rad_s", "start_penetration_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise EnvError(f"EpisodeConfig.{name}={value!r} must be a positive finite number")
        if self.nullspace_iterations < 1:
            raise EnvError(f"EpisodeConfig.nullspace_iterations={self.nullspace_iterations} must be >= 1")


@dataclass(frozen=True)
class Observation:
    """What the episode exposes after a reset or a step (world frame, SI units).

    Attributes:
        time_s: simulated time since the reset.
        qpos, qvel: arm joint positions (rad) and velocities (rad/s), (7,).
        flange, peg_tip: measured poses (pos m, quat w, x, y, z).
        wrench: (6,) [force N; torque N m] the environment exerts on the peg: the sum over the peg's
            contacts of mj_contactForce rotated to the world frame, torque about the peg_tip.
        insertion: the peg_tip relative to the target hole (depth, lateral, tilt, yaw error, in_hole).
        hole: the hole the peg_tip is in (None: none; another shape: wrong hole).
        inserted: the success criteria hold at this instant.
        success: the success tracker has declared success (criteria held for hold_s).
    """

    time_s: float
    qpos: FloatArray
    qvel: FloatArray
    flange: Pose
    peg_tip: Pose
    wrench: FloatArray
    insertion: InsertionState
    hole: str | None
    inserted: bool
    success: bool


@dataclass(frozen=True)
class StepResult:
    """Outcome of one control period: the observation, whether the episode ended and why, and extras.

    ``info`` holds "target" (the commanded Pose), "q_ref" (the nullspace joint reference) and "step"
    (index of the control step, from 1).
    """

    obs: Observation
    done: bool
    reason: str | None
    info: dict[str, Any]


def _site_pose(data: mujoco.MjData, site_id: int) -> Pose:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site_id])
    return Pose(pos=data.site_xpos[site_id].copy(), quat=quat)


class PegInHoleEnv:
    """A Panda holding a peg above the shape sorter; commands are peg_tip poses (see the module docstring).

    Usage::

        env = PegInHoleEnv()
        obs = env.reset(seed=0)                 # or reset(start_pose=Pose(pos, quat))
        result = env.step(env.goal)             # hold the goal pose for one control period
    """

    def __init__(self, scene_config: SceneConfig = SceneConfig(),
                 controller_config: ImpedanceConfig = ImpedanceConfig(),
                 episode_config: EpisodeConfig = EpisodeConfig(), scene: Scene | None = None):
        """Args:
            scene_config: what to build (ignored when ``scene`` is given).
            controller_config: impedance gains and torque limits.
            episode_config: control period, time limit, success and instability checks.
            scene: an already built scene to reuse (its config must have peg_mode "held").

        Raises:
            EnvError: a free-peg scene, or a control period that is not a multiple of the timestep.
        """
        self.scene = scene if scene is not None else build_scene(scene_config)
        if self.scene.config.peg_mode != "held":
            raise EnvError(f"PegInHoleEnv needs peg_mode='held', got {self.scene.config.peg_mode!r}")
        self.config = episode_config
        self.model = self.scene.model
        self.data = mujoco.MjData(self.model)
        timestep = float(self.model.opt.timestep)
        ratio = episode_config.control_period_s / timestep
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise EnvError(f"control_period_s={episode_config.control_period_s} is not a multiple of the "
                           f"physics timestep {timestep} s")
        self.n_substeps = int(round(ratio))
        ids = self.scene.ids
        self.peg_tip_site = ids.peg_tip_site
        self.flange_site = ids.flange_site
        self._peg_geoms = frozenset(ids.peg_geoms)
        self.q_nominal = (self.model.key_qpos[ids.home_key].copy() if ids.home_key is not None
                          else self.model.qpos0.copy())
        try:
            self.controller = CartesianImpedanceController(self.model, self.peg_tip_site, controller_config)
            self.nullspace = NullspaceReference(self.model, self.peg_tip_site, self.q_nominal,
                                                iterations=episode_config.nullspace_iterations,
                                                config=episode_config.ik)
        except ControllerError as err:
            raise EnvError(f"cannot control the scene's peg_tip: {err}") from None
        goal_pos, goal_quat = self.scene.goal_pose()
        self.goal = Pose(pos=goal_pos, quat=goal_quat)
        hole_pos, hole_quat = self.scene.hole_pose(self.scene.config.shape)
        self.hole = Pose(pos=hole_pos, quat=hole_quat)
        self.hole_axis = rotate(hole_quat, [0.0, 0.0, 1.0])  # out of the hole
        self._holes = self.scene.hole_specs()
        self._hole_pos = np.array([spec.pos for spec in self._holes.values()])
        self._hole_axes = np.array([rotate(spec.quat, [0.0, 0.0, 1.0]) for spec in self._holes.values()])
        self.tracker = SuccessTracker(episode_config.success)
        self._warning_counts = np.zeros(len(_BAD_STATE_WARNINGS), dtype=int)
        self._steps = 0
        self._done = True
        self._reason: str | None = "not reset"
        self._obs: Observation | None = None
        self.start: Pose | None = None

    # ------------------------------------------------------------------------------------------- queries

    @property
    def shape(self) -> str:
        """The peg's shape (and target hole)."""
        return self.scene.config.shape

    @property
    def control_period_s(self) -> float:
        """Seconds per step: n_substeps physics timesteps."""
        return self.n_substeps * float(self.model.opt.timestep)

    @property
    def done(self) -> bool:
        """The episode has ended (or was never reset)."""
        return self._done

    @property
    def reason(self) -> str | None:
        """Why the episode ended (None while running)."""
        return None if not self._done else self._reason

    @property
    def observation(self) -> Observation:
        """The latest observation.

        Raises:
            EnvError: before the first reset.
        """
        if self._obs is None:
            raise EnvError("no observation yet: call reset() first")
        return self._obs

    def nominal_start(self) -> Pose:
        """The centre of the start region: above the hole opening along its axis, goal orientation."""
        return nominal_start(self.hole.pos, self.hole_axis, self.goal.quat, self.config.start_region)

    def sample_start(self, rng: np.random.Generator) -> Pose:
        """One start pose from ``config.start_region`` (see envs.poses.StartRegion)."""
        return sample_start_poses(self.nominal_start(), self.config.start_region, rng, 1)[0]

    # ------------------------------------------------------------------------------------------- episode

    def reset(self, seed: int | None = None, start_pose: Pose | Sequence[npt.ArrayLike] | None = None) -> Observation:
        """Start an episode with the peg_tip at ``start_pose`` at rest.

        Without ``start_pose``, starts are drawn from ``config.start_region`` with ``seed`` until one is
        reachable and collision-free (at most MAX_START_DRAWS draws). The joints come from mink IK from the
        nominal posture (keyframe "home"); velocities are zero and the controller's torque state is set to
        the gravity torque.

        Raises:
            EnvError: a malformed start pose, an unreachable one (naming the pose), or one in collision.
        """
        if start_pose is not None:
            return self._reset_at(self._as_pose(start_pose, "start pose"))
        rng = np.random.default_rng(seed)
        errors = []
        for _ in range(MAX_START_DRAWS):
            try:
                return self._reset_at(self.sample_start(rng))
            except EnvError as err:
                errors.append(str(err))
        raise EnvError(f"no reachable start in {MAX_START_DRAWS} draws from the start region (last: {errors[-1]})")

    def _reset_at(self, start: Pose) -> Observation:
        try:
            q = solve_ik(self.model, self.peg_tip_site, start.pos, start.quat, self.q_nominal, self.config.ik)
        except ControllerError as err:
            raise EnvError(f"start pose {format_pose(start)} is unreachable ({err})") from None
        data = self.data
        mujoco.mj_resetData(self.model, data)
        data.qpos[:] = q
        data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, data)
        depth = self._deepest_penetration()
        if depth > self.config.start_penetration_m:
            raise EnvError(f"start pose {format_pose(start)} is in collision ({depth * 1e3:.1f} mm penetration)")
        self.controller.reset(data.qfrc_bias[self.controller.dof_slice])
        self.nullspace.reset(q)
        self.tracker.reset()
        self._warning_counts = self._bad_warning_counts()
        self._steps = 0
        self._done = False
        self._reason = None
        self.start = start
        self._obs = self._observe()
        return self._obs

    def step(self, target: Pose | Sequence[npt.ArrayLike], stiffness: npt.ArrayLike | None = None) -> StepResult:
        """Hold the commanded peg_tip pose for one control period under impedance control.

        Args:
            target: commanded peg_tip pose, a Pose or (pos (3,), quat (4,) w, x, y, z).
            stiffness: optional 6x6 SPD Cartesian stiffness (world frame); the controller's default if None.

        Returns:
            StepResult; ``done`` with ``reason`` "success", "time_limit" or "instability: ...".

        Raises:
            EnvError: a malformed target or stiffness, or stepping an episode that has ended.
        """
        if self._done:
            raise EnvError(f"the episode has ended ({self._reason}); call reset() first")
        pose = self._as_pose(target, "target pose")
        if stiffness is not None:
            try:
                stiffness = validate_stiffness(stiffness)
            except ControllerError as err:
                raise EnvError(f"bad stiffness: {err}") from None
        try:
            q_ref = self.nullspace.update(pose.pos, pose.quat)
        except ControllerError as err:
            raise EnvError(f"nullspace reference failed for target {format_pose(pose)}: {err}") from None
        problem: str | None = None
        try:
            with np.errstate(all="ignore"):
                self.controller.step(self.data, pose.pos, pose.quat, stiffness, q_ref, self.n_substeps)
        except (np.linalg.LinAlgError, ControllerError, FloatingPointError) as err:
            problem = f"controller failed ({type(err).__name__}: {err})"
        self._steps += 1
        problem = problem or self._instability()
        obs = self._observe(track=problem is None)
        self._obs = obs
        reason: str | None = None
        if problem is not None:
            reason = f"{REASON_INSTABILITY}: {problem}"
        elif obs.success and self.config.stop_on_success:
            reason = REASON_SUCCESS
        elif obs.time_s >= self.config.time_limit_s - 1e-9:
            reason = REASON_TIME_LIMIT
        if reason is not None:
            self._done, self._reason = True, reason
        return StepResult(obs=obs, done=reason is not None, reason=reason,
                          info={"target": pose, "q_ref": q_ref, "step": self._steps})

    # ------------------------------------------------------------------------------------------- helpers

    @staticmethod
    def _as_pose(value: Pose | Sequence[npt.ArrayLike], what: str) -> Pose:
        if isinstance(value, Pose):
            return validate_pose(value.pos, value.quat, what)
        try:
            pos, quat = value
        except (TypeError, ValueError):
            raise EnvError(f"{what} must be a Pose or a pair (pos, quat), got {type(value).__name__}") from None
        return validate_pose(pos, quat, what)

    def _bad_warning_counts(self) -> npt.NDArray[np.int_]:
        return np.array([self.data.warning[int(w)].number for w in _BAD_STATE_WARNINGS], dtype=int)

    def _instability(self) -> str | None:
        """Describe a physics failure after a control period, or None."""
        now = f"t={self._steps * self.control_period_s:.3f} s"
        counts = self._bad_warning_counts()
        fired = [w.name for w, new, old in zip(_BAD_STATE_WARNINGS, counts, self._warning_counts) if new > old]
        self._warning_counts = counts
        if fired:
            return f"MuJoCo warning {', '.join(fired)} at {now} (MuJoCo reset the state)"
        data = self.data
        if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))
                and np.all(np.isfinite(data.qacc))):
            return f"non-finite state at {now}"
        speed = float(np.max(np.abs(data.qvel)))
        if speed > self.config.max_joint_speed_rad_s:
            return f"joint speed {speed:.1f} rad/s exceeds {self.config.max_joint_speed_rad_s} rad/s at {now}"
        return None

    def _deepest_penetration(self) -> float:
        data = self.data
        if data.ncon == 0:
            return 0.0
        return float(max(0.0, -np.min(data.contact.dist[: data.ncon])))

    def contact_wrench(self) -> FloatArray:
        """[force; torque about peg_tip] (6,) that contacts exert on the peg, world frame.

        For contact i with frame rows (normal, tangent1, tangent2) F_i (3x3) and mj_contactForce f_i (6,) in
        that frame (the force of geom1 on geom2): f_world = +-F_i^T f_i[:3] (+ when the peg is geom2),
        torque = sum (p_i - p_tip) x f_world + F_i^T f_i[3:].
        """
        data, model = self.data, self.model
        wrench = np.zeros(6)
        local = np.zeros(6)
        tip = data.site_xpos[self.peg_tip_site]
        for i in range(data.ncon):
            contact = data.contact[i]
            on_geom1 = contact.geom1 in self._peg_geoms
            on_geom2 = contact.geom2 in self._peg_geoms
            if on_geom1 == on_geom2 or contact.efc_address < 0:
                continue
            mujoco.mj_contactForce(model, data, i, local)
            frame = contact.frame.reshape(3, 3)
            sign = 1.0 if on_geom2 else -1.0
            force = sign * frame.T @ local[:3]
            wrench[:3] += force
            wrench[3:] += np.cross(contact.pos - tip, force) + sign * frame.T @ local[3:]
        return wrench

    def assess(self, peg_tip: Pose | None = None) -> Assessment:
        """Score a peg_tip pose (default: the measured one) against the holes (envs.success).

        Shortcut, exact: a peg_tip is in a hole only deeper than MIN_ENTRY_DEPTH_M below its opening, so
        while it is above every opening (depth_h = -(p - p_h) . z_h <= MIN_ENTRY_DEPTH_M for all holes h)
        only the target hole's state is computed.
        """
        tip = _site_pose(self.data, self.peg_tip_site) if peg_tip is None else peg_tip
        depths = -np.einsum("hi,hi->h", tip.pos - self._hole_pos, self._hole_axes)
        if np.all(depths <= MIN_ENTRY_DEPTH_M):
            state = insertion_state(tip.pos, tip.quat, self._holes[self.shape])
            return Assessment(None, state, False)
        return assess_insertion(tip.pos, tip.quat, self._holes, self.shape, self.scene.config.insertion_depth_m,
                                self.config.success)

    def _observe(self, track: bool = True) -> Observation:
        data = self.data
        time_s = self._steps * self.control_period_s
        flange = _site_pose(data, self.flange_site)
        peg_tip = _site_pose(data, self.peg_tip_site)
        finite = np.all(np.isfinite(peg_tip.pos)) and np.all(np.isfinite(peg_tip.quat))
        if finite and np.linalg.norm(peg_tip.quat) > 0.5:
            assessment = self.assess(peg_tip)
        else:
            nan_state = InsertionState(np.nan, np.nan, np.nan, np.nan, False)
            assessment = Assessment(None, nan_state, False)
        success = self.tracker.update(time_s, assessment.inserted and track)
        return Observation(
            time_s=time_s,
            qpos=data.qpos.copy(),
            qvel=data.qvel.copy(),
            flange=flange,
            peg_tip=peg_tip,
            wrench=self.contact_wrench(),
            insertion=assessment.state,
            hole=assessment.hole,
            inserted=assessment.inserted,
            success=success,
        )


def track_trajectory(env: PegInHoleEnv, pos: npt.ArrayLike, quat: npt.ArrayLike,
                     on_step: Callable[[StepResult], None] | None = None,
                     stiffness: npt.ArrayLike | None = None) -> StepResult | None:
    """Command a pose trajectory sampled at the control period, one pose per step, until it ends or the
    episode ends (a reset episode is required).

    Args:
        env: an environment after ``reset``.
        pos: (K, 3) commanded peg_tip positions, one per control step.
        quat: (K, 4) commanded orientations (w, x, y, z).
        on_step: called with every StepResult (e.g. to record or render).
        stiffness: optional 6x6 stiffness for every step.

    Returns:
        the last StepResult (None for an empty trajectory).

    Raises:
        EnvError: mismatched shapes or a malformed pose.
    """
    p = np.asarray(pos, dtype=float)
    q = np.asarray(quat, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (p.shape[0], 4):
        raise EnvError(f"trajectory must be pos (K, 3) and quat (K, 4), got {p.shape} and {q.shape}")
    result = None
    for k in range(p.shape[0]):
        result = env.step((p[k], q[k]), stiffness)
        if on_step is not None:
            on_step(result)
        if result.done:
            break
    return result


def replay_trajectory(env: PegInHoleEnv, pos: npt.ArrayLike, quat: npt.ArrayLike, dt: float,
                      on_step: Callable[[StepResult], None] | None = None, hold_s: float = 0.0,
                      stiffness: npt.ArrayLike | None = None) -> StepResult | None:
    """Execute a pose trajectory sampled every ``dt`` seconds (e.g. a demo or a generated skill).

    The trajectory is resampled to the control period (positions linearly, quaternions by slerp; the
    command at step k is the pose at time k * control_period) and commanded from the current state,
    then its last pose is held for ``hold_s``. Call ``env.reset`` first (e.g. at the first pose).

    Returns:
        the last StepResult (None when no step was taken).

    Raises:
        EnvError: malformed trajectory or dt.
    """
    p = np.asarray(pos, dtype=float)
    q = np.asarray(quat, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (p.shape[0], 4) or p.shape[0] < 2:
        raise EnvError(f"trajectory must be pos (K>=2, 3) and quat (K, 4), got {p.shape} and {q.shape}")
    if not (np.isfinite(dt) and dt > 0.0):
        raise EnvError(f"trajectory dt={dt!r} must be a positive number of seconds")
    duration = dt * (p.shape[0] - 1)
    period = env.control_period_s
    steps = int(np.ceil(duration / period - 1e-9)) + int(round(max(hold_s, 0.0) / period))
    times = np.minimum(period * np.arange(1, steps + 1), duration)
    cmd_pos, cmd_quat = resample_trajectory(dt * np.arange(p.shape[0]), p, q, times)
    return track_trajectory(env, cmd_pos, cmd_quat, on_step=on_step, stiffness=stiffness)
