"""`pih compare`: exit status 0 / 1 / 2, one-line errors, the refusal of unpaired evaluations, strict JSON output
(synthetic evaluation files); the sequential mode on a tiny skill (slow)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from scripts.cli import main as pih
from tests.helpers.evaluation_fixtures import synthetic_evaluation

EPISODES = 60
BASE = [i != 3 for i in range(EPISODES)]
WORSE = [i % 6 != 0 for i in range(EPISODES)]  # 10 of the base's successes fail
SLIGHTLY_WORSE = [i not in (3, 6) for i in range(EPISODES)]  # one episode fails that the base seated


def strict_json(path: Path) -> dict:
    def refuse(constant: str) -> None:
        raise AssertionError(f"{path} holds {constant}")
    return json.loads(path.read_text(), parse_constant=refuse)


@pytest.fixture
def files(tmp_path):
    def write(name: str, data: object) -> str:
        path = tmp_path / name
        path.write_text(data if isinstance(data, str) else json.dumps(data))
        return str(path)

    return {
        "base": write("base.json", synthetic_evaluation(BASE)),
        "worse": write("worse.json", synthetic_evaluation(WORSE)),
        "slightly": write("slightly.json", synthetic_evaluation(SLIGHTLY_WORSE)),
        "other_seed": write("other.json", synthetic_evaluation(BASE, seed=1)),
        "fewer": write("fewer.json", synthetic_evaluation(BASE[:40])),
        "not_json": write("notes.json", "seated: most of them"),
        "not_eval": write("config.json", {"epochs": 80}),
        "missing": str(tmp_path / "missing.json"),
    }


@pytest.mark.parametrize("cand, extra, status", [
    ("base", [], 0),
    ("worse", [], 1),
    ("slightly", [], 0),
    ("worse", ["--margin", "0.5"], 0),
])
def test_exit_status_says_whether_the_candidate_regressed(files, capsys, cand, extra, status):
    assert pih(["compare", files["base"], files[cand], *extra]) == status
    assert ("decision" in capsys.readouterr().out)


@pytest.mark.parametrize("args, message", [
    (["base", "missing"], "CAND {missing}: file not found"),
    (["not_json", "base"], "BASE {not_json}: not JSON"),
    (["base", "not_eval"], "not an evaluation of `pih evaluate --json`"),
    (["base", "other_seed"], "episode 0: start_pos differs"),
    (["base", "fewer"], "episode 40 is only in the base"),
    (["base"], "give two evaluations"),
    (["base", "base", "--margin", "1.5"], "argument --margin"),
    (["base", "base", "--alpha", "0"], "--alpha 0"),
    (["base", "base", "--sequential"], "--sequential runs the episodes itself"),
    (["--sequential", "--cand-model", "base"], "--sequential needs --base-model"),
])
def test_bad_input_is_one_line_and_status_2(files, capsys, args, message):
    argv = [files.get(a, a) for a in args]
    assert pih(["compare", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pih compare: error: ") and err.count("\n") == 1
    assert message.format(**files) in err


def test_json_output_is_strict_and_holds_the_decision(files, tmp_path):
    out = tmp_path / "out.json"
    assert pih(["compare", files["base"], files["worse"], "--json", str(out)]) == 1
    data = strict_json(out)
    assert data["kind"] == "pih compare" and data["decision"] == "regression"
    assert data["success"]["paired_counts"] == {"both": 49, "base_only": 10, "cand_only": 1, "neither": 0}


def test_missing_figures_become_null_not_nan(tmp_path):
    data = synthetic_evaluation(BASE)
    for r in data["per_episode"]:
        r["peak_sustained_wrist_force_n"] = None
    base = tmp_path / "b.json"
    base.write_text(json.dumps(data))
    out = tmp_path / "out.json"
    assert pih(["compare", str(base), str(base), "--json", str(out)]) == 0
    assert strict_json(out)["metrics"]["held_force_n"]["median_difference"] is None


def test_an_existing_output_is_replaced_only_with_overwrite_and_only_if_it_is_a_comparison(files, tmp_path, capsys):
    out = tmp_path / "out.json"
    args = ["compare", files["base"], files["base"], "--json", str(out)]
    assert pih(args) == 0
    assert pih(args) == 2 and "--overwrite" in capsys.readouterr().err
    assert pih(args + ["--overwrite"]) == 0
    assert pih(["compare", files["base"], files["base"], "--json", files["worse"], "--overwrite"]) == 2
    assert "not written by pih" in capsys.readouterr().err
    assert json.loads(Path(files["worse"]).read_text()) == synthetic_evaluation(WORSE)


@pytest.mark.slow
def test_sequential_mode_runs_paired_episodes_until_a_decision_independent_of_the_chunk(tmp_path):
    from rflow.skill_io import save_skill
    from tests.helpers.skill_fixtures import tiny_skill

    model = str(save_skill(tmp_path / "model", tiny_skill()))
    decided = []
    for chunk in ("4", "7"):
        out = tmp_path / f"seq{chunk}.json"
        args = ["compare", "--sequential", "--base-model", model, "--cand-model", model, "--margin", "0.9",
                "--max-episodes", "20", "--chunk", chunk, "--time-limit-s", "0.05", "--quiet", "--json", str(out)]
        assert pih(args) == 0
        data = strict_json(out)
        assert data["sequential"]["decision"] == "no regression"
        decided.append(data["sequential"]["decided_at_pair"])
        assert len(data["base_evaluation"]["per_episode"]) == decided[-1]
    assert decided[0] == decided[1] < 20


@pytest.mark.parametrize("field, value, message", [
    ("index", True, "record 0 has index True, not an episode"),
    ("time_to_insert_s", "fast", "time_to_insert_s='fast', not a number or null"),
    ("peak_sustained_wrist_force_n", True, "peak_sustained_wrist_force_n=True, not a number or null"),
])
def test_a_record_field_of_the_wrong_type_is_one_line_not_a_figure(tmp_path, capsys, field, value, message):
    data = synthetic_evaluation(BASE)
    data["per_episode"][0][field] = value
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    good = tmp_path / "good.json"
    good.write_text(json.dumps(synthetic_evaluation(BASE)))
    assert pih(["compare", str(good), str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
