"""One episode of a policy on the simulator (`episode`: `run_episode`, `EpisodeRun`, the per-episode `EpisodeRecord`),
episodes side by side one control period at a time (`lockstep`), and what a failure was (`failure`).
"""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "EpisodeRecord": "envs.rollout.episode",
    "EpisodeRun": "envs.rollout.episode",
    "EpisodeTrace": "envs.rollout.episode",
    "StartPose": "envs.rollout.episode",
    "record_from_dict": "envs.rollout.episode",
    "run_episode": "envs.rollout.episode",
    "run_lockstep": "envs.rollout.lockstep",
    "FAILURE_KINDS": "envs.rollout.failure",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
