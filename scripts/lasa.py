"""`pih lasa`: the Riemannian LASA benchmark (SPD matrices and unit quaternions), the paper's four methods.

    pih lasa --shape NShape --manifold spd [--method rflow|naive|rgmm|fdm] [--json r.json] [--config best.json]
    pih lasa --all --workers 2 --out runs/lasa          # 30 shapes x {spd, uq} x {rflow, naive, rgmm, fdm}
    pih lasa --all --workers 2 --out runs/lasa --resume # continue an interrupted run

One model per shape, manifold and method; each demo is reproduced from its first point and compared with
DTW in the z-scored tangent space at the goal (averaged over the 4 demos) and the manifold distance.

`--all` runs every (shape, manifold, method) as one unit of `batch.run_batch`: each finished unit is appended
to OUT/journal.jsonl at once, so `--resume` skips them after a crash or Ctrl-C; a unit that overruns
`--unit-timeout-s` is recorded as a failed unit with its reason and the batch goes on; a unit whose worker dies
runs again, and one lost on every try is an infrastructure error (listed in results.json, not journalled).
results.json says "complete": true only when every unit has a record; the exit status is 0 when every unit
succeeded, 1 when some failed (their cells read "—" with the reason listed) or a fault stopped the batch (the
Ray head lost), 3 when units were lost to infrastructure (`--resume` runs them) and 130 when interrupted.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from envs.io.npz import open_npz
from envs.io.owned_output import (MiB, check_distinct, check_output, check_output_folder, save_npz, write_json,
                                  write_text)
from numerics.cpu_dispatch import DISPATCH_VARIABLES
from pihutil.bounds import LEARNING_RATE, TIMEOUT_S
from rflow.errors import RFlowError
from rflow.lasa import (
    BENCHMARK_MANIFOLDS,
    LASA_POINTS,
    LASA_SHAPES,
    METHODS,
    ShapeResult,
    check_manifold,
    check_shape,
    evaluate_shape,
    riemannian_lasa,
)
from rflow.model import ModelConfig
from rflow.train import TrainConfig, check_training_memory
from scripts.lasa_report import MANIFOLD_LABELS, METHOD_LABELS, gains, markdown_table, plot_comparison, plot_results
from scripts.options import DEFAULT_WORKERS, MAX_EPOCHS, MAX_WORKERS, count, number, refuse_unused, seed, work_begins

JOURNAL = "journal.jsonl"
EXIT_FAILED_UNITS = 1
EXIT_INCOMPLETE = 3
EXIT_INTERRUPTED = 130
_HYPERPARAMETERS = ("epochs", "layers", "lr", "batch_size")  # the options --config replaces
UNIT_BYTES = 256 * 1024
"""Generous size of one unit of --all on disk (its trajectories, journal line and share of the figures)."""
LASA_TANGENT_DIM = 3
"""The tangent dimension of every LASA model (SPD(2) and unit quaternions: 3), for the memory check."""


EXAMPLES: tuple[str, ...] = ('pih lasa --shape NShape --manifold spd --json nshape.json',
                             'pih lasa --all --out lasa/')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih lasa`."""
    parser.add_argument("--shape", help=f"LASA shape, one of: {', '.join(LASA_SHAPES)}")
    parser.add_argument("--manifold", default="spd", help="spd (2x2 SPD matrices) or uq (unit quaternions)")
    parser.add_argument("--method", default="rflow", help=f"one of {', '.join(METHODS)}")
    parser.add_argument("--json", type=Path, help="write the result of --shape as JSON")
    parser.add_argument("--save-trajectories", type=Path, metavar="FILE.npz",
                        help="write demos and generated trajectories of --shape (manifold and z-scored tangent)")
    parser.add_argument("--figure", type=Path, metavar="FILE.png", help="plot demos vs generated of --shape")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace outputs an earlier pih lasa wrote (--all: start its run again); never a file "
                             "pih did not write")
    parser.add_argument("--all", action="store_true", help="run all 30 shapes x spd, uq x the four methods")
    parser.add_argument("--workers", type=count(MAX_WORKERS), default=DEFAULT_WORKERS,
                        help="parallel worker processes for --all")
    parser.add_argument("--out", type=Path, help="output folder of --all: results.json, results.md, comparison.png, "
                                                 "figures/, trajectories/, journal.jsonl")
    parser.add_argument("--resume", action="store_true",
                        help="--all: continue the run journalled in OUT (same options), skipping finished units")
    parser.add_argument("--backend", default="process", help="--all: process (spawned workers) or ray")
    parser.add_argument("--ray-address", metavar="HOST:PORT",
                        help="--all --backend ray: join this Ray cluster (default: a local Ray instance)")
    parser.add_argument("--unit-timeout-s", type=number(bound=TIMEOUT_S), metavar="S",
                        help="--all: record a run taking longer than S seconds as failed (default: no limit)")
    parser.add_argument("--shapes", help="comma-separated subset of shapes for --all (default all 30)")
    parser.add_argument("--manifolds", default="spd,uq", help="comma-separated manifolds for --all")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods for --all")
    parser.add_argument("--seed", type=seed, default=0, help="training seed of rflow and naive, 0..2**32-1")
    parser.add_argument("--n-points", type=count(LASA_POINTS, minimum=2), default=LASA_POINTS,
                        help=f"points per demo, evenly subsampled, 2..{LASA_POINTS} (default {LASA_POINTS}: the benchmark)")
    parser.add_argument("--config", type=Path, metavar="FILE.json",
                        help="training hyperparameters of rflow and naive from a config file (e.g. `pih search`'s "
                             "best.json) instead of --epochs, --layers, --lr, --batch-size")
    defaults = TrainConfig()
    parser.add_argument("--epochs", type=count(MAX_EPOCHS), help=f"training epochs (default {defaults.epochs})")
    parser.add_argument("--layers", type=count(64), help=f"coupling layers, 1..64 (default {defaults.model.layers})")
    parser.add_argument("--lr", type=number(bound=LEARNING_RATE), help=f"learning rate (default {defaults.lr:g})")
    parser.add_argument("--batch-size", type=count(1_000_000),
                        help=f"transitions per step (default {defaults.batch_size})")
    parser.add_argument("--threads", type=count(256), default=1,
                        help="torch threads of a single-shape run (default 1: the networks are too small to gain; "
                             "--all always uses 1 per worker)")
    parser.add_argument("--progress", action="store_true", help="show the training progress bar (single shape)")


