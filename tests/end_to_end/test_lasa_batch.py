"""`pih lasa --all` end to end: the journalled batch trains and scores all four methods (RiemannianFlow, the naive
Euclidean flow, R-GMM, FDM) on one LASA shape with two workers and writes the results table and the figures
(tiny settings; the input checks, the report and failure handling: tests/scripts/test_scripts_lasa.py)."""

import json

import pytest

from scripts import cli

TINY = ["--n-points", "30", "--epochs", "1", "--layers", "2"]


@pytest.mark.slow  # trains four methods
def test_batch_writes_results_table_and_figures_for_all_four_methods(tmp_path) -> None:
    argv = ["lasa", "--all", "--workers", "2", "--out", str(tmp_path), "--shapes", "Angle", "--manifolds", "uq", *TINY]
    assert cli.main(argv) == 0
    record = json.loads((tmp_path / "results.json").read_text())
    assert record["complete"] and {r["method"] for r in record["results"]} == {"rflow", "naive", "rgmm", "fdm"}
    assert all(r["error"] is None and r["dtw"] > 0 for r in record["results"])
    assert (tmp_path / "results.md").is_file() and (tmp_path / "figures" / "Angle.png").stat().st_size > 0
    assert (tmp_path / "comparison.png").stat().st_size > 0
