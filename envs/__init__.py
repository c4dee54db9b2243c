"""The simulated Franka Panda peg-in-hole testbed (MuJoCo) and the execution and evaluation of skills on it.

Sub-packages, each with one job, from the bottom up (a sub-package imports only those below it;
tests/test_architecture.py): `io` (pih's file outputs), `cell` (the scene built in MJCF), `task` (what is asked:
the task, its presets, perturbations, sensing and success check), `sim` (the simulator at 1 kHz), `policies` (what
acts each control period), `rollout` (one episode, episodes in lockstep), then `demos`, `media`, `statistics`, and on
top `evaluation`, `datasets` and the Gymnasium environment `gym_env`. `errors`, `geometry` and `poses` are the shared
base modules.

The project's public surface is re-exported here lazily (PEP 562): ``from envs import Task, PegInHoleEnv`` imports
only the modules that define them, so ``import envs`` stays cheap.
"""

from numerics.cpu_dispatch import pin_cpu_dispatch

pin_cpu_dispatch()  # first, before numpy or torch load: numpy's, torch's and MKL's kernel choices as `pih` pins them

from pihutil.lazy import lazy_exports  # noqa: E402

EXPORTS: dict[str, str] = {
    "EnvError": "envs.errors",
    "Pose": "envs.poses",
    "StartRegion": "envs.poses",
    "Task": "envs.task.task",
    "SuccessConfig": "envs.task.task",
    "StartRange": "envs.task.task",
    "PRESET_NAMES": "envs.task.task",
    "preset": "envs.task.task",
    "load_task": "envs.task.task",
    "SceneConfig": "envs.cell.scene_config",
    "PegInHoleEnv": "envs.sim.env",
    "EpisodeConfig": "envs.sim.episode_config",
    "SimulatorState": "envs.sim.observation",
    "Policy": "envs.policies.interface",
    "Observation": "envs.policies.interface",
    "Action": "envs.policies.interface",
    "PolicyTask": "envs.policies.interface",
    "PrivilegedState": "envs.policies.interface",
    "run_episode": "envs.rollout.episode",
    "EpisodeRecord": "envs.rollout.episode",
    "EvaluationConfig": "envs.evaluation.config",
    "EvaluationResult": "envs.evaluation.result",
    "evaluate": "envs.evaluation.evaluate",
    "evaluate_policy": "envs.evaluation.evaluate_policy",
    "sweep": "envs.evaluation.sweep",
    "compare_evaluations": "envs.statistics.comparison",
    "assert_no_regression": "envs.statistics.regression",
    "collect_demos": "envs.demos.record",
    "DemoSet": "envs.demos.file",
    "load_demos": "envs.demos.file",
    "save_demos": "envs.demos.file",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
