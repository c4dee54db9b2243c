"""The Gymnasium face of the simulator, on the `Policy` interface's schema: the schema itself (`schema`: the Gym
observation is the policy's `Observation`, the Gym action an `Action`, the info's named keys), the environment
``pih/PegInHole-v1`` (`env`; registered by importing envs.gym_env) and the adapters both ways (`agent`: a Gym-trained
agent as a `Policy`, any `Policy` stepped through the environment)."""

from pihutil.lazy import lazy_exports

EXPORTS: dict[str, str] = {
    "ENV_ID": "envs.gym.schema",
    "ACTION_FIELDS": "envs.gym.schema",
    "TRUTH_KEYS": "envs.gym.schema",
    "ActionSchema": "envs.gym.schema",
    "observation_dict": "envs.gym.schema",
    "observation_from_dict": "envs.gym.schema",
    "observation_sizes": "envs.gym.schema",
    "PegInHoleGymEnv": "envs.gym.env",
    "RewardConfig": "envs.gym.env",
    "StartError": "envs.gym.env",
    "AgentPolicy": "envs.gym.agent",
    "run_policy": "envs.gym.agent",
}
"""The public names (name -> the module that defines it), imported on first use."""

__all__ = sorted(EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, EXPORTS)
