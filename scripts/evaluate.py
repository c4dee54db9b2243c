"""`pih evaluate`: execute a trained skill, or any policy, from seeded perturbed starts in physics and score it.

    pih evaluate --model runs/default/model --episodes 100 --seed 0 --json runs/eval.json \\
        [--mode closed-loop|open-loop] [--workers 2] [--video runs/eval.mp4] [--figure runs/eval.png] \\
        [--stiffness learned|constant:K] [--stiffness-figure runs/stiffness.png]
    pih evaluate --policy mypkg.mymodule:make --demos demos.npz [--policy-option KEY=VALUE ...] [--privileged] \\
        --episodes 100 --seed 0 --json runs/mine.json

--policy scores a user policy (envs/policies/interface.py; the factory is called as
factory(task, **options), envs/evaluation/evaluate_policy.py) in the demos' scene, from the starts and
perturbations the skill trained on those demos meets, with the same success check (scripts/evaluate_policy.py).

Starts: the mean demo start (or, with --around demo, a random demo's start) perturbed by +-pos-range-mm (box)
and +-rot-range-deg (ball) -- see envs/evaluation/starts.py. Success is the physics check on the measured
peg_tip pose. Prints a summary table.

Long runs: each finished episode is appended to a journal (--journal, default <json>.journal.jsonl), so
after Ctrl-C (exit 130) the same command with --resume runs only the missing episodes and writes the same
JSON. The default journal is removed once the run is complete (its JSON holds every record); one named with
--journal is kept. An episode over --unit-timeout-s is a failed episode ("wall_timeout"). An episode whose worker dies runs
again on another one; only when all its tries are lost is it an infrastructure error: not scored, listed
apart, and run again by --resume. Infrastructure events go to stderr and the JSON. Exit status: 0 when every
episode has a record (failed episodes are results), 3 when the batch is incomplete (infrastructure errors),
1 when a fault stopped it (the Ray head lost), 130 when interrupted, 2 on bad input (all options and
outputs are checked before any episode, envs/io/owned_output.py), 1 also on an operating-system error while writing,
4 when a --policy failed (it raised, or returned an action that cannot be commanded): its traceback on stderr, and
without --keep-going nothing but the journal written.

--record-episodes DIR keeps every episode's per-step trace as it runs (envs/evaluation/recording.py): `pih export
--episodes` exports such an evaluation from it, and a policy's --video and figures are drawn from it (from a temporary
recording when no DIR is given).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import shlex
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from batch import BACKENDS, describe_event  # noqa: E402
from envs.errors import EnvError  # noqa: E402
from envs.evaluation.config import MAX_LOCKSTEP, EvaluationConfig  # noqa: E402
from envs.io.owned_output import MiB, check_distinct, check_output  # noqa: E402
from envs.policies.skill_settings import DEFAULT_LOOKAHEAD_S, MODES  # noqa: E402
from pihutil.bounds import FEEDFORWARD_GAIN, LOOKAHEAD_S, SPEED, TIMEOUT_S  # noqa: E402
from envs.errors import PolicyFailure  # noqa: E402
from scripts.evaluate_policy import (add_policy_arguments, check_policy_args, policy_media, policy_spec,  # noqa: E402
                                     report_policy_failure)
from scripts.options import (CAMERA_NAMES, DEFAULT_WORKERS, MAX_EPISODES, MAX_WORKERS,  # noqa: E402
                             check_camera, count, number, refuse_unused, seed, work_begins)
from scripts.task_options import add_start_arguments, add_task_arguments, scene_from_task, task_from_args  # noqa: E402

if TYPE_CHECKING:  # the simulator and torch load in main(), never for --help
    from envs.evaluation.evaluate import StartPose
    from envs.evaluation.result import EvaluationResult

GOAL_MISMATCH_WARN_MM = 5.0
EXIT_FAULT = 1
EXIT_INCOMPLETE = 3
EXIT_INTERRUPTED = 130
RECORD_BYTES = 8 * 1024
"""Generous size of one episode in the JSON record or the journal (a record is ~2 KB)."""
VIDEO_EPISODE_BYTES = 20 * MiB
"""Generous size of one rendered episode (640x480 H.264, up to the 20 s time limit)."""
FIGURE_BYTES = 4 * MiB


USAGE = "pih evaluate (--model DIR | --policy MODULE:FACTORY --demos FILE.npz) [options]"
"""The usage line of --help (scripts.cli): one of the two sources, then the options."""
EXAMPLES: tuple[str, ...] = ('pih evaluate --model model/ --episodes 100 --json eval.json --video eval.mp4',
                             'pih evaluate --policy mymodule:make --demos demos.npz --json mine.json')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih evaluate`, in groups: skill, starts and run, output, task."""
    d = EvaluationConfig()
    skill = parser.add_argument_group("skill")
    skill.add_argument("--model", type=Path, metavar="DIR", help="a `pih train` checkpoint (or --policy)")
    add_policy_arguments(parser)
    run = parser.add_argument_group("starts and run")
    run.add_argument("--episodes", type=count(MAX_EPISODES), default=d.episodes, metavar="N",
                     help=f"perturbed starts, 1..{MAX_EPISODES:,}")
    run.add_argument("--journal", type=Path, metavar="FILE",
                     help="journal of finished episodes (default <json>.journal.jsonl, removed once complete)")
    run.add_argument("--resume", action="store_true", help="run only the episodes --journal lacks")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    out = parser.add_argument_group("output")
    out.add_argument("--json", type=Path, metavar="FILE", help="the record: config, task, rate, every episode")
    out.add_argument("--video", type=Path, metavar="FILE.mp4", help="video of the chosen episodes")
    out.add_argument("--video-episodes", default="auto", metavar="I,J|auto",
                     help="episodes of --video and figures; auto: 3 successes, 1 failure")
    out.add_argument("--camera", default="front", metavar="NAME", help=f"camera of --video: {CAMERA_NAMES}")
    out.add_argument("--figure", type=Path, metavar="PNG", help="demos, generated and executed poses")
    out.add_argument("--stiffness-figure", type=Path, metavar="PNG", help="commanded stiffness against time")
    out.add_argument("--force-figure", type=Path, metavar="PNG", help="wrist force against time, with the limit")
    out.add_argument("--record-episodes", type=Path, metavar="DIR",
                     help="each episode's per-step trace, for `pih export`")
    out.add_argument("--overwrite", action="store_true", help="replace outputs an earlier pih run wrote")
    add_evaluation_options(parser, skill, run)


