"""`pih run`: the main job on defaults -- demos -> train -> evaluate -> figures and video, in runs/<name>/.

    pih run [--name default] [--episodes 50] [--workers 2] [--overwrite]

The task is the default "contact" preset (envs/task/presets/contact.toml: grasped peg, 0.2 mm clearance, 1 mm chamfers,
seated on the hole floor, hole-pose error up to 1 mm / 1 deg, 40 N force limit) unless --task (a preset or a task
file) or a task option says otherwise; the demo file, the checkpoint and eval.json record it. Writes runs/<name>/:
demos.npz (7 scripted demos, seed 0), model/ (checkpoint with loss.png), eval.json (closed-loop evaluation, 50
perturbed starts), skill.png (demos / generated / executed, as the paper's peg-in-hole figure), outcomes.png (outcomes by reason over the hole-pose error and where each episode
ended), forces.png (wrist force of the video's episodes, with the limit), episodes.mp4 (three successes and the first
failure, if any) and summary.json (timings and the success rate). Prints a summary. Running it again on the
same folder needs --overwrite, and replaces only what an earlier `pih run` wrote (envs/io/owned_output.py).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

from envs.errors import EnvError
from envs.io.owned_output import MiB, check_output, check_output_folder, write_json
from scripts.options import (DEFAULT_WORKERS, MAX_DEMOS, MAX_EPISODES, MAX_EPOCHS, MAX_SAMPLES, MAX_WORKERS, count, seed,
                             work_begins)
from scripts.task_options import add_start_arguments, add_task_arguments, task_from_args

RUN_OUTPUTS = ("demos.npz", "model", "eval.json", "skill.png", "outcomes.png", "forces.png", "episodes.mp4",
               "summary.json")
"""What `pih run` writes into runs/<name>/ (an earlier run's are replaced only with --overwrite,
envs/io/owned_output.py)."""
RUN_BYTES = 200 * MiB
"""Generous size of a run folder (a checkpoint, the demos, the record and a video of four episodes)."""


EXAMPLES: tuple[str, ...] = ('pih run',
                             'pih run --name realistic --task realistic --overwrite')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih run`, in groups: output, demos, training, evaluation, task."""
    from scripts.train import DEFAULT_SUBSAMPLE

    out = parser.add_argument_group("output")
    out.add_argument("--name", default="default", help="run folder under --root")
    out.add_argument("--root", type=Path, default=Path("runs"), help="parent folder of runs")
    out.add_argument("--overwrite", action="store_true",
                     help="replace the outputs of an earlier `pih run` in the run folder (never a file pih did not write)")
    out.add_argument("--no-video", action="store_true", help="skip the MP4")
    demos = parser.add_argument_group("demos")
    demos.add_argument("--demos", type=count(MAX_DEMOS), default=7,
                       help=f"scripted demos to record, 1..{MAX_DEMOS:,} (default 7, as the paper)")
    demos.add_argument("--demo-seed", type=seed, default=0, help="seed of the demo starts, 0..2**32-1")
    training = parser.add_argument_group("training")
    training.add_argument("--epochs", type=count(MAX_EPOCHS), default=None, help="training epochs (default: `pih train`'s)")
    training.add_argument("--subsample", type=count(MAX_SAMPLES), default=DEFAULT_SUBSAMPLE,
                          help="keep every k-th demo sample")
    evaluation = parser.add_argument_group("evaluation")
    evaluation.add_argument("--episodes", type=count(MAX_EPISODES), default=50,
                            help=f"evaluation episodes, 1..{MAX_EPISODES:,}")
    evaluation.add_argument("--seed", type=seed, default=0, help="seed of the evaluation starts, 0..2**32-1")
    evaluation.add_argument("--workers", type=count(MAX_WORKERS), default=DEFAULT_WORKERS,
                            help="training and evaluation processes")
    add_start_arguments(evaluation)
    add_task_arguments(parser)


def check_run_folder(out: Path, overwrite: bool, video: bool) -> None:
    """runs/<name> may be written: the folder (envs.io.owned_output.check_output_folder) and each output `pih run`
    writes that is there already (an earlier run's, replaced only with ``overwrite``; never anything else).
    Other files in the folder are left alone.

    Raises:
        EnvError: naming the output and the problem.
    """
    if check_output_folder("run folder", out, estimate_bytes=RUN_BYTES):
        return
    for name in RUN_OUTPUTS:
        if name != "episodes.mp4" or video:
            check_output("run output", out / name, overwrite, folder=name == "model")


