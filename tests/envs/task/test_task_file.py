"""The task file (envs/task/task.py): one frozen Task, saved and read as TOML, the presets shipped as such files, bad
files as one-line errors (exit 2 through the CLI), single options over the file, and the task recorded in demo
files, checkpoints and result JSON."""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import fields
from pathlib import Path

import pytest

from envs.errors import EnvError
from envs.evaluation.config import SCENE_FROM_TASK, EvaluationConfig
from envs.task.perturbation import PerturbationRanges
from envs.task.sensor_config import WristSensorConfig
from envs.task.task import PRESET_NAMES, SuccessConfig, StartRange, Task, TASK_VERSION, load_task, parse_toml, preset
from scripts.cli import main
from tests.helpers import REPO

MINE = Task(shape="triangle", peg_mode="welded", clearance_m=0.0005, chamfer_m=0.0, grasp_force_n=50.0,
            pad_stiffness_nm_rad=40.0,
            hole_depth_m=0.05, perturbations=PerturbationRanges(
                0.002, 0.5, 0.001, 0.3, 0.8, 0.6, 1.2, 0.001, 1.0, 0.5, 0.1, joint_friction_scale_min=0.5,
                joint_friction_scale_max=1.5, hole_observation_error_m=0.002, hole_observation_error_deg=3.0,
                payload_com_error_m=0.001, actuator_noise_nm=0.2, hole_observation="measured",
                hole_observation_tilt_deg=0.7, joint_friction_model="smooth"),
            sensing=WristSensorConfig("wrist", 0.1, 0.005, 0.5, 0.02, 200.0),
            force_limit_n=math.inf,
            time_limit_s=7.5, success=SuccessConfig(seat_tolerance_m=0.002, hold_s=0.1),
            start=StartRange(pos_range_m=0.02, rot_range_deg=5.0, around="demo"))
"""A task that differs from the default in every field."""


