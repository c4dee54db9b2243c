"""`pih render`: a demo or an evaluation's episode executed in physics and rendered to MP4.

    pih render --demos runs/demos.npz --index 0 --out runs/demo0.mp4 [--camera front] [--overwrite]
    pih render --episodes runs/eval.json --index 3 --out runs/episode3.mp4 [--camera cutaway]

--demos: the demo's recorded peg_tip trajectory is replayed by the episode loop (envs.policies.replay.ReplayPolicy):
the arm starts at its first pose and the impedance controller tracks it (resampled to the 100 Hz command rate, without
the demo's feed-forward and stiffness); the commanded path and the goal frame are drawn. Other
trajectory sources plug in through ``TrajectorySource``. --episodes: the evaluation's episode is replayed as `pih
export` replays it (its start and perturbation drawn again from the JSON's seed, the skill run from the checkpoint it
names, the replay checked against the record; envs.evaluation.replay), or played back from the evaluation's recorded
episodes (`pih evaluate --record-episodes`: any policy's); an evaluation of --policy without them cannot be replayed
(its policy is not run again). Every frame carries the episode (or demo), its outcome, the time and the wrist force.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from envs.cell.scene_config import SceneConfig
from envs.demos.file import load_demos
from envs.demos.record import scene_config_from_demos
from envs.errors import EnvError
from envs.io.owned_output import MiB, check_output
from envs.media.video import EpisodeVideo, VideoConfig, episode_overlay
from envs.poses import Pose
from envs.policies.replay import ReplayPolicy
from envs.rollout.episode import StartPose, run_episode
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig
from scripts.options import (CAMERA_NAMES, MAX_EPISODES, add_source_arguments, check_camera, count, number,
                             refuse_unused, work_begins)

VIDEO_BYTES = 100 * MiB
"""Generous size of one rendered demo (640x480 H.264, a 10-20 s demo takes a few MiB)."""


@dataclass(frozen=True)
class TrajectorySource:
    """A peg_tip pose trajectory to execute and the scene it belongs to.

    Attributes:
        pos: (K, 3) positions, m.  quat: (K, 4) unit quaternions (w, x, y, z).  dt: sampling time, s.
        scene: the scene to build.  label: what is shown in the console output.
    """

    pos: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64]
    dt: float
    scene: SceneConfig
    label: str


EXAMPLES: tuple[str, ...] = ('pih render --demos demos.npz --index 0 --out demo.mp4 --camera side',
                             'pih render --episodes eval.json --index 3 --out episode3.mp4 --camera cutaway')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih render`."""
    add_source_arguments(parser, "an evaluation (`pih evaluate --json`): the skill's replayed, or its recorded episodes")
    parser.add_argument("--index", type=count(MAX_EPISODES - 1, minimum=0), default=0,
                        help="which demo, or which episode (its index in the evaluation)")
    parser.add_argument("--model", type=Path, metavar="DIR",
                        help="with --episodes: the checkpoint (default: the one the JSON names)")
    parser.add_argument("--out", type=Path, required=True, help="output video (.mp4)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace --out when an earlier pih run wrote it (never a file pih did not write)")
    parser.add_argument("--camera", default="front", help=f"camera: {CAMERA_NAMES}")
    parser.add_argument("--width-px", type=count(4096, minimum=16), default=640, help="frame width, pixels")
    parser.add_argument("--height-px", type=count(4096, minimum=16), default=480, help="frame height, pixels")
    parser.add_argument("--fps", type=count(240), default=30, help="frames per second of simulated time")
    parser.add_argument("--hold-s", type=number(minimum=0.0, maximum=60.0), default=0.5,
                        help="with --demos: seconds to hold the final pose")


def demo_source(path: Path, index: int) -> TrajectorySource:
    """The recorded trajectory ``index`` of a demo file.

    Raises:
        EnvError: unreadable file or an index out of range.
    """
    demos = load_demos(path)
    if not 0 <= index < demos.num_demos:
        raise EnvError(f"--index {index} is out of range: {path} holds {demos.num_demos} demos")
    return TrajectorySource(demos.pos[index], demos.quat[index], demos.dt, scene_config_from_demos(demos),
                            f"demo {index} of {path}")


def trajectory_source(args: argparse.Namespace) -> TrajectorySource:
    """What to execute, from the command line. Extension point: a ``--model DIR`` option adds a branch here
    that returns the trajectory generated by a trained skill (e.g. from the start of demo ``--index``)."""
    return demo_source(args.demos, args.index)


