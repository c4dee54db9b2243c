"""The insertion task: one frozen `Task` (scene fields, peg and grasp, force and time limits, success tolerances,
start range; `task`), saved as a TOML file, with the presets as package data (`presets/*.toml`); the per-episode
perturbations and the cell's imperfections (`perturbation`); the wrench sensing a task sets (`sensor_config`); and
the success check from the peg's measured pose and speed, whose tolerances are the task's (`success`, compiled in
`success_kernel`). Above envs.cell (a task builds its scene config), below the simulator.
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "Task": "envs.task.task",
    "SuccessConfig": "envs.task.task",
    "StartRange": "envs.task.task",
    "PRESET_NAMES": "envs.task.task",
    "preset": "envs.task.task",
    "load_task": "envs.task.task",
    "Perturbation": "envs.task.perturbation",
    "PerturbationRanges": "envs.task.perturbation",
    "sample_perturbation": "envs.task.perturbation",
    "WristSensorConfig": "envs.task.sensor_config",
    "EpisodeHoles": "envs.task.success",
    "SuccessTracker": "envs.task.success",
    "assess_insertion": "envs.task.success",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
