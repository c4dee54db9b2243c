"""`pih export` and `pih demos --import --format`: round trips through both layouts, and bad input."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pyarrow.parquet as pq
import pytest

from envs.demos.file import load_demos, save_demos
from scripts.cli import main
from tests.helpers.stiffness_fixtures import stiffness_demos


@pytest.fixture()
def demo_file(tmp_path: Path) -> Path:
    demos = stiffness_demos(n=3, m=40)
    demos.config["scene"] = {"hole_depth_m": 0.03, "goal_pos": demos.goal_pos.tolist()}
    return save_demos(tmp_path / "demos.npz", demos)


def import_back(source: Path, layout: str, out: Path, *extra: str) -> int:
    return main(["demos", "--import", str(source), "--format", layout, "--samples", "40", "--clearance-mm", "1",
                 "--out", str(out), *extra])


@pytest.mark.parametrize("layout", ["lerobot", "robomimic"])
def test_demos_survive_export_and_import(tmp_path: Path, demo_file: Path, layout: str) -> None:
    """At the demos' own rate (20 fps: 40 samples 50 ms apart) the frames are the samples, bit for bit."""
    assert main(["export", "--demos", str(demo_file), "--format", layout, "--fps", "20",
                 "--out", str(tmp_path / "ds")]) == 0
    assert import_back(tmp_path / "ds", layout, tmp_path / "back.npz") == 0
    before, after = load_demos(demo_file), load_demos(tmp_path / "back.npz")
    np.testing.assert_allclose(after.pos, before.pos, rtol=0, atol=1e-15)  # the tcp frame: no tool conversion
    np.testing.assert_allclose(after.quat, before.quat, rtol=0, atol=1e-15)
    np.testing.assert_allclose(after.stiffness, before.stiffness, rtol=1e-15)
    assert after.dt == pytest.approx(before.dt, rel=1e-15) and after.config["scene"] == before.config["scene"]


