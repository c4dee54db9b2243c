"""envs.evaluation.replay: an evaluation JSON read back (config, checkpoint) and replays checked against records."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from envs.errors import EnvError
from envs.evaluation.evaluate import EvaluationConfig
from envs.evaluation.replay import check_replay, evaluation_config_from_dict, load_evaluation
from envs.io.jsonable import to_jsonable
from envs.io.owned_output import strict_json
from envs.rollout.episode import EpisodeRecord
from envs.task.perturbation import PerturbationRanges
from envs.task.task import Task


def test_config_survives_its_json_record() -> None:
    task = Task(perturbations=PerturbationRanges(0.002, 1.5, 0.001), force_limit_n=float("inf"))
    config = EvaluationConfig(episodes=7, seed=3, mode="open-loop", stiffness="constant:800", task=task)
    text = json.dumps(strict_json({"config": config.settings(), "task": config.task.to_dict()}))
    record = json.loads(text)
    assert evaluation_config_from_dict(record["config"], "eval.json", record["task"]) == config


def test_config_is_rebuilt_for_one_local_process() -> None:
    values = to_jsonable(EvaluationConfig(workers=4, backend="ray", ray_address="head:6379").settings())
    config = evaluation_config_from_dict(values, "eval.json", Task().to_dict())
    assert (config.workers, config.backend, config.ray_address) == (1, "process", None)


def test_a_config_key_of_another_version_is_an_error() -> None:
    values = {**to_jsonable(EvaluationConfig().settings()), "gripper_mode": "soft"}
    with pytest.raises(EnvError, match="gripper_mode"):
        evaluation_config_from_dict(values, "eval.json", Task().to_dict())


def test_a_replay_that_ends_otherwise_than_recorded_is_an_error() -> None:
    replayed = EpisodeRecord(3, -1, [0.0] * 3, [1.0, 0, 0, 0], success=True, reason="success", steps=120)
    recorded = {**replayed.to_dict(), "steps": 121}
    with pytest.raises(EnvError, match="episode 3 differs from its record \\(steps: 121 recorded, 120 replayed\\)"):
        check_replay(recorded, replayed, "eval.json")
    check_replay(replayed.to_dict(), replace(replayed, wall_s=9.0), "eval.json")  # wall time may differ


def write_eval(path: Path, model: str, **extra: object) -> Path:
    record = {"model": model, "config": to_jsonable(EvaluationConfig().settings()), "skill": {},
              "per_episode": [EpisodeRecord(0, -1, [0.0] * 3, [1.0, 0, 0, 0]).to_dict()], **extra}
    path.write_text(json.dumps(record))
    return path


def test_the_checkpoint_is_found_beside_the_json(tmp_path: Path) -> None:
    (tmp_path / "run" / "model").mkdir(parents=True)
    evaluation = load_evaluation(write_eval(tmp_path / "run" / "eval.json", "model"))
    assert evaluation.model_dir == tmp_path / "run" / "model"


@pytest.mark.parametrize("content, message", [
    ("{not json", "not a readable evaluation JSON"),
    ('{"model": "m"}', "missing keys"),
    ('[1, 2]', "not an evaluation JSON"),
])
def test_a_malformed_evaluation_file_is_one_clear_error(tmp_path: Path, content: str, message: str) -> None:
    (tmp_path / "eval.json").write_text(content)
    with pytest.raises(EnvError, match=message):
        load_evaluation(tmp_path / "eval.json")


def test_a_missing_checkpoint_asks_for_model(tmp_path: Path) -> None:
    with pytest.raises(EnvError, match="give it with --model"):
        load_evaluation(write_eval(tmp_path / "eval.json", "gone"))