def add_evaluation_options(parser: argparse.ArgumentParser, skill: Any = None, run: Any = None) -> None:
    """The options `config_from_args` reads, all but --episodes, into the groups ``skill`` and ``run`` (new groups
    when None) and the task group (shared with `pih compare --sequential`)."""
    d = EvaluationConfig()
    skill = parser.add_argument_group("skill") if skill is None else skill
    run = parser.add_argument_group("starts and run") if run is None else run
    skill.add_argument("--mode", choices=MODES, default=d.mode,
                       help="query the flow at the measured pose every 10 ms, or track its trajectory")
    skill.add_argument("--lookahead-s", type=number(bound=LOOKAHEAD_S), default=DEFAULT_LOOKAHEAD_S, metavar="S",
                       help="closed loop: flow time ahead of the measured pose")
    skill.add_argument("--feedforward", type=number(bound=FEEDFORWARD_GAIN), default=d.feedforward_gain,
                       metavar="GAIN", help="velocity feed-forward, 0 = off")
    skill.add_argument("--speed", type=number(bound=SPEED), default=d.speed, metavar="X",
                       help="time scaling of the learned flow")
    skill.add_argument("--stiffness", metavar="SPEC",
                       help="learned, constant:K (N/m) or schedule[:FREE/LATERAL/AXIAL] (default: the "
                            "controller's)")
    add_adaptation_options(skill)
    run.add_argument("--seed", type=seed, default=d.seed, metavar="S", help="seed of the starts, 0..2**32-1")
    add_start_arguments(run)  # the task's start range and time limit
    run.add_argument("--workers", type=count(MAX_WORKERS), default=DEFAULT_WORKERS, metavar="N",
                     help="worker processes")
    run.add_argument("--lockstep", type=count(MAX_LOCKSTEP), default=d.lockstep, metavar="K",
                     help="episodes a worker runs side by side (records alike)")
    run.add_argument("--backend", choices=BACKENDS, default=d.backend, help="local processes or Ray actors")
    run.add_argument("--ray-address", metavar="HOST:PORT", help="a Ray cluster's head (default: a local Ray)")
    run.add_argument("--unit-timeout-s", type=number(minimum=0.0, maximum=TIMEOUT_S.high), default=d.unit_timeout_s,
                     metavar="S", help="wall time per episode, 0 = no limit")
    run.add_argument("--start-timeout-s", type=number(bound=TIMEOUT_S), default=d.start_timeout_s, metavar="S",
                     help="wall time a worker may take to start (with --policy: import it, call its factory)")
    task = add_task_arguments(parser)
    task.add_argument("--shape", help="peg/hole shape (default: the task's, else the demos')")
    task.add_argument("--hole-at-goal", action="store_true", help="the hole at the demos' goal (foreign demos)")


