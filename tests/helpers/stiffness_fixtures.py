"""Synthetic demos with the scripted expert's stiffness schedule, and tiny stiffness skills (no physics)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from envs.demos.file import DemoSet, save_demos
from envs.policies.stiffness_schedule import StiffnessSchedule, expert_stiffness
from rflow.model import ModelConfig
from rflow.skill_io import PoseSkill, fit_pose_skill
from rflow.train import TrainConfig
from tests.helpers.skill_fixtures import GOAL_POS, synthetic_demos

HOLE_AXIS = np.array([0.0, 0.0, 1.0])
OPENING = GOAL_POS + 0.02 * HOLE_AXIS  # the goal lies 20 mm deep in the hole
SCHEDULE = StiffnessSchedule()

SMALL = TrainConfig(model=ModelConfig(layers=4, width=32, log_scale_clamp=0.5), epochs=20, transitions_per_epoch=1024,
                    horizon=20, prior_weight=0.3, seed=0, threads=1)


def stiffness_demos(n: int = 5, m: int = 60, seed: int = 0) -> DemoSet:
    """`synthetic_demos` with the expert's stiffness at every sample (ending at the in-hole goal stiffness)."""
    demos = synthetic_demos(n=n, m=m, seed=seed)
    k = expert_stiffness(demos.pos, OPENING, HOLE_AXIS, SCHEDULE)
    return replace(demos, stiffness=k, goal_stiffness=SCHEDULE.goal_stiffness(HOLE_AXIS))


def write_stiffness_demo_file(folder: Path, **kwargs: object) -> Path:
    """Save `stiffness_demos(**kwargs)` to folder/demos.npz."""
    return save_demos(folder / "demos.npz", stiffness_demos(**kwargs))


def small_stiffness_skill(config: TrainConfig = SMALL, layout: str = "joint") -> tuple[PoseSkill, DemoSet]:
    """A joint R^3 x S^3 x SPD(3) skill (or, with ``layout`` "separate_stiffness", two pose models and one on
    R^3 x SPD(3)) trained briefly on `stiffness_demos`, and those demos."""
    demos = stiffness_demos()
    skill = fit_pose_skill(demos.pos, demos.quat, demos.dt, config, layout, progress=False, stiffness=demos.stiffness)
    skill.metadata.update(shape=demos.shape, clearance_m=demos.clearance_m,
                          demo_starts={"pos": demos.pos[:, 0].tolist(), "quat": demos.quat[:, 0].tolist()})
    return skill, demos
