"""The task options and presets (envs.task.task, scripts.task_options): one spelling on every command, bad values end
with one line and exit 2 before any work, and the presets are what the README says."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from envs.errors import EnvError
from envs.task.task import Task, preset
from scripts import cli
from scripts.task_options import add_task_arguments, scene_from_task, task_from_args


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_task_arguments(parser)
    return parser.parse_args(list(argv))


def test_default_is_the_contact_preset() -> None:
    task = task_from_args(parse())
    assert task == preset("contact") == Task()
    assert (task.clearance_m, task.chamfer_m, task.hole_depth_m) == (0.0002, 0.001, 0.03)
    assert (task.perturbations.hole_error_m, task.perturbations.hole_error_deg, task.force_limit_n) == (0.001, 1.0, 40.0)


def test_paper_preset_is_the_toy_setting() -> None:
    task = preset("paper")
    assert (task.clearance_m, task.chamfer_m, task.perturbations.hole_error_m) == (0.001, 0.0, 0.0)


def test_options_override_the_preset_and_only_given_scene_options_are_reported() -> None:
    args = parse("--preset", "paper", "--hole-error-mm", "0.5")
    assert task_from_args(args).perturbations.hole_error_m == pytest.approx(0.0005)
    assert task_from_args(args).clearance_m == 0.001
    assert scene_from_task(parse("--chamfer-mm", "2")) == ("chamfer_m",)
    assert task_from_args(parse("--chamfer-mm", "2")).chamfer_m == 0.002
    assert scene_from_task(parse()) == ()


@pytest.mark.parametrize("argv, match", [
    (("--clearance-mm", "-1"), "clearance"),
    (("--chamfer-mm", "-0.5"), "chamfer"),
    (("--hole-error-mm", "-1"), "hole_error_m"),
    (("--grasp-offset-mm", "-3"), "grasp_offset_m"),
    (("--force-limit-n", "0"), "force limit"),
])
def test_bad_values_name_the_setting(argv, match) -> None:
    with pytest.raises(EnvError, match=match):
        task_from_args(parse(*argv))


@pytest.mark.parametrize("option", ["--clearance-mm", "--chamfer-mm", "--hole-error-deg", "--force-limit-n"])
def test_nan_is_refused_while_parsing_naming_the_option(option, tmp_path: Path, capsys) -> None:
    assert cli.main(["evaluate", "--model", str(tmp_path), option, "nan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0] and "finite" in err[0]


@pytest.mark.parametrize("command", ["demos", "evaluate"])
def test_bad_task_option_exits_2_with_one_line_and_writes_nothing(command, tmp_path: Path, capsys) -> None:
    out = tmp_path / "out.npz"
    argv = [command, "--clearance-mm", "-1"]
    argv += ["--out", str(out)] if command == "demos" else ["--model", str(tmp_path / "none"), "--json",
                                                             str(tmp_path / "e.json")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"pih {command}: error:") and "clearance" in err[0]
    assert list(tmp_path.iterdir()) == []