def render_trajectory(source: TrajectorySource, out: Path, video: VideoConfig, hold_s: float = 0.5) -> dict[str, object]:
    """Reset at the trajectory's first pose and replay it in physics (envs.policies.replay.ReplayPolicy through the
    episode loop, envs.rollout.episode: the recorded poses resampled to the control period, without feed-forward,
    under the controller's default stiffness), then hold its last pose for ``hold_s``, while recording ``out``.

    Returns:
        {"frames", "sim_s", "wall_s", "render_s", "encode_s", "final_pos_error_mm", "success"} and the end reason.

    Raises:
        EnvError: bad video settings, an unreachable first pose, a replay that failed, or no OpenGL context.
    """
    recorded_s = source.dt * (len(source.pos) - 1)
    env = PegInHoleEnv(source.scene, episode_config=EpisodeConfig(time_limit_s=recorded_s + hold_s + 1.0,
                                                                  stop_on_success=False))
    period = env.control_period_s
    steps = int(np.ceil(recorded_s / period - 1e-9)) + int(round(hold_s / period))
    policy = ReplayPolicy(source.dt * np.arange(len(source.pos)), source.pos, source.quat, feedforward=False)
    label = source.label.split(" of ")[0]
    start = time.perf_counter()
    with EpisodeVideo(env.model, out, video, goal=env.goal, commanded_path=source.pos) as recorder:

        def on_step(sim: PegInHoleEnv) -> None:
            obs = sim.observation
            recorder.capture(sim.data, obs.time_s, text=lambda: _overlay(label, None, obs))

        record, _ = run_episode(env, policy, StartPose(0, -1, Pose(source.pos[0], source.quat[0])), on_step=on_step,
                                max_steps=steps)
        if record.failure in ("unreachable_start", "error"):
            raise EnvError(f"{source.label} cannot be replayed: {record.reason}")
    obs = env.observation
    return {
        "frames": recorder.frames,
        "sim_s": obs.time_s,
        "wall_s": time.perf_counter() - start,
        "render_s": recorder.render_s,
        "encode_s": recorder.encode_s,
        "final_pos_error_mm": float(np.linalg.norm(obs.peg_tip.pos - env.goal.pos) * 1e3),
        "success": bool(obs.success),
        "reason": env.reason,
    }


def _overlay(label: str, outcome: str | None, obs: object) -> str:
    """The frame's text: the label, the outcome, the time and the wrist force of the observation."""
    return episode_overlay(label, outcome, obs.time_s, math.hypot(*obs.wrist_wrench[:3]))


def render_episode(path: Path, index: int, model: Path | None, out: Path, video: VideoConfig) -> dict[str, object]:
    """Replay episode ``index`` of an evaluation JSON (as `pih export` replays it) while recording ``out``.

    Returns:
        {"frames", "wall_s", "success", "reason"} of the replayed episode.

    Raises:
        EnvError: an evaluation that cannot be replayed (of a --policy, or its checkpoint not found), no episode
            ``index``, an episode without a trajectory (an unreachable start, a lost worker), a replay that differs
            from its record.
    """
    from envs.evaluation.replay import NO_TRAJECTORY, load_evaluation, replay_evaluation

    evaluation = load_evaluation(path, model)
    record = next((r for r in evaluation.records if r.get("index") == index), None)
    if record is None:
        raise EnvError(f"--index {index}: {path} has no episode {index} (it holds {len(evaluation.records)})")
    if str(record.get("reason", "")).startswith(NO_TRAJECTORY):
        raise EnvError(f"--index {index}: episode {index} has no trajectory to render ({record.get('reason')})")
    outcome = "success" if record.get("success") else record.get("failure") or "failed"
    holder: dict[str, EpisodeVideo] = {}
    start = time.perf_counter()

    def on_episode(_start: object, env: PegInHoleEnv) -> None:
        holder["video"] = EpisodeVideo(env.model, out, video, goal=env.goal)

    def on_step(env: PegInHoleEnv) -> None:
        obs = env.observation
        holder["video"].capture(env.data, obs.time_s, text=lambda: _overlay(f"episode {index}", outcome, obs))

    try:
        replay_evaluation(evaluation, [index], on_step=on_step, on_episode=on_episode)
    except BaseException:
        if "video" in holder:
            holder["video"].abort()
        raise
    recorder = holder["video"]
    recorder.close()
    return {"frames": recorder.frames, "wall_s": time.perf_counter() - start, "success": bool(record.get("success")),
            "reason": record.get("reason")}


def main(args: argparse.Namespace) -> int:
    """Render the requested demo or episode; returns the exit status."""
    for option, value in (("--width-px", args.width_px), ("--height-px", args.height_px)):
        if value % 8:
            raise EnvError(f"{option} {value}: must be a multiple of 8 (H.264 frames)")
    video = VideoConfig(width=args.width_px, height=args.height_px, fps=args.fps, camera=args.camera)
    check_camera(args.camera)
    if args.demos is not None:
        refuse_unused(args, add_arguments, ["model"], "applies to --episodes only")
    else:
        refuse_unused(args, add_arguments, ["hold_s"], "applies to --demos only")
    check_output("--out", args.out, args.overwrite, suffix=".mp4", inputs=[args.demos, args.episodes, args.model],
                 estimate_bytes=VIDEO_BYTES)
    if args.episodes is not None:
        stats = render_episode(args.episodes, args.index, args.model, args.out, video)
        print(f"wrote {args.out}: episode {args.index} of {args.episodes}, {stats['frames']} frames in "
              f"{stats['wall_s']:.1f} s; {stats['reason']}")
        return 0
    source = trajectory_source(args)
    work_begins()
    stats = render_trajectory(source, args.out, video, hold_s=args.hold_s)
    print(f"wrote {args.out}: {source.label}, {stats['frames']} frames ({stats['sim_s']:.2f} s simulated) in "
          f"{stats['wall_s']:.1f} s; final peg_tip {stats['final_pos_error_mm']:.3f} mm from the goal, "
          f"{'inserted' if stats['success'] else 'NOT inserted'}")
    return 0
