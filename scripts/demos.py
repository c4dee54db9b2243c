"""`pih demos`: record scripted peg-in-hole demonstrations in physics (or check the expert's success rate).

The expert commands and records its translational stiffness schedule (envs/demos/record.py,
envs/policies/stiffness_schedule.py): the demo file's ``stiffness``, learned with `pih train --stiffness expert`. The
scene is the task's (--task and the task options, envs/task/task.py); the demo file records the task, and `pih train`
copies it into the checkpoint.

    pih demos --num 7 --seed 0 --out runs/demos.npz [--shape square] [--task NAME|FILE.toml] [--video runs/demos.mp4]
    pih demos --num 7 --seed 0 --noise realistic --out runs/noisy.npz   # as a real cell records them
    pih demos --check 100 --seed 0            # success rate of the scripted expert over 100 starts
    pih demos --import rec.npz --tool-offset franka-tcp --dt-s 0.001 --out demos.npz [--snap-goal]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from envs.errors import EnvError  # noqa: E402
from envs.io.owned_output import MiB, check_distinct, check_output  # noqa: E402
from scripts.demos_import import add_import_arguments, run_import  # noqa: E402
from pihutil.bounds import ENTRY_SPEED_M_S  # noqa: E402
from scripts.options import (MAX_DEMOS, MAX_EPISODES, MAX_SAMPLES, check_camera, count, number, work_begins,  # noqa: E402
                             refuse_unused, seed)
from scripts.task_options import add_task_arguments, task_from_args  # noqa: E402

if TYPE_CHECKING:  # the simulator loads in main(), never for --help
    from envs.cell.scene_config import SceneConfig
    from envs.demos.record import DemoAttempt
    from envs.policies.expert_plan import ExpertConfig


def expert_stiffness(text: str) -> Any:
    """The `StiffnessSchedule` of --expert-stiffness (argparse type: a bad value is a one-line usage error)."""
    from envs.policies.stiffness_schedule import StiffnessSchedule

    try:
        return StiffnessSchedule.parse(text)
    except EnvError as err:
        raise argparse.ArgumentTypeError(f"{text!r}: {err}") from None


EXAMPLES: tuple[str, ...] = ('pih demos --num 7 --seed 0 --out demos.npz',
                             'pih demos --num 7 --seed 0 --task realistic --video demos.mp4 --out demos.npz',
                             'pih demos --import rec.npz --tool-offset franka-tcp --dt-s 0.001 --out demos.npz')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih demos`, in groups: demos, output, import, task."""
    demos = parser.add_argument_group("demos")
    demos.add_argument("--num", type=count(MAX_DEMOS), default=7,
                       help=f"demonstrations to keep, 1..{MAX_DEMOS:,} (default 7, as the paper)")
    demos.add_argument("--seed", type=seed, default=0, help="seed of the start-pose stream, 0..2**32-1")
    demos.add_argument("--shape", help="peg and hole shape (default: the task's, else square)")
    demos.add_argument("--samples", type=count(MAX_SAMPLES, minimum=2), default=4000,
                       help=f"samples M per demo, 2..{MAX_SAMPLES:,} (default 4000, as the paper)")
    demos.add_argument("--entry-speed-mm-s", type=number(above=0.0, maximum=ENTRY_SPEED_M_S.high * 1e3), default=10.0,
                       help="speed at which the peg enters the hole, mm/s (default 10; 5 for a 0.2 mm clearance)")
    demos.add_argument("--noise", metavar="SPEC",
                       help="record the demos as a real cell would (envs/demos/noise.py): 'realistic' (3 mm / 3 deg "
                            "end scatter, timing jitter, approach curvature, sensor noise) and/or FIELD=VALUE pairs, "
                            "e.g. 'realistic,final_pos_scatter_m=0.004'; the file's demos then end apart")
    demos.add_argument("--expert-stiffness", type=expert_stiffness, metavar="FREE/LATERAL/AXIAL",
                       help="the stiffness schedule the expert commands and records, N/m: FREE in free space, "
                            "LATERAL across and AXIAL along the hole axis near and in the hole (envs/"
                            "stiffness_schedule.py; default 1500/300/1000)")
    demos.add_argument("--check", type=count(MAX_EPISODES), metavar="N",
                       help="instead of recording, run the expert from N seeded starts and report the success rate")
    out = parser.add_argument_group("output")
    out.add_argument("--out", type=Path, help="output .npz demo file (required unless --check)")
    out.add_argument("--video", type=Path, help="also render every attempt to this MP4")
    out.add_argument("--camera", default="front", help="camera for --video (front, side, top, closeup, wrist)")
    out.add_argument("--overwrite", action="store_true",
                     help="replace --out and --video when an earlier pih run wrote them (never a file pih did not write)")
    add_import_arguments(parser)
    add_task_arguments(parser, episode=False)


def check_outputs(args: argparse.Namespace, inputs: list[Path | None], demos: int, samples: int) -> None:
    """--out (and --video) may be written: envs.io.owned_output.check_output, with a generous size estimate
    (pos, quat and stiffness of every sample in float64, and 20 MiB of video per attempt, two per demo).

    Raises:
        EnvError: naming the option.
    """
    if args.out is None:
        raise EnvError("--out FILE.npz is required (or use --check N)")
    check_distinct({"--out": args.out, "--video": args.video})
    check_output("--out", args.out, args.overwrite, suffix=".npz", inputs=inputs,
                 estimate_bytes=2 * demos * samples * (3 + 4 + 9) * 8)
    check_output("--video", args.video, args.overwrite, suffix=".mp4", inputs=inputs,
                 estimate_bytes=2 * demos * 20 * MiB)


