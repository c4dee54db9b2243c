"""`pih sensitivity`: what each imperfection of a real cell costs a trained skill, or any policy, paired with the
ideal cell.

    pih sensitivity --model runs/default/model --out runs/sensitivity [--episodes 100] [--seed 1000] \\
        [--workers 2] [--only friction payload ...] [--task contact]
    pih sensitivity --policy mypkg.mymodule:make --demos demos.npz [--policy-option KEY=VALUE ...] --out sens/

With --policy (and --demos, as `pih evaluate --policy` takes them) the user's policy runs every variant in the demos'
scene, supervised as there; an error in the policy stops the run with its traceback (exit 4).

Runs the skill on the task (default the contact preset: the ideal cell), then on it with each imperfection of
envs/evaluation/sensitivity.py alone and with all of them (the "realistic" preset's magnitudes), every variant on the
same --seed and --episodes, so each pairs with the ideal cell episode for episode. Writes into --out:
sensitivity.md (the table), sensitivity.json (every row with its paired comparison) and sensitivity.png (the
figure), and prints the table and the imperfection that costs most. With --curves, each named imperfection is also
swept over its magnitude (envs.evaluation.sensitivity.CURVES: the joint friction, the in-hand tilt, the joint torque
sensors' noise and bias, and one curve per assumption of the realistic preset), every point a variant paired with the
ideal cell, one figure per curve (curve_CURVE.png) and its rows in the table.

Long runs: every finished episode of a variant goes into its journal, --out/journals/VARIANT.jsonl, so after Ctrl-C
or SIGTERM (exit 130) the same command with --resume runs only what is missing, to the same table. Exit status: 0;
2 on bad input (checked before any episode); 130 when interrupted, 3 when a variant lost episodes to infrastructure,
1 when a fault stopped it (the Ray head lost): each with the command that continues.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import shlex
import sys
from pathlib import Path
from typing import Any, Iterator

from envs.errors import EnvError
from envs.io.owned_output import MiB, check_output, check_output_folder
from scripts.evaluate_policy import policy_spec
from scripts.options import DEFAULT_WORKERS, MAX_EPISODES, MAX_WORKERS, count, seed, work_begins
from scripts.task_options import add_task_file_arguments, task_from_args

CURVE_NAMES = ("joint_friction", "in_hand_tilt", "sensor_noise", "sensor_bias", "in_hand_lateral", "in_hand_yaw",
               "torque_noise", "payload", "part_friction")
"""The names of envs.evaluation.sensitivity.CURVES (spelled here so --help does not load numpy; a test keeps them
equal)."""
DEFAULT_CURVES = ("joint_friction", "in_hand_tilt", "sensor_noise", "sensor_bias")
"""`--curves` without names: the joint friction, the in-hand tilt and the joint torque sensors' noise and bias."""
IMPERFECTION_NAMES = ("friction", "compliant_pads", "in_hand_pose", "grasp_offset", "payload", "joint_friction",
                      "torque_noise", "hole_observation", "joint_torque_sensing", "wrist_sensor")
"""The names of envs.evaluation.sensitivity.IMPERFECTIONS, then ALTERNATIVES (spelled here so --help does not load the
simulator)."""
OUTPUTS = {"table": "sensitivity.md", "json": "sensitivity.json", "figure": "sensitivity.png"}
JOURNALS = "journals"
"""The folder in --out holding one journal per variant (VARIANT.jsonl)."""
RECORD_BYTES = 8 * 1024
"""Generous size of one episode in a journal (a record is ~2 KB)."""
EXIT_FAULT, EXIT_INCOMPLETE, EXIT_INTERRUPTED = 1, 3, 130


