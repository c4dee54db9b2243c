"""`pih warmup`: compile the numba kernels once, so the first real run does not wait for them.

    pih warmup

The impedance law, the IK step, the per-physics-step sensing and the flow passes are compiled with numba and
cached on disk beside their modules (``cache=True``), per argument types. Compiling them takes tens of seconds
(README: `pih warmup`), which the first `pih run` of a fresh clone would otherwise spend. This runs the code paths
of a run on a tiny throw-away skill -- a reset (IK), a few closed-loop steps of an episode with the flow (impedance
law, nullspace IK, sensing, tool load) and the flow's plan -- so every kernel is compiled with the argument types
a run uses (the scripted demos and the evaluation call the same kernels with the same types: after this they add
no cache entry). It writes nothing but numba's cache. `setup.sh` calls it.
"""

from __future__ import annotations

import argparse
import time


EXAMPLES: tuple[str, ...] = ('pih warmup',)
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """`pih warmup` has no options."""


def main(args: argparse.Namespace) -> int:
    """Compile the kernels by running the code paths of a run once; returns 0."""
    from envs.evaluation.evaluate import EvaluationConfig
    from envs.policies.flow_skill import generate_plan, make_policy
    from envs.poses import Pose
    from envs.rollout.episode import StartPose, run_episode
    from envs.sim.env import PegInHoleEnv
    from envs.sim.episode_config import EpisodeConfig
    from envs.task.perturbation import Perturbation
    from rflow.bench import synthetic_pose_demos
    from rflow.model import ModelConfig
    from rflow.skill_io import fit_pose_skill
    from rflow.train import TrainConfig

    wall = time.perf_counter()
    pos, quat, dt = synthetic_pose_demos(n=2, m=50)
    tiny = TrainConfig(model=ModelConfig(layers=2, width=8), epochs=1, transitions_per_epoch=64, horizon=5,
                       threads=1)
    skill = fit_pose_skill(pos, quat, dt, tiny, progress=False)
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=0.05))
    config = EvaluationConfig()
    start = env.nominal_start()
    policy = make_policy(skill, "closed-loop", config.lookahead_s)
    run_episode(env, policy, StartPose(0, 0, start, Perturbation()), feedforward_gain=config.feedforward_gain)
    generate_plan(skill, Pose(pos=pos[0, 0], quat=quat[0, 0]), 1.0, env.control_period_s)
    print(f"pih warmup: numba kernels compiled and cached in {time.perf_counter() - wall:.1f} s")
    return 0


__all__ = ["EXAMPLES", "add_arguments", "main"]
