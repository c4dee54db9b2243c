"""`pih sweep`: success maps of a trained skill over a grid of task settings.

    pih sweep --model runs/default/model --clearance-mm 1,0.5,0.2,0.1 --hole-error-mm 0,0.5,1,2 \\
        --episodes 30 --seed 0 --out runs/sweep [--chamfer-mm 0,1] [--hole-error-deg 0,1] [--pos-range 0.05] \\
        [--stiffness learned,constant:500,constant:1500,constant:4000] \\
        [--workers 2] [--backend ray --ray-address HOST:PORT] [--resume | --overwrite]

Every cell (the product of the axes) runs the same K seeded starts (envs/execution/sweep.py). Writes, in --out:
sweep.json (per cell: rate, Wilson interval, median time, peak forces, contact rate; every episode),
sweep.png (heat map: clearance x hole error, or the first two axes) and journal.jsonl (finished episodes,
for --resume). Settings not swept come from --preset and the task options, and the scene from the demos.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

from envs.errors import EnvError  # noqa: E402
from envs.jsonable import write_json_atomic  # noqa: E402
from envs.execution.evaluate import EvaluationConfig  # noqa: E402
from envs.execution.policy import MODES  # noqa: E402
from envs.execution.sweep import SweepAxes, sweep, sweep_cells, sweep_run  # noqa: E402
from scripts.task_options import task_from_args  # noqa: E402

AXIS_OPTIONS: dict[str, tuple[str, float]] = {
    "clearance_m": ("--clearance-mm", 1e-3),
    "hole_error_m": ("--hole-error-mm", 1e-3),
    "chamfer_m": ("--chamfer-mm", 1e-3),
    "hole_error_deg": ("--hole-error-deg", 1.0),
    "pos_range_m": ("--pos-range", 1.0),
}
OUTPUTS: tuple[str, ...] = ("sweep.json", "sweep.png", "journal.jsonl")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih sweep`."""
    from batch import BACKENDS

    d = EvaluationConfig()
    parser.add_argument("--model", required=True, type=Path, help="checkpoint directory from `pih train`")
    parser.add_argument("--out", required=True, type=Path, help="output folder (created; sweep.json, sweep.png, journal)")
    axes = parser.add_argument_group("axes (comma-separated values; the map is clearance x hole error)")
    axes.add_argument("--clearance-mm", help="hole clearances in mm, e.g. 1,0.5,0.2,0.1")
    axes.add_argument("--hole-error-mm", help="hole-pose error radii in mm, e.g. 0,0.5,1,2")
    axes.add_argument("--chamfer-mm", help="chamfer widths in mm")
    axes.add_argument("--hole-error-deg", help="hole-pose angle errors in deg")
    axes.add_argument("--pos-range", help="start position ranges in m")
    axes.add_argument("--stiffness", help="commanded translational stiffness per cell: 'learned' (a skill from "
                                          "`pih train --stiffness`) or 'constant:K' (K I, K > 0 in N/m), e.g. "
                                          "learned,constant:500,constant:1500,constant:4000")
    parser.add_argument("--episodes", type=int, default=30, help="episodes per cell (default 30)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the starts and perturbations (default 0)")
    parser.add_argument("--mode", choices=MODES, default=d.mode, help=f"skill execution (default {d.mode})")
    parser.add_argument("--time-limit", type=float, default=d.time_limit_s,
                        help=f"simulated seconds per episode (default {d.time_limit_s:g})")
    parser.add_argument("--workers", type=int, default=2, help="parallel workers (default 2)")
    parser.add_argument("--backend", choices=BACKENDS, default=d.backend, help="process (default) or ray")
    parser.add_argument("--ray-address", help="HOST:PORT of a Ray cluster's head (default: a local Ray)")
    parser.add_argument("--unit-timeout", type=float, default=d.unit_timeout_s,
                        help=f"wall seconds per episode before its worker is killed (default {d.unit_timeout_s:g}; 0 = none)")
    parser.add_argument("--resume", action="store_true", help="continue the sweep recorded in --out/journal.jsonl")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier sweep's outputs in --out")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    task = parser.add_argument_group("task settings that are not swept")
    task.add_argument("--preset", help="task preset (contact, paper, factory) for the settings not swept")
    task.add_argument("--peg-mount", choices=("grasped", "welded"), help="peg mount (default: the demos')")
    task.add_argument("--grasp-force", type=float, help="grasp force per finger in N")
    task.add_argument("--grasp-offset-mm", type=float, help="grasp offset range along the peg axis in mm")
    task.add_argument("--force-limit", type=float, help="wrist force limit in N (default 40)")


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
    """Comma-separated stiffness settings ("learned", "constant:K"). Raises EnvError naming the option."""
    from envs.execution.policy import StiffnessSetting

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
    task = task_from_args(argparse.Namespace(**{k: v for k, v in vars(args).items() if k not in swept}))
    explicit_scene = task.scene_fields() if args.preset else {}
    return EvaluationConfig(
        episodes=args.episodes, seed=args.seed, mode=args.mode, time_limit_s=args.time_limit,
        workers=args.workers, backend=args.backend, ray_address=args.ray_address,
        unit_timeout_s=None if args.unit_timeout == 0 else args.unit_timeout,
        peg_mode=args.peg_mount or explicit_scene.get("peg_mode"),
        grasp_force_n=args.grasp_force if args.grasp_force is not None else explicit_scene.get("grasp_force_n"),
        clearance_m=explicit_scene.get("clearance_m"), chamfer_m=explicit_scene.get("chamfer_m"),
        perturbations=task.perturbations, force_limit_n=task.force_limit_n)


