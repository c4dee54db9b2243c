"""`pih sweep`: success maps of a trained skill over a grid of task settings.

    pih sweep --model runs/default/model --clearance-mm 1,0.5,0.2,0.1 --hole-error-mm 0,0.5,1,2 \\
        --episodes 30 --seed 0 --out runs/sweep [--chamfer-mm 0,1] [--hole-error-deg 0,1] [--pos-range-mm 50] \\
        [--stiffness learned,constant:500,constant:1500,constant:4000] \\
        [--workers 2] [--backend ray --ray-address HOST:PORT] [--resume | --overwrite]

Every cell (the product of the axes) runs the same K seeded starts (envs/evaluation/sweep.py). Writes, in --out:
sweep.json (per cell: rate, Wilson interval, median time, peak forces, contact rate; every episode),
sweep.png (heat map: clearance x hole error, or the first two axes) and journal.jsonl (finished episodes,
for --resume). Settings not swept come from --task (a preset or a task file; default the contact preset) and the
task options, and the scene from the demos (but for the task's with --task, and the options given).
Outputs follow envs/io/owned_output.py: an earlier sweep's files are replaced only with --overwrite, others never.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from pathlib import Path

from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.io.owned_output import MiB, check_output, check_output_folder, write_json
from envs.policies.skill_settings import MODES
from pihutil.bounds import TIME_LIMIT_S, TIMEOUT_S
from scripts.options import DEFAULT_WORKERS, MAX_EPISODES, MAX_WORKERS, count, number, seed, work_begins
from scripts.task_options import add_task_file_arguments, check_option_value, scene_from_task, task_from_args

AXIS_OPTIONS: dict[str, tuple[str, float]] = {
    "clearance_m": ("--clearance-mm", 1e-3),
    "hole_error_m": ("--hole-error-mm", 1e-3),
    "chamfer_m": ("--chamfer-mm", 1e-3),
    "hole_error_deg": ("--hole-error-deg", 1.0),
    "pos_range_m": ("--pos-range-mm", 1e-3),
}
OUTPUTS: tuple[str, ...] = ("sweep.json", "sweep.png", "journal.jsonl")
RECORD_BYTES = 8 * 1024
"""Generous size of one episode in sweep.json and in the journal (a record is ~2 KB)."""


EXAMPLES: tuple[str, ...] = (
    "pih sweep --model model/ --clearance-mm 1,0.5,0.2 --hole-error-mm 0,1,2 --episodes 30 --out sweep/",)
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih sweep`, in groups: skill, axes, run, output, task."""
    from batch.config import BACKENDS

    d = EvaluationConfig()
    skill = parser.add_argument_group("skill")
    skill.add_argument("--model", required=True, type=Path, help="checkpoint directory from `pih train`")
    skill.add_argument("--mode", choices=MODES, default=d.mode, help="skill execution")
    axes = parser.add_argument_group("axes (comma-separated values; the map is clearance x hole error)")
    axes.add_argument("--clearance-mm", help="hole clearances, mm, e.g. 1,0.5,0.2,0.1")
    axes.add_argument("--hole-error-mm", help="hole-pose error radii, mm, e.g. 0,0.5,1,2")
    axes.add_argument("--chamfer-mm", help="chamfer widths, mm")
    axes.add_argument("--hole-error-deg", help="hole-pose angle errors, deg")
    axes.add_argument("--pos-range-mm", help="start position ranges, mm (half-width of the box)")
    axes.add_argument("--stiffness", help="commanded translational stiffness per cell: 'learned' (a skill from "
                                          "`pih train --stiffness`), 'constant:K' (K I, K > 0 in N/m) or "
                                          "'schedule[:FREE/LATERAL/AXIAL]', e.g. "
                                          "learned,constant:500,constant:1500,constant:4000")
    run = parser.add_argument_group("run")
    run.add_argument("--episodes", type=count(MAX_EPISODES), default=30, help=f"episodes per cell, 1..{MAX_EPISODES:,}")
    run.add_argument("--seed", type=seed, default=0, help="seed of the starts and perturbations, 0..2**32-1")
    run.add_argument("--time-limit-s", type=number(bound=TIME_LIMIT_S),
                     help=f"simulated seconds per episode (default: the task's, {d.task.time_limit_s:g})")
    run.add_argument("--workers", type=count(MAX_WORKERS), default=DEFAULT_WORKERS, help="parallel workers")
    run.add_argument("--backend", choices=BACKENDS, default=d.backend, help="process or ray")
    run.add_argument("--ray-address", help="HOST:PORT of a Ray cluster's head (default: a local Ray)")
    run.add_argument("--unit-timeout-s", type=number(minimum=0.0, maximum=TIMEOUT_S.high), default=d.unit_timeout_s,
                     help="wall seconds per episode before its worker is killed; 0 = none")
    run.add_argument("--resume", action="store_true", help="continue the sweep recorded in --out/journal.jsonl")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    out = parser.add_argument_group("output")
    out.add_argument("--out", required=True, type=Path,
                     help="output folder (created; sweep.json, sweep.png, journal.jsonl)")
    out.add_argument("--overwrite", action="store_true",
                     help="replace an earlier sweep's outputs in --out (files pih did not write are never replaced)")
    task = parser.add_argument_group("task settings that are not swept (default: the demos' scene and --task)")
    add_task_file_arguments(task)
    task.add_argument("--peg-mount", choices=("grasped", "welded"), help="peg mount (default: the demos')")
    task.add_argument("--grasp-force-n", type=number(above=0.0), help="grasp force per finger, N")
    task.add_argument("--grasp-offset-mm", type=number(minimum=0.0),
                      help="grasp offset range along the peg axis, mm (default: the task's)")
    task.add_argument("--force-limit-n", type=number(above=0.0, infinite=True),
                      help="wrist force limit, N, on the force held for 5 ms (default: the task's, 40)")