def train_config(args: argparse.Namespace, threads: int | None = None) -> TrainConfig:
    """The TrainConfig of the options: --config FILE, or the hyperparameter options over rflow's defaults.

    Raises:
        RFlowError: --config together with a hyperparameter option, or an invalid file or value.
    """
    given = [name for name in _HYPERPARAMETERS if getattr(args, name) is not None]
    if args.config is not None:
        if given:
            raise RFlowError(f"--config {args.config} replaces --{given[0].replace('_', '-')}: give one or the other")
        from rflow.config_file import load_train_config

        return dataclasses.replace(load_train_config(args.config), seed=args.seed, threads=threads)
    d = TrainConfig()
    return TrainConfig(model=ModelConfig(layers=d.model.layers if args.layers is None else args.layers),
                       epochs=d.epochs if args.epochs is None else args.epochs, lr=d.lr if args.lr is None else args.lr,
                       batch_size=d.batch_size if args.batch_size is None else args.batch_size, seed=args.seed,
                       threads=threads)


def _check_method(method: str) -> str:
    if method not in METHODS:
        raise RFlowError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    return method


def _split(text: str, check: Callable[[str], str], what: str) -> list[str]:
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise RFlowError(f"--{what} is empty")
    for item in items:
        check(item)
    if len(set(items)) != len(items):
        raise RFlowError(f"--{what} {text}: an item is repeated")
    return items


def _manifold_name(manifold: str) -> str:
    """The benchmark name "spd" or "uq" (accepts "sphere" too)."""
    name = check_manifold(manifold)
    return next(key for key, value in BENCHMARK_MANIFOLDS.items() if value == name)


def summary_line(result: ShapeResult) -> str:
    """One line: shape, manifold, method, DTW (per demo), manifold distance, times, or the error."""
    head = f"{result.shape} {result.manifold} {result.method}"
    if result.error is not None:
        return f"{head}: FAILED: {result.error}"
    per_demo = " ".join(f"{x:.1f}" for x in result.dtw_per_demo)
    unit = "" if result.manifold == "spd" else " rad"
    return (f"{head}: DTW {result.dtw:.1f} ({per_demo}), manifold distance {result.manifold_distance:.4f}{unit}, "
            f"final error {result.final_error:.2f} (z), train {result.train_time_s:.1f} s, "
            f"generate {result.generate_time_s:.2f} s")


