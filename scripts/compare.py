"""`pih compare`: did a change make insertion worse? A paired comparison of two skills on the same episodes.

    pih compare BASE.json CAND.json [--margin 0.0] [--alpha 0.05] [--json out.json]
    pih compare --sequential --base-model A --cand-model B --seed S [--max-episodes 400] [--chunk 10]
        [--workers N] [the start and task options of `pih evaluate`: --task NAME|FILE.toml, ...]
    pih compare --sequential --base-model A --cand-policy mypkg.mymodule:make --demos demos.npz --seed S
        [--cand-policy-option KEY=VALUE ...] [--cand-privileged] ...      (either side, or both, a policy)

Paired mode reads two `pih evaluate --json` files that ran the same episodes (same --seed, --episodes and
start / task options; refused, one line naming the first differing episode, otherwise) and prints the success
rates with Wilson intervals, the paired counts, the difference with Newcombe's paired interval, McNemar's exact
p, Barnard's unpaired p for reference, the finer paired metrics (progress, time to seat, held force) and the
decision: "regression" when the one-sided (1 - alpha) upper bound of p_cand - p_base lies below -margin
(envs/statistics/fixed_sample.py, sequential.py, pairing.py, comparison.py).

Sequential mode runs the episodes itself: it draws the starts once from the demo starts of --demos (else of the
base model), runs both sides -- each a skill (--base-model, --cand-model) or a user's policy (--base-policy,
--cand-policy, in the scene of --demos, supervised as `pih evaluate --policy` runs one; its first error stops the run
with its traceback, exit 4) -- on the same starts, --chunk episodes at a time, feeds the pairs in episode order to anytime-valid
e-processes on success and progress, and stops at the first decision (or after --max-episodes pairs), so the
answer does not depend on --workers or --chunk. It reports how many pairs the decision needed.

Exit status: 0 no regression (or, sequential, no decision yet), 1 regression, 2 bad input (missing file, not
an evaluation, episodes that do not pair), 3 / 130 an incomplete / interrupted sequential run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
from pathlib import Path
from typing import Any, Sequence

import scripts.evaluate as evaluate_cli
from envs.errors import EnvError
from envs.io.owned_output import write_json
from envs.statistics.comparison import compare_evaluations, load_evaluation, sequential_differences
from envs.statistics.fixed_sample import DECISIONS
from envs.statistics.pairing import pair_records
from envs.statistics.sequential import SequentialComparison
from scripts.options import MAX_EPISODES, count, number, refuse_unused, work_begins

KIND = "pih compare"
EXIT_REGRESSION = 1
EXIT_INCOMPLETE = 3
EXIT_INTERRUPTED = 130
DEFAULT_MAX_EPISODES = 400
DEFAULT_CHUNK = 10


PAIRED_OPTIONS = ("margin", "alpha", "json", "overwrite", "sequential")
"""The options that apply when two evaluation files are compared (the rest are the sequential mode's)."""


EXAMPLES: tuple[str, ...] = ('pih compare base.json cand.json --margin 0.02',
                             'pih compare --sequential --base-model base/ --cand-model cand/ --seed 3000',
                             'pih compare --sequential --base-model base/ --cand-policy mymodule:make --demos demos.npz')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih compare`."""
    parser.add_argument("evaluations", nargs="*", type=Path, metavar="EVAL.json",
                        help="BASE.json CAND.json: two `pih evaluate --json` files of the same episodes")
    parser.add_argument("--margin", type=number(minimum=0.0, maximum=1.0), default=0.0,
                        help="success-rate drop tolerated, as a fraction (0.02 = 2 points; default 0)")
    parser.add_argument("--alpha", type=number(minimum=0.0, maximum=0.5), default=0.05,
                        help="probability of calling a regression that is not there (default 0.05)")
    parser.add_argument("--json", type=Path, help="write the comparison here (strict JSON)")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier `pih compare --json` output")
    group = parser.add_argument_group("sequential mode (also takes the start and task options of `pih evaluate`)")
    group.add_argument("--sequential", action="store_true",
                       help="run both models on the same starts, chunk by chunk, until the e-processes decide")
    group.add_argument("--base-model", type=Path, help="checkpoint of the base skill (its demo starts give the starts)")
    group.add_argument("--cand-model", type=Path, help="checkpoint of the candidate skill")
    for side, name in (("base", "base"), ("cand", "candidate")):
        group.add_argument(f"--{side}-policy", metavar="MODULE:FACTORY",
                           help=f"the {name} as a policy factory instead (docs/policy.md; needs --demos)")
        group.add_argument(f"--{side}-policy-option", action="append", default=[], metavar="KEY=VALUE",
                           help=f"a string for the {name} policy's factory; repeatable")
        group.add_argument(f"--{side}-privileged", action="store_true",
                           help=f"the {name} policy observes the true hole (a teacher)")
    group.add_argument("--demos", type=Path, metavar="FILE.npz",
                       help="the demos whose scene a policy runs in and whose start poses the starts are drawn around")
    group.add_argument("--max-episodes", dest="episodes", type=count(MAX_EPISODES), default=DEFAULT_MAX_EPISODES,
                       help=f"stop undecided after this many pairs (default {DEFAULT_MAX_EPISODES})")
    group.add_argument("--chunk", type=count(MAX_EPISODES), default=DEFAULT_CHUNK,
                       help=f"episodes per model run between updates (default {DEFAULT_CHUNK})")
    group.add_argument("--progress-margin", type=number(minimum=0.0, maximum=1.0),
                       help="margin of the mean insertion progress (0-1) in the sequential test (default: --margin)")
    group.add_argument("--quiet", action="store_true", help="no progress bars or per-chunk lines")
    evaluate_cli.add_evaluation_options(parser)


def check_json_output(path: Path | None, overwrite: bool, inputs: list[Path]) -> None:
    """--json: a .json in an existing folder, none of the inputs, new, or with --overwrite an earlier output of
    `pih compare` (envs.io.owned_output's policy, and the record's kind).

    Raises:
        EnvError: naming the option and the problem.
    """
    from envs.io.owned_output import check_output

    check_output("--json", path, overwrite, suffix=".json", inputs=inputs)
    if path is None or not path.exists():
        return
    try:
        kind = json.loads(path.read_text()).get("kind")
    except (OSError, ValueError, AttributeError):
        kind = None
    if kind != KIND:
        raise EnvError(f"--json {path} is not an output of `pih compare`: not replaced")


def check_args(args: argparse.Namespace) -> None:
    """The options common to both modes and the mode's inputs. Raises EnvError naming the option."""
    if not (math.isfinite(args.margin) and 0.0 <= args.margin < 1.0):
        raise EnvError(f"--margin {args.margin}: must lie in [0, 1) (a fraction: 0.02 = 2 points)")
    if not (math.isfinite(args.alpha) and 0.0 < args.alpha < 0.5):
        raise EnvError(f"--alpha {args.alpha}: must lie strictly between 0 and 0.5")
    if args.progress_margin is not None and not (math.isfinite(args.progress_margin) and 0.0 <= args.progress_margin < 1.0):
        raise EnvError(f"--progress-margin {args.progress_margin}: must lie in [0, 1)")
    check_json_output(args.json, args.overwrite, [*args.evaluations, args.base_model, args.cand_model, args.demos])
    if not args.sequential:
        refuse_unused(args, add_arguments, None, "applies to --sequential only", keep=PAIRED_OPTIONS)
        if len(args.evaluations) != 2:
            raise EnvError(f"give two evaluations, BASE.json CAND.json (got {len(args.evaluations)}), or --sequential "
                           "with --base-model and --cand-model")
        return
    if args.evaluations:
        raise EnvError("--sequential runs the episodes itself: give --base-model and --cand-model, not evaluation files")
    for side in ("base", "cand"):
        model, policy = getattr(args, f"{side}_model"), getattr(args, f"{side}_policy")
        if policy is None:
            given = [o for o, v in ((f"--{side}-policy-option", getattr(args, f"{side}_policy_option")),
                                    (f"--{side}-privileged", getattr(args, f"{side}_privileged"))) if v]
            if given:
                raise EnvError(f"{', '.join(given)}: only with --{side}-policy")
            if model is None:
                raise EnvError(f"--sequential needs --{side}-model DIR or --{side}-policy MODULE:FACTORY")
            if not model.is_dir():
                raise EnvError(f"--{side}-model {model}: checkpoint folder not found")
        elif model is not None:
            raise EnvError(f"--{side}-model and --{side}-policy: give one")
    if args.demos is None and (args.base_policy is not None or args.cand_policy is not None):
        raise EnvError("a --base-policy or --cand-policy needs --demos FILE: the demos whose scene it runs in")


def write_output(path: Path | None, record: dict[str, Any]) -> None:
    """Write ``record`` as strict JSON (no NaN) atomically, tagged as a `pih compare` output."""
    if path is not None:
        write_json(path, {"kind": KIND, **record})
        print(f"wrote {path}")


def main(args: argparse.Namespace) -> int:
    """Run `pih compare`; returns 0 (no regression / undecided), 1 (regression), 3 or 130 (sequential run cut short)."""
    check_args(args)
    if args.sequential:
        return run_sequential(args)
    from envs.evaluation.replay import check_recorded

    base, cand = (load_evaluation(path, label) for path, label in zip(args.evaluations, ("BASE", "CAND")))
    for path, label in zip(args.evaluations, ("BASE", "CAND")):  # its counts, its starts and perturbations
        check_recorded(json.loads(Path(path).read_text()), f"{label} {path}")
    work_begins()
    comparison = compare_evaluations(base, cand, args.margin, args.alpha)
    print(comparison.table())
    write_output(args.json, {"mode": "paired", **comparison.to_dict()})
    return EXIT_REGRESSION if comparison.decision == DECISIONS[0] else 0


# --------------------------------------------------------------------------------------------- sequential


def merge_results(results: Sequence[Any], pairs: int, config: Any) -> Any:
    """One EvaluationResult of the first ``pairs`` episodes of consecutive chunk results of one model."""
    from envs.evaluation.result import EvaluationResult

    records = [r for result in results for r in result.records][:pairs]
    first = results[0]
    return EvaluationResult(dataclasses.replace(config, episodes=max(pairs, 1)), records,
                            sum(r.wall_s for r in results), first.model_dir, first.metadata, first.scene,
                            first.goal_mismatch_mm, all(r.complete for r in results),
                            any(r.interrupted for r in results), task=first.task, policy=first.policy)


def side_evaluation(args: argparse.Namespace, side: str, config: Any) -> Any:
    """How one side of the sequential mode evaluates a chunk of starts: ``run(starts) -> EvaluationResult`` for its
    skill (``--SIDE-model``) or its policy (``--SIDE-policy`` in the scene of --demos), checked before any work.

    Raises:
        EnvError: a bad policy spec or option, a policy module that is not found, an unreadable demo file.
    """
    from envs.evaluation.evaluate import evaluate

    model, policy = getattr(args, f"{side}_model"), getattr(args, f"{side}_policy")
    if policy is None:
        return lambda starts: evaluate(model, config, progress=not args.quiet, starts=starts)
    from envs.evaluation.evaluate_policy import (PolicySpec, demo_metadata, evaluate_policy, parse_policy_options,
                                                 policy_files)

    try:
        spec = PolicySpec(policy, parse_policy_options(getattr(args, f"{side}_policy_option")),
                          bool(getattr(args, f"{side}_privileged")), os.getcwd())
    except EnvError as err:
        raise EnvError(f"--{side}-policy: {err}") from None
    policy_files(spec)  # found (imported only in the supervised workers)
    metadata = demo_metadata(args.demos)
    return lambda starts: evaluate_policy(spec, metadata, config, progress=not args.quiet, starts=starts)


def run_sequential(args: argparse.Namespace) -> int:
    """Sequential mode (module docstring)."""
    from envs.evaluation.evaluate import skill_file
    from envs.evaluation.starts import evaluation_starts, metadata_starts
    from rflow.skill_io import load_skill

    config = evaluate_cli.checked_config(args)
    if args.demos is not None:
        from envs.evaluation.evaluate_policy import demo_metadata

        demo_starts = metadata_starts(demo_metadata(args.demos), f"--demos {args.demos}")
    else:
        demo_starts = metadata_starts(load_skill(args.base_model).metadata, f"--base-model {skill_file(args.base_model)}")
    starts = evaluation_starts(demo_starts, config)
    sides = {"base": side_evaluation(args, "base", config), "candidate": side_evaluation(args, "cand", config)}
    work_begins()
    margin = args.margin if args.progress_margin is None else args.progress_margin
    test = SequentialComparison({"success": args.margin, "progress": margin}, args.alpha)
    runs: dict[str, list[Any]] = {"base": [], "candidate": []}
    status = 0
    for lo in range(0, len(starts), args.chunk):
        chunk = starts[lo:lo + args.chunk]
        results = {side: run(chunk) for side, run in sides.items()}
        if any(r.interrupted or not r.complete for r in results.values()):
            status = EXIT_INTERRUPTED if any(r.interrupted for r in results.values()) else EXIT_INCOMPLETE
            break
        for side, result in results.items():
            runs[side].append(result)
        samples = {side: load_evaluation(result, side) for side, result in results.items()}
        for b, c in zip(*pair_records(samples["base"].records, samples["candidate"].records)):
            if test.update(sequential_differences(samples["base"], samples["candidate"], b, c)) is not None:
                break
        if not args.quiet:
            print(sequential_line(test), file=sys.stderr)
        if test.decision is not None:
            break
    if not runs["base"]:
        print("pih compare: stopped before the first chunk finished", file=sys.stderr)
        return status or EXIT_INCOMPLETE
    pairs = test.pairs
    merged = {side: merge_results(results, pairs, config) for side, results in runs.items()}
    comparison = compare_evaluations(load_evaluation(merged["base"], "base"), load_evaluation(merged["candidate"],
                                                                                            "candidate"),
                                     args.margin, args.alpha)
    print(comparison.table())
    print(sequential_summary(test, sum(len(r.records) for r in runs["base"]), args.episodes))
    write_output(args.json, {"mode": "sequential", "sequential": test.to_dict(), **comparison.to_dict(),
                             "episodes_run": sum(len(r.records) for r in runs["base"]),
                             "base_evaluation": merged["base"].to_dict(),
                             "candidate_evaluation": merged["candidate"].to_dict()})
    if status:
        print(f"pih compare: {'interrupted' if status == EXIT_INTERRUPTED else 'incomplete'} after {pairs} pairs",
              file=sys.stderr)
        return status
    return EXIT_REGRESSION if test.decision == DECISIONS[0] else 0


def sequential_line(test: SequentialComparison) -> str:
    """One progress line: pairs and each metric's e-values."""
    values = ", ".join(f"{name} e {t.e_regression:.2f} (worse) / {t.e_no_regression:.2f} (not worse)"
                       for name, t in test.tests.items())
    return f"pih compare: {test.pairs} pairs: {values}"


def sequential_summary(test: SequentialComparison, episodes_run: int, max_pairs: int) -> str:
    """The sequential decision in words."""
    thresholds = f"thresholds {test.regression_threshold:g} (worse), {1.0 / test.alpha:g} (not worse)"
    if test.decision is None:
        return (f"sequential: no decision after {test.pairs} pairs (of at most {max_pairs}; {thresholds}); "
                "run more episodes or accept a margin")
    return (f"sequential: {test.decision} after {test.decided_at} pairs ({episodes_run} run per model; "
            f"{thresholds})")


__all__ = ["EXAMPLES", "add_arguments", "main"]
