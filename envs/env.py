"""The peg-in-hole episode: the one place that owns the simulator state (MjData) of an episode.

Each ``step`` holds one commanded pose of the ``tcp`` (the nominal peg_tip on the hand, see envs.scene) for one
control period (default 10 ms = 10 physics steps at 1 kHz, i.e. commands at 100 Hz) while the controller runs
at the physics rate (any controllers.protocol.Controller; by default the Cartesian impedance controller):

    tau = J^T (K e - D v) + nullspace(q_ref) + c(q, qdot)      (controllers.impedance)

with q_ref from a NullspaceReference (mink's IK problem, compiled) that follows the commanded pose (when its QP
has no solution in a period, the reference restarts from the measured posture; ``nullspace_failures`` counts those
periods).
A grasped peg is squeezed by both fingers with the grasp force (a generalised force on each finger joint)
and held by friction only. Its weight, which the arm's model does not contain (the peg is a separate body),
is compensated as a known tool load, as the Franka controller does with its end-effector load setting: tau_load = -J_c^T m g, with J_c the
translational Jacobian of the peg's nominal centre of mass (on the hand, half a peg below peg_mount), applied by
the controller before every physics step (CartesianImpedanceController.set_tool_load).

Every physics step the wrist F/T sensor and the peg's contacts are read (envs.sensing): their peaks over the
episode are kept, and a wrist force above ``force_limit_n`` sustained for ``force_limit_window_s`` ends the
episode with reason "force_limit" (this per-step work is compiled, envs.sensing_kernel; the
peaks live in a small state array during a control period and are copied into ``stats`` at its end). After each
period the state is checked (NaN, MuJoCo's bad-qpos/qvel/qacc warnings, joint speeds) and the insertion is scored
from the peg's MEASURED pose and speed (envs.success: seated, inside the walls, at rest, held for hold_s). An
episode ends on success, at the time limit, at the force limit or on an instability; physics failures are recorded
as the end reason, never raised.

``reset`` applies a per-episode perturbation (envs.perturbation): the sorter is moved by a hole-pose error
(mocap) and the peg is placed in the grasp with an offset along its axis, then the grasp settles for
``grasp_settle_s`` with the arm holding the start pose before the episode clock starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import mujoco
import numpy as np
import numpy.typing as npt

from controllers.errors import ControllerError
from controllers.ik import IKConfig, NullspaceReference, solve_ik
from controllers.impedance import CartesianImpedanceController, ImpedanceConfig
from controllers.protocol import Controller
from envs.errors import EnvError
from envs.perturbation import Perturbation, PerturbationRanges, perturbed_frame, sample_perturbation
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
from envs.scene import Scene, SceneConfig, build_scene, goal_from_hole
from envs import sensing_kernel
from envs.sensing import PegContacts, ToolLoad, WristSensor
from envs.shapes import PEG_LENGTH_M, peg_cross_section
from envs.task import Task, check_force_limit, check_number
from envs.geometry import all_finite, as_vector
from envs.success import (
    MIN_ENTRY_DEPTH_M,
    Assessment,
    HoleFrame,
    InsertionState,
    PegFootprint,
    SuccessConfig,
    SuccessTracker,
    frame_assessment,
    frame_state,
)
from rflow.quaternion import quat_to_mat
from rflow.small_linalg import norm

FloatArray = npt.NDArray[np.float64]

REASON_SUCCESS = "success"
REASON_TIME_LIMIT = "time_limit"
REASON_FORCE_LIMIT = "force_limit"
REASON_INSTABILITY = "instability"
"""End reasons; an instability reason reads 'instability: <what was detected>'."""

MAX_START_DRAWS = 100
"""reset(seed) redraws unreachable or colliding starts at most this many times."""

_BAD_STATE_WARNINGS: tuple[mujoco.mjtWarning, ...] = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)
_BAD_STATE_INDICES = np.array([int(w) for w in _BAD_STATE_WARNINGS])


@dataclass(frozen=True)
class EpisodeConfig:
    """How an episode runs and ends.

    Attributes:
        control_period_s: time one commanded pose is held (a multiple of the physics timestep).
        time_limit_s: the episode ends (reason "time_limit") once this much simulated time has passed.
        success: insertion criteria (envs.success).
        stop_on_success: end the episode when the success tracker declares success; False keeps it
            running (the scripted expert holds the peg in the hole to let it settle).
        force_limit_n: a wrist force above this (N), sustained for ``force_limit_window_s``, ends the episode
            as a failure "force_limit"; ``math.inf`` disables it.
        force_limit_window_s: how long the force must stay above the limit (one contact spike does not end it).
        perturbations: ranges of the per-episode hole-pose error and grasp offset.
        grasp_settle_s: physics time the grasp settles at the start pose before the episode clock starts
            (grasped peg only).
        max_joint_speed_rad_s: a joint faster than this is an instability (the Panda's limit is 2.6 rad/s).
        start_penetration_m: a start pose whose contacts penetrate deeper than this is rejected.
        nullspace_iterations: IK iterations per command of the nullspace joint reference.
        start_region: where ``reset`` samples a start when none is given.
        ik: IK settings for placing the arm at the start pose.
    """

    control_period_s: float = 0.01
    time_limit_s: float = 20.0
    success: SuccessConfig = field(default_factory=SuccessConfig)
    stop_on_success: bool = True
    force_limit_n: float = 40.0
    force_limit_window_s: float = 0.005
    perturbations: PerturbationRanges = field(default_factory=PerturbationRanges)
    grasp_settle_s: float = 0.1
    max_joint_speed_rad_s: float = 10.0
    start_penetration_m: float = 1e-3
    nullspace_iterations: int = 3
    start_region: StartRegion = field(default_factory=StartRegion)
    ik: IKConfig = field(default_factory=IKConfig)

    def __post_init__(self) -> None:
        for name in ("control_period_s", "time_limit_s", "max_joint_speed_rad_s", "start_penetration_m"):
            check_number(f"EpisodeConfig.{name}", getattr(self, name), strict=True)
        check_force_limit(self.force_limit_n, "EpisodeConfig.force_limit_n")
        for name in ("force_limit_window_s", "grasp_settle_s"):
            check_number(f"EpisodeConfig.{name}", getattr(self, name))
        if not isinstance(self.perturbations, PerturbationRanges):
            raise EnvError(f"EpisodeConfig.perturbations={self.perturbations!r} must be a PerturbationRanges")
        if self.nullspace_iterations < 1:
            raise EnvError(f"EpisodeConfig.nullspace_iterations={self.nullspace_iterations} must be >= 1")

    @classmethod
    def from_task(cls, task: Task, **overrides: Any) -> EpisodeConfig:
        """The episode settings of ``task`` (envs.task: time and force limits, perturbations, success), plus
        ``overrides``."""
        return cls(**{"time_limit_s": task.time_limit_s, "force_limit_n": task.force_limit_n,
                      "perturbations": task.perturbations, "success": task.success, **overrides})


@dataclass(frozen=True)
class Observation:
    """What the episode exposes after a reset or a step (world frame, SI units).

    Attributes:
        time_s: simulated time since the reset.
        qpos, qvel: arm joint positions (rad) and velocities (rad/s), (7,).
        gripper_width_m: opening between the finger pads (0 when the peg is welded).
        flange: measured flange pose (pos m, quat w, x, y, z).
        tcp: the nominal peg_tip measured through the arm's kinematics (what the robot knows; the skill's frame).
        peg_tip: the peg's own peg_tip pose (simulator truth: it differs from ``tcp`` by the grasp offset and
            any slip or tilt in the grasp).
        wrist_wrench: (6,) [force N; torque N m] the environment exerts on the tool, from the wrist F/T sensor
            zeroed for the tool load, in the sensor frame (envs.sensing).
        contact_force_n: sum of the environment's contact normal-force magnitudes on the peg, now.
        insertion: the peg_tip relative to the target hole (depth, lateral, tilt, yaw, in_hole, wall
            penetration, speed).
        hole: the hole the peg_tip is in (None: none; another shape: wrong hole).
        inserted: the success criteria hold at this instant.
        success: the success tracker has declared success (criteria held for hold_s).
    """

    time_s: float
    qpos: FloatArray
    qvel: FloatArray
    gripper_width_m: float
    flange: Pose
    tcp: Pose
    peg_tip: Pose
    wrist_wrench: FloatArray
    contact_force_n: float
    insertion: InsertionState
    hole: str | None
    inserted: bool
    success: bool


@dataclass
class ContactStats:
    """Peaks over an episode at the physics rate, and control-rate samples for medians (the peaks are copied from
    the compiled sense state, envs.sensing_kernel, at the end of every control period).

    Attributes:
        peak_contact_force_n: largest sum of the environment's normal-force magnitudes on the peg.
        peak_single_contact_n: largest single normal force on the peg.
        peak_wrist_force_n, peak_wrist_torque_nm: largest |F_ext| and |tau_ext| of the wrist sensor.
        peak_sustained_wrist_force_n: largest |F_ext| held for the force limit's whole window (the largest
            minimum of |F_ext| over any window of ``force_limit_window_s``): what the force limit compares.
        wrist_force_samples, wrist_torque_samples: |F_ext|, |tau_ext| at the end of every control period.
        force_limit_time_s: physics time the force first stayed above the limit for the window (None: never).
    """

    peak_contact_force_n: float = 0.0
    peak_single_contact_n: float = 0.0
    peak_wrist_force_n: float = 0.0
    peak_wrist_torque_nm: float = 0.0
    peak_sustained_wrist_force_n: float = 0.0
    wrist_force_samples: list[float] = field(default_factory=list)
    wrist_torque_samples: list[float] = field(default_factory=list)
    force_limit_time_s: float | None = None

    def summary(self) -> dict[str, float | None]:
        """Peaks and medians, JSON-ready."""
        def median(values: list[float]) -> float | None:
            return float(np.median(values)) if values else None

        return {
            "peak_contact_force_n": self.peak_contact_force_n,
            "peak_single_contact_n": self.peak_single_contact_n,
            "peak_wrist_force_n": self.peak_wrist_force_n,
            "peak_sustained_wrist_force_n": self.peak_sustained_wrist_force_n,
            "median_wrist_force_n": median(self.wrist_force_samples),
            "peak_wrist_torque_nm": self.peak_wrist_torque_nm,
            "median_wrist_torque_nm": median(self.wrist_torque_samples),
        }


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


def _block(indices: Sequence[int]) -> slice:
    """The slice of consecutive indices (views instead of copies in the step loop).

    Raises:
        EnvError: indices that are not one ascending consecutive block.
    """
    first = int(indices[0])
    if list(indices) != list(range(first, first + len(indices))):
        raise EnvError(f"arm dof addresses {list(indices)} are not one consecutive block")
    return slice(first, first + len(indices))


def _site_pose(data: mujoco.MjData, site_id: int) -> Pose:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site_id])
    return Pose(pos=data.site_xpos[site_id].copy(), quat=quat)


class PegInHoleEnv:
    """A Panda holding a peg above the shape sorter; commands are tcp poses (see the module docstring).

    Usage::

        env = PegInHoleEnv()
        obs = env.reset(seed=0)                 # or reset(start_pose=Pose(pos, quat), perturbation=...)
        result = env.step(env.goal)             # hold the goal pose for one control period
    """

    def __init__(self, scene_config: SceneConfig = SceneConfig(),
                 controller_config: ImpedanceConfig = ImpedanceConfig(),
                 episode_config: EpisodeConfig = EpisodeConfig(), scene: Scene | None = None,
                 controller: Controller | None = None):
        """Args:
            scene_config: what to build (ignored when ``scene`` is given).
            controller_config: impedance gains and torque limits of the default controller (ignored when
                ``controller`` is given).
            episode_config: control period, time limit, success, force limit, perturbations.
            scene: an already built scene to reuse (its peg must be grasped or welded).
            controller: the controller of the arm's tcp (controllers.protocol.Controller), built on
                ``scene.model``; default a CartesianImpedanceController with ``controller_config``.

        Raises:
            EnvError: a free-peg scene, a control period that is not a multiple of the timestep, or a controller
                that is not a Controller or comes without the scene it was built on.
        """
        if controller is not None and not isinstance(controller, Controller):
            raise EnvError(f"controller must implement controllers.protocol.Controller (start, set_tool_load, "
                           f"checked_stiffness, step), got {type(controller).__name__}")
        if controller is not None and scene is None:
            raise EnvError("a controller is built on a model: pass the scene whose model it drives (scene=)")
        self.scene = scene if scene is not None else build_scene(scene_config)
        if self.scene.config.peg_mode not in ("grasped", "welded"):
            raise EnvError(f"PegInHoleEnv needs a grasped or welded peg, got peg_mode={self.scene.config.peg_mode!r}")
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
        self.tcp_site = ids.tcp_site
        self.peg_tip_site = ids.peg_tip_site
        self.flange_site = ids.flange_site
        self.grasped = self.scene.config.peg_mode == "grasped"
        self._arm_qpos = np.asarray(ids.arm_qpos_adr)
        self._arm_dof = _block(ids.arm_dof_adr)
        self._finger_qpos = np.asarray(ids.finger_qpos_adr, dtype=int)
        self._finger_dof = np.asarray(ids.finger_dof_adr, dtype=int)
        self._peg_footprint = PegFootprint.of(peg_cross_section(self.shape))
        key_qpos = self.model.key_qpos[ids.home_key] if ids.home_key is not None else self.model.qpos0
        self.q_home = key_qpos.copy()
        self.q_nominal = key_qpos[self._arm_qpos].copy()
        self.arm_model = self.scene.arm_model
        self._grip_opening = key_qpos[self._finger_qpos].copy() if self.grasped else np.zeros(0)
        try:
            self.controller: Controller = controller if controller is not None else \
                CartesianImpedanceController(self.model, self.tcp_site, controller_config)
            self.nullspace = NullspaceReference(self.arm_model, "tcp", self.q_nominal,
                                                iterations=episode_config.nullspace_iterations,
                                                config=episode_config.ik)
        except ControllerError as err:
            raise EnvError(f"cannot control the scene's tcp: {err}") from None
        load = ids.hand_subtree + ((ids.peg_body,) if self.grasped else ())
        self.wrist = WristSensor(self.model, ids.ft_site, ids.wrist_force_adr, ids.wrist_torque_adr, ToolLoad(load))
        self.contacts = PegContacts(self.model, ids.peg_geoms, ids.finger_geoms)
        self._velocity = np.zeros(6)
        d = self.data
        if self.grasped:  # the peg's weight, a known tool load compensated by the controller (module docstring)
            self.controller.set_tool_load(float(self.model.body_mass[ids.peg_body]), PEG_LENGTH_M / 2)
        # the per-physics-step sensing (sensing_kernel.sense_substep): its inputs (views of self.data, built once)
        # and a state of peaks, force window and time above the force limit, copied into self.stats after a period
        window = max(1, int(round(episode_config.force_limit_window_s / timestep)))
        self._sense_state = sensing_kernel.sense_state(window)
        self._sense_inputs = (*self.wrist.kernel_inputs(d), *self.contacts.kernel_inputs(),
                              np.array([episode_config.force_limit_n, episode_config.force_limit_window_s, timestep],
                                       dtype=np.float64), self._sense_state)
        nominal_hole_pos, nominal_hole_quat = self.scene.hole_pose(self.shape)
        self.nominal_hole = Pose(pos=nominal_hole_pos, quat=nominal_hole_quat)
        goal_pos, goal_quat = self.scene.goal_pose()
        self.nominal_goal = Pose(pos=goal_pos, quat=goal_quat)
        self._set_hole_error(Perturbation())
        self.tracker = SuccessTracker(episode_config.success)
        self.stats = ContactStats()
        self.perturbation = Perturbation()
        self._warning_counts = np.zeros(len(_BAD_STATE_WARNINGS), dtype=int)
        self.nullspace_failures = 0
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
        """The centre of the start region: above the nominal hole opening along its axis, goal orientation."""
        axis = rotate(self.nominal_hole.quat, [0.0, 0.0, 1.0])
        return nominal_start(self.nominal_hole.pos, axis, self.nominal_goal.quat, self.config.start_region)

    def sample_start(self, rng: np.random.Generator) -> Pose:
        """One start pose from ``config.start_region`` (see envs.poses.StartRegion)."""
        return sample_start_poses(self.nominal_start(), self.config.start_region, rng, 1)[0]

    # ------------------------------------------------------------------------------------------- episode

    def reset(self, seed: int | None = None, start_pose: Pose | Sequence[npt.ArrayLike] | None = None,
              perturbation: Perturbation | None = None) -> Observation:
        """Start an episode with the tcp at ``start_pose`` at rest.

        The perturbation (hole-pose error, grasp offset) is ``perturbation`` or, when None, drawn first from
        the generator seeded with ``seed`` within ``config.perturbations``. Without ``start_pose``, starts are
        then drawn from ``config.start_region`` with the same generator until one is reachable and
        collision-free (at most MAX_START_DRAWS draws). The joints come from `solve_ik` (mink's problem,
        compiled) from the nominal posture (keyframe "home"); velocities are zero and the controller's torque
        state is set to the gravity torque.

        Raises:
            EnvError: a malformed start pose, an unreachable one (naming the pose), or one in collision.
        """
        rng = np.random.default_rng(seed)
        if perturbation is None:
            perturbation = sample_perturbation(self.config.perturbations, rng)
        if start_pose is not None:
            return self._reset_at(self._as_pose(start_pose, "start pose"), perturbation)
        errors = []
        for _ in range(MAX_START_DRAWS):
            try:
                return self._reset_at(self.sample_start(rng), perturbation)
            except EnvError as err:
                errors.append(str(err))
        raise EnvError(f"no reachable start in {MAX_START_DRAWS} draws from the start region (last: {errors[-1]})")

    def _set_hole_error(self, perturbation: Perturbation) -> None:
        """Move the sorter (mocap) by the hole-pose error and update the holes the scorer uses."""
        scene = self.scene
        hole_pos, hole_quat = self.nominal_hole.pos, self.nominal_hole.quat
        sorter_pos, sorter_quat = perturbed_frame(scene.sorter_pos, scene.sorter_quat, hole_pos, hole_quat,
                                                  perturbation)
        self.data.mocap_pos[scene.ids.sorter_mocap] = sorter_pos
        self.data.mocap_quat[scene.ids.sorter_mocap] = sorter_quat
        holes = {}
        for shape, spec in scene.hole_specs().items():
            pos, quat = perturbed_frame(spec.pos, spec.quat, hole_pos, hole_quat, perturbation)
            holes[shape] = replace(spec, pos=tuple(float(v) for v in pos), quat=tuple(float(v) for v in quat))
        self._holes = holes
        self._hole_frames = {shape: HoleFrame.of(spec) for shape, spec in holes.items()}  # once per episode
        self._hole_pos = np.array([spec.pos for spec in holes.values()])
        self._hole_axes = np.array([rotate(spec.quat, [0.0, 0.0, 1.0]) for spec in holes.values()])
        target = holes[self.shape]
        self.hole = Pose(pos=np.asarray(target.pos), quat=np.asarray(target.quat))
        self.hole_axis = rotate(target.quat, [0.0, 0.0, 1.0])  # out of the hole
        goal_pos, goal_quat = goal_from_hole(target.pos, target.quat, scene.config.insertion_depth_m)
        self.goal = Pose(pos=goal_pos, quat=goal_quat)

    def _reset_at(self, start: Pose, perturbation: Perturbation) -> Observation:
        try:
            q = solve_ik(self.arm_model, "tcp", start.pos, start.quat, self.q_nominal, self.config.ik)
        except ControllerError as err:
            raise EnvError(f"start pose {format_pose(start)} is unreachable ({err})") from None
        model, data = self.model, self.data
        mujoco.mj_resetData(model, data)
        data.qpos[:] = self.q_home
        data.qpos[self._arm_qpos] = q
        data.qvel[:] = 0.0
        self._set_hole_error(perturbation)
        if self.grasped:
            self._place_peg_in_grasp(perturbation.grasp_offset_m)
        mujoco.mj_forward(model, data)
        depth = self._deepest_penetration()
        if depth > self.config.start_penetration_m:
            raise EnvError(f"start pose {format_pose(start)} is in collision ({depth * 1e3:.1f} mm penetration)")
        self.controller.start(data)
        q_ref = q.copy()
        self.nullspace.reset(q_ref)
        self._warning_counts = self._bad_warning_counts()
        if self.grasped:
            self._settle_grasp(start, q_ref)
        self.perturbation = perturbation
        self.tracker.reset()
        self.stats = ContactStats()
        self._sense_state[:] = 0.0
        self.nullspace_failures = 0
        self._steps = 0
        self._done = False
        self._reason = None
        self.start = start
        self._obs = self._observe()
        return self._obs

    def _place_peg_in_grasp(self, offset_m: float) -> None:
        """Peg frame = tcp frame shifted by L back and ``offset_m`` out along the peg axis; fingers on its sides."""
        data = self.data
        mujoco.mj_kinematics(self.model, data)
        rot = data.site_xmat[self.tcp_site].reshape(3, 3)
        adr = self.scene.ids.peg_qpos_adr
        data.qpos[adr:adr + 3] = data.site_xpos[self.tcp_site] + rot[:, 2] * (offset_m - PEG_LENGTH_M)
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, data.site_xmat[self.tcp_site])
        data.qpos[adr + 3:adr + 7] = quat
        data.qpos[self._finger_qpos] = self._grip_opening
        data.qfrc_applied[self._finger_dof] = -self.scene.config.grasp_force_n

    def _settle_grasp(self, start: Pose, q_ref: FloatArray) -> None:
        """Hold the start pose while the grasp forces build up (``grasp_settle_s``)."""
        steps = int(round(self.config.grasp_settle_s / float(self.model.opt.timestep)))
        if steps > 0:
            self.controller.step(self.data, start.pos, start.quat, None, q_ref, steps)

    def step(self, target: Pose | Sequence[npt.ArrayLike], stiffness: npt.ArrayLike | None = None) -> StepResult:
        """Hold the commanded tcp pose for one control period under impedance control.

        Args:
            target: commanded tcp pose, a Pose or (pos (3,), quat (4,) w, x, y, z).
            stiffness: optional 6x6 SPD Cartesian stiffness (world frame); the controller's default if None.

        Returns:
            StepResult; ``done`` with ``reason`` "success", "time_limit", "force_limit" or "instability: ...".

        Raises:
            EnvError: a malformed target or stiffness, or stepping an episode that has ended.
        """
        if self._done:
            raise EnvError(f"the episode has ended ({self._reason}); call reset() first")
        pose = self._as_pose(target, "target pose")
        if stiffness is not None:
            try:
                stiffness = self.controller.checked_stiffness(stiffness)
            except ControllerError as err:
                raise EnvError(f"bad stiffness: {err}") from None
        try:
            q_ref = self.nullspace.update(pose.pos, pose.quat)
        except ControllerError:  # the posture QP had no solution this period: hold the measured posture
            self.nullspace.reset(self.data.qpos[self._arm_qpos])
            q_ref = self.nullspace.q
            self.nullspace_failures += 1
        problem: str | None = None
        force_limited = False
        try:
            with np.errstate(all="ignore"):
                ran = self.controller.step(self.data, pose.pos, pose.quat, stiffness, q_ref, self.n_substeps,
                                           after_substep=self._sense)
            force_limited = ran < self.n_substeps or self.stats.force_limit_time_s is not None  # also on the last substep
        except (np.linalg.LinAlgError, ControllerError, FloatingPointError) as err:
            problem = f"controller failed ({type(err).__name__}: {err})"
        finally:
            self._copy_sense_state()
        self._steps += 1
        problem = problem or self._instability()
        obs = self._observe(track=problem is None and not force_limited)
        self._obs = obs
        reason: str | None = None
        if problem is not None:
            reason = f"{REASON_INSTABILITY}: {problem}"
        elif force_limited:
            reason = REASON_FORCE_LIMIT
        elif obs.success and self.config.stop_on_success:
            reason = REASON_SUCCESS
        elif obs.time_s >= self.config.time_limit_s - 1e-9:
            reason = REASON_TIME_LIMIT
        if reason is not None:
            self._done, self._reason = True, reason
        return StepResult(obs=obs, done=reason is not None, reason=reason,
                          info={"target": pose, "q_ref": q_ref, "step": self._steps})

    def _sense(self) -> bool:
        """Update the episode's contact and wrist peaks, force window and time above the force limit after a physics
        step (sensing_kernel.sense_substep; ``_copy_sense_state`` puts them in ``stats``); True when the force limit
        hits."""
        data = self.data
        contact = data.contact
        wrist_rot, wrist_pos, xipos, force, torque, bodies, load, counted, scratch, limits, state = self._sense_inputs
        if not sensing_kernel.sense_substep(wrist_rot, wrist_pos, xipos, force, torque, bodies, load, contact.geom,
                                            contact.efc_address, data.efc_force, counted, scratch, limits, state):
            return False
        stats = self.stats
        stats.force_limit_time_s = stats.force_limit_time_s or self._steps * self.control_period_s
        return True

    def _copy_sense_state(self) -> None:
        """Copy the peaks of the sense state (sensing_kernel) into ``stats``."""
        state, stats, k = self._sense_state, self.stats, sensing_kernel
        stats.peak_contact_force_n = float(state[k.PEAK_CONTACT])
        stats.peak_single_contact_n = float(state[k.PEAK_SINGLE])
        stats.peak_wrist_force_n = float(state[k.PEAK_FORCE])
        stats.peak_wrist_torque_nm = float(state[k.PEAK_TORQUE])
        stats.peak_sustained_wrist_force_n = float(state[k.PEAK_SUSTAINED])

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
        return self.data.warning.number[_BAD_STATE_INDICES]

    def _instability(self) -> str | None:
        """Describe a physics failure after a control period, or None."""
        counts, before = self._bad_warning_counts(), self._warning_counts
        self._warning_counts = counts
        if (counts > before).any():
            fired = [w.name for w, new, old in zip(_BAD_STATE_WARNINGS, counts, before) if new > old]
            return f"MuJoCo warning {', '.join(fired)} at {self._now()} (MuJoCo reset the state)"
        data = self.data
        if not (all_finite(data.qpos) and all_finite(data.qvel) and all_finite(data.qacc)):
            return f"non-finite state at {self._now()}"
        speed = float(np.max(np.abs(data.qvel[self._arm_dof])))
        if speed > self.config.max_joint_speed_rad_s:
            return f"joint speed {speed:.1f} rad/s exceeds {self.config.max_joint_speed_rad_s} rad/s at {self._now()}"
        return None

    def _now(self) -> str:
        """The episode time for messages."""
        return f"t={self._steps * self.control_period_s:.3f} s"

    def _deepest_penetration(self) -> float:
        data = self.data
        if data.ncon == 0:
            return 0.0
        return float(max(0.0, -np.min(data.contact.dist[: data.ncon])))

    def peg_speed_m_s(self) -> float:
        """Linear speed of the peg's peg_tip (m/s), from the simulated state."""
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, self.peg_tip_site,
                                 self._velocity, 0)
        return norm(self._velocity[3:])

    def assess(self, peg_tip: Pose | None = None, speed_m_s: float | None = None) -> Assessment:
        """Score a peg_tip pose and speed (default: the simulated peg's) against the real holes (envs.success).

        Shortcut, exact: a peg_tip is in a hole only deeper than MIN_ENTRY_DEPTH_M below its opening, so
        while it is above every opening (depth_h = -(p - p_h) . z_h <= MIN_ENTRY_DEPTH_M for all holes h)
        only the target hole's state is computed, and otherwise only the holes it is below the opening of.

        Raises:
            EnvError: a given pose that is not 3 + 4 finite numbers, or a zero quaternion.
        """
        if peg_tip is None:
            tip = _site_pose(self.data, self.peg_tip_site)
            return self._assess(tip.pos, quat_to_mat(tip.quat), speed_m_s)
        pos = as_vector(peg_tip.pos, 3, "peg_tip_pos")
        return self._assess(pos, quat_to_mat(as_vector(peg_tip.quat, 4, "peg_tip_quat")), speed_m_s)

    def _assess(self, pos: FloatArray, rot: FloatArray, speed_m_s: float | None) -> Assessment:
        """`assess` of a checked peg_tip position (3,) and rotation matrix (3, 3) with the episode's hole frames."""
        speed = self.peg_speed_m_s() if speed_m_s is None else speed_m_s
        depths = -np.einsum("hi,hi->h", pos - self._hole_pos, self._hole_axes)
        if np.all(depths <= MIN_ENTRY_DEPTH_M):
            state = frame_state(pos, rot, self._hole_frames[self.shape], speed_m_s=speed)
            return Assessment(None, state, False)
        candidates = {shape: frame for (shape, frame), depth in zip(self._hole_frames.items(), depths)
                      if depth > MIN_ENTRY_DEPTH_M or shape == self.shape}  # only these can hold the peg_tip
        return frame_assessment(pos, rot, candidates, self.shape, self.scene.config.insertion_depth_m,
                                self.config.success, self._peg_footprint, speed)

    def _observe(self, track: bool = True) -> Observation:
        data = self.data
        time_s = self._steps * self.control_period_s
        flange = _site_pose(data, self.flange_site)
        tcp = _site_pose(data, self.tcp_site)
        peg_tip = _site_pose(data, self.peg_tip_site)
        if all_finite(peg_tip.pos) and all_finite(peg_tip.quat) and norm(peg_tip.quat) > 0.5:
            assessment = self._assess(peg_tip.pos, quat_to_mat(peg_tip.quat), None)
        else:
            nan_state = InsertionState(np.nan, np.nan, np.nan, np.nan, False)
            assessment = Assessment(None, nan_state, False)
        success = self.tracker.update(time_s, assessment.inserted and track)
        wrench = self.wrist.wrench(data)
        if self._steps > 0:
            self.stats.wrist_force_samples.append(norm(wrench[:3]))
            self.stats.wrist_torque_samples.append(norm(wrench[3:]))
        width = float(np.add.reduce(data.qpos[self._finger_qpos])) if self.grasped else 0.0
        return Observation(
            time_s=time_s,
            qpos=data.qpos[self._arm_qpos].copy(),
            qvel=data.qvel[self._arm_dof].copy(),
            gripper_width_m=width,
            flange=flange,
            tcp=tcp,
            peg_tip=peg_tip,
            wrist_wrench=wrench,
            contact_force_n=self.contacts.normal_forces(data)[0],
            insertion=assessment.state,
            hole=assessment.hole,
            inserted=assessment.inserted,
            success=success,
        )


def track_trajectory(env: PegInHoleEnv, pos: npt.ArrayLike, quat: npt.ArrayLike,
                     on_step: Callable[[StepResult], None] | None = None,
                     stiffness: npt.ArrayLike | None = None) -> StepResult | None:
    """Command a tcp pose trajectory sampled at the control period, one pose per step, until it ends or the
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
