"""`pih lasa`: the Riemannian LASA benchmark (SPD matrices and unit quaternions), RiemannianFlow vs naive.

    pih lasa --shape NShape --manifold spd [--method rflow|naive] [--json r.json] [--save-trajectories t.npz]
    pih lasa --all --workers 2 --out runs/lasa          # 30 shapes x {spd, uq} x {rflow, naive}

One model per shape, manifold and method; each demo is reproduced from its first point and compared with
DTW in the z-scored tangent space at the goal (averaged over the 4 demos) and the manifold distance.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import json
import math
import multiprocessing
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

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
from rflow.train import TrainConfig

MANIFOLD_LABELS = {"spd": "SPD", "uq": "UQ"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih lasa`."""
    parser.add_argument("--shape", help=f"LASA shape, one of: {', '.join(LASA_SHAPES)}")
    parser.add_argument("--manifold", default="spd", help="spd (2x2 SPD matrices) or uq (unit quaternions); default spd")
    parser.add_argument("--method", default="rflow", help="rflow (tangent space at the goal) or naive; default rflow")
    parser.add_argument("--json", type=Path, help="write the result of --shape as JSON")
    parser.add_argument("--save-trajectories", type=Path, metavar="FILE.npz",
                        help="write demos and generated trajectories of --shape (manifold and z-scored tangent)")
    parser.add_argument("--figure", type=Path, metavar="FILE.png", help="plot demos vs generated of --shape")
    parser.add_argument("--all", action="store_true", help="run all 30 shapes x spd, uq x rflow, naive")
    parser.add_argument("--workers", type=int, default=1, help="parallel worker processes for --all (default 1)")
    parser.add_argument("--out", type=Path, help="output folder of --all: results.json, results.md, figures/")
    parser.add_argument("--shapes", help="comma-separated subset of shapes for --all (default all 30)")
    parser.add_argument("--manifolds", default="spd,uq", help="comma-separated manifolds for --all (default spd,uq)")
    parser.add_argument("--methods", default="rflow,naive", help="comma-separated methods for --all (default rflow,naive)")
    parser.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    parser.add_argument("--n-points", type=int, default=LASA_POINTS,
                        help=f"points per demo, evenly subsampled (default {LASA_POINTS}: the benchmark)")
    defaults = TrainConfig()
    parser.add_argument("--epochs", type=int, default=defaults.epochs, help=f"training epochs (default {defaults.epochs})")
    parser.add_argument("--layers", type=int, default=defaults.model.layers,
                        help=f"coupling layers (default {defaults.model.layers})")
    parser.add_argument("--lr", type=float, default=defaults.lr, help=f"learning rate (default {defaults.lr:g})")
    parser.add_argument("--batch-size", type=int, default=defaults.batch_size,
                        help=f"transitions per step (default {defaults.batch_size})")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch threads of a single-shape run (default 1: the networks are too small to gain; "
                             "--all always uses 1 per worker)")
    parser.add_argument("--progress", action="store_true", help="show the training progress bar (single shape)")


def _config(args: argparse.Namespace, threads: int | None = None) -> TrainConfig:
    return TrainConfig(model=ModelConfig(layers=args.layers), epochs=args.epochs, lr=args.lr,
                       batch_size=args.batch_size, seed=args.seed, threads=threads)


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