def _describe(index: int, attempt: DemoAttempt) -> str:
    status = "kept" if attempt.ok else "FAILED"
    extra = (f"residual {attempt.residual_pos_m * 1e3:.3f} mm, {attempt.residual_rot_deg:.3f} deg"
             if attempt.ok else attempt.reason)
    return f"attempt {index:3d}: {status} ({attempt.wall_s:.2f} s) {extra}"


def _check(args: argparse.Namespace, scene: SceneConfig, expert: ExpertConfig) -> int:
    from envs.demos.record import expert_success_rate

    start = time.perf_counter()
    result = expert_success_rate(args.check, args.seed, scene, expert,
                                 on_attempt=lambda i, a: None if a.ok else print(_describe(i, a)))
    print(f"scripted expert: {result.num_success}/{result.num_starts} succeeded "
          f"({100 * result.rate:.1f} %; {result.num_unreachable} starts unreachable, "
          f"{100 * result.rate_reachable:.1f} % of reachable starts)")
    print(f"median {result.seconds_per_demo:.2f} s per demo, worst settled residual "
          f"{result.max_residual_pos_m * 1e3:.4f} mm / {result.max_residual_rot_deg:.4f} deg, "
          f"total {time.perf_counter() - start:.0f} s")
    return 0


def main(args: argparse.Namespace) -> int:
    """Record demos (or run the success-rate check, or import recorded demos); returns the exit status."""
    if args.import_file is not None:
        refuse_unused(args, add_arguments, ["num", "seed", "entry_speed_mm_s", "camera"],
                      "records the scripted expert's demos; it does not apply to --import")
        return run_import(args)
    refuse_unused(args, add_arguments, ["import_format", "tool_offset", "dt_s", "snap_goal", "ends_apart"],
                  "applies to --import only")
    if args.check is not None:
        refuse_unused(args, add_arguments, ["num", "out", "video", "noise", "overwrite"],
                      "not with --check (it runs --check N starts and records nothing)")
    if args.video is None:
        refuse_unused(args, add_arguments, ["camera"], "applies to --video only")
    from envs.demos.record import collect_demos, demo_episode_config
    from envs.policies.expert_plan import ExpertConfig, check_entry_speed
    from envs.sim.env import PegInHoleEnv

    task = task_from_args(args)
    scene = task.scene_config(shape=task.shape or "square")
    schedule = {} if args.expert_stiffness is None else {"stiffness": args.expert_stiffness}
    expert = ExpertConfig(num_samples=args.samples, entry_speed_m_s=args.entry_speed_mm_s * 1e-3, **schedule)
    try:
        check_entry_speed(expert, scene.insertion_depth_m)
    except EnvError as err:
        raise EnvError(f"--entry-speed-mm-s {args.entry_speed_mm_s:g}: {err}") from None
    if args.check is not None:
        work_begins()
        return _check(args, scene, expert)
    noise = None
    if args.noise is not None:
        from envs.demos.noise import DemoNoise

        noise = DemoNoise.parse(args.noise)
    check_outputs(args, [], args.num, args.samples)
    if args.video is not None:
        check_camera(args.camera)
    work_begins()
    env = PegInHoleEnv(scene, episode_config=demo_episode_config(expert))
    video = None
    if args.video is not None:
        from envs.media.video import EpisodeVideo, VideoConfig

        video = EpisodeVideo(env.model, args.video, VideoConfig(camera=args.camera), goal=env.goal)
    try:
        def before_attempt(_env: object, _start: object, planned: object) -> None:
            if video is not None:
                video.new_episode()
                video.set_commanded_path(planned)

        def on_step(sim: PegInHoleEnv) -> None:
            if video is not None:
                video.capture(sim.data, sim.observation.time_s)

        collection = collect_demos(args.num, args.seed, env=env, expert=expert, task=task,
                                   on_attempt=lambda i, a: print(_describe(i, a), flush=True),
                                   on_step=on_step if video is not None else None, before_attempt=before_attempt)
    except BaseException:
        if video is not None:
            video.abort()
        raise
    if video is not None:
        print(f"wrote {video.close()} ({video.frames} frames)")
    from envs.demos.file import save_demos

    demos = collection.demos
    if noise is not None:
        from envs.demos.noise import add_demo_noise

        demos = add_demo_noise(demos, noise, args.seed)
    path = save_demos(args.out, demos)
    executed = [a.wall_s for a in collection.attempts]
    print(f"wrote {path}: {demos.num_demos} demos x {demos.num_samples} samples, dt {demos.dt * 1e3:.4f} ms, "
          f"shape {demos.shape}, clearance {demos.clearance_m * 1e3:g} mm; {len(collection.failures)} failed "
          f"attempts; {sum(executed) / len(executed):.2f} s per attempt")
    if demos.ends_apart:
        spread = demos.config["noise"]
        print(f"noise {args.noise}: the demos end apart, {spread['end_scatter_rms_mm']:.2f} mm and "
              f"{spread['end_scatter_rms_deg']:.2f} deg root-mean-square from their mean goal (the file's goal); "
              f"farthest {max(demos.residual_pos_m) * 1e3:.2f} mm, {max(demos.residual_rot_deg):.2f} deg")
    else:
        print(f"settled residual before snapping to the goal: max {max(demos.residual_pos_m) * 1e3:.4f} mm, "
              f"{max(demos.residual_rot_deg):.4f} deg")
    if demos.stiffness is not None:
        lam = np.linalg.eigvalsh(demos.stiffness)
        print(f"stiffness commanded and recorded (envs/policies/stiffness_schedule.py): eigenvalues {lam.min():.0f} to "
              f"{lam.max():.0f} N/m, every demo ending at the goal stiffness with eigenvalues "
              f"{', '.join(f'{v:.0f}' for v in np.linalg.eigvalsh(demos.goal_stiffness))} N/m")
    return 0

