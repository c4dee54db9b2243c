"""How an episode of the simulator (envs.sim.env.PegInHoleEnv) runs and ends: `EpisodeConfig`, built from a task
(`EpisodeConfig.from_task`) or directly."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from controllers.ik import IKConfig
from envs.errors import EnvError
from envs.poses import StartRegion
from envs.task.perturbation import PerturbationRanges
from envs.task.sensor_config import WristSensorConfig
from envs.task.task import SuccessConfig, Task, check_force_limit, check_number


@dataclass(frozen=True)
class EpisodeConfig:
    """How an episode runs and ends.

    Attributes:
        control_period_s: time one commanded pose is held (a multiple of the physics timestep).
        time_limit_s: the episode ends (reason "time_limit") once this much simulated time has passed.
        success: insertion criteria (envs.task.success).
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
        wrist_sensor: the wrist sensor's model (envs.task.sensor_config; default the exact wrench).
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
    wrist_sensor: WristSensorConfig = field(default_factory=WristSensorConfig)

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
        """The episode settings of ``task`` (envs.task.task: time and force limits, perturbations, success), plus
        ``overrides``."""
        return cls(**{"time_limit_s": task.time_limit_s, "force_limit_n": task.force_limit_n,
                      "perturbations": task.perturbations, "success": task.success, "wrist_sensor": task.sensing,
                      **overrides})
