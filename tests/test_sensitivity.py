"""`pih sensitivity` (envs.execution.sensitivity): every variant runs the ideal cell's episodes with one imperfection
set, pairs with it episode for episode, and the command writes the table, JSON and figure."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from envs.execution.config import EvaluationConfig
from envs.execution.sensitivity import ALTERNATIVES, IMPERFECTIONS, run_sensitivity, sensitivity_table
from envs.task import Task
from scripts.cli import main
from scripts.sensitivity import IMPERFECTION_NAMES


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    from rflow.skill_io import save_skill
    from skill_fixtures import tiny_skill

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


def test_the_command_writes_table_json_and_figure(model, tmp_path) -> None:
    out = tmp_path / "sens"
    assert main(["sensitivity", "--model", str(model), "--out", str(out), "--episodes", "2", "--workers", "1",
                 "--only", "payload"]) == 0
    data = json.loads((out / "sensitivity.json").read_text())
    assert [row["name"] for row in data["rows"]] == ["ideal", "payload"]
    assert data["rows"][1]["paired_with_ideal"]["success"]["pairs"] == 2
    assert (out / "sensitivity.png").stat().st_size > 10_000 and "| payload |" in (out / "sensitivity.md").read_text()
    assert main(["sensitivity", "--model", str(model), "--out", str(out), "--episodes", "2", "--workers", "1",
                 "--only", "payload"]) == 2  # outputs there: --overwrite needed


def test_an_unknown_imperfection_is_refused(model, tmp_path, capsys) -> None:
    assert main(["sensitivity", "--model", str(model), "--out", str(tmp_path / "x"), "--only", "gravity"]) == 2
    assert "gravity" in capsys.readouterr().err
