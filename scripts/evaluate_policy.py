"""The `--policy` options of `pih evaluate`: score any policy in the demos' scene (envs/evaluation/evaluate_policy.py).

    pih evaluate --policy mypkg.mymodule:make --demos demos.npz [--policy-option dataset=ds/] [--privileged] ...

The factory is imported from the current folder first (as `python -m` does) and called as
``factory(task, **options)`` (the options as strings), in the supervised worker processes only (pih's own process
only finds the module's file): a spec without ':' or a module that is not found ends `pih evaluate` with one line
and exit status 2 before any work; a module that fails to import, a missing attribute or one that is not callable,
and a factory that fails or returns no Policy end it with one line and exit status 2 before any episode; a factory
that takes its worker down or hangs (past --start-timeout-s) is an infrastructure fault: one line, exit status 1
(envs/evaluation/evaluate_policy.py).

Errors in the policy: its traceback on stderr, exit status 4 (EXIT_POLICY_ERROR) and no success rate written; with
--keep-going such episodes are recorded as "policy_error", not scored, the rest run, and the exit status is still 4.
Video and figures are drawn from the episodes as they were recorded while they ran (envs/evaluation/recording.py),
never from a second run of the policy.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from envs.errors import EnvError
from envs.evaluation.config import EvaluationConfig
from envs.policies.skill_settings import DEFAULT_LOOKAHEAD_S

if TYPE_CHECKING:  # the simulator loads when the command runs, never for --help
    from envs.evaluation.evaluate_policy import PolicySpec

SKILL_ONLY: tuple[str, ...] = ("--mode", "--lookahead-s", "--speed", "--stiffness", "--no-contact-adaptation",
                               "--adaptation-off", "--model")
"""Options of `pih evaluate` that act on the RiemannianFlow skill only, refused with --policy."""
EXIT_POLICY_ERROR = 4
"""The exit status of a run in which the user's policy failed (it raised, or returned an action that cannot be
commanded): without --keep-going at the first such episode, with it after the whole run."""


def add_policy_arguments(parser: argparse.ArgumentParser) -> None:
    """The "policy" option group of `pih evaluate`."""
    group = parser.add_argument_group("policy (instead of --model; docs/policy.md)")
    group.add_argument("--policy", metavar="MODULE:FACTORY", help="factory(task, **options) -> Policy")
    group.add_argument("--demos", type=Path, metavar="FILE.npz", help="the demos whose scene and starts to run")
    group.add_argument("--policy-option", action="append", default=[], metavar="KEY=VALUE",
                       help="a string for the factory; repeatable")
    group.add_argument("--privileged", action="store_true", help="observations carry the true hole (a teacher)")
    group.add_argument("--keep-going", action="store_true",
                       help="record policy errors (not scored), run on")


def policy_spec(args: argparse.Namespace) -> PolicySpec:
    """The PolicySpec of the parsed options (the current folder as the import's search path).

    Raises:
        EnvError: a malformed spec or option.
    """
    from envs.evaluation.evaluate_policy import PolicySpec, parse_policy_options

    return PolicySpec(args.policy, parse_policy_options(args.policy_option), bool(args.privileged), os.getcwd())


def check_policy_args(args: argparse.Namespace) -> None:
    """The rules of --policy, before any work: --demos given and readable, no skill-only option, a spec whose module is
    found (without importing it: it is imported, and its factory called, in the supervised workers).

    Raises:
        EnvError: naming the offending option.
    """
    from envs.evaluation.evaluate_policy import demo_metadata, policy_files

    d = EvaluationConfig()
    given = {"--mode": args.mode != d.mode, "--lookahead-s": args.lookahead_s != DEFAULT_LOOKAHEAD_S,
             "--speed": args.speed != d.speed, "--stiffness": args.stiffness is not None,
             "--no-contact-adaptation": args.no_contact_adaptation,
             "--adaptation-off": getattr(args, "adaptation_off", None) is not None, "--model": args.model is not None}
    refused = [option for option in SKILL_ONLY if given[option]]
    if refused:
        raise EnvError(f"{', '.join(refused)}: not with --policy (they act on the RiemannianFlow skill of --model)")
    if args.demos is None:
        raise EnvError("--policy needs --demos FILE: the demo file whose scene and start poses the episodes use")
    demo_metadata(args.demos)  # readable and valid
    policy_files(policy_spec(args))


def report_policy_failure(command: str, failure: Any, after: str = "") -> int:
    """Print a `PolicyFailure` as a user's traceback is printed -- the policy's traceback, then one line saying what
    stopped and why -- and return EXIT_POLICY_ERROR."""
    print(failure.traceback.rstrip("\n"), file=sys.stderr)
    print(f"pih {command}: error: {failure}{after}", file=sys.stderr)
    return EXIT_POLICY_ERROR


def policy_media(args: argparse.Namespace, config: EvaluationConfig, result: Any, recording: Path,
                 video_episodes: Sequence[int], figure_episodes: Sequence[int]) -> dict[str, Any]:
    """--video, --figure, --stiffness-figure and --force-figure of a policy's evaluation, drawn from its recorded
    episodes (envs.evaluation.recording): the video plays the chosen episodes back (the commanded tcp path drawn),
    the figure shows the demos, the commanded and the executed poses, the stiffness figure the commanded stiffness
    (beside the demos' when the demo file records one), the force figure the wrist force.

    Returns:
        {"video", "figure", "stiffness_figure", "force_figure": path or None} for the summary.
    """
    import math

    import numpy as np

    from envs.demos.file import load_demos
    from envs.evaluation.evaluate import build_env
    from envs.evaluation.recording import check_episode, episode_file, load_episode, play
    from envs.evaluation.starts import evaluation_starts, metadata_starts
    from envs.media.figures import PoseCurve, StiffnessCurve, plot_force_traces, plot_skill, plot_stiffness
    from envs.poses import Pose
    from rflow.skill_io import POSE

    out: dict[str, Any] = {"video": None, "figure": None, "stiffness_figure": None, "force_figure": None}
    metadata = result.metadata
    starts = {s.index: s for s in evaluation_starts(metadata_starts(metadata, f"--demos {args.demos}"), config)}
    by_index = {r.index: r for r in result.records}
    episodes: dict[int, tuple[Any, Any]] = {}
    for index in sorted(set(video_episodes) | set(figure_episodes)):
        if index not in by_index or by_index[index].steps == 0:
            continue
        kept, trace = load_episode(episode_file(recording, index))
        check_episode(kept, by_index[index].to_dict(), trace, f"--record-episodes {recording}")
        episodes[index] = (by_index[index], trace)
    shown = [i for i in video_episodes if i in episodes]
    if args.video is not None and shown:
        from envs.media.video import EpisodeVideo, VideoConfig, episode_overlay

        goal = Pose(pos=metadata["goal_pos"], quat=metadata["goal_quat"])
        env = build_env(metadata, goal, config)
        video = EpisodeVideo(env.model, args.video, VideoConfig(camera=args.camera), goal=env.goal)
        try:
            for index in shown:
                record, trace = episodes[index]
                outcome = "success" if record.success else (record.failure or "failed")
                video.new_episode()
                video.set_commanded_path(trace.cmd_pos)
                play(env, starts[index], trace, lambda view: video.capture(
                    view.data, view.observation.time_s, text=lambda: episode_overlay(
                        f"episode {index}", outcome, view.observation.time_s,
                        math.hypot(*view.observation.wrist_wrench[:3]))))
        except BaseException:
            video.abort()
            raise
        out["video"] = str(video.close())
    if args.force_figure is not None and shown:
        traces = [(f"episode {i}: {episodes[i][0].reason.split(' (')[0]}", episodes[i][0].success,
                   episodes[i][1].times_s, np.sqrt((episodes[i][1].wrist_wrench[:, :3] ** 2).sum(axis=1)))
                  for i in shown]
        out["force_figure"] = str(plot_force_traces(traces, config.task.force_limit_n, args.force_figure,
                                                    "wrist force of the chosen episodes"))
    chosen = [i for i in figure_episodes if i in episodes]
    if not chosen:
        return out
    demos = load_demos(args.demos)
    goal7 = np.concatenate([demos.goal_pos, demos.goal_quat])

    def curve(times: Any, pos: Any, quat: Any) -> PoseCurve:
        tangent = np.asarray(POSE.log(np.concatenate([pos, quat], axis=-1), goal7))
        return PoseCurve(np.asarray(times), np.asarray(pos), tangent[:, 3:])

    title = f"--policy {args.policy}: episodes {chosen}"
    if args.figure is not None:
        demo_times = demos.dt * np.arange(demos.num_samples)
        shown_demos = [curve(demo_times, demos.pos[n], demos.quat[n]) for n in range(demos.num_demos)]
        commanded = [curve(t.times_s, t.cmd_pos, t.cmd_quat) for _, t in (episodes[i] for i in chosen)]
        executed = [curve(t.times_s, t.pos, t.quat) for _, t in (episodes[i] for i in chosen)]
        out["figure"] = str(plot_skill(shown_demos, commanded, executed, demos.goal_pos, args.figure, title,
                                       plan_label="commanded"))
    if args.stiffness_figure is not None:
        demo_k = [] if demos.stiffness is None else [StiffnessCurve(demos.dt * np.arange(demos.num_samples),
                                                                    demos.stiffness[n])
                                                     for n in range(demos.num_demos)]
        executed_k = [StiffnessCurve(t.times_s, t.stiffness) for _, t in (episodes[i] for i in chosen)]
        out["stiffness_figure"] = str(plot_stiffness(demo_k, executed_k, args.stiffness_figure, title))
    return out