def parse_values(option: str, text: str | None, scale: float) -> tuple[float, ...]:
    """Comma-separated finite non-negative numbers, scaled. Raises EnvError naming the option."""
    if text is None:
        return ()
    values = []
    for item in text.split(","):
        try:
            value = float(item)
        except ValueError:
            raise EnvError(f"{option} {text!r}: {item.strip()!r} is not a number") from None
        if not math.isfinite(value) or value < 0.0:
            raise EnvError(f"{option} {text!r}: {item.strip()} must be a finite number >= 0")
        values.append(value * scale)
    return tuple(values)


def parse_stiffness(text: str | None) -> tuple[str, ...]:
    """Comma-separated stiffness settings ("learned", "constant:K", "schedule[:F/L/A]"). Raises EnvError naming the
    option."""
    from envs.policies.skill_settings import StiffnessSetting

    if text is None:
        return ()
    values = tuple(item.strip() for item in text.split(","))
    for item in values:
        try:
            StiffnessSetting.parse(item)
        except EnvError as err:
            raise EnvError(f"--stiffness {text!r}: {err}") from None
    return values


def base_config(args: argparse.Namespace) -> EvaluationConfig:
    """The EvaluationConfig every cell derives from. Raises EnvError on a bad option."""
    swept = {name[2:].replace("-", "_") for name, _ in AXIS_OPTIONS.values()} | {"stiffness"}
    fixed = argparse.Namespace(**{k: v for k, v in vars(args).items() if k not in swept})
    return EvaluationConfig(
        episodes=args.episodes, seed=args.seed, mode=args.mode, task=task_from_args(fixed),
        scene_from_task=scene_from_task(fixed), workers=args.workers, backend=args.backend,
        ray_address=args.ray_address, unit_timeout_s=None if args.unit_timeout_s == 0 else args.unit_timeout_s)


