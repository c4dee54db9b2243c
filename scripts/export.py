"""`pih export`: demonstrations or evaluation episodes as a LeRobot (v3.0) or robomimic (HDF5) dataset.

    pih export --demos runs/default/demos.npz --format lerobot --out datasets/demos-lerobot
    pih export --episodes runs/default/eval.json --format robomimic --out datasets/eval-robomimic [--video]
    pih export --episodes eval.json --select 0,3,7 --format lerobot --video --camera side --out ds/

Every export has an integer frame rate (--fps, default the control rate 100): the demos' poses (4000 samples over
7 s) and their control signals (joints, wrench, commands), or the episodes' control steps, are resampled onto its
frames. An evaluation JSON holds no per-step data: an evaluation run with `pih evaluate --record-episodes DIR` (any
policy's, a user's `--policy` among them) is exported from the episodes recorded as they ran; otherwise the skill's
episodes are replayed from its checkpoint and config (physics is deterministic). Either way each episode is checked
against its record. What each layout holds: envs/datasets/
(features.py, lerobot.py, robomimic.py).
Read back with `pih demos --import DIR --format lerobot|robomimic --out demos.npz`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from envs.datasets import LAYOUTS, require_layout
from envs.datasets.export_folder import check_export_folder, staged_folder
from envs.datasets.features import DEFAULT_FPS, ExportEpisode, ExportMeta, episodes_from_demos
from envs.datasets.resample import MAX_FPS
from envs.errors import EnvError
from envs.io.owned_output import MiB, check_output_folder
from scripts.options import add_source_arguments, count, refuse_unused, work_begins

DEFAULT_VIDEO_SIZE: dict[str, str] = {"lerobot": "640x480", "robomimic": "128x128"}
VIDEO_BYTES = 500 * MiB
"""Generous room for the frames of --video (a LeRobot MP4 stream or robomimic image arrays)."""


EXAMPLES: tuple[str, ...] = ('pih export --demos demos.npz --format lerobot --fps 50 --out ds/',
                             'pih export --episodes eval.json --select 0,3 --format robomimic --video --out ds_eval/')
"""Shown at the end of --help (scripts.cli)."""

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `pih export`."""
    add_source_arguments(parser, "an evaluation from `pih evaluate --json`: its recorded episodes "
                                 "(--record-episodes), else the skill's replayed")
    parser.add_argument("--format", choices=LAYOUTS, required=True, help="dataset layout")
    parser.add_argument("--fps", type=count(MAX_FPS),
                        help=f"frames per second of the dataset, an integer: every signal is resampled onto its frames "
                             f"(default {DEFAULT_FPS}, the control rate: a frame per control step)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (new, empty, or an export to replace)")
    parser.add_argument("--overwrite", action="store_true", help="replace --out when it holds an earlier export")
    parser.add_argument("--model", type=Path,
                        help="with --episodes of a skill without a recording: the checkpoint (default: the JSON's)")
    parser.add_argument("--select", metavar="I,J,...", help="with --episodes: only these episode indices")
    parser.add_argument("--video", action="store_true",
                        help="with --episodes: the camera frames too (LeRobot: an MP4 stream at the control rate; "
                             "robomimic: obs/<camera>_image arrays)")
    parser.add_argument("--camera", default="front", help="camera of --video (front, side, top, closeup, wrist)")
    parser.add_argument("--video-size", metavar="WxH",
                        help=f"frame size of --video (default {DEFAULT_VIDEO_SIZE['lerobot']} for lerobot, "
                             f"{DEFAULT_VIDEO_SIZE['robomimic']} for robomimic)")


def parse_size(text: str) -> tuple[int, int]:
    """(width, height) from 'WxH'.

    Raises:
        EnvError: not two positive integers.
    """
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise EnvError(f"--video-size {text!r} must be WIDTHxHEIGHT, e.g. 640x480") from None
    from envs.media.rendering import MAX_FRAME_PX

    if not (16 <= width <= MAX_FRAME_PX and 16 <= height <= MAX_FRAME_PX) or width % 8 or height % 8:
        raise EnvError(f"--video-size {text!r}: width and height must be multiples of 8 in [16, {MAX_FRAME_PX}] "
                       "pixels")
    return width, height


def parse_select(text: str | None) -> list[int] | None:
    """Episode indices from 'I,J,...' (None: all).

    Raises:
        EnvError: not a list of integers >= 0.
    """
    if text is None:
        return None
    try:
        chosen = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise EnvError(f"--select {text!r} must be episode indices I,J,...") from None
    if not chosen or min(chosen) < 0 or len(set(chosen)) != len(chosen):
        raise EnvError(f"--select {text!r} must list distinct episode indices >= 0")
    return chosen


