"""`pih sensitivity`: what each imperfection of a real cell costs a trained skill, paired with the ideal cell.

    pih sensitivity --model runs/default/model --out runs/sensitivity [--episodes 100] [--seed 1000] \\
        [--workers 2] [--only friction payload ...] [--task contact]

Runs the skill on the task (default the contact preset: the ideal cell), then on it with each imperfection of
envs/evaluation/sensitivity.py alone and with all of them (the "realistic" preset's magnitudes), every variant on the
same --seed and --episodes, so each pairs with the ideal cell episode for episode. Writes into --out:
sensitivity.md (the table), sensitivity.json (every row with its paired comparison) and sensitivity.png (the
figure), and prints the table and the imperfection that costs most. Exit status: 0, or 2 on bad input (checked
before any episode).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from envs.errors import EnvError
from envs.io.owned_output import MiB, check_output, check_output_folder
from scripts.options import MAX_EPISODES, MAX_WORKERS, count, seed, work_begins
from scripts.task_options import add_task_file_arguments, task_from_args

IMPERFECTION_NAMES = ("friction", "compliant_pads", "in_hand_pose", "grasp_offset", "payload", "joint_friction",
                      "torque_noise", "hole_observation", "joint_torque_sensing", "wrist_sensor")
"""The names of envs.evaluation.sensitivity.IMPERFECTIONS, then ALTERNATIVES (spelled here so --help does not load the
simulator)."""
OUTPUTS = {"table": "sensitivity.md", "json": "sensitivity.json", "figure": "sensitivity.png"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih sensitivity`."""
    parser.add_argument("--model", type=Path, required=True, help="checkpoint directory from `pih train`")
    parser.add_argument("--out", type=Path, default=Path("runs/sensitivity"), help="folder for the table, JSON, figure")
    parser.add_argument("--overwrite", action="store_true", help="replace outputs an earlier pih run wrote there")
    parser.add_argument("--episodes", type=count(MAX_EPISODES), default=100, help="episodes per variant")
    parser.add_argument("--seed", type=seed, default=1000, help="seed of the starts (keep it apart from demo seeds)")
    parser.add_argument("--workers", type=count(MAX_WORKERS), default=2, help="evaluation processes")
    parser.add_argument("--only", nargs="+", choices=IMPERFECTION_NAMES, default=list(IMPERFECTION_NAMES),
                        metavar="NAME", help=f"imperfections to run, of {', '.join(IMPERFECTION_NAMES)} (default all)")
    add_task_file_arguments(parser.add_argument_group("task (the ideal cell; default the contact preset)"))


def main(args: argparse.Namespace) -> int:
    """Run the variants and write the outputs; returns 0."""
    from envs.evaluation.config import EvaluationConfig
    from envs.evaluation.sensitivity import costliest, plot_sensitivity, run_sensitivity, sensitivity_table
    from envs.io.owned_output import write_json, write_text

    if not args.model.is_dir():
        raise EnvError(f"--model {args.model}: no such checkpoint folder")
    from rflow.skill_io import load_skill

    load_skill(args.model)  # a corrupt checkpoint is one line before any output or episode
    check_output_folder("--out", args.out, inputs=[args.model], estimate_bytes=4 * MiB)
    paths = {key: args.out / name for key, name in OUTPUTS.items()}
    # Before any episode runs: the outputs already there are ours, and so is the registry the figure joins.
    for path in paths.values() if args.out.is_dir() else ():
        check_output("--out", path, args.overwrite, inputs=[args.model], estimate_bytes=2 * MiB)
    config = EvaluationConfig(episodes=args.episodes, seed=args.seed, workers=args.workers, task=task_from_args(args))
    names = [n for n in IMPERFECTION_NAMES if n in args.only]
    work_begins()
    rows = run_sensitivity(args.model, config, names,
                           on_variant=lambda name: print(f"evaluating: {name}", file=sys.stderr, flush=True))
    args.out.mkdir(parents=True, exist_ok=True)  # made once there is something to write: a bad model leaves nothing
    table = sensitivity_table(rows)
    worst = costliest(rows)
    verdict = ("no imperfection alone lowered the success rate on these episodes" if worst is None else
               f"costliest imperfection: {worst.name} ({worst.successes}/{worst.episodes} seated)")
    write_text(paths["table"], table + "\n\n" + verdict + "\n")
    write_json(paths["json"], {"episodes": args.episodes, "seed": args.seed, "model": str(args.model),
                               "task": dataclasses.replace(config.task).to_dict(), "costliest": None if worst is None
                               else worst.name, "rows": [row.to_dict() for row in rows]})
    plot_sensitivity(rows, paths["figure"])
    print(table)
    print(verdict)
    return 0


__all__ = ["add_arguments", "main"]
