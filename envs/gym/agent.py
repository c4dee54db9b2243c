"""Adapters between the Gymnasium environment and the `Policy` interface, one each way, on the one schema
(envs.gym.schema), so that both give the same episodes and the same records:

- `AgentPolicy`: a Gym-trained agent (a stable-baselines3 model, or anything with ``predict(observation)``) as a
  `Policy`, so `pih evaluate --policy` scores it like the RiemannianFlow skill. `sb3` is a ready factory:

      pih evaluate --policy envs.gym.agent:sb3 --policy-option model=ppo.zip --demos demos.npz --json agent.json

- `run_policy`: any `Policy` stepped through the Gym environment (its observations rebuilt from the Gym observation,
  its Actions passed to ``step`` as they are, feed-forward included); the episode's record is the one `run_episode`
  gives on the same start.

With ``gymnasium.make("pih/PegInHole-v1", demos=FILE)`` and ``reset(options={"episode": k})`` a Gym episode is episode
k of `pih evaluate --policy ... --demos FILE`: the same start, perturbation and record (``info["episode_record"]``).
"""

from __future__ import annotations

import inspect
import os
from typing import Any

import numpy as np

from envs.errors import EnvError
from envs.gym.env import StartError
from envs.gym.schema import PRIVILEGED_PREFIX, ActionSchema, observation_dict, observation_from_dict
from envs.policies.interface import Action, Observation, Policy, PolicyTask
from envs.rollout.episode import EpisodeRecord

SB3_ALGORITHMS: tuple[str, ...] = ("PPO", "A2C", "SAC", "TD3", "DDPG")
"""stable-baselines3's algorithms with a continuous (Box) action, which `sb3` loads by name."""


class AgentPolicy:
    """A Gym-trained agent as a `Policy`: each control period the agent's action for the Gym observation of the
    policy's observation (`observation_dict`), read as an `Action` through the environment's `ActionSchema`.

    Args:
        agent: anything with ``predict(observation, deterministic=...)`` returning an action, or (action, state) as
            stable-baselines3 does (a recurrent agent's state is carried from step to step and reset per episode).
        schema: the action schema of the environment the agent was trained in (``env.unwrapped.action_schema``, or
            `ActionSchema.for_task` of the `PolicyTask` with the same ``stiffness``).
        privileged: the agent observes the privileged keys (an environment made with ``privileged=True``; the
            evaluation must run with --privileged).
        deterministic: ask the agent for its deterministic action (the mean of a stochastic policy).
    """

    def __init__(self, agent: Any, schema: ActionSchema, privileged: bool = False, deterministic: bool = True):
        if not callable(getattr(agent, "predict", None)):
            raise EnvError(f"AgentPolicy: the agent ({type(agent).__name__}) has no predict(observation) method")
        if not isinstance(schema, ActionSchema):
            raise EnvError(f"AgentPolicy: schema must be an envs.gym.schema.ActionSchema, got {type(schema).__name__}")
        self.agent, self.schema = agent, schema
        self.privileged, self.deterministic = bool(privileged), bool(deterministic)
        self._recurrent = _takes(agent.predict, "state", "episode_start")
        self._state: Any = None
        self._episode_start = True

    @classmethod
    def for_task(cls, agent: Any, task: PolicyTask, deterministic: bool = True) -> AgentPolicy:
        """The adapter of an agent for a `PolicyTask` (a factory's argument): the schema's stiffness and the
        privileged keys read off the agent's own spaces (``action_space``, ``observation_space``) when it has them.

        Raises:
            EnvError: an agent whose action space is neither the schema's with nor without stiffness.
        """
        plain = ActionSchema.for_task(task)
        stiff = ActionSchema.for_task(task, stiffness=True)
        shape = getattr(getattr(agent, "action_space", None), "shape", None)
        if shape is not None and tuple(shape) not in ((plain.size,), (stiff.size,)):
            raise EnvError(f"the agent's action space has shape {tuple(shape)}; a pih/PegInHole-v1 action has "
                           f"{plain.size} entries ({stiff.size} with stiffness_action=True)")
        keys = getattr(getattr(agent, "observation_space", None), "spaces", {}) or {}
        privileged = any(str(k).startswith(PRIVILEGED_PREFIX) for k in keys)
        return cls(agent, stiff if shape == (stiff.size,) else plain, privileged, deterministic)

    def reset(self, observation: Observation, period_s: float) -> None:
        """A new episode: a recurrent agent's state starts afresh."""
        self._state, self._episode_start = None, True

    def act(self, observation: Observation) -> Action:
        """The agent's action for the observation, as an `Action`."""
        values = observation_dict(observation, self.privileged)
        if self._recurrent:  # stable-baselines3's signature: the state of a recurrent policy, the episode's start
            out = self.agent.predict(values, state=self._state, episode_start=np.array([self._episode_start]),
                                     deterministic=self.deterministic)
        else:
            out = self.agent.predict(values, deterministic=self.deterministic)
        self._episode_start = False
        action = out
        if isinstance(out, tuple):
            action, self._state = out[0], (out[1] if len(out) > 1 else None)
        return self.schema.to_policy_action(action)