def _step(name: str) -> None:
    print(f"== {name}", flush=True)


def main(args: argparse.Namespace) -> int:
    """Run the whole job; returns the exit status."""
    from tqdm import tqdm

    from envs.demos.file import save_demos
    from envs.demos.record import collect_demos
    from envs.evaluation.evaluate import EvaluationConfig, evaluate
    from envs.media.figures import plot_outcomes
    from envs.policies.expert_plan import ExpertConfig
    from scripts.evaluate import choose_episodes, render_and_plot
    from scripts.train import skill_train_config, train_skill

    if not args.name or "/" in args.name or args.name in (".", ".."):
        raise EnvError(f"--name {args.name!r} must be a plain folder name")
    task = task_from_args(args)
    task = task.override(shape=task.shape or "square")
    config = EvaluationConfig(episodes=args.episodes, seed=args.seed, workers=args.workers, task=task)  # checked first
    samples = ExpertConfig().num_samples  # what each recorded demo holds
    if (samples - 1) // args.subsample + 1 < 2:
        raise EnvError(f"--subsample {args.subsample}: the demos' {samples} samples would leave fewer than 2; "
                       f"at most {samples - 1}")
    out = args.root / args.name
    check_run_folder(out, args.overwrite, video=not args.no_video)
    work_begins()
    out.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    wall = time.perf_counter()

    _step(f"1/4 recording {args.demos} scripted demonstrations (seed {args.demo_seed})")
    t0 = time.perf_counter()
    with tqdm(total=args.demos, desc="demos", unit="demo") as bar:
        def on_attempt(_index: int, attempt: Any) -> None:
            if attempt.ok:
                bar.update(1)
            else:
                tqdm.write(f"  failed attempt: {attempt.reason}")

        collection = collect_demos(args.demos, args.demo_seed, task.scene_config(), on_attempt=on_attempt,
                                   task=task)
    demo_path = save_demos(out / "demos.npz", collection.demos)
    timings["demos_s"] = time.perf_counter() - t0

    _step("2/4 training the position and orientation models")
    t0 = time.perf_counter()
    overrides = {} if args.epochs is None else {"epochs": args.epochs}
    model_dir = train_skill(demo_path, out / "model", skill_train_config(**overrides), subsample=args.subsample,
                            overwrite=args.overwrite, workers=args.workers)
    timings["train_s"] = time.perf_counter() - t0

    _step(f"3/4 evaluating {args.episodes} perturbed starts (closed loop, {args.workers} workers)")
    t0 = time.perf_counter()
    result = evaluate(model_dir, config)
    result.save_json(out / "eval.json")
    timings["evaluate_s"] = time.perf_counter() - t0
    if result.interrupted or not result.complete:
        print(f"pih run: evaluation {'interrupted' if result.interrupted else 'incomplete'} after "
              f"{len(result.records)} of {config.episodes} episodes (see {out / 'eval.json'})")
        return 130 if result.interrupted else 3

    _step("4/4 figures and video")
    t0 = time.perf_counter()
    figure_episodes = choose_episodes(result, "auto", failures=0)  # the figure shows successes, video and forces also a failure
    extras = render_and_plot(model_dir, config, result, choose_episodes(result, "auto"),
                             None if args.no_video else out / "episodes.mp4", out / "skill.png",
                             figure_episodes=figure_episodes, force_figure=out / "forces.png")
    plot_outcomes([r.to_dict() for r in result.records], out / "outcomes.png",
                  f"{result.num_success}/{len(result.records)} inserted")
    timings["figures_video_s"] = time.perf_counter() - t0
    timings["total_s"] = time.perf_counter() - wall

    low, high = result.interval
    summary = {"name": args.name, "demos": str(demo_path), "model": str(model_dir),
               "success_rate": result.success_rate, "success_rate_ci95": [low, high],
               "episodes": len(result.records), "timings": timings, "video": extras["video"],
               "figure": extras["figure"], "load_average_1min": os.getloadavg()[0]}
    write_json(out / "summary.json", summary)
    print()
    print(result.summary_table())
    print(f"{'files':<30}  {out}/ (demos.npz, model/, eval.json, skill.png, outcomes.png, forces.png"
          f"{', episodes.mp4' if extras['video'] else ''}, summary.json)")
    print("timings (s)".ljust(30) + "  " + ", ".join(f"{k[:-2]} {v:.0f}" for k, v in timings.items()))
    return 0

