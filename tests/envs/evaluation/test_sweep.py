"""Success maps (envs.evaluation.sweep, `pih sweep`): the grid, common starts, per-cell statistics, the files, and
bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from envs.errors import EnvError
from envs.evaluation.evaluate import EvaluationConfig
from envs.evaluation.starts import evaluation_starts
from envs.evaluation.sweep import SweepAxes, cell_summary, sweep_cells, sweep_units, unit_key
from envs.task.perturbation import PerturbationRanges
from envs.task.task import Task
from rflow.skill_io import save_skill
from scripts import cli
from scripts.sweep import parse_values
from tests.helpers.skill_fixtures import tiny_skill


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory) -> Path:
    return save_skill(tmp_path_factory.mktemp("sweep") / "model", tiny_skill())


def test_cells_are_the_product_of_the_axes_first_axis_slowest() -> None:
    cells = sweep_cells(EvaluationConfig(), SweepAxes(clearance_m=(0.001, 0.0002), hole_error_m=(0.0, 0.001, 0.002)))
    assert [c.settings for c in cells[:3]] == [{"clearance_m": 0.001, "hole_error_m": e} for e in (0.0, 0.001, 0.002)]
    assert len(cells) == 6 and cells[4].config.task.clearance_m == 0.0002
    assert cells[4].config.scene_from_task == ("clearance_m",)  # the swept clearance replaces the demos'
    assert cells[4].config.task.perturbations.hole_error_m == 0.001


def test_settings_not_swept_keep_the_base_config() -> None:
    ranges = PerturbationRanges(hole_error_m=0.001, hole_error_deg=0.5)
    base = EvaluationConfig(task=Task(perturbations=ranges), seed=3)
    cell = sweep_cells(base, SweepAxes(hole_error_m=(0.002,)))[0]
    assert cell.config.task.perturbations.hole_error_deg == 0.5 and cell.config.seed == 3
    assert "clearance_m" not in cell.config.scene_from_task  # the demos' clearance


def test_every_cell_uses_the_same_starts_and_scaled_perturbations() -> None:
    """Common random numbers: the cells differ only by their setting."""
    demo_starts = {"pos": [[0.6, 0.0, 0.4], [0.62, 0.02, 0.41]], "quat": [[0.0, 1.0, 0.0, 0.0]] * 2}
    cells = sweep_cells(EvaluationConfig(episodes=3), SweepAxes(hole_error_m=(0.001, 0.002)))
    units = sweep_units(cells, demo_starts)
    assert [key for key, _ in units] == [unit_key(c, e) for c in (0, 1) for e in range(3)]
    small, large = [start for _, (_, start) in units[:3]], [start for _, (_, start) in units[3:]]
    for a, b in zip(small, large):
        assert (a.pose.pos == b.pose.pos).all()
        assert b.perturbation.hole_offset_m == pytest.approx(2 * a.perturbation.hole_offset_m)
    alone = evaluation_starts(demo_starts, cells[0].config)  # the same starts as a plain evaluation of the cell
    assert all((a.pose.pos == b.pose.pos).all() and a.perturbation == b.perturbation for a, b in zip(small, alone))


def test_cell_summary_counts_and_interval() -> None:
    cell = sweep_cells(EvaluationConfig(), SweepAxes(clearance_m=(0.001,)))[0]
    records = [{"index": i, "demo_index": -1, "start_pos": [0, 0, 0], "start_quat": [1, 0, 0, 0], "success": i < 3,
                "reason": "success" if i < 3 else "time_limit (stuck)", "time_to_insert_s": 5.0 if i < 3 else None,
                "peak_wrist_force_n": 10.0 * (i + 1), "touched": True} for i in range(4)]
    summary = cell_summary(cell, records)
    assert (summary["successes"], summary["episodes"]) == (3, 4)
    assert summary["median_peak_wrist_force_n"] == 20.0 and summary["failures_by_kind"] == {"time_limit": 1}
    low, high = summary["success_rate_ci95"]
    assert low < 0.75 < high


def test_no_axis_is_an_error() -> None:
    with pytest.raises(EnvError, match="axis"):
        sweep_cells(EvaluationConfig(), SweepAxes())


@pytest.mark.parametrize("text, match", [("1,x", "not a number"), ("1,-0.5", ">= 0"), ("nan", ">= 0")])
def test_bad_axis_values_are_rejected(text, match) -> None:
    with pytest.raises(EnvError, match=match):
        parse_values("--clearance-mm", text, 1e-3)


def test_out_of_range_value_is_rejected_before_any_work(model_dir, tmp_path, capsys) -> None:
    out = tmp_path / "sweep"
    code = cli.main(["sweep", "--model", str(model_dir), "--clearance-mm", "1,9", "--episodes", "1",
                     "--out", str(out), "--quiet"])
    assert code == 2 and "clearance" in capsys.readouterr().err and not out.exists()


def test_sweep_writes_its_map_and_refuses_to_clobber_it(model_dir, tmp_path, capsys) -> None:
    out = tmp_path / "sweep"
    argv = ["sweep", "--model", str(model_dir), "--clearance-mm", "1,0.5", "--hole-error-mm", "0",
            "--episodes", "1", "--time-limit-s", "0.2", "--workers", "1", "--out", str(out), "--quiet"]
    assert cli.main(argv) == 0
    result = json.loads((out / "sweep.json").read_text())
    assert result["complete"] and len(result["cells"]) == 2 and len(result["per_episode"]) == 2
    assert {c["settings"]["clearance_m"] for c in result["cells"]} == {0.001, 0.0005}
    assert (out / "sweep.png").stat().st_size > 0
    capsys.readouterr()
    assert cli.main(argv) == 2 and "--resume or --overwrite" in capsys.readouterr().err
    assert cli.main(argv + ["--resume"]) == 0  # everything is in the journal: nothing runs again


def test_a_missing_checkpoint_leaves_nothing_behind(tmp_path) -> None:
    """Exit 2 before any episode, and no output folder."""
    out = tmp_path / "sweep"
    argv = ["sweep", "--model", str(tmp_path / "missing"), "--clearance-mm", "1", "--episodes", "1",
            "--out", str(out), "--quiet"]
    assert cli.main(argv) == 2 and not out.exists()


def test_stiffness_is_an_axis_and_each_cell_commands_its_own() -> None:
    cells = sweep_cells(EvaluationConfig(), SweepAxes(hole_error_m=(0.001,), stiffness=("learned", "constant:500")))
    assert [c.settings for c in cells] == [{"hole_error_m": 0.001, "stiffness": "learned"},
                                           {"hole_error_m": 0.001, "stiffness": "constant:500"}]
    assert [c.config.stiffness for c in cells] == ["learned", "constant:500"]


def test_sweep_over_stiffness_records_it_and_resume_needs_the_same_axis(model_dir, tmp_path, capsys) -> None:
    out = tmp_path / "sweep"
    argv = ["sweep", "--model", str(model_dir), "--stiffness", "constant:500,constant:2000", "--episodes", "1",
            "--time-limit-s", "0.1", "--workers", "1", "--out", str(out), "--quiet"]
    assert cli.main(argv) == 0
    result = json.loads((out / "sweep.json").read_text())
    assert [c["settings"]["stiffness"] for c in result["cells"]] == ["constant:500", "constant:2000"]
    by_cell = {r["cell"]: r for r in result["per_episode"]}
    assert (by_cell[0]["min_stiffness_n_m"], by_cell[0]["max_stiffness_n_m"]) == pytest.approx((500.0, 500.0))
    assert (by_cell[1]["min_stiffness_n_m"], by_cell[1]["max_stiffness_n_m"]) == pytest.approx((2000.0, 2000.0))
    capsys.readouterr()
    other = [a if a != "constant:500,constant:2000" else "constant:500,constant:3000" for a in argv]
    assert cli.main(other + ["--resume"]) == 2  # the journal is of another sweep
    assert "\n" not in capsys.readouterr().err.strip()


@pytest.mark.parametrize("spec, words", [("constant:0,learned", "K must be in"), ("constant:-1", "K must be in"),
                                         ("soft", "learned"), ("learned", "needs a skill trained")])
def test_bad_stiffness_axis_exits_2_before_any_work(model_dir, tmp_path, capsys, spec, words) -> None:
    out = tmp_path / "sweep"
    code = cli.main(["sweep", "--model", str(model_dir), "--stiffness", spec, "--episodes", "1", "--out", str(out),
                     "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and words in err and "\n" not in err and not out.exists()


def _summary(settings: dict, rate: float) -> dict:
    return {"settings": settings, "success_rate": rate, "success_rate_ci95": [0.0, 1.0],
            "median_peak_wrist_force_n": None}


def test_a_single_axis_map_is_one_full_row() -> None:
    from envs.media.figures import success_map

    cells = [_summary({"clearance_m": c}, r) for c, r in ((0.001, 1.0), (0.0005, 0.5), (0.0002, 0.25))]
    m = success_map(cells, None, "clearance_m")
    assert len(m.grids) == 1 and m.grids[0].shape == (1, 3)
    np.testing.assert_array_equal(m.grids[0], [[25.0, 50.0, 100.0]])  # columns ascending


def test_a_two_axis_map_puts_every_cell_in_its_square() -> None:
    from envs.media.figures import success_map

    cells = [_summary({"clearance_m": c, "hole_error_m": e}, 0.1 * i)
             for i, (c, e) in enumerate((c, e) for c in (0.001, 0.0002) for e in (0.0, 0.001))]
    grid = success_map(cells, "clearance_m", "hole_error_m").grids[0]
    np.testing.assert_allclose(grid, [[0.0, 10.0], [20.0, 30.0]])  # rows: clearance descending (numbers grow upwards)


def test_a_sweep_in_lockstep_gives_the_records_of_one_episode_at_a_time(model_dir) -> None:
    """Each cell's episodes in lockstep on that cell's slots (groups may straddle two cells) give the records of one
    episode at a time."""
    from envs.evaluation.sweep import sweep

    def records(lockstep: int) -> list[dict]:
        base = EvaluationConfig(episodes=4, task=Task(time_limit_s=0.3), lockstep=lockstep)
        cells = sweep_cells(base, SweepAxes(clearance_m=(0.001, 0.0005)))
        result = sweep(str(model_dir), cells, progress=False)
        assert result.complete
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in result.to_dict()["per_episode"]]

    alone, batched = records(1), records(3)
    assert batched == alone and len(alone) == 8 and {r["cell"] for r in alone} == {0, 1}


def test_a_foreign_registry_is_refused_before_any_episode(model_dir, tmp_path, capsys) -> None:
    out = tmp_path / "sweep"
    out.mkdir()
    (out / ".pih-outputs.json").write_text('{"files": {}}')  # not written by pih
    argv = ["sweep", "--model", str(model_dir), "--clearance-mm", "1", "--episodes", "1", "--time-limit-s", "0.2",
            "--workers", "1", "--out", str(out), "--quiet"]
    assert cli.main(argv) == 2 and ".pih-outputs.json" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == [".pih-outputs.json"]


def test_a_fault_is_one_error_line_and_no_success_map(model_dir, tmp_path, capsys, monkeypatch) -> None:
    """A sweep stopped by a fault (the Ray head lost) prints no cell's success line and writes no map: one line on
    stderr with how to continue, exit 1; the journal keeps what finished."""
    from envs.evaluation import sweep as sweep_module

    def lost_head(model, cells, progress=True, journal=None):
        return sweep_module.SweepResult(model, cells, [], {}, complete=False, interrupted=False, wall_s=1.0,
                                        fault="lost the Ray head at 10.0.0.1:6379: its GCS has not answered for 3 s")

    monkeypatch.setattr(sweep_module, "sweep", lost_head)
    out = tmp_path / "sw"
    assert cli.main(["sweep", "--model", str(model_dir), "--clearance-mm", "0.2", "--episodes", "1", "--out", str(out),
                 "--quiet"]) == 1
    stdout, err = capsys.readouterr()
    assert err.startswith("pih sweep: error: lost the Ray head") and err.count("\n") == 1 and "--resume" in err
    assert stdout == "" and sorted(p.name for p in out.iterdir()) == ["journal.jsonl"]
