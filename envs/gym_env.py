"""Registers the Gymnasium environment ``pih/PegInHole-v1`` (envs.gym.env.PegInHoleGymEnv) and re-exports its names:

    import envs.gym_env   # then gymnasium.make("pih/PegInHole-v1", ...)
    env = gymnasium.make("envs.gym_env:pih/PegInHole-v1", shape="square", clearance_mm=0.2)   # imports this module

Gymnasium 1.x has no plugin entry points (they were removed in 1.0); ``gymnasium.make`` registers a third-party
environment by importing the module named before the ':' of the id, as above. The spaces are the `Policy`
interface's (envs.gym.schema); ``pih/PegInHole-v0`` (observation keys of its own, no rotational stiffness in the
action) is gone, and Gymnasium says so when it is asked for.

Headless: importing ``envs`` chooses an offscreen OpenGL backend when there is no display
(envs.media.rendering.headless_without_display), before the scene loads dm_control, so nothing is printed on a server.
"""

from __future__ import annotations

import gymnasium

from envs.gym.env import PegInHoleGymEnv, RewardConfig, StartError, configs_from_kwargs
from envs.gym.schema import (ACTION_FIELDS, ENV_ID, STIFFNESS_RANGE_N_M, TRUTH_KEYS, ActionSchema, observation_dict,
                             observation_from_dict)

__all__ = ["ACTION_FIELDS", "ENV_ID", "STIFFNESS_RANGE_N_M", "TRUTH_KEYS", "ActionSchema", "PegInHoleGymEnv",
           "RewardConfig", "StartError", "configs_from_kwargs", "observation_dict", "observation_from_dict"]

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="envs.gym.env:PegInHoleGymEnv")