# ---- output (envs.io.owned_output: atomic, marked) ---------------------------------------------------------------
FIGURE_DPI = 90


def save_figure(path: Path, figure: Any) -> Path:
    """Write a matplotlib figure as PNG (envs.io.owned_output.save_figure; the argument order of lasa_report's
    ``save``)."""
    from envs.io.owned_output import save_figure as save_png

    return save_png(figure, path, dpi=FIGURE_DPI)


def save_trajectories(path: Path, result: ShapeResult) -> Path:
    """Write the demos and generated trajectories of one result to an .npz file."""
    data = riemannian_lasa(result.shape, result.manifold, result.n_points)
    return save_npz(path, {"demos": data.demos, "generated": result.generated, "demos_z": result.demos_z,
                           "generated_z": result.generated_z, "goal": data.goal, "dt": np.float64(data.dt)})


# ---- batch units ---------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class BatchSetup:
    """What every worker of `--all` needs: the training config, points per demo, and the output folder."""

    config: TrainConfig
    n_points: int
    out: Path


def unit_key(shape: str, manifold: str, method: str) -> str:
    """Journal key of one benchmark run."""
    return f"{shape}/{manifold}/{method}"


def trajectory_path(out: Path, shape: str, manifold: str, method: str) -> Path:
    """Where `--all` keeps the trajectories of one run (for the figures, also after --resume)."""
    return out / "trajectories" / f"{shape}_{manifold}_{method}.npz"


def init_worker(setup: BatchSetup) -> BatchSetup:
    """Per worker: one torch thread (the networks are small; the workers share the cores); its outputs are
    marked as `pih lasa`'s."""
    import torch

    from envs.io.owned_output import set_command

    set_command("lasa")
    torch.set_num_threads(1)
    return setup


def run_job(shape: str, manifold: str, method: str, config: TrainConfig, n_points: int) -> ShapeResult:
    """One benchmark run; any exception becomes a failed `ShapeResult` carrying the one-line error."""
    try:
        return evaluate_shape(shape, manifold, config, config.seed, method, n_points)
    except Exception as err:  # noqa: BLE001 - a failing shape is recorded, never aborts the batch
        return failed_result(shape, manifold, method, config, n_points, f"{type(err).__name__}: "
                             + (" ".join(str(err).split()) or type(err).__name__))


def work_unit(setup: BatchSetup, unit: tuple[str, str, str]) -> dict[str, Any]:
    """One unit of `--all`: run, save the trajectories of a successful run, return the JSON record."""
    shape, manifold, method = unit
    result = run_job(shape, manifold, method, setup.config, setup.n_points)
    if result.error is None:
        save_npz(trajectory_path(setup.out, shape, manifold, method),
                 {"demos_z": result.demos_z, "generated_z": result.generated_z})
    return result.to_dict()


def failed_result(shape: str, manifold: str, method: str, config: TrainConfig, n_points: int,
                  reason: str) -> ShapeResult:
    """A `ShapeResult` with NaN metrics and the reason of the failure."""
    return ShapeResult(shape=shape, manifold=manifold, method=method, seed=config.seed, n_points=n_points,
                       epochs=config.epochs, error=reason)


def _failure_record(setup: BatchSetup) -> Callable[[str, Any, str], dict]:
    def failure(key: str, unit: tuple[str, str, str], reason: str) -> dict:
        return failed_result(*unit, setup.config, setup.n_points, reason).to_dict()

    return failure


def _figure(out: Path, shape: str, results: list[ShapeResult]) -> bool:
    """The per-shape figure from the saved trajectories of its successful runs; False (and a line on stderr)
    when it failed: the batch goes on, and `run_all` exits 1 at the end."""
    try:
        panels = []
        for r in results:
            path = trajectory_path(out, r.shape, r.manifold, r.method)
            if r.error is None and path.is_file():
                with open_npz(path) as arrays:
                    panels.append((r, arrays["demos_z"], arrays["generated_z"]))
        plot_results(out / "figures" / f"{shape}.png", shape, panels, save_figure)
    except Exception as err:  # noqa: BLE001 - a figure never aborts the batch
        print(f"figure of {shape} failed: {type(err).__name__}: {err}", file=sys.stderr)
        return False
    return True