# ---- atomic output -------------------------------------------------------------------------------------
def _atomic_write(path: Path, write: Callable[[Any], None], mode: str = "w") -> Path:
    """Write through `write(file)` into a temporary file beside `path`, then rename it over `path`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode) as handle:
            write(handle)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_json(path: Path, record: Any) -> Path:
    """Atomically write `record` as indented JSON."""
    return _atomic_write(path, lambda f: json.dump(record, f, indent=2, allow_nan=False))


def save_trajectories(path: Path, result: ShapeResult) -> Path:
    """Atomically write the demos and generated trajectories of one result to an .npz file."""
    data = riemannian_lasa(result.shape, result.manifold, result.n_points)
    arrays = {
        "demos": data.demos, "generated": result.generated, "demos_z": result.demos_z,
        "generated_z": result.generated_z, "goal": data.goal, "dt": np.float64(data.dt),
    }
    return _atomic_write(path, lambda f: np.savez(f, **arrays), mode="wb")


# ---- figures -------------------------------------------------------------------------------------------
def plot_results(path: Path, shape: str, results: Iterable[ShapeResult]) -> Path | None:
    """Grid of 3-D plots (manifold x method) of z-scored tangent demos (grey) vs generated (colour), goal (star).

    Returns:
        The PNG path, or None when no result of the shape has trajectories.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [r for r in results if r.error is None and r.generated_z is not None]
    if not panels:
        return None
    panels.sort(key=lambda r: (r.manifold, METHODS.index(r.method)))
    manifolds = sorted({r.manifold for r in panels})
    methods = [m for m in METHODS if any(r.method == m for r in panels)]
    fig = plt.figure(figsize=(4.2 * len(methods), 3.8 * len(manifolds)))
    for r in panels:
        index = manifolds.index(r.manifold) * len(methods) + methods.index(r.method) + 1
        ax = fig.add_subplot(len(manifolds), len(methods), index, projection="3d")
        for k, (demo, gen) in enumerate(zip(r.demos_z, r.generated_z)):
            ax.plot(*demo.T, color="0.6", lw=1.0, label="demos" if k == 0 else None)
            ax.plot(*gen.T, color=f"C{k}", lw=1.2, label="generated" if k == 0 else None)
            ax.scatter(*demo[0], color="k", s=8)
        ax.scatter(*r.demos_z[0, -1], color="k", marker="*", s=60, label="goal")
        ax.set_title(f"{MANIFOLD_LABELS[r.manifold]} {r.method}: DTW {r.dtw:.1f}", fontsize=9)
        ax.tick_params(labelsize=6)
        if index == 1:
            ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"{shape}: z-scored tangent space at the goal", fontsize=10)
    fig.tight_layout()
    try:
        return _atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=90), mode="wb")
    finally:
        plt.close(fig)


# ---- report --------------------------------------------------------------------------------------------
def _get(results: dict[tuple[str, str, str], ShapeResult], key: tuple[str, str, str], attr: str) -> float:
    r = results.get(key)
    return math.nan if r is None or r.error is not None else float(getattr(r, attr))


def _fmt(value: float, digits: int) -> str:
    return "—" if not math.isfinite(value) else f"{value:.{digits}f}"


def gains(results: Iterable[ShapeResult]) -> dict[str, dict[str, float]]:
    """Mean DTW per manifold and method over the shapes where both methods succeeded, and the gain
    100 (naive - rflow) / naive in % (the paper: 8.2 % SPD, 17.7 % UQ)."""
    table = {(r.shape, r.manifold, r.method): r for r in results}
    out: dict[str, dict[str, float]] = {}
    for manifold in BENCHMARK_MANIFOLDS:
        shapes = [s for s in LASA_SHAPES
                  if all(math.isfinite(_get(table, (s, manifold, m), "dtw")) for m in METHODS)]
        if not shapes:
            continue
        mean = {m: float(np.mean([_get(table, (s, manifold, m), "dtw") for s in shapes])) for m in METHODS}
        out[manifold] = {"shapes": float(len(shapes)), "rflow": mean["rflow"], "naive": mean["naive"],
                         "gain_percent": 100.0 * (mean["naive"] - mean["rflow"]) / mean["naive"]}
    return out


def _row(name: str, results: list[ShapeResult]) -> str:
    """One table row: mean DTW and manifold distance per (manifold, method), mean times, over `results`."""
    def mean(attr: str, manifold: str | None = None, method: str | None = None) -> float:
        values = [getattr(r, attr) for r in results if r.error is None
                  and manifold in (None, r.manifold) and method in (None, r.method)]
        return float(np.mean(values)) if values else math.nan

    combos = [(a, m) for a in BENCHMARK_MANIFOLDS for m in METHODS]
    cells = [name] + [_fmt(mean("dtw", a, m), 1) for a, m in combos]
    cells += [_fmt(mean("manifold_distance", a, m), 4) for a, m in combos]
    cells += [_fmt(mean("train_time_s"), 1), _fmt(mean("generate_time_s"), 2)]
    return "| " + " | ".join(cells) + " |"


