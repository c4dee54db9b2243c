"""Tests of `pih lasa` (scripts/lasa.py): input errors, the report, failure capture, the batch outputs."""

import json
import math

import pytest

from rflow.lasa import ShapeResult
from rflow.train import TrainConfig
from scripts import cli
from scripts.lasa import gains, markdown_table, run_job, write_json


@pytest.mark.parametrize(
    "argv",
    [
        ["lasa", "--shape", "NoShape"],
        ["lasa", "--shape", "NShape", "--manifold", "so3"],
        ["lasa", "--shape", "NShape", "--method", "gmm"],
        ["lasa", "--all"],
        ["lasa", "--all", "--out", "unused", "--shapes", "NShape,Nope"],
    ],
)
def test_bad_input_is_a_one_line_error_with_exit_2(argv: list[str], capsys: pytest.CaptureFixture) -> None:
    assert cli.main(argv) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def _result(shape: str, manifold: str, method: str, dtw: float) -> ShapeResult:
    return ShapeResult(shape, manifold, method, 0, 1000, 40, dtw=dtw, manifold_distance=0.1, train_time_s=10.0,
                       generate_time_s=0.2)


def test_gain_is_relative_to_naive_mean_dtw() -> None:
    results = [_result("Angle", "spd", "rflow", 80.0), _result("Angle", "spd", "naive", 100.0),
               _result("Sine", "spd", "rflow", 100.0), _result("Sine", "spd", "naive", 100.0)]
    assert gains(results)["spd"]["gain_percent"] == pytest.approx(10.0)


def test_gain_skips_shapes_where_a_method_failed() -> None:
    failed = ShapeResult("Sine", "uq", "naive", 0, 1000, 40, error="RFlowError: boom")
    results = [_result("Angle", "uq", "rflow", 50.0), _result("Angle", "uq", "naive", 100.0),
               _result("Sine", "uq", "rflow", 500.0), failed]
    assert gains(results)["uq"]["gain_percent"] == pytest.approx(50.0)


def test_markdown_table_has_a_row_per_shape_and_lists_failures() -> None:
    failed = ShapeResult("Sine", "uq", "naive", 0, 1000, 40, error="RFlowError: boom")
    text = markdown_table([_result("Angle", "spd", "rflow", 80.0), failed], TrainConfig())
    assert "| Angle | 80.0 |" in text and "| Sine |" in text and "Sine uq naive: RFlowError: boom" in text


def test_run_job_records_a_failure_instead_of_raising() -> None:
    result = run_job("Angle", "spd", "rflow", TrainConfig(), n_points=1)
    assert result.error is not None and result.error.startswith("RFlowError") and math.isnan(result.dtw)


def test_write_json_replaces_atomically_and_leaves_no_temp_file(tmp_path) -> None:
    path = write_json(tmp_path / "r.json", {"a": 1})
    with pytest.raises(ValueError):
        write_json(path, {"a": math.nan})  # allow_nan=False: the write fails half-way
    assert json.loads(path.read_text()) == {"a": 1} and [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_batch_writes_results_table_and_figures(tmp_path) -> None:
    argv = ["lasa", "--all", "--workers", "2", "--out", str(tmp_path), "--shapes", "Angle", "--manifolds", "uq",
            "--n-points", "30", "--epochs", "1", "--layers", "2"]
    assert cli.main(argv) == 0
    record = json.loads((tmp_path / "results.json").read_text())
    assert record["complete"] and {r["method"] for r in record["results"]} == {"rflow", "naive"}
    assert (tmp_path / "results.md").is_file() and (tmp_path / "figures" / "Angle.png").stat().st_size > 0


def test_single_shape_writes_json_and_trajectories(tmp_path, capsys: pytest.CaptureFixture) -> None:
    import numpy as np

    argv = ["lasa", "--shape", "Angle", "--manifold", "spd", "--method", "naive", "--n-points", "30",
            "--epochs", "1", "--layers", "2", "--json", str(tmp_path / "r.json"),
            "--save-trajectories", str(tmp_path / "t.npz")]
    assert cli.main(argv) == 0
    assert capsys.readouterr().out.startswith("Angle spd naive: DTW ")
    assert json.loads((tmp_path / "r.json").read_text())["n_points"] == 30
    assert np.load(tmp_path / "t.npz")["generated"].shape == (4, 30, 2, 2)
