"""`pih sensitivity` (envs.evaluation.sensitivity): every variant runs the ideal cell's episodes with one imperfection
set, pairs with it episode for episode, and the command writes the table, JSON and figure."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from envs.evaluation.config import EvaluationConfig
from envs.evaluation.sensitivity import ALTERNATIVES, IMPERFECTIONS, run_sensitivity, sensitivity_table
from envs.task.task import Task
from scripts.cli import main
from scripts.sensitivity import IMPERFECTION_NAMES


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    from rflow.skill_io import save_skill
    from tests.helpers.skill_fixtures import tiny_skill

    return save_skill(tmp_path_factory.mktemp("sens") / "model", tiny_skill())


def test_the_cli_names_are_the_imperfections() -> None:
    assert IMPERFECTION_NAMES == (*IMPERFECTIONS, *ALTERNATIVES)


def test_every_variant_pairs_with_the_ideal_cell(model) -> None:
    config = EvaluationConfig(episodes=3, seed=5, task=Task(time_limit_s=0.3))
    seen = []
    rows = run_sensitivity(model, config, ["payload", "grasp_offset"], on_variant=seen.append)
    assert seen == ["ideal", "payload", "grasp_offset", "all"] == [r.name for r in rows]
    assert rows[0].comparison is None and all(r.comparison.success.counts.pairs == 3 for r in rows[1:])
    assert rows[3].settings == {**IMPERFECTIONS["payload"], **IMPERFECTIONS["grasp_offset"]}
    table = sensitivity_table(rows).splitlines()
    assert len(table) == 2 + 4 and table[2].startswith("| ideal | ")


def _short_task(folder: Path) -> Path:
    """The contact task with 1 s episodes, as a task file: the command's plumbing, not its rates, is under test."""
    path = folder / "short.toml"
    path.write_text(Task().override(time_limit_s=1.0).to_toml())
    return path


def test_the_command_writes_table_json_and_figure(model, tmp_path) -> None:
    out = tmp_path / "sens"
    assert main(["sensitivity", "--model", str(model), "--out", str(out), "--episodes", "2", "--workers", "1",
                 "--only", "payload", "--task", str(_short_task(tmp_path))]) == 0
    data = json.loads((out / "sensitivity.json").read_text())
    assert [row["name"] for row in data["rows"]] == ["ideal", "payload"]
    assert data["rows"][1]["paired_with_ideal"]["success"]["pairs"] == 2
    assert (out / "sensitivity.png").stat().st_size > 10_000 and "| payload |" in (out / "sensitivity.md").read_text()
    assert main(["sensitivity", "--model", str(model), "--out", str(out), "--episodes", "2", "--workers", "1",
                 "--only", "payload"]) == 2  # outputs there: --overwrite needed


def test_an_unknown_imperfection_is_refused(model, tmp_path, capsys) -> None:
    assert main(["sensitivity", "--model", str(model), "--out", str(tmp_path / "x"), "--only", "gravity"]) == 2
    assert "gravity" in capsys.readouterr().err


def test_a_foreign_registry_is_refused_before_any_episode(model, tmp_path, capsys, monkeypatch) -> None:
    import scripts.sensitivity  # noqa: F401 -- the command's module, whose runner must not be reached

    out = tmp_path / "sens"
    out.mkdir()
    (out / ".pih-outputs.json").write_text('{"files": {}}')  # not written by pih
    monkeypatch.setattr("envs.evaluation.sensitivity.run_sensitivity",
                        lambda *a, **k: pytest.fail("episodes ran before the outputs were checked"))
    assert main(["sensitivity", "--model", str(model), "--out", str(out), "--episodes", "1", "--workers", "1",
                 "--only", "payload"]) == 2
    assert ".pih-outputs.json" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [".pih-outputs.json"]


@pytest.mark.parametrize("bad", ["task", "model"])
def test_bad_input_leaves_no_output_folder(model, tmp_path, capsys, bad) -> None:
    out = tmp_path / "new" if bad == "task" else tmp_path / "deep"
    args = ["sensitivity", "--model", str(model), "--out", str(out), "--episodes", "1", "--workers", "1",
            "--only", "payload"]
    if bad == "task":
        (tmp_path / "bad.toml").write_text("this is = not [toml")
        args += ["--task", str(tmp_path / "bad.toml")]
    else:
        garbage = tmp_path / "garbage"
        garbage.mkdir()
        (garbage / "skill.json").write_text("{")
        args[2] = str(garbage)
    assert main(args) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not out.exists()


