"""What an episode (envs.sim.env.PegInHoleEnv) exposes: the simulator's state after a reset or a step
(`SimulatorState`, the simulator's truth beside what a cell measures, read from MjData by an `Observer`), the outcome
of a control period (`StepResult`) and why an episode ended. A policy sees less: envs.policies.interface.Observation.

The insertion is scored from the peg's simulated pose and speed against the episode's holes (envs.task.success: seated,
inside the walls, at rest, held for hold_s); the commanded pose is never consulted.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import mujoco
import numpy as np
import numpy.typing as npt

from controllers.mujoco_c import FUNCTIONS
from envs.cell.scene import SceneIds
from envs.poses import Pose
from envs.sim import observation_kernel as kernel
from envs.sim.sensing import ContactStats, PegContacts, WristSensor
from envs.task.success import Assessment, EpisodeHoles, InsertionState, SuccessTracker
from numerics.small_linalg import norm

FloatArray = npt.NDArray[np.float64]

REASON_SUCCESS = "success"
REASON_TIME_LIMIT = "time_limit"
REASON_FORCE_LIMIT = "force_limit"
REASON_INSTABILITY = "instability"
"""End reasons; an instability reason reads 'instability: <what was detected>'."""


@dataclass(frozen=True)
class SimulatorState:
    """What the episode exposes after a reset or a step (world frame, SI units): the simulator's truth (the peg's own
    pose, the true wrench, the insertion state) beside what a cell measures.

    Attributes:
        time_s: simulated time since the reset.
        qpos, qvel: arm joint positions (rad) and velocities (rad/s), (7,).
        gripper_width_m: opening between the finger pads (0 when the peg is welded).
        flange: measured flange pose (pos m, quat w, x, y, z).
        tcp: the nominal peg_tip measured through the arm's kinematics (what the robot knows; the skill's frame).
        peg_tip: the peg's own peg_tip pose (simulator truth: it differs from ``tcp`` by the grasp offset and
            any slip or tilt in the grasp).
        wrist_wrench: (6,) [force N; torque N m] the environment exerts on the tool, from the wrist F/T sensor
            zeroed for the tool load, in the sensor frame (envs.sim.sensing): the true wrench.
        sensed_wrench: (6,) what the cell's sensor reads of it (envs.task.sensor_config: noise, bias, low-pass; the same
            array as ``wrist_wrench`` for the ideal sensor): what a policy sees.
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
    sensed_wrench: FloatArray
    contact_force_n: float
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

    obs: SimulatorState
    done: bool
    reason: str | None
    info: dict[str, Any]


def site_pose(data: mujoco.MjData, site_id: int) -> Pose:
    """The world pose of a site (a copy of its position, its rotation as a quaternion w, x, y, z)."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site_id])
    return Pose(pos=data.site_xpos[site_id].copy(), quat=quat)


class Observer:
    """Reads the SimulatorState of an episode from its MjData (module docstring)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, ids: SceneIds, arm_dof: slice, grasped: bool,
                 wrist: WristSensor, contacts: PegContacts) -> None:
        """Args:
            model, data: the episode's model and data.
            ids: the scene's sites and addresses.
            arm_dof: the arm's joints in ``data.qvel``.
            grasped: the fingers hold the peg (else it is welded: no gripper width).
            wrist, contacts: the sensors.
        """
        self.model, self.data, self.grasped, self.wrist, self.contacts = model, data, grasped, wrist, contacts
        self.floor_geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "sorter/base")  # the holes' floor
        self.flange_site, self.tcp_site, self.peg_tip_site = ids.flange_site, ids.tcp_site, ids.peg_tip_site
        self.arm_qpos, self.arm_dof = np.asarray(ids.arm_qpos_adr), arm_dof
        self.finger_qpos = np.asarray(ids.finger_qpos_adr, dtype=int)
        self._velocity = np.zeros(6)
        self._sites = np.array([self.flange_site, self.tcp_site, self.peg_tip_site], dtype=np.int64)
        self._fns = FUNCTIONS  # MuJoCo's C functions for the compiled read

    def peg_speed_m_s(self) -> float:
        """Linear speed of the peg's peg_tip (m/s), from the simulated state."""
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, self.peg_tip_site,
                                 self._velocity, 0)
        return norm(self._velocity[3:])

    def assess(self, holes: EpisodeHoles, pos: FloatArray, rot: FloatArray, speed_m_s: float | None) -> Assessment:
        """A checked peg_tip position (3,) and rotation matrix (3, 3) scored against ``holes``, at ``speed_m_s``
        (None: the simulated peg's)."""
        return holes.assess(pos, rot, self.peg_speed_m_s() if speed_m_s is None else speed_m_s)

    def observe(self, time_s: float, holes: EpisodeHoles, tracker: SuccessTracker, stats: ContactStats | None,
                track: bool = True, sensed: Callable[[FloatArray], FloatArray] | None = None) -> SimulatorState:
        """The observation at episode time ``time_s``; the success ``tracker`` is updated (with "not inserted" unless
        ``track``) and the (true) wrist force and torque are appended to the samples of ``stats`` (None: not
        sampled); ``sensed`` maps the true wrench to the sensor's reading (None: the true one)."""
        data = self.data
        poses, rotation = np.empty((3, 7)), np.empty((3, 3))  # flange, tcp, peg_tip (one compiled read)
        speed = kernel.read_sites_into(self._fns, self.model._address, data._address, self._sites, data.site_xpos,
                                       data.site_xmat, poses, rotation, self._velocity)
        flange, tcp, peg_tip = (Pose(pos=row[:3], quat=row[3:]) for row in poses)
        if speed != kernel.NOT_FINITE:  # the peg tip's pose is finite
            assessment = holes.assess(peg_tip.pos, rotation, speed)
        else:
            nan_state = InsertionState(np.nan, np.nan, np.nan, np.nan, False)
            assessment = Assessment(None, nan_state, False)
        inserted = assessment.inserted and track
        floor_n = holes.config.floor_force_n
        if inserted and floor_n > 0.0:  # the option of SuccessConfig: seated means pressed on the floor
            inserted = self.contacts.force_on(data, self.floor_geom) >= floor_n
        success = tracker.update(time_s, inserted)
        wrench = self.wrist.wrench(data)
        if stats is not None:
            stats.wrist_force_samples.append(norm(wrench[:3]))
            stats.wrist_torque_samples.append(norm(wrench[3:]))
        width = float(np.add.reduce(data.qpos[self.finger_qpos])) if self.grasped else 0.0
        return SimulatorState(
            time_s=time_s,
            qpos=data.qpos[self.arm_qpos].copy(),
            qvel=data.qvel[self.arm_dof].copy(),
            gripper_width_m=width,
            flange=flange,
            tcp=tcp,
            peg_tip=peg_tip,
            wrist_wrench=wrench,
            sensed_wrench=wrench if sensed is None else sensed(wrench),
            contact_force_n=self.contacts.normal_forces(data)[0],
            insertion=assessment.state,
            hole=assessment.hole,
            inserted=assessment.inserted,
            success=success,
        )
