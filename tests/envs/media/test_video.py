"""Offscreen rendering to MP4: size, frame count, atomic output, errors."""

from __future__ import annotations

from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest

from envs.errors import EnvError
from envs.media.video import PATH_RGBA, EpisodeVideo, Mp4Writer, OffscreenRenderer, VideoConfig, add_polyline
from envs.poses import Pose
from envs.sim.env import PegInHoleEnv
from envs.sim.episode_config import EpisodeConfig

SMALL = VideoConfig(width=160, height=120, fps=30, camera="side")


@pytest.fixture(scope="module")
def env() -> PegInHoleEnv:
    env = PegInHoleEnv(episode_config=EpisodeConfig(time_limit_s=5.0))
    env.reset(start_pose=(env.hole.pos + [0.0, 0.0, 0.05], env.goal.quat))
    return env


def record(env: PegInHoleEnv, path: Path, seconds: float, config: VideoConfig = SMALL) -> EpisodeVideo:
    start = env.reset(start_pose=(env.hole.pos + [0.0, 0.0, 0.05], env.goal.quat))
    target = Pose(start.peg_tip.pos + [0.0, 0.0, 0.01], start.peg_tip.quat)
    with EpisodeVideo(env.model, path, config, goal=env.goal,
                      commanded_path=np.stack([start.peg_tip.pos, target.pos])) as video:
        video.capture(env.data, 0.0)
        for _ in range(int(round(seconds / env.control_period_s))):
            result = env.step(target)
            video.capture(env.data, result.obs.time_s)
    return video


def test_short_render_has_the_right_size_and_frame_count(env: PegInHoleEnv, tmp_path: Path) -> None:
    path = tmp_path / "clip.mp4"
    video = record(env, path, seconds=0.5)
    frames = [frame for frame in imageio.get_reader(path)]  # list() would ask len(): inf for ffmpeg
    assert video.frames == 16  # floor(0.5 s * 30 fps) + 1
    assert len(frames) == 16 and frames[0].shape == (120, 160, 3)


def test_frames_are_not_blank(env: PegInHoleEnv, tmp_path: Path) -> None:
    path = tmp_path / "clip.mp4"
    record(env, path, seconds=0.1)
    frame = imageio.get_reader(path).get_data(0)
    assert frame.std() > 10.0


def test_commanded_path_is_drawn(env: PegInHoleEnv) -> None:
    env.reset(start_pose=(env.hole.pos + [0.0, 0.0, 0.05], env.goal.quat))
    with OffscreenRenderer(env.model, 160, 120) as renderer:
        renderer.set_camera("front")
        before = renderer.update_scene(env.data).ngeom
        drawn = add_polyline(renderer.scene, np.linspace([0.3, -0.2, 0.3], [0.6, 0.2, 0.5], 50), 3.0, PATH_RGBA, 10)
        assert drawn == 10 and renderer.scene.ngeom == before + 10


def test_exception_leaves_no_file(env: PegInHoleEnv, tmp_path: Path) -> None:
    path = tmp_path / "clip.mp4"
    with pytest.raises(RuntimeError, match="boom"):
        with EpisodeVideo(env.model, path, SMALL) as video:
            video.capture(env.data, 0.0)
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_unknown_camera_is_rejected_without_a_file(env: PegInHoleEnv, tmp_path: Path) -> None:
    with pytest.raises(EnvError, match="camera 'nope' not in the scene"):
        EpisodeVideo(env.model, tmp_path / "clip.mp4", VideoConfig(width=160, height=120, camera="nope"))
    assert list(tmp_path.iterdir()) == []


def test_frame_size_must_be_a_multiple_of_eight() -> None:
    with pytest.raises(EnvError, match="width"):
        VideoConfig(width=642)


def test_video_path_must_be_mp4(tmp_path: Path) -> None:
    with pytest.raises(EnvError, match=".mp4"):
        Mp4Writer(tmp_path / "clip.avi", fps=30)


def test_multisampling_smooths_edges_without_moving_the_scene(env: PegInHoleEnv) -> None:
    env.reset(seed=0)
    frames = []
    for samples in (0, 4):
        with OffscreenRenderer(env.model, 160, 120, multisamples=samples) as renderer:
            assert env.model.vis.quality.offsamples == samples
            renderer.set_camera("front")
            renderer.update_scene(env.data)
            frames.append(renderer.render().astype(float))
    changed = np.abs(frames[0] - frames[1]).max(axis=-1) > 8
    assert 0.001 < changed.mean() < 0.2  # edge pixels blend; the picture is the same
    env.model.vis.quality.offsamples = 0


def test_bad_multisamples_are_rejected() -> None:
    with pytest.raises(EnvError, match="multisamples"):
        VideoConfig(multisamples=-1)