def write(tmp_path: Path, text: str, name: str = "my_task.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


# ------------------------------------------------------------------------------------------- the file


def test_every_field_differs_in_the_probe_task() -> None:
    default, mine = Task().to_dict(), MINE.to_dict()
    assert all(mine[k] != default.get(k) for k in mine if k != "version")
    for table in ("perturbations", "start"):
        assert all(mine[table][k] != default[table][k] for k in mine[table])


def test_a_task_survives_its_toml_file(tmp_path: Path) -> None:
    path = write(tmp_path, MINE.to_toml())
    assert Task.from_toml(path) == MINE
    assert tomllib.loads(path.read_text())["version"] == TASK_VERSION


def test_a_task_survives_its_record_through_strict_json() -> None:
    from envs.io.owned_output import strict_json

    record = json.loads(json.dumps(strict_json(MINE.to_dict()), allow_nan=False))
    assert record["force_limit_n"] is None and Task.from_dict(record) == MINE  # null: no limit


@pytest.mark.parametrize("name", PRESET_NAMES)
def test_each_preset_file_round_trips(name: str) -> None:
    task = preset(name)
    assert parse_toml(task.to_toml(), name) == task
    assert load_task(name) == task
    assert task.shape is None  # a preset fits any shape: new demos are square, evaluations the demos'


def test_the_contact_preset_is_the_default_task() -> None:
    assert preset("contact") == Task()
    shipped = tomllib.loads((REPO / "envs" / "task" / "presets" / "contact.toml").read_text())
    assert shipped == {k: v for k, v in Task().to_dict().items()}  # every field written out, none left to defaults


def test_the_presets_are_what_the_readme_table_says() -> None:
    paper, factory = preset("paper"), preset("factory")
    assert (paper.clearance_m, paper.chamfer_m, paper.hole_depth_m, paper.perturbations) == \
        (0.001, 0.0, 0.04, PerturbationRanges())
    assert (factory.clearance_m, factory.chamfer_m) == (0.0001, 0.0005)
    assert factory.perturbations == PerturbationRanges(hole_error_m=0.001, hole_error_deg=0.0, grasp_offset_m=0.003)


def test_the_preset_files_are_package_data() -> None:
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert "presets/*.toml" in pyproject["tool"]["setuptools"]["package-data"]["envs.task"]
    assert sorted(p.stem for p in (REPO / "envs" / "task" / "presets").glob("*.toml")) == sorted(PRESET_NAMES)


def test_a_key_left_out_keeps_the_default_value(tmp_path: Path) -> None:
    path = write(tmp_path, "version = 1\nclearance_m = 0.0005\n[perturbations]\ngrasp_offset_m = 0.002\n")
    task = Task.from_toml(path)
    assert task == Task().override(clearance_m=0.0005, grasp_offset_m=0.002)
    assert task.perturbations.hole_error_m == Task().perturbations.hole_error_m  # the default task's, not zero


@pytest.mark.parametrize("text, words", [
    ("version = 1\nclearence_m = 0.001\n", "unknown key 'clearence_m'"),
    ("version = 1\n[perturbations]\nhole_eror_m = 0.001\n", "unknown key 'perturbations.hole_eror_m'"),
    ("version = 1\n[scene]\nclearance_m = 0.001\n", "unknown key 'scene'"),
    ('version = 1\nclearance_m = "0.2 mm"\n', "clearance_m = '0.2 mm' must be a number"),
    ("version = 1\nforce_limit_n = true\n", "force_limit_n = True must be a number"),
    ("version = 1\nshape = 3\n", "shape = 3 must be a string"),
    ("version = 1\nperturbations = 0.001\n", "perturbations must be a table"),
    ("version = 1\nclearance_m = 0.01\n", "clearance_m=0.01 is outside"),
    ("version = 1\n[start]\naround = \"everywhere\"\n", "around='everywhere' must be one of mean, demo"),
    ("version = 1\n[perturbations]\nhole_observation = \"camera\"\n",
     "hole_observation='camera' must be one of nominal, measured"),
    ("version = 1\n[success]\nhold_s = -1\n", "hold_s=-1.0 must be a finite number >= 0"),
    # fields past what the code that reads them takes (pihutil.bounds): every episode would fail for it
    ("version = 1\ntime_limit_s = 1e12\n", "time_limit_s=1000000000000.0 must be a number of simulated seconds"),
    ("version = 1\n[sensing]\nsensor_mode = \"wrist\"\nforce_noise_n = 1e300\n",
     "sensing force_noise_n=1e+300 must be a number in [0, 10000] N"),
    ("version = 1\n[sensing]\nsensor_mode = \"joint_torque\"\njoint_torque_bias_nm = 1000.0\n",
     "joint_torque_bias_nm=1000.0 must be a number in [0, 87] N m"),
    ("version = 1\n[success]\nseat_tolerance_m = 1e300\n", "success.seat_tolerance_m=1e+300 must be a number"),
    ("version = 1\n[success]\nfloor_force_n = 50.0\n", "floor_force_n=50.0 must be below force_limit_n=40.0"),
    ('version = 1\nshape = "blob"\n', "shape='blob' is unknown"),
    ("clearance_m = 0.001\n", "missing key 'version'"),
    ("version = 3\n", "version = 3 is not one this pih reads"),
    ("version = 1\nclearance_m = \n", "not valid TOML"),
])
def test_a_bad_file_is_one_line_naming_the_file_and_the_key(tmp_path: Path, text: str, words: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(EnvError) as caught:
        Task.from_toml(path)
    message = str(caught.value)
    assert message.startswith(f"task file {path}") and words in message and "\n" not in message


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(EnvError, match=f"task file {tmp_path / 'gone.toml'} not found"):
        load_task(tmp_path / "gone.toml")


def test_every_task_field_has_one_definition() -> None:
    """The task's fields live in Task (and its nested configs) only: EvaluationConfig holds a Task, not copies; and
    each field's name is unique across the tables, so `Task.override` and the CLI can name it alone."""
    nested = (PerturbationRanges, SuccessConfig, StartRange)
    names = [f.name for f in fields(Task) if f.type not in {k.__name__ for k in nested}]
    names += [f.name for kind in nested for f in fields(kind)]
    assert len(names) == len(set(names))
    assert not set(names) & {f.name for f in fields(EvaluationConfig)}


def test_override_names_a_field_wherever_it_sits() -> None:
    task = Task().override(pos_range_m=0.01, hole_error_deg=2.0, hold_s=0.5, time_limit_s=3.0, clearance_m=None)
    assert (task.start.pos_range_m, task.perturbations.hole_error_deg, task.success.hold_s, task.time_limit_s) == \
        (0.01, 2.0, 0.5, 3.0)
    assert task.clearance_m == Task().clearance_m  # None: not given
    with pytest.raises(EnvError, match="'clearance' is not a task field"):
        Task().override(clearance=0.001)


# ------------------------------------------------------------------------------------------- the CLI


def test_single_options_replace_fields_of_the_file(tmp_path: Path, capsys) -> None:
    path = write(tmp_path, MINE.to_toml())
    assert main(["task", "show", "--task", str(path), "--clearance-mm", "0.3", "--pos-range-mm", "10"]) == 0
    shown = parse_toml(capsys.readouterr().out, "shown")
    assert shown == MINE.override(clearance_m=0.0003, pos_range_m=0.01)


def test_preset_is_an_alias_of_task(capsys) -> None:
    assert main(["task", "show", "--preset", "factory"]) == 0
    by_alias = capsys.readouterr().out
    assert main(["task", "show", "--task", "factory"]) == 0
    assert capsys.readouterr().out == by_alias
    assert parse_toml(by_alias, "shown") == preset("factory")
    assert main(["task", "show", "--task", "paper", "--preset", "factory"]) == 2
    assert "give one" in one_line(capsys)


def test_task_show_prints_the_default_task_as_a_file_to_start_from(capsys) -> None:
    assert main(["task", "show"]) == 0
    assert parse_toml(capsys.readouterr().out, "shown") == Task()


@pytest.mark.parametrize("command", ["demos", "evaluate", "sweep", "run", "benchmark", "compare"])
def test_a_bad_task_file_exits_2_with_one_line_before_any_work(command: str, tmp_path: Path, capsys) -> None:
    bad = write(tmp_path, "version = 1\nclearance_m = -1\n", "bad.toml")
    argv = {"demos": ["--out", str(tmp_path / "d.npz")],
            "evaluate": ["--model", str(tmp_path), "--json", str(tmp_path / "e.json")],
            "sweep": ["--model", str(tmp_path), "--hole-error-mm", "0", "--out", str(tmp_path / "sweep")],
            "run": ["--root", str(tmp_path / "runs")],
            "benchmark": ["--out", str(tmp_path / "bench")],
            "compare": ["--sequential", "--base-model", str(tmp_path), "--cand-model", str(tmp_path)]}[command]
    before = sorted(tmp_path.iterdir())
    assert main([command, "--task", str(bad), *argv]) == 2
    err = one_line(capsys)
    assert err.startswith(f"pih {command}: error: task file {bad}") and "clearance_m" in err
    assert sorted(tmp_path.iterdir()) == before


def test_the_evaluation_takes_the_scene_of_a_task_file_and_the_demos_otherwise(tmp_path: Path) -> None:
    from scripts.evaluate import add_arguments, config_from_args
    import argparse

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    path = write(tmp_path, preset("paper").to_toml())
    given = config_from_args(parser.parse_args(["--task", str(path), "--hole-error-mm", "0.5"]))
    assert given.scene_from_task == SCENE_FROM_TASK and given.task == preset("paper").override(hole_error_m=0.0005)
    assert config_from_args(parser.parse_args(["--clearance-mm", "0.5"])).scene_from_task == ("clearance_m",)
    assert config_from_args(parser.parse_args([])).scene_from_task == ()


# ------------------------------------------------------------------------------------------- the records


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory) -> dict[str, Path]:
    """Two tiny checkpoints trained by `pih train`: from a demo file that records a task (MINE, a triangle task on
    square demos: the demos' scene wins), and from one of before task files (none recorded)."""
    import dataclasses

    from envs.demos.file import save_demos
    from envs.io.owned_output import strict_json
    from tests.helpers.skill_fixtures import TINY_ARGS, synthetic_demos

    folder = tmp_path_factory.mktemp("task_records")
    demos = synthetic_demos()
    files = {"with": save_demos(folder / "with.npz",
                                dataclasses.replace(demos, config={"task": strict_json(MINE.to_dict())})),
             "without": save_demos(folder / "without.npz", demos)}
    for name, path in files.items():
        assert main(["train", "--demos", str(path), "--out", str(folder / name), *TINY_ARGS]) == 0
    return {name: folder / name for name in files}


def test_the_checkpoint_records_the_demos_task_with_their_scene(checkpoints) -> None:
    from envs.cell.scene_config import SceneConfig

    recorded = json.loads((checkpoints["with"] / "skill.json").read_text())["metadata"]["task"]
    scene = SceneConfig(shape="square", clearance_m=0.001)  # the synthetic demos' (no scene recorded)
    assert recorded["version"] == TASK_VERSION
    assert Task.from_dict(recorded) == MINE.with_scene(scene)


def test_a_demo_file_without_a_task_gives_the_default_task_with_its_scene(checkpoints) -> None:
    from envs.cell.scene_config import SceneConfig

    recorded = json.loads((checkpoints["without"] / "skill.json").read_text())["metadata"]["task"]
    assert Task.from_dict(recorded) == Task().with_scene(SceneConfig(shape="square", clearance_m=0.001))


def test_the_result_json_records_the_task_it_ran_and_reads_back(checkpoints, tmp_path: Path) -> None:
    from envs.evaluation.replay import load_evaluation

    path = write(tmp_path, Task(clearance_m=0.0005, time_limit_s=0.05).override(pos_range_m=0.01).to_toml())
    out = tmp_path / "eval.json"
    assert main(["evaluate", "--model", str(checkpoints["without"]), "--task", str(path), "--episodes", "1",
                 "--json", str(out), "--quiet"]) == 0
    data = json.loads(out.read_text())
    ran = Task.from_dict(data["task"])
    assert ran == Task.from_toml(path).override(shape="square", hole_depth_m=data["scene"]["hole_depth_m"])
    assert data["scene"]["clearance_m"] == 0.0005 and "time_limit_s" not in data["config"]
    assert load_evaluation(out).config.task == ran


def test_an_old_checkpoint_without_a_task_still_evaluates(tmp_path: Path) -> None:
    """tiny_skill's metadata is that of a checkpoint of before task files: the scene falls back to its demos'."""
    from envs.evaluation.evaluate import evaluate
    from rflow.skill_io import save_skill
    from tests.helpers.skill_fixtures import tiny_skill

    model = save_skill(tmp_path / "old", tiny_skill())
    result = evaluate(model, EvaluationConfig(episodes=1, task=Task(time_limit_s=0.05)), progress=False)
    assert result.to_dict()["task"] == Task(time_limit_s=0.05).with_scene(result_scene(result)).to_dict()
    assert result.scene["clearance_m"] == 0.001  # the demos', not the task's 0.2 mm


def result_scene(result):
    from envs.cell.scene_config import SceneConfig

    return SceneConfig(**{k: result.scene[k] for k in ("shape", "clearance_m", "chamfer_m", "hole_depth_m", "peg_mode",
                                                       "grasp_force_n")})


def test_an_evaluation_json_of_before_task_files_still_reads() -> None:
    from envs.evaluation.replay import evaluation_config_from_dict

    legacy = {"episodes": 4, "seed": 2, "mode": "closed-loop", "pos_range_m": 0.02, "rot_range_deg": 5.0,
              "around": "demo", "lookahead_s": 0.05, "feedforward_gain": 1.0, "speed": 1.0, "time_limit_s": 8.0,
              "clearance_m": 0.0005, "chamfer_m": None, "peg_mode": None, "grasp_force_n": None,
              "perturbations": {"hole_error_m": 0.002, "hole_error_deg": 0.0, "grasp_offset_m": 0.0},
              "force_limit_n": None, "shape": None, "hole_at_goal": False, "workers": 2, "unit_timeout_s": 300.0,
              "backend": "process", "ray_address": None, "stiffness": None, "contact_adaptation": True}
    config = evaluation_config_from_dict(legacy, "old.json")
    assert config.task == Task().override(pos_range_m=0.02, rot_range_deg=5.0, around="demo", time_limit_s=8.0,
                                          clearance_m=0.0005, hole_error_m=0.002, hole_error_deg=0.0,
                                          force_limit_n=math.inf)
    assert config.scene_from_task == ("clearance_m",) and (config.episodes, config.seed) == (4, 2)


def test_the_demo_file_records_the_task(tmp_path: Path) -> None:
    from envs.demos.file import load_demos

    path = write(tmp_path, preset("paper").to_toml())
    out = tmp_path / "demos.npz"
    assert main(["demos", "--num", "1", "--samples", "100", "--task", str(path), "--out", str(out)]) == 0
    recorded = Task.from_dict(load_demos(out).config["task"])
    assert recorded == preset("paper").override(shape="square")


def test_the_gym_environment_takes_a_task() -> None:
    from envs.gym_env import PegInHoleGymEnv

    env = PegInHoleGymEnv(task=preset("factory"), hole_error_mm=0.5, time_limit_s=2.0)
    sim = env.sim
    assert (sim.scene.config.clearance_m, sim.scene.config.chamfer_m) == (0.0001, 0.0005)
    assert sim.config.perturbations == PerturbationRanges(hole_error_m=0.0005, grasp_offset_m=0.003)
    assert (sim.config.force_limit_n, sim.config.time_limit_s, sim.config.success) == (40.0, 2.0, SuccessConfig())
    env.close()


def test_a_comparison_records_the_tasks_of_its_evaluations(tmp_path: Path) -> None:
    """The time limit is read from the task (a file of before task files: from its config) and the tasks go into the
    comparison's JSON."""
    from tests.helpers.evaluation_fixtures import synthetic_evaluation

    base = synthetic_evaluation([True] * 10)  # of before task files: config.time_limit_s, no task
    cand = {**synthetic_evaluation([True] * 10), "config": {}, "task": Task(time_limit_s=5.0).to_dict()}
    paths = []
    for name, data in (("base", base), ("cand", cand)):
        paths.append(tmp_path / f"{name}.json")
        paths[-1].write_text(json.dumps(data))
    out = tmp_path / "cmp.json"
    assert main(["compare", *map(str, paths), "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["base_task"] is None and Task.from_dict(data["candidate_task"]) == Task(time_limit_s=5.0)
    assert data["time_to_seat_of_a_failure_s"] == 20.0  # the larger of the two time limits