EXAMPLES: tuple[str, ...] = ('pih sensitivity --model model/ --out sens/ --episodes 100 --seed 1000',
                             'pih sensitivity --model model/ --out curves/ --curves --episodes 100 --seed 1000',
                             'pih sensitivity --policy mymodule:make --demos demos.npz --out sens_mine/')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih sensitivity`."""
    source = parser.add_argument_group("what runs: a skill (--model) or a policy (--policy with --demos)")
    source.add_argument("--model", type=Path, help="checkpoint directory from `pih train`")
    source.add_argument("--policy", metavar="MODULE:FACTORY", help="factory(task, **options) -> Policy (docs/policy.md)")
    source.add_argument("--demos", type=Path, metavar="FILE.npz", help="with --policy: the demos whose scene and starts "
                                                                       "to run")
    source.add_argument("--policy-option", action="append", default=[], metavar="KEY=VALUE",
                        help="with --policy: a string for the factory; repeatable")
    source.add_argument("--privileged", action="store_true", help="with --policy: observations carry the true hole")
    parser.add_argument("--out", type=Path, default=Path("runs/sensitivity"), help="folder for the table, JSON, figure")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace outputs (and the journals of an unfinished run) an earlier pih run wrote there")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run whose journals are in --out/journals: only missing episodes run")
    parser.add_argument("--episodes", type=count(MAX_EPISODES), default=100, help="episodes per variant")
    parser.add_argument("--seed", type=seed, default=1000, help="seed of the starts (keep it apart from demo seeds)")
    parser.add_argument("--workers", type=count(MAX_WORKERS), default=DEFAULT_WORKERS, help="evaluation processes")
    parser.add_argument("--only", nargs="+", choices=IMPERFECTION_NAMES, default=None, metavar="NAME",
                        help=f"imperfections to run, of {', '.join(IMPERFECTION_NAMES)} (default all; with --curves "
                             "none)")
    parser.add_argument("--curves", nargs="*", choices=CURVE_NAMES, default=None, metavar="CURVE",
                        help="also sweep these imperfections over their magnitude, each point paired with the ideal "
                             f"cell, one figure each (curve_CURVE.png), of {', '.join(CURVE_NAMES)} (no name: "
                             f"{', '.join(DEFAULT_CURVES)})")
    add_task_file_arguments(parser.add_argument_group("task (the ideal cell; default the contact preset)"))


def main(args: argparse.Namespace) -> int:
    """Run (or continue) the variants and write the outputs; returns the exit status (module docstring)."""
    from envs.evaluation.config import EvaluationConfig
    from envs.evaluation.sensitivity import (CURVE_SEPARATOR, Stopped, costliest, plot_curves, plot_sensitivity,
                                             run_sensitivity, sensitivity_table, sensitivity_verdict)
    from envs.evaluation.sensitivity import variants as variants_of
    from envs.io.owned_output import write_json, write_text

    if args.resume and args.overwrite:
        raise EnvError("--resume continues an earlier run and --overwrite replaces it: choose one")
    evaluate, run_of, source = evaluation_of(args)
    config = EvaluationConfig(episodes=args.episodes, seed=args.seed, workers=args.workers, task=task_from_args(args))
    curves = [] if args.curves is None else (list(args.curves) or list(DEFAULT_CURVES))
    only = args.only if args.only is not None else ([] if curves else list(IMPERFECTION_NAMES))
    names = [n for n in IMPERFECTION_NAMES if n in only]
    planned = [name for name, _, _ in variants_of(config, names, curves)]
    journals = args.out / JOURNALS
    check_output_folder("--out", args.out, inputs=[source],
                        estimate_bytes=4 * MiB + RECORD_BYTES * args.episodes * len(planned))
    paths = {key: args.out / name for key, name in OUTPUTS.items()}
    paths.update({f"curve_{curve}": args.out / f"curve_{curve}.png" for curve in curves})
    # Before any episode runs: the outputs already there are ours, and so is the registry the figure joins.
    for path in paths.values() if args.out.is_dir() else ():
        check_output("--out", path, args.overwrite or args.resume, inputs=[source], estimate_bytes=2 * MiB)
    check_journals(journals, planned, args.resume, args.overwrite, source)
    work_begins()
    journals.mkdir(parents=True, exist_ok=True)
    try:
        rows = run_sensitivity(args.model, config, names, evaluate=evaluate,
                               journal=variant_journal(journals, args, run_of), curves=curves,
                               on_variant=lambda name: print(f"evaluating: {name}", file=sys.stderr, flush=True))
    except Stopped as stop:
        return stopped(args, stop.name, stop.result, planned)
    except KeyboardInterrupt:  # between two batches (a variant's batch handles its own)
        return stopped(args, None, None, planned)
    table = sensitivity_table(rows)
    worst = costliest(rows)
    verdict = sensitivity_verdict(rows)
    write_text(paths["table"], table + "\n\n" + verdict + "\n")
    what = ({"model": str(args.model)} if args.policy is None else
            {"policy": policy_spec(args).to_dict(), "demos": str(args.demos)})
    write_json(paths["json"], {"episodes": args.episodes, "seed": args.seed, **what,
                               "task": dataclasses.replace(config.task).to_dict(), "costliest": None if worst is None
                               else worst.name, "rows": [row.to_dict() for row in rows]})
    plot_sensitivity([row for row in rows if CURVE_SEPARATOR not in row.name], paths["figure"])
    plot_curves(rows, args.out)
    print(table)
    print(verdict)
    return 0


def check_journals(journals: Path, planned: list[str], resume: bool, overwrite: bool, model: Path) -> None:
    """The journals of an earlier run in ``journals`` are continued with --resume, replaced with --overwrite (each
    only if pih wrote it: `batch.Journal.open`), and otherwise keep a plain run from starting over them.

    Raises:
        EnvError: journals there without --resume or --overwrite; a file pih did not write among the planned ones.
    """
    found = sorted(p.name for p in journals.glob("*.jsonl")) if journals.is_dir() else []
    if journals.exists() and not journals.is_dir():
        raise EnvError(f"--out {journals.parent}: {journals} is not a folder of journals")
    if found and not (resume or overwrite):
        raise EnvError(f"--out {journals.parent} holds the journals of an unfinished or earlier run ({', '.join(found)}"
                       f"): continue it with --resume, or start again with --overwrite")
    for name in planned:
        path = journals / f"{name}.jsonl"
        if path.exists() or path.is_symlink():
            check_output("--out", path, True, suffix=".jsonl", inputs=[model])


def evaluation_of(args: argparse.Namespace) -> tuple[Any, Any, Path]:
    """What runs a variant, from --model or --policy and --demos, checked before any work: (the ``evaluate`` of
    `run_sensitivity`, the journal's run of a variant's config, the input file or folder).

    Raises:
        EnvError: neither or both of --model and --policy, a missing checkpoint or demo file, a policy module that
            is not found, a policy option without --policy.
    """
    if args.policy is None:
        given = [o for o, v in (("--demos", args.demos), ("--policy-option", args.policy_option),
                                ("--privileged", args.privileged)) if v]
        if given:
            raise EnvError(f"{', '.join(given)}: only with --policy")
        if args.model is None:
            raise EnvError("give --model DIR (a `pih train` checkpoint) or --policy MODULE:FACTORY with --demos FILE")
        if not args.model.is_dir():
            raise EnvError(f"--model {args.model}: no such checkpoint folder")
        from envs.evaluation.evaluate import evaluate, journal_run
        from rflow.skill_io import load_skill

        load_skill(args.model)  # a corrupt checkpoint is one line before any output or episode
        return evaluate, lambda config: journal_run(args.model, config), args.model
    if args.model is not None:
        raise EnvError("--model and --policy: give one (a skill, or a policy with --demos)")
    if args.demos is None:
        raise EnvError("--policy needs --demos FILE: the demo file whose scene and start poses the episodes use")
    from envs.evaluation.evaluate_policy import demo_metadata, evaluate_policy, policy_files, policy_journal_run

    spec, metadata = policy_spec(args), demo_metadata(args.demos)
    policy_files(spec)  # found (imported only in the supervised workers)

    def evaluate(_model: Any, config: Any, progress: bool = True, journal: Any = None) -> Any:
        return evaluate_policy(spec, metadata, config, progress=progress, journal=journal)

    return evaluate, lambda config: policy_journal_run(spec, metadata, config), args.demos


def variant_journal(journals: Path, args: argparse.Namespace, run_of: Any) -> Any:
    """The ``journal`` of `run_sensitivity`: a variant's journal in ``journals``, continued when it is there (with
    --resume), else new (replacing one with --overwrite); ``run_of(config)`` is what identifies its run."""
    from batch import Journal

    @contextlib.contextmanager
    def open_journal(name: str, config: Any) -> Iterator[Any]:
        path = journals / f"{name}.jsonl"
        resume = args.resume and path.is_file()
        with Journal.open(path, run_of(config), resume=resume, overwrite=args.overwrite) as journal:
            yield journal

    return open_journal


def resume_command(args: argparse.Namespace) -> str:
    """The command line that continues this run."""
    argv = [a for a in sys.argv[1:] if a not in ("--overwrite", "--resume")]
    if not argv or argv[0] != "sensitivity":
        return f"the same command with --resume (journals in {args.out / JOURNALS})"
    return shlex.join(["pih", *argv, "--resume"])


def stopped(args: argparse.Namespace, name: str | None, result: Any, planned: list[str]) -> int:
    """Say where the run stopped and how to continue it; the exit status (module docstring)."""
    from batch import describe_event

    journals = args.out / JOURNALS
    done = [v for v in planned if _finished(journals / f"{v}.jsonl", args.episodes)]
    where = f"in variant {name!r} " if name is not None else ""
    if result is not None:
        for event in result.new_events:
            print(f"pih sensitivity: infrastructure: {describe_event(event)}", file=sys.stderr)
        if result.fault is not None:
            print(f"pih sensitivity: error: {result.fault}", file=sys.stderr)
    what = ("interrupted" if result is None or result.interrupted else
            "stopped by a fault" if result.fault is not None else "incomplete")
    print(f"pih sensitivity: {what} {where}after {len(done)} of {len(planned)} variants; finished episodes are in "
          f"{journals}; continue with: {resume_command(args)}", file=sys.stderr)
    if result is None or result.interrupted:
        return EXIT_INTERRUPTED
    return EXIT_FAULT if result.fault is not None else EXIT_INCOMPLETE


def _finished(path: Path, episodes: int) -> bool:
    """Whether the journal at ``path`` holds ``episodes`` episodes."""
    try:
        return sum('"kind": "unit"' in line for line in path.read_text().splitlines()) >= episodes
    except OSError:
        return False


__all__ = ["EXAMPLES", "add_arguments", "main"]
