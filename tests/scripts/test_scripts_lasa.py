"""Tests of `pih lasa` (scripts/lasa.py, scripts/lasa_report.py): input errors, the report, failure capture,
the journalled batch (resume, a dead worker, exit status) and the outputs."""

import json
import math
import os

import numpy as np
import pytest

from envs.io.owned_output import write_json
from rflow.config_file import train_config_record
from rflow.lasa import ShapeResult
from rflow.model import ModelConfig
from rflow.train import TrainConfig
from scripts import cli
from scripts import lasa as lasa_script
from scripts.lasa import run_job
from scripts.lasa_report import gains, markdown_table, summary

TINY = ["--n-points", "30", "--epochs", "1", "--layers", "2"]


@pytest.mark.parametrize(
    "argv",
    [
        ["lasa", "--shape", "NoShape"],
        ["lasa", "--shape", "NShape", "--manifold", "so3"],
        ["lasa", "--shape", "NShape", "--method", "gmm"],
        ["lasa", "--all"],
        ["lasa", "--all", "--out", "unused", "--shapes", "NShape,Nope"],
        ["lasa", "--all", "--out", "unused", "--methods", "rflow,rflow"],
        ["lasa", "--all", "--out", "unused", "--backend", "mpi"],
        ["lasa", "--all", "--out", "unused", "--workers", "0"],
        ["lasa", "--all", "--out", "unused", "--ray-address", "nohost"],
        ["lasa", "--shape", "NShape", "--config", "missing.json"],
        ["lasa", "--shape", "NShape", "--resume"],
        ["lasa", "--all", "--out", "unused", "--resume"],
    ],
)
def test_bad_input_is_a_one_line_error_with_exit_2(argv: list[str], capsys: pytest.CaptureFixture, tmp_path) -> None:
    os.chdir(tmp_path)
    assert cli.main(argv) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not (tmp_path / "unused").exists()  # nothing written before the options are validated


def test_config_file_together_with_a_hyperparameter_option_is_refused(tmp_path, capsys) -> None:
    path = write_json(tmp_path / "best.json", train_config_record(TrainConfig()))
    assert cli.main(["lasa", "--shape", "Angle", "--config", str(path), "--lr", "0.01"]) == 2
    assert "--lr" in capsys.readouterr().err


def _result(shape: str, manifold: str, method: str, dtw: float) -> ShapeResult:
    return ShapeResult(shape, manifold, method, 0, 1000, 40, dtw=dtw, manifold_distance=0.1, train_time_s=10.0,
                       generate_time_s=0.2)


def test_gain_is_relative_to_the_baseline_mean_dtw() -> None:
    results = [_result("Angle", "spd", "rflow", 80.0), _result("Angle", "spd", "naive", 100.0),
               _result("Sine", "spd", "rflow", 100.0), _result("Sine", "spd", "naive", 100.0),
               _result("Angle", "spd", "fdm", 160.0), _result("Sine", "spd", "fdm", 200.0)]
    assert gains(results)["spd"]["gain_percent"] == pytest.approx(10.0)
    assert gains(results, "fdm")["spd"]["gain_percent"] == pytest.approx(50.0)


def test_gain_skips_shapes_where_a_method_failed() -> None:
    failed = ShapeResult("Sine", "uq", "naive", 0, 1000, 40, error="RFlowError: boom")
    results = [_result("Angle", "uq", "rflow", 50.0), _result("Angle", "uq", "naive", 100.0),
               _result("Sine", "uq", "rflow", 500.0), failed]
    assert gains(results)["uq"]["gain_percent"] == pytest.approx(50.0)


def test_summary_is_mean_and_std_over_successful_shapes() -> None:
    failed = ShapeResult("Sine", "spd", "rgmm", 0, 1000, 40, error="worker_died")
    results = [_result("Angle", "spd", "rgmm", 100.0), _result("Line", "spd", "rgmm", 300.0), failed]
    s = summary(results)["spd"]["rgmm"]
    assert (s["runs"], s["failed"], s["dtw_mean"], s["dtw_std"]) == (3, 1, 200.0, 100.0)


