"""`pih benchmark`: the success-rate protocol -- demos, training and evaluation per demo seed, then the rate as a
distribution over demo seeds (envs/evaluation/benchmark.py says what is randomised and which intervals it reports).

    pih benchmark --demo-seeds 0-4 --episodes 200 --out bench/ [--shape square] [--task NAME|FILE.toml]
        [task options] [--workers 2] [--no-contact-adaptation | --adaptation-off PARTS] [--follow-observed-hole]

    pih benchmark --policy mypkg.mymodule:make --demo-seeds 0-4 --episodes 200 --out bench_mine/ [--policy-option ..]

Writes bench/protocol.json (what runs, the task among it), bench/seed-<s>/ (demos.npz, model/, eval.json and its
journal), bench/benchmark.json (per-seed and pooled rates, between-seed interval, beta-binomial fit) and bench/benchmark.png.
With --policy no skill is trained: each replicate's evaluation calls the policy's factory with the options
demo_seed=<s> and demo_file=<seed-s/demos.npz> besides --policy-option's (docs/policy.md), so a learner trains per seed
in its factory; the policy's first error stops the protocol with its traceback (exit 4).
Run it again with the same options to continue after Ctrl-C or a crash: finished stages are kept, an interrupted
evaluation resumes from its journal. Exit 0 when every replicate ran, 3 when one could not (its error is listed).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any, Callable

from envs.errors import EnvError
from envs.evaluation.benchmark import (
    PROTOCOL_FILE,
    REPLICATE_PREFIX,
    RESULT_FILE,
    ProtocolConfig,
    ReplicateOutcome,
    outcome_from_records,
    parse_seeds,
    summarise,
    summary_lines,
)
from scripts.evaluate import adaptation_parts, add_adaptation_options
from scripts.options import DEFAULT_WORKERS, MAX_DEMOS, MAX_EPISODES, MAX_EPOCHS, MAX_WORKERS, count, seed, work_begins
from scripts.task_options import add_start_arguments, add_task_arguments, task_from_args

REPLICATE_BYTES = 200 * 2**20
"""Generous size of one replicate's folder (demos, a checkpoint, the record and its journal)."""