def test_the_cli_names_are_the_curves() -> None:
    from envs.evaluation.sensitivity import CURVES
    from scripts.sensitivity import CURVE_NAMES, DEFAULT_CURVES

    assert CURVE_NAMES == tuple(CURVES) and set(DEFAULT_CURVES) <= set(CURVES)


def test_a_curve_sweeps_one_imperfection_over_its_magnitude() -> None:
    """Each point of a curve is the ideal cell with that imperfection at that magnitude, and nothing else: the joint
    friction's points are the identified friction scaled so that its largest joint's Coulomb friction is x."""
    from envs.evaluation.sensitivity import CURVES, curve_variants
    from envs.sim.joint_friction import PANDA_COULOMB_NM

    config = EvaluationConfig(task=Task())
    points = curve_variants(config, ["joint_friction", "in_hand_tilt"])
    assert [name for name, _, _ in points] == [f"joint_friction@{x:g}" for x in CURVES["joint_friction"].points] + [
        f"in_hand_tilt@{x:g}" for x in CURVES["in_hand_tilt"].points]
    for (name, _, task), x in zip(points[:4], CURVES["joint_friction"].points):
        scale = task.perturbations.joint_friction_scale_max
        assert scale * max(PANDA_COULOMB_NM) == pytest.approx(x) and task.perturbations.joint_friction_scale_min == scale
        assert task.override(joint_friction_scale_min=0.0, joint_friction_scale_max=0.0) == Task()
    assert points[-1][2] == Task().override(grasp_tilt_deg=2.0)
    with pytest.raises(Exception, match="unknown sensitivity curve"):
        curve_variants(config, ["gravity"])


def test_the_command_writes_a_figure_per_curve(model, tmp_path) -> None:
    out = tmp_path / "curves"
    assert main(["sensitivity", "--model", str(model), "--out", str(out), "--episodes", "2", "--workers", "1",
                 "--curves", "in_hand_tilt", "--task", str(_short_task(tmp_path))]) == 0
    data = json.loads((out / "sensitivity.json").read_text())
    assert [row["name"] for row in data["rows"]] == ["ideal"] + [f"in_hand_tilt@{x:g}" for x in (0.5, 1.0, 1.5, 2.0)]
    assert all(row["paired_with_ideal"]["success"]["pairs"] == 2 for row in data["rows"][1:])
    assert (out / "curve_in_hand_tilt.png").stat().st_size > 10_000
    assert (out / "sensitivity.md").read_text().rstrip().endswith(
        "curve in_hand_tilt: no point lowered the success rate")  # 1 s episodes: none seats, on either cell


def test_the_verdict_names_each_curves_first_costly_point_and_the_costliest_imperfection() -> None:
    from types import SimpleNamespace

    from envs.evaluation.sensitivity import sensitivity_verdict

    def row(name: str, successes: int, difference: float | None) -> SimpleNamespace:
        comparison = None if difference is None else SimpleNamespace(
            success=SimpleNamespace(counts=SimpleNamespace(difference=difference)), )
        return SimpleNamespace(name=name, successes=successes, episodes=100, comparison=comparison,
                               median_held_force_n=10.0)

    curves = [row("ideal", 100, None), row("payload@0.1", 100, 0.0), row("payload@0.2", 99, -0.01),
              row("payload@0.4", 90, -0.1), row("part_friction@0.4", 100, 0.0)]
    assert sensitivity_verdict(curves).splitlines() == [
        "curve payload: first cost at 0.2 (99/100 seated)", "curve part_friction: no point lowered the success rate"]
    single = [row("ideal", 100, None), row("friction", 97, -0.03), row("payload", 99, -0.01), row("all", 50, -0.5)]
    assert sensitivity_verdict(single) == "costliest imperfection: friction (97/100 seated)"
    assert sensitivity_verdict(single[:1] + [row("payload", 100, 0.0)]) == (
        "no imperfection alone lowered the success rate on these episodes")