def test_export_of_a_corrupt_demo_file_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "demos.npz").write_bytes(b"not a zip")
    assert main(["export", "--demos", str(tmp_path / "demos.npz"), "--format", "lerobot",
                 "--out", str(tmp_path / "ds")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pih export: error:") and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demos.npz"]


def test_a_truncated_dataset_is_one_line_error_and_no_demo_file(tmp_path: Path, demo_file: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", "--demos", str(demo_file), "--format", "robomimic", "--out", str(tmp_path / "ds")]) == 0
    path = tmp_path / "ds" / "demos.hdf5"
    path.write_bytes(path.read_bytes()[:4000])
    capsys.readouterr()
    assert import_back(tmp_path / "ds", "robomimic", tmp_path / "back.npz") == 2
    err = capsys.readouterr().err
    assert err.startswith("pih demos: error:") and "truncated" in err and err.count("\n") == 1
    assert not (tmp_path / "back.npz").exists()


def test_export_refuses_a_folder_of_other_files(tmp_path: Path, demo_file: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "mine.txt").write_text("keep")
    assert main(["export", "--demos", str(demo_file), "--format", "lerobot", "--out", str(tmp_path / "ds"),
                 "--overwrite"]) == 2
    assert "not a `pih export` output" in capsys.readouterr().err
    assert [p.name for p in (tmp_path / "ds").iterdir()] == ["mine.txt"]


def test_video_of_demos_is_refused(tmp_path: Path, demo_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", "--demos", str(demo_file), "--format", "lerobot", "--out", str(tmp_path / "ds"),
                 "--video"]) == 2
    assert "--episodes only" in capsys.readouterr().err and not (tmp_path / "ds").exists()


def test_a_foreign_dataset_needs_a_tool_offset(tmp_path: Path, demo_file: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", "--demos", str(demo_file), "--format", "robomimic", "--out", str(tmp_path / "ds")]) == 0
    with h5py.File(tmp_path / "ds" / "demos.hdf5", "r+") as f:
        del f["data"].attrs["pih_export"]  # as if written elsewhere: no frame, dt, shape or clearance
    capsys.readouterr()
    assert import_back(tmp_path / "ds", "robomimic", tmp_path / "back.npz", "--dt-s", "0.05") == 2
    assert "--tool-offset is required" in capsys.readouterr().err


@pytest.mark.slow
def test_evaluation_episodes_are_exported_from_their_replay(tmp_path: Path) -> None:
    """Replayed episodes: one row per control step, as the trace of an independent replay, the outcome as recorded;
    an unreachable start is skipped; the video has a frame per row."""
    import json

    from envs.evaluation.evaluate import EvaluationConfig, evaluate, replay_episodes
    from envs.evaluation.starts import evaluation_starts
    from envs.task.task import Task
    from rflow.skill_io import save_skill
    from tests.helpers.skill_fixtures import tiny_skill

    save_skill(tmp_path / "model", tiny_skill())
    config = EvaluationConfig(episodes=2, task=Task(time_limit_s=0.3))
    evaluate(tmp_path / "model", config, progress=False).save_json(tmp_path / "eval.json")
    records = json.loads((tmp_path / "eval.json").read_text())["per_episode"]
    ran = [r for r in records if r["steps"] > 0]
    assert main(["export", "--episodes", str(tmp_path / "eval.json"), "--format", "lerobot", "--video",
                 "--video-size", "64x48", "--out", str(tmp_path / "le")]) == 0
    assert main(["export", "--episodes", str(tmp_path / "eval.json"), "--format", "robomimic", "--video",
                 "--video-size", "32x24", "--out", str(tmp_path / "rm")]) == 0
    skill_meta = json.loads((tmp_path / "eval.json").read_text())["skill"]
    starts = [evaluation_starts(skill_meta["demo_starts"], config)[r["index"]] for r in ran]
    traces = [trace for _, trace in replay_episodes(tmp_path / "model", config, starts)]
    data = pq.read_table(tmp_path / "le" / "data" / "chunk-000" / "file-000.parquet").to_pydict()
    episodes = pq.read_table(tmp_path / "le" / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    assert [e["source_index"] for e in episodes] == [r["index"] for r in ran]
    with h5py.File(tmp_path / "rm" / "episodes.hdf5", "r") as f:
        for e, (record, trace) in enumerate(zip(ran, traces)):
            rows = np.array(data["episode_index"]) == e
            assert rows.sum() == record["steps"] + 1 == len(trace.times_s)
            np.testing.assert_array_equal(np.array(data["observation.joint_pos"])[rows], trace.qpos)
            np.testing.assert_array_equal(f[f"data/demo_{e}/obs/wrist_wrench"][()], trace.wrist_wrench)
            np.testing.assert_array_equal(f[f"data/demo_{e}/actions"][:-1, :3], trace.cmd_pos[1:])
            assert (episodes[e]["end_reason"], episodes[e]["success"]) == (record["reason"], record["success"])
            assert f[f"data/demo_{e}"].attrs["end_reason"] == record["reason"]
            assert f[f"data/demo_{e}/obs/front_image"].shape == (record["steps"] + 1, 24, 32, 3)
    import imageio.v2 as imageio

    reader = imageio.get_reader(tmp_path / "le" / "videos" / "observation.images.front" / "chunk-000" / "file-000.mp4")
    assert reader.count_frames() == len(data["index"])
    reader.close()
    # at 50 fps (every other control step): the frames are those steps' rows, the video a frame per row
    assert main(["export", "--episodes", str(tmp_path / "eval.json"), "--format", "lerobot", "--fps", "50", "--video",
                 "--video-size", "64x48", "--out", str(tmp_path / "le50")]) == 0
    info = json.loads((tmp_path / "le50" / "meta" / "info.json").read_text())
    assert info["fps"] == 50 and info["features"]["observation.images.front"]["info"]["video.fps"] == 50
    half = pq.read_table(tmp_path / "le50" / "data" / "chunk-000" / "file-000.parquet").to_pydict()
    for e, (record, trace) in enumerate(zip(ran, traces)):
        rows = np.array(half["episode_index"]) == e
        assert rows.sum() == record["steps"] // 2 + 1
        np.testing.assert_array_equal(np.array(half["observation.joint_pos"])[rows], trace.qpos[::2])
        np.testing.assert_array_equal(np.array(half["observation.wrist_wrench"])[rows], trace.sensed_wrench[::2])
        np.testing.assert_array_equal(np.array(half["action"])[rows][:-1, :3], trace.cmd_pos[1::2][:rows.sum() - 1])
    reader = imageio.get_reader(tmp_path / "le50" / "videos" / "observation.images.front" / "chunk-000" /
                                "file-000.mp4")
    assert reader.count_frames() == len(half["index"])
    reader.close()


@pytest.mark.parametrize("change", ["added", "edited", "folder"])
def test_overwrite_never_deletes_what_the_user_put_into_an_export(tmp_path: Path, demo_file: Path, change: str,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ds"
    args = ["export", "--demos", str(demo_file), "--format", "lerobot", "--out", str(out), "--overwrite"]
    assert main(args) == 0
    assert main(args) == 0  # an untouched export of ours is replaced
    if change == "added":
        (out / "notes.txt").write_text("mine")
    elif change == "edited":
        (out / "pih_export.json").write_text((out / "pih_export.json").read_text() + " ")
    else:
        (out / "mine").mkdir()
        (out / "mine" / "f").write_text("x")
    _refused_leaving_it_as_it_was(args, out, capsys, "did not write or that changed since")


@pytest.mark.parametrize("text", ["16x40000", "8x480", "641x480"])
def test_a_frame_size_no_renderer_makes_is_refused_naming_the_option(text: str) -> None:
    from envs.errors import EnvError
    from scripts.export import parse_size

    with pytest.raises(EnvError, match="--video-size .*multiples of 8 in \\[16, 4096\\]"):
        parse_size(text)
    assert parse_size("640x480") == (640, 480)


def test_an_export_from_before_the_file_lists_is_refused_not_deleted(tmp_path: Path, demo_file: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ds"
    args = ["export", "--demos", str(demo_file), "--format", "lerobot", "--out", str(out), "--overwrite"]
    assert main(args) == 0
    (out / ".pih-files.json").unlink()  # as exports were written before the lists
    _refused_leaving_it_as_it_was(args, out, capsys, "from before exports listed their files")


def _refused_leaving_it_as_it_was(args: list[str], out: Path, capsys: pytest.CaptureFixture[str], words: str) -> None:
    """`pih export ARGS` exits 2 with one line saying ``words``, and every path under ``out`` is still there."""
    before = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == before
