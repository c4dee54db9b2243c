"""`pih warmup`: compile the numba kernels once, so the first real run does not wait for them.

    pih warmup
    pih warmup --generic-too

The impedance law, the IK step, the per-physics-step sensing and the flow passes are compiled with numba and
cached on disk beside their modules (``cache=True``), per argument types. Compiling them takes tens of seconds
(README: `pih warmup`), which the first `pih run` of a fresh clone would otherwise spend. This runs the code paths
of a run on a tiny throw-away skill -- a reset (IK), a few closed-loop steps of an episode with the flow (impedance
law, nullspace IK, sensing, tool load) and the flow's plan -- so every kernel is compiled with the argument types
a run uses (the scripted demos and the evaluation call the same kernels with the same types: after this they add
no cache entry). It writes nothing but numba's cache. `setup.sh` calls it.

With ``--generic-too`` a second process compiles the same kernels at the same time for a generic x86-64
(`numerics.cpu_dispatch.GENERIC_CPU_ENVIRONMENT`: numba caches per CPU name), which the test that records do not
depend on the CPU runs; on two cores it costs no extra wall time.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time


EXAMPLES: tuple[str, ...] = ('pih warmup', 'pih warmup --generic-too')
"""Shown at the end of --help (scripts.cli)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--generic-too."""
    parser.add_argument("--generic-too", action="store_true",
                        help="also compile the kernels for a generic x86-64, in a second process at the same time "
                             "(what NUMBA_CPU_NAME=generic runs: the test that records do not depend on the CPU)")


def generic_command() -> list[str]:
    """The command of the second process of ``--generic-too``: this warmup, without the option."""
    return [sys.executable, "-m", "scripts.cli", "warmup"]


def main(args: argparse.Namespace) -> int:
    """Compile the kernels by running the code paths of a run once (with ``--generic-too`` also in a second
    process, for a generic x86-64); returns 0, or 1 when the second process failed."""
    from batch.lifetime import die_with_parent
    from numerics.cpu_dispatch import generic_cpu_environment

    generic = None
    if args.generic_too:
        parent = os.getpid()
        generic = subprocess.Popen(generic_command(), env=generic_cpu_environment(), stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, text=True,
                                   preexec_fn=lambda: die_with_parent(parent))  # it never outlives this one
    try:
        warm_up()
    except BaseException:
        if generic is not None:
            generic.kill()
            generic.wait()
        raise
    if generic is None:
        return 0
    output, _ = generic.communicate()
    if generic.returncode != 0:
        print(f"pih warmup: error: the generic x86-64 warmup failed (exit {generic.returncode}): "
              f"{output.strip().splitlines()[-1] if output.strip() else 'no output'}", file=sys.stderr)
        return 1
    print(f"{output.strip()} (generic x86-64)")
    return 0


def warm_up() -> None:
    """Run the code paths of a run once, printing how long it took."""
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
    print(f"pih warmup: numba kernels compiled and cached in {time.perf_counter() - wall:.1f} s", flush=True)


__all__ = ["EXAMPLES", "add_arguments", "generic_command", "main", "warm_up"]
