"""The simulator at 1 kHz: the episode environment (`env`: `PegInHoleEnv`, reset with its perturbation and grasp,
one control period of ten physics steps), how an episode runs and ends (`episode_config`), what it exposes
(`observation`: `SimulatorState`, `StepResult`), the wrist F/T and contact sensing (`sensing`, compiled per physics
step in `sensing_kernel`, the period in `period_kernel`), the sensor's reading model (`sensor_reading`), instability
checks (`instability`) and the cell's friction and model errors (`friction`, `model_error`). A policy's episode on
it is envs.rollout's.
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "PegInHoleEnv": "envs.sim.env",
    "EpisodeConfig": "envs.sim.episode_config",
    "SimulatorState": "envs.sim.observation",
    "StepResult": "envs.sim.observation",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
