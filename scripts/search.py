"""`pih search`: Optuna hyperparameter search of RiemannianFlow on one Riemannian LASA shape (rflow.search).

    pih search --shape NShape --manifold spd --trials 40 --out runs/search
    pih search ... --storage postgresql+psycopg://user@host/db --study nshape   # many processes or machines

Writes OUT/study.db (the SQLite storage, unless --storage names another), OUT/search.json (every trial of
the study: number, state, validation DTW, parameters, epoch of pruning) and OUT/best.json, the best trial's
training config, which `pih lasa --config` and `pih train --config` read. The objective is a validation
DTW from held-out starts, never the benchmark's own numbers: run `pih lasa --config OUT/best.json` for those.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

from rflow.errors import RFlowError
from rflow.lasa import LASA_POINTS, LASA_SHAPES
from rflow.train import TrainConfig
from scripts.options import MAX_EPOCHS, MAX_TRIALS, count, seed, work_begins

OUTPUT_BYTES_PER_TRIAL = 64 * 1024
"""Generous size of one trial in search.json and the SQLite study."""


EXAMPLES: tuple[str, ...] = ('pih search --shape NShape --manifold spd --trials 40 --out search/',)
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih search`."""
    d = TrainConfig()
    parser.add_argument("--shape", default="NShape", help=f"LASA shape, one of: {', '.join(LASA_SHAPES)}")
    parser.add_argument("--manifold", default="spd", help="spd or uq")
    parser.add_argument("--trials", type=count(MAX_TRIALS), default=40, help="trials this process runs")
    parser.add_argument("--out", type=Path, required=True, help="output folder: study.db, search.json, best.json")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace search.json and best.json of an earlier pih search in --out (the study "
                             "itself is continued, never replaced)")
    parser.add_argument("--storage", help="SQLAlchemy URL of the Optuna storage shared by all processes "
                                          "(default sqlite:///OUT/study.db)")
    parser.add_argument("--study", help="study name (default SHAPE-MANIFOLD-seedSEED); processes with the same "
                                        "name and storage share one study")
    parser.add_argument("--epochs", type=count(MAX_EPOCHS), default=d.epochs, help="training epochs per trial")
    parser.add_argument("--report-every", type=count(MAX_EPOCHS), default=10,
                        help="epochs between validation DTW reports to the median pruner")
    parser.add_argument("--seed", type=seed, default=0, help="training seed of every trial, 0..2**32-1")
    parser.add_argument("--sampler-seed", type=seed, default=0,
                        help="TPE sampler seed; give each process sharing a study its own")
    parser.add_argument("--n-points", type=count(LASA_POINTS, minimum=2), default=LASA_POINTS,
                        help=f"points per demo, 2..{LASA_POINTS} (default {LASA_POINTS}: the benchmark's)")


OPTUNA_TABLES = frozenset({"alembic_version", "studies", "study_directions", "study_system_attributes",
                           "study_user_attributes", "trial_heartbeats", "trial_intermediate_values", "trial_params",
                           "trial_system_attributes", "trial_user_attributes", "trial_values", "trials",
                           "version_info"})
"""The tables of an Optuna RDB storage (Optuna 4): an existing OUT/study.db with any other table is not a study."""


def check_study_file(path: Path) -> None:
    """An existing default storage ``path`` is written into (its study resumed) only when it is an SQLite file
    holding Optuna's tables and nothing else; somebody's other database is refused before any work.

    Raises:
        RFlowError: naming the file and what it holds.
    """
    import sqlite3

    if not path.exists() and not path.is_symlink():
        return
    if path.is_symlink() or not path.is_file():
        raise RFlowError(f"--out {path} is not a file: not writing a study into it; choose another --out")
    try:
        with sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True) as connection:
            tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.Error as err:
        raise RFlowError(f"--out {path} is not an SQLite database ({err}): not writing a study into it; choose "
                         "another --out") from None
    others = sorted(tables - OPTUNA_TABLES)
    if others:
        raise RFlowError(f"--out {path} is a database with tables that are not Optuna's ({', '.join(others[:3])}): "
                         "not writing a study into it; choose another --out")


def _storage_url(args: argparse.Namespace, out: Path) -> str:
    """The storage URL, validated by SQLAlchemy's parser (no connection yet)."""
    if args.storage is None:
        check_study_file(out / "study.db")
        return f"sqlite:///{(out / 'study.db').resolve()}"
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        make_url(args.storage)
    except ArgumentError as err:
        raise RFlowError(f"--storage {args.storage!r} is not an SQLAlchemy URL ({err})") from None
    return args.storage


def _trial_record(trial: Any) -> dict[str, Any]:
    steps = sorted(trial.intermediate_values)
    return {"number": trial.number, "state": trial.state.name, "value": trial.value, "params": trial.params,
            "last_epoch": steps[-1] if steps else None,
            "train_seconds": trial.user_attrs.get("train_seconds")}


def main(args: argparse.Namespace) -> int:
    """Run `pih search`; returns the exit status."""
    from envs.io.owned_output import check_output, check_output_folder, write_json
    from rflow.config_file import train_config_record
    from rflow.search import SearchConfig, best_config, run_search

    manifold = {"spd": "spd", "uq": "uq", "sphere": "uq"}.get(args.manifold)
    if manifold is None:
        raise RFlowError(f"unknown benchmark manifold {args.manifold!r}; expected 'spd' or 'uq'")
    base = TrainConfig(epochs=args.epochs, seed=args.seed, threads=1)
    config = SearchConfig(shape=args.shape, manifold=manifold, trials=args.trials, base=base,
                          report_every=args.report_every, n_points=args.n_points, sampler_seed=args.sampler_seed)
    out: Path = args.out
    if not check_output_folder("--out", out, estimate_bytes=OUTPUT_BYTES_PER_TRIAL * args.trials):
        for name in ("search.json", "best.json"):
            check_output("--out", out / name, args.overwrite)
    storage = _storage_url(args, out)
    study_name = args.study or f"{config.shape}-{manifold}-seed{args.seed}"
    if not study_name.strip():
        raise RFlowError("--study must not be empty")
    work_begins()
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    study = run_search(config, storage, study_name, on_trial=lambda line: print(line, flush=True))
    trials = [_trial_record(t) for t in study.trials]
    counts = {state: sum(t["state"] == state for t in trials) for state in ("COMPLETE", "PRUNED", "FAIL")}
    best, value, number = best_config(study, base)
    source = {"study": study_name, "storage": storage if args.storage is None else "(--storage)",
              "trial": number, "validation_dtw": value, "shape": config.shape, "manifold": manifold,
              "validation": "DTW from held-out starts (rflow.search.VALIDATION_START_FRACTIONS)"}
    write_json(out / "search.json", {"study": study_name, "shape": config.shape, "manifold": manifold,
                                     "counts": counts, "best": {"trial": number, "validation_dtw": value,
                                                                "config": dataclasses.asdict(best)},
                                     "trials": trials})
    write_json(out / "best.json", train_config_record(best, source))
    print(f"wrote {out / 'best.json'}, {out / 'search.json'}: study {study_name!r} has {len(trials)} trials "
          f"({counts['COMPLETE']} complete, {counts['PRUNED']} pruned, {counts['FAIL']} failed); best trial {number}: "
          f"validation DTW {value:.1f}, {best.model.layers} layers, {best.model.activation}, {best.optimizer}, "
          f"lr {best.lr:.3g} ({time.perf_counter() - start:.0f} s)")
    return 0
