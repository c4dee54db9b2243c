"""envs.evaluation.profile: the split of a control period into its parts adds up, leaves the episodes unchanged and
leaves no wrapper behind."""

from __future__ import annotations

import dataclasses
import json

import pytest

from envs.evaluation.evaluate import EvaluationConfig, build_setup
from envs.evaluation.profile import LAW_FLOOR_PARTS, PARTS, law_floor_periods, profile_periods
from envs.evaluation.starts import evaluation_starts
from envs.rollout.episode import run_episode
from envs.task.task import Task
from rflow.skill_io import save_skill
from tests.helpers.skill_fixtures import tiny_skill


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    model = save_skill(tmp_path_factory.mktemp("ck") / "model", tiny_skill())
    config = EvaluationConfig(episodes=2, task=Task(time_limit_s=0.1))
    skill, env, policy = build_setup(model, config)
    return env, policy, evaluation_starts(skill.metadata["demo_starts"], config), config


def _records(env, policy, starts, config):
    out = []
    for start in starts:
        record, _ = run_episode(env, policy, start, feedforward_gain=config.feedforward_gain)
        out.append(json.dumps({k: v for k, v in dataclasses.asdict(record).items() if k != "wall_s"}))
    return out  # JSON text: NaN fields (an unreachable start) compare equal


def test_the_parts_add_up_to_the_period_and_the_episodes_are_unchanged(setup):
    env, policy, starts, config = setup
    plain = _records(env, policy, starts, config)
    profile = profile_periods(env, policy, starts, config.feedforward_gain)
    assert profile["periods"] == sum(json.loads(r)["steps"] for r in plain) > 0
    parts = [profile[part] for part, _, _ in PARTS]
    assert all(p > 0.0 for p in parts)  # every part was called every period
    assert profile["other"] >= 0.0 and profile["total"] == pytest.approx(sum(parts) + profile["other"])
    assert profile["reset_ms"] > 0.0
    compiled = profile["compiled"]
    assert all(v > 0.0 for v in compiled.values()), compiled  # every kernel found where its caller looks it up
    assert compiled["physics_law_and_sensing"] < profile["control_and_sensing"]
    assert compiled["nullspace_ik"] < profile["nullspace_ik"] and compiled["feedforward_lead"] < profile["feedforward_lead"]
    assert _records(env, policy, starts, config) == plain  # profiling changed nothing, and nothing stayed wrapped
    for _, owner, name in PARTS:
        obj = {"env": env, "policy": policy, "controller": env.controller, "nullspace": env.nullspace}[owner]
        assert name not in vars(obj)  # the class's method again
    assert "reset" not in vars(env)
    import importlib

    from envs.evaluation.profile import COMPILED
    for _, module, names in COMPILED:  # the kernels themselves again, not their timers
        assert all(hasattr(getattr(importlib.import_module(module), name), "py_func") for name in names)


def test_the_law_floor_times_every_part_and_leaves_the_episodes_unchanged(setup):
    env, policy, starts, config = setup
    plain = _records(env, policy, starts, config)
    floor = law_floor_periods(env, policy, starts, config.feedforward_gain)
    assert floor["periods"] == sum(json.loads(r)["steps"] for r in plain) - 1 > 0  # the first period is the load
    assert all(floor[part] > 0.0 for part in LAW_FLOOR_PARTS)
    assert "run_period" not in vars(env)
    assert _records(env, policy, starts, config) == plain
