"""Small synthetic pose skills and demo files for the skill / evaluation / train-CLI tests (fast, no physics)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from envs.demos.file import DemoSet, save_demos
from envs.poses import quat_from_rotvec, quat_mul, slerp
from rflow.model import ModelConfig
from rflow.skill_io import PoseSkill, fit_pose_skill
from rflow.train import TrainConfig

GOAL_POS = np.array([0.675, -0.051, 0.203])
GOAL_QUAT = np.array([0.0, 0.99213864, -0.12514362, 0.0]) / np.linalg.norm([0.0, 0.99213864, -0.12514362, 0.0])

TINY = TrainConfig(model=ModelConfig(layers=2, width=16), epochs=2, transitions_per_epoch=256, horizon=5, seed=0,
                   threads=1)
TINY_ARGS = ["--epochs", "2", "--layers", "2", "--width", "16", "--subsample", "1", "--horizon", "5",
             "--transitions-per-epoch", "256", "--threads", "1", "--quiet"]
"""`pih train` options for a tiny skill, quietly (the command-line tests)."""


def synthetic_demos(n: int = 3, m: int = 40, shape: str = "square", seed: int = 0) -> DemoSet:
    """N smooth demos from starts above the goal down to it (minimum-jerk in time), ending exactly there."""
    rng = np.random.default_rng(seed)
    tau = np.linspace(0.0, 1.0, m)
    s = tau**3 * (10 - 15 * tau + 6 * tau**2)
    pos, quat = [], []
    for _ in range(n):
        start = GOAL_POS + np.array([rng.uniform(-0.08, 0.0), rng.uniform(-0.05, 0.05), rng.uniform(0.15, 0.2)])
        q0 = quat_mul(quat_from_rotvec(rng.uniform(-0.2, 0.2, 3)), GOAL_QUAT)
        pos.append(start + s[:, None] * (GOAL_POS - start))
        q = slerp(q0, GOAL_QUAT, s)
        q[-1] = GOAL_QUAT
        quat.append(q / np.linalg.norm(q, axis=-1, keepdims=True))
    p = np.stack(pos)
    p[:, -1] = GOAL_POS
    return DemoSet(pos=p, quat=np.stack(quat), dt=0.05, goal_pos=GOAL_POS.copy(), goal_quat=GOAL_QUAT.copy(),
                   shape=shape, clearance_m=0.001, config={"source": "synthetic"})


def write_demo_file(folder: Path, **kwargs: object) -> Path:
    """Save `synthetic_demos(**kwargs)` to folder/demos.npz."""
    return save_demos(folder / "demos.npz", synthetic_demos(**kwargs))


def tiny_skill(layout: str = "separate", shape: str = "square") -> PoseSkill:
    """A barely trained skill on synthetic demos, with the metadata `pih evaluate` needs."""
    demos = synthetic_demos(shape=shape)
    skill = fit_pose_skill(demos.pos, demos.quat, demos.dt, TINY, layout, progress=False)
    skill.metadata = {"shape": shape, "clearance_m": demos.clearance_m,
                      "demo_starts": {"pos": demos.pos[:, 0].tolist(), "quat": demos.quat[:, 0].tolist()}}
    return skill