def add_adaptation_options(skill: Any) -> None:
    """--no-contact-adaptation or --adaptation-off (not both) and --follow-observed-hole, into ``skill`` (a group of
    `pih evaluate`, `pih compare --sequential` and `pih benchmark`)."""
    ablation = skill.add_mutually_exclusive_group()  # all parts off, or some: not both
    ablation.add_argument("--no-contact-adaptation", action="store_true",
                          help="the bare learned flow (the ablation)")
    ablation.add_argument("--adaptation-off", metavar="PARTS",
                          help="parts off: push,frame,compliance,search,seat")
    skill.add_argument("--follow-observed-hole", action="store_true",
                       help="run in the frame of the hole the cell observes")


def adaptation_parts(text: str | None) -> tuple[str, ...]:
    """The parts of --adaptation-off ("push,frame"), checked by `envs.policies.adaptation.adaptation_parts`.

    Raises:
        EnvError: an unknown or repeated part (one line naming the option).
    """
    from envs.policies.adaptation import adaptation_parts as checked

    if text is None:
        return ()
    try:
        return checked(part.strip() for part in text.split(","))
    except EnvError as err:
        raise EnvError(f"--adaptation-off {text!r}: {err}") from None


def config_from_args(args: argparse.Namespace) -> EvaluationConfig:
    """EvaluationConfig of the parsed options (validated there): the task of --task and the single task options,
    the scene the demos' but for the scene options given (all of them with --task or --preset)."""
    return EvaluationConfig(
        episodes=args.episodes, seed=args.seed, mode=args.mode, lookahead_s=args.lookahead_s,
        feedforward_gain=args.feedforward, speed=args.speed, task=task_from_args(args),
        scene_from_task=scene_from_task(args), hole_at_goal=args.hole_at_goal, workers=args.workers,
        unit_timeout_s=None if args.unit_timeout_s == 0 else args.unit_timeout_s,
        start_timeout_s=args.start_timeout_s, backend=args.backend,
        ray_address=args.ray_address, stiffness=args.stiffness,
        contact_adaptation=not args.no_contact_adaptation,
        adaptation_off=adaptation_parts(getattr(args, "adaptation_off", None)),
        lockstep=args.lockstep, follow_observed_hole=getattr(args, "follow_observed_hole", False))


def checked_config(args: argparse.Namespace) -> EvaluationConfig:
    """`config_from_args` after the checks of the options it does not validate itself.

    Raises:
        EnvError: naming the offending option.
    """
    if args.ray_address is not None and args.backend != "ray":
        raise EnvError("--ray-address needs --backend ray")
    return config_from_args(args)


def journal_path(args: argparse.Namespace) -> Path | None:
    """--journal, or <json>.journal.jsonl beside --json, or None."""
    if args.journal is not None:
        return args.journal
    return args.json.with_name(args.json.name + ".journal.jsonl") if args.json is not None else None


def check_video_episodes(spec: str, episodes: int) -> None:
    """--video-episodes is 'auto' or indices within the evaluation. Raises EnvError."""
    if spec == "auto":
        return
    try:
        chosen = [int(x) for x in spec.split(",") if x.strip()]
    except ValueError:
        raise EnvError(f"--video-episodes {spec!r} must be 'auto' or comma-separated integers") from None
    bad = [i for i in chosen if not 0 <= i < episodes]
    if bad or not chosen:
        raise EnvError(f"--video-episodes {spec!r}: indices must lie in 0..{episodes - 1}")