def test_markdown_table_has_a_row_per_shape_and_lists_failures() -> None:
    failed = ShapeResult("Sine", "uq", "fdm", 0, 1000, 40, error="wall_timeout")
    text = markdown_table([_result("Angle", "spd", "rflow", 80.0), failed], TrainConfig())
    assert "| Angle | 80.0 |" in text and "| Sine |" in text and "Sine uq fdm: wall_timeout" in text
    assert "| UQ | FDM | 0/1 | — |" in text


def test_run_job_records_a_failure_instead_of_raising() -> None:
    result = run_job("Angle", "spd", "rflow", TrainConfig(), n_points=1)
    assert result.error is not None and result.error.startswith("RFlowError") and math.isnan(result.dtw)


@pytest.mark.slow
def test_a_finished_run_is_not_redone_on_resume_and_a_new_run_is_refused(tmp_path, capsys) -> None:
    argv = ["lasa", "--all", "--out", str(tmp_path), "--shapes", "Angle", "--manifolds", "spd", "--methods", "fdm",
            *TINY]
    assert cli.main(argv) == 0
    first = json.loads((tmp_path / "results.json").read_text())["results"]
    assert cli.main(argv) == 2  # the folder holds a run: never overwritten without --resume
    assert "--resume" in capsys.readouterr().err
    assert cli.main(argv + ["--resume"]) == 0
    assert "resuming: 1 of 1 runs" in capsys.readouterr().out
    assert json.loads((tmp_path / "results.json").read_text())["results"] == first
    assert cli.main(argv[:-2] + ["--layers", "3", "--resume"]) == 2  # a different run's journal


def _die_on_rgmm(setup, unit):
    """A unit that kills its worker process when it is R-GMM's (as the OS would, out of memory)."""
    if unit[2] == "rgmm":
        os._exit(9)
    return lasa_script.work_unit(setup, unit)


@pytest.mark.slow
def test_a_unit_whose_worker_dies_on_every_try_is_an_infrastructure_error(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(lasa_script, "work_unit", _die_on_rgmm)
    argv = ["lasa", "--all", "--workers", "2", "--out", str(tmp_path), "--shapes", "Angle", "--manifolds", "spd",
            "--methods", "fdm,rgmm,naive", *TINY]
    assert cli.main(argv) == 3  # incomplete: --resume runs it again
    record = json.loads((tmp_path / "results.json").read_text())
    assert not record["complete"] and {r["method"]: r["error"] for r in record["results"]} == {"fdm": None, "naive": None}
    assert [r["error"] for r in record["infrastructure_errors"]] == ["infrastructure: worker_died after 3 tries"]
    assert [e["unit_action"] for e in record["infrastructure_events"]] == ["retried", "retried", "given_up"]


def test_single_shape_writes_json_and_trajectories(tmp_path, capsys: pytest.CaptureFixture) -> None:
    argv = ["lasa", "--shape", "Angle", "--manifold", "spd", "--method", "naive", *TINY,
            "--json", str(tmp_path / "r.json"), "--save-trajectories", str(tmp_path / "t.npz")]
    assert cli.main(argv) == 0
    assert capsys.readouterr().out.startswith("Angle spd naive: DTW ")
    assert json.loads((tmp_path / "r.json").read_text())["n_points"] == 30
    assert np.load(tmp_path / "t.npz")["generated"].shape == (4, 30, 2, 2)


def test_single_shape_takes_hyperparameters_from_a_config_file(tmp_path, capsys) -> None:
    config = TrainConfig(model=ModelConfig(layers=2, width=8, activation="tanh"), optimizer="rmsprop", epochs=1)
    path = write_json(tmp_path / "best.json", train_config_record(config))
    argv = ["lasa", "--shape", "Angle", "--method", "rflow", "--n-points", "30", "--config", str(path),
            "--json", str(tmp_path / "r.json")]
    assert cli.main(argv) == 0
    assert json.loads((tmp_path / "r.json").read_text())["epochs"] == 1