def _write_all(root: Path, layout: str, meta: ExportMeta, episodes: list[ExportEpisode]) -> None:
    """Write episodes that are all in memory."""
    if layout == "lerobot":
        from envs.datasets.lerobot import write_lerobot

        write_lerobot(root, meta, episodes)
        return
    from envs.datasets.robomimic import RobomimicWriter

    writer = RobomimicWriter(root, meta)
    try:
        for episode in episodes:
            writer.add(episode)
    except BaseException:
        writer.abort()
        raise
    writer.close()


def checked_evaluation(args: argparse.Namespace) -> Any:
    """The evaluation of --episodes, checked field by field (envs.evaluation.replay.check_recorded) and, with
    --select, the chosen episodes drawn again: before the export folder is staged.

    Raises:
        EnvError: see `envs.evaluation.replay.load_evaluation` and `recorded_starts`.
    """
    from envs.evaluation.replay import load_evaluation, recorded_starts

    evaluation = load_evaluation(args.episodes, args.model)
    chosen = parse_select(args.select)
    if chosen is not None:
        recorded_starts(evaluation, chosen)
    return evaluation


def export_episodes(args: argparse.Namespace, root: Path, evaluation: Any) -> tuple[int, dict[int, str]]:
    """Replay the evaluation's episodes into ``root``; (episodes written, {skipped index: reason})."""
    from envs.datasets.episode_export import EpisodeExport
    from envs.evaluation.replay import replay_evaluation

    size = parse_size(args.video_size or DEFAULT_VIDEO_SIZE[args.format])
    job = EpisodeExport(root, args.format, str(args.episodes), evaluation, args.camera if args.video else None, size,
                        args.fps or DEFAULT_FPS)
    try:
        replayed, skipped = replay_evaluation(evaluation, parse_select(args.select), on_step=job.on_step,
                                              on_episode=job.on_episode, on_trace=job.on_trace)
        job.finish()
    except BaseException:
        job.abort()
        raise
    return len(replayed), skipped


def main(args: argparse.Namespace) -> int:
    """Export; returns the exit status."""
    require_layout(args.format)
    source = args.demos if args.demos is not None else args.episodes
    check_output_folder("--out", args.out, inputs=[args.demos, args.episodes, args.model],
                        estimate_bytes=4 * (source.stat().st_size if source.is_file() else 0)
                        + (VIDEO_BYTES if args.video else 0))
    check_export_folder(args.out, args.overwrite)
    if args.demos is not None:
        extra = [name for name in ("model", "select", "video_size") if getattr(args, name) is not None]
        if args.video or extra:
            raise EnvError(f"{'--video' if args.video else '--' + extra[0].replace('_', '-')} applies to --episodes "
                           "only (a demo file holds no camera frames; render a demo with `pih render`)")
    if not args.video:
        refuse_unused(args, add_arguments, ["camera"], "applies to --video only")
    parse_select(args.select)
    if args.video and args.format == "lerobot":
        from envs.media.video import VideoConfig

        width, height = parse_size(args.video_size or DEFAULT_VIDEO_SIZE[args.format])
        VideoConfig(width=width, height=height, camera=args.camera, fps=args.fps or DEFAULT_FPS)  # H.264: multiples of 8
    elif args.video_size is not None:
        parse_size(args.video_size)
    evaluation = checked_evaluation(args) if args.episodes is not None else None
    work_begins()
    start = time.perf_counter()
    with staged_folder(args.out, args.overwrite) as root:
        if args.demos is not None:
            from envs.demos.file import load_demos

            meta, episodes = episodes_from_demos(load_demos(args.demos), str(args.demos), args.fps or DEFAULT_FPS)
            _write_all(root, args.format, meta, episodes)
            count, skipped, absent = len(episodes), {}, meta.absent
        else:
            count, skipped = export_episodes(args, root, evaluation)
            absent = {}
    wall = time.perf_counter() - start
    print(f"wrote {args.out} ({args.format}, {args.fps or DEFAULT_FPS} fps): {count} "
          f"{'demos' if args.demos is not None else 'episodes'} in {wall:.2f} s")
    for index, reason in skipped.items():
        print(f"skipped episode {index}: {reason} (no trajectory)")
    if absent:
        print("absent (this demo file does not record them): " + ", ".join(sorted(absent)))
    return 0
