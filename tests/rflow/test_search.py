"""Tests of rflow.search and `pih search` (SQLite): validation from held-out starts, pruning, the config file."""

import json

import numpy as np
import pytest

from envs.io.owned_output import write_json
from rflow.config_file import load_train_config, train_config_from_dict, train_config_record
from rflow.errors import RFlowError
from rflow.lasa import riemannian_lasa
from rflow.model import ModelConfig
from rflow.search import SearchConfig, trial_config, validation_dtw
from rflow.train import TrainConfig, fit
from scripts import cli

optuna = pytest.importorskip("optuna", reason="optuna not installed: pip install -e '.[search]'")

TINY = TrainConfig(model=ModelConfig(layers=2, width=8), epochs=1, transitions_per_epoch=128, horizon=3)


def test_validation_never_starts_at_the_protocol_start(monkeypatch) -> None:
    import rflow.search as search

    data = riemannian_lasa("Angle", "spd", n_points=41)
    model, _ = fit(data.demos, data.manifold, data.dt, TINY, progress=False)
    starts = []
    original = search.rollout

    def spy(model, points, steps, xi):
        starts.append((np.asarray(points), steps))
        return original(model, points, steps, xi=xi)

    monkeypatch.setattr(search, "rollout", spy)
    value = validation_dtw(model, data, fractions=(0.25, 0.5))
    assert np.isfinite(value) and value > 0
    np.testing.assert_array_equal(starts[0][0], data.demos[:, 10])  # 25 % of 40 steps
    np.testing.assert_array_equal(starts[1][0], data.demos[:, 20])
    assert [s for _, s in starts] == [30, 20]  # each rollout runs to the end of its demo


def test_trial_config_sets_only_the_searched_fields() -> None:
    config = trial_config({"layers": 9, "activation": "tanh", "optimizer": "rmsprop", "lr": 3e-4}, TINY)
    assert (config.model.layers, config.model.activation, config.optimizer, config.lr) == (9, "tanh", "rmsprop", 3e-4)
    assert config.model.width == TINY.model.width and config.epochs == TINY.epochs


def test_config_file_round_trips_and_rejects_unknown_fields(tmp_path) -> None:
    config = TrainConfig(model=ModelConfig(layers=9, activation="tanh"), optimizer="sgd", lr=0.02, seed=3)
    path = write_json(tmp_path / "c.json", train_config_record(config, {"trial": 7}))
    assert load_train_config(path) == config
    with pytest.raises(RFlowError, match="model.depth"):
        train_config_from_dict({"model": {"depth": 3}})
    (tmp_path / "bad.json").write_text(json.dumps({"lr": 1}))
    with pytest.raises(RFlowError, match="not a training config"):
        load_train_config(tmp_path / "bad.json")


def test_bad_search_config_raises() -> None:
    with pytest.raises(RFlowError):
        SearchConfig(shape="Nope")
    with pytest.raises(RFlowError):
        SearchConfig(trials=0)


@pytest.mark.parametrize("argv", [["--shape", "Nope"], ["--trials", "0"], ["--storage", "not a url"],
                                  ["--manifold", "so3"], ["--epochs", "0"]])
def test_bad_input_is_a_one_line_error_with_exit_2(argv, tmp_path, capsys) -> None:
    assert cli.main(["search", "--out", str(tmp_path / "out"), *argv]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_search_writes_the_study_and_a_best_config_that_pih_lasa_reads(tmp_path, capsys) -> None:
    out = tmp_path / "search"
    argv = ["search", "--shape", "Angle", "--trials", "3", "--epochs", "2", "--report-every", "1",
            "--n-points", "40", "--out", str(out)]
    assert cli.main(argv) == 0
    record = json.loads((out / "search.json").read_text())
    assert len(record["trials"]) == 3 and (out / "study.db").is_file()
    best = load_train_config(out / "best.json")
    values = [t["value"] for t in record["trials"] if t["state"] == "COMPLETE"]
    assert record["best"]["validation_dtw"] == min(values)
    assert 8 <= best.model.layers <= 12 and best.epochs == 2
    assert cli.main(["lasa", "--shape", "Angle", "--n-points", "40", "--config", str(out / "best.json")]) == 0
    assert "Angle spd rflow: DTW" in capsys.readouterr().out


def test_a_trial_worse_than_the_median_of_earlier_trials_is_pruned_at_its_first_report(tmp_path) -> None:
    import rflow.search as search

    config = SearchConfig(shape="Angle", trials=1, base=TINY.__class__(**{**TINY.__dict__, "epochs": 3}),
                          report_every=1, n_points=40, startup_trials=3)
    study = search.open_study(f"sqlite:///{tmp_path / 's.db'}", "p", sampler_seed=0, startup_trials=3)
    for _ in range(3):  # earlier trials with a validation DTW no real trial reaches
        study.add_trial(optuna.trial.create_trial(value=1e-6, intermediate_values={1: 1e-6, 2: 1e-6, 3: 1e-6}))
    data = riemannian_lasa("Angle", "spd", n_points=40)
    study.optimize(search.make_objective(config, data), n_trials=1)
    last = study.trials[-1]
    assert last.state.name == "PRUNED" and sorted(last.intermediate_values) == [1]


def test_pih_train_takes_its_hyperparameters_from_a_config_file(tmp_path) -> None:
    import argparse

    from scripts import train as train_script

    config = TrainConfig(model=ModelConfig(layers=9, activation="tanh"), optimizer="adamax", lr=0.004, epochs=7)
    path = write_json(tmp_path / "best.json", train_config_record(config))
    parser = argparse.ArgumentParser()
    train_script.add_arguments(parser)
    args = parser.parse_args(["--demos", "d.npz", "--out", "m", "--config", str(path), "--seed", "4"])
    got = train_script.train_config_from_args(args)
    assert got == TrainConfig(model=config.model, optimizer="adamax", lr=0.004, epochs=7, seed=4, threads=1)


@pytest.mark.parametrize("kind", ["another database", "not sqlite"])
def test_somebody_else_s_study_db_is_never_written_into(kind, tmp_path, capsys) -> None:
    import sqlite3

    out = tmp_path / "out"
    out.mkdir()
    db = out / "study.db"
    if kind == "another database":
        with sqlite3.connect(db) as connection:
            connection.execute("CREATE TABLE contacts (name TEXT)")
    else:
        db.write_text("my notes")
    before = db.read_bytes()
    assert cli.main(["search", "--shape", "Angle", "--trials", "1", "--epochs", "1", "--n-points", "20",
                     "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "study.db" in err[0]
    assert db.read_bytes() == before and sorted(p.name for p in out.iterdir()) == ["study.db"]
