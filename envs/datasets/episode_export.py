"""Evaluation episodes exported while they are replayed or played back from their recording
(envs.evaluation.replay.replay_evaluation calls the
``on_episode``, ``on_step`` and ``on_trace`` methods) at the export's frame rate: the data resampled onto the frames
t_j = j / fps (envs.datasets.resample), and with a camera the frames rendered as the control steps reach them (frame j:
the state of the first control step at or after t_j, the exact one when fps divides the control rate; LeRobot: one MP4
at fps, a frame per data row; robomimic: (T, H, W, 3) arrays per episode; both without the drawn path and goal of the
figures' videos), and each episode written as it ends (robomimic) or kept for the tables written at the end (LeRobot;
small arrays).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from envs.datasets.features import DEFAULT_FPS, ExportEpisode, ExportMeta, episode_from_trace, evaluation_meta
from envs.datasets.frame_sample import FrameSample
from envs.datasets.resample import SNAP
from envs.errors import EnvError
from envs.io.jsonable import to_jsonable


class EpisodeExport:
    """Replayed episodes into a staged export folder: frames captured as they run, episodes written (robomimic)
    or kept (LeRobot, small arrays) as each ends."""

    def __init__(self, root: Path, layout: str, source: str, evaluation: Any, camera: str | None,
                 size: tuple[int, int], fps: int = DEFAULT_FPS):
        self.root, self.layout, self.source, self.evaluation = root, layout, source, evaluation
        self.camera, self.size, self.fps = camera, size, int(fps)
        self._emitted = 0  # frames of the current episode rendered so far
        self.meta: ExportMeta | None = None
        self.episodes: list[ExportEpisode] = []  # LeRobot: every episode; robomimic: none (written at once)
        self.count = 0
        self.video: Any = None  # LeRobot: an EpisodeVideo; robomimic: an OffscreenRenderer
        self.frames: list[np.ndarray] = []
        self.video_frames: list[int] = []
        self._frames_before = 0
        self.writer: Any = None
        self.sample = FrameSample()  # LeRobot: the frames its video statistics are computed from

    def on_episode(self, _start: Any, env: Any) -> None:
        """Before each episode: the metadata and the frame sink on the first, a new clip on every one."""
        if self.meta is None:
            scene = self.evaluation.scene
            evaluation = self.evaluation.config
            config = {"evaluation": to_jsonable(evaluation.settings()), "task": to_jsonable(evaluation.task.to_dict()),
                      "scene": scene, "skill": self.evaluation.skill,
                      "model": None if self.evaluation.model_dir is None else str(self.evaluation.model_dir),
                      **({} if self.evaluation.policy is None else {"policy": self.evaluation.policy})}
            self.meta = evaluation_meta(self.source, 1.0 / self.fps, str(scene.get("shape", env.shape)),
                                        float(scene.get("clearance_m", env.scene.config.clearance_m)), config,
                                        self.camera)
            if self.camera is not None:
                self._open_video(env)
            if self.layout == "robomimic":
                from envs.datasets.robomimic import RobomimicWriter

                self.writer = RobomimicWriter(self.root, self.meta)
        self.frames = []
        self._emitted = 0
        if self.layout == "lerobot" and self.video is not None:
            self._frames_before = self.video.frames

    def _open_video(self, env: Any) -> None:
        width, height = self.size
        if self.layout == "lerobot":
            from envs.datasets.lerobot import video_file, video_key
            from envs.media.video import EpisodeVideo, VideoConfig

            path = video_file(self.root, video_key(self.camera))
            path.parent.mkdir(parents=True)
            self.video = EpisodeVideo(env.model, path, VideoConfig(width=width, height=height, fps=self.fps,
                                                                   camera=self.camera, draw_path=False,
                                                                   goal_axis_length_m=0.0),
                                      on_frame=self.sample.add)
        else:
            from envs.media.video import OffscreenRenderer

            self.video = OffscreenRenderer(env.model, width, height)
            self.video.set_camera(self.camera)

    def on_step(self, env: Any) -> None:
        """After the reset and every step: the frames whose time this step reached (none, one, or with fps above the
        control rate several of the same state)."""
        if self.video is None:
            return
        time_s = env.observation.time_s
        due = math.floor(time_s * self.fps + SNAP) + 1 - self._emitted  # as envs.datasets.resample.frame_times counts
        if due <= 0:
            return
        self._emitted += due
        if self.layout == "lerobot":
            for _ in range(due):
                self.video.capture(env.data, time_s, force=True)
        else:
            self.video.update_scene(env.data)
            frame = self.video.render().copy()
            self.frames.extend([frame] * due)

    def on_trace(self, record: dict[str, Any], _replayed: Any, trace: Any) -> None:
        """After each episode: its export episode, written (robomimic) or kept (LeRobot)."""
        episode = episode_from_trace(record, trace, self.fps)
        self.count += 1
        if self.layout == "lerobot":
            if self.video is not None:
                self.video_frames.append(self.video.frames - self._frames_before)
            self.episodes.append(episode)
            return
        if self.frames:
            episode.frames = np.stack(self.frames)
            self.frames = []
        self.writer.add(episode)

    def finish(self) -> None:
        """Close the frame sink and write the dataset (LeRobot) or finish its file (robomimic)."""
        if self.meta is None or not self.count:
            raise EnvError(f"{self.source}: no episode to export (every chosen episode lacks a trajectory)")
        if self.layout == "lerobot":
            from envs.datasets.lerobot import LeRobotVideo, video_key, write_lerobot

            video = None
            if self.video is not None:
                self.video.close()
                width, height = self.size
                video = LeRobotVideo(video_key(self.camera), height, width, tuple(self.video_frames), self.sample)
            write_lerobot(self.root, self.meta, self.episodes, video)
        else:
            if self.video is not None:
                self.video.close()
            self.writer.close()

    def abort(self) -> None:
        """Release the frame sink and the open file after a failure."""
        if self.video is not None:
            (self.video.abort if self.layout == "lerobot" else self.video.close)()
        if self.writer is not None:
            self.writer.abort()