def markdown_table(results: list[ShapeResult], config: TrainConfig) -> str:
    """The Markdown report: per-shape DTW and manifold distances of rflow/naive on SPD and UQ, times, means,
    the gain of rflow over naive per manifold, and the failures."""
    combos = [(a, m) for a in BENCHMARK_MANIFOLDS for m in METHODS]
    head = (["Shape"] + [f"DTW {MANIFOLD_LABELS[a]} {m}" for a, m in combos]
            + [f"dist {MANIFOLD_LABELS[a]} {m}" for a, m in combos] + ["train s", "generate s"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for shape in LASA_SHAPES:
        subset = [r for r in results if r.shape == shape]
        if subset:
            lines.append(_row(shape, subset))
    lines.append(_row("**mean**", results))
    text = [
        "# Riemannian LASA benchmark",
        "",
        "DTW: sum of Euclidean distances along the optimal warping path between each demo and the trajectory "
        "generated from its first point, in the z-scored tangent space at the goal, mean of 4 demos. "
        "dist: mean manifold distance along the sequence (Log-Euclidean for SPD, ||2 Log(q conj(q_hat))|| "
        "in rad for UQ). train s / generate s: mean wall time per run of the shape. "
        f"Training: {config.epochs} epochs, {config.model.layers} layers, lr {config.lr:g}, batch {config.batch_size}, "
        f"seed {config.seed}.",
        "",
        *lines,
        "",
        "## Gain of RiemannianFlow over naive (mean DTW over the shapes where both succeeded)",
        "",
        "| manifold | shapes | rflow | naive | gain % | paper gain % |",
        "|---|---|---|---|---|---|",
    ]
    paper = {"spd": 8.2, "uq": 17.7}
    for manifold, g in gains(results).items():
        text.append(f"| {MANIFOLD_LABELS[manifold]} | {int(g['shapes'])} | {g['rflow']:.1f} | {g['naive']:.1f} | "
                    f"{g['gain_percent']:.1f} | {paper[manifold]} |")
    failures = [r for r in results if r.error is not None]
    if failures:
        text += ["", "## Failures", ""] + [f"- {r.shape} {r.manifold} {r.method}: {r.error}" for r in failures]
    return "\n".join(text) + "\n"


# ---- batch ---------------------------------------------------------------------------------------------
def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)


def run_job(shape: str, manifold: str, method: str, config: TrainConfig, n_points: int) -> ShapeResult:
    """One benchmark run; any exception becomes a failed `ShapeResult` carrying the one-line error."""
    try:
        return evaluate_shape(shape, manifold, config, config.seed, method, n_points)
    except Exception as err:  # noqa: BLE001 - a failing shape is recorded, never aborts the batch
        return failed_result(shape, manifold, method, config, n_points, err)


def failed_result(shape: str, manifold: str, method: str, config: TrainConfig, n_points: int,
                  err: BaseException) -> ShapeResult:
    """A `ShapeResult` with NaN metrics and the error as one line."""
    message = " ".join(str(err).split()) or type(err).__name__
    return ShapeResult(shape=shape, manifold=manifold, method=method, seed=config.seed, n_points=n_points,
                       epochs=config.epochs, error=f"{type(err).__name__}: {message}")


def _collect(futures: dict, results: list[ShapeResult], record: Callable[[], None], start: float, total: int,
             out: Path, manifolds: list[str], methods: list[str]) -> None:
    """Gather finished runs: append, rewrite results.json, print a line, plot a shape once all its runs are in."""
    for future in concurrent.futures.as_completed(futures):
        shape, manifold, method, config, n_points = futures[future]
        try:
            result = future.result()
        except Exception as err:  # noqa: BLE001 - e.g. a worker killed by the OS
            result = failed_result(shape, manifold, method, config, n_points, err)
        results.append(result)
        record()
        print(f"[{len(results)}/{total} {time.perf_counter() - start:.0f} s] {summary_line(result)}", flush=True)
        done = {(r.manifold, r.method) for r in results if r.shape == shape}
        if all((a, m) in done for a in manifolds for m in methods):
            try:
                plot_results(out / "figures" / f"{shape}.png", shape, [r for r in results if r.shape == shape])
            except Exception as err:  # noqa: BLE001 - a figure never aborts the batch
                print(f"figure of {shape} failed: {type(err).__name__}: {err}", file=sys.stderr)


def run_all(args: argparse.Namespace) -> int:
    """Run the benchmark grid in parallel processes; write results.json, results.md and figures."""
    if args.out is None:
        raise RFlowError("--all needs --out DIR")
    if args.workers < 1:
        raise RFlowError(f"--workers {args.workers}: need at least 1")
    shapes = _split(args.shapes, check_shape, "shapes") if args.shapes else list(LASA_SHAPES)
    manifolds = [_manifold_name(m) for m in _split(args.manifolds, check_manifold, "manifolds")]
    methods = _split(args.methods, _check_method, "methods")
    config = _config(args)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(s, man, m) for s in shapes for man in manifolds for m in methods]
    results: list[ShapeResult] = []
    start = time.perf_counter()

    def record() -> None:
        write_json(out / "results.json", {
            "config": dataclasses.asdict(config), "n_points": args.n_points, "complete": len(results) == len(jobs),
            "gains": gains(results), "results": [r.to_dict() for r in results],
        })

    context = multiprocessing.get_context("spawn")  # no forked torch thread pools
    with concurrent.futures.ProcessPoolExecutor(args.workers, mp_context=context, initializer=_init_worker) as pool:
        futures = {pool.submit(run_job, s, man, m, config, args.n_points): (s, man, m, config, args.n_points)
                   for s, man, m in jobs}
        try:
            _collect(futures, results, record, start, len(jobs), out, manifolds, methods)
        except BaseException:  # e.g. Ctrl-C: drop the queued runs; results.json keeps the finished ones
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    order = {key: i for i, key in enumerate(jobs)}
    results.sort(key=lambda r: order[(r.shape, r.manifold, r.method)])
    record()
    _atomic_write(out / "results.md", lambda f: f.write(markdown_table(results, config)))
    failed = sum(r.error is not None for r in results)
    summary = "; ".join(f"{MANIFOLD_LABELS[a]} rflow {g['rflow']:.1f} vs naive {g['naive']:.1f} "
                        f"({g['gain_percent']:+.1f} %)" for a, g in gains(results).items())
    print(f"wrote {out / 'results.json'}, {out / 'results.md'}, {out / 'figures'}: {len(results)} runs, "
          f"{failed} failed, {time.perf_counter() - start:.0f} s. Mean DTW: {summary or 'n/a'}")
    return 0


def run_one(args: argparse.Namespace) -> int:
    """Train and evaluate one shape, manifold and method; print one summary line."""
    if args.shape is None:
        raise RFlowError("give --shape NAME (or --all)")
    shape = check_shape(args.shape)
    manifold = _manifold_name(args.manifold)
    method = _check_method(args.method)
    for option in ("json", "save_trajectories", "figure"):
        path = getattr(args, option)
        if path is not None and path.parent != Path("") and not path.parent.is_dir():
            raise RFlowError(f"--{option.replace('_', '-')} {path}: folder {path.parent} does not exist")
    result = evaluate_shape(shape, manifold, _config(args, args.threads), args.seed, method, args.n_points,
                            progress=args.progress)
    if args.json is not None:
        write_json(args.json, result.to_dict())
    if args.save_trajectories is not None:
        save_trajectories(args.save_trajectories, result)
    if args.figure is not None:
        plot_results(args.figure, shape, [result])
    print(summary_line(result))
    return 0


def main(args: argparse.Namespace) -> int:
    """`pih lasa`; returns the exit status."""
    return run_all(args) if args.all else run_one(args)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="lasa")
    add_arguments(parser)
    sys.exit(main(parser.parse_args()))
