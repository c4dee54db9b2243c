"""The simulated Franka Panda peg-in-hole testbed (MuJoCo) and the execution and evaluation of skills on it.

Sub-packages, each with one job, from the bottom up (a sub-package imports only those below it;
tests/test_architecture.py): `io` (pih's file outputs), `cell` (the scene built in MJCF), `task` (what is asked:
the task, its presets, perturbations, sensing and success check), `sim` (the simulator at 1 kHz), `policies` (what
acts each control period), `rollout` (one episode, episodes in lockstep), then `demos`, `media`, `statistics`, and on
top `evaluation`, `datasets` and the Gymnasium environment `gym` (registered by `gym_env`). `errors`, `geometry` and `poses` are the shared
base modules.

The project's public surface is re-exported here lazily (PEP 562): ``from envs import Task, PegInHoleEnv`` imports
only the modules that define them, so ``import envs`` stays cheap.
"""

from numerics.cpu_dispatch import pin_cpu_dispatch

pin_cpu_dispatch()  # first, before numpy or torch load: numpy's, torch's and MKL's kernel choices as `pih` pins them

from envs.media.rendering import headless_without_display  # noqa: E402

headless_without_display()  # no display: a headless GL for MuJoCo before dm_control picks GLFW (which prints)

from pihutil.lazy import lazy_exports  # noqa: E402

EXPORTS: dict[str, str] = {
    # name -> the sub-package (or base module) that exports it; a sub-package's own table names the defining module
    "EnvError": "envs.errors",
    "Pose": "numerics.pose",
    "StartRegion": "envs.poses",
    **{name: "envs.task" for name in ("Task", "SuccessConfig", "StartRange", "PRESET_NAMES", "preset", "load_task")},
    "SceneConfig": "envs.cell",
    **{name: "envs.sim" for name in ("PegInHoleEnv", "EpisodeConfig", "SimulatorState")},
    "Action": "controllers.action",
    **{name: "envs.policies" for name in ("Policy", "Observation", "PolicyTask", "PrivilegedState")},
    **{name: "envs.rollout" for name in ("run_episode", "EpisodeRecord")},
    **{name: "envs.evaluation" for name in ("EvaluationConfig", "EvaluationResult")},
    "evaluate": "envs.evaluation.evaluate",
    "evaluate_policy": "envs.evaluation.evaluate_policy",
    "sweep": "envs.evaluation.sweep",
    **{name: "envs.statistics" for name in ("compare_evaluations", "assert_no_regression")},
    **{name: "envs.demos" for name in ("collect_demos", "DemoSet", "load_demos", "save_demos")},
}
"""The public names (name -> where to find it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