def _takes(function: Any, *names: str) -> bool:
    """Whether ``function`` takes every keyword argument of ``names``."""
    try:
        parameters = inspect.signature(function).parameters
    except (TypeError, ValueError):  # a builtin without a signature
        return False
    return all(name in parameters for name in names)


def sb3(task: PolicyTask, model: str = "", algorithm: str = "PPO", deterministic: str = "true") -> AgentPolicy:
    """`pih evaluate --policy envs.gym.agent:sb3 --policy-option model=FILE.zip [--policy-option algorithm=SAC]`: a
    stable-baselines3 model trained on pih/PegInHole-v1, loaded on the CPU, as a `Policy` (`AgentPolicy.for_task`).

    Raises:
        EnvError: no model given, an unknown algorithm, stable-baselines3 missing, or a model that does not load.
    """
    if not model:
        raise EnvError("envs.gym.agent:sb3 needs --policy-option model=FILE.zip (a stable-baselines3 model)")
    if algorithm not in SB3_ALGORITHMS:
        raise EnvError(f"envs.gym.agent:sb3: algorithm={algorithm!r} must be one of {', '.join(SB3_ALGORITHMS)}")
    if deterministic not in ("true", "false"):
        raise EnvError(f"envs.gym.agent:sb3: deterministic={deterministic!r} must be true or false")
    return AgentPolicy.for_task(_load_sb3(algorithm, model), task, deterministic == "true")


_LOADED: dict[tuple[str, str, int, int], Any] = {}
"""The stable-baselines3 models loaded in this process, by (algorithm, path, mtime, size): the evaluation calls the
factory for every lockstep slot of a worker, and a feed-forward agent's predict keeps no state, so they share one."""


def _load_sb3(algorithm: str, model: str) -> Any:
    """The stable-baselines3 ``algorithm`` model in the file ``model``, on the CPU (loaded once per process and file).

    Raises:
        EnvError: stable-baselines3 missing, or a file that does not load as such a model.
    """
    try:
        import stable_baselines3
    except ModuleNotFoundError:
        raise EnvError("envs.gym.agent:sb3 needs stable-baselines3: pip install stable-baselines3") from None
    try:
        stat = os.stat(model)
        key = (algorithm, os.path.realpath(model), stat.st_mtime_ns, stat.st_size)
        if key not in _LOADED:
            _LOADED[key] = getattr(stable_baselines3, algorithm).load(model, device="cpu")
    except (OSError, ValueError, KeyError) as err:
        raise EnvError(f"envs.gym.agent:sb3: cannot load {model} as a {algorithm} model ({type(err).__name__}: "
                       f"{err})") from None
    return _LOADED[key]


def run_policy(env: Any, policy: Policy, seed: int | None = None,
               options: dict[str, Any] | None = None) -> EpisodeRecord:
    """Step any `Policy` through the Gym environment ``env`` (made by ``gymnasium.make("pih/PegInHole-v1", ...)``)
    for one episode: ``reset(seed, options)``, the policy reset with the rebuilt `Observation`, then each step the
    policy's `Action` for the observation the step returned, until the episode ends.

    Returns:
        the episode's record (``info["episode_record"]``; for a start the arm cannot reach, the record the
        environment kept).

    Raises:
        EnvError: a bad reset option or a refused action.
    """
    gym_env = env.unwrapped
    try:
        observation, _ = env.reset(seed=seed, options=options)
    except StartError as err:  # the start was unreachable: recorded as `pih evaluate` records it
        return err.record
    policy.reset(observation_from_dict(observation), gym_env.control_period_s)
    while True:
        observation, _, terminated, truncated, info = env.step(policy.act(observation_from_dict(observation)))
        if terminated or truncated:
            return gym_env.episode_record