def main(args: argparse.Namespace) -> int:
    """Run the sweep; exit 0 when complete, 3 when incomplete, 1 when a fault stopped it, 130 when interrupted."""
    from batch import Journal, describe_event
    from envs.evaluation.evaluate import journal_run
    from envs.evaluation.sweep import SweepAxes, sweep, sweep_cells, sweep_run
    from envs.media.figures import plot_success_map

    axes = SweepAxes(**{name: parse_values(option, getattr(args, option[2:].replace("-", "_")), scale)
                        for name, (option, scale) in AXIS_OPTIONS.items()}, stiffness=parse_stiffness(args.stiffness))
    if args.resume and args.overwrite:
        raise EnvError("--resume and --overwrite exclude each other")
    base = base_config(args)
    try:
        cells = sweep_cells(base, axes)
    except EnvError:  # name the axis option and the value as given, when one value alone is at fault
        for name, (option, scale) in AXIS_OPTIONS.items():
            for value in getattr(axes, name):
                check_option_value(base.task, option, value / scale, name, value)
        raise
    out: Path = args.out
    records = 64 * 1024 + RECORD_BYTES * args.episodes * len(cells)
    created = check_output_folder("--out", out, inputs=[args.model], estimate_bytes=2 * records + 4 * MiB)
    existing = [name for name in OUTPUTS if (out / name).exists()]
    if existing and not (args.resume or args.overwrite):
        raise EnvError(f"--out {out} already holds {', '.join(existing)} (use --resume or --overwrite)")
    for name in OUTPUTS if out.is_dir() else ():  # those there are ours; a registry there is ours (sweep.png)
        check_output("--out", out / name, args.overwrite or args.resume)
    checksum = journal_run(args.model, cells[0].config)["skill_sha256"]
    work_begins()
    out.mkdir(parents=True, exist_ok=True)
    wall = time.perf_counter()
    journal_path = out / "journal.jsonl"
    try:
        with Journal.open(journal_path, sweep_run(str(args.model), cells, checksum), resume=args.resume,
                          overwrite=args.overwrite) as journal:
            result = sweep(str(args.model), cells, progress=not args.quiet, journal=journal)
    except Exception:  # a cell's scene or the checkpoint failed before any episode: leave nothing behind
        if not args.resume and journal_path.is_file() and len(journal_path.read_text().splitlines()) <= 1:
            journal_path.unlink()
            if created and not any(out.iterdir()):
                out.rmdir()
        raise
    if result.fault is not None:  # the batch was stopped: one line, no success map of a sweep that did not happen
        print(f"pih sweep: error: {result.fault}; finished episodes are in {journal_path}; continue with the same "
              "command and --resume", file=sys.stderr)
        return 1
    write_json(out / "sweep.json", result.to_dict())
    active = axes.active()
    rows: str | None
    if {"clearance_m", "hole_error_m"} <= set(active):
        rows, columns = "clearance_m", "hole_error_m"
    elif len(active) >= 2:
        rows, columns = active[0], active[1]
    else:  # one axis: one row of cells
        rows, columns = None, active[0]
    plot_success_map(result.summaries, rows, columns, out / "sweep.png",
                     f"{args.model}: seated (%) over {len(cells)} cells x {args.episodes} episodes ({args.mode})")
    for summary in result.summaries:
        low, high = summary["success_rate_ci95"]
        force = summary["median_peak_wrist_force_n"]
        settings = ", ".join(f"{k} {v}" if isinstance(v, str) else f"{k} {v:g}" for k, v in summary["settings"].items())
        print(f"{settings}: {summary['successes']}/{summary['episodes']} seated [{100 * low:.0f}, {100 * high:.0f}] %, "
              f"contact {100 * summary['contact_rate']:.0f} %, "
              f"median peak wrist force {'-' if force is None else f'{force:.1f} N'}")
    print(f"wrote {out / 'sweep.json'} and {out / 'sweep.png'} ({time.perf_counter() - wall:.0f} s)")
    for event in result.infrastructure_events[result.events_before:]:  # a resumed sweep's earlier ones: in the JSON
        print(f"pih sweep: infrastructure: {describe_event(event)}", file=sys.stderr)
    if result.interrupted:
        print("interrupted: continue with the same command and --resume", flush=True)
        return 130
    if not result.complete:
        print(f"pih sweep: incomplete: {len(result.infrastructure_errors)} episode(s) lost to infrastructure; "
              "continue with the same command and --resume", file=sys.stderr)
        return 3
    return 0