EXAMPLES: tuple[str, ...] = ('pih benchmark --demo-seeds 0-4 --episodes 200 --out bench/',
                             'pih benchmark --policy mymodule:make --demo-seeds 0-4 --episodes 200 --out bench_mine/')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih benchmark`."""
    run = parser.add_argument_group("protocol")
    run.add_argument("--demo-seeds", default="0-4", help="one replicate per demo seed: '0-4', '0,3,9' (default 0-4)")
    run.add_argument("--episodes", type=count(MAX_EPISODES), default=200,
                     help=f"evaluation episodes per replicate, 1..{MAX_EPISODES:,} (default 200)")
    run.add_argument("--start-seed-offset", type=seed, default=1000,
                     help="replicate s evaluates starts and hole errors of seed s + offset (default 1000)")
    run.add_argument("--demos", type=count(MAX_DEMOS), default=7, help="demos per replicate (default 7, as the paper)")
    run.add_argument("--shape", help="peg and hole shape (default: the task's, else square)")
    run.add_argument("--epochs", type=count(MAX_EPOCHS), default=None, help="training epochs (default: `pih train`'s)")
    run.add_argument("--workers", type=count(MAX_WORKERS), default=DEFAULT_WORKERS,
                     help="training and evaluation processes")
    run.add_argument("--demo-noise", metavar="SPEC",
                     help="record each replicate's demos as a real cell would (`pih demos --noise`, e.g. 'realistic'); "
                          "the hole is then placed at the demos' mean goal")
    run.add_argument("--quiet", action="store_true", help="no progress bars")
    add_adaptation_options(parser.add_argument_group("skill (as `pih evaluate`'s)"))
    policy = parser.add_argument_group("policy (instead of training the skill; docs/policy.md)")
    policy.add_argument("--policy", metavar="MODULE:FACTORY",
                        help="factory(task, demo_seed=, demo_file=, **options) -> Policy, per replicate")
    policy.add_argument("--policy-option", action="append", default=[], metavar="KEY=VALUE",
                        help="a string for the factory; repeatable")
    policy.add_argument("--privileged", action="store_true", help="observations carry the true hole (a teacher)")
    out = parser.add_argument_group("output")
    out.add_argument("--out", type=Path, required=True, help="protocol folder (new, or one to continue)")
    add_start_arguments(run)
    add_task_arguments(parser)


def protocol_from_args(args: argparse.Namespace) -> ProtocolConfig:
    """The protocol of the parsed options, its task among it (validated before any work).

    Raises:
        EnvError: naming the offending option.
    """
    from envs.evaluation.evaluate import EvaluationConfig

    task = task_from_args(args)
    try:
        seeds = parse_seeds(args.demo_seeds)
    except EnvError as err:
        raise EnvError(f"--demo-seeds: {err}") from None
    policy = None
    if args.policy is not None:
        from envs.evaluation.evaluate_policy import policy_files
        from scripts.evaluate_policy import policy_spec

        skill_only = [o for o, v in (("--no-contact-adaptation", args.no_contact_adaptation),
                                     ("--adaptation-off", args.adaptation_off), ("--epochs", args.epochs)) if v]
        if skill_only:
            raise EnvError(f"{', '.join(skill_only)}: not with --policy (they act on the trained skill)")
        policy = policy_spec(args)
        policy_files(policy)  # found (imported only in the supervised workers)
    elif args.policy_option or args.privileged:
        raise EnvError(f"{'--policy-option' if args.policy_option else '--privileged'}: only with --policy")
    evaluation = EvaluationConfig(episodes=args.episodes, task=task.override(shape=task.shape or "square"),
                                  hole_at_goal=args.demo_noise is not None,
                                  contact_adaptation=not args.no_contact_adaptation,
                                  adaptation_off=adaptation_parts(args.adaptation_off),
                                  follow_observed_hole=args.follow_observed_hole)
    return ProtocolConfig(demo_seeds=seeds, start_seed_offset=args.start_seed_offset, num_demos=args.demos,
                          epochs=args.epochs, evaluation=evaluation, demo_noise=args.demo_noise, policy=policy)


def protocol_record(config: ProtocolConfig) -> dict[str, Any]:
    """What protocol.json holds: everything that decides the results (not the number of workers): the task
    (versioned, envs.task.task) and the other evaluation settings."""
    from envs.io.jsonable import to_jsonable

    evaluation = {k: v for k, v in config.evaluation.settings().items()
                  if k not in ("seed", "workers", "unit_timeout_s", "start_timeout_s", "backend", "ray_address",
                               "lockstep")}
    noise = {} if config.demo_noise is None else {"demo_noise": config.demo_noise}
    noise.update({} if config.policy is None else {"policy": config.policy.to_dict()})
    return to_jsonable({"command": "pih benchmark", **noise, "demo_seeds": list(config.demo_seeds),
                        "start_seeds": config.start_seeds(), "num_demos": config.num_demos, "epochs": config.epochs,
                        "task": config.task.to_dict(), "evaluation": evaluation})


def prepare_folder(out: Path, record: dict[str, Any]) -> None:
    """A new protocol folder, or the folder of the same protocol to continue.

    Raises:
        EnvError: ``out`` is a file, a folder with other contents, or a protocol with other settings.
    """
    from envs.io.owned_output import MARKER_KEY, check_output_folder, write_json

    check_output_folder("--out", out, estimate_bytes=REPLICATE_BYTES * len(record["demo_seeds"]))
    if out.is_dir():
        path = out / PROTOCOL_FILE
        if path.is_file():
            try:
                earlier = json.loads(path.read_text())
            except (OSError, ValueError) as err:
                raise EnvError(f"--out {out}: unreadable {PROTOCOL_FILE} ({err})") from None
            if isinstance(earlier, dict):
                earlier.pop(MARKER_KEY, None)  # which pih version wrote it does not decide the results
            if earlier != json.loads(json.dumps(record)):
                raise EnvError(f"--out {out} holds a protocol with other settings: choose another --out")
            work_begins()
            return
        foreign = [p.name for p in out.iterdir()]
        if foreign:
            raise EnvError(f"--out {out} is not a `pih benchmark` folder (it holds {', '.join(sorted(foreign)[:5])})")
    work_begins()
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / PROTOCOL_FILE, record)


def run_replicate(config: ProtocolConfig, folder: Path, demo_seed: int, start_seed: int, workers: int, progress: bool,
                  report: Callable[[str], None]) -> ReplicateOutcome:
    """Demos, training and evaluation of one replicate in ``folder``; a stage whose output exists is skipped and an
    interrupted evaluation resumes from its journal.

    Raises:
        EnvError / RFlowError: the replicate cannot be completed (the expert gives up, training fails).
        KeyboardInterrupt: Ctrl-C during the evaluation (its journal keeps the finished episodes).
    """
    from envs.demos.file import save_demos
    from envs.demos.record import collect_demos
    from envs.evaluation.evaluate import evaluate, journal_run
    from envs.rollout.episode import record_from_dict
    from scripts.train import skill_train_config, train_skill

    folder.mkdir(exist_ok=True)
    demos_path, model_dir, eval_path = folder / "demos.npz", folder / "model", folder / "eval.json"
    if not demos_path.exists():
        report(f"seed {demo_seed}: recording {config.num_demos} {config.task.shape} demos")
        collection = collect_demos(config.num_demos, demo_seed, config.task.scene_config(), task=config.task)
        demos = collection.demos
        if config.demo_noise is not None:
            from envs.demos.noise import DemoNoise, add_demo_noise

            demos = add_demo_noise(demos, DemoNoise.parse(config.demo_noise), demo_seed)
            report(f"seed {demo_seed}: demos with noise {config.demo_noise!r}, ends "
                   f"{demos.config['noise']['end_scatter_rms_mm']:.2f} mm / "
                   f"{demos.config['noise']['end_scatter_rms_deg']:.2f} deg root-mean-square from their mean")
        save_demos(demos_path, demos)
    if config.policy is not None:
        return evaluate_replicate_policy(config, folder, demo_seed, start_seed, workers, progress, report)
    if not (model_dir / "skill.json").exists():
        report(f"seed {demo_seed}: training (seed {demo_seed})")
        overrides: dict[str, Any] = {"seed": demo_seed}
        if config.epochs is not None:
            overrides["epochs"] = config.epochs
        train_skill(demos_path, model_dir, skill_train_config(**overrides), progress=progress, overwrite=True,
                    workers=workers)
    if eval_path.exists():
        return outcome_from_records(demo_seed, start_seed, [record_from_dict(r) for r in
                                                            json.loads(eval_path.read_text())["per_episode"]])
    evaluation = dataclasses.replace(config.evaluation, seed=start_seed, workers=workers)
    report(f"seed {demo_seed}: evaluating {evaluation.episodes} episodes (start seed {start_seed})")
    records = run_journaled(folder, journal_run(model_dir, evaluation), evaluation.episodes,
                            lambda journal: evaluate(model_dir, evaluation, progress=progress, journal=journal))
    return outcome_from_records(demo_seed, start_seed, records)


def run_journaled(folder: Path, run_identity: dict[str, Any], episodes: int,
                  run: Callable[[Any], Any]) -> list[Any]:
    """Run one replicate's evaluation ``run(journal)`` against the journal ``folder/eval.json.journal.jsonl`` (resumed
    when it exists, refused when ``run_identity`` differs from the journal's), write ``folder/eval.json`` and return
    its records.

    Raises:
        KeyboardInterrupt: Ctrl-C during the evaluation (the journal keeps what finished).
        EnvError: the evaluation ended incomplete.
    """
    from batch import Journal

    journal_path = folder / "eval.json.journal.jsonl"
    journal = Journal.open(journal_path, run_identity, resume=journal_path.exists())
    try:
        result = run(journal)
    finally:
        journal.close()
    if result.interrupted:
        raise KeyboardInterrupt
    if not result.complete:
        raise EnvError(f"evaluation incomplete: {len(result.records)} of {episodes} episodes")
    result.save_json(folder / "eval.json")
    return list(result.records)


def evaluate_replicate_policy(config: ProtocolConfig, folder: Path, demo_seed: int, start_seed: int, workers: int,
                              progress: bool, report: Callable[[str], None]) -> ReplicateOutcome:
    """The evaluation of one replicate of a --policy protocol: the factory called with the replicate's demo seed and
    demo file (envs.evaluation.benchmark.replicate_policy) in the demos' scene, resumed from its journal.

    Raises:
        PolicyFailure: the policy failed in an episode (the journal keeps what finished).
        KeyboardInterrupt: Ctrl-C during the evaluation.
    """
    from envs.evaluation.benchmark import replicate_policy
    from envs.evaluation.evaluate_policy import demo_metadata, evaluate_policy, policy_journal_run
    from envs.rollout.episode import record_from_dict

    demos_path, eval_path = folder / "demos.npz", folder / "eval.json"
    if eval_path.exists():
        return outcome_from_records(demo_seed, start_seed, [record_from_dict(r) for r in
                                                            json.loads(eval_path.read_text())["per_episode"]])
    spec = replicate_policy(config.policy, demo_seed, str(demos_path.resolve()))
    metadata = demo_metadata(demos_path)
    evaluation = dataclasses.replace(config.evaluation, seed=start_seed, workers=workers)
    report(f"seed {demo_seed}: evaluating --policy {spec.spec} on {evaluation.episodes} episodes (start seed "
           f"{start_seed}; its factory given demo_seed={demo_seed})")
    records = run_journaled(folder, policy_journal_run(spec, metadata, evaluation), evaluation.episodes,
                            lambda journal: evaluate_policy(spec, metadata, evaluation, progress=progress,
                                                            journal=journal))
    return outcome_from_records(demo_seed, start_seed, records)


def main(args: argparse.Namespace) -> int:
    """Run or continue the protocol; print and write its summary."""
    from envs.io.owned_output import write_json
    from envs.media.figures import plot_protocol
    from numerics.errors import NumericsError

    config = protocol_from_args(args)
    record = protocol_record(config)
    prepare_folder(args.out, record)
    outcomes = []
    for demo_seed, start_seed in zip(config.demo_seeds, config.start_seeds()):
        try:
            outcomes.append(run_replicate(config, args.out / f"{REPLICATE_PREFIX}{demo_seed}", demo_seed, start_seed,
                                          args.workers, not args.quiet, lambda line: print(line, flush=True)))
        except (EnvError, NumericsError) as err:  # NumericsError: rflow's RFlowError too
            print(f"seed {demo_seed}: failed -- {err}", flush=True)
            outcomes.append(ReplicateOutcome(demo_seed, start_seed, error=str(err)))
    summary = {"protocol": record, **summarise(outcomes)}
    write_json(args.out / RESULT_FILE, summary)
    title = (f"{config.task.shape}, {len(config.demo_seeds)} demo seeds x {config.evaluation.episodes} episodes")
    plot_protocol(summary, args.out / "benchmark.png", title)
    print()
    print("\n".join(summary_lines(summary)))
    print(f"wrote {args.out / RESULT_FILE} and {args.out / 'benchmark.png'}")
    return 0 if summary["complete"] else 3