def run_all(args: argparse.Namespace) -> int:
    """Run the benchmark grid as journalled batch units; write results.json, results.md and the figures."""
    from batch import BatchConfig, BatchError, Journal, describe_event, run_batch

    if args.out is None:
        raise RFlowError("--all needs --out DIR")
    shapes = _split(args.shapes, check_shape, "shapes") if args.shapes else list(LASA_SHAPES)
    manifolds = [_manifold_name(m) for m in _split(args.manifolds, check_manifold, "manifolds")]
    methods = _split(args.methods, _check_method, "methods")
    config = train_config(args)
    check_training_memory(config, [LASA_TANGENT_DIM] * min(args.workers, os.cpu_count() or 1))  # workers at once
    try:
        batch_config = BatchConfig(workers=args.workers, unit_timeout_s=args.unit_timeout_s, backend=args.backend,
                                   ray_address=args.ray_address, worker_environment=DISPATCH_VARIABLES)
    except BatchError as err:
        raise RFlowError(str(err).replace("workers=", "--workers ").replace("unit_timeout_s=", "--unit-timeout-s ")
                         .replace("backend=", "--backend ").replace("ray_address=", "--ray-address ")) from None
    if args.resume and args.overwrite:
        raise RFlowError("--resume continues an earlier run and --overwrite replaces it: choose one")
    out: Path = args.out
    units = [(unit_key(s, a, m), (s, a, m)) for s in shapes for a in manifolds for m in methods]
    if not check_output_folder("--out", out, inputs=[args.config], estimate_bytes=UNIT_BYTES * len(units)):
        if (out / JOURNAL).exists() and not (args.resume or args.overwrite):
            raise RFlowError(f"--out {out} holds a run already ({JOURNAL}): add --resume (or --overwrite), or "
                             "choose another folder")
        planned = [out / name for name in (JOURNAL, "results.json", "results.md", "comparison.png")]
        planned += [out / "figures" / f"{shape}.png" for shape in shapes]
        planned += [trajectory_path(out, *unit) for _, unit in units]
        for path in planned:
            if path.exists() or path.is_symlink():
                check_output("--out", path, args.overwrite or args.resume)
    if args.resume and not (out / JOURNAL).is_file():
        raise RFlowError(f"--resume: there is no run to continue in {out} (no {JOURNAL})")
    run = {"command": "lasa", "shapes": shapes, "manifolds": manifolds, "methods": methods,
           "n_points": args.n_points, "config": dataclasses.asdict(config)}
    work_begins()
    for folder in (out, out / "figures", out / "trajectories"):
        folder.mkdir(parents=True, exist_ok=True)
    try:
        journal = Journal.open(out / JOURNAL, run, resume=args.resume, overwrite=args.overwrite)
    except BatchError as err:
        raise RFlowError(str(err)) from None
    setup = BatchSetup(config=config, n_points=args.n_points, out=out)
    results: dict[str, ShapeResult] = {k: ShapeResult.from_dict(r) for k, r in journal.done().items()}
    start = time.perf_counter()
    figure_failures: list[str] = []
    if results:
        print(f"resuming: {len(results)} of {len(units)} runs already in {out / JOURNAL}", flush=True)

    def write_results(complete: bool, outcome: Any = None) -> None:
        ordered = [results[k] for k, _ in units if k in results]
        write_json(out / "results.json", {
            "config": dataclasses.asdict(config), "n_points": args.n_points, "complete": complete,
            "runs": len(units), "finished": len(ordered), "failed": sum(r.error is not None for r in ordered),
            "gains": {m: gains(ordered, m) for m in methods if m != "rflow"},
            "results": [r.to_dict() for r in ordered],
            "infrastructure_errors": list(outcome.infrastructure_errors.values()) if outcome else [],
            "infrastructure_events": outcome.events if outcome else [],
        })

    def on_record(key: str, record: dict) -> None:
        result = ShapeResult.from_dict(record)
        results[key] = result
        write_results(complete=False)
        print(f"[{len(results)}/{len(units)} {time.perf_counter() - start:.0f} s] {summary_line(result)}", flush=True)
        shape_keys = [unit_key(result.shape, a, m) for a in manifolds for m in methods]
        if all(k in results for k in shape_keys) and not _figure(out, result.shape, [results[k] for k in shape_keys]):
            figure_failures.append(result.shape)

    with journal:
        try:
            outcome = run_batch(units, setup, init_worker, work_unit, _failure_record(setup), batch_config, journal,
                                on_record)
        except BatchError as err:
            raise RFlowError(str(err)) from None
    results = {k: ShapeResult.from_dict(r) for k, r in outcome.records.items()}
    complete = outcome.complete and not outcome.interrupted
    write_results(complete, outcome)
    ordered = [results[k] for k, _ in units if k in results]
    write_text(out / "results.md", markdown_table(ordered, config))
    plot_comparison(out / "comparison.png", ordered, save_figure)
    failed = sum(r.error is not None for r in ordered)
    means = "; ".join(f"{MANIFOLD_LABELS[a]} {METHOD_LABELS[m]} {g[m]:.1f} vs RiemannianFlow {g['rflow']:.1f}"
                      for m in methods if m != "rflow" for a, g in gains(ordered, m).items())
    print(f"wrote {out / 'results.json'}, {out / 'results.md'}, {out / 'comparison.png'}: {len(ordered)} of "
          f"{len(units)} runs, {failed} failed, {time.perf_counter() - start:.0f} s. Mean DTW: {means or 'n/a'}")
    for event in outcome.events[outcome.events_before:]:  # a resumed run's earlier losses are in the JSON
        print(f"pih lasa: infrastructure: {describe_event(event)}", file=sys.stderr)
    if outcome.fault is not None:
        print(f"pih lasa: error: {outcome.fault}; continue with --resume", file=sys.stderr)
        return EXIT_FAILED_UNITS
    if outcome.interrupted:
        print(f"interrupted: {len(units) - len(ordered)} runs left; continue with --resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    if not outcome.complete:
        print(f"pih lasa: incomplete: {len(outcome.infrastructure_errors)} runs lost to infrastructure; continue "
              "with --resume", file=sys.stderr)
        return EXIT_INCOMPLETE
    if figure_failures:
        print(f"pih lasa: the figures of {', '.join(figure_failures)} could not be written", file=sys.stderr)
    return EXIT_FAILED_UNITS if failed or figure_failures else 0


def run_one(args: argparse.Namespace) -> int:
    """Train and evaluate one shape, manifold and method; print one summary line."""
    if args.shape is None:
        raise RFlowError("give --shape NAME (or --all)")
    shape = check_shape(args.shape)
    manifold = _manifold_name(args.manifold)
    method = _check_method(args.method)
    config = train_config(args, args.threads)
    check_training_memory(config, [LASA_TANGENT_DIM])
    outputs = {"--json": args.json, "--save-trajectories": args.save_trajectories, "--figure": args.figure}
    check_distinct(outputs)
    for (option, path), suffix in zip(outputs.items(), (".json", ".npz", ".png")):
        check_output(option, path, args.overwrite, suffix=suffix, inputs=[args.config], estimate_bytes=4 * MiB)
    work_begins()
    result = evaluate_shape(shape, manifold, config, args.seed, method, args.n_points, progress=args.progress)
    if args.json is not None:
        write_json(args.json, result.to_dict())
    if args.save_trajectories is not None:
        save_trajectories(args.save_trajectories, result)
    if args.figure is not None:
        plot_results(args.figure, shape, [(result, result.demos_z, result.generated_z)], save_figure)
    print(summary_line(result))
    return 0


def main(args: argparse.Namespace) -> int:
    """`pih lasa`; returns the exit status."""
    if args.all:
        refuse_unused(args, add_arguments, ["shape", "manifold", "method", "json", "save_trajectories", "figure",
                                            "progress"],
                      "applies to a single --shape, not to --all (use --shapes, --manifolds, --methods, --out)")
        return run_all(args)
    refuse_unused(args, add_arguments, ["workers", "out", "resume", "backend", "ray_address", "unit_timeout_s",
                                        "shapes", "manifolds", "methods"], "applies to --all only")
    return run_one(args)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="lasa")
    add_arguments(parser)
    sys.exit(main(parser.parse_args()))
