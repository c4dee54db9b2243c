"""rflow.skill_io: the R^3 x S^3 product manifold, the checkpoint directory, subsampling."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from rflow.errors import RFlowError
from rflow.generate import next_point
from rflow.skill_io import POSE, file_sha256, load_skill, save_skill, subsample
from tests.helpers.skill_fixtures import GOAL_POS, GOAL_QUAT, tiny_skill


@pytest.fixture(scope="module")
def skill():
    return tiny_skill()


def test_pose_log_of_goal_is_zero():
    goal = np.concatenate([GOAL_POS, GOAL_QUAT])
    assert np.allclose(POSE.log(goal, goal), 0.0)


def test_pose_exp_inverts_log():
    goal = np.concatenate([GOAL_POS, GOAL_QUAT])
    v = np.array([[0.01, -0.02, 0.03, 0.1, -0.2, 0.05]])
    assert np.allclose(POSE.log(POSE.exp(v, goal), goal), v)


def test_pose_rejects_non_unit_quaternion_part():
    with pytest.raises(RFlowError):
        POSE.check_points(np.array([0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0]))


def test_subsample_keeps_the_goal_and_uniform_steps():
    x = np.arange(10.0)[None, :, None]
    out = subsample(x, 4)
    assert out[0, :, 0].tolist() == [1.0, 5.0, 9.0]


def test_subsample_rejects_too_large_factor():
    with pytest.raises(RFlowError):
        subsample(np.zeros((1, 3, 3)), 5)


def test_save_load_round_trip_predicts_the_same(skill, tmp_path):
    save_skill(tmp_path / "ck", skill)
    loaded = load_skill(tmp_path / "ck")
    p = GOAL_POS + np.array([-0.03, 0.01, 0.1])
    assert np.allclose(next_point(loaded.models["position"], p), next_point(skill.models["position"], p))


def test_weights_load_with_weights_only(skill, tmp_path):
    save_skill(tmp_path / "ck", skill)
    state = torch.load(tmp_path / "ck" / "orientation" / "weights.pt", weights_only=True)
    assert len(state) > 0


def test_failed_writer_leaves_nothing_behind(skill, tmp_path):
    def broken(path: Path) -> None:
        raise OSError("disk full")

    with pytest.raises(OSError):
        save_skill(tmp_path / "ck", skill, {"loss.png": broken})
    assert list(tmp_path.iterdir()) == []


def test_failed_overwrite_keeps_the_old_checkpoint(skill, tmp_path):
    save_skill(tmp_path / "ck", skill)
    with pytest.raises(OSError):
        save_skill(tmp_path / "ck", skill, {"x": lambda path: (_ for _ in ()).throw(OSError("no"))}, overwrite=True)
    assert load_skill(tmp_path / "ck").layout == "separate"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck"]


def test_missing_checkpoint_is_an_rflow_error(tmp_path):
    with pytest.raises(RFlowError, match="not found"):
        load_skill(tmp_path / "nothing")


def test_corrupt_skill_json_is_an_rflow_error(skill, tmp_path):
    save_skill(tmp_path / "ck", skill)
    (tmp_path / "ck" / "skill.json").write_text("{not json")
    with pytest.raises(RFlowError, match="corrupt"):
        load_skill(tmp_path / "ck")


def test_truncated_weights_are_an_rflow_error(skill, tmp_path):
    save_skill(tmp_path / "ck", skill)
    weights = tmp_path / "ck" / "position" / "weights.pt"
    weights.write_bytes(weights.read_bytes()[:100])
    with pytest.raises(RFlowError, match="corrupt"):
        load_skill(tmp_path / "ck")


def test_joint_skill_round_trip(tmp_path):
    joint = tiny_skill("joint")
    save_skill(tmp_path / "ck", joint)
    loaded = load_skill(tmp_path / "ck")
    assert loaded.layout == "joint" and loaded.models["joint"].dim == 6


def test_joint_skill_goal_is_the_demo_goal():
    joint = tiny_skill("joint")
    assert np.allclose(joint.goal_pos, GOAL_POS) and abs(abs(joint.goal_quat @ GOAL_QUAT) - 1) < 1e-9


def test_file_sha256_changes_with_content(tmp_path):
    a = tmp_path / "a"
    a.write_bytes(b"x")
    before = file_sha256(a)
    a.write_bytes(b"y")
    assert file_sha256(a) != before


def test_skill_json_records_layout_and_models(skill, tmp_path):
    save_skill(tmp_path / "ck", skill)
    record = json.loads((tmp_path / "ck" / "skill.json").read_text())
    assert record["layout"] == "separate" and record["models"] == ["position", "orientation"]
