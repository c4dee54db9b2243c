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


def _seated(env: PegInHoleEnv) -> None:
    """Lower the peg from 12 mm above the true goal to 2 mm past it: it ends in the hole."""
    goal = env.goal
    env.reset(start_pose=Pose(goal.pos + np.array([0.0, 0.0, 0.012]), goal.quat))
    for k in range(120):
        s = min(1.0, k / 80)
        env.step((goal.pos + np.array([0.0, 0.0, 0.012 * (1 - s) - 0.002 * s]), goal.quat))


def _peg_pixels(frame: np.ndarray) -> int:
    """Pixels of the peg's red, also seen through the translucent sorter (red well above green and blue)."""
    r, g, b = (frame[..., i].astype(int) for i in range(3))
    return int(np.sum((r > g + 50) & (r > b + 50)))


def test_the_cutaway_camera_shows_the_peg_inside_the_hole(env: PegInHoleEnv, monkeypatch: pytest.MonkeyPatch) -> None:
    """From the cutaway camera the sorter is translucent: the seated peg's part below the opening shows, which the
    same view of an opaque sorter hides."""
    import envs.media.video as video_module

    _seated(env)
    assert env.observation.insertion.depth_m > 0.025
    with OffscreenRenderer(env.model, 320, 240) as renderer:
        renderer.set_camera("cutaway")
        renderer.update_scene(env.data)
        translucent = renderer.render().copy()
        monkeypatch.setattr(video_module, "CUTAWAY_ALPHA", 1.0)
        renderer.update_scene(env.data)
        opaque = renderer.render().copy()
        renderer.set_camera("closeup")
        alphas = {float(renderer.scene.geoms[i].rgba[3]) for i in range(renderer.update_scene(env.data).ngeom)}
    assert _peg_pixels(translucent) > 1.3 * _peg_pixels(opaque) > 0
    assert alphas <= {1.0} | {float(a) for a in env.model.geom_rgba[:, 3]}  # other cameras: the sorter as it is


def test_a_frame_carries_the_episode_its_outcome_time_and_force(env: PegInHoleEnv) -> None:
    from envs.media.video import episode_overlay

    text = episode_overlay("episode 3", "success", 1.234, 5.67)
    assert text == "episode 3: success\nt  1.23 s   |F|   5.7 N"
    with OffscreenRenderer(env.model, 320, 240) as renderer:
        renderer.set_camera("front")
        renderer.update_scene(env.data)
        plain = renderer.render().copy()
        renderer.update_scene(env.data)
        marked = renderer.render(text=text).copy()
    changed = np.argwhere(np.any(plain != marked, axis=-1))
    assert len(changed) > 200  # the letters
    assert changed[:, 0].max() < 100 and changed[:, 1].max() < 260  # top left only: the rest of the scene untouched
