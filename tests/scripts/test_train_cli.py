"""`pih train` and the bad-input paths of `pih evaluate` (synthetic demos, tiny models, no long physics)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from envs.demos.file import load_demos
from rflow.skill_io import file_sha256, load_skill
from scripts.cli import main
from tests.helpers.skill_fixtures import TINY_ARGS, write_demo_file


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    folder = tmp_path_factory.mktemp("train")
    demos = write_demo_file(folder)
    assert main(["train", "--demos", str(demos), "--out", str(folder / "ck"), *TINY_ARGS]) == 0
    return demos, folder / "ck"


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def test_checkpoint_holds_models_figure_and_metadata(trained):
    _, ck = trained
    names = {p.name for p in ck.iterdir()}
    assert {"position", "orientation", "skill.json", "loss.png", "demos.npz"} <= names


def test_metadata_records_the_demo_checksum_and_shape(trained):
    demos, ck = trained
    meta = json.loads((ck / "skill.json").read_text())["metadata"]
    assert meta["demo_sha256"] == file_sha256(demos) and meta["shape"] == "square"


def test_goal_is_the_demos_goal(trained):
    demos, ck = trained
    assert np.allclose(load_skill(ck).goal_pos, load_demos(demos).goal_pos)


def test_weights_are_plain_tensors(trained):
    _, ck = trained
    state = torch.load(ck / "position" / "weights.pt", weights_only=True)
    assert all(isinstance(v, torch.Tensor) for v in state.values())


def test_training_config_uses_the_paper_optimiser_with_the_skill_schedule(trained):
    from rflow.train import SKILL_SCHEDULE

    _, ck = trained
    config = json.loads((ck / "skill.json").read_text())["training"]["position"]["config"]
    assert (config["optimizer"], config["lr"], config["batch_size"], config["model"]["activation"]) == (
        "adam", SKILL_SCHEDULE["lr"], SKILL_SCHEDULE["batch_size"], "relu")


def test_train_defaults_are_the_skill_config_of_pih_run():
    """`pih train` without training options trains the same skill as `pih run` and `pih benchmark`."""
    import argparse

    from scripts.train import add_arguments, skill_train_config, train_config_from_args

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert train_config_from_args(parser.parse_args(["--demos", "d.npz", "--out", "m"])) == skill_train_config()


def test_training_config_records_the_off_data_prior(trained, tmp_path):
    from scripts.train import DEFAULT_PRIOR_WEIGHT

    demos, ck = trained
    config = json.loads((ck / "skill.json").read_text())["training"]["orientation"]["config"]
    assert (config["prior_weight"], config["prior_radius"]) == (DEFAULT_PRIOR_WEIGHT, 3.0) and DEFAULT_PRIOR_WEIGHT > 0
    assert main(["train", "--demos", str(demos), "--out", str(tmp_path / "plain"), "--prior-weight", "0", *TINY_ARGS]) == 0
    plain = json.loads((tmp_path / "plain" / "skill.json").read_text())["training"]["orientation"]["config"]
    assert plain["prior_weight"] == 0.0


def test_negative_prior_weight_fails_cleanly(tmp_path, capsys):
    demos = write_demo_file(tmp_path)
    assert main(["train", "--demos", str(demos), "--out", str(tmp_path / "ck"), "--prior-weight", "-1", *TINY_ARGS]) == 2
    assert "--prior-weight" in _one_line_error(capsys) and not (tmp_path / "ck").exists()


def test_joint_option_writes_one_joint_model(tmp_path):
    demos = write_demo_file(tmp_path)
    assert main(["train", "--demos", str(demos), "--out", str(tmp_path / "ck"), "--joint", *TINY_ARGS]) == 0
    assert load_skill(tmp_path / "ck").models["joint"].dim == 6


def test_bad_demo_file_fails_cleanly_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    assert main(["train", "--demos", str(bad), "--out", str(tmp_path / "ck"), *TINY_ARGS]) == 2
    assert "bad.npz" in _one_line_error(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz"]


def test_evaluate_missing_checkpoint_exits_2(tmp_path, capsys):
    assert main(["evaluate", "--model", str(tmp_path / "none"), "--episodes", "1", "--quiet"]) == 2
    assert "not found" in _one_line_error(capsys)


def test_evaluate_corrupt_checkpoint_exits_2(trained, tmp_path, capsys):
    import shutil

    _, ck = trained
    broken = tmp_path / "ck"
    shutil.copytree(ck, broken)
    (broken / "position" / "weights.pt").write_bytes(b"garbage")
    assert main(["evaluate", "--model", str(broken), "--episodes", "1", "--quiet"]) == 2
    assert "corrupt" in _one_line_error(capsys)


def test_evaluate_in_a_scene_of_another_shape_exits_2(tmp_path, capsys):
    demos = write_demo_file(tmp_path, shape="triangle")
    assert main(["train", "--demos", str(demos), "--out", str(tmp_path / "ck"), *TINY_ARGS]) == 0
    assert main(["evaluate", "--model", str(tmp_path / "ck"), "--shape", "square", "--episodes", "1", "--quiet"]) == 2
    assert "triangle" in _one_line_error(capsys)


def test_evaluate_rejects_a_negative_range(trained, capsys):
    _, ck = trained
    assert main(["evaluate", "--model", str(ck), "--pos-range-mm", "-1", "--quiet"]) == 2
    assert "--pos-range-mm" in _one_line_error(capsys)


def test_evaluate_rejects_nan_lookahead(trained, capsys):
    _, ck = trained
    assert main(["evaluate", "--model", str(ck), "--lookahead-s", "nan", "--quiet"]) == 2
    assert "lookahead" in _one_line_error(capsys)


def test_nan_in_demos_fails_cleanly(tmp_path, capsys):
    demos = load_demos(write_demo_file(tmp_path))
    pos = demos.pos.copy()
    pos[0, 3, 1] = np.nan
    bad = tmp_path / "nan.npz"
    np.savez(bad, pos=pos, quat=demos.quat, dt=demos.dt, goal_pos=demos.goal_pos, goal_quat=demos.goal_quat,
             shape=np.str_(demos.shape), clearance_m=demos.clearance_m, config_json=np.str_("{}"))
    assert main(["train", "--demos", str(bad), "--out", str(tmp_path / "ck"), *TINY_ARGS]) == 2
    assert "NaN" in _one_line_error(capsys)
