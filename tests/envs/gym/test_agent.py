"""The adapters both ways (envs/gym/agent.py): a stable-baselines3 agent trained on pih/PegInHole-v1 scored by `pih
evaluate --policy` gives the records that stepping the Gym environment gives on the same starts, and any Policy stepped
through the Gym environment gives the records `run_episode` gives."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium
import numpy as np
import pytest

from envs.gym.agent import AgentPolicy, run_policy
from envs.gym_env import ENV_ID
from envs.policies.expert import ScriptedExpertPolicy
from envs.rollout.episode import run_episode
from envs.task.task import preset
from scripts.cli import main
from tests.helpers.skill_fixtures import write_demo_file

TASK = preset("contact").override(time_limit_s=0.3, pos_range_m=0.01)
"""Short episodes from starts within 10 mm of the synthetic demos' mean start."""
CLI_TASK = ["--task", "contact", "--time-limit-s", "0.3", "--pos-range-mm", "10"]
"""The same task as `pih evaluate` options."""


def _same(a: dict, b: dict) -> list[str]:
    """The fields in which two records differ (wall time aside)."""
    return [k for k in sorted(set(a) | set(b)) if k != "wall_s" and a.get(k, "<missing>") != b.get(k, "<missing>")]


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    return write_demo_file(tmp_path_factory.mktemp("demos"))


@pytest.mark.slow
def test_a_ppo_agent_scored_by_pih_evaluate_gives_the_records_of_its_gym_episodes(demos, tmp_path) -> None:
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)  # as in the evaluation's workers
    env = gymnasium.make(ENV_ID, demos=str(demos), task=TASK)
    agent = PPO("MultiInputPolicy", env, n_steps=512, batch_size=128, n_epochs=2, seed=0, device="cpu",
                policy_kwargs={"net_arch": [32, 32]})
    agent.learn(total_timesteps=2048)
    agent.save(tmp_path / "ppo.zip")
    out = tmp_path / "agent.json"
    assert main(["evaluate", "--policy", "envs.gym.agent:sb3", "--policy-option", f"model={tmp_path / 'ppo.zip'}",
                 "--demos", str(demos), "--episodes", "3", *CLI_TASK, "--json", str(out), "--quiet"]) == 0
    evaluated = json.loads(out.read_text())["per_episode"]
    stepped = []
    for k in range(3):
        obs, info = env.reset(options={"episode": k})
        done = False
        while not done:
            action, _ = agent.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        stepped.append(info["episode_record"])
    assert [r["index"] for r in evaluated] == [0, 1, 2]
    assert all(r["steps"] > 0 for r in evaluated)
    assert [_same(a, b) for a, b in zip(evaluated, stepped)] == [[], [], []]
    env.close()


def test_any_policy_stepped_through_gym_gives_the_record_of_run_episode(demos) -> None:
    """The privileged scripted expert, whose Actions carry a feed-forward twist and a stiffness: its Gym episode (the
    Actions passed to step as they are) and its run_episode on the same start are one episode."""
    env = gymnasium.make(ENV_ID, demos=str(demos), task=TASK.override(time_limit_s=1.0), privileged=True)
    gym_env = env.unwrapped
    start = gym_env.evaluation_start(1)
    through_gym = run_policy(env, ScriptedExpertPolicy(), options={"episode": 1})
    direct, _ = run_episode(gym_env.sim, ScriptedExpertPolicy(), start, privileged=True)
    assert through_gym.steps > 50 and through_gym.start_pos == start.pose.pos.tolist()
    assert _same(through_gym.to_dict(), direct.to_dict()) == []
    env.close()


def test_an_agent_adapter_takes_the_schema_from_the_agents_spaces(demos) -> None:
    env = gymnasium.make(ENV_ID, demos=str(demos), task=TASK, stiffness_action=True)
    gym_env = env.unwrapped

    class Constant:  # an agent that always asks for the centre of the action range
        action_space, observation_space = env.action_space, env.observation_space

        def predict(self, observation, deterministic=True):
            assert set(observation) == set(env.observation_space.spaces)
            return np.zeros(10, dtype=np.float32), None

    from envs.policies.interface import policy_task

    policy = AgentPolicy.for_task(Constant(), policy_task(gym_env.sim))
    assert policy.schema == gym_env.action_schema and not policy.privileged
    gym_env.reset(options={"episode": 0})
    action = policy.act(gym_env._run.observation())
    assert action.rotational_stiffness == pytest.approx(np.mean(gym_env.action_schema.low[9:] +
                                                                gym_env.action_schema.high[9:]))
    env.close()
