"""The peg-in-hole episode: the one place that owns the simulator state (MjData) of an episode.

Each ``step`` takes a policy's `Action` (controllers.action) or a pose of the ``tcp`` (the nominal peg_tip on the hand,
see envs.cell.scene) for one control period (default 10 ms = 10 physics steps at 1 kHz, i.e. commands at 100 Hz); the
controller turns it into the pose and stiffness it holds (with a twist, the pose led by its velocity feed-forward) and
runs at the physics rate (any controllers.interface.Controller; by default the Cartesian impedance controller):

    tau = J^T (K e - D v) + nullspace(q_ref) + c(q, qdot)      (controllers.impedance)

with q_ref from a NullspaceReference (mink's IK problem, compiled) that follows the commanded pose (when its QP
has no solution in a period, the reference restarts from the measured posture; ``nullspace_failures`` counts those
periods). A grasped peg is squeezed by both fingers with the grasp force (a generalised force on each finger joint)
and held by friction only; its weight, which the arm's model does not contain, is a known tool load the controller
compensates (tau_load = -J_c^T m g at the peg's nominal centre of mass, half a peg below peg_mount; as the Franka
controller does with its end-effector load setting).

After every physics step the wrist F/T sensor and the peg's contacts are read (envs.sim.sensing.EpisodeSensing): a
wrist force above ``force_limit_n`` sustained for ``force_limit_window_s`` ends the episode ("force_limit"). After
each period the state is checked (envs.sim.instability) and observed (envs.sim.observation), the insertion scored from
the peg's MEASURED pose and speed (envs.task.success). An episode ends on success, at the time limit, at the force limit
or on an instability; physics failures are recorded as the end reason, never raised. The configuration is
envs.sim.episode_config.EpisodeConfig. A policy's episode, its actions one period at a time, is run by
envs.rollout.episode (demos, rendering and evaluation alike).

``reset`` applies a per-episode perturbation (envs.task.perturbation): the sorter is moved by a hole-pose error
(mocap), the hole the cell believes in is moved by its observation error, the episode's frictions, payload and joint
friction are written into the model (envs.sim.friction, envs.sim.model_error) and the peg is placed in the grasp with
its offset along its axis and its in-hand pose error, then the grasp settles for
``grasp_settle_s`` with the arm holding the start pose before the episode clock starts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import mujoco
import numpy as np
import numpy.typing as npt

from controllers.action import Action
from controllers.errors import ControllerError
from controllers.ik import NullspaceReference, solve_ik
from controllers.impedance import CartesianImpedanceController, ImpedanceConfig
from controllers.impedance_kernel import STATUS_OK
from controllers.interface import Controller
from envs.cell.scene import Scene, build_scene
from envs.cell.scene_config import SceneConfig, goal_from_hole
from envs.cell.shapes import PEG_LENGTH_M, peg_cross_section
from envs.errors import ActionError, EnvError
from envs.geometry import as_vector
from envs.poses import (Pose, format_pose, quat_from_rotvec_one, quat_mul_one, nominal_start, rotate,
                        sample_start_poses, validate_pose)
from envs.sim.episode_config import EpisodeConfig
from envs.sim.friction import EpisodeFriction
from envs.sim.instability import InstabilityCheck
from envs.sim.joint_friction import JointFriction
from envs.sim.model_error import ActuatorNoise, ModelError
from envs.sim.observation import (REASON_FORCE_LIMIT, REASON_INSTABILITY, REASON_SUCCESS, REASON_TIME_LIMIT,
                                  Observer, SimulatorState, StepResult, site_pose)
from envs.sim.period_kernel import controlled_period
from envs.sim.sensing import ContactStats, EpisodeSensing, JointTorqueSensors, PegContacts, ToolLoad, WristSensor
from envs.sim.sensor_reading import episode_generator
from envs.task.perturbation import Perturbation, perturbed_frame, sample_perturbation
from envs.task.success import Assessment, EpisodeHoles, PegFootprint, SuccessTracker
from numerics.quaternion import quat_to_mat

FloatArray = npt.NDArray[np.float64]

MAX_START_DRAWS = 100
"""reset(seed) redraws unreachable or colliding starts at most this many times."""


def _block(indices: Sequence[int]) -> slice:
    """The slice of consecutive indices (views instead of copies in the step loop).

    Raises:
        EnvError: indices that are not one ascending consecutive block.
    """
    first = int(indices[0])
    if list(indices) != list(range(first, first + len(indices))):
        raise EnvError(f"arm dof addresses {list(indices)} are not one consecutive block")
    return slice(first, first + len(indices))


@dataclass
class PeriodCommand:
    """One control period between `PegInHoleEnv.prepare_period` and `PegInHoleEnv.finish_period`.

    Attributes:
        pose: the tcp pose the controller holds (an action's pose, or with a twist its lead), checked (its quaternion
            normalised).
        stiffness: the checked 6x6 stiffness it holds with, or None (a controller without one).
        q_ref: the nullspace reference of the period.
        arguments: the compiled period's arguments (envs.sim.period_kernel), None for a controller other than the
            impedance controller.
        ran: physics steps completed; status: the control law's status; limit_hit: the force limit hit.
        problem: why the controller failed ("controller failed (...)"), else None.
    """

    pose: Pose
    stiffness: FloatArray | None
    q_ref: FloatArray
    arguments: tuple | None = None
    ran: int = 0
    status: int = STATUS_OK
    limit_hit: bool = False
    problem: str | None = None
    commanded: Pose | None = None
    """The pose as the controller's ``command`` gave it, before the check (what an episode's trace records)."""


def _frozen_pose(pos: npt.ArrayLike, quat: npt.ArrayLike) -> Pose:
    """A Pose on read-only copies: the nominal poses every observation and policy task hands out, which no policy
    may change for the episodes after it."""
    pos, quat = np.array(pos, dtype=np.float64), np.array(quat, dtype=np.float64)
    pos.setflags(write=False)
    quat.setflags(write=False)
    return Pose(pos=pos, quat=quat)


class PegInHoleEnv:
    """A Panda holding a peg above the shape sorter; commands are actions or tcp poses (see the module docstring).

    Usage::

        env = PegInHoleEnv()
        obs = env.reset(seed=0)                 # or reset(start_pose=Pose(pos, quat), perturbation=...)
        result = env.step(env.goal)             # hold the goal pose for one control period
        result = env.step(Action(env.goal, twist=np.zeros(6)))   # a policy's action
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
            controller: the controller of the arm's tcp (controllers.interface.Controller), built on
                ``scene.model``; default a CartesianImpedanceController with ``controller_config``.

        Raises:
            EnvError: a free-peg scene, a control period that is not a multiple of the timestep, or a controller
                that is not a Controller or comes without the scene it was built on.
        """
        if controller is not None and not isinstance(controller, Controller):
            raise EnvError(f"controller must implement controllers.interface.Controller (start, settled, "
                           f"set_tool_load, command, checked_stiffness, step), got {type(controller).__name__}")
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
        self.friction = EpisodeFriction(self.model, ids.sorter_geoms, ids.finger_geoms if self.grasped else (),
                                        ids.peg_geoms)
        self.model_error = ModelError(self.model, ids.peg_body)
        self.joint_friction = JointFriction(self.model, tuple(ids.arm_dof_adr), self.controller,
                                            episode_config.perturbations.joint_friction_model)
        self.actuator_noise = ActuatorNoise(self.controller, len(ids.arm_dof_adr), self.n_substeps)
        self.observer = Observer(self.model, self.data, ids, self._arm_dof, self.grasped, self.wrist, self.contacts)
        if self.grasped:  # the peg's weight, a known tool load compensated by the controller (module docstring)
            self.controller.set_tool_load(float(self.model.body_mass[ids.peg_body]), PEG_LENGTH_M / 2)
        joints = JointTorqueSensors(self.model, ids.ft_site, ids.arm_dof_adr,
                                    ToolLoad((ids.peg_body,) if self.grasped else ()))
        self.sensing = EpisodeSensing(self.data, self.wrist, self.contacts, episode_config.force_limit_n,
                                      episode_config.force_limit_window_s, timestep, self.n_substeps,
                                      episode_config.wrist_sensor, joints)
        self.stability = InstabilityCheck(self.data, self._arm_dof, episode_config.max_joint_speed_rad_s)
        nominal_hole_pos, nominal_hole_quat = self.scene.hole_pose(self.shape)
        self.nominal_hole = _frozen_pose(nominal_hole_pos, nominal_hole_quat)
        goal_pos, goal_quat = self.scene.goal_pose()
        self.nominal_goal = _frozen_pose(goal_pos, goal_quat)
        self.believed_hole, self.believed_goal = self.nominal_hole, self.nominal_goal
        self._set_hole_error(Perturbation())
        self.tracker = SuccessTracker(episode_config.success)
        self.perturbation = Perturbation()
        self.nullspace_failures = 0
        self._steps = 0
        self._done = True
        self._reason: str | None = "not reset"
        self._obs: SimulatorState | None = None
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
    def stats(self) -> ContactStats:
        """The episode's contact and wrist figures (peaks, samples, force-limit time; envs.sim.sensing)."""
        return self.sensing.stats

    @property
    def done(self) -> bool:
        """The episode has ended (or was never reset)."""
        return self._done

    @property
    def reason(self) -> str | None:
        """Why the episode ended (None while running)."""
        return None if not self._done else self._reason

    @property
    def observation(self) -> SimulatorState:
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
              perturbation: Perturbation | None = None) -> SimulatorState:
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
        try:
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
            raise EnvError(f"no reachable start in {MAX_START_DRAWS} draws from the start region (last: "
                           f"{errors[-1]})")
        except BaseException:  # the simulator may be half reset (also after Ctrl-C): no step until a reset succeeds
            self._done, self._reason = True, "its reset failed"
            raise

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
        self.holes = EpisodeHoles(holes, self.shape, scene.config.insertion_depth_m, self.config.success,
                                  self._peg_footprint)
        target = holes[self.shape]
        self.hole = Pose(pos=np.asarray(target.pos), quat=np.asarray(target.quat))
        self.hole_axis = rotate(target.quat, [0.0, 0.0, 1.0])  # out of the hole
        goal_pos, goal_quat = goal_from_hole(target.pos, target.quat, scene.config.insertion_depth_m)
        self.goal = Pose(pos=goal_pos, quat=goal_quat)

    def _set_believed_hole(self, perturbation: Perturbation) -> None:
        """Where the cell believes the hole and the goal are (what a policy sees as ``nominal_hole`` and
        ``nominal_goal``): the nominal ones, or with ``hole_observation = "measured"`` the true ones (a sensor that
        sees the part), moved by the episode's hole observation error (envs.task.perturbation). `_set_hole_error`
        first."""
        error = perturbation.observation_error()
        measured = self.config.perturbations.hole_observation == "measured"
        hole, goal = (self.hole, self.goal) if measured else (self.nominal_hole, self.nominal_goal)
        if error == Perturbation():
            self.believed_hole, self.believed_goal = hole, goal
            return
        self.believed_hole = Pose(*perturbed_frame(hole.pos, hole.quat, hole.pos, hole.quat, error))
        self.believed_goal = Pose(*perturbed_frame(goal.pos, goal.quat, hole.pos, hole.quat, error))

    def _reset_at(self, start: Pose, perturbation: Perturbation) -> SimulatorState:
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
        self._set_believed_hole(perturbation)
        self.friction.apply(perturbation)
        self.model_error.apply(perturbation)
        self.joint_friction.apply(perturbation)
        self.actuator_noise.reset(perturbation)
        if self.grasped:
            self._place_peg_in_grasp(perturbation)
        mujoco.mj_forward(model, data)
        depth = self._deepest_penetration()
        if depth > self.config.start_penetration_m:
            raise EnvError(f"start pose {format_pose(start)} is in collision ({depth * 1e3:.1f} mm penetration)")
        self.sensing.reset(episode_generator(perturbation))
        self._hand_joint_torque_sensors(settle=True)
        self.controller.start(data)
        q_ref = q.copy()
        self.nullspace.reset(q_ref)
        self.stability.reset()
        if self.grasped:
            self._settle_grasp(start, q_ref)
        self.controller.settled()
        self.perturbation = perturbation
        self.tracker.reset()
        self.nullspace_failures = 0
        self._steps = 0
        self._done = False
        self._reason = None
        self.start = start
        self._obs = self._observe()
        return self._obs

    def _hand_joint_torque_sensors(self, settle: bool = False) -> None:
        """Hand the controller what its link-side joint torque sensors add to what they read (its friction observer
        reads them, controllers.joint_torque_kernel): the episode's bias and this control period's noise rows, those
        the wrench estimate reads too (`EpisodeSensing.joint_torque_errors`); ``settle``: the rows of the grasp's
        settle instead (at the episode's start)."""
        hand = getattr(self.controller, "set_joint_torque_sensors", None)
        if hand is not None:
            n = len(self.q_nominal)
            steps = int(round(self.config.grasp_settle_s / float(self.model.opt.timestep))) if settle else 0
            bias, noise = self.sensing.joint_torque_errors(settle_steps=steps)
            hand(bias[:n] if settle else None, None if noise is None else noise[:, :n])

    def _place_peg_in_grasp(self, perturbation: Perturbation) -> None:
        """Peg frame = tcp frame shifted by L back and the grasp offset out along the peg axis, then (the in-hand
        pose error, envs.task.perturbation) shifted along the hand's x, tilted about its y (the fingers' closing axis)
        about the peg's top and turned about the peg's own axis; the fingers on its sides."""
        data = self.data
        mujoco.mj_kinematics(self.model, data)
        rot = data.site_xmat[self.tcp_site].reshape(3, 3)
        adr = self.scene.ids.peg_qpos_adr
        top = data.site_xpos[self.tcp_site] + rot[:, 2] * (perturbation.grasp_offset_m - PEG_LENGTH_M)
        data.qpos[adr:adr + 3] = top + rot[:, 0] * perturbation.grasp_lateral_m
        in_hand = quat_mul_one(quat_from_rotvec_one([0.0, math.radians(perturbation.grasp_tilt_deg), 0.0]),
                               quat_from_rotvec_one([0.0, 0.0, math.radians(perturbation.grasp_yaw_deg)]))
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, data.site_xmat[self.tcp_site])
        data.qpos[adr + 3:adr + 7] = quat if in_hand == [1.0, 0.0, 0.0, 0.0] else quat_mul_one(quat.tolist(), in_hand)
        data.qpos[self._finger_qpos] = self._grip_opening
        data.qfrc_applied[self._finger_dof] = -self.scene.config.grasp_force_n

    def _settle_grasp(self, start: Pose, q_ref: FloatArray) -> None:
        """Hold the start pose while the grasp forces build up (``grasp_settle_s``)."""
        steps = int(round(self.config.grasp_settle_s / float(self.model.opt.timestep)))
        if steps > 0:
            self.controller.step(self.data, start.pos, start.quat, None, q_ref, steps)

    def step(self, command: Action | Pose | Sequence[npt.ArrayLike], stiffness: npt.ArrayLike | None = None,
             feedforward_gain: float = 1.0) -> StepResult:
        """Hold a command for one control period under the controller (default impedance control).

        Args:
            command: a policy's `Action` (controllers.action), or a tcp pose to hold, a Pose or (pos (3,), quat (4,)
                w, x, y, z), which is the Action of that pose and ``stiffness``.
            stiffness: with a pose: an optional 6x6 SPD Cartesian stiffness (world frame; or a 3x3 translational one);
                the controller's default if None. An Action carries its own.
            feedforward_gain: scale of the controller's velocity feed-forward for an Action with a twist (0: none).

        Returns:
            StepResult; ``done`` with ``reason`` "success", "time_limit", "force_limit" or "instability: ...".

        Raises:
            EnvError: a malformed command or stiffness, or stepping an episode that has ended.
        """
        period = self.prepare_period(command, stiffness, feedforward_gain)
        self.run_period(period)
        return self.finish_period(period)

    def prepare_period(self, command: Action | Pose | Sequence[npt.ArrayLike], stiffness: npt.ArrayLike | None = None,
                       feedforward_gain: float = 1.0) -> PeriodCommand:
        """The first part of `step`: the controller turns the command into the period's target pose and stiffness
        (`Controller.command`: with a twist, the pose led by its feed-forward), checked; then the nullspace reference
        advances and the period's sensing and torque noise start. The physics follows in `run_period`, the scoring in
        `finish_period`.

        Raises:
            ActionError: an action the controller cannot command, or a bad stiffness (an EnvError).
            EnvError: a malformed command, or stepping an episode that has ended.
        """
        if self._done:
            raise EnvError(f"the episode has ended ({self._reason}); call reset() first")
        if isinstance(command, Action):
            if stiffness is not None:
                raise EnvError("an Action carries its own stiffness: pass stiffness= with a pose only")
            action = command
        else:  # checked below, once, as the controller returns it
            action = Action(command if isinstance(command, Pose) else Pose(*self._pose_pair(command, "target pose")),
                            stiffness)
        try:
            target, stiffness = self.controller.command(self.data, action, feedforward_gain)
        except ControllerError as err:
            raise ActionError(f"the controller cannot command this action: {err}") from None
        pose = self._as_pose(target, "target pose")
        if stiffness is not None:
            try:
                stiffness = self.controller.checked_stiffness(stiffness)
            except ControllerError as err:
                raise ActionError(f"bad stiffness: {err}") from None
        try:
            q_ref = self.nullspace.update(pose.pos, pose.quat)
        except ControllerError:  # the posture QP had no solution this period: hold the measured posture
            self.nullspace.reset(self.data.qpos[self._arm_qpos])
            q_ref = self.nullspace.q
            self.nullspace_failures += 1
        self.sensing.start_period(self._steps * self.control_period_s)
        self._hand_joint_torque_sensors()
        self.actuator_noise.start_period()
        period = PeriodCommand(pose, stiffness, q_ref, commanded=target)
        controller = self.controller
        if isinstance(controller, CartesianImpedanceController):
            try:
                period.arguments = (controller.substep_arguments(self.data, pose.pos, pose.quat, stiffness, q_ref)
                                    + self.sensing.period_arguments())
            except (np.linalg.LinAlgError, ControllerError, FloatingPointError) as err:
                period.problem = f"controller failed ({type(err).__name__}: {err})"
        return period

    def run_period(self, period: PeriodCommand) -> None:
        """The physics of a prepared period (`prepare_period`): its physics steps toward the command, each followed by
        the sensing; the outcome is stored in ``period``. With the impedance controller this is one compiled call
        (envs.sim.period_kernel) that touches this episode's MjData and buffers only and releases the GIL, so the
        periods of several episodes may run on threads at once (envs.rollout.lockstep); any other Controller runs its
        ``step`` with the sensing hook."""
        if period.problem is not None:
            return
        try:
            with np.errstate(all="ignore"):
                if period.arguments is None:
                    period.ran = self.controller.step(self.data, period.pose.pos, period.pose.quat, period.stiffness,
                                                      period.q_ref, self.n_substeps, after_substep=self._sense)
                else:
                    ran, status, limit_hit = controlled_period(self.n_substeps, *period.arguments)
                    period.ran, period.status, period.limit_hit = int(ran), int(status), bool(limit_hit)
        except (np.linalg.LinAlgError, ControllerError, FloatingPointError) as err:
            period.problem = f"controller failed ({type(err).__name__}: {err})"

    def finish_period(self, period: PeriodCommand) -> StepResult:
        """The last part of `step`: the period's sensing peaks, the instability check, the observation and
        success check and the end of the episode (module docstring)."""
        problem = period.problem
        force_limited = False
        if problem is None and period.arguments is not None:
            self.sensing.after_period(period.limit_hit)
            if period.status != STATUS_OK:
                problem = ("controller failed (ControllerError: J M^-1 J^T is not positive definite (Cholesky "
                           "failed); the arm is singular)")
        if problem is None:
            force_limited = period.ran < self.n_substeps or self.stats.force_limit_time_s is not None
        self.sensing.copy_peaks()
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
                          info={"target": period.pose, "q_ref": period.q_ref, "step": self._steps})

    def _sense(self) -> bool:
        """The hook after every physics step (envs.sim.sensing.EpisodeSensing.substep: peaks, force window, force
        limit); True when the force limit hits."""
        return self.sensing.substep()

    # ------------------------------------------------------------------------------------------- helpers

    @staticmethod
    def _as_pose(value: Pose | Sequence[npt.ArrayLike], what: str) -> Pose:
        """``value`` checked, its quaternion normalised (envs.poses.validate_pose)."""
        if isinstance(value, Pose):
            return validate_pose(value.pos, value.quat, what)
        return validate_pose(*PegInHoleEnv._pose_pair(value, what), what)

    @staticmethod
    def _pose_pair(value: Sequence[npt.ArrayLike], what: str) -> tuple[npt.ArrayLike, npt.ArrayLike]:
        """The (pos, quat) of a pair, unchecked."""
        try:
            pos, quat = value
        except (TypeError, ValueError):
            raise EnvError(f"{what} must be a Pose or a pair (pos, quat), got {type(value).__name__}") from None
        return pos, quat

    def _instability(self) -> str | None:
        """Describe a physics failure after a control period (envs.sim.instability), or None."""
        return self.stability.check(self._steps * self.control_period_s)

    def _deepest_penetration(self) -> float:
        data = self.data
        if data.ncon == 0:
            return 0.0
        return float(max(0.0, -np.min(data.contact.dist[: data.ncon])))

    def peg_speed_m_s(self) -> float:
        """Linear speed of the peg's peg_tip (m/s), from the simulated state."""
        return self.observer.peg_speed_m_s()

    def assess(self, peg_tip: Pose | None = None, speed_m_s: float | None = None) -> Assessment:
        """Score a peg_tip pose and speed (default: the simulated peg's) against the episode's holes
        (envs.task.success).

        Raises:
            EnvError: a given pose that is not 3 + 4 finite numbers, or a zero quaternion.
        """
        if peg_tip is None:
            tip = site_pose(self.data, self.peg_tip_site)
            return self.observer.assess(self.holes, tip.pos, quat_to_mat(tip.quat), speed_m_s)
        pos = as_vector(peg_tip.pos, 3, "peg_tip_pos")
        return self.observer.assess(self.holes, pos, quat_to_mat(as_vector(peg_tip.quat, 4, "peg_tip_quat")), speed_m_s)

    def _observe(self, track: bool = True) -> SimulatorState:
        """The observation now (envs.sim.observation.Observer), the success tracker updated unless not ``track``."""
        return self.observer.observe(self._steps * self.control_period_s, self.holes, self.tracker,
                                     self.stats if self._steps > 0 else None, track, self.sensing.sensed_wrench)
