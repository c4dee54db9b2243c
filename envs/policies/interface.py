"""The interface every insertion policy implements, so the testbed scores any skill alike.

A policy is any object with two methods (the `Policy` protocol; no base class to inherit):

    policy.reset(observation, period_s)     # once per episode, with the observation at the start pose
    action = policy.act(observation)        # once per control period (10 ms by default)

The episode loop (envs.rollout.episode.run_episode) resets the simulator at a start pose with the episode's
perturbation (hole-pose error, grasp offset), calls ``reset`` with the first `Observation`, then every control
period calls ``act`` with the latest observation and hands the `Action` to the environment, whose controller turns
it into the pose and stiffness it holds for one period, and in the end scores the MEASURED peg (envs.task.success),
never what the policy commanded. The RiemannianFlow skill (envs.policies.flow_skill), the scripted expert
(envs.policies.expert; `pih demos` records it), a replay of recorded poses (envs.policies.replay; `pih render
--demos` shows one) and a user's policy (`pih evaluate --policy`) all run through it.

What a policy sees is what a real cell measures: joint positions and velocities, the tcp pose from the arm's
kinematics (the nominal peg_tip, the frame a policy commands), the wrist F/T reading, the gripper opening, the
time, and the NOMINAL hole and goal poses (where the cell believes the hole is, e.g. from its CAD model). Never the
true, perturbed hole pose, the peg's own pose in the grasp or the contact forces on it: those are the simulator's
truth. A privileged teacher (the scripted expert) may get the true hole through one explicit, named option:
``run_episode(..., privileged=True)`` (`pih evaluate --privileged`) fills ``Observation.privileged``; it is None
otherwise.

An `Action` (controllers.action, re-exported here) is the commanded tcp pose, optionally a stiffness (6x6, or a
translational 3x3 with an optional rotational scalar) and optionally the feed-forward the controller adds: with a
``twist`` xi (and ``accel``) the controller commands ``anchor`` led by K^-1 (D(q) xi + Lambda(q) xi') + ``push``
(controllers.feedforward), so a compliant arm moves at the intended velocity instead of lagging behind it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from controllers.action import Action
from envs.poses import Pose

__all__ = ["Action", "Observation", "Policy", "PolicyTask", "PrivilegedState", "is_policy", "observe",
           "policy_task"]  # Action: controllers.action's, re-exported for the policies

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PrivilegedState:
    """Simulator truth for a privileged teacher only (``run_episode(..., privileged=True)``).

    Attributes:
        hole: the true (perturbed) target hole frame (pos m, quat w, x, y, z; its z axis out of the hole).
        hole_axis: (3,) that z axis, world frame.
        goal: the true goal pose of the peg_tip in the perturbed hole.
    """

    hole: Pose
    hole_axis: FloatArray
    goal: Pose


@dataclass(frozen=True)
class Observation:
    """What a policy sees after a reset or a control period: what a real cell measures (module docstring).

    Attributes:
        time_s: seconds since the episode's start.
        qpos, qvel: (7,) arm joint positions (rad) and velocities (rad/s).
        gripper_width_m: opening between the finger pads (0 for a welded peg).
        tcp: the measured tcp pose (the nominal peg_tip through the arm's kinematics), world frame.
        wrist_wrench: (6,) [force N; torque N m] of the wrist F/T sensor, in the sensor frame, zeroed for the tool
            load (hand, fingers, peg), as the cell's sensor reads it (envs.sim.sensing; with the task's sensor model,
            envs.task.sensor_config: noise, bias and low-pass).
        nominal_hole: where the cell believes the target hole is (its z axis out of the hole), not the true one: the
            design pose, moved by the task's hole observation error when it sets one (envs.task.perturbation).
        nominal_goal: the tcp pose seated in that hole (without an observation error, the demonstrations' goal).
        privileged: simulator truth for a privileged teacher; None unless the episode runs with privileged=True.
    """

    time_s: float
    qpos: FloatArray
    qvel: FloatArray
    gripper_width_m: float
    tcp: Pose
    wrist_wrench: FloatArray
    nominal_hole: Pose
    nominal_goal: Pose
    privileged: PrivilegedState | None = None


@runtime_checkable
class Policy(Protocol):
    """An insertion policy: ``reset`` once per episode, ``act`` once per control period (module docstring)."""

    def reset(self, observation: Observation, period_s: float) -> None:
        """Start an episode at ``observation`` (the start pose, at rest); ``period_s``: seconds per ``act``."""

    def act(self, observation: Observation) -> Action:
        """The command for the next control period, given the latest observation."""


@dataclass(frozen=True)
class PolicyTask:
    """What a policy factory is told about the task before the first episode (`pih evaluate --policy
    MODULE:FACTORY` calls ``FACTORY(task, **options)``): the nominal cell, as a real cell's programmer knows it.

    Attributes:
        shape: the peg's cross-section and its target hole ("square", "triangle", ...).
        clearance_m: nominal gap between peg and hole walls (hole width minus peg width), m.
        control_period_s: seconds between two ``act`` calls (the action is held that long).
        time_limit_s: an episode ends unsuccessful after this much simulated time.
        force_limit_n: an episode ends ("force_limit") when the wrist force stays above this for 5 ms.
        nominal_hole, nominal_goal: as in `Observation` (not the episode's true, perturbed hole).
        translational_stiffness_n_m, rotational_stiffness_nm_rad: the controller's default stiffness, used where
            an `Action` commands none.
    """

    shape: str
    clearance_m: float
    control_period_s: float
    time_limit_s: float
    force_limit_n: float
    nominal_hole: Pose
    nominal_goal: Pose
    translational_stiffness_n_m: float
    rotational_stiffness_nm_rad: float


def policy_task(env: Any) -> PolicyTask:
    """The `PolicyTask` of a simulator (envs.sim.env.PegInHoleEnv)."""
    config = env.controller.config
    return PolicyTask(env.shape, float(env.scene.config.clearance_m), env.control_period_s,
                      float(env.config.time_limit_s), float(env.config.force_limit_n), env.nominal_hole,
                      env.nominal_goal, float(config.translational_stiffness), float(config.rotational_stiffness))


def is_policy(value: Any) -> bool:
    """Whether ``value`` has callable ``reset`` and ``act`` methods (an instance, not a class)."""
    return (not isinstance(value, type) and isinstance(value, Policy)
            and callable(getattr(value, "reset", None)) and callable(getattr(value, "act", None)))


def observe(env: Any, privileged: bool = False) -> Observation:
    """The policy's view of the simulator's latest observation (envs.sim.env.PegInHoleEnv): its measured signals and
    the nominal hole and goal; with ``privileged`` also the true hole and goal (`PrivilegedState`)."""
    obs = env.observation
    truth = PrivilegedState(env.hole, env.hole_axis, env.goal) if privileged else None
    return Observation(obs.time_s, obs.qpos, obs.qvel, obs.gripper_width_m, obs.tcp, obs.sensed_wrench,
                       env.believed_hole, env.believed_goal, truth)