def load_preview(model_dir: Path) -> dict[str, Any] | None:
    """The checkpoint's demos.npz (pos, quat, dt and, for a stiffness skill, stiffness) for the figures, or None
    when there is none; read without unpickling.

    Raises:
        EnvError: the file is not a readable archive of numeric arrays of the documented shapes.
    """
    import zipfile

    import numpy as np

    from envs.io.npz import open_npz

    path = model_dir / "demos.npz"
    if not path.is_file():
        return None
    try:
        with open_npz(path) as data:
            arrays = {key: np.asarray(data[key], dtype=np.float64) for key in ("pos", "quat", "dt", "stiffness")
                      if key in data.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as err:
        raise EnvError(f"{path}: not a readable demo preview ({type(err).__name__}: {err})") from None
    pos, quat = arrays.get("pos"), arrays.get("quat")
    if (pos is None or quat is None or pos.ndim != 3 or pos.shape[2] != 3 or quat.shape != pos.shape[:2] + (4,)
            or arrays.get("dt", np.zeros(1)).shape != () or not all(np.all(np.isfinite(a)) for a in arrays.values())):
        raise EnvError(f"{path}: a demo preview needs finite pos (N, M, 3), quat (N, M, 4) and a scalar dt")
    k = arrays.get("stiffness")
    if k is not None and k.shape != pos.shape[:2] + (3, 3):
        raise EnvError(f"{path}: 'stiffness' must have shape {pos.shape[:2] + (3, 3)}, got {k.shape}")
    return arrays


def check_args(args: argparse.Namespace) -> EvaluationConfig:
    """Every option, before any work: the config, the outputs (envs.io.owned_output.check_output), the journal, the
    video and figure options and the checkpoint's demo preview the figures read.

    Raises:
        EnvError: naming the offending option.
    """
    config = checked_config(args)
    if args.policy is not None:
        check_policy_args(args)
        inputs = [args.demos]
    else:
        if args.model is None:
            raise EnvError("give --model DIR (a `pih train` checkpoint) or --policy MODULE:FACTORY with --demos FILE")
        given = [o for o, v in (("--demos", args.demos), ("--privileged", args.privileged),
                                ("--policy-option", args.policy_option), ("--keep-going", args.keep_going)) if v]
        if given:
            raise EnvError(f"{', '.join(given)}: only with --policy (not with --model)")
        inputs = [args.model]
    if args.model is not None and not args.model.is_dir():
        raise EnvError(f"--model {args.model}: checkpoint folder not found")
    if config.stiffness == "learned":
        from rflow.skill_io import load_skill

        if not load_skill(args.model).has_stiffness:
            raise EnvError(f"--stiffness learned: {args.model} has no stiffness model (train it with `pih train "
                           "--stiffness expert|variability`)")
    if args.resume and args.overwrite:
        raise EnvError("--resume continues an earlier run and --overwrite replaces it: choose one")
    journal = journal_path(args)
    if args.resume and journal is None:
        raise EnvError("--resume needs the journal of the earlier run: give --journal or --json")
    shown = 4 if args.video_episodes == "auto" else len(args.video_episodes.split(","))
    records = 64 * 1024 + RECORD_BYTES * config.episodes
    outputs = {"--json": args.json, "--video": args.video, "--figure": args.figure,
               "--stiffness-figure": args.stiffness_figure, "--force-figure": args.force_figure, "--journal": journal}
    check_distinct(outputs)
    check_output("--json", args.json, args.overwrite or args.resume, suffix=".json", inputs=inputs,
                 estimate_bytes=records)
    check_output("--video", args.video, args.overwrite, suffix=".mp4", inputs=inputs,
                 estimate_bytes=VIDEO_EPISODE_BYTES * shown)
    for option in ("--figure", "--stiffness-figure", "--force-figure"):
        check_output(option, outputs[option], args.overwrite, suffix=".png", inputs=inputs,
                     estimate_bytes=FIGURE_BYTES)
    if journal is not None:
        if args.resume and not journal.is_file():
            raise EnvError(f"--resume: journal {journal} does not exist")
        if journal.exists() and not (args.resume or args.overwrite):
            raise EnvError(f"journal {journal} already exists: use --resume to continue that run, "
                           "--overwrite to start again, or another --journal")
        check_output("--journal", journal, args.overwrite or args.resume, suffix=".jsonl", inputs=inputs,
                     estimate_bytes=records)
    if any(p is not None for p in (args.video, args.figure, args.stiffness_figure, args.force_figure)):
        check_video_episodes(args.video_episodes, config.episodes)
    else:
        refuse_unused(args, add_arguments, ["video_episodes"],
                      "applies to --video, --figure, --stiffness-figure and --force-figure only")
    if args.video is None:
        refuse_unused(args, add_arguments, ["camera"], "applies to --video only")
    if (args.figure is not None or args.stiffness_figure is not None) and args.model is not None:
        load_preview(args.model)
    if args.record_episodes is not None:
        from envs.evaluation.recording import EPISODE_BYTES, check_recording
        from envs.io.owned_output import check_output_folder

        check_output_folder("--record-episodes", args.record_episodes, inputs=inputs,
                            estimate_bytes=EPISODE_BYTES * config.episodes)
        check_distinct({**outputs, "--record-episodes": args.record_episodes})
        check_recording(args.record_episodes, args.overwrite, args.resume)
    if args.video is not None:
        check_camera(args.camera)
    return config


def media_recording(args: argparse.Namespace, temporary: contextlib.ExitStack) -> tuple[Path | None, list[int] | None]:
    """Where a run records its episodes and which (None: all): --record-episodes, else for a policy's video or
    figures a temporary folder (removed when ``temporary`` closes) with the chosen episodes only when they are
    named; (None, None) when nothing is recorded."""
    if args.record_episodes is not None:
        return args.record_episodes, None
    wanted = args.policy is not None and any(p is not None for p in (args.video, args.figure, args.stiffness_figure,
                                                                        args.force_figure))
    if not wanted:
        return None, None
    import tempfile

    only = None if args.video_episodes == "auto" else [int(x) for x in args.video_episodes.split(",") if x.strip()]
    return Path(temporary.enter_context(tempfile.TemporaryDirectory(prefix="pih-recording-"))), only


def run_evaluation(args: argparse.Namespace, config: EvaluationConfig,
                   recording: tuple[Path | None, list[int] | None] = (None, None)) -> EvaluationResult:
    """`evaluate` with the run's journal (opened here; a new journal with no episode in it is removed again
    when the evaluation fails before its first episode, so a bad input leaves nothing behind) and its recording
    (``recording``: the folder and the episodes to record, `media_recording`)."""
    from batch import Journal
    from envs.evaluation.evaluate import evaluate, journal_run

    folder, only = recording
    if args.policy is not None:
        from envs.evaluation.evaluate_policy import demo_metadata, evaluate_policy, policy_journal_run

        spec, metadata = policy_spec(args), demo_metadata(args.demos)
        run = policy_journal_run(spec, metadata, config)

        def evaluate_it(journal: Journal | None = None) -> EvaluationResult:
            return evaluate_policy(spec, metadata, config, progress=not args.quiet, journal=journal,
                                   keep_going=args.keep_going, record_dir=folder, record_only=only)
    else:
        run = journal_run(args.model, config)

        def evaluate_it(journal: Journal | None = None) -> EvaluationResult:
            return evaluate(args.model, config, progress=not args.quiet, journal=journal, record_dir=folder)
    if args.record_episodes is not None:
        from envs.evaluation.recording import prepare_recording

        new = not args.record_episodes.exists()
        prepare_recording(args.record_episodes, args.overwrite, args.resume, run)
        plain = evaluate_it

        def evaluate_it(journal: Journal | None = None) -> EvaluationResult:
            try:
                return plain(journal)
            except BaseException:  # a new recording with no episode in it must not block a plain rerun either
                if new and not any(args.record_episodes.glob("episode-*.npz")):
                    import shutil

                    shutil.rmtree(args.record_episodes, ignore_errors=True)
                raise
    path = journal_path(args)
    if path is None:
        return evaluate_it()
    journal = Journal.open(path, run, resume=args.resume, overwrite=args.overwrite)
    try:
        result = evaluate_it(journal)
    except BaseException:
        journal.close()
        if not args.resume and not journal.done():
            path.unlink(missing_ok=True)
        raise
    finally:
        journal.close()
    if not args.resume and not journal.done():  # nothing to continue: it must not block a plain rerun
        path.unlink(missing_ok=True)
    return result


def fault_text(args: argparse.Namespace, result: EvaluationResult) -> str:
    """The fault that stopped the batch, for its one line; a policy that no worker could start is named."""
    if args.policy is not None and result.workers == 0:
        return f"--policy {args.policy}: no worker could start the policy ({result.fault})"
    return str(result.fault)


def continue_text(args: argparse.Namespace, result: EvaluationResult) -> str:
    """"; N of M episodes finished (in JOURNAL); continue with: COMMAND" when there is a journal to continue."""
    path = journal_path(args)
    if path is None or not path.is_file():
        return ""
    return (f"; {len(result.records)} of {result.config.episodes} episodes finished (in {path}); continue with: "
            f"{resume_command(args)}")


def resume_command(args: argparse.Namespace) -> str:
    """The command line that continues this run."""
    argv = [a for a in sys.argv[1:] if a not in ("--overwrite", "--resume")]
    if not argv or argv[0] != "evaluate":
        return f"the same command with --resume (journal {journal_path(args)})"
    return shlex.join(["pih", *argv, "--resume"])


def choose_episodes(result: EvaluationResult, spec: str, failures: int = 1) -> list[int]:
    """Episode indices from "auto" (the first three successes and up to ``failures`` failures) or "i,j,k".

    Raises:
        EnvError: malformed list or an index outside the evaluation.
    """
    n = len(result.records)
    if spec == "auto":
        ok = [r.index for r in result.records if r.success][:3]
        bad = [r.index for r in result.records if not r.success and not r.reason.startswith("unreachable")]
        return sorted(ok + bad[:failures])
    check_video_episodes(spec, n)
    return [int(x) for x in spec.split(",") if x.strip()]


def render_and_plot(model_dir: Path, config: EvaluationConfig, result: EvaluationResult, episodes: Sequence[int],
                    video: Path | None, figure: Path | None, camera: str = "front",
                    stiffness_figure: Path | None = None,
                    figure_episodes: Sequence[int] | None = None,
                    force_figure: Path | None = None) -> dict[str, Any]:
    """Replay ``episodes`` once (deterministic physics) to render an MP4 of them and/or draw the skill and
    stiffness figures of those among them in ``figure_episodes`` (default: all of them), and/or the wrist force
    of all of them (``force_figure``).

    Returns:
        {"video": path or None, "figure": path or None, "stiffness_figure": path or None, "replayed": [...]}
        for the summary.
    """
    from envs.evaluation.evaluate import replay_episodes, skill_file
    from envs.evaluation.starts import evaluation_starts, metadata_starts
    from envs.media.video import EpisodeVideo, VideoConfig, episode_overlay
    from envs.policies.flow_skill import generate_plan
    from rflow.skill_io import load_skill

    out: dict[str, Any] = {"video": None, "figure": None, "stiffness_figure": None, "force_figure": None,
                           "replayed": list(episodes)}
    if not episodes or all(p is None for p in (video, figure, stiffness_figure, force_figure)):
        return out
    skill = load_skill(model_dir)
    meta = metadata_starts(skill.metadata, skill_file(model_dir))
    starts_all = evaluation_starts(meta, config)
    starts = [starts_all[i] for i in episodes]
    outcomes = {r.index: "success" if r.success else (r.failure or "failed") for r in result.records}
    holder: dict[str, Any] = {}

    def on_episode(start: StartPose, env: Any) -> None:
        if video is None:
            return
        if "video" not in holder:
            holder["video"] = EpisodeVideo(env.model, video, VideoConfig(camera=camera), goal=env.goal)
        holder["video"].new_episode()
        holder["video"].set_commanded_path(generate_plan(skill, start.pose, config.task.time_limit_s,
                                                         env.control_period_s).pos)
        holder["episode"] = start.index

    def on_step(env: Any) -> None:
        if "video" in holder:
            obs = env.observation
            holder["video"].capture(env.data, obs.time_s, text=lambda: episode_overlay(
                f"episode {holder['episode']}", outcomes.get(holder["episode"]), obs.time_s,
                math.hypot(*obs.wrist_wrench[:3])))

    try:
        replays = replay_episodes(model_dir, config, starts, on_step=on_step, on_episode=on_episode)
    except BaseException:
        if "video" in holder:
            holder["video"].abort()
        raise
    if "video" in holder:
        out["video"] = str(holder["video"].close())
    if force_figure is not None and replays:
        out["force_figure"] = str(plot_episode_forces(replays, starts, force_figure, config))
    shown = [i for i, episode in enumerate(episodes) if figure_episodes is None or episode in figure_episodes]
    replays, starts = [replays[i] for i in shown], [starts[i] for i in shown]
    if figure is not None and replays:
        out["figure"] = str(plot_episodes(model_dir, skill, replays, starts, figure, config))
    if stiffness_figure is not None and replays:
        out["stiffness_figure"] = str(plot_episode_stiffness(model_dir, replays, starts, stiffness_figure, config))
    return out


def plot_episode_forces(replays: Sequence[Any], starts: Sequence[StartPose], path: Path,
                        config: EvaluationConfig) -> Path:
    """The force figure: the wrist force |F| of each replayed episode against time, with the force limit."""
    import numpy as np

    from envs.media.figures import plot_force_traces

    traces = [(f"episode {start.index}: {record.reason.split(' (')[0]}", record.success, trace.times_s,
               np.sqrt((trace.wrist_wrench[:, :3] ** 2).sum(axis=1)))
              for (record, trace), start in zip(replays, starts) if trace is not None]
    return plot_force_traces(traces, config.task.force_limit_n, path, "wrist force of the chosen episodes")


def plot_episode_stiffness(model_dir: Path, replays: Sequence[Any], starts: Sequence[StartPose], path: Path,
                           config: EvaluationConfig) -> Path:
    """The stiffness figure: the demos' stiffness (from the checkpoint's demos.npz, present for a stiffness
    skill) beside the stiffness commanded in the replayed episodes."""
    import numpy as np

    from envs.media.figures import StiffnessCurve, plot_stiffness

    demos = []
    preview = load_preview(model_dir)
    if preview is not None and "stiffness" in preview:
        k, dt = preview["stiffness"], float(preview["dt"])
        demos = [StiffnessCurve(dt * np.arange(k.shape[1]), k[n]) for n in range(k.shape[0])]
    executed = [StiffnessCurve(trace.times_s, trace.stiffness) for _, trace in replays if trace is not None]
    title = f"stiffness {config.stiffness or 'controller default'} ({config.mode}): episodes {[s.index for s in starts]}"
    return plot_stiffness(demos, executed, path, title)


def plot_episodes(model_dir: Path, skill: Any, replays: Sequence[Any], starts: Sequence[StartPose], path: Path,
                  config: EvaluationConfig) -> Path:
    """The paper-style figure: demos (from the checkpoint's demos.npz), plans from the starts, executions."""
    import numpy as np

    from envs.media.figures import PoseCurve, plot_skill
    from envs.policies.flow_skill import generate_plan, on_goal_hemisphere

    demos = []
    preview = load_preview(model_dir)
    if preview is not None:
        pos, quat, dt = preview["pos"], preview["quat"], float(preview["dt"])
        for n in range(pos.shape[0]):
            q = on_goal_hemisphere(quat[n], skill.goal_quat)
            demos.append(PoseCurve(dt * np.arange(pos.shape[1]), pos[n], skill.to_tangent(pos[n], q)[:, 3:]))
    plans, executed = [], []
    for (rec, trace), start in zip(replays, starts):
        plan = generate_plan(skill, start.pose, config.task.time_limit_s, 0.01)
        keep = plan.times_s <= (trace.times_s[-1] if trace is not None else config.task.time_limit_s) + 1e-9
        plans.append(PoseCurve(plan.times_s[keep], plan.pos[keep], plan.tangent[keep, 3:]))
        if trace is not None:
            q = on_goal_hemisphere(trace.quat, skill.goal_quat)
            executed.append(PoseCurve(trace.times_s, trace.pos, skill.to_tangent(trace.pos, q)[:, 3:]))
    title = f"{config.mode}: episodes {[s.index for s in starts]}"
    return plot_skill(demos, plans, executed, skill.goal_pos, path, title)


def main(args: argparse.Namespace) -> int:
    """Run `pih evaluate`; returns the exit status: 0 when every episode has a record (even failed ones:
    the record says so), 3 when the batch is incomplete, 1 when a fault stopped it, 130 when interrupted."""
    wall = time.perf_counter()
    config = check_args(args)
    work_begins()
    with contextlib.ExitStack() as temporary:
        try:
            return _evaluate_and_report(args, config, media_recording(args, temporary), wall)
        except PolicyFailure as failure:
            path = journal_path(args)
            kept = (f"; the episodes that finished are in {path}: `--resume --keep-going` records the rest"
                    if path is not None and path.is_file() else "")
            return report_policy_failure("evaluate", failure, f"; no success rate written{kept}")


def _evaluate_and_report(args: argparse.Namespace, config: EvaluationConfig,
                         recording: tuple[Path | None, list[int] | None], wall: float) -> int:
    """The run of `main` after its checks: evaluate, report, draw; returns the exit status."""
    result = run_evaluation(args, config, recording)
    if result.goal_mismatch_mm > GOAL_MISMATCH_WARN_MM:
        whose = "demos" if args.policy else "skill"
        print(f"pih evaluate: warning: the {whose}'s goal is {result.goal_mismatch_mm:.0f} mm from the scene's goal; "
              "for demos recorded elsewhere use --hole-at-goal", file=sys.stderr)
    if result.fault is not None:  # the batch was stopped: one line, no table of a run that did not happen
        if args.json is not None and result.records:
            result.save_json(args.json)  # what ran, and the fault (the events are in it)
        print(f"pih evaluate: error: {fault_text(args, result)}{continue_text(args, result)}", file=sys.stderr)
        return EXIT_FAULT
    print(result.summary_table())
    for event in result.new_events:  # a resumed run's earlier losses are in the JSON, not news
        print(f"pih evaluate: infrastructure: {describe_event(event)}", file=sys.stderr)
    if args.json is not None:
        result.save_json(args.json)
        print(f"wrote {args.json}")
    if result.interrupted or not result.complete:
        what = "interrupted" if result.interrupted else "incomplete"
        unscored = f" ({len(result.infrastructure_errors)} lost to infrastructure)" if result.infrastructure_errors else ""
        print(f"pih evaluate: {what} after {len(result.records)} of {config.episodes} episodes{unscored}",
              file=sys.stderr)
        if journal_path(args) is not None and journal_path(args).is_file():
            print(f"pih evaluate: finished episodes are in {journal_path(args)}; continue with: {resume_command(args)}",
                  file=sys.stderr)
        return EXIT_INTERRUPTED if result.interrupted else EXIT_INCOMPLETE
    if args.journal is None and journal_path(args) is not None:  # the run's own journal, of a complete run: the JSON
        journal_path(args).unlink(missing_ok=True)                # holds every record, nothing is left to resume
    figure_episodes = choose_episodes(result, args.video_episodes, failures=0)  # 'auto': successes only
    chosen = choose_episodes(result, args.video_episodes) if args.video else figure_episodes
    if args.force_figure is not None and not args.video:
        chosen = choose_episodes(result, args.video_episodes)  # 'auto': the successes and the first failure
    if args.policy is not None:  # drawn from the episodes as they were recorded: a policy is not run again
        extras = {"video": None, "figure": None, "stiffness_figure": None, "force_figure": None}
        if recording[0] is not None and any(getattr(args, k) is not None for k in extras):
            extras = policy_media(args, config, result, recording[0], chosen, figure_episodes)
    else:
        extras = render_and_plot(args.model, config, result, chosen, args.video, args.figure, args.camera,
                                 args.stiffness_figure, figure_episodes=figure_episodes,
                                 force_figure=args.force_figure)
    for key, episodes in (("video", chosen), ("figure", figure_episodes), ("stiffness_figure", figure_episodes),
                          ("force_figure", chosen)):
        if extras[key]:
            print(f"wrote {extras[key]} (episodes {episodes})")
        elif getattr(args, key) is not None:
            print(f"pih evaluate: --{key.replace('_', '-')} {getattr(args, key)} not written: no episode to show "
                  f"({'no episode was seated' if key in ('figure', 'stiffness_figure') else 'none chosen'})",
                  file=sys.stderr)
    if not args.quiet:
        print(f"total {time.perf_counter() - wall:.1f} s")
    if result.policy_errors:  # --keep-going: the run is recorded, and the policy's first error shown
        from envs.evaluation.evaluate_policy import policy_failure

        first = policy_failure(result.policy_errors[0].to_dict())
        return report_policy_failure("evaluate", first, f" ({len(result.policy_errors)} episode(s) with policy "
                                                        "errors, recorded as policy_error and not scored)")
    return 0
