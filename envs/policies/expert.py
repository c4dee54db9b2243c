"""The scripted expert of envs.demos.record as a `Policy`: a privileged teacher, scored like any other policy.

At ``reset`` it plans the expert's path (envs.policies.expert_plan.plan_expert_path: align above the hole, slow entry,
seat, hold) from the measured start pose into the TRUE hole, which only a privileged observation carries
(``run_episode(..., privileged=True)``, `pih evaluate --policy envs.policies.expert:make --privileged`);
without it ``reset`` raises. Each ``act`` commands the plan's next sample with the plan's twist and acceleration as
feed-forward (the controller leads the pose by them, controllers.feedforward) and, with a stiffness schedule,
the schedule's translational stiffness at the measured tcp position (envs.policies.stiffness_schedule); after the plan's
end it holds the goal. `pih demos` records this policy (envs.demos.record.execute_demo) with a plan made beforehand
from the requested start pose (``plan=``), so a demo's path does not depend on where the arm settled.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from envs.errors import EnvError
from envs.policies.expert_plan import ExpertConfig, plan_expert_path, plan_twists
from envs.policies.interface import Action, Observation, PolicyTask
from envs.policies.stiffness_schedule import expert_stiffness
from envs.poses import Pose

FloatArray = npt.NDArray[np.float64]


class ScriptedExpertPolicy:
    """The scripted expert (module docstring); needs privileged observations."""

    def __init__(self, config: ExpertConfig = ExpertConfig(),
                 plan: tuple[npt.ArrayLike, npt.ArrayLike] | None = None):
        """Args:
            config: the expert (its path and stiffness schedule).
            plan: the path to follow, (K, 3) positions and (K, 4) quaternions, one sample per control period from
                the first period's end (`plan_expert_path` at those times); None: plan at ``reset`` from the
                measured start pose.

        Raises:
            EnvError: a config that is no ExpertConfig, or a plan of mismatched shapes.
        """
        if not isinstance(config, ExpertConfig):
            raise EnvError(f"ScriptedExpertPolicy needs an ExpertConfig, got {type(config).__name__}")
        if plan is not None:
            pos, quat = (np.asarray(a, dtype=np.float64) for a in plan)
            if pos.ndim != 2 or pos.shape[1:] != (3,) or quat.shape != (pos.shape[0], 4) or pos.shape[0] < 2:
                raise EnvError(f"an expert plan must be positions (K >= 2, 3) and quaternions (K, 4), got {pos.shape} "
                               f"and {quat.shape}")
            plan = (pos, quat)
        self.config = config
        self.plan = plan
        self.plan_pos: FloatArray = np.zeros((0, 3))
        self.plan_quat: FloatArray = np.zeros((0, 4))
        self._twist: FloatArray = np.zeros((0, 6))
        self._accel: FloatArray = np.zeros((0, 6))
        self._hole_pos: FloatArray = np.zeros(3)
        self._hole_axis: FloatArray = np.zeros(3)
        self._step = 0

    def reset(self, observation: Observation, period_s: float) -> None:
        """Plan from the measured tcp pose into the true hole (``observation.privileged``), or take the given plan.

        Raises:
            EnvError: no privileged state in the observation, or a start the expert cannot plan from.
        """
        truth = observation.privileged
        if truth is None:
            raise EnvError("the scripted expert is a privileged teacher (it plans into the true hole): run it with "
                           "privileged=True (pih evaluate --privileged)")
        if self.plan is not None:
            self.plan_pos, self.plan_quat = self.plan
        else:
            steps = int(round(self.config.duration_s / period_s))
            times = period_s * np.arange(1, steps + 1)
            start = Pose(pos=np.asarray(observation.tcp.pos), quat=np.asarray(observation.tcp.quat))
            self.plan_pos, self.plan_quat = plan_expert_path(start, truth.hole.pos, truth.hole_axis, truth.goal,
                                                             self.config, times)
        self._twist, self._accel = plan_twists(self.plan_pos, self.plan_quat, period_s)
        self._hole_pos, self._hole_axis = np.asarray(truth.hole.pos), np.asarray(truth.hole_axis)
        self._step = 0

    def act(self, observation: Observation) -> Action:
        """The plan's next sample with its twist and acceleration (the goal, at rest, after the plan's end) and the
        schedule's stiffness at the measured tcp position."""
        if self.plan_pos.shape[0] == 0:
            raise EnvError("ScriptedExpertPolicy.act before reset")
        last = self.plan_pos.shape[0] - 1
        k = min(self._step, last)
        self._step += 1
        schedule = self.config.stiffness
        stiffness = (None if schedule is None
                     else expert_stiffness(observation.tcp.pos, self._hole_pos, self._hole_axis, schedule))
        pose = Pose(pos=self.plan_pos[k], quat=self.plan_quat[k])
        if self._step > last + 1:
            return Action(pose, stiffness, twist=np.zeros(6))
        return Action(pose, stiffness, twist=self._twist[k], accel=self._accel[k])


def make(task: PolicyTask, **options: Any) -> ScriptedExpertPolicy:
    """`pih evaluate --policy envs.policies.expert:make --privileged`: the expert with its default config.

    Raises:
        EnvError: any option (it takes none).
    """
    if options:
        raise EnvError(f"the scripted expert takes no policy options, got {sorted(options)}")
    return ScriptedExpertPolicy()