def main(args: argparse.Namespace) -> int:
    """Run the sweep; exit 0 when complete, 3 when incomplete, 1 when a fault stopped it, 130 when interrupted."""
    from batch import Journal, describe_event
    from envs.execution.evaluate import journal_run
    from envs.execution.figures import plot_success_map

    axes = SweepAxes(**{name: parse_values(option, getattr(args, option[2:].replace("-", "_")), scale)
                        for name, (option, scale) in AXIS_OPTIONS.items()}, stiffness=parse_stiffness(args.stiffness))
    if not isinstance(args.episodes, int) or args.episodes < 1:
        raise EnvError(f"--episodes {args.episodes}: need at least 1")
    if args.resume and args.overwrite:
        raise EnvError("--resume and --overwrite exclude each other")
    cells = sweep_cells(base_config(args), axes)
    out: Path = args.out
    if out.exists() and not out.is_dir():
        raise EnvError(f"--out {out} is a file, not a folder")
    if not out.parent.is_dir():
        raise EnvError(f"--out {out}: folder {out.parent} does not exist")
    existing = [name for name in OUTPUTS if (out / name).exists()]
    if existing and not (args.resume or args.overwrite):
        raise EnvError(f"--out {out} already holds {', '.join(existing)} (use --resume or --overwrite)")
    checksum = journal_run(args.model, cells[0].config)["skill_sha256"]
    created = not out.exists()
    out.mkdir(exist_ok=True)
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
    write_json_atomic(out / "sweep.json", result.to_dict())
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
    for event in result.infrastructure_events:
        print(f"pih sweep: infrastructure: {describe_event(event)}", file=sys.stderr)
    if result.fault is not None:
        print(f"pih sweep: error: {result.fault}; continue with the same command and --resume", file=sys.stderr)
        return 1
    if result.interrupted:
        print(f"interrupted: continue with the same command and --resume", flush=True)
        return 130
    if not result.complete:
        print(f"pih sweep: incomplete: {len(result.infrastructure_errors)} episode(s) lost to infrastructure; "
              "continue with the same command and --resume", file=sys.stderr)
        return 3
    return 0



